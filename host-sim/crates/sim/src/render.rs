//! Acoustic rendering of a scene into one ARIS 3000 frame per view, by ray casting with exact
//! first-hit occlusion.
//!
//! Per beam, `azimuth_subrays × elevation_rays` rays (stratified, jittered) cross the beam's
//! width and the ±7° elevation aperture. Each ray's first hit adds
//! `reflectivity × cos²(incidence) × (r_ref / r)² × 10^(−absorption·(r − r_ref)/10)`
//! to the beam's range profile through a Gaussian pulse kernel, at the hit's range plus a small
//! jitter. The profiles then leak into neighbouring beams (crosstalk), get Rayleigh speckle
//! (exponentially distributed intensity) and a noise floor, and are log-compressed to u8.
//!
//! All randomness comes from ChaCha8 streams seeded by (scene seed, view, beam), so a frame is
//! the same whatever the thread count.

use epssn::config;
use epssn::geometry::{deg_to_rad, direction, rad_to_deg, SampleRanges};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Exp1, Gamma, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

use crate::scene::{mix64, Scene};
use crate::world::World;
use epssn_aris::aris::FrameHeader;

/// Every parameter of the simulated sonar and its image formation.
///
/// Serialised as `<split>/sim_params.json`; `simulate --params FILE` reads one back (fields
/// left out keep their defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SonarSimParams {
    /// Speed of sound, m/s (ARIS header SoundSpeed). Default 1500.
    pub sound_speed_m_s: f64,
    /// Sample period, µs (SamplePeriod). Default 4 µs = 3 mm of range.
    pub sample_period_us: u32,
    /// Delay of sample 0, µs (SampleStartDelay). Default 2660 µs = 1.995 m, just before the
    /// model's 2.0 m window start.
    pub sample_start_delay_us: u32,
    /// Samples per beam. Default 520: up to 3.552 m, past the window's 3.536 m end.
    pub samples_per_beam: usize,
    /// Elevation rays per azimuth sub-ray, stratified over ±half aperture. Default 256.
    pub elevation_rays: usize,
    /// Azimuth sub-rays across each beam's width. Default 3.
    pub azimuth_subrays: usize,
    /// Half elevation aperture, degrees. Default: the model spec's (7°, ARIS 3000 standard lens).
    pub half_elevation_deg: f64,
    /// Absorption, dB per metre of range (ACSim's figure). Default 1.95.
    pub absorption_db_per_m: f64,
    /// Range at which spreading and absorption losses are normalised to 1, metres. Default 2.
    pub reference_range_m: f64,
    /// Standard deviation of the pulse's range spread, samples. Default 1.0.
    pub pulse_sigma_samples: f64,
    /// Standard deviation of the per-ray range jitter, metres. Default 0.0015.
    pub range_jitter_m: f64,
    /// Fraction of a beam's intensity leaking into each adjacent beam. Default 0.08.
    pub crosstalk: f64,
    /// Fraction leaking into beams two apart. Default 0.02.
    pub crosstalk2: f64,
    /// Far side lobes of the beam pattern: every beam also receives this fraction of the fan's
    /// mean intensity at the same range (before crosstalk), as a lens's side lobes let a strong
    /// return leak into every beam. Default 0 (none, as the renderer always did); `host-sim
    /// fit-sensor` fits it with the texture.
    #[serde(skip_serializing_if = "is_zero")]
    pub sidelobe: f64,
    /// Apply Rayleigh speckle (exponential intensity). Default true.
    pub speckle: bool,
    /// Independent speckle looks averaged in intensity before compression: L pings of a
    /// hovering vehicle, whose sub-millimetre motion (the ARIS 3000's wavelength is 0.5 mm)
    /// decorrelates their speckle, averaged per view. The speckle of one pixel then follows
    /// Gamma(L, 1/L) (mean 1, variance 1/L). Default 1 (one ping), which draws exactly what
    /// the simulator drew before the field existed, so older datasets stay byte-identical.
    #[serde(skip_serializing_if = "is_one")]
    pub speckle_looks: u32,
    /// With `speckle_looks` L > 1, each look is a ping of its own, compressed to counts with
    /// its own speckle and noise draw, and the L pings are averaged by the library's
    /// [`epssn::ping_average`] at `dynamic_range_db`: what a host that averages recorded pings
    /// computes, instead of the intensities averaged before compression. The draws are the same
    /// either way. `simulate` then writes the L pings as the frames of each `view<k>.aris`, so
    /// a bundled recording carries every ping (`host-sim run --pings-per-view L` averages them
    /// back). Default false.
    #[serde(skip_serializing_if = "is_false")]
    pub ping_frames: bool,
    /// Mean intensity of the background noise, linear (a beam whose every ray met a
    /// reflectivity-1 surface head-on at the reference range in one sample reads 1). Default 1e-6.
    pub noise_floor: f64,
    /// Independent looks of the noise floor, when it has its own: the floor's intensity then
    /// follows Gamma(N, 1/N) (mean 1, variance 1/N; N need not be whole), drawn after the
    /// speckle's looks. A real receiver's floor is smoother than single-look speckle (the
    /// ARIS 1200 recording's floor reads 53 ± 11 counts with no zeros, the default floor
    /// 26 ± 17 with 2–10 % zeros), and `host-sim fit-sensor` fits N. Default 0: the floor
    /// shares `speckle_looks` and its draws, byte for byte what the simulator drew before the
    /// field existed. Not with `ping_frames` (each ping's floor is one look there).
    #[serde(skip_serializing_if = "is_zero")]
    pub noise_looks: f64,
    /// The floor's slope with range, dB per metre from `reference_range_m`: a receiver's
    /// time-varied gain, which lifts the returns' spreading and absorption losses, lifts its
    /// electronic noise with range as well, so relative to the returns the floor rises. Default
    /// 0 (a floor level at every range, as the renderer always had); `host-sim fit-sensor` fits
    /// it with the texture.
    #[serde(skip_serializing_if = "is_zero")]
    pub noise_floor_db_per_m: f64,
    /// Gain added before compression, dB. Default 70.
    pub gain_db: f64,
    /// dB mapped onto 0..255 (0 dB after gain reads 0). Default 70.
    pub dynamic_range_db: f64,
}

