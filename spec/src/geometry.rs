//! Sonar geometry: the single source of truth for every part of epssn.
//!
//! The simulator, the float model, the quantiser, the build-time warp tables of the firmware
//! (`build.rs` compiles this very file) and the point-cloud export all use these functions.
//! Everything is `f64`, `no_std`, allocation-free, and depends only on `libm`.
//!
//! # Axes and angles
//!
//! The sonar frame is right-handed: **x forward** (along the acoustic axis), **y left**, **z up**.
//! A point at range `r`, azimuth `θ` and elevation `φ` is
//!
//! ```text
//! x = r cos φ cos θ,   y = r cos φ sin θ,   z = r sin φ
//! ```
//!
//! Azimuth is positive to the left, so ARIS beam 0 (the right-most beam, whose table angle is
//! negative) has negative θ. Elevation is positive upwards. Angles in the public API are
//! radians unless a name ends in `_deg`.
//!
//! # The roll baseline
//!
//! The source view is the reference sonar rolled by `+ρ` about its own forward (x) axis, by
//! the right-hand rule (the left side of the fan goes up). A point fixed in the world has
//! coordinates `p_src = R_x(−ρ) · p_ref` in the source frame: [`RigidTransform::roll_deg`]
//! builds exactly that reference→source map. A lever arm between the rotator axis and the
//! acoustic centre adds a translation; [`RigidTransform::rolled_about_axis`] builds it.

use libm::{asin, atan2, cos, floor, sin, sqrt};

/// Degrees to radians.
pub fn deg_to_rad(deg: f64) -> f64 {
    deg * core::f64::consts::PI / 180.0
}

/// Radians to degrees.
pub fn rad_to_deg(rad: f64) -> f64 {
    rad * 180.0 / core::f64::consts::PI
}

/// A point in polar sonar coordinates (metres, radians).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Polar {
    /// Slant range, metres.
    pub range: f64,
    /// Azimuth θ, radians, positive to the left.
    pub azimuth: f64,
    /// Elevation φ, radians, positive up.
    pub elevation: f64,
}

/// Polar → Cartesian in the sonar frame (x forward, y left, z up).
pub fn polar_to_cartesian(p: Polar) -> [f64; 3] {
    let ce = cos(p.elevation);
    [
        p.range * ce * cos(p.azimuth),
        p.range * ce * sin(p.azimuth),
        p.range * sin(p.elevation),
    ]
}

/// Cartesian → polar in the sonar frame. The origin maps to range 0, angles 0.
pub fn cartesian_to_polar(v: [f64; 3]) -> Polar {
    let range = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if range == 0.0 {
        return Polar {
            range: 0.0,
            azimuth: 0.0,
            elevation: 0.0,
        };
    }
    let s = (v[2] / range).clamp(-1.0, 1.0);
    Polar {
        range,
        azimuth: atan2(v[1], v[0]),
        elevation: asin(s),
    }
}

/// Unit direction of the ray at azimuth θ and elevation φ.
pub fn direction(azimuth: f64, elevation: f64) -> [f64; 3] {
    polar_to_cartesian(Polar {
        range: 1.0,
        azimuth,
        elevation,
    })
}

/// A rigid transform `p' = R p + t` between two sonar frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidTransform {
    /// Row-major rotation matrix.
    pub rotation: [[f64; 3]; 3],
    /// Translation, metres.
    pub translation: [f64; 3],
}

