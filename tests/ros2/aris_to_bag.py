"""An ARIS recording written as a ROS 2 bag by an independent writer (PyPI mcap +
mcap-ros2-support), for the check that a bag gives the depth maps the .aris file gives.

    python aris_to_bag.py IN.aris OUT.mcap [--compression zstd|lz4|none] [--chunk-size N] [--no-tf]

Reads the ARIS file by docs/ARIS.md alone (offsets, range of each sample, beam tables) and
writes, per frame:
  /sonar/image  marine_acoustic_msgs/msg/ProjectedSonarImage, frame `sonar_image` (Z forward,
                X up): `ranges` each sample's range, `beam_directions` from the beam table,
                uint8 image, range-major (the ARIS samples as stored).
  /tf           map -> sonar: the attitude of docs/POSE.md (x forward, y left, z up).
and once /tf_static sonar -> sonar_image (the message's axes in the sonar's).
"""

import argparse
import math
import struct
from pathlib import Path

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

import msgdefs

ROOT = Path(__file__).resolve().parents[2]
TABLES = {
    (1, 128): "ARIS3000_128",
    (1, 64): "ARIS3000_64",
    (0, 96): "ARIS1800_96",
    (0, 48): "ARIS1800_1200_48",
    (2, 48): "ARIS1800_1200_48",
}
# The message's axes (Z forward, X up, Y starboard) in the sonar's (x forward, y left, z up):
# 180 degrees about (x + z)/sqrt(2). [x, y, z, w].
MESSAGE_IN_SONAR = (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)


def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def axis(i, deg):
    h = math.radians(deg) / 2
    v = [0.0, 0.0, 0.0]
    v[i] = math.sin(h)
    return (v[0], v[1], v[2], math.cos(h))


def attitude(h):
    """docs/POSE.md: Rz(-Heading) Ry(-Pitch) Rx(Roll) Rz(-Pan) Ry(-Tilt) Rx(RotatorRoll)."""
    first = lambda a, b: a if math.isfinite(a) else b
    pan = first(h["pan"], h["pan_abs"])
    tilt = first(h["tilt"], h["tilt_abs"])
    rot = first(h["roll_rot"], h["roll_abs"])
    if not all(math.isfinite(a) for a in (h["heading"], h["pitch"], h["roll"], rot)):
        return None
    q = (0.0, 0.0, 0.0, 1.0)
    for i, deg in (
        (2, -h["heading"]),
        (1, -h["pitch"]),
        (0, h["roll"]),
        (2, -(pan if math.isfinite(pan) else 0.0)),
        (1, -(tilt if math.isfinite(tilt) else 0.0)),
        (0, rot),
    ):
        q = qmul(q, axis(i, deg))
    return q


def read_aris(path):
    raw = Path(path).read_bytes()
    beams, samples = struct.unpack_from("<I", raw, 16)[0], struct.unpack_from("<I", raw, 24)[0]
    frame_len = 1024 + beams * samples
    count = (len(raw) - 1024) // frame_len
    frames = []
    for k in range(count):
        at = 1024 + k * frame_len
        f32 = lambda off: struct.unpack_from("<f", raw, at + off)[0]
        u32 = lambda off: struct.unpack_from("<I", raw, at + off)[0]
        header = {
            "time_us": struct.unpack_from("<Q", raw, at + 4)[0],
            "pitch": f32(136),
            "roll": f32(144),
            "heading": f32(152),
            "pan": f32(244),
            "tilt": f32(248),
            "roll_rot": f32(252),
            "period_us": u32(452),
            "sound_speed": f32(464),
            "samples": u32(468),
            "delay_us": u32(476),
            "large_lens": u32(480),
            "system": u32(484),
            "pan_abs": f32(632),
            "tilt_abs": f32(636),
            "roll_abs": f32(640),
        }
        assert header["samples"] == samples, "SamplesPerBeam differs from the file header"
        assert header["large_lens"] != 1, "telephoto tables are not handled here"
        frames.append((header, raw[at + 1024 : at + frame_len]))
    return beams, samples, frames


def beam_table(system, beams):
    name = TABLES[(system, beams)]
    rows = (ROOT / "data/aris-beam-widths" / f"{name}.csv").read_text().split("\n")[1:]
    cols = [r.split(",") for r in rows if r.strip()]
    return [(float(c[1]), float(c[2]), float(c[3])) for c in cols]


def sonar_image(header, beams, samples, data):
    c = header["sound_speed"]
    half = c * 1e-6 / 2
    start = header["delay_us"] * half
    step = header["period_us"] * half
    table = beam_table(header["system"], beams)
    directions = []
    for centre, _, _ in table:
        a = math.radians(centre)
        # Azimuth is the rotation about X (up): positive to port, which is -Y.
        directions.append({"x": 0.0, "y": -math.sin(a), "z": math.cos(a)})
    return {
        "header": {"stamp": msgdefs.stamp(header["time_us"] * 1000), "frame_id": "sonar_image"},
        "ping_info": {
            "frequency": 0.0,
            "sound_speed": c,
            "tx_beamwidths": [math.radians(14.0)] * beams,
            "rx_beamwidths": [math.radians(abs(r - l)) for _, l, r in table],
        },
        "beam_directions": directions,
        "ranges": [start + step * i for i in range(samples)],
        "image": {"is_bigendian": False, "dtype": 0, "beam_count": beams, "data": data},
    }


def main():
    p = argparse.ArgumentParser()
    p.add_argument("aris")
    p.add_argument("out")
    p.add_argument("--compression", choices=["zstd", "lz4", "none"], default="zstd")
    p.add_argument("--chunk-size", type=int, default=1024 * 1024)
    p.add_argument("--no-tf", action="store_true", help="no /tf: attitudes from --poses")
    a = p.parse_args()
    beams, samples, frames = read_aris(a.aris)
    compression = {
        "zstd": CompressionType.ZSTD,
        "lz4": CompressionType.LZ4,
        "none": CompressionType.NONE,
    }[a.compression]
    with open(a.out, "wb") as f:
        w = Writer(f, chunk_size=a.chunk_size, compression=compression)
        image = w.register_msgdef(msgdefs.SONAR_IMAGE_TYPE, msgdefs.SONAR_IMAGE_SCHEMA)
        tf = w.register_msgdef(msgdefs.TF_TYPE, msgdefs.TF_SCHEMA)
        t0 = frames[0][0]["time_us"] * 1000
        static = msgdefs.transform(t0, "sonar", "sonar_image", MESSAGE_IN_SONAR)
        w.write_message("/tf_static", tf, {"transforms": [static]}, log_time=t0)
        for header, data in frames:
            t = header["time_us"] * 1000
            q = attitude(header)
            if q is not None and not a.no_tf:
                msg = {"transforms": [msgdefs.transform(t, "map", "sonar", q)]}
                w.write_message("/tf", tf, msg, log_time=t)
            w.write_message(
                "/sonar/image", image, sonar_image(header, beams, samples, data), log_time=t
            )
        w.finish()
    print(f"wrote {len(frames)} frames of {beams} beams x {samples} samples to {a.out}")


if __name__ == "__main__":
    main()
