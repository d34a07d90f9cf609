//! How a recording's frames become depth maps' views, shared by `run` and `label`: each
//! frame's roll and attitude, the bursts of pings averaged into one view, the groups paired by
//! rotator roll and passed by the pose gate (or given with `--pair`), and every candidate's
//! verdict.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use epssn::attitude::Attitude;
use epssn::config;
use epssn::model::Model;
use epssn::pairing::{check_pair, CachedFrame};
use epssn::ping_average;
use serde::Serialize;

use epssn_reference::weights;
use epssn_ros2::{OpenOptions, Recording};

/// What decides the depth maps a recording gives: `run` and `label` share it, so `label`
/// labels exactly the reference views `run` forms.
#[derive(Debug, Clone, Default)]
pub struct PairingOptions {
    /// Weights folder (`epssn-s.q8.bin` + `manifest.json`); default: the firmware's weights.
    pub weights: Option<PathBuf>,
    /// Views per depth map (2 or 3); default: the count the weights were trained for (the
    /// blob's `views`, else the spec's).
    pub views: Option<usize>,
    /// Pair frames by index instead of by roll, `REF:SRC` (repeatable), for recordings
    /// without rotator roll. The roll between them is assumed to be the baseline.
    pub pairs: Vec<(usize, usize)>,
    /// Pings averaged per view (`epssn::ping_average`): each run of this many consecutive
    /// frames at one roll (within the pair tolerance) becomes one frame, named by its first;
    /// frames left over are skipped with a warning. Default: the pings per view the weights
    /// were trained on (their manifest's `speckle_looks`), else 1.
    pub pings_per_view: Option<u32>,
    /// The ProjectedSonarImage topic of a bag (default: its only one).
    pub topic: Option<String>,
    /// Each frame's pose (`--poses` of `run` and `label`): a bag's pings without a transform
    /// in /tf take their attitude, and so their roll, from it.
    pub poses: Option<PathBuf>,
}

impl PairingOptions {
    /// The weights folder: given, else the firmware's.
    pub fn weights_dir(&self) -> Result<PathBuf> {
        match &self.weights {
            Some(w) => Ok(w.clone()),
            None => weights::firmware_weights_dir(),
        }
    }
}

/// One candidate pair (frames whose rotator rolls pair) and the pose gate's verdict on it
/// (docs/POSE.md), the very check the device runs.
#[derive(Clone, Debug, Serialize)]
pub struct CandidateReport {
    /// Frame indices, reference first.
    pub frames: Vec<usize>,
    /// The pair is used (a depth map is computed).
    pub accepted: bool,
    /// Relative roll, degrees: from the attitudes, or the rotator rolls' difference.
    pub roll_deg: f64,
    /// Tilt of the forward axis, degrees; null without attitude (the roll-only rule).
    pub residual_deg: Option<f64>,
    /// `ok`, `roll_only`, `roll` or `residual`.
    pub reason: &'static str,
}

/// The pose gate on a candidate group: each source j checked at baseline j·step against the
/// reference with the library's [`epssn::pairing::check_pair`]; the figures are those of the
/// first rejected source, else of the one with the largest residual (as the device reports).
pub fn gate(
    group: &[usize],
    rolls: &[Option<f64>],
    attitudes: &[Option<Attitude>],
) -> CandidateReport {
    let frame = |i: usize| CachedFrame {
        seq: i as u32,
        roll_deg: rolls.get(i).copied().flatten().unwrap_or(f64::NAN) as f32,
        attitude: attitudes.get(i).copied().flatten(),
        slot: 0,
    };
    let reference = frame(group[0]);
    let mut worst: Option<epssn::pairing::PairCheck> = None;
    for (j, &src) in group.iter().enumerate().skip(1) {
        let c = check_pair(
            &reference,
            &frame(src),
            j,
            config::ROLL_STEP_DEG,
            config::PAIR_TOLERANCE_DEG,
            config::PAIR_RESIDUAL_TOLERANCE_DEG,
        );
        let take = match worst {
            None => true,
            Some(w) => {
                !c.verdict.accepted() || (w.verdict.accepted() && c.residual_deg > w.residual_deg)
            }
        };
        if take {
            worst = Some(c);
        }
        if !c.verdict.accepted() {
            break;
        }
    }
    let c = worst.unwrap_or(epssn::pairing::PairCheck {
        reference: 0,
        source: 0,
        roll_deg: f32::NAN,
        residual_deg: f32::NAN,
        verdict: epssn::attitude::Verdict::Roll,
    });
    CandidateReport {
        frames: group.to_vec(),
        accepted: c.verdict.accepted(),
        roll_deg: f64::from(c.roll_deg),
        residual_deg: c
            .residual_deg
            .is_finite()
            .then_some(f64::from(c.residual_deg)),
        reason: c.verdict.reason(),
    }
}