impl RigidTransform {
    /// The identity transform.
    pub const IDENTITY: Self = Self {
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0; 3],
    };

    /// The rotation of a quaternion `[w, x, y, z]` (normalised in f64: the link's values are
    /// kept as sent, up to 2 % off unit norm), then `translation_m`.
    pub fn from_quaternion(q: [f32; 4], translation_m: [f64; 3]) -> Self {
        let [w, x, y, z] = q.map(f64::from);
        let n = sqrt(w * w + x * x + y * y + z * z);
        let [w, x, y, z] = [w / n, x / n, y / n, z / n];
        Self {
            rotation: [
                [
                    1.0 - 2.0 * (y * y + z * z),
                    2.0 * (x * y - w * z),
                    2.0 * (x * z + w * y),
                ],
                [
                    2.0 * (x * y + w * z),
                    1.0 - 2.0 * (x * x + z * z),
                    2.0 * (y * z - w * x),
                ],
                [
                    2.0 * (x * z - w * y),
                    2.0 * (y * z + w * x),
                    1.0 - 2.0 * (x * x + y * y),
                ],
            ],
            translation: translation_m,
        }
    }

    /// Reference → source map for a sonar rolled by `roll_deg` about its own forward axis
    /// through the acoustic centre: `p_src = R_x(−roll) p_ref`.
    pub fn roll_deg(roll_deg: f64) -> Self {
        let a = -deg_to_rad(roll_deg);
        let (s, c) = (sin(a), cos(a));
        Self {
            rotation: [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
            translation: [0.0; 3],
        }
    }

    /// Reference → source map for a sonar rolled by `roll_deg` about an axis parallel to its
    /// forward axis that passes through `axis_point_m` (in the reference frame): the lever
    /// arm between a rotator and the acoustic centre. With the axis through the origin this is
    /// [`RigidTransform::roll_deg`].
    pub fn rolled_about_axis(roll_deg: f64, axis_point_m: [f64; 3]) -> Self {
        let r = Self::roll_deg(roll_deg);
        // p_src = R (p − a) + a, since the acoustic centre moves around the axis.
        let ra = r.rotate(axis_point_m);
        Self {
            rotation: r.rotation,
            translation: [
                axis_point_m[0] - ra[0],
                axis_point_m[1] - ra[1],
                axis_point_m[2] - ra[2],
            ],
        }
    }

    /// Rotation part applied to a vector.
    pub fn rotate(&self, v: [f64; 3]) -> [f64; 3] {
        let m = &self.rotation;
        [
            m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
            m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
        ]
    }

    /// Applies the transform to a point.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotate(p);
        [
            r[0] + self.translation[0],
            r[1] + self.translation[1],
            r[2] + self.translation[2],
        ]
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Self {
        let m = &self.rotation;
        let rt = [
            [m[0][0], m[1][0], m[2][0]],
            [m[0][1], m[1][1], m[2][1]],
            [m[0][2], m[1][2], m[2][2]],
        ];
        let inv = Self {
            rotation: rt,
            translation: [0.0; 3],
        };
        let t = inv.rotate(self.translation);
        Self {
            rotation: rt,
            translation: [-t[0], -t[1], -t[2]],
        }
    }

    /// `self ∘ other`: first `other`, then `self`.
    pub fn compose(&self, other: &Self) -> Self {
        let a = &self.rotation;
        let b = &other.rotation;
        let mut rot = [[0.0; 3]; 3];
        for (i, row) in rot.iter_mut().enumerate() {
            for (j, cell) in row.iter_mut().enumerate() {
                *cell = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
            }
        }
        let t = self.apply(other.translation);
        Self {
            rotation: rot,
            translation: t,
        }
    }

    /// True when the transform preserves range from the origin (no translation), so a warp
    /// depends on direction only.
    pub fn preserves_range(&self) -> bool {
        self.translation.iter().all(|t| t.abs() < 1e-12)
    }
}

/// Index of the last element of ascending `xs` that is `<= x`, with the fraction to the next
/// one: the fractional index of `x` in `xs`. `None` outside `[xs[0], xs[n−1]]` or for fewer
/// than two points. The result's integer part is at most `n − 2`, its fraction in `[0, 1]`.
pub fn fractional_index(xs: &[f64], x: f64) -> Option<(usize, f64)> {
    let n = xs.len();
    if n < 2 || x.is_nan() || x < xs[0] || x > xs[n - 1] {
        return None;
    }
    // Binary search for the segment [xs[i], xs[i+1]] holding x.
    let (mut lo, mut hi) = (0usize, n - 1);
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if xs[mid] <= x {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let span = xs[lo + 1] - xs[lo];
    let frac = if span > 0.0 { (x - xs[lo]) / span } else { 0.0 };
    Some((lo, frac.clamp(0.0, 1.0)))
}

/// Linear interpolation of ascending `xs` ↦ `ys` at fractional position `(i, f)`.
pub fn lerp_at(ys: &[f64], at: (usize, f64)) -> f64 {
    let (i, f) = at;
    if i + 1 >= ys.len() {
        return ys[ys.len() - 1];
    }
    ys[i] * (1.0 - f) + ys[i + 1] * f
}

/// The model's polar grids, derived from the model spec.
///
/// All angle lists are ascending (right-most column first, as ARIS beam 0).
#[derive(Clone, Copy, Debug)]
pub struct Grid<'a> {
    /// Start of the range window, metres.
    pub r_min: f64,
    /// End of the range window, metres.
    pub r_max: f64,
    /// Half the elevation aperture, radians.
    pub half_elevation: f64,
    /// Input beam-column centres (B of them), radians.
    pub column_azimuths: &'a [f64],
}

