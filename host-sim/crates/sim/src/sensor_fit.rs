//! `host-sim fit-sensor`: fits the simulator's image formation (speckle looks, noise floor
//! level, looks and slope with range, gain, dynamic range, crosstalk, far side lobes, the
//! pulse's extent along range) to a recording's image statistics
//! ([`crate::sensor_stats`]), and writes the `SonarSimParams` that `simulate --params` reads.
//!
//! The estimator works in the compression's own terms: a sample reads
//! `κ · ln I + o` counts, `κ = 2550 / (DR · ln 10)` and `o = 255 · gain / DR`, with
//! `I = v · Gamma(L, 1/L) + floor · Gamma(N, 1/N)`. So in the windows where returns dominate,
//! the spread is `κ·√ψ'(L)` (plus the scene's texture) and the skewness `ψ''(L) / ψ'(L)^1.5`
//! depends on L alone; in the floor's windows, the level gives `ln floor` and the spread
//! `κ·√ψ'(N)`. The moment estimates from these relations start a deterministic search that
//! simulates fixed scenes (traced once, re-formed per candidate) and matches the statistics:
//! for each L, fixed-point updates of κ, o, floor and N through the same relations; then L by
//! the skewness, the crosstalk by the lag-1 correlation across beams, and L once more; then
//! the texture stage ([`texture_mismatch`]): the pulse with the looks around, the side lobes,
//! the floor's slope and smoother floors, each with the moments matched again.
//! Only image-formation fields change; the base's geometry and rays stay.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{ensure, Context, Result};
use serde::Serialize;

use crate::render::{form_image, trace_view, SonarSimParams, TracedView};
use crate::scene::{generate, SceneKind, Split};
use crate::sensor_stats::{measure, measure_any, measure_recording, FrameRef, ImageStats};
use crate::world::World;

/// Speckle looks the search tries.
pub const MAX_LOOKS: u32 = 8;
/// Second-neighbour crosstalk as a share of the first's (the default 0.02 / 0.08): one
/// correlation cannot tell them apart, so the fit keeps their ratio.
pub const CROSSTALK2_RATIO: f64 = 0.25;
/// Crosstalk values the search brackets the lag-1 correlation with.
const CROSSTALK_GRID: [f64; 6] = [0.0, 0.04, 0.08, 0.12, 0.16, 0.2];
/// Pulse widths the texture stage tries, as multiples of the base's `pulse_sigma_samples`: the
/// range PSF that sets how far a return's rise and fall spread along range.
const PULSE_GRID: [f64; 5] = [1.0, 0.7, 0.5, 0.35, 0.25];
/// Far side-lobe levels the texture stage tries (`sidelobe`, share of the fan's mean: 1 lets
/// each of the 128 beams leak into every other at −21 dB).
const SIDELOBE_GRID: [f64; 5] = [0.0, 0.03, 0.1, 0.3, 1.0];
/// The floor's slopes with range the texture stage tries, dB per metre.
const FLOOR_SLOPE_GRID: [f64; 3] = [2.5, 5.0, 10.0];
/// Floor looks the texture stage tries last, as multiples of the matched ones.
const FLOOR_LOOKS_FACTORS: [f64; 3] = [1.5, 2.0, 3.0];
/// What the texture stage must gain in [`texture_mismatch`] for its parameters to be taken:
/// two histogram modes' worth. Measured 2026-12-06: 181 on the ARIS 1200 recording, at most 25
/// on the recovery test's simulated recordings (other scenes than the bench's, same texture).
const TEXTURE_MARGIN: f64 = 50.0;
/// Dynamic range bounds, dB (`simulate` takes up to 200).
const DR_RANGE: (f64, f64) = (10.0, 200.0);
/// Noise floor looks bounds.
const NOISE_LOOKS_RANGE: (f64, f64) = (0.5, 1e4);
/// Noise floor bounds, linear.
const FLOOR_RANGE: (f64, f64) = (1e-15, 1.0);

/// Trigamma ψ'(x), x > 0: recurrence up to 6, then the asymptotic series.
pub fn trigamma(mut x: f64) -> f64 {
    let mut acc = 0.0;
    while x < 6.0 {
        acc += 1.0 / (x * x);
        x += 1.0;
    }
    let x2 = 1.0 / (x * x);
    acc + 1.0 / x
        + x2 / 2.0
        + (1.0 / x) * x2 * (1.0 / 6.0 - x2 * (1.0 / 30.0 - x2 * (1.0 / 42.0 - x2 / 30.0)))
}

