//! The sonar scene simulator of the epssn host tools: scenes, ray-cast ARIS views with exact
//! ground truth, simulated datasets on disk, previews and the figures' drawing helpers, the accuracy metrics against ground
//! truth (MAE, masked MAE, CD), and the deterministic generator of test and bring-up data.

#![deny(missing_docs)]

pub mod dataset;
pub mod draw;
pub mod groundtruth;
pub mod mesh;
pub mod metrics;
pub mod poses;
pub mod preview;
pub mod ray;
pub mod render;
pub mod scene;
pub mod sensor_fit;
pub mod sensor_stats;
pub mod simulate;
pub mod site;
pub mod synthetic;
pub mod tessellate;
pub mod world;
