//! Bags written by the crate's small writer, read back through `Recording`: every chunk
//! compression, the ARIS geometry given back exactly, attitudes and rolls from /tf, the
//! resampling rule onto the model's grid, and every refusal by name (no panic).

use epssn::config;
use epssn_aris::beams::table_by_name;
use epssn_ros2::bag::BagRecording;
use epssn_ros2::encode::{self, bag, Compression, Entry};
use epssn_ros2::fit::misfit;
use epssn_ros2::msgs::{
    Header, ProjectedSonarImage, TransformStamped, PROJECTED_SONAR_IMAGE, TF_MESSAGE,
};
use epssn_ros2::Recording;

const T0: i64 = 1_700_000_000_000_000_000;

/// A ping of `azimuths` × `ranges`, uint8 value `value(range index, beam index)`.
fn ping(
    stamp_ns: i64,
    azimuths: &[f64],
    ranges: &[f32],
    sound_speed: f32,
    value: impl Fn(usize, usize) -> u8,
) -> ProjectedSonarImage {
    let data = (0..ranges.len())
        .flat_map(|r| (0..azimuths.len()).map(move |b| (r, b)))
        .map(|(r, b)| value(r, b))
        .collect();
    encode::level_ping(stamp_ns, azimuths, ranges, sound_speed, 0, data)
}

/// map ← sonar_image for a level sonar rolled `roll_deg` about its forward axis: the rotation
/// Rx(roll) in the sonar frame, then the message's axes in it (180° about (x + z)/√2).
fn tf(stamp_ns: i64, roll_deg: f64) -> TransformStamped {
    let h = roll_deg.to_radians() / 2.0;
    let roll = [h.sin(), 0.0, 0.0, h.cos()];
    let s = std::f64::consts::FRAC_1_SQRT_2;
    TransformStamped {
        header: Header {
            stamp_ns,
            frame_id: "map".into(),
        },
        child_frame_id: "sonar_image".into(),
        translation: [0.0; 3],
        rotation: epssn_ros2::tf::mul(roll, [s, 0.0, s, 0.0]),
    }
}

/// The ARIS 3000 geometry of the demo: 128 beams of its table, 520 samples of 4 µs from
/// 2667 µs at 1497.3 m/s.
fn aris_geometry() -> (Vec<f64>, Vec<f32>, f32, f64, f64) {
    let c = 1497.3f32;
    let half = f64::from(c) * 1e-6 / 2.0;
    let (start, step) = (2667.0 * half, 4.0 * half);
    let ranges = (0..520).map(|i| (start + step * i as f64) as f32).collect();
    let table = table_by_name("ARIS3000_128").unwrap();
    (table.centres_rad(), ranges, c, start, step)
}

fn entries<'a>(images: &'a [Vec<u8>], tfs: &'a [Vec<u8>]) -> Vec<Entry<'a>> {
    let mut out = Vec::new();
    for (k, (img, t)) in images.iter().zip(tfs).enumerate() {
        let log_time = (T0 as u64) + k as u64 * 1000;
        out.push(Entry {
            topic: "/tf",
            schema: TF_MESSAGE,
            log_time,
            data: t,
        });
        out.push(Entry {
            topic: "/sonar",
            schema: PROJECTED_SONAR_IMAGE,
            log_time,
            data: img,
        });
    }
    out
}

#[test]
fn every_compression_reads_back_the_aris_geometry_exactly_with_rolls_from_tf() {
    let (az, ranges, c, start, step) = aris_geometry();
    let rolls = [-7.0, 0.0, 7.0];
    let images: Vec<Vec<u8>> = (0..3)
        .map(|k| {
            let p = ping(T0 + k * 1000, &az, &ranges, c, |r, b| {
                ((r * 3 + b + k as usize) % 251) as u8
            });
            encode::cdr::sonar_image(&p)
        })
        .collect();
    let tfs: Vec<Vec<u8>> = rolls
        .iter()
        .enumerate()
        .map(|(k, &r)| encode::cdr::tf_message(&[tf(T0 + k as i64 * 1000, r)]))
        .collect();
    for compression in [Compression::None, Compression::Lz4, Compression::Zstd] {
        let bytes = bag(&entries(&images, &tfs), compression);
        let rec = BagRecording::from_bytes(&bytes, None).unwrap();
        assert_eq!((rec.frame_count(), rec.topic.as_str()), (3, "/sonar"));
        assert!(rec.warnings().is_empty(), "{:?}", rec.warnings());
        for (k, want_roll) in rolls.iter().enumerate() {
            let f = rec.frame(k).unwrap();
            // The table's exact angles and docs/ARIS.md's ranges, not the float32 ones.
            assert_eq!(f.beam_centres_rad, az);
            assert_eq!(
                (f.ranges.start, f.ranges.step, f.ranges.samples),
                (start, step, 520)
            );
            assert_eq!(f.data[5 * 128 + 9], ((5 * 3 + 9 + k) % 251) as u8);
            assert_eq!(f.time_us, (T0 as u64 + k as u64 * 1000) / 1000);
            let roll = rec.roll_deg(k).unwrap();
            assert!(
                (roll - want_roll).abs() < 1e-4,
                "{compression:?} ping {k}: roll {roll}"
            );
            assert!(rec.attitude(k).is_some());
        }
        assert!(misfit(&rec.frame(0).unwrap()).is_none());
    }
}