/// Tetragamma ψ''(x), x > 0.
pub fn tetragamma(mut x: f64) -> f64 {
    let mut acc = 0.0;
    while x < 6.0 {
        acc -= 2.0 / (x * x * x);
        x += 1.0;
    }
    let x2 = 1.0 / (x * x);
    acc - x2 - x2 / x - x2 * x2 * (0.5 - x2 * (1.0 / 6.0 - x2 * (1.0 / 6.0 - x2 * 3.0 / 10.0)))
}

/// Skewness of ln Gamma(L): the bright windows' scale-free signature of L looks.
pub fn log_gamma_skewness(looks: f64) -> f64 {
    tetragamma(looks) / trigamma(looks).powf(1.5)
}

/// The x with ψ'(x) = `value`, clamped to `NOISE_LOOKS_RANGE` (ψ' falls monotonically).
fn inverse_trigamma(value: f64) -> f64 {
    let (mut lo, mut hi) = (NOISE_LOOKS_RANGE.0.ln(), NOISE_LOOKS_RANGE.1.ln());
    if !(value.is_finite() && value > 0.0) {
        return NOISE_LOOKS_RANGE.1;
    }
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if trigamma(mid.exp()) > value {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (0.5 * (lo + hi)).exp()
}

/// The fields the fit moves, in the compression's terms.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Candidate {
    looks: u32,
    /// Counts per neper.
    kappa: f64,
    /// Counts at intensity 1.
    offset: f64,
    ln_floor: f64,
    noise_looks: f64,
    crosstalk: f64,
    /// The range PSF, samples (`pulse_sigma_samples`).
    pulse_sigma: f64,
    /// Far side lobes (`sidelobe`).
    sidelobe: f64,
    /// The floor's slope with range, dB/m (`noise_floor_db_per_m`).
    floor_slope: f64,
}

const LN10: f64 = std::f64::consts::LN_10;

impl Candidate {
    fn from_params(p: &SonarSimParams) -> Self {
        let dr = p.dynamic_range_db.clamp(DR_RANGE.0, DR_RANGE.1);
        Self {
            looks: p.speckle_looks.clamp(1, MAX_LOOKS),
            kappa: 2550.0 / (dr * LN10),
            offset: 255.0 * p.gain_db / dr,
            ln_floor: p.noise_floor.clamp(FLOOR_RANGE.0, FLOOR_RANGE.1).ln(),
            noise_looks: if p.noise_looks > 0.0 {
                p.noise_looks
            } else {
                p.speckle_looks.max(1) as f64
            },
            crosstalk: p.crosstalk.clamp(0.0, CROSSTALK_GRID[5]),
            pulse_sigma: p.pulse_sigma_samples,
            sidelobe: p.sidelobe,
            floor_slope: p.noise_floor_db_per_m,
        }
    }

    /// Keeps every field inside what `simulate` accepts.
    fn clamped(mut self) -> Self {
        let k = |dr: f64| 2550.0 / (dr * LN10);
        self.kappa = self.kappa.clamp(k(DR_RANGE.1), k(DR_RANGE.0));
        self.ln_floor = self.ln_floor.clamp(FLOOR_RANGE.0.ln(), FLOOR_RANGE.1.ln());
        self.noise_looks = self
            .noise_looks
            .clamp(NOISE_LOOKS_RANGE.0, NOISE_LOOKS_RANGE.1);
        self.crosstalk = self.crosstalk.clamp(0.0, CROSSTALK_GRID[5]);
        self
    }

    fn apply(&self, base: &SonarSimParams) -> SonarSimParams {
        let dr = 2550.0 / (self.kappa * LN10);
        SonarSimParams {
            speckle: true,
            speckle_looks: self.looks,
            ping_frames: false,
            noise_floor: self.ln_floor.exp(),
            noise_looks: self.noise_looks,
            gain_db: self.offset * dr / 255.0,
            dynamic_range_db: dr,
            crosstalk: self.crosstalk,
            crosstalk2: self.crosstalk * CROSSTALK2_RATIO,
            pulse_sigma_samples: self.pulse_sigma,
            sidelobe: self.sidelobe,
            noise_floor_db_per_m: self.floor_slope,
            ..base.clone()
        }
    }
}

