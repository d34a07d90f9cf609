//! `host-sim keygen` and `host-sim sign`'s command lines.

use std::path::PathBuf;

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