impl Grid<'_> {
    /// Number of input range bins R is the caller's choice; centre of bin `i` of `bins`.
    pub fn range_bin_centre(&self, i: usize, bins: usize) -> f64 {
        self.r_min + (self.r_max - self.r_min) * (i as f64 + 0.5) / bins as f64
    }

    /// The range value of output bin `i` of `bins` for soft-argmax: evenly spaced with both
    /// ends included, so a ray that meets nothing can read exactly `r_max`.
    pub fn depth_bin_value(&self, i: usize, bins: usize) -> f64 {
        if bins < 2 {
            return self.r_max;
        }
        self.r_min + (self.r_max - self.r_min) * i as f64 / (bins - 1) as f64
    }

    /// The range that soft-argmax bin `i` of `bins` stands for when the end bins reach
    /// `offset` steps beyond the window (`OutputSpec::end_bin_offset`): the first bin
    /// `r_min − offset·step`, the last `r_max + offset·step`, the others
    /// [`depth_bin_value`](Self::depth_bin_value).
    pub fn depth_bin_weight(&self, i: usize, bins: usize, offset: u16) -> f64 {
        let v = self.depth_bin_value(i, bins);
        if bins < 2 {
            return v;
        }
        let reach = offset as f64 * (self.r_max - self.r_min) / (bins - 1) as f64;
        if i == 0 {
            v - reach
        } else if i == bins - 1 {
            v + reach
        } else {
            v
        }
    }

    /// Elevation of plane (or output row) `j` of `n`, evenly spaced over the aperture with
    /// both ends included (the paper's eq. 3); index 0 is the lowest.
    pub fn elevation(&self, j: usize, n: usize) -> f64 {
        if n < 2 {
            return 0.0;
        }
        -self.half_elevation + 2.0 * self.half_elevation * j as f64 / (n - 1) as f64
    }
}

/// Centre azimuth of input column `k` when every input column averages `group` adjacent beams
/// of the sonar's table (`beam_centres_rad`, ascending): the mean of their centres.
pub fn grouped_azimuth(beam_centres_rad: &[f64], group: usize, k: usize) -> f64 {
    let lo = k * group;
    let hi = (lo + group).min(beam_centres_rad.len());
    if lo >= hi {
        return 0.0;
    }
    beam_centres_rad[lo..hi].iter().sum::<f64>() / (hi - lo) as f64
}

/// Range geometry of a recorded frame: sample `i` lies at `start + step · i` metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleRanges {
    /// Range of sample 0, metres.
    pub start: f64,
    /// Range step between samples, metres.
    pub step: f64,
    /// Samples per beam.
    pub samples: usize,
}

/// Error from [`resample_to_grid`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResampleError {
    /// `samples.len()` is not `samples_per_beam × beams`.
    SampleCount,
    /// The output slice is not `range_bins × columns`.
    OutputSize,
    /// Fewer than two beams, or a non-ascending beam table.
    BeamTable,
    /// The frame's range step is not positive.
    RangeStep,
}

