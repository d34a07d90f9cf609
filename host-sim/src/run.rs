//! `host-sim run`: the main job. Pairs the frames of a recording at the roll baseline, runs the
//! fixed-point library and the float model on every pair, checks the library against the
//! independent integer reference bit for bit, scores both against ground truth when there is
//! some, and writes depth PNGs and PLY point clouds.
//!
//! With no arguments it runs on the small simulated recording bundled in `data/demo/`.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use epssn::attitude::Attitude;
use epssn::config;
use epssn::model::{Model, Workspace};
use epssn::ping_average;
use fixed::types::U16F16;
use serde::Serialize;

use crate::figure;
use crate::mcap_out::{self, PairMessages, RunMessages};
use crate::pairing::{
    frame_attitude, model_of, pair_recording, CandidateReport, FrameViews, Pairing, PairingOptions,
};
use crate::sweep::{self, CloudFrame};
use epssn_aris::aris::ArisReader;
use epssn_aris::npy;
use epssn_mcap::msgs::SonarPoint;
use epssn_reference::{floatref, reference_model, weights};
use epssn_ros2::Recording;
use epssn_sim::dataset::demo_dir;
use epssn_sim::metrics::{self, Accuracy, Metrics};
use epssn_sim::poses::SitePose;
use epssn_sim::preview;

/// Options of `host-sim run`.
#[derive(Debug)]
pub struct RunOptions {
    /// ARIS recording (default: the bundled simulated demo, `data/demo/recording.aris`).
    pub recording: Option<PathBuf>,
    /// Ground-truth folder with `depth_<frame>.npy` and `mask_<frame>.npy` per reference
    /// frame (default: `gt/` beside the bundled demo recording; `gt-<spec>/` for another spec).
    pub gt: Option<PathBuf>,
    /// Weights, views and how frames are grouped.
    pub pairing: PairingOptions,
    /// Dynamic range of the recording's 0–255 counts, dB, for averaging pings in intensity
    /// (80 for ARIS files, docs/ARIS.md; 70 for the simulator's default).
    pub ping_dynamic_range_db: f32,
    /// Output folder for PNGs, PLYs and `summary.json`.
    pub out: PathBuf,
    /// Print the summary as JSON.
    pub json: bool,
    /// Also write the run as ROS 2 messages (CDR) in this MCAP file: images, depth maps,
    /// point clouds, the sonar's transforms, the pair checks and the summary (docs/MCAP.md).
    pub mcap: Option<PathBuf>,
    /// Frame of the clouds: `sonar`, each pair in its reference view's sonar frame; `world`
    /// also merges every pair by its reference frame's attitude (and `--poses` positions) into
    /// `world.ply` and, with `--mcap`, one merged cloud.
    pub frame: CloudFrame,
    /// Each frame's position in the site (`frame,x_m,y_m,z_m,roll_deg,pitch_deg,yaw_deg`, as
    /// `bundle` writes and `label` reads): moves the world-frame clouds and the transforms.
    pub poses: Option<PathBuf>,
}

/// One depth map of the run.
#[derive(Clone, Debug, Serialize)]
pub struct PairReport {
    /// Frame indices, reference first.
    pub frames: Vec<usize>,
    /// The frames averaged into each view (`--pings-per-view`), reference first.
    pub pings: Vec<Vec<usize>>,
    /// Rolls of those frames, degrees (NaN → null).
    pub rolls_deg: Vec<Option<f64>>,
    /// Library equals the integer reference on every layer and the depth map.
    pub bit_exact: bool,
    /// Mean |int8 − float| depth, mm, over all pixels.
    pub int8_vs_float_mae: f64,
    /// Float model against ground truth.
    pub float: Option<Metrics>,
    /// Int8 library against ground truth.
    pub int8: Option<Metrics>,
}

/// The run's summary (`--json`).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Recording read.
    pub recording: String,
    /// Weights used.
    pub weights: String,
    /// Depth maps computed.
    pub pairs: usize,
    /// Pings averaged per view.
    pub pings_per_view: u32,
    /// Float model accuracy.
    pub float: Accuracy,
    /// Int8 library accuracy.
    pub int8: Accuracy,
    /// Mean over pairs of the mean |int8 − float| depth, mm.
    pub int8_vs_float_mae: f64,
    /// Every pair bit-exact against the integer reference.
    pub bit_exact: bool,
    /// Per pair.
    pub details: Vec<PairReport>,
    /// Every candidate pair with the pose gate's verdict, accepted or not (none with `--pair`).
    pub candidates: Vec<CandidateReport>,
    /// The residual tolerance of the gate, degrees (the spec's).
    pub residual_tolerance_deg: f64,
    /// Warnings (recording, pairing).
    pub warnings: Vec<String>,
}

