//! Several pings of one view averaged into one frame, in intensity.
//!
//! Speckle is independent from ping to ping once the sonar moves by a fraction of its
//! wavelength (0.5 mm for the ARIS 3000), so a vehicle that holds each roll position for L
//! pings and averages them sees speckle with 1/L of the variance. Measured on terrain at equal
//! training (docs/ACCURACY.md): four pings per view take the two-view error from 40.4 to
//! 34.4 mm, and a model must be trained on the pings it will see.
//!
//! Frames arrive log-compressed: count `v` of 0–255 stands for `v · D / 255` dB over a
//! dynamic range of D dB (80 for ARIS recordings, docs/ARIS.md; the simulator's default is
//! 70). Averaging counts would average decibels, a biased and less efficient estimator; this
//! module maps each count to its intensity, sums the pings in f32 and maps the mean back to
//! the nearest count in dB. The table is built with `libm`, in software, so a host and a
//! Cortex-M7 average the same frames to the same bytes.
//!
//! Pings are averaged as recorded, before resampling to the model's grid (`host-sim run
//! --pings-per-view`, the simulator's `ping_frames`). The running sum is one f32 per sample,
//! 260 KiB for an ARIS 3000 frame of 128 beams × 520 samples, which the mps2 firmware's
//! 128 KiB does not hold beside the model: the vehicle computer averages and sends the
//! averaged frame (docs/LINK.md).
//!
//! ```
//! use epssn::ping_average::{IntensityTable, PingAverager};
//!
//! let table = IntensityTable::new(80.0).unwrap();
//! let mut sum = [0f32; 4];
//! let mut avg = PingAverager::new(&table, &mut sum);
//! avg.add(&[200, 200, 10, 0]).unwrap();
//! avg.add(&[200, 190, 10, 255]).unwrap();
//! let mut out = [0u8; 4];
//! assert_eq!(avg.finish(&mut out), Ok(2));
//! // Equal pings average to themselves; unequal ones sit nearer the louder ping in dB.
//! assert_eq!(out[0], 200);
//! assert!(out[1] > 195 && out[1] < 200);
//! assert_eq!(out[2], 10);
//! assert!(out[3] > 240);
//! ```

/// Counts of a log-compressed frame.
pub const COUNTS: usize = 256;

/// Most pings one average takes (f32 sums of intensities at most 1 stay exact to 2⁻⁸ relative
/// far beyond this; the bound keeps `pings` in a `u16`).
pub const MAX_PINGS: u16 = 1024;

/// Why pings could not be averaged. Nothing is lost on an error: the sum so far stays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PingAverageError {
    /// The dynamic range is not finite, or not in (0, 200] dB.
    DynamicRange,
    /// A frame or the output is not as long as the sum buffer.
    Length {
        /// The sum buffer's length.
        expected: usize,
        /// The frame's or output's length.
        got: usize,
    },
    /// [`MAX_PINGS`] pings are summed already.
    TooManyPings,
    /// `finish` with no ping added.
    NoPings,
}

/// Count ↔ intensity for one dynamic range: intensity relative to count 255.
#[derive(Clone, Debug, PartialEq)]
pub struct IntensityTable {
    level: [f32; COUNTS],
    /// `threshold[v]`: the intensity half a count above `v` in dB, where `v + 1` becomes nearer.
    threshold: [f32; COUNTS - 1],
}

impl IntensityTable {
    /// The table for frames whose 0–255 counts span `dynamic_range_db` dB.
    pub fn new(dynamic_range_db: f32) -> Result<Self, PingAverageError> {
        if !(dynamic_range_db.is_finite() && dynamic_range_db > 0.0 && dynamic_range_db <= 200.0) {
            return Err(PingAverageError::DynamicRange);
        }
        let db_per_count = dynamic_range_db / 255.0;
        let intensity = |count: f32| libm::powf(10.0, (count - 255.0) * db_per_count / 10.0);
        let mut level = [0f32; COUNTS];
        let mut threshold = [0f32; COUNTS - 1];
        for (v, l) in level.iter_mut().enumerate() {
            *l = intensity(v as f32);
        }
        for (v, t) in threshold.iter_mut().enumerate() {
            *t = intensity(v as f32 + 0.5);
        }
        Ok(Self { level, threshold })
    }

    /// The intensity of `count`, relative to count 255.
    pub fn intensity(&self, count: u8) -> f32 {
        self.level[usize::from(count)]
    }

    /// The count nearest to `intensity` in dB (0 below the range or for NaN, 255 above it).
    pub fn count(&self, intensity: f32) -> u8 {
        // The thresholds ascend, so this is a binary search: 8 comparisons.
        let n = self.threshold.partition_point(|&t| t < intensity);
        u8::try_from(n).unwrap_or(u8::MAX)
    }
}