/// The scenes the fit simulates: traced once, formed again for every candidate.
pub struct Bench {
    base: SonarSimParams,
    views: Vec<TracedView>,
}

impl Bench {
    /// Traces view 0 of `scenes` scenes of `kind` (test split, `seed`) with `base`'s geometry.
    pub fn new(kind: SceneKind, scenes: usize, seed: u64, base: &SonarSimParams) -> Result<Self> {
        ensure!(
            kind != SceneKind::Site,
            "the fit simulates procedural scenes"
        );
        ensure!(scenes > 0, "the fit needs at least one scene");
        crate::simulate::check_params(base)?;
        let views = (0..scenes as u64)
            .map(|i| {
                let scene = generate(kind, Split::Test, seed, i, 2);
                trace_view(&scene, &World::new(&scene), 0, base)
            })
            .collect();
        Ok(Self {
            base: base.clone(),
            views,
        })
    }

    /// The base parameters (geometry and rays) the scenes were traced with.
    pub fn base(&self) -> &SonarSimParams {
        &self.base
    }

    /// The frames the bench's scenes give with `params` (its geometry must be the base's).
    pub fn frames(&self, params: &SonarSimParams) -> Vec<Vec<u8>> {
        self.views
            .iter()
            .map(|v| form_image(v, params).samples)
            .collect()
    }

    /// The statistics of the bench's scenes formed with `params`.
    pub fn stats(&self, params: &SonarSimParams) -> Result<ImageStats> {
        self.stats_with(params, measure)
    }

    fn stats_with(
        &self,
        params: &SonarSimParams,
        measure: fn(&[FrameRef]) -> Result<ImageStats>,
    ) -> Result<ImageStats> {
        let frames = self.frames(params);
        let refs: Vec<FrameRef> = frames
            .iter()
            .map(|f| FrameRef {
                data: f,
                beams: epssn::config::BEAMS,
            })
            .collect();
        measure(&refs)
    }
}

/// The closed-form estimates that start the search.
#[derive(Clone, Debug, Serialize)]
pub struct MomentEstimates {
    /// Looks from the bright windows' skewness (ψ''(L)/ψ'(L)^1.5, texture ignored).
    pub speckle_looks: f64,
    /// Dynamic range from the bright spread and those looks, dB.
    pub dynamic_range_db: f64,
    /// Floor looks from the dark spread at that dynamic range.
    pub noise_looks: f64,
}

/// What [`fit`] found.
#[derive(Clone, Debug, Serialize)]
pub struct Fit {
    /// The fitted parameters (the base's geometry).
    pub params: SonarSimParams,
    /// The estimates the search started from.
    pub moment_estimates: MomentEstimates,
    /// The bench's statistics with the fitted parameters.
    pub fitted: ImageStats,
    /// Weighted squared mismatch of the matched statistics (see [`mismatch`]).
    pub mismatch: f64,
    /// Simulations the search ran.
    pub evaluations: usize,
}

/// Σ ((simulated − target) / scale)² over the statistics the fit matches; the scales are the
/// tolerances the search aims at (1 count for levels, 0.5 for spreads, 0.03 for skewness and
/// correlation).
pub fn mismatch(sim: &ImageStats, target: &ImageStats) -> f64 {
    [
        (sim.bright_mean - target.bright_mean, 1.0),
        (sim.speckle_std - target.speckle_std, 0.5),
        (sim.speckle_skew - target.speckle_skew, 0.03),
        (sim.dark_mean - target.dark_mean, 1.0),
        (sim.dark_std - target.dark_std, 0.5),
        (sim.lag1_beam_columns - target.lag1_beam_columns, 0.03),
    ]
    .iter()
    .map(|(d, s)| (d / s).powi(2))
    .sum()
}

/// [`mismatch`] plus the texture: the lag-1 correlations along range and across beams (scale
/// 0.03), the bright contrast (0.01), the share of samples clipped to 0 (0.001: a floor whose
/// fades clip piles up a mode at 0) and the histogram's mode count (each mode off weighs 5).
pub fn texture_mismatch(sim: &ImageStats, target: &ImageStats) -> f64 {
    let modes = sim.histogram_modes.abs_diff(target.histogram_modes) as f64;
    mismatch(sim, target)
        + ((sim.zero_fraction - target.zero_fraction) / 0.001).powi(2)
        + ((sim.lag1_range - target.lag1_range) / 0.03).powi(2)
        + ((sim.lag1_beam - target.lag1_beam) / 0.03).powi(2)
        + ((sim.bright_contrast - target.bright_contrast) / 0.01).powi(2)
        + 25.0 * modes * modes
}

