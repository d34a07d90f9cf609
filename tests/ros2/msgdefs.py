"""The ros2msg schema texts the bags are written with: each type's definition, then every type
it uses, each after a line of 80 '=' and 'MSG: pkg/Type', as rosbag2 writes them. The
definitions are those of marine_msgs 2.1.0 (marine_acoustic_msgs, BSD-3-Clause,
github.com/apl-ocean-engineering/marine_msgs) and ROS 2's common_interfaces, comments dropped."""

SEP = "=" * 80

TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
QUATERNION = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
PING_INFO = (
    "float32 frequency\nfloat32 sound_speed\nfloat32[] tx_beamwidths\nfloat32[] rx_beamwidths\n"
)
SONAR_IMAGE_DATA = """bool    is_bigendian
uint32  DTYPE_UINT8 = 0
uint32  DTYPE_INT8 = 1
uint32  DTYPE_UINT16 = 2
uint32  DTYPE_INT16 = 3
uint32  DTYPE_UINT32 = 4
uint32  DTYPE_INT32 = 5
uint32  DTYPE_UINT64 = 6
uint32  DTYPE_INT64 = 7
uint32  DTYPE_FLOAT32 = 8
uint32  DTYPE_FLOAT64 = 9
uint32  dtype
uint32 beam_count
uint8[] data
"""
PROJECTED_SONAR_IMAGE = """std_msgs/Header header
PingInfo ping_info
geometry_msgs/Vector3[] beam_directions
float32[] ranges
SonarImageData image
"""
TRANSFORM_STAMPED = (
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"
)
TRANSFORM = "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
TF_MESSAGE = "geometry_msgs/TransformStamped[] transforms\n"


def _schema(own, deps):
    return own + "".join(f"{SEP}\nMSG: {name}\n{text}" for name, text in deps)


SONAR_IMAGE_SCHEMA = _schema(
    PROJECTED_SONAR_IMAGE,
    [
        ("std_msgs/Header", HEADER),
        ("builtin_interfaces/Time", TIME),
        ("marine_acoustic_msgs/PingInfo", PING_INFO),
        ("geometry_msgs/Vector3", VECTOR3),
        ("marine_acoustic_msgs/SonarImageData", SONAR_IMAGE_DATA),
    ],
)
TF_SCHEMA = _schema(
    TF_MESSAGE,
    [
        ("geometry_msgs/TransformStamped", TRANSFORM_STAMPED),
        ("std_msgs/Header", HEADER),
        ("builtin_interfaces/Time", TIME),
        ("geometry_msgs/Transform", TRANSFORM),
        ("geometry_msgs/Vector3", VECTOR3),
        ("geometry_msgs/Quaternion", QUATERNION),
    ],
)
SONAR_IMAGE_TYPE = "marine_acoustic_msgs/msg/ProjectedSonarImage"
TF_TYPE = "tf2_msgs/msg/TFMessage"


def stamp(ns):
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def transform(stamp_ns, parent, child, q_xyzw):
    x, y, z, w = q_xyzw
    return {
        "header": {"stamp": stamp(stamp_ns), "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": {"x": 0.0, "y": 0.0, "z": 0.0},
            "rotation": {"x": x, "y": y, "z": z, "w": w},
        },
    }
