//! Model updates over the link, host side (docs/UPDATE.md): the upload and commit client that
//! `host-sim push` and `host-sim sil --update` share (`upload`, `commit`), and the SIL's
//! update check (`check_update`): blobs the device must refuse, each with its code, while
//! the old model serves on; resets at seeded points of the upload and the commit, after each
//! of which the model that serves (the old one until the commit) must give every depth map
//! bit for bit; then the commit, the switch, and every streamed map bit-exact with the host
//! library running the new blob.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use epssn::config;
use epssn::crc32::crc32;
use epssn::link::{ErrorCode, Message, Serving, MAX_CHUNK_LEN};
use epssn_ros2::OpenOptions;
use epssn_sim::synthetic::Rng;
use epssn_update::image::{self, Header, HEADER_LEN};
use serde::Serialize;

use crate::device::{Device, Reply};
use crate::resets::hello;
use crate::stream::{prepare_frames, stream, HostFrame};

/// A refusal by the device: its error code and text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refused {
    /// The link error code.
    pub code: u16,
    /// Its text.
    pub msg: String,
}

/// What an upload sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pushed {
    /// The offset it resumed from (what the device held of this image).
    pub resumed_from: u32,
    /// Chunks sent.
    pub chunks: usize,
}

/// The next reply that is not a straggler of the session (a depth map or status of frames).
fn reply_of(device: &mut Device) -> Result<Reply> {
    loop {
        match device.reply()? {
            Reply::Depth { .. } => continue,
            r => return Ok(r),
        }
    }
}

/// What the device holds of an upload: `upload?`.
fn held(device: &mut Device, seq: &mut u32) -> Result<Option<epssn::link::Held>> {
    *seq += 1;
    device.send_msg(&Message::UploadRequest { seq: *seq })?;
    match reply_of(device)? {
        Reply::Upload(_, held) => Ok(held),
        other => bail!("upload?: unexpected reply {other:?}"),
    }
}

/// One chunk of `image` at `off`, with its CRC (or `crc` when given: a corrupt chunk).
fn send_chunk(
    device: &mut Device,
    seq: &mut u32,
    image: &[u8],
    off: usize,
    crc: Option<u32>,
) -> Result<()> {
    let end = (off + MAX_CHUNK_LEN).min(image.len());
    let data = &image[off..end];
    *seq += 1;
    device.send_msg(&Message::Chunk {
        seq: *seq,
        offset: off as u32,
        crc: crc.unwrap_or_else(|| crc32(data)),
        data,
    })
}

/// Uploads the signed image `image` in chunks of [`MAX_CHUNK_LEN`], from what the device
/// already holds of it (`upload?`: the same header's id), stopping after `limit` chunks if
/// given. A slot holding another upload cut short (`UploadConflict`) restarts it from 0 once.
pub(crate) fn upload(
    device: &mut Device,
    seq: &mut u32,
    image: &[u8],
    limit: Option<usize>,
) -> Result<Result<Pushed, Refused>> {
    let header = image
        .get(..HEADER_LEN)
        .context("image shorter than its header")?;
    let id = crc32(header);
    let mut off = match held(device, seq)? {
        Some(h) if h.id == id && h.total as usize == image.len() => h.held as usize,
        _ => 0,
    };
    let resumed_from = off as u32;
    let (mut chunks, mut restarted) = (0, false);
    while off < image.len() && limit.is_none_or(|l| chunks < l) {
        send_chunk(device, seq, image, off, None)?;
        chunks += 1;
        match reply_of(device)? {
            Reply::Upload(_, Some(h)) if h.id == id => off = h.held as usize,
            Reply::Error { code, .. } if code == ErrorCode::UploadConflict.code() && !restarted => {
                (off, restarted) = (0, true);
            }
            Reply::Error { code, msg } => return Ok(Err(Refused { code, msg })),
            other => bail!("chunk at {off}: unexpected reply {other:?}"),
        }
    }
    Ok(Ok(Pushed {
        resumed_from,
        chunks,
    }))
}

/// `commit`: the model that serves after it (the device then resets to serve it) and the
/// stack high-water mark the reply reports (the commit's self-test included), or why not.
pub(crate) fn commit(
    device: &mut Device,
    seq: &mut u32,
) -> Result<Result<(Serving, u32), Refused>> {
    *seq += 1;
    device.send_msg(&Message::Commit { seq: *seq })?;
    match reply_of(device)? {
        Reply::Status(s) => s
            .model
            .map(|m| Ok((m, s.stack_high_water)))
            .context("commit: a status without the model"),
        Reply::Error { code, msg } => Ok(Err(Refused { code, msg })),
        other => bail!("commit: unexpected reply {other:?}"),
    }
}

