//! `host-sim sil`: software in the loop. Boots the firmware in QEMU (MPS2-AN500, Cortex-M7,
//! `-icount shift=0`) with UART0 on a Unix socket, streams a recording's frames over the link
//! protocol (`epssn::link`), and checks every depth map bit for bit against the library run
//! on the host on the same frames with the same weight blob. Reports instructions per depth
//! map (the firmware's timer ticks × 40 under `-icount shift=0`), flash and RAM from the ELF
//! sections plus the measured stack high-water mark. `--fuzz N` then sends N malformed
//! messages interleaved with status requests and checks that the firmware always answers.
//! `--faults N` (default 2) runs the fault campaign; `--soak N` instead sends at least N valid
//! and faulty messages in blocks and checks the stack high-water mark is unchanged. The faults
//! of both come from `faults.rs`, the link to the device from `device.rs`, the frames and their
//! streaming from `stream.rs`, the firmware image from `firmware.rs`; this file is the
//! orchestration and the report.
//! `--serial PORT` runs the same checks against a real board (boards/stm32h743) on a serial
//! port instead of QEMU; its figures are then core cycles, and the QEMU budgets are not applied.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use epssn::link::{self, Message};
use serde::Serialize;

use epssn_ros2::OpenOptions;

use crate::device::{Device, Reply};
pub use crate::faults::FuzzReport;
use crate::faults::{campaign, fuzz, FaultReport};
use crate::firmware::firmware_blob;
pub use crate::firmware::{build_firmware, build_firmware_with, elf_sizes, TEST_UPDATE_KEY};
use crate::mcap_out::{DeviceMap, StreamedFrame};
use crate::stream::{prepare_frames, stream, HostFrame, Streamed};
use crate::target::Target;

/// Options of `host-sim sil`.
#[derive(Debug, Clone)]
pub struct SilOptions {
    /// The recording to stream (default: the bundled simulated demo, `data/demo/`).
    pub recording: Option<PathBuf>,
    /// A bag's ProjectedSonarImage topic (default: its only one).
    pub topic: Option<String>,
    /// Print machine-readable JSON.
    pub json: bool,
    /// The firmware ELF (default: build the target's firmware crate in release and use it).
    pub firmware: Option<PathBuf>,
    /// The core to run on: `m7` (QEMU mps2-an500, `boards/mps2-an500`) or `m55` (QEMU mps3-an547,
    /// `boards/mps3-an547`, budgets `weights/budgets-m55.json`).
    pub target: Target,
    /// Stream at most this many frames.
    pub frames: Option<usize>,
    /// After the frames, send this many malformed messages (with status requests between).
    pub fuzz: usize,
    /// Fault campaign (docs/LINK.md, "Fault campaign"): rounds per fault class, each fault checked
    /// against the library decoder's verdict, then a hello and valid frames checked bit for bit.
    pub faults: usize,
    /// Soak (docs/LINK.md): instead of the fault campaign, at least this many messages (N ≥
    /// 5,000 for the soak), valid and faulty: blocks of one round of every fault class
    /// followed by a hello and valid frames whose depth maps must be bit-exact; the stack
    /// high-water must end where it began.
    pub soak: usize,
    /// Seed of the fuzz run and the fault campaign.
    pub seed: u64,
    /// Seconds to wait for any one reply.
    pub timeout: u64,
    /// The budgets file (default: the target's, `weights/budgets.json` for the M7).
    pub budgets: Option<PathBuf>,
    /// Talk to a real board on this serial port (e.g. `/dev/ttyACM0`, the ST-LINK's virtual
    /// COM port) instead of booting the firmware in QEMU. Sizes come from `--firmware`
    /// (default: the STM32H743 board's release ELF, if built); budgets are not applied.
    pub serial: Option<PathBuf>,
    /// The serial port's baud rate (the board's `LINK_BAUD`).
    pub baud: u32,
    /// Device resets (docs/LINK.md, "Resets"): builds the firmware with its test-only feature
    /// `reset-faults` and provokes a hang, a panic and a stack overflow this many rounds each
    /// (seeded order), checking each reset's cause and fault record and the depth maps after
    /// it bit for bit.
    pub reset_faults: usize,
    /// Also write what the device returned as an MCAP file of ROS 2 messages (docs/MCAP.md):
    /// every frame streamed and every depth map the device sent back, with its points.
    pub mcap: Option<PathBuf>,
    /// A signed update image (docs/UPDATE.md): after the other checks, blobs the device must
    /// refuse (each with its code), then this one uploaded and committed, and every streamed
    /// depth map bit-exact with the host library running its blob.
    pub update: Option<PathBuf>,
    /// With `update`: resets at this many seeded points of the upload and the commit, after
    /// each of which the old model (until the commit) must serve bit for bit.
    pub update_faults: usize,
}