/// The moment estimates of `target` (see [`MomentEstimates`]).
pub fn moment_estimates(target: &ImageStats) -> MomentEstimates {
    // Skewness rises monotonically from −1.14 (one look) towards 0; bisect in ln L.
    let (mut lo, mut hi) = (0.0f64, (MAX_LOOKS as f64 * 4.0).ln());
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if log_gamma_skewness(mid.exp()) < target.speckle_skew {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let looks = (0.5 * (lo + hi)).exp();
    let kappa = target.speckle_std / trigamma(looks).sqrt();
    let dr = (2550.0 / (kappa * LN10)).clamp(DR_RANGE.0, DR_RANGE.1);
    let kappa = 2550.0 / (dr * LN10);
    MomentEstimates {
        speckle_looks: looks,
        dynamic_range_db: dr,
        noise_looks: inverse_trigamma((target.dark_std / kappa).powi(2)),
    }
}

struct Search<'a> {
    bench: &'a Bench,
    target: &'a ImageStats,
    evaluations: usize,
    /// Floor looks held while the moments are matched (the texture stage's smoother floors).
    hold_noise_looks: bool,
}

impl Search<'_> {
    fn eval(&mut self, c: &Candidate) -> Result<ImageStats> {
        self.evaluations += 1;
        let s = self
            .bench
            .stats_with(&c.apply(&self.bench.base), measure_any)
            .context("simulating a candidate")?;
        Ok(s)
    }

    /// Fixed-point updates of κ, o, floor and N at `c`'s looks and crosstalk; returns the
    /// candidate, its statistics and mismatch.
    fn match_moments(
        &mut self,
        mut c: Candidate,
        iterations: usize,
    ) -> Result<(Candidate, ImageStats, f64)> {
        let t = self.target;
        for _ in 0..iterations {
            let s = self.eval(&c)?;
            let old = c;
            // Spreads in counts scale with κ, speckle and texture alike.
            c.kappa *= t.speckle_std / s.speckle_std.max(1e-3);
            c = c.clamped();
            // The bright windows' mean log intensity stays; the offset puts it on the target.
            let bright_ln = (s.bright_mean - old.offset) / old.kappa;
            c.offset = t.bright_mean - c.kappa * bright_ln;
            // The floor's level, in nepers, moves by what the dark windows miss.
            let dark_ln_sim = (s.dark_mean - old.offset) / old.kappa;
            let dark_ln_want = (t.dark_mean - c.offset) / c.kappa;
            c.ln_floor += dark_ln_want - dark_ln_sim;
            // ψ'(N) is the floor's log variance: scale it by the spread's ratio.
            let ratio = (t.dark_std / c.kappa) / (s.dark_std.max(1e-3) / old.kappa);
            if !self.hold_noise_looks {
                c.noise_looks = inverse_trigamma(trigamma(old.noise_looks) * ratio * ratio);
            }
            c = c.clamped();
        }
        let s = self.eval(&c)?;
        let m = mismatch(&s, t);
        Ok((c, s, m))
    }

    /// The best of `looks` (each matched from `start`, κ rescaled by ψ' for the new looks).
    fn best_looks(
        &mut self,
        start: Candidate,
        looks: impl Iterator<Item = u32>,
        iterations: usize,
    ) -> Result<(Candidate, ImageStats, f64)> {
        let mut best: Option<(Candidate, ImageStats, f64)> = None;
        for l in looks {
            let mut c = start;
            c.kappa *= (trigamma(start.looks as f64) / trigamma(l as f64)).sqrt();
            c.looks = l;
            let r = self.match_moments(c.clamped(), iterations)?;
            if best.as_ref().is_none_or(|b| r.2 < b.2) {
                best = Some(r);
            }
        }
        best.context("no looks to try")
    }

    /// The texture stage: for each pulse width of [`PULSE_GRID`] and the looks around `c`'s,
    /// the moments matched again; then, at the best of those, each side-lobe level of
    /// [`SIDELOBE_GRID`], and at the best of all, each floor slope of [`FLOOR_SLOPE_GRID`];
    /// the candidate with the smallest [`texture_mismatch`] wins.
    fn texture(&mut self, c: Candidate) -> Result<(Candidate, ImageStats)> {
        let mut best: Option<(Candidate, ImageStats, f64)> = None;
        let keep = |best: &mut Option<(Candidate, ImageStats, f64)>, r: (Candidate, ImageStats)| {
            let m = texture_mismatch(&r.1, self.target);
            if best.as_ref().is_none_or(|b| m < b.2) {
                *best = Some((r.0, r.1, m));
            }
        };
        // Up to two looks more: the texture the scenes add to the bright windows' skewness
        // makes the first stage pick fewer looks than the speckle has.
        let looks = c.looks.saturating_sub(1).max(1)..=(c.looks + 2).min(MAX_LOOKS);
        for f in PULSE_GRID {
            for l in looks.clone() {
                let mut start = c;
                start.pulse_sigma = self.bench.base.pulse_sigma_samples * f;
                start.kappa *= (trigamma(c.looks as f64) / trigamma(l as f64)).sqrt();
                start.looks = l;
                let (cand, s, _) = self.match_moments(start.clamped(), 4)?;
                keep(&mut best, (cand, s));
            }
        }
        let pulse = best.as_ref().context("no pulse to try")?.0;
        for x in SIDELOBE_GRID.into_iter().filter(|&x| x != pulse.sidelobe) {
            let (cand, s, _) = self.match_moments(
                Candidate {
                    sidelobe: x,
                    ..pulse
                },
                4,
            )?;
            keep(&mut best, (cand, s));
        }
        let lobes = best.as_ref().context("no side lobes to try")?.0;
        for x in FLOOR_SLOPE_GRID {
            let (cand, s, _) = self.match_moments(
                Candidate {
                    floor_slope: x,
                    ..lobes
                },
                4,
            )?;
            keep(&mut best, (cand, s));
        }
        // A smoother floor than its spread asks for: fewer fades clipped to 0, whose pile is a
        // histogram mode of its own.
        let slope = best.as_ref().context("no floor slope to try")?.0;
        self.hold_noise_looks = true;
        for f in FLOOR_LOOKS_FACTORS {
            let start = Candidate {
                noise_looks: slope.noise_looks * f,
                ..slope
            };
            let (cand, s, _) = self.match_moments(start.clamped(), 4)?;
            keep(&mut best, (cand, s));
        }
        self.hold_noise_looks = false;
        best.map(|(c, s, _)| (c, s)).context("no pulse to try")
    }

    /// The crosstalk whose lag-1 correlation across beams meets the target's, interpolated on
    /// [`CROSSTALK_GRID`] (0 when even none correlates more than the target).
    fn crosstalk(&mut self, c: Candidate) -> Result<f64> {
        let mut lags = Vec::new();
        for x in CROSSTALK_GRID {
            let s = self.eval(&Candidate { crosstalk: x, ..c })?;
            lags.push(s.lag1_beam_columns);
        }
        let t = self.target.lag1_beam_columns;
        if t <= lags[0] {
            return Ok(0.0);
        }
        for i in 1..lags.len() {
            if t <= lags[i] {
                let f = (t - lags[i - 1]) / (lags[i] - lags[i - 1]).max(1e-9);
                return Ok(CROSSTALK_GRID[i - 1] + f * (CROSSTALK_GRID[i] - CROSSTALK_GRID[i - 1]));
            }
        }
        Ok(CROSSTALK_GRID[CROSSTALK_GRID.len() - 1])
    }
}

