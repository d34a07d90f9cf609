//! `host-sim keygen`, `host-sim sign` and `host-sim push`'s command lines.

use std::path::PathBuf;

use epssn_sil_core::update::PushOptions;
use host_sim::update::{KeygenOptions, SignOptions};

/// Arguments of `host-sim keygen`.
#[derive(clap::Args, Debug, Clone)]
pub struct KeygenArgs {
    /// Folder for the key pair: DIR/private (keep it secret) and DIR/public.
    #[arg(long)]
    pub out: PathBuf,
}

impl From<KeygenArgs> for KeygenOptions {
    fn from(a: KeygenArgs) -> Self {
        KeygenOptions { out: a.out }
    }
}

/// Arguments of `host-sim sign`.
#[derive(clap::Args, Debug, Clone)]
pub struct SignArgs {
    /// The private key (keygen's DIR/private).
    #[arg(long)]
    pub key: PathBuf,
    /// The weight blob (e.g. weights/site-tank/epssn-s.q8.bin).
    #[arg(long)]
    pub blob: PathBuf,
    /// The model version: a device takes only a version above the one it serves.
    #[arg(long)]
    pub version: u32,
    /// The signed update image to write.
    #[arg(long)]
    pub out: PathBuf,
}

impl From<SignArgs> for SignOptions {
    fn from(a: SignArgs) -> Self {
        SignOptions {
            key: a.key,
            blob: a.blob,
            version: a.version,
            out: a.out,
        }
    }
}

/// Arguments of `host-sim push`.
#[derive(clap::Args, Debug, Clone)]
pub struct PushArgs {
    /// The signed update image (`host-sim sign`).
    #[arg(long)]
    pub blob: PathBuf,
    /// A board on this serial port (e.g. `/dev/ttyACM0`).
    #[arg(long, conflicts_with = "qemu", required_unless_present = "qemu")]
    pub serial: Option<PathBuf>,
    /// The Cortex-M7 firmware in QEMU (its partition lives as long as QEMU runs).
    #[arg(long)]
    pub qemu: bool,
    /// The firmware ELF for `--qemu` (default: build it, with `EPSSN_UPDATE_KEY` or the test key).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// The serial port's baud rate (the board's `LINK_BAUD`).
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// Seconds to wait for any one reply.
    #[arg(long, default_value_t = 120)]
    pub timeout: u64,
}

impl From<PushArgs> for PushOptions {
    fn from(a: PushArgs) -> Self {
        PushOptions {
            image: a.blob,
            serial: a.serial,
            qemu: a.qemu,
            firmware: a.firmware,
            baud: a.baud,
            timeout: a.timeout,
        }
    }
}
