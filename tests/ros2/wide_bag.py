"""A bag of a sonar the model cannot take: 130 degrees, 512 beams, ranges from 5 m to 40 m
(outside the model's window), uint16 image, no /tf. `run` must refuse it by name, without a
panic, and write nothing.

    python wide_bag.py OUT.mcap
"""

import math
import sys

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

import msgdefs

BEAMS, RANGES = 512, 700


def main():
    out = sys.argv[1]
    half = math.radians(130.0) / 2
    azimuths = [-half + 2 * half * b / (BEAMS - 1) for b in range(BEAMS)]
    ranges = [5.0 + 35.0 * i / (RANGES - 1) for i in range(RANGES)]
    data = bytes((i * 7) % 256 for i in range(BEAMS * RANGES * 2))
    with open(out, "wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        image = w.register_msgdef(msgdefs.SONAR_IMAGE_TYPE, msgdefs.SONAR_IMAGE_SCHEMA)
        for k in range(4):
            t = 1_700_000_000_000_000_000 + k * 100_000_000
            msg = {
                "header": {"stamp": msgdefs.stamp(t), "frame_id": "oculus"},
                "ping_info": {
                    "frequency": 750e3,
                    "sound_speed": 1500.0,
                    "tx_beamwidths": [],
                    "rx_beamwidths": [],
                },
                "beam_directions": [
                    {"x": 0.0, "y": -math.sin(a), "z": math.cos(a)} for a in azimuths
                ],
                "ranges": ranges,
                "image": {"is_bigendian": False, "dtype": 2, "beam_count": BEAMS, "data": data},
            }
            w.write_message("/oculus/sonar_image", image, msg, log_time=t)
        w.finish()


if __name__ == "__main__":
    main()