/// Fits `bench`'s image formation to `target`.
pub fn fit(target: &ImageStats, bench: &Bench) -> Result<Fit> {
    let est = moment_estimates(target);
    let mut search = Search {
        bench,
        target,
        evaluations: 0,
        hold_noise_looks: false,
    };
    let mut start = Candidate::from_params(&bench.base);
    start.looks = (est.speckle_looks.round() as u32).clamp(1, MAX_LOOKS);
    start.kappa = 2550.0 / (est.dynamic_range_db * LN10);
    start.noise_looks = est.noise_looks;
    let start = start.clamped();
    let (c, _, _) = search.best_looks(start, 1..=MAX_LOOKS, 4)?;
    let crosstalk = search.crosstalk(c)?;
    let c = Candidate { crosstalk, ..c };
    let around = c.looks.saturating_sub(1).max(1)..=(c.looks + 1).min(MAX_LOOKS);
    let (c, plain, _) = search.best_looks(c, around, 4)?;
    let (textured, textured_stats) = search.texture(c)?;
    // The texture stage's parameters only where they buy a clear match: on a recording whose
    // texture the base's already has, the other scenes' differences would move them (and the
    // gain and floor with them) for nothing.
    let (c, fitted) = if texture_mismatch(&plain, target)
        - texture_mismatch(&textured_stats, target)
        >= TEXTURE_MARGIN
    {
        (textured, textured_stats)
    } else {
        (c, plain)
    };
    let mismatch = mismatch(&fitted, target);
    Ok(Fit {
        params: c.apply(&bench.base),
        moment_estimates: est,
        fitted,
        mismatch,
        evaluations: search.evaluations,
    })
}