fn load_gt(dir: &Path, frame: usize) -> Result<Option<(Vec<f32>, Vec<bool>)>> {
    let d = dir.join(format!("depth_{frame:04}.npy"));
    if !d.exists() {
        return Ok(None);
    }
    let depth = npy::read_f32(&d)?;
    let mask = npy::read_f32(&dir.join(format!("mask_{frame:04}.npy")))?;
    ensure!(
        depth.data.len() == config::DEPTH_LEN && mask.data.len() == config::DEPTH_LEN,
        "ground truth for frame {frame} is not {}×{}",
        config::DEPTH_ROWS,
        config::DEPTH_COLUMNS
    );
    Ok(Some((
        depth.data,
        epssn_sim::metrics::mask_from_f32(&mask.data),
    )))
}

/// Runs `host-sim run`.
pub fn run(args: &RunOptions, out: &mut impl Write) -> Result<()> {
    let weights_dir = args.pairing.weights_dir()?;
    let bundle = weights::load(&weights_dir)?;
    let model = model_of(&bundle.blob, &weights_dir)?;
    let recording = args
        .recording
        .clone()
        .unwrap_or_else(|| demo_dir().join("recording.aris"));
    let Pairing {
        reader,
        frames,
        groups,
        candidates,
        mut warnings,
    } = pair_recording(&args.pairing, model.views(), &weights_dir, &recording)?;
    std::fs::create_dir_all(&args.out)?;
    let images = polar_images(args, &reader, &frames, &groups)?;
    let poses = match &args.poses {
        Some(p) => Some(epssn_sim::poses::load(p, reader.frame_count())?),
        None => None,
    };
    let computed = compute_groups(args, &model, &bundle, &groups, &images)?;
    let details = computed
        .iter()
        .zip(&groups)
        .map(|(c, g)| pair_report(g, &frames, &c.maps, c.gt.as_ref()))
        .collect::<Result<Vec<_>>>()?;
    let clouds: Vec<(usize, Vec<SonarPoint>)> = groups
        .iter()
        .zip(&computed)
        .map(|(g, c)| Ok((g[0], mcap_out::sonar_points(&c.maps.int8, &images[&g[0]])?)))
        .collect::<Result<_>>()?;
    let merged = match args.frame {
        CloudFrame::Sonar => None,
        CloudFrame::World => world_cloud(
            &args.out,
            &clouds,
            &frames.attitudes,
            poses.as_ref(),
            &mut warnings,
        )?,
    };
    let summary = Summary::of(
        &recording,
        &weights_dir,
        &frames,
        details,
        candidates,
        warnings,
    );
    let summary_json = serde_json::to_string_pretty(&summary)?;
    std::fs::write(args.out.join("summary.json"), &summary_json)?;
    if let Some(path) = &args.mcap {
        let outputs = RunOutputs {
            groups: &groups,
            computed: &computed,
            images: &images,
            poses: poses.as_ref(),
            merged: merged.as_deref(),
        };
        write_mcap(path, &reader, &summary, &summary_json, &outputs)?;
    }
    if args.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&summary)?)?;
    } else {
        print_summary(&summary, &bundle.description, &args.out, out)?;
        if merged.is_some() {
            writeln!(
                out,
                "wrote the pairs merged in the world frame to world.ply"
            )?;
        }
        if let Some(path) = &args.mcap {
            writeln!(
                out,
                "wrote {} (ROS 2 messages, docs/MCAP.md)",
                path.display()
            )?;
        }
    }
    Ok(())
}

/// The ground truth `run` reads: `--gt`, else, for the bundled demo, its folder for the build's
/// output grid (`gt/` for EPSSN-S); none for another recording without `--gt`.
fn gt_dir(args: &RunOptions) -> Option<PathBuf> {
    args.gt.clone().or_else(|| {
        args.recording.is_none().then(|| {
            demo_dir().join(epssn_spec::load::per_spec_name(
                "gt",
                epssn::config::SPEC_FILE_NAME,
            ))
        })
    })
}

/// One group's depth maps and its ground truth, if any.
struct Computed {
    maps: DepthMaps,
    gt: Option<(Vec<f32>, Vec<bool>)>,
}

