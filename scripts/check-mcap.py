#!/usr/bin/env python3
"""Reads a `host-sim run --mcap` file with the ROS 2 tooling's own decoder, not ours.

    python3 scripts/check-mcap.py RUN.mcap RUN.json [--render PNG]

RUN.json is the same run's `--json` output. `mcap-ros2-support` (PyPI: the MCAP project's own
Python reader and ROS 2 CDR decoder, written apart from this repository) decodes every message
from the file's own schema texts; the script then checks, failing with a message:

- every sonar frame has its polar image, its fan and a `/tf`, each stamped at the frame's time,
  and the log time of every message equals its header stamp;
- one `/depth/{int8,float,ground_truth}` image (32FC1, the spec's rows x columns) and one
  `/points/{int8,float}` cloud per pair of the JSON, in the JSON's order;
- the all-pixel MAE recomputed here from the decoded depth and ground-truth images (the paper's
  formula: 1000 / (H W) * sum |d - clamp(g, r_min, r_max)|, mm) equals the JSON's per pair to
  1e-6 relative;
- each cloud holds exactly the pixels whose decoded depth reads more than 1 mm inside
  (r_min, r_max) (the prediction's own mask), and each point's range field equals its
  x, y, z norm;
- `/run/summary` equals the JSON.

`--render PNG` draws the merged `/sweep/points` (or, without `--frame world`, the per-pair int8
clouds) seen from above and from the side, coloured by pair.
"""

import argparse
import json
import math
import struct
import sys
from collections import defaultdict
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

ROOT = Path(__file__).resolve().parent.parent


def fail(what):
    sys.exit(f"check-mcap: {what}")


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def depth_image(msg):
    if msg.encoding != "32FC1" or msg.step != 4 * msg.width:
        fail(f"depth image encoding {msg.encoding}, step {msg.step}, width {msg.width}")
    n = msg.width * msg.height
    fmt = (">" if msg.is_bigendian else "<") + f"{n}f"
    return msg.height, msg.width, struct.unpack(fmt, bytes(msg.data))


def cloud_points(msg):
    fields = {f.name: f.offset for f in msg.fields}
    for name in ("x", "y", "z", "range"):
        if name not in fields:
            fail(f"cloud without field {name}")
    data = bytes(msg.data)
    order = ">" if msg.is_bigendian else "<"
    out = []
    for i in range(msg.width * msg.height):
        base = i * msg.point_step
        out.append(
            {
                name: struct.unpack_from(order + "f", data, base + off)[0]
                for name, off in fields.items()
                if name != "pair"
            }
        )
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mcap")
    ap.add_argument("json")
    ap.add_argument("--render")
    ap.add_argument("--spec", default=str(ROOT / "weights" / "epssn-s.json"))
    args = ap.parse_args()

    spec = json.loads(Path(args.spec).read_text())
    # As f32, the depth maps' type: an empty ray reads r_max exactly, in f32.
    r_min, r_max = (f32(spec["range_window"][k]) for k in ("r_min_m", "r_max_m"))
    rows = spec["output"]["elevation_rows"]
    cols = spec["output"]["azimuth_columns"]
    run = json.loads(Path(args.json).read_text())

    topics = defaultdict(list)
    with open(args.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, ros in reader.iter_decoded_messages():
            topics[channel.topic].append((message.log_time, schema.name, ros))
    counts = {t: len(m) for t, m in sorted(topics.items())}

    # Time stamps: the log time is the header stamp (tf: each transform's).
    for topic, msgs in topics.items():
        for log_time, _, ros in msgs:
            if hasattr(ros, "header"):
                if stamp_ns(ros.header) != log_time:
                    fail(f"{topic}: log time {log_time} != header stamp {stamp_ns(ros.header)}")
            elif hasattr(ros, "transforms"):
                if any(stamp_ns(t.header) != log_time for t in ros.transforms):
                    fail(f"{topic}: a transform's stamp differs from the log time")
    frame_times = [t for t, _, _ in topics["/sonar/polar"]]
    for topic in ("/sonar/fan", "/tf"):
        if [t for t, _, _ in topics[topic]] != frame_times:
            fail(f"{topic}: not one message per sonar frame at its time")

    pairs = run["details"]
    for topic in ("/depth/int8", "/depth/float", "/points/int8", "/points/float"):
        if len(topics[topic]) != len(pairs):
            fail(f"{topic}: {len(topics[topic])} messages for {len(pairs)} pairs")
    worst = 0.0
    for k, pair in enumerate(pairs):
        # The ground truth decoded once per pair, for both models.
        truth = topics["/depth/ground_truth"]
        gt = depth_image(truth[k][2])[2] if truth else None
        for model in ("int8", "float"):
            h, w, depth = depth_image(topics[f"/depth/{model}"][k][2])
            if (h, w) != (rows, cols):
                fail(f"/depth/{model} {k}: {h} x {w}, the spec says {rows} x {cols}")
            if gt is not None:
                mae = 1000.0 / (h * w) * sum(
                    abs(d - min(max(g, r_min), r_max)) for d, g in zip(depth, gt)
                )
                want = pair[model]["mae"]
                rel = abs(mae - want) / max(want, 1e-12)
                worst = max(worst, rel)
                if rel > 1e-6:
                    fail(f"pair {k} {model}: MAE from the file {mae:.6f} mm, run --json {want:.6f}")
            own = sum(1 for d in depth if r_min + 1e-3 < d < r_max - 1e-3)
            points = cloud_points(topics[f"/points/{model}"][k][2])
            if len(points) != own:
                fail(f"pair {k} {model}: {len(points)} points, {own} pixels inside the window")
            for p in points:
                norm = math.sqrt(p["x"] ** 2 + p["y"] ** 2 + p["z"] ** 2)
                if abs(norm - p["range"]) > 1e-4:
                    fail(f"pair {k} {model}: a point's range {p['range']} != its norm {norm}")
    if topics["/run/summary"]:
        summary = json.loads(topics["/run/summary"][0][2].data)
        if summary != run:
            fail("/run/summary differs from run --json")

    print(json.dumps({"messages": counts, "pairs": len(pairs),
                      "worst_mae_relative_difference": worst}, indent=1))

    if args.render:
        render(topics, args.render)


def render(topics, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = []
    if topics.get("/sweep/points"):
        msg = topics["/sweep/points"][-1][2]
        fields = {f.name: f.offset for f in msg.fields}
        data = bytes(msg.data)
        by_pair = defaultdict(list)
        for i in range(msg.width * msg.height):
            base = i * msg.point_step
            xyz = struct.unpack_from("<3f", data, base + fields["x"])
            pair = struct.unpack_from("<I", data, base + fields["pair"])[0]
            by_pair[pair].append(xyz)
        sets = [(f"pair {p}", pts) for p, pts in sorted(by_pair.items())]
        frame = msg.header.frame_id
    else:
        for k, (_, _, msg) in enumerate(topics["/points/int8"]):
            sets.append((f"pair {k}", [(p["x"], p["y"], p["z"]) for p in cloud_points(msg)]))
        frame = "each pair's sonar frame"
    fig, (top, side) = plt.subplots(1, 2, figsize=(11, 4.5))
    for label, pts in sets:
        xs, ys, zs = zip(*pts)
        top.scatter(xs, ys, s=1, label=label)
        side.scatter(xs, zs, s=1, label=label)
    top.set(xlabel="x (m)", ylabel="y (m)", title=f"from above ({frame})", aspect="equal")
    side.set(xlabel="x (m)", ylabel="z (m)", title="from the side", aspect="equal")
    top.legend(markerscale=8, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