/// `host-sim fit-sensor`.
#[derive(Debug)]
pub struct FitSensorOptions {
    /// The recording (.aris, or a ROS 2 bag of ProjectedSonarImage) whose image statistics the
    /// simulator is fitted to.
    pub recording: PathBuf,
    /// A bag's ProjectedSonarImage topic (default: its only one).
    pub topic: Option<String>,
    /// Write the fitted SonarSimParams here (JSON, for `simulate --params`).
    pub out: PathBuf,
    /// Base parameters (geometry, rays; JSON as `simulate --params`); default: the defaults.
    pub params: Option<PathBuf>,
    /// Scene family the fit simulates.
    pub scene: SceneKind,
    /// Scenes the fit simulates (view 0 of each); fewer scenes let the scenes' own texture
    /// move the speckle statistics (6 scenes mistook 4 looks for 3 in the recovery test).
    pub scenes: usize,
    /// Seed of those scenes.
    pub seed: u64,
    /// Print the report as JSON instead of a table.
    pub json: bool,
}

/// One set's statistics in the `--json` report: every [`ImageStats`] field, and the texture
/// figures also under the short names `lag1_beams` (= `lag1_beam`) and `modes`
/// (= `histogram_modes`), so that `recording`, `base` and `fitted` each hold `lag1_range`,
/// `lag1_beams`, `bright_contrast`, `dark_mean` and `modes`.
#[derive(Serialize)]
struct ReportStats<'a> {
    #[serde(flatten)]
    stats: &'a ImageStats,
    lag1_beams: f64,
    modes: usize,
}

impl<'a> From<&'a ImageStats> for ReportStats<'a> {
    fn from(stats: &'a ImageStats) -> Self {
        Self {
            stats,
            lag1_beams: stats.lag1_beam,
            modes: stats.histogram_modes,
        }
    }
}

/// The `--json` report.
#[derive(Serialize)]
struct Report<'a> {
    recording: ReportStats<'a>,
    /// The simulation with the base parameters (also under its older name).
    base: ReportStats<'a>,
    /// The simulation with the fitted parameters (also under its older name).
    fitted: ReportStats<'a>,
    default_simulator: &'a ImageStats,
    fitted_simulator: &'a ImageStats,
    params: &'a SonarSimParams,
    moment_estimates: &'a MomentEstimates,
    mismatch: f64,
    evaluations: usize,
}