pub(crate) fn frame_attitude(reader: &Recording, i: usize) -> Option<Attitude> {
    reader.attitude(i)
}

fn frame_roll(reader: &Recording, i: usize) -> Option<f64> {
    reader.roll_deg(i)
}

/// Pairs frames by roll: each frame with a later frame `step` (and `2·step` for 3 views) more
/// rolled, within the spec's tolerance. Each frame is a reference at most once.
pub fn pair_by_roll(rolls: &[Option<f64>], views: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    for (i, ri) in rolls.iter().enumerate() {
        let Some(ri) = ri else { continue };
        let mut group = vec![i];
        for k in 1..views {
            let want = ri + config::ROLL_STEP_DEG * k as f64;
            let found =
                rolls.iter().enumerate().skip(i + 1).find(|(_, r)| {
                    r.is_some_and(|r| (r - want).abs() <= config::PAIR_TOLERANCE_DEG)
                });
            match found {
                Some((j, _)) => group.push(j),
                None => break,
            }
        }
        if group.len() == views {
            out.push(group);
        }
    }
    out
}

/// Bursts of `pings` consecutive frames at one roll (each within the pair tolerance of the
/// first's), keyed by their first frame; greedy from the start, a frame that cannot start a
/// full burst is skipped. With one ping every frame with a roll is its own burst.
pub fn ping_bursts(rolls: &[Option<f64>], pings: usize) -> BTreeMap<usize, Vec<usize>> {
    let mut out = BTreeMap::new();
    let mut i = 0;
    while i < rolls.len() {
        let Some(first) = rolls[i] else {
            i += 1;
            continue;
        };
        let full = i + pings <= rolls.len()
            && rolls[i..i + pings]
                .iter()
                .all(|r| r.is_some_and(|r| (r - first).abs() <= config::PAIR_TOLERANCE_DEG));
        if full {
            out.insert(i, (i..i + pings).collect());
            i += pings;
        } else {
            i += 1;
        }
    }
    out
}

/// The library's model of a blob, refused with the folder's name.
pub(crate) fn model_of<'a>(blob: &'a [u8], weights_dir: &Path) -> Result<Model<'a>> {
    Model::from_blob(blob)
        .map_err(|e| anyhow::anyhow!("weights {} refused: {e:?}", weights_dir.display()))
}

/// The views the weights in `weights_dir` take (the blob's), as `run` uses them by default.
pub fn blob_views(weights_dir: &Path) -> Result<usize> {
    let path = weights_dir.join(weights::BLOB_FILE);
    let blob = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    Ok(model_of(&blob, weights_dir)?.views())
}

/// A recording opened and grouped as `run` groups it, before any depth is computed.
pub struct Pairing {
    /// The recording (an ARIS file or a ROS 2 bag).
    pub reader: Recording,
    pub(crate) frames: FrameViews,
    /// The groups whose depth maps are computed, reference frame first.
    pub groups: Vec<Vec<usize>>,
    /// Every candidate with the pose gate's verdict (none with `--pair`).
    pub candidates: Vec<CandidateReport>,
    /// The recording's and the pairing's warnings.
    pub warnings: Vec<String>,
}