/// Resamples one frame (`samples[sample × beams + beam]`, beam centres ascending) onto the
/// model's polar input grid: `out[i × columns + k]` for range bin `i` over
/// `[r_min, r_max)` and input column `k` at `column_azimuths[k]`.
///
/// Along range each output bin is the mean of the samples whose range lies inside the bin
/// (a box filter: with 3 mm samples and 6 mm bins, two samples), or the linear interpolation
/// at the bin centre when no sample falls inside. Across beams the value is interpolated
/// linearly in angle through the sonar's beam table, never a linear fan: at the midpoint of
/// two adjacent beams' centres that is the mean of the two, which is exactly the reference
/// configuration's "pairs of beams averaged". Cells outside the recorded window or beyond the
/// outermost beam centres read 0. Values are rounded half up to u8.
pub fn resample_to_grid(
    samples: &[u8],
    ranges: SampleRanges,
    beam_centres_rad: &[f64],
    grid: &Grid<'_>,
    range_bins: usize,
    out: &mut [u8],
) -> Result<(), ResampleError> {
    let beams = beam_centres_rad.len();
    let columns = grid.column_azimuths.len();
    if beams < 2 || beam_centres_rad.windows(2).any(|w| w[1] <= w[0]) {
        return Err(ResampleError::BeamTable);
    }
    if samples.len() != ranges.samples * beams {
        return Err(ResampleError::SampleCount);
    }
    if out.len() != range_bins * columns {
        return Err(ResampleError::OutputSize);
    }
    if ranges.step.is_nan() || ranges.step <= 0.0 {
        return Err(ResampleError::RangeStep);
    }
    let bin = (grid.r_max - grid.r_min) / range_bins as f64;
    // Tolerance so that a sample exactly on a bin edge is not lost to rounding.
    let eps = ranges.step * 1e-6;
    for i in 0..range_bins {
        let lo = grid.r_min + bin * i as f64;
        let hi = lo + bin;
        // Sample indices whose range is in [lo, hi).
        let first = ceil_index((lo - eps - ranges.start) / ranges.step);
        let last = ceil_index((hi - eps - ranges.start) / ranges.step); // exclusive
        let first = first.clamp(0, ranges.samples as i64) as usize;
        let last = last.clamp(0, ranges.samples as i64) as usize;
        for k in 0..columns {
            let slot = &mut out[i * columns + k];
            let Some(at) = fractional_index(beam_centres_rad, grid.column_azimuths[k]) else {
                *slot = 0;
                continue;
            };
            let across = |s: usize| -> f64 {
                let a = samples[s * beams + at.0] as f64;
                let b = samples[s * beams + (at.0 + 1).min(beams - 1)] as f64;
                a * (1.0 - at.1) + b * at.1
            };
            let value = if last > first {
                (first..last).map(across).sum::<f64>() / (last - first) as f64
            } else {
                let centre = (lo + hi) / 2.0;
                let pos = (centre - ranges.start) / ranges.step;
                if pos < 0.0 || pos > (ranges.samples - 1) as f64 {
                    0.0
                } else {
                    let s0 = floor(pos) as usize;
                    let s1 = (s0 + 1).min(ranges.samples - 1);
                    let f = pos - s0 as f64;
                    across(s0) * (1.0 - f) + across(s1) * f
                }
            };
            *slot = floor(value + 0.5).clamp(0.0, 255.0) as u8;
        }
    }
    Ok(())
}

fn ceil_index(x: f64) -> i64 {
    let f = floor(x);
    let c = if f < x { f + 1.0 } else { f };
    c.clamp(-1.0e15, 1.0e15) as i64
}

/// One entry of the range-independent warp table for a pure roll: where the reference ray of
/// plane `j`, feature column `b` lands in the source view's feature columns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct WarpEntry {
    /// Left source column of the bilinear pair (the right one is `column + 1`).
    pub column: u8,
    /// Weight of the right column, in `0 ..= 1 << fraction_bits`.
    pub fraction: u16,
    /// The rotated ray lies inside the source's azimuth and elevation aperture.
    pub visible: bool,
}

/// Where a reference ray `(azimuth, elevation)` appears in the source view after `transform`
/// (which must preserve range): the source azimuth and elevation, radians.
pub fn warp_direction(transform: &RigidTransform, azimuth: f64, elevation: f64) -> (f64, f64) {
    let p = cartesian_to_polar(transform.rotate(direction(azimuth, elevation)));
    (p.azimuth, p.elevation)
}