/// What a soak (`--soak N`) adds to the fault campaign's table.
#[derive(Serialize, Debug, Clone, Default, PartialEq)]
pub struct SoakReport {
    /// Messages sent, valid and faulty (the campaign's messages plus the valid frames).
    pub messages: usize,
    /// Blocks: one round of every fault class, then a hello and valid frames.
    pub blocks: usize,
    /// Valid frames sent between the blocks.
    pub valid_frames: usize,
    /// Depth maps received for them.
    pub depth_maps: usize,
    /// Depth maps the host library expected for them.
    pub expected_depth_maps: usize,
    /// Values that differed from the host library, over all of them.
    pub mismatched_values: usize,
    /// Stack high-water mark at the soak's first hello and at its last, bytes.
    pub stack_high_water_before: u32,
    /// At the last hello.
    pub stack_high_water_after: u32,
    /// The two are equal: no path of the soak went deeper than the valid frames before it.
    pub stack_unchanged: bool,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// The result of a SIL run.
#[derive(Serialize, Debug, Clone)]
pub struct SilReport {
    /// The recording streamed.
    pub recording: String,
    /// The firmware ELF.
    pub firmware: String,
    /// Where the firmware ran: "qemu" or the serial port.
    pub device: String,
    /// The core QEMU emulated: "m7" or "m55".
    pub target: Target,
    /// What the cost figures count: "instructions" (QEMU `-icount`) or "cycles" (a board's
    /// cycle counter, over `--serial`).
    pub cost_unit: String,
    /// Frames sent.
    pub frames: usize,
    /// Depth maps received.
    pub depth_maps: usize,
    /// Depth maps the host library's pairing expected.
    pub expected_depth_maps: usize,
    /// Every depth map equal to the host library's, bit for bit, with the same frame pairs.
    pub bit_exact: bool,
    /// Values that differed, over all depth maps.
    pub mismatched_values: usize,
    /// Instructions per depth map: the newest frame's features plus the depth map, as the
    /// firmware measured them (mean over the maps).
    pub instructions_per_depth_map: u64,
    /// Per depth map.
    pub instructions: Vec<u32>,
    /// `(reference, sources)` frame sequence numbers of each depth map.
    pub pairs: Vec<(u32, Vec<u32>)>,
    /// `(reference, source, reason)` of each candidate pair the device's pose gate rejected
    /// (docs/POSE.md).
    pub rejected_pairs: Vec<(u32, u32, String)>,
    /// The host library rejected exactly the same pairs for the same reasons.
    pub rejections_agree: bool,
    /// Flash: .vector_table + .text + .rodata + .data.
    pub flash_bytes: u64,
    /// RAM: .data + .bss + .uninit + stack high-water mark.
    pub ram_bytes: u64,
    /// Static RAM: .data + .bss + .uninit.
    pub static_ram_bytes: u64,
    /// Stack high-water mark reported by the firmware, bytes (with `--update`, the larger of
    /// the one at the commit and the one at the end).
    pub stack_high_water_bytes: u32,
    /// Status counters at the end: frames, depth maps, errors.
    pub device_frames: u32,
    /// Depth maps the device counted.
    pub device_depth_maps: u32,
    /// Errors the device counted.
    pub device_errors: u32,
    /// The fuzz run, if any.
    pub fuzz: Option<FuzzReport>,
    /// The fault campaign, if any (with `--soak`, the soak's blocks summed).
    pub faults: Option<FaultReport>,
    /// The soak, with `--soak N`.
    pub soak: Option<SoakReport>,
    /// The provoked resets, with `--reset-faults N`.
    pub resets: Option<crate::resets::ResetReport>,
    /// The model update, with `--update S`.
    pub update: Option<crate::update::UpdateReport>,
    /// After the fault campaign: a hello, then frames again, every depth map bit-exact with
    /// the host library (pairs and feature cache included); true without a campaign.
    pub after_faults_bit_exact: bool,
    /// Depth maps received after the faults.
    pub after_faults_depth_maps: usize,
    /// Wall time of the fault campaign and the frames after it, seconds.
    pub faults_seconds: f64,
    /// The firmware answered every status request and shut down cleanly.
    pub alive: bool,
    /// The budgets checked (`weights/budgets.json`).
    pub budgets: crate::budgets::Budgets,
    /// What exceeds the budgets (empty: within budget).
    pub budget_violations: Vec<String>,
}

/// Frames streamed again after the fault campaign (enough for a few depth maps).
pub(crate) const AFTER_FAULTS_FRAMES: usize = 6;

/// The default ELF of the STM32H743 board (`boards/stm32h743`, release).
fn board_elf() -> PathBuf {
    epssn_spec::load::repo_root()
        .join("boards/stm32h743/target/thumbv7em-none-eabihf/release/epssn-stm32h743")
}

/// The soak of `--soak n`: blocks of one fault round of every class (a new seed each) and the
/// first frames again after its closing hello, until `n` messages are sent. Returns the
/// campaign table summed over the blocks and the soak's own figures.
fn soak(
    device: &mut Device,
    n: usize,
    seed: u64,
    frames: &[HostFrame],
) -> Result<(FaultReport, SoakReport)> {
    let start = Instant::now();
    let again = &frames[..frames.len().min(AFTER_FAULTS_FRAMES)];
    let mut total: Option<FaultReport> = None;
    let mut s = SoakReport::default();
    let mut pairs_ok = true;
    while s.messages < n {
        let block_seed = seed.wrapping_add(s.blocks as u64);
        let (report, _) = campaign(device, 1, block_seed, &frames[0].image)?;
        s.messages += report.messages;
        match &mut total {
            None => total = Some(report),
            Some(t) => t.merge(report),
        }
        // The block ended with a hello (seq 0, cache cleared): same seqs, same pairs.
        let mut seq = 0;
        let streamed = stream(device, again, &mut seq)?;
        s.messages += again.len();
        s.valid_frames += again.len();
        s.depth_maps += streamed.depth_maps;
        s.expected_depth_maps += again.iter().filter(|f| f.expected.is_some()).count();
        s.mismatched_values += streamed.mismatched;
        pairs_ok &= streamed.pairs_ok;
        s.blocks += 1;
    }
    let mut total = total.unwrap_or_default();
    total.seed = seed;
    s.stack_high_water_before = total.stack_high_water_before;
    s.stack_high_water_after = total.stack_high_water_after;
    s.stack_unchanged = s.stack_high_water_before == s.stack_high_water_after;
    s.seconds = start.elapsed().as_secs_f64();
    if !pairs_ok {
        // Counted as mismatches so the bit-exact verdict below fails.
        s.mismatched_values = s.mismatched_values.max(1);
    }
    Ok((total, s))
}

/// The firmware ELF (built unless named), its flash and static RAM, and the device running
/// it: QEMU, or the board on `--serial`.
fn open_device(args: &SilOptions, timeout: Duration) -> Result<(PathBuf, (u64, u64), Device)> {
    if args.reset_faults > 0 && args.target != Target::M7 {
        bail!(
            "--reset-faults needs the Cortex-M7 firmware (boards/mps2-an500): the {:?} board has \
             no watchdog or fault record yet",
            args.target
        );
    }
    Ok(match &args.serial {
        None => {
            let elf = match &args.firmware {
                Some(p) => p.clone(),
                None => build_firmware_with(
                    args.target,
                    (args.reset_faults > 0).then_some("reset-faults"),
                )?,
            };
            let sizes = elf_sizes(&elf)?;
            let device = Device::boot_with(&elf, timeout, args.target, args.update_faults > 0)?;
            (elf, sizes, device)
        }
        Some(port) => {
            // The board runs whatever was flashed: sizes from the ELF named (or the board's
            // release build), when there is one.
            let elf = args.firmware.clone().unwrap_or_else(board_elf);
            let sizes = elf_sizes(&elf).unwrap_or((0, 0));
            (elf, sizes, Device::serial(port, args.baud, timeout)?)
        }
    })
}

/// What the fault campaign or the soak gave.
struct AfterFaults {
    /// The campaign's table (the soak's blocks summed).
    faults: Option<FaultReport>,
    /// The frames streamed after the faults: all bit-exact, and how many depth maps.
    after: Option<(bool, usize)>,
    soak: Option<SoakReport>,
}

/// `--soak N`, else `--faults N` followed by the first frames again; `seq` is the session's
/// last sequence number, which the campaign's closing hello restarts.
fn faults_and_soak(
    args: &SilOptions,
    device: &mut Device,
    frames: &[HostFrame],
    seq: &mut u32,
) -> Result<AfterFaults> {
    Ok(if args.soak > 0 {
        let (report, s) = soak(device, args.soak, args.seed, frames)?;
        let ok = s.mismatched_values == 0
            && s.depth_maps == s.expected_depth_maps
            && s.expected_depth_maps > 0;
        let maps = s.depth_maps;
        AfterFaults {
            faults: Some(report),
            after: Some((ok, maps)),
            soak: Some(s),
        }
    } else if args.faults > 0 {
        let (report, _) = campaign(device, args.faults, args.seed, &frames[0].image)?;
        // The campaign ended with a hello (seq 0, cache cleared): the frames again, with the
        // same seqs as the first time, so the same pairs and depth maps are expected.
        let again = &frames[..frames.len().min(AFTER_FAULTS_FRAMES)];
        *seq = 0;
        let s = stream(device, again, seq)?;
        let expected = again.iter().filter(|f| f.expected.is_some()).count();
        let ok = s.pairs_ok && s.mismatched == 0 && s.depth_maps == expected && expected > 0;
        AfterFaults {
            faults: Some(report),
            after: Some((ok, s.depth_maps)),
            soak: None,
        }
    } else {
        AfterFaults {
            faults: None,
            after: None,
            soak: None,
        }
    })
}

/// `--reset-faults N` on the session's frames (the first `AFTER_FAULTS_FRAMES`), each
/// stream starting a session's numbering at 1.
fn provoke_resets(
    args: &SilOptions,
    device: &mut Device,
    frames: &[HostFrame],
) -> Result<crate::resets::ResetReport> {
    let again = &frames[..frames.len().min(AFTER_FAULTS_FRAMES)];
    // Frames the reset loses: those after the last one that completed a view set.
    let cached_after = |n: usize| {
        let done = again[..n].iter().rposition(|f| f.expected.is_some());
        n - done.map_or(0, |i| i + 1)
    };
    let mut stream_n = |device: &mut Device, n: usize| {
        let mut seq = 0;
        let part = &again[..n.min(again.len())];
        let s = stream(device, part, &mut seq)?;
        let expected = part.iter().filter(|f| f.expected.is_some()).count();
        Ok((s.depth_maps, expected, s.pairs_ok && s.mismatched == 0))
    };
    crate::resets::reset_faults(
        device,
        args.reset_faults,
        args.seed,
        again.len(),
        &cached_after,
        &mut stream_n,
    )
}

/// The device's final status counters, then a shutdown: whether it was acknowledged and
/// QEMU exited cleanly.
fn close(device: &mut Device, seq: &mut u32) -> Result<(link::Status, bool, bool)> {
    *seq += 1;
    device.send_msg(&Message::StatusRequest { seq: *seq })?;
    let status = loop {
        match device.reply()? {
            Reply::Status(s) => break s,
            Reply::Error { .. } => continue,
            other => bail!("status request: unexpected reply {other:?}"),
        }
    };
    *seq += 1;
    device.send_msg(&Message::Shutdown { seq: *seq })?;
    let shutdown_ok = matches!(device.reply()?, Reply::Status(_));
    let exited = device.wait_exit();
    Ok((status, shutdown_ok, exited))
}

/// `--fuzz N`: N malformed messages, interleaved with status requests.
fn fuzz_if_asked(
    args: &SilOptions,
    device: &mut Device,
    seq: &mut u32,
    frames: &[HostFrame],
) -> Result<Option<FuzzReport>> {
    if args.fuzz == 0 {
        return Ok(None);
    }
    Ok(Some(fuzz(
        device,
        args.fuzz,
        args.seed,
        seq,
        &frames[0].image,
    )?))
}

/// `--update S`: the refusals, the seeded resets and the update (`crate::update`).
fn update_if_asked(
    args: &SilOptions,
    device: &mut Device,
    recording: &Path,
    open: &OpenOptions,
    frames: &[HostFrame],
) -> Result<Option<crate::update::UpdateReport>> {
    let Some(image) = &args.update else {
        return Ok(None);
    };
    let input = crate::update::UpdateInput {
        image,
        recording,
        open,
        frames: args.frames,
        old: frames,
        faults: args.update_faults,
        seed: args.seed,
    };
    Ok(Some(crate::update::check_update(device, &input)?))
}

/// The mean of the per-map counts (0 for none).
fn mean_instructions(instructions: &[u32]) -> u64 {
    if instructions.is_empty() {
        return 0;
    }
    instructions.iter().map(|&x| u64::from(x)).sum::<u64>() / instructions.len() as u64
}

/// Runs the SIL and returns the report.
pub fn sil(args: &SilOptions) -> Result<SilReport> {
    let recording = args
        .recording
        .clone()
        .unwrap_or_else(|| epssn_sim::dataset::demo_dir().join("recording.aris"));
    let blob = firmware_blob()?;
    let open = OpenOptions {
        topic: args.topic.clone(),
    };
    let frames = prepare_frames(&recording, &open, args.frames, &blob)?;
    if frames.is_empty() {
        bail!("{}: no frames", recording.display());
    }
    let timeout = Duration::from_secs(args.timeout);
    let (elf, sizes, mut device) = open_device(args, timeout)?;
    let (flash, static_ram) = sizes;

    let mut seq = 0u32;
    let Streamed {
        depth_maps,
        mismatched,
        pairs_ok,
        instructions,
        pairs,
        rejected,
        rejections_agree,
        maps,
    } = stream(&mut device, &frames, &mut seq)?;
    let fuzz_report = fuzz_if_asked(args, &mut device, &mut seq, &frames)?;
    let faults_start = Instant::now();
    let AfterFaults {
        faults,
        after,
        soak: soak_report,
    } = faults_and_soak(args, &mut device, &frames, &mut seq)?;
    let faults_seconds = faults_start.elapsed().as_secs_f64();
    let resets = if args.reset_faults > 0 {
        Some(provoke_resets(args, &mut device, &frames)?)
    } else {
        None
    };
    let update = update_if_asked(args, &mut device, &recording, &open, &frames)?;
    let (status, shutdown_ok, exited) = close(&mut device, &mut seq)?;
    let expected_depth_maps = frames.iter().filter(|f| f.expected.is_some()).count();
    let mean = mean_instructions(&instructions);
    // The deepest stack seen: at the end, or at an update's commit (whose switch resets the
    // board and paints the stack anew).
    let stack = update
        .as_ref()
        .map_or(0, |u| u.stack_high_water_at_commit)
        .max(status.stack_high_water);
    let ram = static_ram + u64::from(stack);
    let (budgets, budget_violations) = check_budgets(args, &instructions, ram, flash)?;
    let fuzz_alive = fuzz_report
        .as_ref()
        .is_none_or(|f| f.status_replies == f.status_requests && f.unanswered == 0);
    let report = SilReport {
        recording: recording.display().to_string(),
        firmware: elf.display().to_string(),
        device: args
            .serial
            .as_ref()
            .map_or_else(|| "qemu".to_string(), |p| p.display().to_string()),
        target: args.target,
        cost_unit: if args.serial.is_some() {
            "cycles"
        } else {
            "instructions"
        }
        .to_string(),
        frames: frames.len(),
        depth_maps,
        expected_depth_maps,
        bit_exact: pairs_ok
            && mismatched == 0
            && depth_maps == expected_depth_maps
            && depth_maps > 0,
        mismatched_values: mismatched,
        instructions_per_depth_map: mean,
        instructions,
        pairs,
        rejected_pairs: rejected,
        rejections_agree,
        flash_bytes: flash,
        ram_bytes: ram,
        static_ram_bytes: static_ram,
        stack_high_water_bytes: stack,
        device_frames: status.frames,
        device_depth_maps: status.depth_maps,
        device_errors: status.errors,
        fuzz: fuzz_report,
        after_faults_bit_exact: after.is_none_or(|a| a.0),
        after_faults_depth_maps: after.map_or(0, |a| a.1),
        faults_seconds,
        faults,
        soak: soak_report,
        resets,
        update,
        alive: shutdown_ok && exited && fuzz_alive,
        budgets,
        budget_violations,
    };
    if let Some(path) = &args.mcap {
        write_mcap(path, &frames, &maps, &report)?;
    }
    Ok(report)
}

/// The budgets of the run's target (or `--budgets`) and what the run broke of them. The
/// budgets are the QEMU build's (instructions, its flash and RAM): not a board's cycles, so a
/// run over `--serial` breaks none.
fn check_budgets(
    args: &SilOptions,
    instructions: &[u32],
    ram: u64,
    flash: u64,
) -> Result<(crate::budgets::Budgets, Vec<String>)> {
    let budgets = crate::budgets::Budgets::load(
        &args
            .budgets
            .clone()
            .unwrap_or_else(|| args.target.budgets_path()),
    )?;
    let violations = if args.serial.is_some() {
        Vec::new()
    } else {
        budgets.violations(instructions, ram, flash)
    };
    Ok((budgets, violations))
}

/// `--mcap`: every frame streamed and every depth map the device sent back.
fn write_mcap(
    path: &Path,
    frames: &[HostFrame],
    maps: &[DeviceMap],
    report: &SilReport,
) -> Result<()> {
    let streamed: Vec<StreamedFrame> = frames
        .iter()
        .map(|f| StreamedFrame {
            time_us: f.time_us,
            attitude: f.attitude,
            image: &f.image,
        })
        .collect();
    crate::mcap_out::write(path, &streamed, maps, report)
        .with_context(|| format!("sil --mcap {}", path.display()))
}

/// `host-sim sil`: prints the report; fails unless bit-exact, with the host's pair
/// rejections, and alive.
pub fn run(args: &SilOptions, out: &mut impl Write) -> Result<()> {
    let r = sil(args)?;
    if args.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&r)?)?;
    } else {
        write_text(&r, out)?;
    }
    verdict(&r, args)
}