/// Every group's depth maps, each pair's figure and clouds written to `args.out`. The library
/// computes each group's features and depth in one call and hands the features back for the
/// bit-exactness check.
fn compute_groups(
    args: &RunOptions,
    model: &Model,
    bundle: &weights::Bundle,
    groups: &[Vec<usize>],
    images: &BTreeMap<usize, Vec<u8>>,
) -> Result<Vec<Computed>> {
    let gt_dir = gt_dir(args);
    let mut ws = Box::new(Workspace::new());
    let mut computed = Vec::new();
    for group in groups {
        let views: Vec<&[u8]> = group.iter().map(|f| images[f].as_slice()).collect();
        let maps = depth_maps(model, bundle, &views, &mut ws)
            .with_context(|| format!("depth of frames {group:?}"))?;
        let gt = match &gt_dir {
            Some(dir) => load_gt(dir, group[0])?,
            None => None,
        };
        let name = format!("frame{:04}", group[0]);
        write_pair_outputs(&args.out, &name, &maps, gt.as_ref())?;
        computed.push(Computed { maps, gt });
    }
    Ok(computed)
}

impl Summary {
    /// The run's summary from its pairs' reports.
    fn of(
        recording: &Path,
        weights_dir: &Path,
        frames: &FrameViews,
        details: Vec<PairReport>,
        candidates: Vec<CandidateReport>,
        warnings: Vec<String>,
    ) -> Self {
        let float: Vec<Metrics> = details.iter().filter_map(|d| d.float.clone()).collect();
        let int8: Vec<Metrics> = details.iter().filter_map(|d| d.int8.clone()).collect();
        Summary {
            recording: recording.display().to_string(),
            weights: weights_dir.display().to_string(),
            pairs: details.len(),
            pings_per_view: frames.pings_per_view,
            float: Accuracy::of(&float),
            int8: Accuracy::of(&int8),
            int8_vs_float_mae: details.iter().map(|d| d.int8_vs_float_mae).sum::<f64>()
                / details.len() as f64,
            bit_exact: details.iter().all(|d| d.bit_exact),
            details,
            candidates,
            residual_tolerance_deg: config::PAIR_RESIDUAL_TOLERANCE_DEG,
            warnings,
        }
    }
}

/// What the run computed, as `--mcap` writes it.
struct RunOutputs<'a> {
    groups: &'a [Vec<usize>],
    computed: &'a [Computed],
    images: &'a BTreeMap<usize, Vec<u8>>,
    poses: Option<&'a BTreeMap<usize, SitePose>>,
    merged: Option<&'a [SonarPoint]>,
}

/// `--mcap`: the run as ROS 2 messages.
fn write_mcap(
    path: &Path,
    reader: &Recording,
    summary: &Summary,
    summary_json: &str,
    o: &RunOutputs,
) -> Result<()> {
    let pairs: Vec<PairMessages> = o
        .groups
        .iter()
        .zip(o.computed)
        .map(|(g, c)| PairMessages {
            frames: g,
            int8: &c.maps.int8,
            float: &c.maps.float,
            truth: c.gt.as_ref().map(|(d, _)| d.as_slice()),
            polar: &o.images[&g[0]],
        })
        .collect();
    // Every frame's attitude, bursts' other pings included: the transforms show the
    // sonar's motion, not only the views the pairing kept.
    let attitudes: Vec<Option<Attitude>> = (0..reader.frame_count())
        .map(|i| frame_attitude(reader, i))
        .collect();
    let positions: BTreeMap<usize, [f64; 3]> = o
        .poses
        .iter()
        .copied()
        .flatten()
        .map(|(&f, p)| (f, p.position_m))
        .collect();
    let run = RunMessages {
        candidates: &summary.candidates,
        pairs: &pairs,
        attitudes: &attitudes,
        positions: &positions,
        sweep: o.merged,
        summary_json,
    };
    mcap_out::write(path, reader, &run).with_context(|| format!("writing {}", path.display()))
}