/// Opens `recording` and forms its groups as `run` does: views from `args` (default
/// `model_views`, the blob's), pings per view, pairing by roll and the pose gate, or the
/// `--pair` pairs. Fails when no group is formed.
pub fn pair_recording(
    args: &PairingOptions,
    model_views: usize,
    weights_dir: &Path,
    recording: &Path,
) -> Result<Pairing> {
    let views = args.views.unwrap_or(model_views);
    ensure!(
        (2..=config::MAX_VIEWS).contains(&views),
        "--views must be 2..={}",
        config::MAX_VIEWS
    );
    let options = OpenOptions {
        topic: args.topic.clone(),
    };
    let needed = if args.pairs.is_empty() { views } else { 2 };
    let (mut reader, misfits) = open_recording(recording, &options, needed)?;
    let mut warnings: Vec<String> = reader.warnings().to_vec();
    if let (Some(path), Recording::Bag(_)) = (&args.poses, &reader) {
        let rows = epssn_sim::poses::load(path, reader.frame_count())?;
        let placed = reader.fill_attitudes(|i| Some(rows.get(&i)?.site_from_sonar().rotation));
        if placed > 0 {
            warnings.push(format!(
                "{placed} ping(s) without a transform take their attitude from {}",
                path.display()
            ));
        }
    }
    let frames = FrameViews::of(
        args,
        &reader,
        misfits,
        weights_dir,
        recording,
        &mut warnings,
    )?;
    let (groups, candidates) = if args.pairs.is_empty() {
        pair_by_pose(&frames, views, &mut warnings)
    } else {
        (
            given_pairs(args, &reader, &frames, views, &mut warnings)?,
            Vec::new(),
        )
    };
    if groups.is_empty() {
        bail!(no_pairs_message(recording, &candidates));
    }
    Ok(Pairing {
        reader,
        frames,
        groups,
        candidates,
        warnings,
    })
}

/// Opens a recording that fits the model and holds at least `needed` frames; returns it with
/// its frames that do not fit among frames that do ([`Recording::misfit_frames`]).
fn open_recording(
    recording: &Path,
    options: &OpenOptions,
    needed: usize,
) -> Result<(Recording, Vec<(usize, String)>)> {
    let reader = Recording::open(recording, options)
        .with_context(|| format!("opening {}", recording.display()))?;
    let misfits = reader.misfit_frames();
    if let Some(why) = reader.geometry_mismatch(&misfits) {
        bail!(
            "{} does not fit the model ({}): {why}. Depth from mismatched geometry would be \
             wrong, so nothing was computed.",
            recording.display(),
            config::SPEC_NAME
        );
    }
    // Too few frames for one depth map: the reader's warnings (truncation, FrameCount) say why.
    if reader.frame_count() < needed {
        let warnings = reader.warnings();
        bail!(
            "{} holds {} complete frame(s), a depth map needs {needed}{}",
            recording.display(),
            reader.frame_count(),
            if warnings.is_empty() {
                String::new()
            } else {
                format!(": {}", warnings.join("; "))
            }
        );
    }
    Ok((reader, misfits))
}

/// Each frame's roll and attitude, and the bursts of pings averaged into one view.
pub(crate) struct FrameViews {
    pub(crate) rolls: Vec<Option<f64>>,
    pub(crate) attitudes: Vec<Option<Attitude>>,
    bursts: BTreeMap<usize, Vec<usize>>,
    /// Frames whose own range window or fan does not fit the model, with why: never paired.
    misfits: BTreeMap<usize, String>,
    pub(crate) pings_per_view: u32,
}

impl FrameViews {
    fn of(
        args: &PairingOptions,
        reader: &Recording,
        misfits: Vec<(usize, String)>,
        weights_dir: &Path,
        recording: &Path,
        warnings: &mut Vec<String>,
    ) -> Result<Self> {
        let mut rolls: Vec<Option<f64>> = (0..reader.frame_count())
            .map(|i| frame_roll(reader, i))
            .collect();
        let mut attitudes: Vec<Option<Attitude>> = (0..reader.frame_count())
            .map(|i| frame_attitude(reader, i))
            .collect();
        let misfits: BTreeMap<usize, String> = misfits.into_iter().collect();
        if let Some((first, why)) = misfits.iter().next() {
            warnings.push(format!(
                "{} frame(s) whose own range window or fan does not fit the model were skipped \
                 (frame {first}: {why})",
                misfits.len()
            ));
            for &i in misfits.keys() {
                rolls[i] = None;
                attitudes[i] = None;
            }
        }
        let trained_pings = weights::trained_pings_per_view(weights_dir);
        let pings_per_view = args.pings_per_view.or(trained_pings).unwrap_or(1);
        ensure!(
            (1..=u32::from(ping_average::MAX_PINGS)).contains(&pings_per_view),
            "--pings-per-view must be 1..={}",
            ping_average::MAX_PINGS
        );
        if let Some(m) = trained_pings {
            if m != pings_per_view {
                warnings.push(format!(
                    "the weights were trained on {m} ping(s) per view and this run averages \
                     {pings_per_view}: expect them to read worse than their accuracy"
                ));
            }
        }
        // Each burst of pings is one view, named by its first frame: the other frames lose
        // their roll and attitude so pairing sees only the bursts.
        let bursts = ping_bursts(&rolls, pings_per_view as usize);
        if pings_per_view > 1 {
            ensure!(
                args.pairs.is_empty(),
                "--pair pairs single frames; with --pings-per-view {pings_per_view} pairing is by roll"
            );
            let in_bursts: usize = bursts.values().map(Vec::len).sum();
            let skipped = reader.frame_count() - in_bursts;
            if skipped > 0 {
                warnings.push(format!(
                    "{skipped} frame(s) not in a run of {pings_per_view} pings at one roll were skipped"
                ));
            }
            ensure!(
                !bursts.is_empty(),
                "{} holds no run of {pings_per_view} consecutive frames at one roll (±{} °): \
                 nothing to average (give --pings-per-view 1 for single pings)",
                recording.display(),
                config::PAIR_TOLERANCE_DEG
            );
            for i in 0..rolls.len() {
                if !bursts.contains_key(&i) {
                    rolls[i] = None;
                    attitudes[i] = None;
                }
            }
        }
        Ok(FrameViews {
            rolls,
            attitudes,
            bursts,
            misfits,
            pings_per_view,
        })
    }

