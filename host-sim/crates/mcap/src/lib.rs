//! The sonar's products as ROS 2 messages in MCAP files, for Foxglove, RViz and `ros2 bag`
//! (docs/MCAP.md): the message types and their `ros2msg` definitions (`msgs`, `schemas`),
//! their CDR encoding (`cdr`), the polar image drawn as a Cartesian fan (`fan`) and the file
//! writer that registers schemas and channels (`bag`), and what `run` and `sil` write alike
//! (`sonar`: TF frames, stamped headers, the sonar's transform, a depth map's points), and
//! the polar image as `marine_acoustic_msgs/ProjectedSonarImage` (`sonar_image`). What a
//! run writes where is the caller's (`host-sim run --mcap`, `sil --mcap`).

#![deny(missing_docs)]

pub mod bag;
pub mod cdr;
pub mod fan;
pub mod msgs;
pub mod schemas;
pub mod sonar;
pub mod sonar_image;

pub use bag::Bag;