/// A new session (hellos until one is answered, through any reboot): the model that serves.
fn serving(device: &mut Device) -> Result<Serving> {
    let (status, _, _) = hello(device, None)?;
    status
        .model
        .context("the device's hello names no model (no update partition?)")
}

/// One refusal the SIL provokes.
#[derive(Serialize, Debug, Clone)]
pub struct UpdateCase {
    /// `other_key`, `other_spec`, `corrupted_chunk`, `older_version`.
    pub name: String,
    /// The code it must be refused with.
    pub expected_code: u16,
    /// The code it was refused with (none: accepted).
    pub code: Option<u16>,
    /// The device's text.
    pub msg: String,
    /// The version that served after it: the one before it.
    pub serving_version: u32,
    /// Wall milliseconds from its commit to the refusal (0: refused before a commit).
    pub commit_ms: u64,
    /// Refused with the expected code and the old model serving on.
    pub ok: bool,
}

/// One reset at a seeded point of the upload or the commit.
#[derive(Serialize, Debug, Clone)]
pub struct UpdateReset {
    /// `upload` (after `after_chunks` chunks and during the next) or `commit` (after
    /// `delay_ms` of the commit's checks).
    pub phase: String,
    /// Chunks answered before the reset (upload).
    pub after_chunks: usize,
    /// Wall milliseconds between the commit and the reset (commit).
    pub delay_ms: u64,
    /// What the device held of the upload after the reboot, bytes.
    pub held_after: u32,
    /// The version its hello said serves after the reboot.
    pub serving_version: u32,
    /// Depth maps streamed after the reboot, and how many the host library expected.
    pub depth_maps: usize,
    /// Expected.
    pub expected_depth_maps: usize,
    /// All bit-exact with the host library running the model the hello named.
    pub bit_exact: bool,
    /// The old model served (or, after the commit's reset only, the new one), bit-exact.
    pub ok: bool,
}

/// What `sil --update` gave.
#[derive(Serialize, Debug, Clone)]
pub struct UpdateReport {
    /// The signed image.
    pub image: String,
    /// Its version.
    pub version: u32,
    /// Its bytes.
    pub image_bytes: usize,
    /// The version that served before the update.
    pub version_before: u32,
    /// Refusals, by name.
    pub cases: Vec<UpdateCase>,
    /// Seeded resets (`--update-faults N`).
    pub resets: Vec<UpdateReset>,
    /// The upload that completed: the offset it resumed from and the chunks it sent.
    pub resumed_from: u32,
    /// Chunks of that last upload.
    pub chunks: usize,
    /// The slot and version the commit's reply named.
    pub committed_slot: Option<u8>,
    /// Version.
    pub committed_version: u32,
    /// The version the hello after the switch named.
    pub serving_after: u32,
    /// Depth maps streamed after the switch, and how many the host library expected.
    pub depth_maps_after: usize,
    /// Expected.
    pub expected_depth_maps_after: usize,
    /// Every one bit-exact with the host library running the new blob.
    pub bit_exact_after: bool,
    /// Of them, maps that differ from the old model's: the new model serves, not the old.
    pub maps_differing_from_old: usize,
    /// The stack high-water mark the commit's reply reported, bytes (the commit's signature
    /// check and self-test included; the switch's reset paints the stack anew).
    pub stack_high_water_at_commit: u32,
    /// The firmware's console lines about the commit (its cost figures).
    pub console: Vec<String>,
    /// Wall time, seconds.
    pub seconds: f64,
    /// Everything as it must be.
    pub ok: bool,
}

/// What `sil --update` is given.
pub(crate) struct UpdateInput<'a> {
    /// The signed image.
    pub image: &'a Path,
    /// The recording and frame limit the SIL streams.
    pub recording: &'a Path,
    /// How the recording is opened (its topic, for a bag).
    pub open: &'a OpenOptions,
    /// Frames.
    pub frames: Option<usize>,
    /// The frames prepared with the model that serves before the update.
    pub old: &'a [HostFrame],
    /// Seeded resets.
    pub faults: usize,
    /// Their seed (and the throwaway key's).
    pub seed: u64,
}