/// The report as text, for a person.
fn write_text(r: &SilReport, out: &mut impl Write) -> Result<()> {
    writeln!(out, "recording: {}", r.recording)?;
    writeln!(
        out,
        "firmware: {} (on {}, {:?})",
        r.firmware, r.device, r.target
    )?;
    writeln!(
        out,
        "frames sent: {}, depth maps: {} (host expected {}), bit-exact: {} ({} values differ)",
        r.frames, r.depth_maps, r.expected_depth_maps, r.bit_exact, r.mismatched_values
    )?;
    writeln!(out, "pairs (reference, sources): {:?}", r.pairs)?;
    writeln!(
        out,
        "pairs the pose gate rejected (reference, source, reason): {:?}; same as the host: {}",
        r.rejected_pairs, r.rejections_agree
    )?;
    writeln!(
        out,
        "{} per depth map (features of the new frame + depth map): {} (each: {:?})",
        r.cost_unit, r.instructions_per_depth_map, r.instructions
    )?;
    writeln!(
        out,
        "flash: {} bytes; RAM: {} bytes = {} static + {} stack high-water",
        r.flash_bytes, r.ram_bytes, r.static_ram_bytes, r.stack_high_water_bytes
    )?;
    writeln!(
        out,
        "device counters: {} frames, {} depth maps, {} errors",
        r.device_frames, r.device_depth_maps, r.device_errors
    )?;
    if let Some(f) = &r.fuzz {
        writeln!(
            out,
            "fuzz: sent {:?}; error replies {:?}; status {}/{} answered; {} malformed \
             messages without an error reply",
            f.sent, f.error_replies, f.status_replies, f.status_requests, f.unanswered
        )?;
    }
    if let Some(f) = &r.faults {
        write_faults(r, f, out)?;
    }
    if let Some(x) = &r.resets {
        write_resets(x, out)?;
    }
    if let Some(u) = &r.update {
        write_update(u, out)?;
    }
    writeln!(out, "alive: {}", r.alive)?;
    writeln!(
        out,
        "budgets: {} instructions per depth map, RAM {} bytes, flash {} bytes: {}",
        r.budgets.instructions_per_depth_map,
        r.budgets.ram_bytes,
        r.budgets.flash_bytes,
        if r.budget_violations.is_empty() {
            "within".to_string()
        } else {
            r.budget_violations.join("; ")
        }
    )?;
    Ok(())
}

