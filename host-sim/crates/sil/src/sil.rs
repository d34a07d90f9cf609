//! `host-sim sil`: software in the loop. Boots the firmware in QEMU (MPS2-AN500, Cortex-M7,
//! `-icount shift=0`) with UART0 on a Unix socket, streams a recording's frames over the link
//! protocol (`epssn::link`), and checks every depth map bit for bit against the library run
//! on the host on the same frames with the same weight blob. Reports instructions per depth
//! map (the firmware's timer ticks × 40 under `-icount shift=0`), flash and RAM from the ELF
//! sections plus the measured stack high-water mark. `--fuzz N` then sends N malformed
//! messages interleaved with status requests and checks that the firmware always answers.
//! `--faults N` (default 2) runs the fault campaign of `faults.rs`; `--soak N` instead sends at
//! least N valid and faulty messages in blocks and checks the stack high-water mark is unchanged.
//! `--serial PORT` runs the same checks against a real board (boards/stm32h743) on a serial
//! port instead of QEMU; its figures are then core cycles, and the QEMU budgets are not applied.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use epssn::config;
use epssn::link::{self, kind, Decoder, ErrorCode, Header, Message, Payload};
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;
use serde::Serialize;

use epssn_aris::aris::ArisReader;
use epssn_aris::polar::frame_to_polar;
use epssn_sim::synthetic::Rng;

/// Arguments of `host-sim sil`.
#[derive(Args, Debug, Clone)]
pub struct SilArgs {
    /// The recording to stream (default: the bundled simulated demo, `data/demo/`).
    #[arg(long)]
    pub recording: Option<PathBuf>,
    /// Print machine-readable JSON.
    #[arg(long)]
    pub json: bool,
    /// The firmware ELF (default: build firmware/ in release and use it).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// Stream at most this many frames.
    #[arg(long)]
    pub frames: Option<usize>,
    /// After the frames, send this many malformed messages (with status requests between).
    #[arg(long, default_value_t = 0)]
    pub fuzz: usize,
    /// Fault campaign (docs/LINK.md, issue 14): rounds per fault class, each fault checked
    /// against the library decoder's verdict, then a hello and valid frames checked bit for bit.
    #[arg(long, default_value_t = 2)]
    pub faults: usize,
    /// Soak (docs/LINK.md): instead of the fault campaign, at least this many messages (N ≥
    /// 5,000 for the issue's soak), valid and faulty: blocks of one round of every fault class
    /// followed by a hello and valid frames whose depth maps must be bit-exact; the stack
    /// high-water must end where it began.
    #[arg(long, default_value_t = 0)]
    pub soak: usize,
    /// Seed of the fuzz run and the fault campaign.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seconds to wait for any one reply.
    #[arg(long, default_value_t = 120)]
    pub timeout: u64,
    /// The budgets file (default: `weights/budgets.json`).
    #[arg(long)]
    pub budgets: Option<PathBuf>,
    /// Talk to a real board on this serial port (e.g. `/dev/ttyACM0`, the ST-LINK's virtual
    /// COM port) instead of booting the firmware in QEMU. Sizes come from `--firmware`
    /// (default: the STM32H743 board's release ELF, if built); budgets are not applied.
    #[arg(long)]
    pub serial: Option<PathBuf>,
    /// The serial port's baud rate (the board's `LINK_BAUD`).
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
}

/// Counts of a fuzz run.
#[derive(Serialize, Debug, Clone, Default, PartialEq)]
pub struct FuzzReport {
    /// Malformed messages sent, per kind.
    pub sent: std::collections::BTreeMap<String, usize>,
    /// Error replies received, per error code name.
    pub error_replies: std::collections::BTreeMap<String, usize>,
    /// Status requests sent between the malformed messages.
    pub status_requests: usize,
    /// Status replies received to them.
    pub status_replies: usize,
    /// Malformed messages that got no error reply before the next status reply.
    pub unanswered: usize,
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
    /// Stack high-water mark reported by the firmware, bytes.
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
    pub faults: Option<crate::faults::FaultReport>,
    /// The soak, with `--soak N`.
    pub soak: Option<SoakReport>,
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

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../..")
}