/// Streams the first `n` frames in a new session: (depth maps, expected, bit-exact).
fn stream_session(
    device: &mut Device,
    frames: &[HostFrame],
    n: usize,
) -> Result<(usize, usize, bool)> {
    let part = &frames[..n.min(frames.len())];
    // A new session: its frame seqs from 1, its cache empty, as the host's expectations.
    hello(device, None)?;
    let mut seq = 0;
    let s = stream(device, part, &mut seq)?;
    let expected = part.iter().filter(|f| f.expected.is_some()).count();
    Ok((
        s.depth_maps,
        expected,
        s.pairs_ok && s.mismatched == 0 && s.depth_maps == expected,
    ))
}

/// A blob of another spec than this build's, from weights/.
fn other_spec_blob() -> Result<Vec<u8>> {
    let weights = epssn_spec::load::repo_root().join("weights");
    for name in ["paper/epssn-p.q8.bin", "general/epssn-s.q8.bin"] {
        let bytes = std::fs::read(weights.join(name))?;
        let hash = bytes
            .get(12..16)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        if hash.is_some_and(|h| h != config::SPEC_HASH) {
            return Ok(bytes);
        }
    }
    bail!("weights/ has no blob of another spec")
}

/// `blob` as `version` with `golden`, signed by the throwaway key of `seed`.
fn signed_by_other(seed: u64, version: u32, golden: u32, blob: &[u8]) -> Vec<u8> {
    let mut rng = Rng::new(seed ^ 0x07e4_5eed_0f0e_4e75);
    let secret: [u8; 32] = core::array::from_fn(|_| rng.next_u64() as u8);
    let mut img = image::sign(&secret, version, golden, blob)
        .to_bytes()
        .to_vec();
    img.extend_from_slice(blob);
    img
}

/// One refusal: a new session, the upload (or the corrupt first chunk), the commit; then
/// which model serves.
fn refusal(
    device: &mut Device,
    name: &str,
    img: &[u8],
    corrupt: bool,
    expected: ErrorCode,
) -> Result<UpdateCase> {
    let before = serving(device)?.version;
    let mut seq = 0;
    let mut commit_ms = 0;
    let refused = if corrupt {
        // The first chunk with one byte flipped after its CRC was taken.
        let mut bad = img.to_vec();
        let crc = crc32(&bad[..MAX_CHUNK_LEN.min(bad.len())]);
        bad[HEADER_LEN + 7] ^= 0x10;
        send_chunk(device, &mut seq, &bad, 0, Some(crc))?;
        match reply_of(device)? {
            Reply::Error { code, msg } => Some(Refused { code, msg }),
            _ => None,
        }
    } else {
        match upload(device, &mut seq, img, None)? {
            Err(r) => Some(r),
            Ok(_) => {
                let t = Instant::now();
                let r = commit(device, &mut seq)?.err();
                commit_ms = t.elapsed().as_millis() as u64;
                r
            }
        }
    };
    let after = serving(device)?.version;
    let code = refused.as_ref().map(|r| r.code);
    Ok(UpdateCase {
        name: name.into(),
        expected_code: expected.code(),
        code,
        msg: refused.map(|r| r.msg).unwrap_or_default(),
        serving_version: after,
        commit_ms,
        ok: code == Some(expected.code()) && after == before,
    })
}

/// Frames streamed after each reset (enough for a few depth maps).
const CHECK_FRAMES: usize = 4;

/// Where a seeded reset falls: during the upload, after this many chunks answered (as the
/// next one is written), or during the commit, this many milliseconds after it was sent.
#[derive(Clone, Copy, Debug)]
enum Point {
    Upload(usize),
    Commit(u64),
}