/// The fault campaign's table, and the soak's line after it.
fn write_faults(r: &SilReport, f: &FaultReport, out: &mut impl Write) -> Result<()> {
    writeln!(
        out,
        "fault campaign (seed {}, {} rounds, {:.1} s): {} faults, {} failed; stack \
         high-water {} -> {} bytes",
        f.seed,
        f.rounds,
        r.faults_seconds,
        f.faults,
        f.failed,
        f.stack_high_water_before,
        f.stack_high_water_after
    )?;
    writeln!(
        out,
        "  {:<22} {:>5} {:>9} {:>9}  expected code",
        "class", "sent", "answered", "recovered"
    )?;
    for (class, c) in &f.classes {
        writeln!(
            out,
            "  {class:<22} {:>5} {:>9} {:>9}  {}",
            c.sent,
            c.answered_expected,
            c.recovered,
            c.expected_code.join("/")
        )?;
        for failure in &c.failures {
            writeln!(out, "    failed: {failure}")?;
        }
    }
    writeln!(
        out,
        "after the faults: {} depth maps, bit-exact: {}",
        r.after_faults_depth_maps, r.after_faults_bit_exact
    )?;
    if let Some(s) = &r.soak {
        writeln!(
            out,
            "soak: {} messages in {} blocks ({:.1} s), {} valid frames, {} of {} depth \
             maps, {} values differ; stack high-water {} -> {} bytes (unchanged: {})",
            s.messages,
            s.blocks,
            s.seconds,
            s.valid_frames,
            s.depth_maps,
            s.expected_depth_maps,
            s.mismatched_values,
            s.stack_high_water_before,
            s.stack_high_water_after,
            s.stack_unchanged
        )?;
    }
    Ok(())
}