#[test]
fn a_bag_file_is_read_ping_by_ping_from_its_chunks() {
    // Five pings, two entries (a transform and a ping) to a chunk: three chunks, read from a
    // file in an order that crosses them back and forth.
    let (az, ranges, c, _, _) = aris_geometry();
    let images: Vec<Vec<u8>> = (0..5)
        .map(|k| {
            let p = ping(T0 + k * 1000, &az, &ranges, c, |r, b| {
                ((r + 7 * b + 11 * k as usize) % 253) as u8
            });
            encode::cdr::sonar_image(&p)
        })
        .collect();
    let tfs: Vec<Vec<u8>> = (0..5)
        .map(|k| encode::cdr::tf_message(&[tf(T0 + k * 1000, 7.0 * k as f64)]))
        .collect();
    let whole = bag(&entries(&images, &tfs), Compression::Zstd);
    let in_memory = BagRecording::from_bytes(&whole, None).unwrap();
    for compression in [Compression::None, Compression::Lz4, Compression::Zstd] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pings.mcap");
        std::fs::write(
            &path,
            encode::bag_in_chunks(&entries(&images, &tfs), compression, 2),
        )
        .unwrap();
        let rec = BagRecording::open(&path, None).unwrap();
        assert_eq!(rec.frame_count(), 5);
        for k in [4, 0, 3, 1, 2, 2, 0] {
            let f = rec.frame(k).unwrap();
            assert_eq!(
                f.data,
                in_memory.frame(k).unwrap().data,
                "{compression:?} ping {k}"
            );
            assert_eq!(f.data[9 * 128 + 5], ((9 + 7 * 5 + 11 * k) % 253) as u8);
            assert_eq!(rec.roll_deg(k), in_memory.roll_deg(k));
        }
        // A file cut after it was opened: the pings past the cut are refused, no panic.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        let err = rec.frame(4).unwrap_err();
        assert!(
            format!("{err:#}").contains("changed since it was opened"),
            "{err:#}"
        );
    }
}

#[test]
fn port_first_beams_are_turned_round_and_a_ping_without_tf_has_no_roll() {
    let (mut az, ranges, c, _, _) = aris_geometry();
    az.reverse();
    let p = ping(T0, &az, &ranges, c, |r, b| (b % 200) as u8 + (r == 0) as u8);
    let img = encode::cdr::sonar_image(&p);
    let bytes = bag(
        &[Entry {
            topic: "/sonar",
            schema: PROJECTED_SONAR_IMAGE,
            log_time: 0,
            data: &img,
        }],
        Compression::Lz4,
    );
    let rec = BagRecording::from_bytes(&bytes, None).unwrap();
    let f = rec.frame(0).unwrap();
    assert!(f.beam_centres_rad.windows(2).all(|w| w[1] > w[0]));
    // Beam 0 is now the message's last (right-most) beam.
    assert_eq!(f.data[128], 127);
    assert_eq!(f.data[128 + 127], 0);
    assert_eq!((rec.roll_deg(0), rec.attitude(0)), (None, None));
    assert!(
        rec.warnings()[0].contains("no transform"),
        "{:?}",
        rec.warnings()
    );
}

/// A fan that covers the model's: the polar image is the library's resampling of the ping.
/// Here a 60°, 400-beam sonar with 2 mm bins from 1 m: left of 0° it reads 100, right 200;
/// nearer than 2.75 m it reads 20 more. Columns and bins wholly on one side read that side's
/// value exactly (box mean along range, linear across beams).
/// A ping of `beams` beams evenly over ±30° at `ranges`: 100 counts to starboard, 200 to port,
/// 20 more nearer than 2.75 m; read back from a bag as frame 0.
fn two_sided_frame(beams: usize, ranges: Vec<f32>) -> (epssn_ros2::SonarFrame, f64) {
    let half = 30f64.to_radians();
    let az: Vec<f64> = (0..beams)
        .map(|b| -half + 2.0 * half * b as f64 / (beams - 1) as f64)
        .collect();
    let az2 = az.clone();
    let ranges2 = ranges.clone();
    let p = ping(T0, &az, &ranges, 0.0, move |r, b| {
        (if az2[b] < 0.0 { 100 } else { 200 }) + if ranges2[r] < 2.75 { 20 } else { 0 }
    });
    let img = encode::cdr::sonar_image(&p);
    let bytes = bag(
        &[Entry {
            topic: "/sonar",
            schema: PROJECTED_SONAR_IMAGE,
            log_time: 0,
            data: &img,
        }],
        Compression::Zstd,
    );
    let f = BagRecording::from_bytes(&bytes, None)
        .unwrap()
        .frame(0)
        .unwrap();
    (f, 2.0 * half / (beams - 1) as f64)
}