/// One reset at a seeded point. Then the model the reboot's hello names must give every
/// depth map bit for bit: the old one, or after a commit's reset, the new one if the switch
/// was done before it.
fn reset_at(
    device: &mut Device,
    point: Point,
    img: &[u8],
    (old, new): (&[HostFrame], &[HostFrame]),
    old_version: u32,
    new_version: u32,
) -> Result<UpdateReset> {
    let mut seq = 0;
    serving(device)?;
    let during_commit = matches!(point, Point::Commit(_));
    let (mut after_chunks, mut delay_ms) = (0, 0);
    if let Point::Commit(delay) = point {
        if let Err(r) = upload(device, &mut seq, img, None)? {
            bail!("upload before the commit's reset refused: {r:?}");
        }
        delay_ms = delay;
        seq += 1;
        device.send_msg(&Message::Commit { seq })?;
        std::thread::sleep(Duration::from_millis(delay_ms));
    } else if let Point::Upload(k) = point {
        after_chunks = k;
        if let Err(r) = upload(device, &mut seq, img, Some(after_chunks))? {
            bail!("upload before a reset refused: {r:?}");
        }
        let off = match held(device, &mut seq)? {
            Some(h) if (h.held as usize) < img.len() => h.held as usize,
            _ => 0,
        };
        send_chunk(device, &mut seq, img, off, None)?;
    }
    device.reset()?;
    let version = serving(device)?.version;
    let mut s = 0;
    let held_after = held(device, &mut s)?.map_or(0, |h| h.held);
    let frames = if version == new_version { new } else { old };
    let (maps, expected, exact) = stream_session(device, frames, CHECK_FRAMES)?;
    let version_ok = version == old_version || (during_commit && version == new_version);
    Ok(UpdateReset {
        phase: if during_commit { "commit" } else { "upload" }.into(),
        after_chunks,
        delay_ms,
        held_after,
        serving_version: version,
        depth_maps: maps,
        expected_depth_maps: expected,
        bit_exact: exact,
        ok: version_ok && exact && expected > 0,
    })
}

/// The seeded resets of `--update-faults N`: the first half during the upload (at seeded
/// chunk counts: each resumes from what the device holds), the rest during the commit, after
/// a seeded delay of up to a few times `check_ms` (the wall time of a refused commit's checks,
/// a fraction of a whole commit's): mostly before the switch. Once a reset finds the new
/// model serving, the switch is done and no commit is left to cut: the rest are not made.
#[allow(clippy::too_many_arguments)]
fn seeded_resets(
    device: &mut Device,
    input: &UpdateInput<'_>,
    img: &[u8],
    new: &[HostFrame],
    old_version: u32,
    new_version: u32,
    check_ms: u64,
) -> Result<Vec<UpdateReset>> {
    let mut rng = Rng::new(input.seed);
    let chunks = img.len().div_ceil(MAX_CHUNK_LEN);
    let mut resets: Vec<UpdateReset> = Vec::new();
    for i in 0..input.faults {
        if resets
            .last()
            .is_some_and(|r| r.serving_version == new_version)
        {
            break;
        }
        let point = if i < input.faults.div_ceil(2) {
            Point::Upload(rng.below(chunks))
        } else {
            Point::Commit(rng.below(3 * check_ms.max(1) as usize) as u64)
        };
        let frames = (input.old, new);
        resets.push(reset_at(
            device,
            point,
            img,
            frames,
            old_version,
            new_version,
        )?);
    }
    Ok(resets)
}

/// `sil --update`: refusals, seeded resets, the update, every map after it bit-exact.
pub(crate) fn check_update(device: &mut Device, input: &UpdateInput<'_>) -> Result<UpdateReport> {
    let start = Instant::now();
    let img =
        std::fs::read(input.image).with_context(|| format!("reading {}", input.image.display()))?;
    let header = Header::parse(&img, img.len())
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", input.image.display()))?;
    let blob = &img[HEADER_LEN..];
    let new = prepare_frames(input.recording, input.open, input.frames, blob)
        .context("the host library on the update's blob")?;
    let before = serving(device)?.version;
    // The refused commit of another key's signature runs the commit's checks whole: its
    // wall time scales the seeded delays of the resets during the commit.
    let other_key = refusal(
        device,
        "other_key",
        &signed_by_other(input.seed, header.version, header.golden, blob),
        false,
        ErrorCode::UpdateSignature,
    )?;
    let commit_ms = other_key.commit_ms;
    let mut cases = vec![
        other_key,
        refusal(
            device,
            "other_spec",
            &signed_by_other(input.seed, header.version, 0, &other_spec_blob()?),
            false,
            ErrorCode::UpdateSpec,
        )?,
        refusal(device, "corrupted_chunk", &img, true, ErrorCode::UploadCrc)?,
    ];
    let resets = seeded_resets(device, input, &img, &new, before, header.version, commit_ms)?;
    let mut seq = 0;
    let mut committed = serving(device)?;
    let mut pushed = Pushed {
        resumed_from: img.len() as u32,
        chunks: 0,
    };
    let mut stack_at_commit = 0;
    if committed.version != header.version {
        pushed = match upload(device, &mut seq, &img, None)? {
            Ok(p) => p,
            Err(r) => bail!("the update's upload was refused: {r:?}"),
        };
        committed = match commit(device, &mut seq)? {
            Ok((s, stack)) => {
                stack_at_commit = stack;
                s
            }
            Err(r) => bail!(
                "the update was refused at the commit: code {} ({})",
                r.code,
                r.msg
            ),
        };
    }
    // The switch resets the device; its next hello names the model that serves.
    let serving_after = serving(device)?.version;
    let (maps, expected, exact) = stream_session(device, &new, new.len())?;
    let differing = new
        .iter()
        .zip(input.old)
        .filter(|(n, o)| n.expected.is_some() && n.expected != o.expected)
        .count();
    cases.push(refusal(
        device,
        "older_version",
        &img,
        false,
        ErrorCode::UpdateVersion,
    )?);
    let ok = cases.iter().all(|c| c.ok)
        && resets.iter().all(|r| r.ok)
        && committed.version == header.version
        && serving_after == header.version
        && exact
        && expected > 0;
    Ok(UpdateReport {
        image: input.image.display().to_string(),
        version: header.version,
        image_bytes: img.len(),
        version_before: before,
        cases,
        resets,
        resumed_from: pushed.resumed_from,
        chunks: pushed.chunks,
        committed_slot: committed.slot,
        committed_version: committed.version,
        serving_after,
        depth_maps_after: maps,
        expected_depth_maps_after: expected,
        bit_exact_after: exact,
        maps_differing_from_old: differing,
        stack_high_water_at_commit: stack_at_commit,
        console: device.console_lines("update"),
        seconds: start.elapsed().as_secs_f64(),
        ok,
    })
}