impl Default for SonarSimParams {
    fn default() -> Self {
        Self {
            sound_speed_m_s: 1500.0,
            sample_period_us: 4,
            sample_start_delay_us: 2660,
            samples_per_beam: 520,
            elevation_rays: 256,
            azimuth_subrays: 3,
            half_elevation_deg: rad_to_deg(config::HALF_ELEVATION_RAD),
            absorption_db_per_m: 1.95,
            reference_range_m: 2.0,
            pulse_sigma_samples: 1.0,
            range_jitter_m: 0.0015,
            crosstalk: 0.08,
            crosstalk2: 0.02,
            sidelobe: 0.0,
            speckle: true,
            speckle_looks: 1,
            ping_frames: false,
            noise_floor: 1e-6,
            noise_looks: 0.0,
            noise_floor_db_per_m: 0.0,
            gain_db: 70.0,
            dynamic_range_db: 70.0,
        }
    }
}

fn is_one(v: &u32) -> bool {
    *v == 1
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_false(v: &bool) -> bool {
    !*v
}

impl SonarSimParams {
    /// Range of each recorded sample (the ARIS header's arithmetic).
    pub fn sample_ranges(&self) -> SampleRanges {
        let half_c = self.sound_speed_m_s / 2.0 * 1e-6;
        SampleRanges {
            start: self.sample_start_delay_us as f64 * half_c,
            step: self.sample_period_us as f64 * half_c,
            samples: self.samples_per_beam,
        }
    }
}

/// The ARIS 3000 frame header of a simulated view: the recording geometry of `params` and the
/// view's roll in SonarRoll, TargetRoll and RollAbsPosition.
pub fn frame_header(params: &SonarSimParams, roll_deg: f64) -> anyhow::Result<FrameHeader> {
    frame_header_posed(params, roll_deg, [0.0, 0.0])
}

/// [`frame_header`] with the view's true pose error `[pitch, yaw]` (degrees, docs/POSE.md)
/// written as the platform's Pitch and Heading (the reference view's platform frame is the
/// level frame, so the reference has heading 0 and pitch 0).
pub fn frame_header_posed(
    params: &SonarSimParams,
    roll_deg: f64,
    pose_error_deg: [f64; 2],
) -> anyhow::Result<FrameHeader> {
    let [pitch, yaw] = pose_error_deg;
    Ok(FrameHeader::new_aris3000(
        config::BEAMS,
        params.samples_per_beam,
        params.sample_period_us,
        params.sample_start_delay_us,
        params.sound_speed_m_s as f32,
    )?
    .with_roll_deg(roll_deg as f32)
    .with_platform_attitude_deg(yaw.rem_euclid(360.0) as f32, pitch as f32, 0.0))
}

/// Beam centres of the ARIS3000_128 table, radians, beam 0 (right-most) first.
pub fn beam_centres_rad() -> Vec<f64> {
    config::BEAM_CENTRES_DEG
        .iter()
        .map(|d| deg_to_rad(*d))
        .collect()
}

/// Half width of beam `b`: half the spacing to its neighbours.
fn beam_half_width(c: &[f64], b: usize) -> f64 {
    let n = c.len();
    let lo = if b > 0 { c[b - 1] } else { 2.0 * c[0] - c[1] };
    let hi = if b + 1 < n {
        c[b + 1]
    } else {
        2.0 * c[n - 1] - c[n - 2]
    };
    (hi - lo) / 4.0
}

/// A rendered view: the frame and, for the reference view, what the elevation map needs.
#[derive(Clone, Debug)]
pub struct RenderedView {
    /// `samples[sample × beams + beam]`, as stored in an ARIS frame.
    pub samples: Vec<u8>,
    /// With `ping_frames`: the L pings that `samples` averages, each laid out like `samples`
    /// (what a sonar would record, one frame per ping); empty otherwise.
    pub pings: Vec<Vec<u8>>,
    /// Per beam and range sample: Σ w (noiseless linear contributions).
    pub weight: Vec<f64>,
    /// Per beam and range sample: Σ w · elevation (radians, in this view's frame).
    pub weighted_elevation: Vec<f64>,
}

/// One beam's noiseless accumulation.
struct BeamProfile {
    intensity: Vec<f64>,
    weight: Vec<f64>,
    weighted_elevation: Vec<f64>,
    /// Every ray's return, kept so that [`form_image`] can deposit them again with another
    /// pulse than the tracing's (the sensor fit's candidates).
    hits: Vec<RayHit>,
}

/// One ray's return: where it lands in range and what it weighs before the pulse.
#[derive(Clone, Copy, Debug)]
struct RayHit {
    /// Range in samples (jittered), fractional.
    sample: f64,
    /// Linear weight (reflectivity, incidence, spreading, absorption, ray share).
    weight: f64,
}

/// Adds `w` spread by a Gaussian pulse of `sigma` samples centred on sample `s` to `profile`:
/// the one deposit rule of tracing and re-forming.
fn deposit(profile: &mut [f64], s: f64, w: f64, sigma: f64) {
    let ns = profile.len() as i64;
    let reach = (3.0 * sigma).ceil() as i64;
    let centre = s.round() as i64;
    for i in (centre - reach)..=(centre + reach) {
        if i < 0 || i >= ns {
            continue;
        }
        let z = (i as f64 - s) / sigma;
        profile[i as usize] += w * (-0.5 * z * z).exp();
    }
}

/// Renders view `k` of `scene` (whose ray-casting form is `world`).
pub fn render_view(
    scene: &Scene,
    world: &World,
    view: usize,
    params: &SonarSimParams,
) -> RenderedView {
    form_image(&trace_view(scene, world, view, params), params)
}

/// A view's noiseless beam profiles: what the ray casting produced, before crosstalk, speckle,
/// noise and compression. [`form_image`] turns it into a frame; the sensor fit
/// (`crate::sensor_fit`) forms many frames from one tracing, since only the image formation's
/// parameters change between its candidates.
pub struct TracedView {
    profiles: Vec<BeamProfile>,
    view_seed: u64,
    /// The pulse `profiles` were deposited with.
    pulse_sigma_samples: f64,
}

/// Ray-casts view `k` of `scene` (whose ray-casting form is `world`): the expensive half of
/// [`render_view`]. Reads only the geometry and ray fields of `params`.
pub fn trace_view(
    scene: &Scene,
    world: &World,
    view: usize,
    params: &SonarSimParams,
) -> TracedView {
    let centres = beam_centres_rad();
    let beams = centres.len();
    let ranges = params.sample_ranges();
    let ns = ranges.samples;
    let wfv = scene.world_from_view(view);
    let origin = wfv.translation;
    let half_el = deg_to_rad(params.half_elevation_deg);
    let nel = params.elevation_rays.max(1);
    let naz = params.azimuth_subrays.max(1);
    // Each beam's rays share unit weight, so brightness does not depend on the ray count.
    let ray_weight = 1.0 / (naz * nel) as f64;
    let sigma = params.pulse_sigma_samples.max(1e-3);
    let view_seed = mix64(scene.sample_seed ^ mix64(view as u64 + 1));

    let profiles: Vec<BeamProfile> = (0..beams)
        .into_par_iter()
        .map(|b| {
            let mut rng = ChaCha8Rng::seed_from_u64(mix64(view_seed ^ ((b as u64) << 1)));
            let mut p = BeamProfile {
                intensity: vec![0.0; ns],
                weight: vec![0.0; ns],
                weighted_elevation: vec![0.0; ns],
                hits: Vec::with_capacity(naz * nel),
            };
            let hw = beam_half_width(&centres, b);
            for sa in 0..naz {
                for se in 0..nel {
                    let az =
                        centres[b] - hw + 2.0 * hw * (sa as f64 + rng.random::<f64>()) / naz as f64;
                    let el =
                        -half_el + 2.0 * half_el * (se as f64 + rng.random::<f64>()) / nel as f64;
                    let d = wfv.rotate(direction(az, el));
                    let jitter: f64 = rng.sample(StandardNormal);
                    let Some(hit) = world.first_hit(origin, d) else {
                        continue;
                    };
                    let cos_inc =
                        (d[0] * hit.normal[0] + d[1] * hit.normal[1] + d[2] * hit.normal[2]).abs();
                    let r = hit.t + params.range_jitter_m * jitter;
                    let spread = (params.reference_range_m / r).powi(2);
                    let absorb = 10f64
                        .powf(-params.absorption_db_per_m * (r - params.reference_range_m) / 10.0);
                    let w = ray_weight * hit.reflectivity * cos_inc * cos_inc * spread * absorb;
                    let s = (r - ranges.start) / ranges.step;
                    p.hits.push(RayHit {
                        sample: s,
                        weight: w,
                    });
                    deposit(&mut p.intensity, s, w, sigma);
                    // The elevation map bins the exact (jitter-free) range.
                    let se_exact = ((hit.t - ranges.start) / ranges.step).round();
                    if se_exact >= 0.0 && (se_exact as usize) < ns {
                        let i = se_exact as usize;
                        p.weight[i] += w;
                        p.weighted_elevation[i] += w * el;
                    }
                }
            }
            p
        })
        .collect();
    TracedView {
        profiles,
        view_seed,
        pulse_sigma_samples: params.pulse_sigma_samples,
    }
}

/// The beams' intensity profiles with `params`' pulse: the traced ones when it is the
/// tracing's, else the rays deposited again (what the sensor fit's pulse candidates need).
fn intensities<'a>(traced: &'a TracedView, params: &SonarSimParams) -> Vec<Cow<'a, [f64]>> {
    let same = params.pulse_sigma_samples == traced.pulse_sigma_samples;
    let sigma = params.pulse_sigma_samples.max(1e-3);
    traced
        .profiles
        .par_iter()
        .map(|p| {
            if same {
                return Cow::Borrowed(p.intensity.as_slice());
            }
            let mut v = vec![0.0; p.intensity.len()];
            for h in &p.hits {
                deposit(&mut v, h.sample, h.weight, sigma);
            }
            Cow::Owned(v)
        })
        .collect()
}