/// The weight blob the firmware embeds.
fn firmware_blob() -> Result<Vec<u8>> {
    let path = epssn_reference::weights::firmware_blob_path()?;
    std::fs::read(&path).with_context(|| format!("reading weight blob {}", path.display()))
}

/// Builds the firmware (release; cargo decides whether anything changed) for the spec this
/// host build was generated from, and returns the ELF path. The target directory is
/// `epssn_spec::load::per_spec_dir` of `firmware/target` (EPSSN-S in `firmware/target`, any
/// other configuration in `firmware/target/<spec stem>`), so the two never rebuild each
/// other's artefacts.
pub fn build_firmware() -> Result<PathBuf> {
    let dir = repo_root().join("firmware");
    let spec_file = epssn::config::SPEC_FILE_NAME;
    let target = epssn_spec::load::per_spec_dir(&dir.join("target"), spec_file);
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(["build", "--release", "--quiet", "--target-dir"])
        .arg(&target)
        .current_dir(&dir)
        // The firmware is built from the same spec as this host tool (specs live in weights/).
        .env("EPSSN_SPEC", Path::new("weights").join(spec_file))
        // The host build's variables must not leak into the cross build.
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .stdout(Stdio::null())
        .status()
        .context("running cargo build for the firmware")?;
    if !status.success() {
        bail!("firmware build failed ({status})");
    }
    Ok(target.join("thumbv7em-none-eabihf/release/epssn-firmware"))
}

/// Flash and static RAM of the ELF, from its section sizes.
pub fn elf_sizes(elf: &Path) -> Result<(u64, u64)> {
    use object::{Object, ObjectSection};
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes).map_err(|e| anyhow!("parsing ELF: {e}"))?;
    let size = |name: &str| {
        file.section_by_name(name)
            .map(|s| s.size())
            .unwrap_or_default()
    };
    let flash = size(".vector_table") + size(".text") + size(".rodata") + size(".data");
    // .axisram: the STM32H743 board's buffers in AXI SRAM (absent in the QEMU build).
    let ram = size(".data") + size(".bss") + size(".uninit") + size(".axisram");
    if flash == 0 || ram == 0 {
        bail!(
            "{}: no .text/.bss sections (not the firmware?)",
            elf.display()
        );
    }
    Ok((flash, ram))
}

/// One frame prepared on the host: the link message's content and the expected reply.
struct HostFrame {
    roll_deg: f32,
    /// The header's attitude (docs/POSE.md), sent with the frame.
    attitude: Option<epssn::attitude::Attitude>,
    /// The host gate's rejection, when the frame forms a candidate pair it refuses.
    rejected: Option<epssn::pairing::PairCheck>,
    image: Vec<u8>,
    /// `(reference, sources, depth bits)` when the frame completes a view set.
    expected: Option<(u32, Vec<u32>, Vec<u32>)>,
}

/// Refuses recordings whose geometry the model cannot use, with the same check as `host-sim
/// run` ([`epssn_aris::polar::geometry_mismatch`]).
fn check_geometry(reader: &ArisReader) -> Result<()> {
    if let Some(why) = epssn_aris::polar::geometry_mismatch(reader)? {
        bail!(
            "recording geometry does not fit the model ({}): {why}",
            config::SPEC_NAME
        );
    }
    Ok(())
}