/// The statistics table: one row per statistic, one column per set.
pub fn write_table(out: &mut dyn Write, columns: &[(&str, &ImageStats)]) -> Result<()> {
    type Row = (&'static str, fn(&ImageStats) -> String);
    let rows: [Row; 21] = [
        ("frames", |s| s.frames.to_string()),
        ("windows (dark / bright)", |s| {
            format!("{} ({}/{})", s.windows, s.dark_windows, s.bright_windows)
        }),
        ("bright mean, counts", |s| format!("{:.1}", s.bright_mean)),
        ("bright std, counts", |s| format!("{:.2}", s.bright_std)),
        ("bright std / mean", |s| format!("{:.3}", s.bright_contrast)),
        ("bright skewness", |s| format!("{:.3}", s.bright_skew)),
        ("speckle std, counts", |s| format!("{:.2}", s.speckle_std)),
        ("speckle skewness", |s| format!("{:.3}", s.speckle_skew)),
        ("dark mean, counts", |s| format!("{:.1}", s.dark_mean)),
        ("dark std, counts", |s| format!("{:.2}", s.dark_std)),
        ("dark zeros", |s| {
            format!("{:.2} %", 100.0 * s.dark_zero_fraction)
        }),
        ("all zeros", |s| format!("{:.2} %", 100.0 * s.zero_fraction)),
        ("p1, counts", |s| format!("{:.0}", s.p1)),
        ("p50, counts", |s| format!("{:.0}", s.p50)),
        ("p99, counts", |s| format!("{:.0}", s.p99)),
        ("histogram modes", |s| s.histogram_modes.to_string()),
        ("lag-1 along range", |s| format!("{:.3}", s.lag1_range)),
        ("lag-1 across beams", |s| format!("{:.3}", s.lag1_beam)),
        ("lag-1 across beam means", |s| {
            format!("{:.3}", s.lag1_beam_columns)
        }),
        ("lag-1 along range, pooled", |s| {
            format!("{:.3}", s.lag1_range_pooled)
        }),
        ("lag-1 across beams, pooled", |s| {
            format!("{:.3}", s.lag1_beam_pooled)
        }),
    ];
    write!(out, "{:<26}", "statistic")?;
    for (name, _) in columns {
        write!(out, " {name:>16}")?;
    }
    writeln!(out)?;
    for (label, f) in rows {
        write!(out, "{label:<26}")?;
        for (_, s) in columns {
            write!(out, " {:>16}", f(s))?;
        }
        writeln!(out)?;
    }
    Ok(())
}

/// Runs `host-sim fit-sensor`.
pub fn run(args: &FitSensorOptions, out: &mut dyn Write) -> Result<()> {
    let base: SonarSimParams = match &args.params {
        Some(p) => serde_json::from_str(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("parsing {}", p.display()))?,
        None => SonarSimParams::default(),
    };
    ensure!(
        (1..=64).contains(&args.scenes),
        "--scenes must be within 1..=64"
    );
    let started = std::time::Instant::now();
    let target = measure_recording(&args.recording, args.topic.as_deref())?;
    let bench = Bench::new(args.scene, args.scenes, args.seed, &base)?;
    let default_stats = bench
        .stats(&base)
        .context("measuring the simulation with the base parameters")?;
    let fit = fit(&target, &bench)?;
    std::fs::write(&args.out, serde_json::to_string_pretty(&fit.params)? + "\n")
        .with_context(|| format!("writing {}", args.out.display()))?;
    if args.json {
        let report = Report {
            recording: (&target).into(),
            base: (&default_stats).into(),
            fitted: (&fit.fitted).into(),
            default_simulator: &default_stats,
            fitted_simulator: &fit.fitted,
            params: &fit.params,
            moment_estimates: &fit.moment_estimates,
            mismatch: fit.mismatch,
            evaluations: fit.evaluations,
        };
        writeln!(out, "{}", serde_json::to_string_pretty(&report)?)?;
    } else {
        write_table(
            out,
            &[
                ("recording", &target),
                ("base simulator", &default_stats),
                ("fitted simulator", &fit.fitted),
            ],
        )?;
        let p = &fit.params;
        let e = &fit.moment_estimates;
        writeln!(out)?;
        writeln!(
            out,
            "fitted: speckle_looks {} (moments {:.2}), noise_looks {:.2} (moments {:.2}), \
             noise_floor {:.3e} ({:.1} dB), gain_db {:.2}, dynamic_range_db {:.2} (moments {:.2}), \
             crosstalk {:.3} / {:.3}, pulse_sigma_samples {:.2}, sidelobe {:.2}, \
             noise_floor_db_per_m {:.1}",
            p.speckle_looks,
            e.speckle_looks,
            p.noise_looks,
            e.noise_looks,
            p.noise_floor,
            10.0 * p.noise_floor.log10(),
            p.gain_db,
            p.dynamic_range_db,
            e.dynamic_range_db,
            p.crosstalk,
            p.crosstalk2,
            p.pulse_sigma_samples,
            p.sidelobe,
            p.noise_floor_db_per_m
        )?;
        writeln!(
            out,
            "mismatch {:.2} after {} simulations of {} {:?} scenes; wrote {}",
            fit.mismatch,
            fit.evaluations,
            args.scenes,
            args.scene,
            args.out.display()
        )?;
    }
    eprintln!("fit-sensor: {:.1} s", started.elapsed().as_secs_f64());
    Ok(())
}
