//! Software in the loop: the real firmware booted in QEMU (or a real board on a serial port)
//! and fed a recording over the link,
//! every depth map compared bit for bit with the host library (`host-sim sil`), per-layer
//! instruction counts (`host-sim bench`), and the budgets both enforce.
//!
//! `sil` orchestrates a run; `faults` generates every fault it sends (the campaign, the soak's
//! blocks, the fuzz run); both talk to the device through `device` (QEMU or a serial port, the
//! reply reader, message bytes), which knows neither; `mcap_out` writes `sil --mcap`;
//! `update` is the model update client (`host-sim push`) and `sil --update`'s check; both
//! stream frames prepared on the host through `stream`, and run the image `firmware` builds.

#![deny(missing_docs)]

pub mod bench;
pub mod budgets;
mod device;
pub mod faults;
pub mod firmware;
pub mod mcap_out;
pub mod resets;
pub mod serial;
pub mod sil;
mod stream;
pub mod target;
pub mod update;