/// `--frame world`: every placed pair's int8 cloud merged into `dir/world.ply`; `None`, with
/// the reason among the warnings, when no pair can be placed. Pairs that cannot are named.
fn world_cloud(
    dir: &Path,
    clouds: &[(usize, Vec<SonarPoint>)],
    attitudes: &[Option<Attitude>],
    poses: Option<&BTreeMap<usize, SitePose>>,
    warnings: &mut Vec<String>,
) -> Result<Option<Vec<SonarPoint>>> {
    let refs: Vec<usize> = clouds.iter().map(|(f, _)| *f).collect();
    let placement = sweep::place(&refs, attitudes, poses);
    warnings.extend(placement.warnings.iter().cloned());
    let why = |(f, reason): (&usize, &String)| format!("frame {f}: {reason}");
    if placement.transforms.is_empty() {
        let reasons: Vec<String> = placement.missing.iter().map(why).collect();
        warnings.push(format!(
            "no world-frame cloud: no pair's reference frame can be placed ({})",
            reasons.join("; ")
        ));
        return Ok(None);
    }
    if !placement.missing.is_empty() {
        let reasons: Vec<String> = placement.missing.iter().map(why).collect();
        warnings.push(format!(
            "world-frame cloud without {} pair(s): {}",
            reasons.len(),
            reasons.join("; ")
        ));
    }
    if poses.is_none() && placement.transforms.len() > 1 {
        warnings.push(
            "world-frame cloud without --poses: every pair sits at the origin, turned by its \
             header attitude only, so pairs recorded at different places (or, as in the bundled \
             demo, of different scenes) overlap; a rotator sweep from one place merges right"
                .into(),
        );
    }
    let merged = sweep::merge(clouds, &placement);
    sweep::write_merged_ply(&dir.join("world.ply"), &merged)?;
    Ok(Some(merged))
}

/// The polar image of every frame the groups use, each computed once (its pings averaged).
fn polar_images(
    args: &RunOptions,
    reader: &Recording,
    frames: &FrameViews,
    groups: &[Vec<usize>],
) -> Result<BTreeMap<usize, Vec<u8>>> {
    let table = ping_average::IntensityTable::new(args.ping_dynamic_range_db).map_err(|_| {
        anyhow::anyhow!(
            "--ping-dynamic-range-db {} is not within (0, 200]",
            args.ping_dynamic_range_db
        )
    })?;
    let mut images = BTreeMap::new();
    for &f in groups.iter().flatten() {
        if let std::collections::btree_map::Entry::Vacant(e) = images.entry(f) {
            let pings = reader.average_pings(&frames.pings_of(f), &table)?;
            e.insert(pings.to_polar()?);
        }
    }
    Ok(images)
}

/// One group's depth maps: the library's int8 map, checked bit for bit against the integer
/// reference, and the float reference network's.
struct DepthMaps {
    int8: Vec<f32>,
    float: Vec<f32>,
    bit_exact: bool,
}

fn depth_maps(
    model: &Model,
    bundle: &weights::Bundle,
    views: &[&[u8]],
    ws: &mut Workspace,
) -> Result<DepthMaps> {
    let mut features = vec![0i8; views.len() * config::FEATURE_LEN];
    let mut depth_q = vec![U16F16::ZERO; config::DEPTH_LEN];
    model
        .depth(views, &mut features, ws, &mut depth_q)
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let reference = reference_model::run(&bundle.blob, views)?;
    let bits: Vec<u32> = depth_q.iter().map(|d| d.to_bits()).collect();
    let bit_exact = bits == reference.depth
        && features
            .chunks_exact(config::FEATURE_LEN)
            .zip(&reference.features)
            .all(|(f, layers)| layers.values().last().is_some_and(|v| v.as_slice() == f));
    Ok(DepthMaps {
        int8: depth_q.iter().map(|d| d.to_num::<f32>()).collect(),
        float: floatref::run(&bundle.float, views)?.decided(model.no_return16()),
        bit_exact,
    })
}

/// Per-pixel |a − b|.
fn abs_diff(a: &[f32], b: &[f32]) -> Vec<f32> {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).collect()
}

