//! `host-sim sil --reset-faults N`: device resets, end to end. The firmware built with its
//! test-only feature `reset-faults` hangs in the serving loop, panics or overflows its stack
//! when an `inject` message asks (`epssn::fault::inject`). `N` rounds each provoke the three
//! in a seeded random order, each after a seeded random number of frames of the session (so
//! the reset loses cached frames whose partner never came). After every reset the host starts
//! a new session (hellos until one is answered), checks the reset cause and the fault record
//! the hello carries, acknowledges the record, checks it is gone, and streams the first frames
//! again from the start of the new session: every depth map must be bit-exact with the host
//! library. Frames sent before the reset that had not completed a view set are re-sent with
//! the new session (never paired with its cache: a hello clears it); depth maps received
//! before the reset were checked when they came.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use epssn::fault::{inject, Record, ResetCause};
use epssn::link::Header;
use epssn_sim::synthetic::Rng;
use serde::Serialize;

use crate::device::{raw_bytes, Device, Reply};

/// Streams the first `n` frames of a session: (depth maps, expected, all bit-exact).
pub(crate) type StreamFn<'a> = dyn FnMut(&mut Device, usize) -> Result<(usize, usize, bool)> + 'a;

/// A fault record as the report shows it.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct RecordReport {
    /// The recorded cause.
    pub cause: String,
    /// Stacked PC, LR, xPSR; CFSR, HFSR, MMFAR, BFAR (hex).
    pub pc: String,
    /// Stacked LR.
    pub lr: String,
    /// Stacked xPSR.
    pub xpsr: String,
    /// Configurable Fault Status Register.
    pub cfsr: String,
    /// HardFault Status Register.
    pub hfsr: String,
    /// MemManage fault address.
    pub mmfar: String,
    /// BusFault address.
    pub bfar: String,
    /// Panic: line and column.
    pub line: u32,
    /// Panic column.
    pub column: u32,
    /// Panic text (message @ file).
    pub text: String,
}

impl From<&Record> for RecordReport {
    fn from(r: &Record) -> Self {
        let hex = |v: u32| format!("{v:#010x}");
        Self {
            cause: r.cause.name().into(),
            pc: hex(r.pc),
            lr: hex(r.lr),
            xpsr: hex(r.xpsr),
            cfsr: hex(r.cfsr),
            hfsr: hex(r.hfsr),
            mmfar: hex(r.mmfar),
            bfar: hex(r.bfar),
            line: r.line,
            column: r.column,
            text: r.text().into(),
        }
    }
}

/// One provoked reset.
#[derive(Serialize, Debug, Clone)]
pub struct ResetEvent {
    /// `hang`, `panic` or `stack_overflow`.
    pub fault: String,
    /// Frames of the session sent before the fault.
    pub frames_before: usize,
    /// Of them, cached without a completed view set when the reset came: re-sent.
    pub frames_lost: usize,
    /// The reset cause the new session's hello reported.
    pub cause: String,
    /// The cause the fault must give.
    pub expected_cause: String,
    /// The record the hello carried.
    pub record: Option<RecordReport>,
    /// The record is of the fault (cause; for a panic its text, for a HardFault its status
    /// registers, for the watchdog the stacked PC).
    pub record_ok: bool,
    /// The record was gone from the hello after the acknowledging one.
    pub acknowledged: bool,
    /// Wall time from the fault to the answered hello, seconds.
    pub reboot_seconds: f64,
    /// Depth maps received after the reset, and expected.
    pub depth_maps_after: usize,
    /// Expected after the reset.
    pub expected_depth_maps_after: usize,
    /// Every one bit-exact with the host library, with the same pairs.
    pub bit_exact_after: bool,
}

impl ResetEvent {
    /// Everything about this reset as it must be.
    pub fn ok(&self) -> bool {
        self.cause == self.expected_cause
            && self.record_ok
            && self.acknowledged
            && self.bit_exact_after
            && self.depth_maps_after == self.expected_depth_maps_after
    }
}