/// Reads the recording, resamples every frame and runs the host library with the same
/// pairing as the firmware.
fn prepare_frames(path: &Path, limit: Option<usize>, blob: &[u8]) -> Result<Vec<HostFrame>> {
    let reader =
        ArisReader::open(path).with_context(|| format!("opening recording {}", path.display()))?;
    check_geometry(&reader).with_context(|| format!("{}", path.display()))?;
    let model = Model::from_blob(blob).map_err(|e| anyhow!("weight blob refused: {e:?}"))?;
    let mut ws = Box::new(Workspace::new());
    let mut cache = Box::new(FeatureCache::new());
    let n = limit.unwrap_or(usize::MAX).min(reader.frame_count());
    let mut out: Vec<HostFrame> = Vec::new();
    for i in 0..n {
        let frame = reader.frame(i)?;
        let h = &frame.header;
        let roll = if h.sonar_roll_deg.is_finite() {
            h.sonar_roll_deg
        } else if h.roll_abs_position_deg.is_finite() {
            h.roll_abs_position_deg
        } else {
            bail!("frame {i} has neither SonarRoll nor RollAbsPosition: no roll to pair by");
        };
        let image = frame_to_polar(&frame)?;
        let seq = i as u32 + 1;
        let attitude = h.attitude().and_then(epssn::attitude::Attitude::from_array);
        let newest = cache
            .insert_with_attitude(seq, roll, attitude, |f| model.features(&image, &mut ws, f))
            .map_err(|e| anyhow!("host features of frame {i}: {e:?}"))?;
        let found = cache.find_checked(&newest, model.views());
        let rejected = found.as_ref().and_then(|r| r.as_ref().err()).copied();
        let expected = match found.and_then(|r| r.ok()) {
            Some(set) => {
                let reference = set.reference().context("empty view set")?;
                // Frame seq s is frame s − 1 of the recording: this one or one already pushed.
                let image_of = |s: u32| -> &[u8] {
                    if s == seq {
                        &image
                    } else {
                        &out[s as usize - 1].image
                    }
                };
                let views: Vec<&[u8]> = core::iter::once(reference.seq)
                    .chain(set.sources().iter().map(|f| f.seq))
                    .map(image_of)
                    .collect();
                let mut features = vec![0i8; views.len() * config::FEATURE_LEN];
                let mut depth = vec![U16F16::ZERO; config::DEPTH_LEN];
                model
                    .depth(&views, &mut features, &mut ws, &mut depth)
                    .map_err(|e| anyhow!("host depth of frame {i}: {e:?}"))?;
                Some((
                    reference.seq,
                    set.sources().iter().map(|f| f.seq).collect(),
                    depth.iter().map(|d| d.to_bits()).collect(),
                ))
            }
            None => None,
        };
        out.push(HostFrame {
            roll_deg: roll,
            attitude,
            rejected,
            image,
            expected,
        });
    }
    Ok(out)
}

/// Frames streamed again after the fault campaign (enough for a few depth maps).
const AFTER_FAULTS_FRAMES: usize = 6;

/// An owned device reply.
#[derive(Debug, Clone)]
// The texts are read through `Debug` in error messages.
#[allow(dead_code)]
pub(crate) enum Reply {
    Depth {
        reference: u32,
        sources: Vec<u32>,
        instructions: u32,
        bits: Vec<u32>,
    },
    Status(link::Status),
    /// The device's hello reply, with its counters.
    Hello(link::Status),
    Error {
        code: u16,
        msg: String,
    },
    /// A reply the host could not decode (the firmware must never send one).
    Garbled(String),
    Other(String),
}

fn owned(event: Result<Message<'_>, link::DecodeError>) -> Reply {
    match event {
        Ok(Message::Depth {
            reference,
            sources,
            instructions,
            depth,
            ..
        }) => Reply::Depth {
            reference,
            sources: sources.to_vec(),
            instructions,
            bits: (0..depth.len())
                .filter_map(|i| depth.get(i).map(|d| d.to_bits()))
                .collect(),
        },
        Ok(Message::Status { status, .. }) => Reply::Status(status),
        Ok(Message::Hello {
            status: Some(status),
            ..
        }) => Reply::Hello(status),
        Ok(Message::Error { code, msg, .. }) => Reply::Error {
            code,
            msg: msg.to_string(),
        },
        Ok(m) => Reply::Other(m.kind().to_string()),
        Err(e) => Reply::Garbled(e.to_string()),
    }
}

