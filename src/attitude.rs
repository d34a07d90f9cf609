//! The sonar's attitude as a unit quaternion, and the check that a candidate pair's relative
//! rotation is the roll baseline the warp tables assume (docs/POSE.md).
//!
//! Axes are the geometry module's sonar frame: **x forward, y left, z up**. An attitude maps
//! sonar coordinates to the platform's level frame (z up, heading 0 along x). The ARIS header's
//! angles are composed as
//!
//! ```text
//! q = Rz(−Heading) · Ry(−Pitch) · Rx(Roll) · Rz(−Pan) · Ry(−Tilt) · Rx(RotatorRoll)
//! ```
//!
//! (heading and pan clockwise seen from above, pitch and tilt nose-up, both rolls by the right
//! hand about the forward axis, which is the roll of [`crate::geometry`]'s baseline).
//!
//! For a candidate pair, `q_rel = q_ref⁻¹ · q_src` is split into a twist about the forward
//! axis (the roll) and a swing that tilts the forward axis (the residual): the warp tables are
//! right only when the roll is the baseline and the residual is near zero. The product runs in
//! f32 with `micromath`'s [`Quaternion`]; the angles in f64 `libm` (code the firmware already
//! links). The gate is not on the bit-exact depth path, and host and device run this very
//! function, so they decide alike.
//!
//! ```
//! use epssn::attitude::{Attitude, Verdict};
//!
//! let reference = Attitude::from_header_deg(30.0, 2.0, 0.0, 0.0, 0.0, 0.0).unwrap();
//! // The source: the rotator rolled 7°, the vehicle pitched 0.3° between the pings.
//! let source = Attitude::from_header_deg(30.0, 2.3, 0.0, 0.0, 0.0, 7.0).unwrap();
//! let rel = reference.relative(&source);
//! assert!((rel.roll_deg - 7.0).abs() < 0.01);
//! assert!((rel.residual_deg - 0.3).abs() < 0.01);
//! assert_eq!(rel.check(7.0, 0.5, 1.0), Verdict::Accepted);
//! assert_eq!(rel.check(7.0, 0.5, 0.2), Verdict::Residual);
//! ```

use micromath::Quaternion;

/// A unit quaternion `w + xi + yj + zk`: sonar frame → level platform frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Attitude(Quaternion);

#[cfg(feature = "defmt")]
impl defmt::Format for Attitude {
    fn format(&self, f: defmt::Formatter) {
        let [w, x, y, z] = self.to_array();
        defmt::write!(f, "q({}, {}, {}, {})", w, x, y, z)
    }
}

/// A rotation of `deg` about axis 0 (x), 1 (y) or 2 (z).
fn axis_deg(axis: usize, deg: f32) -> Quaternion {
    let half = f64::from(deg).to_radians() / 2.0;
    let (s, c) = (libm::sin(half) as f32, libm::cos(half) as f32);
    match axis {
        0 => Quaternion::new(c, s, 0.0, 0.0),
        1 => Quaternion::new(c, 0.0, s, 0.0),
        _ => Quaternion::new(c, 0.0, 0.0, s),
    }
}

/// Norms a quaternion may have on the link before it is refused rather than normalised:
/// anything outside is a corrupt value, not rounding.
const NORM_RANGE: core::ops::RangeInclusive<f32> = 0.98..=1.02;

impl Attitude {
    /// The identity: sonar axes = level axes.
    pub const IDENTITY: Self = Self(Quaternion::IDENTITY);

    /// From the header's angles, degrees (the module's convention). `None` if one is not
    /// finite.
    pub fn from_header_deg(
        heading: f32,
        pitch: f32,
        roll: f32,
        pan: f32,
        tilt: f32,
        rotator_roll: f32,
    ) -> Option<Self> {
        let angles = [heading, pitch, roll, pan, tilt, rotator_roll];
        if !angles.iter().all(|a| a.is_finite()) {
            return None;
        }
        let q = axis_deg(2, -heading)
            * axis_deg(1, -pitch)
            * axis_deg(0, roll)
            * axis_deg(2, -pan)
            * axis_deg(1, -tilt)
            * axis_deg(0, rotator_roll);
        Self::from_array(q.to_array())
    }