/// Options of `host-sim push`.
#[derive(Debug, Clone)]
pub struct PushOptions {
    /// The signed update image (`host-sim sign`).
    pub image: std::path::PathBuf,
    /// A board on this serial port.
    pub serial: Option<std::path::PathBuf>,
    /// Or the Cortex-M7 firmware in QEMU (built unless `firmware` names an ELF).
    pub qemu: bool,
    /// The firmware ELF for `qemu`.
    pub firmware: Option<std::path::PathBuf>,
    /// The serial port's baud rate.
    pub baud: u32,
    /// Seconds to wait for any one reply.
    pub timeout: u64,
}

/// `host-sim push`: uploads the image from what the device holds of it, commits it, and
/// reads back, after the device restarts, which model serves.
pub fn push(o: &PushOptions, out: &mut impl std::io::Write) -> Result<()> {
    let img = std::fs::read(&o.image).with_context(|| format!("reading {}", o.image.display()))?;
    let header = Header::parse(&img, img.len())
        .map_err(|e| anyhow::anyhow!("{}: not an update image: {e:?}", o.image.display()))?;
    anyhow::ensure!(
        img.len() == header.image_len(),
        "{}: {} bytes, its header says {}",
        o.image.display(),
        img.len(),
        header.image_len()
    );
    let timeout = Duration::from_secs(o.timeout);
    let mut device = match (&o.serial, o.qemu) {
        (Some(port), false) => Device::serial(port, o.baud, timeout)?,
        (None, true) => {
            let elf = match &o.firmware {
                Some(p) => p.clone(),
                None => crate::firmware::build_firmware()?,
            };
            Device::boot(&elf, timeout, crate::target::Target::M7)?
        }
        _ => bail!("push needs one of --serial PORT and --qemu"),
    };
    let before = serving(&mut device)?;
    writeln!(
        out,
        "device serves version {} (slot {:?})",
        before.version, before.slot
    )?;
    let mut seq = 0;
    let pushed = upload(&mut device, &mut seq, &img, None)?
        .map_err(|r| anyhow::anyhow!("upload refused: code {} ({})", r.code, r.msg))?;
    writeln!(
        out,
        "uploaded {} bytes from offset {} in {} chunks",
        img.len() as u32 - pushed.resumed_from,
        pushed.resumed_from,
        pushed.chunks
    )?;
    let (committed, _) = commit(&mut device, &mut seq)?
        .map_err(|r| anyhow::anyhow!("commit refused: code {} ({})", r.code, r.msg))?;
    writeln!(
        out,
        "committed version {} to slot {:?}; the device restarts to serve it",
        committed.version, committed.slot
    )?;
    let after = serving(&mut device)?;
    writeln!(
        out,
        "device serves version {} (slot {:?})",
        after.version, after.slot
    )?;
    anyhow::ensure!(
        after.version == header.version,
        "the device serves version {}, not {}",
        after.version,
        header.version
    );
    Ok(())
}
