//! Each subcommand's clap arguments, converted into the plain options its library function takes.

pub mod bench;
pub mod bundle;
pub mod eval;
pub mod fit_sensor;
pub mod inspect;
pub mod label;
pub mod metrics;
pub mod pairing;
pub mod qdiag;
pub mod quantise;
pub mod run;
pub mod sil;
pub mod simulate;
pub mod update;