    /// From `[w, x, y, z]` as the link carries it; `None` when a component is not finite or
    /// the norm is not 1 within 2 % (a corrupt value). Kept as sent, not normalised: the
    /// decomposition of [`Relative::of`] does not depend on the scale.
    pub fn from_array(q: [f32; 4]) -> Option<Self> {
        if !q.iter().all(|c| c.is_finite()) {
            return None;
        }
        let norm2: f64 = q.iter().map(|&c| f64::from(c) * f64::from(c)).sum();
        let (lo, hi) = (NORM_RANGE.start(), NORM_RANGE.end());
        if !(f64::from(lo * lo)..=f64::from(hi * hi)).contains(&norm2) {
            return None;
        }
        let [w, x, y, z] = q;
        Some(Self(Quaternion::new(w, x, y, z)))
    }

    /// `[w, x, y, z]`.
    pub fn to_array(&self) -> [f32; 4] {
        self.0.to_array()
    }

    /// The quaternion.
    pub fn quaternion(&self) -> Quaternion {
        self.0
    }

    /// The rotation from this (reference) attitude to `source`'s, decomposed.
    pub fn relative(&self, source: &Attitude) -> Relative {
        // The conjugate is the inverse up to the scale, which the decomposition ignores;
        // micromath's `inv` divides by an approximate norm (and asserts it is not zero), which
        // a gate should not.
        Relative::of(self.0.conj() * source.0)
    }
}

/// A relative rotation split into roll and residual.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Relative {
    /// Twist about the forward axis, degrees in (−180, 180].
    pub roll_deg: f32,
    /// Angle by which the forward axis is tilted (the swing: pitch and yaw together), degrees
    /// in [0, 180].
    pub residual_deg: f32,
}

/// Whether a pair may use the warp tables, and if not why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Verdict {
    /// Roll and residual within their tolerances.
    Accepted,
    /// A frame has no attitude: accepted by the roll-only rule (the rotator rolls).
    RollOnly,
    /// The relative roll is not the baseline within its tolerance.
    Roll,
    /// The forward axis tilted by more than the residual tolerance.
    Residual,
}

impl Verdict {
    /// True when the pair is used.
    pub fn accepted(self) -> bool {
        matches!(self, Verdict::Accepted | Verdict::RollOnly)
    }

    /// The reason as the link and `host-sim run --json` write it.
    pub fn reason(self) -> &'static str {
        match self {
            Verdict::Accepted => "ok",
            Verdict::RollOnly => "roll_only",
            Verdict::Roll => "roll",
            Verdict::Residual => "residual",
        }
    }

    /// Every verdict, in wire-code order.
    pub const ALL: [Verdict; 4] = [
        Verdict::Accepted,
        Verdict::RollOnly,
        Verdict::Roll,
        Verdict::Residual,
    ];

    /// The number on the link (`why` of a status reply).
    pub fn code(self) -> u8 {
        self as u8
    }

    /// The verdict of a link number.
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.iter().copied().find(|v| v.code() == code)
    }
}

impl Relative {
    /// Decomposes `q` (any non-zero quaternion, of any scale; a zero one reads as NaN, which
    /// the gate refuses).
    pub fn of(q: Quaternion) -> Self {
        let [w, x, y, z] = q.to_array().map(f64::from);
        // q and −q are the same rotation: take w ≥ 0 so the twist lies in [−180°, 180°].
        let (w, x) = if w < 0.0 { (-w, -x) } else { (w, x) };
        // Twist = (w, x, 0, 0) normalised, angle 2·atan2(x, w); the swing's cosine of half its
        // angle is |(w, x)|, so its angle is 2·atan2(|(y, z)|, |(w, x)|): well conditioned at
        // the small angles the gate looks at, unlike acos.
        // `atan` of the ratios rather than `atan2`: with w ≥ 0 they agree, and the firmware
        // links `atan` already (flash is tight). x/0 is ±∞, whose atan is ±90°.
        let mut roll = if w == 0.0 && x == 0.0 {
            0.0
        } else {
            2.0 * libm::atan(x / w)
        };
        if roll <= -core::f64::consts::PI {
            roll += 2.0 * core::f64::consts::PI;
        }
        let residual = 2.0 * libm::atan(libm::sqrt((y * y + z * z) / (w * w + x * x)));
        Self {
            roll_deg: roll.to_degrees() as f32,
            residual_deg: residual.to_degrees() as f32,
        }
    }