/// A running average of pings of one view, over a caller-owned f32 sum per pixel.
pub struct PingAverager<'a> {
    table: &'a IntensityTable,
    sum: &'a mut [f32],
    pings: u16,
}

impl<'a> PingAverager<'a> {
    /// An empty average over `sum` (its length is the frame's; it is zeroed here).
    pub fn new(table: &'a IntensityTable, sum: &'a mut [f32]) -> Self {
        sum.fill(0.0);
        Self {
            table,
            sum,
            pings: 0,
        }
    }

    /// Pings summed so far.
    pub fn pings(&self) -> u16 {
        self.pings
    }

    /// Adds one ping.
    pub fn add(&mut self, frame: &[u8]) -> Result<(), PingAverageError> {
        if frame.len() != self.sum.len() {
            return Err(PingAverageError::Length {
                expected: self.sum.len(),
                got: frame.len(),
            });
        }
        if self.pings >= MAX_PINGS {
            return Err(PingAverageError::TooManyPings);
        }
        for (s, &v) in self.sum.iter_mut().zip(frame) {
            *s += self.table.intensity(v);
        }
        self.pings += 1;
        Ok(())
    }

    /// Writes the average into `out`, returns how many pings it holds and starts a new one.
    pub fn finish(&mut self, out: &mut [u8]) -> Result<u16, PingAverageError> {
        if out.len() != self.sum.len() {
            return Err(PingAverageError::Length {
                expected: self.sum.len(),
                got: out.len(),
            });
        }
        if self.pings == 0 {
            return Err(PingAverageError::NoPings);
        }
        let n = f32::from(self.pings);
        for (o, s) in out.iter_mut().zip(self.sum.iter_mut()) {
            *o = self.table.count(*s / n);
            *s = 0.0;
        }
        let pings = self.pings;
        self.pings = 0;
        Ok(pings)
    }
}

/// What [`fingerprint`] gives on a correct build: the host tests and `qemu-check` on the
/// Cortex-M7 both expect it, so host and device are shown to average pings to the same bytes.
pub const FINGERPRINT: u32 = 0x5cc9_f3cd;

