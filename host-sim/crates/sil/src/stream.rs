//! The host's half of streaming: a recording's frames prepared with the host library (the
//! resampled image, the pairing the firmware will do and the depth map it must send back), and
//! streaming them over the link, checking every reply bit for bit. `sil`, its fault campaign
//! and `sil --update` all stream through here.

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use epssn::config;
use epssn::link::Message;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;

use epssn_ros2::{OpenOptions, Recording};

use crate::device::{Device, Reply};
use crate::mcap_out::DeviceMap;

/// One frame prepared on the host: the link message's content and the expected reply.
pub(crate) struct HostFrame {
    /// ARIS FrameTime, µs.
    pub(crate) time_us: u64,
    pub(crate) roll_deg: f32,
    /// The header's attitude (docs/POSE.md), sent with the frame.
    pub(crate) attitude: Option<epssn::attitude::Attitude>,
    /// The host gate's rejection, when the frame forms a candidate pair it refuses.
    pub(crate) rejected: Option<epssn::pairing::PairCheck>,
    pub(crate) image: Vec<u8>,
    /// `(reference, sources, depth bits)` when the frame completes a view set.
    pub(crate) expected: Option<(u32, Vec<u32>, Vec<u32>)>,
}

/// Refuses recordings whose geometry the model cannot use, with the same check as `host-sim
/// run` ([`Recording::geometry_mismatch`]), and, among the first `n` frames the SIL streams,
/// any frame whose own window or fan does not fit: the SIL streams every frame in order, as a
/// vehicle's host would, and such a frame would reach the device as zeros, so it is refused,
/// not skipped.
fn check_geometry(reader: &Recording, n: usize) -> Result<()> {
    let misfits = reader.misfit_frames();
    if let Some(why) = reader.geometry_mismatch(&misfits) {
        bail!(
            "recording geometry does not fit the model ({}): {why}",
            config::SPEC_NAME
        );
    }
    if let Some((i, why)) = misfits.into_iter().find(|&(i, _)| i < n) {
        bail!(
            "frame {i} does not fit the model ({}): {why}",
            config::SPEC_NAME
        );
    }
    Ok(())
}

/// Reads the recording, resamples every frame and runs the host library with the same
/// pairing as the firmware.
pub(crate) fn prepare_frames(
    path: &Path,
    open: &OpenOptions,
    limit: Option<usize>,
    blob: &[u8],
) -> Result<Vec<HostFrame>> {
    // An ARIS file or a ROS 2 bag's ProjectedSonarImage topic, as `run` reads it.
    let reader = Recording::open(path, open)
        .with_context(|| format!("opening recording {}", path.display()))?;
    let n = limit.unwrap_or(usize::MAX).min(reader.frame_count());
    check_geometry(&reader, n).with_context(|| format!("{}", path.display()))?;
    let model = Model::from_blob(blob).map_err(|e| anyhow!("weight blob refused: {e:?}"))?;
    let mut ws = Box::new(Workspace::new());
    let mut cache = Box::new(FeatureCache::new());
    let mut out: Vec<HostFrame> = Vec::new();
    for i in 0..n {
        let frame = reader.frame(i)?;
        let Some(roll) = reader.roll_deg(i).map(|r| r as f32) else {
            bail!(
                "frame {i} has no roll to pair by (an ARIS file: neither SonarRoll nor \
                 RollAbsPosition; a bag: no transform of its frame in /tf)"
            );
        };
        let image = frame.to_polar()?;
        let seq = i as u32 + 1;
        let attitude = reader.attitude(i);
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
            time_us: frame.time_us,
            roll_deg: roll,
            attitude,
            rejected,
            image,
            expected,
        });
    }
    Ok(out)
}

/// What streaming frames gave.
pub(crate) struct Streamed {
    pub(crate) depth_maps: usize,
    pub(crate) mismatched: usize,
    pub(crate) pairs_ok: bool,
    pub(crate) instructions: Vec<u32>,
    pub(crate) pairs: Vec<(u32, Vec<u32>)>,
    /// `(reference, source, reason)` of each pair the device's gate rejected.
    pub(crate) rejected: Vec<(u32, u32, String)>,
    /// Every device rejection equals the host's (pair and reason), and there are no others.
    pub(crate) rejections_agree: bool,
    /// The depth maps as the device sent them.
    pub(crate) maps: Vec<DeviceMap>,
}

/// Streams `frames` with seqs from `seq + 1` (frame i has seq i + 1 when `seq` starts at 0,
/// as the host's expectations assume) and checks each reply against the host library.
pub(crate) fn stream(device: &mut Device, frames: &[HostFrame], seq: &mut u32) -> Result<Streamed> {
    let mut depth_maps = 0;
    let mut mismatched = 0;
    let mut pairs_ok = true;
    let mut instructions = Vec::new();
    let mut pairs = Vec::new();
    let mut rejected = Vec::new();
    let mut rejections_agree = true;
    let mut maps = Vec::new();
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
                let same_pair = reference == *eref && sources == *esrc;
                pairs_ok &= same_pair;
                let differ = bits.iter().zip(ebits).filter(|(a, b)| a != b).count()
                    + bits.len().abs_diff(ebits.len());
                mismatched += differ;
                maps.push(DeviceMap {
                    reference,
                    sources: sources.clone(),
                    instructions: instr,
                    bit_exact: same_pair && differ == 0,
                    bits,
                });
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
        maps,
    })
}