/// Quantises a fraction in [0, 1] to `fraction_bits` bits, rounding half up.
pub fn quantise_fraction(f: f64, fraction_bits: u32) -> u16 {
    let one = (1u32 << fraction_bits) as f64;
    floor(f.clamp(0.0, 1.0) * one + 0.5) as u16
}

/// Error from the warp-table generators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WarpError {
    /// The output slice does not have `planes × columns` (or `planes × ranges × columns`) entries.
    OutputSize,
    /// A pure-roll table was asked for a transform that changes range.
    NotRangePreserving,
    /// Fewer than two feature columns, more than 256, or fraction bits outside 1..=15.
    Shape,
}

/// Generates the range-independent warp table for a range-preserving `transform`
/// (reference → source): `out[j × columns + b]` for plane `j` at elevation
/// `plane_elevations[j]` and feature column `b` at `feature_azimuths[b]` (ascending).
///
/// An entry is visible when the rotated ray's elevation is within ±`half_elevation` and its
/// azimuth lies between the outermost feature-column centres (so both bilinear neighbours
/// exist).
pub fn warp_table_pure_roll(
    transform: &RigidTransform,
    feature_azimuths: &[f64],
    plane_elevations: &[f64],
    half_elevation: f64,
    fraction_bits: u32,
    out: &mut [WarpEntry],
) -> Result<(), WarpError> {
    let columns = feature_azimuths.len();
    if !transform.preserves_range() {
        return Err(WarpError::NotRangePreserving);
    }
    if !(2..=256).contains(&columns) || !(1..=15).contains(&fraction_bits) {
        return Err(WarpError::Shape);
    }
    if out.len() != plane_elevations.len() * columns {
        return Err(WarpError::OutputSize);
    }
    for (j, &phi) in plane_elevations.iter().enumerate() {
        for (b, &theta) in feature_azimuths.iter().enumerate() {
            let (az, el) = warp_direction(transform, theta, phi);
            let entry = &mut out[j * columns + b];
            *entry = WarpEntry::default();
            if el.abs() > half_elevation + 1e-12 {
                continue;
            }
            if let Some((col, frac)) = fractional_index(feature_azimuths, az) {
                *entry = WarpEntry {
                    column: col as u8,
                    fraction: quantise_fraction(frac, fraction_bits),
                    visible: true,
                };
            }
        }
    }
    Ok(())
}

/// One entry of the general (range-dependent) warp table: bilinear in range and column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct WarpEntry2d {
    /// Lower source range bin of the bilinear quad.
    pub range_bin: u16,
    /// Weight of the upper range bin, in `0 ..= 1 << fraction_bits`.
    pub range_fraction: u16,
    /// Left source column of the bilinear quad.
    pub column: u8,
    /// Weight of the right column, in `0 ..= 1 << fraction_bits`.
    pub fraction: u16,
    /// The transformed point lies inside the source's range window and apertures.
    pub visible: bool,
}

