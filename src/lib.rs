//! # epssn
//!
//! EPSSN (Elevation Plane Sweeping Stereo Network; Wang et al., IROS 2022) for 2D
//! forward-looking sonar, as `no_std`, allocation-free int8 fixed-point inference for a
//! Cortex-M7-class co-processor. Two or three sonar images with a known small roll between
//! them go in; a *front depth map* comes out: for every (elevation, azimuth) ray, the range at
//! which it first meets a surface.
//!
//! Every size comes from the model spec in `weights/` through `build.rs` ([`config`]); the
//! spec types and the sonar geometry live in one crate, `epssn-spec` (re-exported as [`spec`],
//! [`geometry`], [`grids`], [`crc32`]), that the build script, the host tools and the firmware
//! share.
//!
//! ```
//! use epssn::{config, geometry};
//!
//! // Where does the ray of plane 0, feature column 8 appear in the rolled source view?
//! let entry = config::WARP_TABLES[0][8];
//! let (az, el) = geometry::warp_direction(
//!     &geometry::RigidTransform::roll_deg(config::ROLL_STEP_DEG),
//!     config::FEATURE_COLUMN_AZIMUTH_RAD[8],
//!     config::PLANE_ELEVATION_RAD[0],
//! );
//! assert_eq!(entry.visible, el.abs() <= config::HALF_ELEVATION_RAD);
//! assert!(az.is_finite());
//! ```

#![no_std]
// The only unsafe code is the inline assembly of `arch`'s optional `dsp` and `mve` backends.
#![cfg_attr(not(feature = "dsp"), forbid(unsafe_code))]
#![cfg_attr(feature = "dsp", deny(unsafe_code))]
#![deny(missing_docs)]

#[cfg(any(test, feature = "std"))]
extern crate std;

// The spec, the geometry, the grids and the CRC live in `epssn-spec` (shared with the build
// script and the host tools); re-exported here so `epssn::spec` and `epssn::geometry` stay.
pub use epssn_spec::{crc32, geometry, grids, spec};

pub mod arch;
pub mod attitude;
pub mod blob;
pub mod config;
pub mod fault;
pub mod golden;
pub mod kernels;
pub mod link;
pub mod model;
pub mod pairing;
pub mod ping_average;
pub mod requant;
pub mod server;