/// The pair's depth figure (`<name>_depth.png`) and point clouds (`<name>_int8.ply`,
/// `<name>_float.ply`).
fn write_pair_outputs(
    dir: &Path,
    name: &str,
    maps: &DepthMaps,
    gt: Option<&(Vec<f32>, Vec<bool>)>,
) -> Result<()> {
    // int8 | float | ground truth (labels clamped, as the metric reads them) | per-pixel
    // |int8 − truth|; without ground truth the last panel is |int8 − float|.
    let truth = gt.map(|(d, _)| metrics::clamp_labels(d));
    let (error, error_title) = match &truth {
        Some(t) => (abs_diff(&maps.int8, t), "|int8 - truth|"),
        None => (abs_diff(&maps.int8, &maps.float), "|int8 - float|"),
    };
    let mut panels = vec![
        figure::Panel::Depth {
            title: "int8",
            depth: &maps.int8,
        },
        figure::Panel::Depth {
            title: "float",
            depth: &maps.float,
        },
    ];
    if let Some(t) = &truth {
        panels.push(figure::Panel::Depth {
            title: "ground truth",
            depth: t,
        });
    }
    panels.push(figure::Panel::Error {
        title: error_title,
        error: &error,
        max_mm: 200.0,
    });
    preview::save_png(
        &figure::depth_figure(&panels),
        &dir.join(format!("{name}_depth.png")),
    )?;
    // Each cloud holds the map's own returns, with or without ground truth: what the device
    // reports in the field, phantoms and misses included.
    metrics::write_ply(
        &dir.join(format!("{name}_int8.ply")),
        &metrics::depth_points(&maps.int8, &metrics::prediction_mask(&maps.int8))?,
        Some([255, 140, 0]),
    )?;
    metrics::write_ply(
        &dir.join(format!("{name}_float.ply")),
        &metrics::depth_points(&maps.float, &metrics::prediction_mask(&maps.float))?,
        Some([0, 160, 255]),
    )?;
    Ok(())
}

/// The pair's report: frames, pings, rolls, bit-exactness and scores against ground truth.
fn pair_report(
    group: &[usize],
    frames: &FrameViews,
    maps: &DepthMaps,
    gt: Option<&(Vec<f32>, Vec<bool>)>,
) -> Result<PairReport> {
    let (float, int8) = match gt {
        Some((d, m)) => (
            Some(metrics::evaluate(&maps.float, d, m)?),
            Some(metrics::evaluate(&maps.int8, d, m)?),
        ),
        None => (None, None),
    };
    let int8_vs_float_mae = metrics::mae(&maps.int8, &maps.float, None)?;
    Ok(PairReport {
        frames: group.to_vec(),
        pings: group.iter().map(|&f| frames.pings_of(f)).collect(),
        rolls_deg: group.iter().map(|&f| frames.rolls[f]).collect(),
        bit_exact: maps.bit_exact,
        int8_vs_float_mae,
        float,
        int8,
    })
}

fn print_summary(s: &Summary, weights: &str, dir: &Path, out: &mut impl Write) -> Result<()> {
    writeln!(out, "recording: {}", s.recording)?;
    writeln!(out, "weights:   {} ({weights})", s.weights)?;
    writeln!(out, "depth maps: {}", s.pairs)?;
    if s.pings_per_view > 1 {
        writeln!(out, "pings averaged per view: {}", s.pings_per_view)?;
    }
    for d in &s.details {
        writeln!(
            out,
            "  frames {:?}: bit-exact {}, int8 vs float {:.2} mm{}",
            d.frames,
            if d.bit_exact { "yes" } else { "NO" },
            d.int8_vs_float_mae,
            match (&d.float, &d.int8) {
                (Some(f), Some(q)) => format!(
                    ", float MAE {:.2} mm (masked {:.2}) CD {:.4}, int8 MAE {:.2} mm (masked {:.2}) CD {:.4}",
                    f.mae, f.mae_masked, f.cd, q.mae, q.mae_masked, q.cd
                ),
                _ => String::new(),
            }
        )?;
    }
    writeln!(out, "float:  {}", s.float.line())?;
    writeln!(out, "int8:   {}", s.int8.line())?;
    writeln!(
        out,
        "int8 vs float: {:.2} mm mean absolute depth difference",
        s.int8_vs_float_mae
    )?;
    writeln!(
        out,
        "library vs integer reference: {}",
        if s.bit_exact {
            "bit-exact on every pair"
        } else {
            "MISMATCH"
        }
    )?;
    for c in s.candidates.iter().filter(|c| !c.accepted) {
        writeln!(
            out,
            "  frames {:?} rejected by the pose gate: {} (roll {:.3}°, residual {})",
            c.frames,
            c.reason,
            c.roll_deg,
            c.residual_deg
                .map_or_else(|| "n/a".into(), |r| format!("{r:.3}°"))
        )?;
    }
    for w in &s.warnings {
        writeln!(out, "warning: {w}")?;
    }
    writeln!(
        out,
        "wrote depth PNGs, PLY point clouds and summary.json to {}",
        dir.display()
    )?;
    if !s.bit_exact {
        bail!("the library differs from the integer reference");
    }
    Ok(())
}

