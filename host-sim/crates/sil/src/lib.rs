//! Software in the loop: the real firmware booted in QEMU (or a real board on a serial port)
//! and fed a recording over the link,
//! every depth map compared bit for bit with the host library (`host-sim sil`), per-layer
//! instruction counts (`host-sim bench`), and the budgets both enforce.

#![deny(missing_docs)]

pub mod bench;
pub mod budgets;
pub mod faults;
pub mod serial;
pub mod sil;