/// The device resets' lines.
fn write_resets(x: &crate::resets::ResetReport, out: &mut impl Write) -> Result<()> {
    writeln!(
        out,
        "resets (seed {}, {} rounds, {:.1} s): {} depth maps checked, all as they must be: {}",
        x.seed, x.rounds, x.seconds, x.depth_maps, x.all_ok
    )?;
    for e in &x.resets {
        writeln!(
            out,
            "  {:<15} after {} frames ({} lost, re-sent): reset {} (expected {}), {:.1} s; \
             record {:?} fits: {}; acknowledged: {}; {} of {} depth maps after, bit-exact: {}",
            e.fault,
            e.frames_before,
            e.frames_lost,
            e.cause,
            e.expected_cause,
            e.reboot_seconds,
            e.record,
            e.record_ok,
            e.acknowledged,
            e.depth_maps_after,
            e.expected_depth_maps_after,
            e.bit_exact_after
        )?;
    }
    Ok(())
}

/// The model update's lines.
fn write_update(u: &crate::update::UpdateReport, out: &mut impl Write) -> Result<()> {
    writeln!(
        out,
        "update {} (version {}, {} bytes; {:.1} s): served version {} before; committed to \
         slot {:?} as version {}; serving {} after the switch: {} of {} depth maps bit-exact \
         with the new blob: {} ({} differ from the old model's); all as it must be: {}",
        u.image,
        u.version,
        u.image_bytes,
        u.seconds,
        u.version_before,
        u.committed_slot,
        u.committed_version,
        u.serving_after,
        u.depth_maps_after,
        u.expected_depth_maps_after,
        u.bit_exact_after,
        u.maps_differing_from_old,
        u.ok
    )?;
    for c in &u.cases {
        writeln!(
            out,
            "  refused {:<16} code {:?} (expected {}) {:?}; serving version {}: {}",
            c.name, c.code, c.expected_code, c.msg, c.serving_version, c.ok
        )?;
    }
    for x in &u.resets {
        writeln!(
            out,
            "  reset during {:<6} (after {} chunks, {} ms): held {} B, serving version {}, \
             {} of {} depth maps bit-exact: {}",
            x.phase,
            x.after_chunks,
            x.delay_ms,
            x.held_after,
            x.serving_version,
            x.depth_maps,
            x.expected_depth_maps,
            x.ok
        )?;
    }
    for l in &u.console {
        writeln!(out, "  device: {l}")?;
    }
    Ok(())
}