    /// The gate: `Roll` unless the roll is `baseline_deg` within `roll_tolerance_deg`, then
    /// `Residual` unless the residual is within `residual_tolerance_deg`, else `Accepted`.
    /// Bounds are inclusive; NaN fails.
    pub fn check(
        &self,
        baseline_deg: f64,
        roll_tolerance_deg: f64,
        residual_tolerance_deg: f64,
    ) -> Verdict {
        // Comparisons with NaN are false, so NaN fails both.
        let roll_ok = (f64::from(self.roll_deg) - baseline_deg).abs() <= roll_tolerance_deg;
        let residual_ok = f64::from(self.residual_deg) <= residual_tolerance_deg;
        if !roll_ok {
            Verdict::Roll
        } else if !residual_ok {
            Verdict::Residual
        } else {
            Verdict::Accepted
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type M = [[f64; 3]; 3];

    fn mul(a: &M, b: &M) -> M {
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, c) in row.iter_mut().enumerate() {
                *c = (0..3).map(|k| a[i][k] * b[k][j]).sum();
            }
        }
        m
    }

    fn transpose(a: &M) -> M {
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, c) in row.iter_mut().enumerate() {
                *c = a[j][i];
            }
        }
        m
    }

    /// Plain right-handed rotation matrix about axis 0/1/2.
    fn rot(axis: usize, deg: f64) -> M {
        let (s, c) = deg.to_radians().sin_cos();
        match axis {
            0 => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
            1 => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
            _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
        }
    }

    fn header_matrix(a: &[f64; 6]) -> M {
        let mut m = rot(2, -a[0]);
        for (axis, deg) in [(1, -a[1]), (0, a[2]), (2, -a[3]), (1, -a[4]), (0, a[5])] {
            m = mul(&m, &rot(axis, deg));
        }
        m
    }

    /// Roll and residual from matrices alone: the residual is the angle between x and R·x;
    /// the swing S is the smallest rotation taking x to R·x (Rodrigues), and the roll is the
    /// angle of the twist T = Sᵀ·R about x.
    fn matrix_decomposition(r: &M) -> (f64, f64) {
        let v = [r[0][0], r[1][0], r[2][0]];
        let residual = v[0].clamp(-1.0, 1.0).acos();
        // Axis x × v = (0, −v2, v1), |x × v| = sin(residual).
        let (s, c) = (residual.sin(), v[0]);
        let swing = if s < 1e-12 {
            rot(0, 0.0)
        } else {
            let (ky, kz) = (-v[2] / s, v[1] / s);
            let kx = 0.0;
            let k = [[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]];
            let k2 = mul(&k, &k);
            let mut m = rot(0, 0.0);
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += s * k[i][j] + (1.0 - c) * k2[i][j];
                }
            }
            m
        };
        let t = mul(&transpose(&swing), r);
        (t[2][1].atan2(t[1][1]).to_degrees(), residual.to_degrees())
    }

    /// xorshift64*: deterministic test poses without a dependency.
    struct Rng(u64);
    impl Rng {
        fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let u = (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
            lo + (hi - lo) * u
        }
    }

    #[test]
    fn decomposition_matches_rotation_matrices_on_random_poses() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for case in 0..2000 {
            let reference: [f64; 6] = core::array::from_fn(|i| match i {
                0 => rng.uniform(0.0, 360.0),
                1 | 2 => rng.uniform(-30.0, 30.0),
                _ => rng.uniform(-20.0, 20.0),
            });
            // Sources near the reference (the gate's regime) and anywhere (robustness).
            let near = case % 2 == 0;
            let source: [f64; 6] = core::array::from_fn(|i| {
                if near {
                    reference[i] + rng.uniform(-5.0, 5.0) + if i == 5 { 7.0 } else { 0.0 }
                } else {
                    rng.uniform(-170.0, 170.0)
                }
            });
            let f = |a: &[f64; 6]| {
                Attitude::from_header_deg(
                    a[0] as f32,
                    a[1] as f32,
                    a[2] as f32,
                    a[3] as f32,
                    a[4] as f32,
                    a[5] as f32,
                )
                .unwrap()
            };
            let rel = f(&reference).relative(&f(&source));
            // The matrices from the f32-rounded angles the quaternions were built from.
            let r32 = |a: &[f64; 6]| a.map(|v| f64::from(v as f32));
            let r_rel = mul(
                &transpose(&header_matrix(&r32(&reference))),
                &header_matrix(&r32(&source)),
            );
            let (roll, residual) = matrix_decomposition(&r_rel);
            let tol = if near { 2e-3 } else { 2e-2 };
            assert!(
                (f64::from(rel.residual_deg) - residual).abs() < tol,
                "case {case}: residual {} vs {residual}",
                rel.residual_deg
            );
            // The twist is undefined when the forward axis turns over.
            if residual < 170.0 {
                let d = (f64::from(rel.roll_deg) - roll + 540.0).rem_euclid(360.0) - 180.0;
                assert!(
                    d.abs() < tol * 10.0,
                    "case {case}: roll {} vs {roll}",
                    rel.roll_deg
                );
            }
        }
    }

    #[test]
    fn pure_roll_and_pure_tilt() {
        let a = Attitude::IDENTITY;
        let b = Attitude::from_header_deg(0.0, 0.0, 0.0, 0.0, 0.0, 14.0).unwrap();
        let r = a.relative(&b);
        assert!((r.roll_deg - 14.0).abs() < 1e-4 && r.residual_deg.abs() < 1e-4);
        // Platform roll adds to the rotator roll: the gate sees the sonar's roll.
        let c = Attitude::from_header_deg(0.0, 0.0, 2.0, 0.0, 0.0, 7.0).unwrap();
        assert!((a.relative(&c).roll_deg - 9.0).abs() < 1e-4);
        // Heading 1° turns the forward axis by 1°, roll stays 0.
        let d = Attitude::from_header_deg(1.0, 0.0, 0.0, 0.0, 0.0, 0.0).unwrap();
        let r = a.relative(&d);
        assert!(r.roll_deg.abs() < 1e-4 && (r.residual_deg - 1.0).abs() < 1e-4);
        // Order matters: the reference's inverse comes first.
        assert!((c.relative(&a).roll_deg + 9.0).abs() < 1e-4);
    }

    #[test]
    fn gate_bounds_are_inclusive_and_nan_fails() {
        let rel = |roll_deg, residual_deg| Relative {
            roll_deg,
            residual_deg,
        };
        assert_eq!(rel(7.5, 0.0).check(7.0, 0.5, 1.0), Verdict::Accepted);
        assert_eq!(rel(7.51, 0.0).check(7.0, 0.5, 1.0), Verdict::Roll);
        assert_eq!(rel(6.49, 0.0).check(7.0, 0.5, 1.0), Verdict::Roll);
        assert_eq!(rel(7.0, 1.0).check(7.0, 0.5, 1.0), Verdict::Accepted);
        assert_eq!(rel(7.0, 1.01).check(7.0, 0.5, 1.0), Verdict::Residual);
        // A roll failure is reported before a residual one.
        assert_eq!(rel(9.0, 3.0).check(7.0, 0.5, 1.0), Verdict::Roll);
        assert_eq!(rel(f32::NAN, 0.0).check(7.0, 0.5, 1.0), Verdict::Roll);
        assert_eq!(rel(7.0, f32::NAN).check(7.0, 0.5, 1.0), Verdict::Residual);
        assert_eq!(
            rel(7.0, 100.0).check(7.0, 0.5, f64::INFINITY),
            Verdict::Accepted
        );
        for v in Verdict::ALL {
            assert_eq!(Verdict::from_code(v.code()), Some(v));
        }
        assert_eq!(Verdict::from_code(9), None);
    }

    #[test]
    fn link_values_are_checked() {
        assert!(Attitude::from_array([1.0, 0.0, 0.0, 0.0]).is_some());
        // Within 2 % of unit: kept as sent, and the decomposition ignores the scale.
        let q = Attitude::from_array([1.01, 0.0, 0.0, 0.0]).unwrap();
        assert_eq!(q.to_array(), [1.01, 0.0, 0.0, 0.0]);
        let half = 3.5f32.to_radians();
        let r = q.relative(
            &Attitude::from_array([0.99 * half.cos(), 0.99 * half.sin(), 0.0, 0.0]).unwrap(),
        );
        assert!((r.roll_deg - 7.0).abs() < 1e-4 && r.residual_deg.abs() < 1e-4);
        assert_eq!(Attitude::from_array([0.0; 4]), None);
        assert_eq!(Attitude::from_array([1.1, 0.0, 0.0, 0.0]), None);
        assert_eq!(Attitude::from_array([f32::NAN, 0.0, 0.0, 0.0]), None);
        assert_eq!(Attitude::from_array([f32::INFINITY, 0.0, 0.0, 0.0]), None);
        assert_eq!(
            Attitude::from_header_deg(f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0),
            None
        );
        // A zero quaternion (never built here) decomposes without panicking, and is refused.
        let r = Relative::of(Quaternion::new(0.0, 0.0, 0.0, 0.0));
        assert_ne!(r.check(0.0, 0.5, 1.0), Verdict::Accepted);
        // The forward axis turned over: w = x = 0 is a 180° residual.
        let r = Relative::of(Quaternion::new(0.0, 0.0, 1.0, 0.0));
        assert_eq!((r.roll_deg, r.residual_deg), (0.0, 180.0));
    }
}
