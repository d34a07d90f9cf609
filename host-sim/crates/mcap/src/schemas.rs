//! The `ros2msg` schemas of the messages written: each type's definition followed by every
//! type it depends on, each introduced by a line of 80 `=` and `MSG: pkg/Type`, as rosbag2's
//! MCAP storage writes them (so Foxglove, RViz's bag tools and `ros2 bag` decode the file
//! without the message packages installed). Field types are fully qualified; the texts are the
//! ROS 2 definitions without their comments.

/// Line before each dependent definition.
pub const SEPARATOR: &str =
    "================================================================================";

const TIME: &str = "int32 sec\nuint32 nanosec\n";
const HEADER: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
const IMAGE: &str = "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
uint8 is_bigendian\nuint32 step\nuint8[] data\n";
const POINT_FIELD: &str = "uint8 INT8    = 1\nuint8 UINT8   = 2\nuint8 INT16   = 3\n\
uint8 UINT16  = 4\nuint8 INT32   = 5\nuint8 UINT32  = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n\
string name\nuint32 offset\nuint8 datatype\nuint32 count\n";
const POINT_CLOUD2: &str = "std_msgs/Header header\nuint32 height\nuint32 width\n\
sensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\n\
uint8[] data\nbool is_dense\n";
const VECTOR3: &str = "float64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION: &str = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
const TRANSFORM: &str = "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n";
const TRANSFORM_STAMPED: &str =
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n";
const TF_MESSAGE: &str = "geometry_msgs/TransformStamped[] transforms\n";
const STRING: &str = "string data\n";
// marine_msgs 2.1.0 (marine_acoustic_msgs), its constants kept: readers list them.
const PING_INFO: &str = "float32 frequency\nfloat32 sound_speed\nfloat32[] tx_beamwidths\n\
float32[] rx_beamwidths\n";
const SONAR_IMAGE_DATA: &str = "bool is_bigendian\nuint32 DTYPE_UINT8 = 0\n\
uint32 DTYPE_INT8 = 1\nuint32 DTYPE_UINT16 = 2\nuint32 DTYPE_INT16 = 3\n\
uint32 DTYPE_UINT32 = 4\nuint32 DTYPE_INT32 = 5\nuint32 DTYPE_UINT64 = 6\n\
uint32 DTYPE_INT64 = 7\nuint32 DTYPE_FLOAT32 = 8\nuint32 DTYPE_FLOAT64 = 9\n\
uint32 dtype\nuint32 beam_count\nuint8[] data\n";
const PROJECTED_SONAR_IMAGE: &str = "std_msgs/Header header\n\
marine_acoustic_msgs/PingInfo ping_info\ngeometry_msgs/Vector3[] beam_directions\n\
float32[] ranges\nmarine_acoustic_msgs/SonarImageData image\n";

/// A message type written to MCAP.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Schema {
    /// `sensor_msgs/msg/Image`.
    Image,
    /// `sensor_msgs/msg/PointCloud2`.
    PointCloud2,
    /// `tf2_msgs/msg/TFMessage`.
    TfMessage,
    /// `std_msgs/msg/String`.
    String,
    /// `marine_acoustic_msgs/msg/ProjectedSonarImage`.
    ProjectedSonarImage,
}

impl Schema {
    /// The schema record's name, as rosbag2 writes it (`pkg/msg/Type`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Image => "sensor_msgs/msg/Image",
            Self::PointCloud2 => "sensor_msgs/msg/PointCloud2",
            Self::TfMessage => "tf2_msgs/msg/TFMessage",
            Self::String => "std_msgs/msg/String",
            Self::ProjectedSonarImage => "marine_acoustic_msgs/msg/ProjectedSonarImage",
        }
    }

    /// The type's own definition, then its dependencies (`pkg/Type`, definition) in the order
    /// they are first met.
    fn parts(self) -> (&'static str, &'static [(&'static str, &'static str)]) {
        const HEADER_DEPS: [(&str, &str); 2] = [
            ("std_msgs/Header", HEADER),
            ("builtin_interfaces/Time", TIME),
        ];
        match self {
            Self::Image => (IMAGE, &HEADER_DEPS),
            Self::PointCloud2 => (
                POINT_CLOUD2,
                &[
                    HEADER_DEPS[0],
                    HEADER_DEPS[1],
                    ("sensor_msgs/PointField", POINT_FIELD),
                ],
            ),
            Self::TfMessage => (
                TF_MESSAGE,
                &[
                    ("geometry_msgs/TransformStamped", TRANSFORM_STAMPED),
                    HEADER_DEPS[0],
                    HEADER_DEPS[1],
                    ("geometry_msgs/Transform", TRANSFORM),
                    ("geometry_msgs/Vector3", VECTOR3),
                    ("geometry_msgs/Quaternion", QUATERNION),
                ],
            ),
            Self::String => (STRING, &[]),
            Self::ProjectedSonarImage => (
                PROJECTED_SONAR_IMAGE,
                &[
                    HEADER_DEPS[0],
                    HEADER_DEPS[1],
                    ("marine_acoustic_msgs/PingInfo", PING_INFO),
                    ("geometry_msgs/Vector3", VECTOR3),
                    ("marine_acoustic_msgs/SonarImageData", SONAR_IMAGE_DATA),
                ],
            ),
        }
    }

    /// The schema record's data: the `ros2msg` text.
    pub fn definition(self) -> String {
        let (own, deps) = self.parts();
        let mut text = own.to_string();
        for (name, def) in deps {
            text.push_str(&format!("{SEPARATOR}\nMSG: {name}\n{def}"));
        }
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_type_named_in_a_definition_is_defined_in_it() {
        let primitives = [
            "bool", "uint8", "int32", "uint32", "float64", "string", "float32",
        ];
        for s in [
            Schema::Image,
            Schema::PointCloud2,
            Schema::TfMessage,
            Schema::String,
            Schema::ProjectedSonarImage,
        ] {
            let text = s.definition();
            let defined: Vec<&str> = text
                .lines()
                .filter_map(|l| l.strip_prefix("MSG: "))
                .collect();
            for line in text
                .lines()
                .filter(|l| !l.is_empty() && !l.starts_with('='))
            {
                if line.starts_with("MSG: ") {
                    continue;
                }
                let ty = line
                    .split_whitespace()
                    .next()
                    .unwrap()
                    .trim_end_matches("[]");
                assert!(
                    primitives.contains(&ty) || defined.contains(&ty),
                    "{}: {ty} is not defined",
                    s.name()
                );
            }
        }
    }
}