/// What `--reset-faults` gave.
#[derive(Serialize, Debug, Clone)]
pub struct ResetReport {
    /// Seed of the order and the frames before each fault.
    pub seed: u64,
    /// Rounds of the three faults.
    pub rounds: usize,
    /// Each reset, in order.
    pub resets: Vec<ResetEvent>,
    /// Depth maps received over the run (before and after the resets), all checked.
    pub depth_maps: usize,
    /// Every reset as it must be.
    pub all_ok: bool,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// How long a hello waits for its answer before it is sent again (a hello sent while the
/// device boots is lost: its UART is not enabled yet).
const HELLO_RETRY: Duration = Duration::from_secs(3);
/// How long a reset may take until the hello is answered (boot self-test included).
const REBOOT_TIMEOUT: Duration = Duration::from_secs(120);

/// The faults, their names and the causes they must give.
const FAULTS: [(u16, &str, ResetCause); 3] = [
    (inject::HANG, "hang", ResetCause::Watchdog),
    (inject::PANIC, "panic", ResetCause::Panic),
    (
        inject::STACK_OVERFLOW,
        "stack_overflow",
        ResetCause::HardFault,
    ),
];

/// A new session: hellos until one is answered, then what it said.
pub(crate) fn hello(
    device: &mut Device,
    ack: Option<u32>,
) -> Result<(epssn::link::Status, Option<ResetCause>, Option<Record>)> {
    let start = Instant::now();
    let header = Header {
        t: epssn::link::kind::HELLO,
        seq: 0,
        ack,
        ..Header::default()
    };
    while start.elapsed() < REBOOT_TIMEOUT {
        device.send(&raw_bytes(&header, &[]))?;
        let sent = Instant::now();
        while let Some(wait) = HELLO_RETRY.checked_sub(sent.elapsed()) {
            match device.reply_within(wait)? {
                Some(Reply::Hello(status, reset, record)) => return Ok((status, reset, record)),
                // Replies to the old session, or errors for a hello cut by the reset.
                Some(_) => continue,
                None => break,
            }
        }
    }
    bail!("no hello answered within {REBOOT_TIMEOUT:?} of a reset")
}

/// Waits until no reply has come for `quiet` (stragglers of the last session).
fn drain(device: &mut Device, quiet: Duration) -> Result<()> {
    while device.reply_within(quiet)?.is_some() {}
    Ok(())
}

/// Whether `record` is the one `fault` must leave.
fn record_fits(fault: u16, record: &Record) -> bool {
    match fault {
        inject::PANIC => record.cause == ResetCause::Panic && record.text().contains("injected"),
        // HFSR FORCED or a configurable fault: some status bit says what it was.
        inject::STACK_OVERFLOW => {
            record.cause == ResetCause::HardFault && (record.hfsr != 0 || record.cfsr != 0)
        }
        // The NMI found the loop that stopped feeding: a PC in the code.
        _ => record.cause == ResetCause::Watchdog && record.pc != 0,
    }
}

/// Runs `rounds` rounds of the three faults on `device`; `stream` sends frames from the
/// session's start and returns (depth maps, expected, bit-exact).
pub(crate) fn reset_faults(
    device: &mut Device,
    rounds: usize,
    seed: u64,
    frames: usize,
    cached_after: &dyn Fn(usize) -> usize,
    stream: &mut StreamFn<'_>,
) -> Result<ResetReport> {
    let start = Instant::now();
    let mut rng = Rng::new(seed);
    let mut resets = Vec::new();
    let mut depth_maps = 0;
    // Start from a clean session: whatever the device said at boot is not a provoked reset.
    let (_, _, record) = hello(device, None)?;
    if let Some(r) = record {
        hello(device, Some(r.id()))?;
    }
    drain(device, Duration::from_millis(200))?;
    for _ in 0..rounds {
        let mut order = FAULTS;
        rng.shuffle(&mut order);
        for (code, name, expected) in order {
            let before = rng.below(frames + 1);
            // A session of its own: the host's expectations number frames from its start.
            hello(device, None)?;
            drain(device, Duration::from_millis(200))?;
            let (maps, expected_maps, exact) = stream(device, before)?;
            depth_maps += maps;
            if !exact || maps != expected_maps {
                bail!("{name}: the {before} frames before the fault were not bit-exact");
            }
            let inject_at = Instant::now();
            let header = Header {
                t: "inject",
                seq: u32::try_from(before + 1).unwrap_or(u32::MAX),
                code: Some(code),
                ..Header::default()
            };
            device.send(&raw_bytes(&header, &[]))?;
            let (_, cause, record) = hello(device, None)?;
            let reboot_seconds = inject_at.elapsed().as_secs_f64();
            let acknowledged = match &record {
                Some(r) => hello(device, Some(r.id()))?.2.is_none(),
                None => false,
            };
            drain(device, Duration::from_millis(200))?;
            let (maps, expected_maps, exact) = stream(device, frames)?;
            depth_maps += maps;
            resets.push(ResetEvent {
                fault: name.into(),
                frames_before: before,
                frames_lost: cached_after(before),
                cause: cause.map_or("none", ResetCause::name).into(),
                expected_cause: expected.name().into(),
                record_ok: record.as_ref().is_some_and(|r| record_fits(code, r)),
                record: record.as_ref().map(RecordReport::from),
                acknowledged,
                reboot_seconds,
                depth_maps_after: maps,
                expected_depth_maps_after: expected_maps,
                bit_exact_after: exact,
            });
        }
    }
    let all_ok = !resets.is_empty() && resets.iter().all(ResetEvent::ok);
    Ok(ResetReport {
        seed,
        rounds,
        resets,
        depth_maps,
        all_ok,
        seconds: start.elapsed().as_secs_f64(),
    })
}
