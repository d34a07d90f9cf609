//! A ProjectedSonarImage as a native frame ([`SonarFrame`]):
//!
//! - **Layout**, as sonar_image_proc reads it: element `(range r, beam b)` at
//!   `(r · beam_count + b) · size`, range-major, beams in `beam_directions` order.
//! - **Azimuth** of each beam from its direction `(x, y, z)` in the message's axes (Z forward,
//!   X up, so Y to starboard): `atan2(−y, z)`, positive to port, as the ARIS tables count
//!   (beam 0 right-most). Beams listed port first are reversed.
//! - **Intensity** to u8 by the dtype ([`to_u8`]).
//! - **Ranges** ascending. Evenly spaced ones (each within 1 % of a step of the line through the
//!   first and last) are taken as they are; uneven ones are resampled first ([`resample_ranges`]):
//!   each beam's counts linearly interpolated onto as many even bins from the first range to the
//!   last, rounded. `start` is the first and `step` the mean spacing. When `ping_info.sound_speed`
//!   is set and both are whole microseconds of two-way travel, they are taken as those
//!   microseconds × c/2 exactly (docs/ARIS.md's rule): the float32 of the message loses the
//!   ARIS geometry's last bits, and this gives them back.
//! - **Beam table**: azimuths within 1 µrad of an embedded ARIS table's (same beam count) are
//!   taken as that table's exact angles, for the same reason.

use anyhow::{bail, ensure, Result};
use epssn::geometry::SampleRanges;

use crate::frame::SonarFrame;
use crate::msgs::{ProjectedSonarImage, SonarImageData};

/// How close a spacing must be to even, in steps.
const EVEN_TOLERANCE: f64 = 0.01;
/// How close to a whole microsecond a range must be to be snapped to it.
const MICROSECOND_TOLERANCE: f64 = 1e-3;
/// How close to an ARIS table's angle each azimuth must be, radians.
const TABLE_TOLERANCE_RAD: f64 = 1e-6;

/// Bytes per element of a dtype, `None` for a dtype the message does not define.
pub fn dtype_size(dtype: u32) -> Option<usize> {
    match dtype {
        0 | 1 => Some(1),
        2 | 3 => Some(2),
        4 | 5 | 8 => Some(4),
        6 | 7 | 9 => Some(8),
        _ => None,
    }
}

/// The image's elements as u8 counts. Unsigned integers keep their top 8 bits (`uint8` as is,
/// `uint16 >> 8`, `uint32 >> 24`, `uint64 >> 56`: sonar_image_proc's `intensity_uint8`);
/// signed integers read negative as 0 and keep the top 8 bits of their positive range
/// (`int8 · 2`, `int16 >> 7`, `int32 >> 23`, `int64 >> 55`); floats are a fraction of full
/// scale (sonar_image_proc's `intensity_float`): `round(v · 255)` clamped to 0–255, NaN 0.
pub fn to_u8(image: &SonarImageData) -> Result<Vec<u8>> {
    let Some(size) = dtype_size(image.dtype) else {
        bail!(
            "image dtype {} is not one SonarImageData defines (0–9)",
            image.dtype
        );
    };
    ensure!(
        image.data.len().is_multiple_of(size),
        "image data of {} bytes is not whole elements of {size} bytes",
        image.data.len()
    );
    let big = image.is_bigendian;
    let word = |e: &[u8]| -> u64 {
        let mut b = [0u8; 8];
        if big {
            b[8 - e.len()..].copy_from_slice(e);
            u64::from_be_bytes(b)
        } else {
            b[..e.len()].copy_from_slice(e);
            u64::from_le_bytes(b)
        }
    };
    let float = |v: f64| -> u8 {
        if v.is_nan() {
            0
        } else {
            (v * 255.0).round().clamp(0.0, 255.0) as u8
        }
    };
    let bits = size as u32 * 8;
    Ok(image
        .data
        .chunks_exact(size)
        .map(|e| {
            let w = word(e);
            match image.dtype {
                0 | 2 | 4 | 6 => (w >> (bits - 8)) as u8,
                1 | 3 | 5 | 7 => {
                    if w >> (bits - 1) == 1 {
                        0
                    } else if bits == 8 {
                        (w << 1) as u8
                    } else {
                        (w >> (bits - 9)) as u8
                    }
                }
                8 => float(f64::from(f32::from_bits(w as u32))),
                _ => float(f64::from_bits(w)),
            }
        })
        .collect())
}

