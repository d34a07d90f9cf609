//! Image statistics that describe a sonar's image formation rather than its scene: speckle,
//! noise floor, compression and crosstalk, measured on raw u8 frames in small windows so that
//! they do not depend on the recording's beam count, range or geometry (docs/SITES.md,
//! "Fitting the noise model to your sonar").
//!
//! Every frame is cut into non-overlapping windows of [`WINDOW_SAMPLES`] range samples ×
//! [`WINDOW_BEAMS`] adjacent beams. The tenth of the windows with the lowest mean are the
//! *dark* windows (the noise floor), the tenth with the highest the *bright* ones (returns,
//! where speckle dominates). Per-window figures are summarised by their median over the
//! selection, so a few windows straddling an edge do not move them.

use anyhow::{bail, ensure, Result};
use serde::{Deserialize, Serialize};

/// Range samples per window.
pub const WINDOW_SAMPLES: usize = 16;
/// Adjacent beams per window.
pub const WINDOW_BEAMS: usize = 4;
/// Share of the windows taken as dark, and as bright.
pub const SELECTED_SHARE: f64 = 0.1;
/// Fewest windows a recording must have (ten dark and ten bright ones).
pub const MIN_WINDOWS: usize = 100;

/// One frame as the statistics read it: `data[sample × beams + beam]`, as an ARIS frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameRef<'a> {
    /// The samples.
    pub data: &'a [u8],
    /// Beams per sample row.
    pub beams: usize,
}

/// The statistics of a set of frames (one recording, or one simulation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageStats {
    /// Frames measured.
    pub frames: usize,
    /// Windows measured (all frames).
    pub windows: usize,
    /// Dark windows among them.
    pub dark_windows: usize,
    /// Bright windows among them.
    pub bright_windows: usize,
    /// Bright windows: median of the window means, counts.
    pub bright_mean: f64,
    /// Bright windows: median of the window standard deviations, counts (speckle × compression).
    pub bright_std: f64,
    /// Bright windows: median of std / mean (the contrast).
    pub bright_contrast: f64,
    /// Bright windows: median of the window skewness (scale-free; log-compressed speckle of L
    /// looks has skewness ψ''(L) / ψ'(L)^1.5: −1.14, −0.78, −0.53 for 1, 2, 4 looks).
    pub bright_skew: f64,
    /// Bright windows: median of the speckle's spread from second differences along range,
    /// `√(mean r² / 1.5)` with `r = x(s) − (x(s−1) + x(s+1)) / 2`, counts: the scene's smooth
    /// variation cancels, so this is `κ·√ψ'(L)` for white speckle.
    pub speckle_std: f64,
    /// Bright windows: median skewness of those residuals, rescaled by 1 / 0.408 so that white
    /// log-compressed speckle of L looks reads ψ''(L) / ψ'(L)^1.5, as `bright_skew` would
    /// without texture.
    pub speckle_skew: f64,
    /// Dark windows: median of the window means, counts (the floor's level).
    pub dark_mean: f64,
    /// Dark windows: median of the window standard deviations, counts (the floor's spread).
    pub dark_std: f64,
    /// Dark windows: share of samples reading exactly 0.
    pub dark_zero_fraction: f64,
    /// All samples: share reading exactly 0.
    pub zero_fraction: f64,
    /// All samples: 1st percentile, counts.
    pub p1: f64,
    /// All samples: median, counts.
    pub p50: f64,
    /// All samples: 99th percentile, counts.
    pub p99: f64,
    /// Modes of the histogram of all samples (smoothed over 9 counts; a peak counts when it
    /// stands 10 % above the valley to its higher neighbour and holds 1 % of the highest).
    pub histogram_modes: usize,
    /// Bright windows: lag-1 correlation along range, the texture's: per window, after the
    /// window's least-squares plane (its mean and its gradients along range and across beams,
    /// the scene's smooth variation) is removed; median over the bright windows. Independent
    /// samples read about −0.03 (the plane's removal), speckle correlated over the pulse more.
    pub lag1_range: f64,
    /// Bright windows: lag-1 correlation across adjacent beams, as [`Self::lag1_range`].
    pub lag1_beam: f64,
    /// Bright windows: lag-1 correlation along range with only the window mean removed, pooled
    /// over the windows (the definition before 2026-12-06): windows straddling a return's edge
    /// have the largest variance and set it, so it reads the scene's edges more than the
    /// sensor's texture.
    #[serde(default)]
    pub lag1_range_pooled: f64,
    /// Bright windows: the same across adjacent beams, pooled.
    #[serde(default)]
    pub lag1_beam_pooled: f64,
    /// Bright windows: lag-1 correlation across beams of the 16-sample column means (speckle
    /// averaged out: the beam pattern, which crosstalk widens).
    pub lag1_beam_columns: f64,
}