/// Options of `host-sim bundle`.
#[derive(Debug)]
pub struct BundleOptions {
    /// Simulated sample folders (`DIR/<split>/<index>/`), in the order to record them.
    pub samples: Vec<PathBuf>,
    /// Output folder: `recording.aris`, `gt/` and, for samples of one site, `poses.csv`.
    pub out: PathBuf,
}

/// The site (file name, SHA-256) all of `scenes` were drawn in, if they were all drawn in one.
fn common_site(scenes: &[&epssn_sim::scene::Scene]) -> Option<(String, String)> {
    let site_of = |s: &epssn_sim::scene::Scene| {
        s.objects.iter().find_map(|o| match o {
            epssn_sim::scene::Object::Site { file, sha256, .. } => {
                Some((file.clone(), sha256.clone()))
            }
            _ => None,
        })
    };
    let first = site_of(scenes.first()?)?;
    scenes
        .iter()
        .all(|s| site_of(s).as_ref() == Some(&first))
        .then_some(first)
}

/// `host-sim bundle`: concatenates simulated samples into one ARIS recording (each sample's
/// views in roll order, as a rotating sonar would record them, each view's pings in a row when
/// it was simulated with `ping_frames`) with the ground truth of every
/// reference frame in `gt/depth_<frame>.npy` and `gt/mask_<frame>.npy`. When every sample was
/// drawn in one site, `poses.csv` gives each frame's pose in the site frame (`label` reads it);
/// procedural samples each have a world of their own, so no one file of poses describes them.
pub fn bundle(args: &BundleOptions, out: &mut impl Write) -> Result<()> {
    let gt = args.out.join("gt");
    std::fs::create_dir_all(&gt)?;
    let mut frames: Vec<(epssn_aris::aris::FrameHeader, Vec<u8>)> = Vec::new();
    let mut poses = Vec::new();
    let mut scenes = Vec::new();
    for dir in &args.samples {
        let sample = epssn_sim::dataset::Sample::load(dir)?;
        let reference = frames.len();
        for k in 0..sample.polar_views.len() {
            let path = dir.join(format!("view{k}.aris"));
            let r =
                ArisReader::open(&path).with_context(|| format!("opening {}", path.display()))?;
            // Every frame: one, or the view's pings (simulated with `ping_frames`).
            for i in 0..r.frame_count() {
                let f = r.frame(i)?;
                let mut h = f.header.clone();
                h.frame_index = frames.len() as u32;
                h.frame_time_us = 1_700_000_000_000_000 + frames.len() as u64 * 100_000;
                poses.push((frames.len(), SitePose::of_view(&sample.scene, k)));
                frames.push((h, f.data));
            }
        }
        let shape = [config::DEPTH_ROWS, config::DEPTH_COLUMNS];
        npy::write_f32(
            &gt.join(format!("depth_{reference:04}.npy")),
            &shape,
            &sample.depth,
        )?;
        npy::write_f32(
            &gt.join(format!("mask_{reference:04}.npy")),
            &shape,
            &sample.mask,
        )?;
        scenes.push(sample.scene);
    }
    let refs: Vec<(&epssn_aris::aris::FrameHeader, &[u8])> =
        frames.iter().map(|(h, d)| (h, d.as_slice())).collect();
    let path = args.out.join("recording.aris");
    epssn_aris::aris::write_recording(&path, &refs)?;
    writeln!(
        out,
        "wrote {} frames to {} and ground truth to {}",
        frames.len(),
        path.display(),
        gt.display()
    )?;
    let poses_path = args.out.join("poses.csv");
    match common_site(&scenes.iter().collect::<Vec<_>>()) {
        Some((file, _)) => {
            std::fs::write(&poses_path, epssn_sim::poses::to_csv(&poses))
                .with_context(|| format!("writing {}", poses_path.display()))?;
            writeln!(
                out,
                "wrote the pose of every frame in site {file} to {}",
                poses_path.display()
            )?;
        }
        None => {
            // A poses file left from an earlier bundle would describe other frames.
            if poses_path.exists() {
                std::fs::remove_file(&poses_path)
                    .with_context(|| format!("removing {}", poses_path.display()))?;
            }
            writeln!(
                out,
                "no poses.csv: the samples were not all drawn in one site"
            )?;
        }
    }
    Ok(())
}