/// Beam azimuths (radians, `atan2(−y, z)`) of `directions`.
pub fn azimuths(directions: &[[f64; 3]]) -> Result<Vec<f64>> {
    directions
        .iter()
        .enumerate()
        .map(|(i, &[x, y, z])| {
            ensure!(
                [x, y, z].iter().all(|c| c.is_finite()) && (y != 0.0 || z != 0.0),
                "beam {i}'s direction ({x}, {y}, {z}) has no azimuth"
            );
            Ok((-y).atan2(z))
        })
        .collect()
}

/// The azimuths as an embedded ARIS table's exact angles, when they match one.
fn snap_to_table(az: Vec<f64>) -> Vec<f64> {
    let Ok(tables) = epssn_aris::beams::tables() else {
        return az;
    };
    for t in tables.iter().filter(|t| t.beams() == az.len()) {
        let exact = t.centres_rad();
        if exact
            .iter()
            .zip(&az)
            .all(|(a, b)| (a - b).abs() <= TABLE_TOLERANCE_RAD)
        {
            return exact;
        }
    }
    az
}

/// The message's range axis: the even bins the frame holds, and the message's own ranges when
/// they are uneven (the frame's counts are then resampled onto the bins).
#[derive(Debug, Clone, PartialEq)]
pub struct RangeAxis {
    /// The frame's even bins.
    pub bins: SampleRanges,
    /// The message's ranges (m), when they are not even.
    pub uneven: Option<Vec<f64>>,
}

/// The ranges' axis, by the rule of the module's documentation.
pub fn range_axis(ranges: &[f32], sound_speed: f32) -> Result<RangeAxis> {
    let n = ranges.len();
    ensure!(n >= 2, "{n} range bin(s): at least 2 are needed");
    ensure!(
        ranges.iter().all(|r| r.is_finite()),
        "a range is not finite"
    );
    if let Some(i) = (1..n).find(|&i| ranges[i] <= ranges[i - 1]) {
        bail!(
            "ranges are not ascending (bin {i} at {} m after {} m)",
            ranges[i],
            ranges[i - 1]
        );
    }
    let first = f64::from(ranges[0]);
    let step = (f64::from(ranges[n - 1]) - first) / (n - 1) as f64;
    let mut bins = SampleRanges {
        start: first,
        step,
        samples: n,
    };
    let even = ranges
        .iter()
        .enumerate()
        .all(|(i, &r)| (f64::from(r) - (first + step * i as f64)).abs() <= EVEN_TOLERANCE * step);
    if !even {
        let uneven = ranges.iter().map(|&r| f64::from(r)).collect();
        return Ok(RangeAxis {
            bins,
            uneven: Some(uneven),
        });
    }
    let c = f64::from(sound_speed);
    if c.is_finite() && c > 0.0 {
        let half = c * 1e-6 / 2.0;
        let (delay, period) = (first / half, step / half);
        let whole = |x: f64| (x - x.round()).abs() <= MICROSECOND_TOLERANCE;
        if whole(delay) && whole(period) && period.round() >= 1.0 && delay.round() >= 0.0 {
            bins.start = delay.round() * half;
            bins.step = period.round() * half;
        }
    }
    Ok(RangeAxis { bins, uneven: None })
}

