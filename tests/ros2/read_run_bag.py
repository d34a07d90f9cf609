"""Reads `run --mcap`'s output with the independent reader (PyPI mcap-ros2-support) and checks
its sonar frames decode as ProjectedSonarImage: one per frame of the recording, the model's
range bins and beam columns, ranges ascending inside the window, unit beam directions with
azimuths ascending to port, uint8 data of beams x ranges bytes. Prints the depth maps'
bytes' digest per topic and stamp, for comparing two runs.

    python read_run_bag.py RUN.mcap FRAMES
"""

import hashlib
import math
import sys

from mcap_ros2.reader import read_ros2_messages


def main():
    path, frames = sys.argv[1], int(sys.argv[2])
    images, depth = [], []
    for m in read_ros2_messages(path):
        topic = m.channel.topic
        if m.schema.name == "marine_acoustic_msgs/msg/ProjectedSonarImage":
            images.append((topic, m.ros_msg))
        elif topic.startswith("/depth/"):
            s = m.ros_msg.header.stamp
            digest = hashlib.sha256(bytes(m.ros_msg.data)).hexdigest()[:16]
            depth.append(f"{topic} {s.sec}.{s.nanosec:09d} {digest}")
    assert len(images) == frames, f"{len(images)} ProjectedSonarImage messages, {frames} frames"
    for topic, msg in images:
        bins, beams = len(msg.ranges), len(msg.beam_directions)
        assert msg.image.dtype == 0 and msg.image.beam_count == beams
        assert len(msg.image.data) == bins * beams, (len(msg.image.data), bins, beams)
        assert all(b > a for a, b in zip(msg.ranges, msg.ranges[1:])), "ranges not ascending"
        az = [math.atan2(-d.y, d.z) for d in msg.beam_directions]
        assert all(b > a for a, b in zip(az, az[1:])), "azimuths not ascending to port"
        for d in msg.beam_directions:
            assert abs(math.hypot(d.x, d.y, d.z) - 1) < 1e-9
        assert len(msg.ping_info.tx_beamwidths) == beams
    print(f"{len(images)} ProjectedSonarImage on {images[0][0]}: {bins} ranges "
          f"{msg.ranges[0]:.4f}-{msg.ranges[-1]:.4f} m, {beams} beams "
          f"{math.degrees(az[0]):.2f}..{math.degrees(az[-1]):.2f} deg")
    for line in depth:
        print(line)


if __name__ == "__main__":
    main()