/// Generates the general warp table for any rigid `transform` (reference → source), such as a
/// roll about an axis offset from the acoustic centre: `out[(j × ranges + i) × columns + b]`
/// for plane `j`, feature range bin `i` at `feature_ranges[i]` (ascending) and feature column
/// `b`. For a range-preserving transform every range bin maps to itself with fraction 0 and
/// the column entries equal [`warp_table_pure_roll`]'s.
pub fn warp_table_general(
    transform: &RigidTransform,
    feature_azimuths: &[f64],
    feature_ranges: &[f64],
    plane_elevations: &[f64],
    half_elevation: f64,
    fraction_bits: u32,
    out: &mut [WarpEntry2d],
) -> Result<(), WarpError> {
    let columns = feature_azimuths.len();
    let ranges = feature_ranges.len();
    if !(2..=256).contains(&columns) || ranges < 2 || !(1..=15).contains(&fraction_bits) {
        return Err(WarpError::Shape);
    }
    if out.len() != plane_elevations.len() * ranges * columns {
        return Err(WarpError::OutputSize);
    }
    for (j, &phi) in plane_elevations.iter().enumerate() {
        for (i, &r) in feature_ranges.iter().enumerate() {
            for (b, &theta) in feature_azimuths.iter().enumerate() {
                let p = transform.apply(polar_to_cartesian(Polar {
                    range: r,
                    azimuth: theta,
                    elevation: phi,
                }));
                let q = cartesian_to_polar(p);
                let entry = &mut out[(j * ranges + i) * columns + b];
                *entry = WarpEntry2d::default();
                if q.elevation.abs() > half_elevation + 1e-12 {
                    continue;
                }
                let (Some((col, cf)), Some((rb, rf))) = (
                    fractional_index(feature_azimuths, q.azimuth),
                    fractional_index(feature_ranges, snap(q.range, r)),
                ) else {
                    continue;
                };
                *entry = WarpEntry2d {
                    range_bin: rb as u16,
                    range_fraction: quantise_fraction(rf, fraction_bits),
                    column: col as u8,
                    fraction: quantise_fraction(cf, fraction_bits),
                    visible: true,
                };
            }
        }
    }
    Ok(())
}

/// Rounding noise of a rotation must not move a range that is preserved off its bin.
fn snap(range: f64, original: f64) -> f64 {
    if (range - original).abs() < 1e-12 * original.abs().max(1.0) {
        original
    } else {
        range
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polar_round_trip() {
        for &(r, a, e) in &[(2.5, 0.1, -0.05), (3.0, -0.26, 0.12), (2.0, 0.0, 0.0)] {
            let p = Polar {
                range: r,
                azimuth: a,
                elevation: e,
            };
            let q = cartesian_to_polar(polar_to_cartesian(p));
            assert!((q.range - r).abs() < 1e-12);
            assert!((q.azimuth - a).abs() < 1e-12);
            assert!((q.elevation - e).abs() < 1e-12);
        }
    }

    #[test]
    fn axes_are_forward_left_up() {
        let p = polar_to_cartesian(Polar {
            range: 1.0,
            azimuth: deg_to_rad(90.0),
            elevation: 0.0,
        });
        assert!(p[1] > 0.999, "positive azimuth is to the left (+y)");
        let up = polar_to_cartesian(Polar {
            range: 1.0,
            azimuth: 0.0,
            elevation: deg_to_rad(90.0),
        });
        assert!(up[2] > 0.999);
    }

    #[test]
    fn positive_roll_raises_the_left_side() {
        // A point on the sonar's left (+y) in the world: after the sonar rolls +ρ (left side
        // up), the point appears below the new horizon.
        let t = RigidTransform::roll_deg(7.0);
        let (_, el) = warp_direction(&t, deg_to_rad(10.0), 0.0);
        assert!(el < 0.0);
        let (_, el) = warp_direction(&t, deg_to_rad(-10.0), 0.0);
        assert!(el > 0.0);
    }

    #[test]
    fn inverse_and_compose() {
        let t = RigidTransform::rolled_about_axis(7.0, [0.0, 0.05, -0.1]);
        let id = t.compose(&t.inverse());
        let p = [1.0, -2.0, 0.5];
        let q = id.apply(p);
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() < 1e-12);
        }
        let twice = RigidTransform::roll_deg(7.0).compose(&RigidTransform::roll_deg(7.0));
        let direct = RigidTransform::roll_deg(14.0);
        let a = twice.apply(p);
        let b = direct.apply(p);
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-12);
        }
        assert!(!t.preserves_range());
        assert!(RigidTransform::roll_deg(7.0).preserves_range());
    }

    #[test]
    fn fractional_index_edges() {
        let xs = [0.0, 1.0, 3.0];
        assert_eq!(fractional_index(&xs, 0.0), Some((0, 0.0)));
        assert_eq!(fractional_index(&xs, 2.0), Some((1, 0.5)));
        assert_eq!(fractional_index(&xs, 3.0), Some((1, 1.0)));
        assert_eq!(fractional_index(&xs, 3.1), None);
        assert_eq!(fractional_index(&xs, f64::NAN), None);
    }
}