    /// The frames a view averages: its burst, or the frame alone (`--pair`, no roll).
    pub(crate) fn pings_of(&self, f: usize) -> Vec<usize> {
        self.bursts.get(&f).cloned().unwrap_or_else(|| vec![f])
    }
}

/// Groups paired by rotator roll and passed by the pose gate, and every candidate's verdict.
fn pair_by_pose(
    frames: &FrameViews,
    views: usize,
    warnings: &mut Vec<String>,
) -> (Vec<Vec<usize>>, Vec<CandidateReport>) {
    let candidates: Vec<CandidateReport> = pair_by_roll(&frames.rolls, views)
        .iter()
        .map(|g| gate(g, &frames.rolls, &frames.attitudes))
        .collect();
    let rejected = candidates.iter().filter(|c| !c.accepted).count();
    if rejected > 0 {
        warnings.push(format!(
            "{rejected} candidate pair(s) rejected by the pose gate (see candidates)"
        ));
    }
    if candidates.iter().any(|c| c.reason == "roll_only") {
        warnings
            .push("frames without attitude paired by the roll-only rule (reason roll_only)".into());
    }
    let groups = candidates
        .iter()
        .filter(|c| c.accepted)
        .map(|c| c.frames.clone())
        .collect();
    (groups, candidates)
}

/// The pairs given with `--pair`, checked against the recording.
fn given_pairs(
    args: &PairingOptions,
    reader: &Recording,
    frames: &FrameViews,
    views: usize,
    warnings: &mut Vec<String>,
) -> Result<Vec<Vec<usize>>> {
    ensure!(
        views == 2,
        "--pair gives two-view pairs, and these weights take {views} views"
    );
    warnings.push(format!(
        "pairs given by index: the roll between them is assumed to be the {} ° baseline",
        config::ROLL_STEP_DEG
    ));
    for &(a, b) in &args.pairs {
        ensure!(
            a < reader.frame_count() && b < reader.frame_count(),
            "pair {a}:{b}: the recording has {} frames",
            reader.frame_count()
        );
        for f in [a, b] {
            if let Some(why) = frames.misfits.get(&f) {
                bail!("pair {a}:{b}: frame {f} does not fit the model: {why}");
            }
        }
    }
    Ok(args.pairs.iter().map(|&(a, b)| vec![a, b]).collect())
}

/// Why no depth map can be made: the baseline, its tolerances and every rejected candidate.
fn no_pairs_message(recording: &Path, candidates: &[CandidateReport]) -> String {
    format!(
        "no frames of {} pair at the {} ° roll baseline (±{} °, residual ≤ {} °){}; give \
         --pair REF:SRC for recordings without rotator roll",
        recording.display(),
        config::ROLL_STEP_DEG,
        config::PAIR_TOLERANCE_DEG,
        config::PAIR_RESIDUAL_TOLERANCE_DEG,
        if candidates.is_empty() {
            String::new()
        } else {
            format!(
                ": the pose gate rejected all {} candidates ({})",
                candidates.len(),
                candidates
                    .iter()
                    .map(|c| format!(
                        "{:?} {} roll {:.3}° residual {}",
                        c.frames,
                        c.reason,
                        c.roll_deg,
                        c.residual_deg
                            .map_or_else(|| "n/a".into(), |r| format!("{r:.3}°"))
                    ))
                    .collect::<Vec<_>>()
                    .join("; ")
            )
        }
    )
}