/// The default ELF of the STM32H743 board (`boards/stm32h743`, release).
fn board_elf() -> PathBuf {
    repo_root().join("boards/stm32h743/target/thumbv7em-none-eabihf/release/epssn-stm32h743")
}

/// QEMU running the firmware (or a board on a serial port), its link and the reply reader.
pub(crate) struct Device {
    qemu: Option<Child>,
    link: Box<dyn Write + Send>,
    replies: Receiver<Reply>,
    console: Arc<Mutex<Vec<String>>>,
    dir: PathBuf,
    timeout: Duration,
}

/// `qemu-system-arm` on the emulated Cortex-M7 board, no display or monitor; callers add the
/// serial, semihosting and timing options.
pub(crate) fn qemu_m7() -> Command {
    let mut c = Command::new("qemu-system-arm");
    c.args([
        "-machine",
        "mps2-an500",
        "-cpu",
        "cortex-m7",
        "-nographic",
        "-monitor",
        "none",
    ]);
    c
}

impl Device {
    fn boot(elf: &Path, timeout: Duration) -> Result<Self> {
        let dir = std::env::temp_dir().join(format!("epssn-sil-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        let sock = dir.join("link.sock");
        let _ = std::fs::remove_file(&sock);
        let mut qemu = qemu_m7()
            .args([
                "-semihosting-config",
                "enable=on,target=native,arg=serve",
                "-icount",
                "shift=0",
                "-chardev",
            ])
            .arg(format!(
                "socket,id=link,path={},server=on,wait=on",
                sock.display()
            ))
            .args(["-serial", "chardev:link", "-kernel"])
            .arg(elf)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .context("starting qemu-system-arm (is QEMU installed?)")?;
        let console = Arc::new(Mutex::new(Vec::new()));
        for pipe in [
            qemu.stdout
                .take()
                .map(|p| Box::new(p) as Box<dyn Read + Send>),
            qemu.stderr
                .take()
                .map(|p| Box::new(p) as Box<dyn Read + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let console = console.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines().map_while(|l| l.ok()) {
                    if let Ok(mut c) = console.lock() {
                        c.push(line);
                    }
                }
            });
        }
        let start = Instant::now();
        let link = loop {
            match UnixStream::connect(&sock) {
                Ok(s) => break s,
                Err(e) => {
                    if let Ok(Some(status)) = qemu.try_wait() {
                        bail!("QEMU exited before the link came up ({status})");
                    }
                    if start.elapsed() > Duration::from_secs(20) {
                        let _ = qemu.kill();
                        bail!("QEMU link socket {}: {e}", sock.display());
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
            }
        };
        let reader = link.try_clone()?;
        let mut device = Self::over(Box::new(link), Box::new(reader), timeout);
        device.qemu = Some(qemu);
        device.console = console;
        device.dir = dir;
        Ok(device)
    }

    /// A board on a serial port: no process, the port is the link.
    fn serial(port: &Path, baud: u32, timeout: Duration) -> Result<Self> {
        let file = crate::serial::open(port, baud)?;
        let reader = file.try_clone()?;
        Ok(Self::over(Box::new(file), Box::new(reader), timeout))
    }

    /// The reply reader on `reader`, messages out on `link`.
    fn over(
        link: Box<dyn Write + Send>,
        mut reader: Box<dyn Read + Send>,
        timeout: Duration,
    ) -> Self {
        let (tx, replies) = channel();
        std::thread::spawn(move || {
            let mut decoder = Box::new(Decoder::new());
            let mut buf = [0u8; 4096];
            while let Ok(n) = reader.read(&mut buf) {
                if n == 0 {
                    break;
                }
                for &b in &buf[..n] {
                    decoder.push(b);
                    while let Some(ev) = decoder.poll() {
                        if tx.send(owned(ev)).is_err() {
                            return;
                        }
                    }
                }
            }
        });
        Self {
            qemu: None,
            link,
            replies,
            console: Arc::new(Mutex::new(Vec::new())),
            dir: PathBuf::new(),
            timeout,
        }
    }

    pub(crate) fn send(&mut self, bytes: &[u8]) -> Result<()> {
        self.link.write_all(bytes).context("writing to the link")
    }

    fn send_msg(&mut self, msg: &Message<'_>) -> Result<()> {
        let mut v = Vec::new();
        link::encode(msg, &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .map_err(|e| anyhow!("encoding: {e:?}"))?;
        self.send(&v)
    }

    pub(crate) fn reply(&mut self) -> Result<Reply> {
        match self.replies.recv_timeout(self.timeout) {
            Ok(r) => Ok(r),
            Err(RecvTimeoutError::Timeout) => bail!(
                "no reply from the firmware within {:?}; console:\n{}",
                self.timeout,
                self.console_text()
            ),
            Err(RecvTimeoutError::Disconnected) => {
                bail!("the link closed; console:\n{}", self.console_text())
            }
        }
    }

    fn console_text(&self) -> String {
        self.console
            .lock()
            .map(|c| c.join("\n"))
            .unwrap_or_default()
    }

    /// Waits for QEMU to exit; true when it exited successfully (a board resets instead: true).
    fn wait_exit(&mut self) -> bool {
        let Some(qemu) = self.qemu.as_mut() else {
            return true;
        };
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(30) {
            if let Ok(Some(status)) = qemu.try_wait() {
                return status.success();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        if let Some(qemu) = self.qemu.as_mut() {
            if let Ok(None) = qemu.try_wait() {
                let _ = qemu.kill();
                let _ = qemu.wait();
            }
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

pub(crate) fn raw_bytes(h: &Header<'_>, payload: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    let _ = link::encode_raw(h, Payload::Bytes(payload), &mut |b: &[u8]| {
        v.extend_from_slice(b);
        Ok::<(), ()>(())
    });
    v
}

pub(crate) fn msg_bytes(msg: &Message<'_>) -> Vec<u8> {
    let mut v = Vec::new();
    let _ = link::encode(msg, &mut |b: &[u8]| {
        v.extend_from_slice(b);
        Ok::<(), ()>(())
    });
    v
}

/// One malformed message of a random kind; `seq` is the next valid sequence number and
/// `last` the last one the device accepted.
fn malformed(rng: &mut Rng, seq: &mut u32, last: u32, image: &[u8]) -> (&'static str, Vec<u8>) {
    let frame_header = |seq: u32| Header {
        t: kind::FRAME,
        seq,
        roll: Some(7.0),
        r: Some(config::INPUT_RANGE_BINS as u32),
        b: Some(config::INPUT_COLUMNS as u32),
        len: Some(image.len() as u32),
        ..Header::default()
    };
    let pick = (rng.next_u64() % 8) as usize;
    *seq += 1;
    let s = *seq;
    match pick {
        0 => {
            let n = 1 + (rng.next_u64() % 200) as usize;
            (
                "random_bytes",
                (0..n).map(|_| rng.next_u64() as u8).collect(),
            )
        }
        1 => {
            let full = if rng.next_u64() & 1 == 0 {
                raw_bytes(&frame_header(s), image)
            } else {
                msg_bytes(&Message::StatusRequest { seq: s })
            };
            let n = 1 + (rng.next_u64() as usize) % (full.len() - 1);
            ("truncated", full[..n].to_vec())
        }
        2 => {
            let mut v = if rng.next_u64() & 3 == 0 {
                raw_bytes(&frame_header(s), image)
            } else {
                msg_bytes(&Message::StatusRequest { seq: s })
            };
            let at =
                link::PREAMBLE_LEN + (rng.next_u64() as usize) % (v.len() - link::PREAMBLE_LEN);
            v[at] ^= 1 << (rng.next_u64() % 8);
            ("bad_crc", v)
        }
        3 => {
            let json = br#"{"t":"frame","seq":}"#;
            let mut v = link::SYNC.to_vec();
            v.extend((json.len() as u16).to_le_bytes());
            v.extend_from_slice(json);
            let crc = epssn::crc32::crc32(json);
            v.extend(crc.to_le_bytes());
            ("bad_json", v)
        }
        4 => {
            let mut h = frame_header(s);
            h.len = Some(link::MAX_PAYLOAD_LEN as u32 + 1 + (rng.next_u64() % 1000) as u32);
            ("oversized", raw_bytes(&h, &[]))
        }
        5 => {
            *seq -= 1;
            (
                "out_of_order",
                msg_bytes(&Message::StatusRequest { seq: last }),
            )
        }
        6 => {
            let mut h = frame_header(s);
            h.r = Some(2 * config::INPUT_RANGE_BINS as u32);
            ("wrong_geometry", raw_bytes(&h, &[]))
        }
        _ => {
            let mut h = raw_header_unknown(s);
            h.len = None;
            ("unknown_type", raw_bytes(&h, &[]))
        }
    }
}

fn raw_header_unknown(seq: u32) -> Header<'static> {
    Header {
        t: "reboot",
        seq,
        ..Header::default()
    }
}

fn code_name(code: u16) -> String {
    ErrorCode::from_code(code).map_or_else(|| format!("code {code}"), |c| format!("{c:?}"))
}

fn fuzz(
    device: &mut Device,
    n: usize,
    seed: u64,
    seq: &mut u32,
    image: &[u8],
) -> Result<FuzzReport> {
    let mut rng = Rng(seed);
    let mut report = FuzzReport::default();
    for _ in 0..n {
        let last = *seq;
        let (what, bytes) = malformed(&mut rng, seq, last, image);
        *report.sent.entry(what.to_string()).or_default() += 1;
        device.send(&bytes)?;
        *seq += 1;
        device.send_msg(&Message::StatusRequest { seq: *seq })?;
        report.status_requests += 1;
        let mut errors = 0;
        loop {
            match device.reply()? {
                Reply::Status(_) => {
                    report.status_replies += 1;
                    break;
                }
                Reply::Error { code, .. } => {
                    errors += 1;
                    *report.error_replies.entry(code_name(code)).or_default() += 1;
                }
                other => bail!("fuzz: unexpected reply {other:?}"),
            }
        }
        if errors == 0 {
            report.unanswered += 1;
        }
    }
    Ok(report)
}

/// What streaming frames gave.
struct Streamed {
    depth_maps: usize,
    mismatched: usize,
    pairs_ok: bool,
    instructions: Vec<u32>,
    pairs: Vec<(u32, Vec<u32>)>,
    /// `(reference, source, reason)` of each pair the device's gate rejected.
    rejected: Vec<(u32, u32, String)>,
    /// Every device rejection equals the host's (pair and reason), and there are no others.
    rejections_agree: bool,
}

/// Streams `frames` with seqs from `seq + 1` (frame i has seq i + 1 when `seq` starts at 0,
/// as the host's expectations assume) and checks each reply against the host library.
fn stream(device: &mut Device, frames: &[HostFrame], seq: &mut u32) -> Result<Streamed> {
    let mut depth_maps = 0;
    let mut mismatched = 0;
    let mut pairs_ok = true;
    let mut instructions = Vec::new();
    let mut pairs = Vec::new();
    let mut rejected = Vec::new();
    let mut rejections_agree = true;
    for (i, f) in frames.iter().enumerate() {
        *seq += 1;
        device.send_msg(&Message::Frame {
            seq: *seq,
            roll_deg: f.roll_deg,
            attitude: f.attitude,
            image: &f.image,
        })?;
        match (device.reply()?, &f.expected) {
            (
                Reply::Depth {
                    reference,
                    sources,
                    instructions: instr,
                    bits,
                },
                Some((eref, esrc, ebits)),
            ) => {
                depth_maps += 1;
                instructions.push(instr);
                pairs_ok &= reference == *eref && sources == *esrc;
                mismatched += bits.iter().zip(ebits).filter(|(a, b)| a != b).count()
                    + bits.len().abs_diff(ebits.len());
                pairs.push((reference, sources));
            }
            (Reply::Status(st), None) => {
                // The device's verdict on the candidate this frame formed, against the host's.
                let device = st.pair.filter(|p| !p.verdict.accepted());
                let key = |p: &epssn::pairing::PairCheck| (p.reference, p.source, p.verdict);
                rejections_agree &= device.as_ref().map(key) == f.rejected.as_ref().map(key);
                if let Some(p) = device {
                    rejected.push((p.reference, p.source, p.verdict.reason().to_string()));
                }
            }
            (r, e) => bail!(
                "frame {i}: reply {:?} but the host expected {}",
                match r {
                    Reply::Depth {
                        reference, sources, ..
                    } => format!("depth ({reference}, {sources:?})"),
                    other => format!("{other:?}"),
                },
                match e {
                    Some((r, s, _)) => format!("a depth map of ({r}, {s:?})"),
                    None => "a status (no pair yet)".into(),
                }
            ),
        }
    }
    Ok(Streamed {
        depth_maps,
        mismatched,
        pairs_ok,
        instructions,
        pairs,
        rejected,
        rejections_agree,
    })
}

/// The soak of `--soak n`: blocks of one fault round of every class (a new seed each) and the
/// first frames again after its closing hello, until `n` messages are sent. Returns the
/// campaign table summed over the blocks and the soak's own figures.
fn soak(
    device: &mut Device,
    n: usize,
    seed: u64,
    frames: &[HostFrame],
) -> Result<(crate::faults::FaultReport, SoakReport)> {
    let start = Instant::now();
    let again = &frames[..frames.len().min(AFTER_FAULTS_FRAMES)];
    let mut total: Option<crate::faults::FaultReport> = None;
    let mut s = SoakReport::default();
    let mut pairs_ok = true;
    while s.messages < n {
        let block_seed = seed.wrapping_add(s.blocks as u64);
        let (report, _) = crate::faults::campaign(device, 1, block_seed, &frames[0].image)?;
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

/// Runs the SIL and returns the report.
pub fn sil(args: &SilArgs) -> Result<SilReport> {
    let recording = args
        .recording
        .clone()
        .unwrap_or_else(|| Path::new(epssn_sim::dataset::DEMO_DIR).join("recording.aris"));
    let blob = firmware_blob()?;
    let frames = prepare_frames(&recording, args.frames, &blob)?;
    if frames.is_empty() {
        bail!("{}: no frames", recording.display());
    }
    let timeout = Duration::from_secs(args.timeout);
    let (elf, sizes, mut device) = match &args.serial {
        None => {
            let elf = match &args.firmware {
                Some(p) => p.clone(),
                None => build_firmware()?,
            };
            let sizes = elf_sizes(&elf)?;
            let device = Device::boot(&elf, timeout)?;
            (elf, sizes, device)
        }
        Some(port) => {
            // The board runs whatever was flashed: sizes from the ELF named (or the board's
            // release build), when there is one.
            let elf = args.firmware.clone().unwrap_or_else(board_elf);
            let sizes = elf_sizes(&elf).unwrap_or((0, 0));
            (elf, sizes, Device::serial(port, args.baud, timeout)?)
        }
    };
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
    } = stream(&mut device, &frames, &mut seq)?;
    let fuzz_report = if args.fuzz > 0 {
        Some(fuzz(
            &mut device,
            args.fuzz,
            args.seed,
            &mut seq,
            &frames[0].image,
        )?)
    } else {
        None
    };
    let faults_start = Instant::now();
    let mut soak_report = None;
    let (faults, after) = if args.soak > 0 {
        let (report, s) = soak(&mut device, args.soak, args.seed, &frames)?;
        let ok = s.mismatched_values == 0
            && s.depth_maps == s.expected_depth_maps
            && s.expected_depth_maps > 0;
        let maps = s.depth_maps;
        soak_report = Some(s);
        (Some(report), Some((ok, maps)))
    } else if args.faults > 0 {
        let (report, _) =
            crate::faults::campaign(&mut device, args.faults, args.seed, &frames[0].image)?;
        // The campaign ended with a hello (seq 0, cache cleared): the frames again, with the
        // same seqs as the first time, so the same pairs and depth maps are expected.
        let again = &frames[..frames.len().min(AFTER_FAULTS_FRAMES)];
        seq = 0;
        let s = stream(&mut device, again, &mut seq)?;
        let expected = again.iter().filter(|f| f.expected.is_some()).count();
        let ok = s.pairs_ok && s.mismatched == 0 && s.depth_maps == expected && expected > 0;
        (Some(report), Some((ok, s.depth_maps)))
    } else {
        (None, None)
    };
    let faults_seconds = faults_start.elapsed().as_secs_f64();
    seq += 1;
    device.send_msg(&Message::StatusRequest { seq })?;
    let status = loop {
        match device.reply()? {
            Reply::Status(s) => break s,
            Reply::Error { .. } => continue,
            other => bail!("status request: unexpected reply {other:?}"),
        }
    };
    seq += 1;
    device.send_msg(&Message::Shutdown { seq })?;
    let shutdown_ok = matches!(device.reply()?, Reply::Status(_));
    let exited = device.wait_exit();
    let expected_depth_maps = frames.iter().filter(|f| f.expected.is_some()).count();
    let mean = if instructions.is_empty() {
        0
    } else {
        instructions.iter().map(|&x| u64::from(x)).sum::<u64>() / instructions.len() as u64
    };
    let budgets = crate::budgets::Budgets::load(
        &args
            .budgets
            .clone()
            .unwrap_or_else(crate::budgets::default_path),
    )?;
    let ram = static_ram + u64::from(status.stack_high_water);
    // The budgets are the QEMU build's (instructions, its flash and RAM): not a board's cycles.
    let budget_violations = if args.serial.is_some() {
        Vec::new()
    } else {
        budgets.violations(&instructions, ram, flash)
    };
    let fuzz_alive = fuzz_report
        .as_ref()
        .is_none_or(|f| f.status_replies == f.status_requests && f.unanswered == 0);
    Ok(SilReport {
        recording: recording.display().to_string(),
        firmware: elf.display().to_string(),
        device: args
            .serial
            .as_ref()
            .map_or_else(|| "qemu".to_string(), |p| p.display().to_string()),
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
        stack_high_water_bytes: status.stack_high_water,
        device_frames: status.frames,
        device_depth_maps: status.depth_maps,
        device_errors: status.errors,
        fuzz: fuzz_report,
        after_faults_bit_exact: after.is_none_or(|a| a.0),
        after_faults_depth_maps: after.map_or(0, |a| a.1),
        faults_seconds,
        faults,
        soak: soak_report,
        alive: shutdown_ok && exited && fuzz_alive,
        budgets,
        budget_violations,
    })
}

/// `host-sim sil`: prints the report; fails unless bit-exact, with the host's pair
/// rejections, and alive.
pub fn run(args: &SilArgs, out: &mut impl Write) -> Result<()> {
    let r = sil(args)?;
    if args.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&r)?)?;
    } else {
        writeln!(out, "recording: {}", r.recording)?;
        writeln!(out, "firmware: {} (on {})", r.firmware, r.device)?;
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
    }
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
    if !r.alive {
        bail!("SIL: the firmware stopped answering or did not shut down cleanly");
    }
    if !r.budget_violations.is_empty() {
        let file = args
            .budgets
            .clone()
            .unwrap_or_else(crate::budgets::default_path);
        bail!(
            "SIL: over budget ({}): {}",
            file.display(),
            r.budget_violations.join("; ")
        );
    }
    Ok(())
}