/// A self-check: the CRC-32 of the intensity tables at 70 and 80 dB and of four
/// pseudo-random pings averaged at each. Equal to [`FINGERPRINT`] wherever the float
/// arithmetic matches the host's.
pub fn fingerprint() -> Result<u32, PingAverageError> {
    let mut crc = crate::crc32::Crc32::new();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for range in [70.0f32, 80.0] {
        let table = IntensityTable::new(range)?;
        for v in 0..=255u8 {
            crc.update(&table.intensity(v).to_bits().to_le_bytes());
        }
        let mut sum = [0f32; 1024];
        let mut avg = PingAverager::new(&table, &mut sum);
        let mut frame = [0u8; 1024];
        for _ in 0..4 {
            for x in frame.iter_mut() {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                *x = (state >> 56) as u8;
            }
            avg.add(&frame)?;
        }
        let mut out = [0u8; 1024];
        avg.finish(&mut out)?;
        crc.update(&out);
    }
    Ok(crc.finish())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_host_averages_to_the_bytes_the_device_does() {
        assert_eq!(fingerprint(), Ok(FINGERPRINT), "{:#010x?}", fingerprint());
    }

    #[test]
    fn every_count_maps_to_itself_and_the_table_ascends() {
        for range in [70.0, 80.0, 3.0, 200.0] {
            let t = IntensityTable::new(range).unwrap();
            for v in 0..=255u8 {
                assert_eq!(t.count(t.intensity(v)), v, "range {range}, count {v}");
            }
            assert!(t.level.windows(2).all(|w| w[0] < w[1]));
            assert!(t.threshold.windows(2).all(|w| w[0] < w[1]));
            assert_eq!(t.intensity(255), 1.0);
        }
    }

    #[test]
    fn out_of_range_and_nan_intensities_clamp() {
        let t = IntensityTable::new(80.0).unwrap();
        assert_eq!(t.count(0.0), 0);
        assert_eq!(t.count(-1.0), 0);
        assert_eq!(t.count(f32::NAN), 0);
        assert_eq!(t.count(1e9), 255);
        assert_eq!(t.count(f32::INFINITY), 255);
    }

    #[test]
    fn bad_ranges_are_refused() {
        for r in [0.0, -70.0, f32::NAN, f32::INFINITY, 201.0] {
            assert_eq!(IntensityTable::new(r), Err(PingAverageError::DynamicRange));
        }
    }

    #[test]
    fn the_average_is_in_intensity_not_in_counts() {
        // 80 dB over 255 counts: two pings 20 dB apart average to 10·log10((1 + 0.01)/2)
        // ≈ −2.97 dB below the louder, not to the middle count.
        let t = IntensityTable::new(80.0).unwrap();
        let mut sum = [0f32; 1];
        let mut a = PingAverager::new(&t, &mut sum);
        let step: f32 = 20.0 * 255.0 / 80.0; // 63.75 counts
        a.add(&[200]).unwrap();
        a.add(&[libm::roundf(200.0 - step) as u8]).unwrap();
        let mut out = [0u8; 1];
        a.finish(&mut out).unwrap();
        let want = 200.0 + 10.0 * libm::log10f((1.0 + 0.01) / 2.0) * 255.0 / 80.0;
        assert!(
            (f32::from(out[0]) - want).abs() <= 0.6,
            "{} vs {want}",
            out[0]
        );
    }

    #[test]
    fn pings_average_in_any_order_and_the_averager_restarts() {
        let t = IntensityTable::new(70.0).unwrap();
        let frames: [[u8; 5]; 3] = [
            [0, 50, 100, 255, 7],
            [3, 60, 90, 250, 7],
            [9, 40, 130, 1, 7],
        ];
        let mut sum = [0f32; 5];
        let mut a = PingAverager::new(&t, &mut sum);
        let (mut fwd, mut rev) = ([0u8; 5], [0u8; 5]);
        for f in &frames {
            a.add(f).unwrap();
        }
        assert_eq!(a.finish(&mut fwd), Ok(3));
        assert_eq!(a.pings(), 0);
        for f in frames.iter().rev() {
            a.add(f).unwrap();
        }
        assert_eq!(a.finish(&mut rev), Ok(3));
        assert_eq!(fwd, rev);
        assert_eq!(fwd[4], 7);
        // The mean of intensities lies between the quietest and the loudest ping.
        for k in 0..5 {
            let lo = frames.iter().map(|f| f[k]).min().unwrap();
            let hi = frames.iter().map(|f| f[k]).max().unwrap();
            assert!(lo <= fwd[k] && fwd[k] <= hi, "{k}");
        }
    }

    #[test]
    fn errors_lose_nothing() {
        let t = IntensityTable::new(80.0).unwrap();
        let mut sum = [0f32; 3];
        let mut a = PingAverager::new(&t, &mut sum);
        let mut out = [0u8; 3];
        assert_eq!(a.finish(&mut out), Err(PingAverageError::NoPings));
        a.add(&[100, 120, 140]).unwrap();
        assert_eq!(
            a.add(&[1, 2]),
            Err(PingAverageError::Length {
                expected: 3,
                got: 2
            })
        );
        assert_eq!(
            a.finish(&mut [0u8; 4]),
            Err(PingAverageError::Length {
                expected: 3,
                got: 4
            })
        );
        assert_eq!(a.pings(), 1);
        assert_eq!(a.finish(&mut out), Ok(1));
        assert_eq!(out, [100, 120, 140]);
    }

    #[test]
    fn the_ping_count_is_bounded() {
        let t = IntensityTable::new(80.0).unwrap();
        let mut sum = [0f32; 1];
        let mut a = PingAverager::new(&t, &mut sum);
        for _ in 0..MAX_PINGS {
            a.add(&[255]).unwrap();
        }
        assert_eq!(a.add(&[255]), Err(PingAverageError::TooManyPings));
        let mut out = [0u8; 1];
        assert_eq!(a.finish(&mut out), Ok(MAX_PINGS));
        assert_eq!(out, [255]);
    }

    #[test]
    fn averaging_exponential_speckle_shrinks_its_spread_in_db() {
        // Unit-mean exponential intensity (Rayleigh speckle) at −30 dB, from a fixed LCG:
        // the spread of the averaged counts falls roughly as 1/sqrt(L).
        let t = IntensityTable::new(70.0).unwrap();
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut draw = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let u = ((state >> 40) as f32 + 0.5) / (1u64 << 24) as f32;
            -libm::logf(u)
        };
        let n = 4096;
        let spread = |looks: usize, draw: &mut dyn FnMut() -> f32| {
            let mut sum = std::vec![0f32; n];
            let mut a = PingAverager::new(&t, &mut sum);
            for _ in 0..looks {
                let frame: std::vec::Vec<u8> = (0..n).map(|_| t.count(1e-3 * draw())).collect();
                a.add(&frame).unwrap();
            }
            let mut out = std::vec![0u8; n];
            a.finish(&mut out).unwrap();
            let mean = out.iter().map(|&v| f64::from(v)).sum::<f64>() / n as f64;
            let var = out
                .iter()
                .map(|&v| {
                    let d = f64::from(v) - mean;
                    d * d
                })
                .sum::<f64>()
                / n as f64;
            libm::sqrt(var)
        };
        let one = spread(1, &mut draw);
        let four = spread(4, &mut draw);
        let sixteen = spread(16, &mut draw);
        assert!(four < 0.6 * one && four > 0.4 * one, "{one} {four}");
        assert!(
            sixteen < 0.6 * four && sixteen > 0.4 * four,
            "{four} {sixteen}"
        );
    }
}