/// The image formation half of [`render_view`]: crosstalk, speckle, noise floor and log
/// compression of a traced view, with the noise streams seeded by the view as before.
pub fn form_image(traced: &TracedView, params: &SonarSimParams) -> RenderedView {
    let profiles = &traced.profiles;
    let view_seed = traced.view_seed;
    let beams = profiles.len();
    // The traced length, not `params`: a caller forming with other geometry cannot index past it.
    let ns = profiles.first().map_or(0, |p| p.intensity.len());
    // The pulse is `params`' own (the fit's candidates form with other pulses than traced).
    let intensity = intensities(traced, params);
    let floor = noise_floor_profile(params, ns);
    // The fan's mean at each range, for the far side lobes (none by default).
    let fan_mean: Vec<f64> = if params.sidelobe > 0.0 {
        (0..ns)
            .map(|s| intensity.iter().map(|p| p[s]).sum::<f64>() / beams as f64)
            .collect()
    } else {
        Vec::new()
    };
    // Crosstalk, speckle, noise and log compression, beam by beam.
    let (c1, c2) = (params.crosstalk, params.crosstalk2);
    let looks = params.speckle_looks.max(1);
    let compress = |total: f64| -> u8 {
        let db = 10.0 * total.max(1e-30).log10() + params.gain_db;
        (255.0 * db / params.dynamic_range_db)
            .round()
            .clamp(0.0, 255.0) as u8
    };
    // Pings averaged as the host would average recorded frames (`ping_frames`).
    // (`simulate` refuses a dynamic range the table cannot take before rendering.)
    let ping_table = (params.ping_frames && params.speckle && looks > 1)
        .then(|| epssn::ping_average::IntensityTable::new(params.dynamic_range_db as f32).ok())
        .flatten();
    // Pings recorded one by one only when they are averaged as frames.
    let recorded_pings = if ping_table.is_some() {
        looks as usize
    } else {
        0
    };
    // A floor with looks of its own (`noise_looks`): Gamma(N, 1/N), mean 1. Without the field
    // the floor shares the speckle's looks and draws, as it always did.
    let noise_gamma = (params.noise_looks > 0.0)
        .then(|| Gamma::new(params.noise_looks, 1.0 / params.noise_looks).ok())
        .flatten();
    let columns: Vec<(Vec<u8>, Vec<Vec<u8>>)> = (0..beams)
        .into_par_iter()
        .map(|b| {
            let mut rng = ChaCha8Rng::seed_from_u64(mix64(view_seed ^ (((b as u64) << 1) | 1)));
            let get = |j: i64| -> Option<&[f64]> {
                (j >= 0 && (j as usize) < beams).then(|| &*intensity[j as usize])
            };
            let bi = b as i64;
            let mut out = vec![0u8; ns];
            let mut pings = vec![vec![0u8; ns]; recorded_pings];
            for (s, o) in out.iter_mut().enumerate() {
                let mut v = (1.0 - 2.0 * c1 - 2.0 * c2) * intensity[b][s];
                for (off, c) in [(1, c1), (2, c2)] {
                    v += c * get(bi - off).map_or(0.0, |p| p[s]);
                    v += c * get(bi + off).map_or(0.0, |p| p[s]);
                }
                if let Some(m) = fan_mean.get(s) {
                    v += params.sidelobe * m;
                }
                if let Some(table) = &ping_table {
                    let mut sum = 0f32;
                    for ping in pings.iter_mut() {
                        let e1 = rng.sample::<f64, _>(Exp1);
                        let e2 = rng.sample::<f64, _>(Exp1);
                        ping[s] = compress(v * e1 + floor[s] * e2);
                        sum += table.intensity(ping[s]);
                    }
                    *o = table.count(sum / looks as f32);
                    continue;
                }
                let (e1, e2): (f64, f64) = if params.speckle {
                    let (mut e1, mut e2) = (0.0, 0.0);
                    for _ in 0..looks {
                        e1 += rng.sample::<f64, _>(Exp1);
                        if noise_gamma.is_none() {
                            e2 += rng.sample::<f64, _>(Exp1);
                        }
                    }
                    match &noise_gamma {
                        Some(g) => (e1 / looks as f64, rng.sample::<f64, _>(g)),
                        None => (e1 / looks as f64, e2 / looks as f64),
                    }
                } else {
                    (1.0, 1.0)
                };
                *o = compress(v * e1 + floor[s] * e2);
            }
            (out, pings)
        })
        .collect();

    interleave(&columns, profiles, ns, recorded_pings)
}