/// The model grid's cells clear of the two edges read `two_sided_frame`'s values.
fn assert_reads_two_sides(f: &epssn_ros2::SonarFrame, spacing: f64) {
    assert!(misfit(f).is_none(), "{:?}", misfit(f));
    let polar = f.to_polar().unwrap();
    let cols = &config::INPUT_COLUMN_AZIMUTH_RAD;
    let bin = (config::R_MAX_M - config::R_MIN_M) / config::INPUT_RANGE_BINS as f64;
    let mut checked = 0;
    for i in 0..config::INPUT_RANGE_BINS {
        let lo = config::R_MIN_M + bin * i as f64;
        let near = if lo + bin < 2.745 {
            20
        } else if lo > 2.755 {
            0
        } else {
            continue;
        };
        for (k, &a) in cols.iter().enumerate() {
            let side = if a < -spacing {
                100
            } else if a > spacing {
                200
            } else {
                continue;
            };
            assert_eq!(polar[i * cols.len() + k], side + near, "bin {i} column {k}");
            checked += 1;
        }
    }
    assert!(checked > config::INPUT_LEN / 2);
}

#[test]
fn a_wider_finer_fan_is_resampled_onto_the_model_grid() {
    let ranges = (0..2000).map(|i| 1.0 + 0.002 * i as f32).collect();
    let (f, spacing) = two_sided_frame(400, ranges);
    assert_reads_two_sides(&f, spacing);
}

#[test]
fn uneven_ranges_are_resampled_onto_even_bins_first() {
    // Spacing growing with range (0.3 mm to 3 mm), as a sonar with range-dependent bins.
    let ranges: Vec<f32> = (0..2000)
        .map(|i| 1.0 + 4.0 * (i as f32 / 1999.0).powf(1.5))
        .collect();
    let (f, spacing) = two_sided_frame(400, ranges);
    assert_eq!((f.ranges.start, f.ranges.samples), (1.0, 2000));
    assert!((f.ranges.step - 4.0 / 1999.0).abs() < 1e-6);
    assert_reads_two_sides(&f, spacing);
}

/// What does not fit is named: aperture, too few beams, range window.
#[test]
fn fans_that_do_not_cover_the_model_are_refused_by_name() {
    let fan = |deg: f64, beams: usize, from: f32, to: f32| {
        let half = (deg / 2.0).to_radians();
        let az: Vec<f64> = (0..beams)
            .map(|b| -half + 2.0 * half * b as f64 / (beams - 1) as f64)
            .collect();
        let n = 500;
        let ranges: Vec<f32> = (0..n)
            .map(|i| from + (to - from) * i as f32 / (n - 1) as f32)
            .collect();
        let img = encode::cdr::sonar_image(&ping(T0, &az, &ranges, 1500.0, |_, _| 9));
        let bytes = bag(
            &[Entry {
                topic: "/sonar",
                schema: PROJECTED_SONAR_IMAGE,
                log_time: 0,
                data: &img,
            }],
            Compression::None,
        );
        misfit(
            &BagRecording::from_bytes(&bytes, None)
                .unwrap()
                .frame(0)
                .unwrap(),
        )
    };
    assert_eq!(fan(60.0, 256, 1.0, 5.0), None);
    let narrow = fan(20.0, 256, 1.0, 5.0).unwrap();
    assert!(narrow.starts_with("aperture"), "{narrow}");
    let coarse = fan(40.0, 40, 1.0, 5.0).unwrap();
    assert!(coarse.starts_with("too few beams"), "{coarse}");
    let far = fan(130.0, 512, 5.0, 40.0).unwrap();
    assert!(
        far.starts_with("range window 5.000–40.000 m") && !far.contains(';'),
        "{far}"
    );
}