/// Moments of one window.
struct Window {
    mean: f64,
    std: f64,
    skew: f64,
    resid_std: f64,
    resid_skew: f64,
    zeros: usize,
    /// Σ d(s,b)·d(s+1,b), Σ d(s,b)², Σ d(s+1,b)² for range pairs; the same across beams.
    range_pairs: [f64; 3],
    beam_pairs: [f64; 3],
    column_pairs: [f64; 3],
    /// Lag-1 correlations along range and across beams with the window's plane removed.
    lag1_range: f64,
    lag1_beam: f64,
}

/// Σ d·e, Σ d², Σ e² over the lag-1 neighbours along range and across beams of `d(s, b)`.
fn lag1_pairs(d: impl Fn(usize, usize) -> f64) -> ([f64; 3], [f64; 3]) {
    let mut range_pairs = [0.0; 3];
    let mut beam_pairs = [0.0; 3];
    let add = |p: &mut [f64; 3], x: f64, y: f64| {
        p[0] += x * y;
        p[1] += x * x;
        p[2] += y * y;
    };
    for s in 0..WINDOW_SAMPLES {
        for b in 0..WINDOW_BEAMS {
            if s + 1 < WINDOW_SAMPLES {
                add(&mut range_pairs, d(s, b), d(s + 1, b));
            }
            if b + 1 < WINDOW_BEAMS {
                add(&mut beam_pairs, d(s, b), d(s, b + 1));
            }
        }
    }
    (range_pairs, beam_pairs)
}

/// The correlation of summed pairs (0 when either side is flat).
fn correlation(p: &[f64; 3]) -> f64 {
    let den = (p[1] * p[2]).sqrt();
    if den > 0.0 {
        p[0] / den
    } else {
        0.0
    }
}

/// The window's lag-1 correlations along range and across beams after its least-squares plane
/// `mean + gs·(s − s̄) + gb·(b − b̄)` is removed (centred coordinates: the slopes are independent
/// regressions).
fn detrended_lag1(at: impl Fn(usize, usize) -> f64, mean: f64) -> (f64, f64) {
    let sc = (WINDOW_SAMPLES as f64 - 1.0) / 2.0;
    let bc = (WINDOW_BEAMS as f64 - 1.0) / 2.0;
    let (mut gs, mut ss, mut gb, mut sb) = (0.0, 0.0, 0.0, 0.0);
    for s in 0..WINDOW_SAMPLES {
        for b in 0..WINDOW_BEAMS {
            let (u, v, d) = (s as f64 - sc, b as f64 - bc, at(s, b) - mean);
            gs += u * d;
            ss += u * u;
            gb += v * d;
            sb += v * v;
        }
    }
    let (gs, gb) = (gs / ss, gb / sb);
    let (r, b) = lag1_pairs(|s, b| at(s, b) - mean - gs * (s as f64 - sc) - gb * (b as f64 - bc));
    (correlation(&r), correlation(&b))
}