/// The noise floor at each of `ns` samples: level everywhere unless it has a slope with range.
fn noise_floor_profile(params: &SonarSimParams, ns: usize) -> Vec<f64> {
    if params.noise_floor_db_per_m == 0.0 {
        return vec![params.noise_floor; ns];
    }
    let ranges = params.sample_ranges();
    (0..ns)
        .map(|s| {
            let r = ranges.start + ranges.step * s as f64;
            let db = params.noise_floor_db_per_m * (r - params.reference_range_m);
            params.noise_floor * 10f64.powf(db / 10.0)
        })
        .collect()
}

/// The formed beams' columns (and their recorded pings) laid out range-major as a frame, with
/// the traced weights beside them.
fn interleave(
    columns: &[(Vec<u8>, Vec<Vec<u8>>)],
    profiles: &[BeamProfile],
    ns: usize,
    recorded_pings: usize,
) -> RenderedView {
    let beams = columns.len();
    let mut samples = vec![0u8; ns * beams];
    let mut weight = vec![0.0; ns * beams];
    let mut weighted_elevation = vec![0.0; ns * beams];
    let mut pings = vec![vec![0u8; ns * beams]; recorded_pings];
    for b in 0..beams {
        for s in 0..ns {
            samples[s * beams + b] = columns[b].0[s];
            for (ping, column) in pings.iter_mut().zip(&columns[b].1) {
                ping[s * beams + b] = column[s];
            }
            weight[s * beams + b] = profiles[b].weight[s];
            weighted_elevation[s * beams + b] = profiles[b].weighted_elevation[s];
        }
    }
    RenderedView {
        samples,
        pings,
        weight,
        weighted_elevation,
    }
}