/// A sonar's range can change in mid-recording: each ping's fan is checked, the ones that do
/// not fit are named, and the bag is refused only when none fits.
#[test]
fn every_ping_is_checked_not_the_first_only() {
    let (az, ranges, c, _, _) = aris_geometry();
    let far: Vec<f32> = ranges.iter().map(|r| r + 3.0).collect();
    let fit = encode::cdr::sonar_image(&ping(T0, &az, &ranges, c, |_, _| 1));
    let moved = encode::cdr::sonar_image(&ping(T0 + 1, &az, &far, c, |_, _| 1));
    let recording = |pings: &[&Vec<u8>]| {
        let entries: Vec<Entry> = pings
            .iter()
            .map(|d| Entry {
                topic: "/sonar",
                schema: PROJECTED_SONAR_IMAGE,
                log_time: 0,
                data: d.as_slice(),
            })
            .collect();
        Recording::Bag(BagRecording::from_bytes(&bag(&entries, Compression::None), None).unwrap())
    };
    let mixed = recording(&[&fit, &moved, &fit]);
    let misfits = mixed.misfit_frames();
    assert_eq!(misfits.len(), 1, "{misfits:?}");
    assert_eq!(misfits[0].0, 1);
    assert!(misfits[0].1.starts_with("range window"), "{misfits:?}");
    assert_eq!(mixed.geometry_mismatch(&misfits), None);
    let none = recording(&[&moved, &moved]);
    let misfits = none.misfit_frames();
    assert_eq!(misfits.len(), 2);
    let why = none.geometry_mismatch(&misfits).unwrap();
    assert!(why.starts_with("range window"), "{why}");
}

#[test]
fn topics_are_chosen_or_refused_by_name() {
    let (az, ranges, c, _, _) = aris_geometry();
    let img = encode::cdr::sonar_image(&ping(T0, &az, &ranges, c, |_, _| 1));
    let e = |topic| Entry {
        topic,
        schema: PROJECTED_SONAR_IMAGE,
        log_time: 0,
        data: &img,
    };
    let two = bag(&[e("/a"), e("/b")], Compression::None);
    let err = BagRecording::from_bytes(&two, None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("2 ") && err.contains("/a, /b") && err.contains("--topic"),
        "{err}"
    );
    assert_eq!(
        BagRecording::from_bytes(&two, Some("/b")).unwrap().topic,
        "/b"
    );
    let err = BagRecording::from_bytes(&two, Some("/c"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("no topic /c"), "{err}");
    let tf_only = bag(
        &[Entry {
            topic: "/tf",
            schema: TF_MESSAGE,
            log_time: 0,
            data: &encode::cdr::tf_message(&[tf(T0, 0.0)]),
        }],
        Compression::None,
    );
    let err = BagRecording::from_bytes(&tf_only, None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("no marine_acoustic_msgs/msg/ProjectedSonarImage topic"),
        "{err}"
    );
    let err = BagRecording::from_bytes(&tf_only, Some("/tf"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("carries tf2_msgs/msg/TFMessage"), "{err}");
}

#[test]
fn wider_dtypes_read_as_their_top_bits_and_bad_images_are_refused() {
    let (az, ranges, c, _, _) = aris_geometry();
    let mut p = ping(T0, &az, &ranges, c, |_, _| 0);
    p.image.dtype = 2;
    p.image.data = (0..az.len() * ranges.len())
        .flat_map(|i| ((i % 65536) as u16).to_le_bytes())
        .collect();
    let read = |p: &ProjectedSonarImage| {
        let img = encode::cdr::sonar_image(p);
        let bytes = bag(
            &[Entry {
                topic: "/sonar",
                schema: PROJECTED_SONAR_IMAGE,
                log_time: 0,
                data: &img,
            }],
            Compression::Lz4,
        );
        BagRecording::from_bytes(&bytes, None).unwrap().frame(0)
    };
    let f = read(&p).unwrap();
    assert_eq!(f.data[1000], (1000u32 >> 8) as u8);
    let mut bad = p.clone();
    bad.image.beam_count = 3;
    assert!(read(&bad).unwrap_err().to_string().contains("ping 0"));
    let mut short = p.clone();
    short.image.data.truncate(100);
    let err = format!("{:#}", read(&short).unwrap_err());
    assert!(err.contains("elements"), "{err}");
}

#[test]
fn broken_files_are_refused_without_a_panic() {
    let (az, ranges, c, _, _) = aris_geometry();
    let img = encode::cdr::sonar_image(&ping(T0, &az, &ranges, c, |_, _| 1));
    let entry = [Entry {
        topic: "/sonar",
        schema: PROJECTED_SONAR_IMAGE,
        log_time: 0,
        data: &img,
    }];
    for compression in [Compression::None, Compression::Lz4, Compression::Zstd] {
        let good = bag(&entry, compression);
        // Every prefix and a flipped byte at many places: an error or a bag, never a panic.
        for cut in (0..good.len()).step_by(97) {
            let _ = BagRecording::from_bytes(&good[..cut], None).map(|b| b.frame(0));
        }
        for at in (8..good.len()).step_by(61) {
            let mut bad = good.clone();
            bad[at] ^= 0x5a;
            let _ = BagRecording::from_bytes(&bad, None).map(|b| b.frame(0));
        }
    }
    let err = BagRecording::from_bytes(b"not a bag", None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("not an MCAP file"), "{err}");
}