fn window(frame: &FrameRef, s0: usize, b0: usize) -> Window {
    let at = |s: usize, b: usize| frame.data[(s0 + s) * frame.beams + b0 + b] as f64;
    let n = (WINDOW_SAMPLES * WINDOW_BEAMS) as f64;
    let (mut sum, mut zeros) = (0.0, 0);
    for s in 0..WINDOW_SAMPLES {
        for b in 0..WINDOW_BEAMS {
            let v = at(s, b);
            sum += v;
            zeros += usize::from(v == 0.0);
        }
    }
    let mean = sum / n;
    let (mut m2, mut m3) = (0.0, 0.0);
    for s in 0..WINDOW_SAMPLES {
        for b in 0..WINDOW_BEAMS {
            let d = at(s, b) - mean;
            m2 += d * d;
            m3 += d * d * d;
        }
    }
    let (range_pairs, beam_pairs) = lag1_pairs(|s, b| at(s, b) - mean);
    let (lag1_range, lag1_beam) = detrended_lag1(at, mean);
    let (m2, m3) = (m2 / n, m3 / n);
    // Second-difference residuals along range, r = x(s) − (x(s−1) + x(s+1)) / 2: the scene's
    // smooth variation cancels, white speckle keeps 1.5× its variance and 0.75× its third
    // cumulant (skewness × 0.408).
    let (mut r2, mut r3, mut rn) = (0.0, 0.0, 0.0);
    for s in 1..WINDOW_SAMPLES - 1 {
        for b in 0..WINDOW_BEAMS {
            let r = at(s, b) - 0.5 * (at(s - 1, b) + at(s + 1, b));
            r2 += r * r;
            r3 += r * r * r;
            rn += 1.0;
        }
    }
    let (r2, r3) = (r2 / rn, r3 / rn);
    // Column means over the window's samples: speckle averages out, the beam pattern stays.
    let col: Vec<f64> = (0..WINDOW_BEAMS)
        .map(|b| (0..WINDOW_SAMPLES).map(|s| at(s, b)).sum::<f64>() / WINDOW_SAMPLES as f64)
        .collect();
    let mut column_pairs = [0.0; 3];
    for b in 0..WINDOW_BEAMS - 1 {
        let (d, e) = (col[b] - mean, col[b + 1] - mean);
        column_pairs[0] += d * e;
        column_pairs[1] += d * d;
        column_pairs[2] += e * e;
    }
    Window {
        mean,
        std: m2.sqrt(),
        skew: if m2 > 0.0 { m3 / m2.powf(1.5) } else { 0.0 },
        resid_std: (r2 / 1.5).sqrt(),
        resid_skew: if r2 > 0.0 {
            r3 / r2.powf(1.5) / 0.408_248
        } else {
            0.0
        },
        zeros,
        range_pairs,
        beam_pairs,
        column_pairs,
        lag1_range,
        lag1_beam,
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn pooled_correlation<'a>(pairs: impl Iterator<Item = &'a [f64; 3]>) -> f64 {
    let mut t = [0.0; 3];
    for p in pairs {
        for (t, p) in t.iter_mut().zip(p) {
            *t += p;
        }
    }
    correlation(&t)
}

/// Percentile `q` (0..=1) of a histogram of `total` samples: the lowest count reaching it.
fn percentile(hist: &[u64; 256], total: u64, q: f64) -> f64 {
    let want = (q * total as f64).ceil().max(1.0) as u64;
    let mut acc = 0;
    for (v, h) in hist.iter().enumerate() {
        acc += h;
        if acc >= want {
            return v as f64;
        }
    }
    255.0
}

/// Prominent peaks of the histogram (see [`ImageStats::histogram_modes`]).
fn histogram_modes(hist: &[u64; 256]) -> usize {
    // Smoothing over 9 counts: the compression's rounding leaves comb-like gaps otherwise.
    let h: Vec<f64> = (0..256usize)
        .map(|i| {
            let lo = i.saturating_sub(4);
            let hi = (i + 4).min(255);
            hist[lo..=hi].iter().sum::<u64>() as f64 / (hi - lo + 1) as f64
        })
        .collect();
    let top = h.iter().cloned().fold(0.0, f64::max);
    if top <= 0.0 {
        return 0;
    }
    let mut modes = 0;
    for i in 0..256 {
        let left = if i > 0 { h[i - 1] } else { f64::NEG_INFINITY };
        let right = if i < 255 { h[i + 1] } else { f64::NEG_INFINITY };
        if !(h[i] > left && h[i] >= right) || h[i] < 0.01 * top {
            continue;
        }
        // The valley towards the nearest higher ground on each side (none: the edge).
        let valley = |range: &mut dyn Iterator<Item = usize>| -> Option<f64> {
            let mut low = h[i];
            for j in range {
                if h[j] > h[i] {
                    return Some(low);
                }
                low = low.min(h[j]);
            }
            None
        };
        let l = valley(&mut (0..i).rev());
        let r = valley(&mut (i + 1..256));
        let key_valley = match (l, r) {
            (None, None) => 0.0,
            (Some(a), None) | (None, Some(a)) => a,
            (Some(a), Some(b)) => a.max(b),
        };
        if h[i] - key_valley >= 0.1 * h[i] {
            modes += 1;
        }
    }
    modes
}

/// Measures `frames`. Fails on frames that hold fewer than [`MIN_WINDOWS`] windows in all, on a
/// frame whose length is not a whole number of rows, and when the bright windows do not stand
/// above the floor or the floor is mostly clipped to 0 (no level or spread can be read then).
pub fn measure(frames: &[FrameRef]) -> Result<ImageStats> {
    let stats = measure_any(frames)?;
    check_measurable(&stats)?;
    Ok(stats)
}

/// [`measure`] without the checks that the floor and the returns can be read: what a search
/// needs for candidates on the way, whose floor may well be clipped.
pub fn measure_any(frames: &[FrameRef]) -> Result<ImageStats> {
    let mut windows = Vec::new();
    let mut hist = [0u64; 256];
    for (k, f) in frames.iter().enumerate() {
        ensure!(
            f.beams > 0 && f.data.len() % f.beams == 0,
            "frame {k}: {} samples are not a whole number of {}-beam rows",
            f.data.len(),
            f.beams
        );
        for &v in f.data {
            hist[v as usize] += 1;
        }
        let samples = f.data.len() / f.beams;
        for s0 in (0..samples / WINDOW_SAMPLES).map(|i| i * WINDOW_SAMPLES) {
            for b0 in (0..f.beams / WINDOW_BEAMS).map(|i| i * WINDOW_BEAMS) {
                windows.push(window(f, s0, b0));
            }
        }
    }
    ensure!(
        windows.len() >= MIN_WINDOWS,
        "{} frame(s) hold {} windows of {WINDOW_SAMPLES} samples × {WINDOW_BEAMS} beams; \
         the statistics need at least {MIN_WINDOWS}",
        frames.len(),
        windows.len()
    );
    windows.sort_by(|a, b| a.mean.total_cmp(&b.mean));
    let take = ((windows.len() as f64 * SELECTED_SHARE) as usize).max(1);
    let dark = &windows[..take];
    let bright = &windows[windows.len() - take..];
    let med = |w: &[Window], f: fn(&Window) -> f64| median(w.iter().map(f).collect());
    let total: u64 = hist.iter().sum();
    let dark_samples = (dark.len() * WINDOW_SAMPLES * WINDOW_BEAMS) as f64;
    Ok(ImageStats {
        frames: frames.len(),
        windows: windows.len(),
        dark_windows: dark.len(),
        bright_windows: bright.len(),
        bright_mean: med(bright, |w| w.mean),
        bright_std: med(bright, |w| w.std),
        bright_contrast: med(bright, |w| if w.mean > 0.0 { w.std / w.mean } else { 0.0 }),
        bright_skew: med(bright, |w| w.skew),
        speckle_std: med(bright, |w| w.resid_std),
        speckle_skew: med(bright, |w| w.resid_skew),
        dark_mean: med(dark, |w| w.mean),
        dark_std: med(dark, |w| w.std),
        dark_zero_fraction: dark.iter().map(|w| w.zeros).sum::<usize>() as f64 / dark_samples,
        zero_fraction: hist[0] as f64 / total as f64,
        p1: percentile(&hist, total, 0.01),
        p50: percentile(&hist, total, 0.5),
        p99: percentile(&hist, total, 0.99),
        histogram_modes: histogram_modes(&hist),
        lag1_range: med(bright, |w| w.lag1_range),
        lag1_beam: med(bright, |w| w.lag1_beam),
        lag1_range_pooled: pooled_correlation(bright.iter().map(|w| &w.range_pairs)),
        lag1_beam_pooled: pooled_correlation(bright.iter().map(|w| &w.beam_pairs)),
        lag1_beam_columns: pooled_correlation(bright.iter().map(|w| &w.column_pairs)),
    })
}

/// Fails when `stats` cannot describe a sensor: the floor mostly clipped to 0, no windows above
/// the floor, or flat bright windows.
pub fn check_measurable(stats: &ImageStats) -> Result<()> {
    if stats.dark_zero_fraction >= 0.5 {
        bail!(
            "the dark windows read 0 in {:.0} % of their samples: the floor lies below the \
             compression's range, so its level and spread cannot be measured",
            100.0 * stats.dark_zero_fraction
        );
    }
    if stats.bright_mean - stats.dark_mean < (2.0 * stats.dark_std).max(4.0) {
        bail!(
            "no bright windows: the brightest tenth of the windows ({:.1} counts) does not stand \
             above the floor ({:.1} ± {:.1} counts)",
            stats.bright_mean,
            stats.dark_mean,
            stats.dark_std
        );
    }
    if stats.bright_std <= 0.0 {
        bail!("the bright windows are flat (saturated or constant): no speckle to measure");
    }
    Ok(())
}

/// Measures every frame of a recording: an ARIS file, or a ROS 2 bag's ProjectedSonarImage
/// topic `topic` (default: its only one), its native pings (`epssn_ros2::Recording`).
pub fn measure_recording(path: &std::path::Path, topic: Option<&str>) -> Result<ImageStats> {
    use anyhow::Context;
    let options = epssn_ros2::OpenOptions {
        topic: topic.map(str::to_owned),
    };
    let reader = epssn_ros2::Recording::open(path, &options)
        .with_context(|| format!("opening {}", path.display()))?;
    ensure!(
        reader.frame_count() > 0,
        "{}: the recording holds no frames",
        path.display()
    );
    let frames = (0..reader.frame_count())
        .map(|i| reader.frame(i))
        .collect::<Result<Vec<_>, _>>()
        .with_context(|| format!("reading the frames of {}", path.display()))?;
    let refs: Vec<FrameRef> = frames
        .iter()
        .map(|f| FrameRef {
            data: &f.data,
            beams: f.beams,
        })
        .collect();
    measure(&refs).with_context(|| format!("measuring {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::Rng;

    const BEAMS: usize = 64;
    const SAMPLES: usize = 256;

    /// A frame of independent noise (σ 10 counts) around a level that rises by `slope` counts per
    /// sample along range (a scene's gradient, starting again every 64 samples, at a window's
    /// edge), optionally averaged over two neighbours along range (a pulse spanning two samples).
    fn frame(seed: u64, slope: f64, smooth: bool) -> Vec<u8> {
        let mut rng = Rng::new(seed);
        let noise: Vec<f64> = (0..SAMPLES * BEAMS).map(|_| rng.normal(10.0)).collect();
        (0..SAMPLES * BEAMS)
            .map(|i| {
                let s = i / BEAMS;
                let n = if smooth && s + 1 < SAMPLES {
                    (noise[i] + noise[i + BEAMS]) / 2f64.sqrt()
                } else {
                    noise[i]
                };
                (60.0 + slope * (s % 64) as f64 + n).clamp(0.0, 255.0) as u8
            })
            .collect()
    }

    fn stats(slope: f64, smooth: bool) -> ImageStats {
        let frames: Vec<Vec<u8>> = (0..2).map(|k| frame(k, slope, smooth)).collect();
        let refs: Vec<FrameRef> = frames
            .iter()
            .map(|f| FrameRef {
                data: f,
                beams: BEAMS,
            })
            .collect();
        measure_any(&refs).unwrap()
    }

    #[test]
    fn the_lag1_statistics_read_the_texture_not_the_scenes_gradient() {
        // Independent samples: a little below 0 (a window's plane removed from 64 samples, and
        // the median of short-series correlations, both lean negative).
        let flat = stats(0.0, false);
        assert!(
            (-0.12..0.0).contains(&flat.lag1_range),
            "{}",
            flat.lag1_range
        );
        assert!((-0.12..0.0).contains(&flat.lag1_beam), "{}", flat.lag1_beam);
        // A gradient along range of 2 counts per sample (30 per window, three times the noise)
        // leaves them there, while the pooled, mean-removed figure reads the gradient.
        let ramp = stats(2.0, false);
        assert!((ramp.lag1_range - flat.lag1_range).abs() < 0.03);
        assert!((ramp.lag1_beam - flat.lag1_beam).abs() < 0.03);
        assert!(ramp.lag1_range_pooled > flat.lag1_range_pooled + 0.2);
        // Speckle correlated over two samples along range (ρ = 0.5) reads along range only.
        let smooth = stats(0.0, true);
        println!(
            "independent {:.3} / {:.3}, gradient {:.3} / {:.3} (pooled {:.3}), two-sample {:.3} / {:.3}",
            flat.lag1_range,
            flat.lag1_beam,
            ramp.lag1_range,
            ramp.lag1_beam,
            ramp.lag1_range_pooled,
            smooth.lag1_range,
            smooth.lag1_beam
        );
        assert!(smooth.lag1_range > 0.35, "{}", smooth.lag1_range);
        assert!(
            (-0.15..0.0).contains(&smooth.lag1_beam),
            "{}",
            smooth.lag1_beam
        );
    }
}