/// Range-major counts (`beams` per row) at the ascending ranges `from`, linearly interpolated
/// onto `bins` and rounded: each bin between the two message ranges around it.
pub fn resample_ranges(data: &[u8], beams: usize, from: &[f64], bins: &SampleRanges) -> Vec<u8> {
    let mut out = Vec::with_capacity(bins.samples * beams);
    let mut j = 0;
    for k in 0..bins.samples {
        let r = bins.start + bins.step * k as f64;
        while j + 2 < from.len() && from[j + 1] < r {
            j += 1;
        }
        let t = ((r - from[j]) / (from[j + 1] - from[j])).clamp(0.0, 1.0);
        let (lo, hi) = (
            &data[j * beams..][..beams],
            &data[(j + 1) * beams..][..beams],
        );
        out.extend(
            lo.iter()
                .zip(hi)
                .map(|(&a, &b)| (f64::from(a) + t * (f64::from(b) - f64::from(a))).round() as u8),
        );
    }
    out
}

/// The message as a native frame (`index` its position in the recording).
pub fn frame_of(msg: &ProjectedSonarImage, index: usize) -> Result<SonarFrame> {
    let beams = msg.beam_directions.len();
    ensure!(
        msg.image.beam_count as usize == beams,
        "image.beam_count {} but {beams} beam_directions",
        msg.image.beam_count
    );
    ensure!(beams >= 2, "{beams} beam(s): at least 2 are needed");
    let axis = range_axis(&msg.ranges, msg.ping_info.sound_speed)?;
    let ranges = axis.bins;
    let mut data = to_u8(&msg.image)?;
    ensure!(
        data.len() == beams * ranges.samples,
        "image holds {} elements, {beams} beams × {} ranges need {}",
        data.len(),
        ranges.samples,
        beams * ranges.samples
    );
    if let Some(from) = &axis.uneven {
        data = resample_ranges(&data, beams, from, &ranges);
    }
    let mut az = azimuths(&msg.beam_directions)?;
    if az.windows(2).all(|w| w[1] < w[0]) {
        // Port first: turn each row round so beam 0 is the right-most.
        az.reverse();
        for row in data.chunks_exact_mut(beams) {
            row.reverse();
        }
    }
    ensure!(
        az.windows(2).all(|w| w[1] > w[0]),
        "beam azimuths are not monotonic"
    );
    let stamp = msg.header.stamp_ns.max(0) as u64;
    Ok(SonarFrame {
        index,
        time_us: stamp / 1000,
        beams,
        data,
        ranges,
        beam_centres_rad: snap_to_table(az),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(dtype: u32, big: bool, data: Vec<u8>) -> SonarImageData {
        SonarImageData {
            is_bigendian: big,
            dtype,
            beam_count: 1,
            data,
        }
    }

    #[test]
    fn every_dtype_maps_to_u8_by_the_rule() {
        assert_eq!(
            to_u8(&image(0, false, vec![0, 7, 255])).unwrap(),
            [0, 7, 255]
        );
        assert_eq!(
            to_u8(&image(1, false, vec![0x80, 0x7f, 3])).unwrap(),
            [0, 254, 6]
        );
        assert_eq!(to_u8(&image(2, false, vec![0x34, 0x12])).unwrap(), [0x12]);
        assert_eq!(to_u8(&image(2, true, vec![0x34, 0x12])).unwrap(), [0x34]);
        assert_eq!(
            to_u8(&image(3, false, 0x7fffi16.to_le_bytes().to_vec())).unwrap(),
            [255]
        );
        assert_eq!(
            to_u8(&image(3, false, (-5i16).to_le_bytes().to_vec())).unwrap(),
            [0]
        );
        assert_eq!(
            to_u8(&image(4, false, 0xab00_0000u32.to_le_bytes().to_vec())).unwrap(),
            [0xab]
        );
        assert_eq!(
            to_u8(&image(5, true, (1i32 << 30).to_be_bytes().to_vec())).unwrap(),
            [128]
        );
        assert_eq!(
            to_u8(&image(6, false, (200u64 << 56).to_le_bytes().to_vec())).unwrap(),
            [200]
        );
        assert_eq!(
            to_u8(&image(7, false, (-1i64).to_le_bytes().to_vec())).unwrap(),
            [0]
        );
        assert_eq!(
            to_u8(&image(8, false, 0.5f32.to_le_bytes().to_vec())).unwrap(),
            [128]
        );
        assert_eq!(
            to_u8(&image(8, false, f32::NAN.to_le_bytes().to_vec())).unwrap(),
            [0]
        );
        assert_eq!(
            to_u8(&image(9, true, 2.0f64.to_be_bytes().to_vec())).unwrap(),
            [255]
        );
        assert!(to_u8(&image(10, false, vec![0])).is_err());
        assert!(to_u8(&image(2, false, vec![0, 1, 2])).is_err());
    }

    #[test]
    fn azimuth_is_positive_to_port_with_z_forward_and_x_up() {
        // Y is starboard (Z forward × X up): a beam toward −Y points to port.
        let a = azimuths(&[[0.0, -1.0, 1.0], [0.3, 0.0, 1.0], [0.0, 1.0, 1.0]]).unwrap();
        assert!((a[0] - std::f64::consts::FRAC_PI_4).abs() < 1e-15);
        assert_eq!(a[1], 0.0);
        assert!((a[2] + std::f64::consts::FRAC_PI_4).abs() < 1e-15);
        assert!(azimuths(&[[1.0, 0.0, 0.0]]).is_err());
    }

    #[test]
    fn ranges_at_whole_microseconds_are_given_back_exactly() {
        let (c, delay, period) = (1480.5f32, 2667u32, 4u32);
        let half = f64::from(c) * 1e-6 / 2.0;
        let exact: Vec<f64> = (0..500)
            .map(|i| f64::from(delay) * half + f64::from(period) * half * i as f64)
            .collect();
        let written: Vec<f32> = exact.iter().map(|&r| r as f32).collect();
        let r = range_axis(&written, c).unwrap().bins;
        assert_eq!(r.start, f64::from(delay) * half);
        assert_eq!(r.step, f64::from(period) * half);
        // Without the sound speed the float32 values stand, a few ulps from the exact ones.
        let r0 = range_axis(&written, 0.0).unwrap().bins;
        assert_eq!(r0.start, f64::from(written[0]));
        assert!((r0.step - f64::from(period) * half).abs() < 1e-8);
    }

    #[test]
    fn unordered_or_too_few_ranges_are_refused() {
        assert!(range_axis(&[1.0, 1.2, 1.2, 1.4], 0.0)
            .unwrap_err()
            .to_string()
            .contains("bin 2 at 1.2 m after 1.2 m"));
        assert!(range_axis(&[2.0, 1.0], 0.0).is_err());
        assert!(range_axis(&[2.0], 0.0).is_err());
        assert!(range_axis(&[1.0, f32::NAN, 2.0], 0.0).is_err());
    }

    #[test]
    fn uneven_ranges_are_resampled_onto_even_bins_from_the_first_to_the_last() {
        // Squared spacing: 1.0, 1.1, 1.4, 1.9, 2.6 m; the even bins step 0.4 m.
        let written = [1.0f32, 1.1, 1.4, 1.9, 2.6];
        let axis = range_axis(&written, 1500.0).unwrap();
        let from = axis.uneven.clone().expect("uneven");
        assert_eq!((axis.bins.start, axis.bins.samples), (1.0, 5));
        assert!((axis.bins.step - 0.4).abs() < 1e-6);
        // Two beams: one linear in range (50 counts per metre), one constant.
        let data: Vec<u8> = written
            .iter()
            .flat_map(|&r| [(50.0 * f64::from(r)).round() as u8, 9])
            .collect();
        let out = resample_ranges(&data, 2, &from, &axis.bins);
        assert_eq!(out, [50, 9, 70, 9, 90, 9, 110, 9, 130, 9]);
        // Within 1 % of a step of even: taken as they are.
        assert_eq!(
            range_axis(&[1.0, 1.1004, 1.2, 1.3], 0.0).unwrap().uneven,
            None
        );
    }
}