/// Fails with the first thing the report says went wrong: the printed report comes first, so
/// the figures are on screen when the run fails.
fn verdict(r: &SilReport, args: &SilOptions) -> Result<()> {
    if !r.bit_exact {
        bail!("SIL: depth maps are not bit-exact with the host library");
    }
    if !r.rejections_agree {
        bail!("SIL: the device's pose gate rejected other pairs than the host library's");
    }
    if let Some(f) = &r.faults {
        if f.failed > 0 {
            bail!(
                "SIL: {} of {} faults not answered with the expected code or not recovered from",
                f.failed,
                f.faults
            );
        }
    }
    if !r.after_faults_bit_exact {
        bail!("SIL: depth maps after the fault campaign are not bit-exact with the host library");
    }
    if let Some(s) = &r.soak {
        if !s.stack_unchanged {
            bail!(
                "SIL: the soak moved the stack high-water mark from {} to {} bytes",
                s.stack_high_water_before,
                s.stack_high_water_after
            );
        }
    }
    if r.resets.as_ref().is_some_and(|x| !x.all_ok) {
        bail!("SIL: a provoked reset was not reported, recovered from or bit-exact after");
    }
    if r.update.as_ref().is_some_and(|u| !u.ok) {
        bail!("SIL: the model update was not refused, reset, committed or served as it must be");
    }
    if !r.alive {
        bail!("SIL: the firmware stopped answering or did not shut down cleanly");
    }
    if !r.budget_violations.is_empty() {
        let file = args
            .budgets
            .clone()
            .unwrap_or_else(|| args.target.budgets_path());
        bail!(
            "SIL: over budget ({}): {}",
            file.display(),
            r.budget_violations.join("; ")
        );
    }
    Ok(())
}
