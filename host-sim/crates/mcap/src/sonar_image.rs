//! The model's polar image as `marine_acoustic_msgs/ProjectedSonarImage` (docs/ROS2.md), in
//! its own TF frame `sonar_image` (Z forward, X up, Y starboard, as the message defines its
//! axes), which `/tf_static` places in the sonar frame (x forward, y port, z up).

use anyhow::Result;
use epssn::config;
use epssn::geometry::Grid;

use crate::cdr::Bytes;
use crate::msgs::{
    PingInfo, ProjectedSonarImage, Quaternion, SonarImageData, TfMessage, Transform,
    TransformStamped, Vector3,
};
use crate::sonar::{header, SONAR_FRAME};

/// The topic of the sonar frames as ProjectedSonarImage.
pub const SONAR_IMAGE_TOPIC: &str = "/sonar/image";
/// The TF frame of the ProjectedSonarImage (the message's axes).
pub const SONAR_IMAGE_FRAME: &str = "sonar_image";
/// The static transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";

/// The polar image (`img[i · B + k]`, range bin `i`, input column `k`) at FrameTime `time_us`:
/// a beam per input column at its azimuth (from the spec's beam table), a range per bin at
/// its centre, uint8.
pub fn sonar_image(time_us: u64, polar: &[u8]) -> Result<ProjectedSonarImage> {
    anyhow::ensure!(
        polar.len() == config::INPUT_LEN,
        "polar image of {} bytes, {} expected",
        polar.len(),
        config::INPUT_LEN
    );
    let grid = Grid {
        r_min: config::R_MIN_M,
        r_max: config::R_MAX_M,
        half_elevation: config::HALF_ELEVATION_RAD,
        column_azimuths: &config::INPUT_COLUMN_AZIMUTH_RAD,
    };
    let az = grid.column_azimuths;
    // A column's width: half the distance to each neighbour (the outer ones mirrored).
    let widths = (0..az.len()).map(|k| {
        let lo = if k > 0 {
            az[k] - az[k - 1]
        } else {
            az[1] - az[0]
        };
        let hi = if k + 1 < az.len() {
            az[k + 1] - az[k]
        } else {
            lo
        };
        ((lo + hi) / 2.0) as f32
    });
    Ok(ProjectedSonarImage {
        header: header(time_us, SONAR_IMAGE_FRAME)?,
        ping_info: PingInfo {
            frequency: 0.0,
            sound_speed: 0.0,
            tx_beamwidths: vec![(2.0 * grid.half_elevation) as f32; az.len()],
            rx_beamwidths: widths.collect(),
        },
        beam_directions: az
            .iter()
            .map(|&a| Vector3 {
                x: 0.0,
                y: -a.sin(),
                z: a.cos(),
            })
            .collect(),
        ranges: (0..config::INPUT_RANGE_BINS)
            .map(|i| grid.range_bin_centre(i, config::INPUT_RANGE_BINS) as f32)
            .collect(),
        image: SonarImageData {
            is_bigendian: false,
            dtype: 0,
            beam_count: az.len() as u32,
            data: Bytes(polar.to_vec()),
        },
    })
}

/// sonar ← sonar_image: 180° about (x + z)/√2, which takes the message's Z (forward) to the
/// sonar's x, its X (up) to z and its Y (starboard) to −y.
pub fn image_frame_tf(time_us: u64) -> Result<TfMessage> {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    Ok(TfMessage {
        transforms: vec![TransformStamped {
            header: header(time_us, SONAR_FRAME)?,
            child_frame_id: SONAR_IMAGE_FRAME.into(),
            transform: Transform {
                translation: Vector3 {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0,
                },
                rotation: Quaternion {
                    x: h,
                    y: 0.0,
                    z: h,
                    w: 0.0,
                },
            },
        }],
    })
}
