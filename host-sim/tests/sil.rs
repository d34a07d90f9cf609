//! Software in the loop: the firmware in QEMU against the host library, and its liveness
//! under malformed input. Needs `qemu-system-arm` and the thumbv7em target (scripts/test-all.sh
//! installs both); builds the firmware through `host-sim sil`.

use std::process::Command;

mod common;

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

/// Runs `host-sim sil ARGS --json`, fails the test with both streams unless it succeeds, and
/// returns its JSON report.
fn sil_json<I, S>(args: I) -> serde_json::Value
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let out = host_sim()
        .arg("sil")
        .args(args)
        .arg("--json")
        .output()
        .expect("run host-sim sil");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "host-sim sil failed: {}\n{}",
        stdout,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&stdout).expect("JSON report")
}

#[test]
fn sil_is_bit_exact_and_firmware_survives_fuzz() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("sil.mcap");
    let r = sil_json([
        "--frames",
        "3",
        "--fuzz",
        "200",
        "--seed",
        "11",
        "--faults",
        "1",
        "--mcap",
        bag.to_str().unwrap(),
    ]);
    device_mcap_holds_the_stream_and_the_maps(&bag, &r);
    // The bundled demo recording's first frames have rolls 0, 7, 0: frame 2 (7°) completes a
    // pair with frame 1 as reference, frame 3 (0°) one with itself as reference and frame 2 as
    // source (the lower roll is always the reference).
    assert_eq!(r["depth_maps"], 2, "{r}");
    assert_eq!(r["expected_depth_maps"], 2);
    assert_eq!(r["bit_exact"], true);
    assert_eq!(r["mismatched_values"], 0);
    assert_eq!(r["pairs"], serde_json::json!([[1, [2]], [3, [2]]]));
    let instr = r["instructions_per_depth_map"].as_u64().unwrap();
    assert!(instr > 1_000_000, "instructions per depth map {instr}");
    let (ram, flash) = (
        r["ram_bytes"].as_u64().unwrap(),
        r["flash_bytes"].as_u64().unwrap(),
    );
    let stack = r["stack_high_water_bytes"].as_u64().unwrap();
    assert!(stack > 0 && ram > stack, "ram {ram} stack {stack}");
    // The budgets of weights/budgets.json (which `host-sim sil` itself enforces).
    let b =
        epssn_sil_core::budgets::Budgets::load(&epssn_sil_core::budgets::default_path()).unwrap();
    assert!(ram <= b.ram_bytes, "RAM budget: {ram}");
    assert!(flash > 0 && flash <= b.flash_bytes, "flash budget: {flash}");
    assert!(
        instr <= b.instructions_per_depth_map,
        "instruction budget: {instr}"
    );
    assert_eq!(r["budget_violations"], serde_json::json!([]));
    // Liveness: every status request between malformed messages was answered, every
    // malformed message got an error reply, and the firmware shut down on request.
    let f = &r["fuzz"];
    assert_eq!(f["status_requests"], 200);
    assert_eq!(f["status_replies"], 200);
    assert_eq!(f["unanswered"], 0);
    let sent: u64 = f["sent"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert_eq!(sent, 200);
    assert!(
        f["sent"].as_object().unwrap().len() >= 7,
        "kinds: {}",
        f["sent"]
    );
    assert_eq!(r["alive"], true);
    // The device counted the errors it replied.
    let replied: u64 = f["error_replies"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    let faults = &r["faults"];
    assert_eq!(
        r["device_errors"].as_u64().unwrap(),
        replied + faults["error_replies"].as_u64().unwrap()
    );
    // The fault campaign: every class sent, answered with its code and recovered from, then
    // the frames again after a hello, bit-exact.
    let classes = faults["classes"].as_object().unwrap();
    assert_eq!(
        classes.len(),
        epssn_sil_core::faults::CLASSES.len(),
        "{faults}"
    );
    for (name, c) in classes {
        assert_eq!(c["sent"], 1, "{name}: {c}");
        assert_eq!(c["answered_expected"], 1, "{name}: {c}");
        assert_eq!(c["recovered"], 1, "{name}: {c}");
    }
    assert_eq!(faults["failed"], 0);
    assert_eq!(r["after_faults_bit_exact"], true);
    assert_eq!(r["after_faults_depth_maps"], 2);
}

/// `sil --mcap`: every frame streamed and every map the device returned, stamped with the ARIS
/// frame times, the maps' values inside the reach of the end bins, and the report itself.
fn device_mcap_holds_the_stream_and_the_maps(path: &std::path::Path, report: &serde_json::Value) {
    use epssn_sil_core::mcap_out::topic;
    let bytes = std::fs::read(path).unwrap();
    let mut by_topic: std::collections::BTreeMap<String, Vec<(u64, Vec<u8>)>> = Default::default();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        by_topic
            .entry(m.channel.topic.clone())
            .or_default()
            .push((m.log_time, m.data.to_vec()));
    }
    let recording = epssn_sim::dataset::demo_dir().join("recording.aris");
    let reader = epssn_aris::aris::ArisReader::open(&recording).unwrap();
    let time_ns = |f: usize| reader.frame(f).unwrap().header.frame_time_us * 1000;
    let frame_times: Vec<u64> = (0..3).map(time_ns).collect();
    for t in [topic::POLAR, topic::FAN] {
        let times: Vec<u64> = by_topic[t].iter().map(|(t, _)| *t).collect();
        assert_eq!(times, frame_times, "{t}");
    }
    let pairs = report["pairs"].as_array().unwrap();
    for t in [topic::DEPTH, topic::POINTS, topic::REPLY] {
        assert_eq!(by_topic[t].len(), pairs.len(), "{t}");
    }
    for (k, pair) in pairs.iter().enumerate() {
        let reference = pair[0].as_u64().unwrap() as usize;
        let (time, data) = &by_topic[topic::DEPTH][k];
        assert_eq!(
            *time,
            time_ns(reference - 1),
            "map {k} at its reference's time"
        );
        // A 32FC1 image ends with its pixels, little-endian f32.
        let pixels = &data[data.len() - 4 * epssn::config::DEPTH_LEN..];
        // The end bins reach END_BIN_OFFSET steps past the window, and the depths are U16F16
        // (to one 2^-16 m step).
        use epssn::config::{DEPTH_RANGE_BINS, END_BIN_OFFSET, R_MAX_M, R_MIN_M};
        let bin = (R_MAX_M - R_MIN_M) / (DEPTH_RANGE_BINS - 1) as f64;
        let reach = f64::from(END_BIN_OFFSET) * bin + 1.0 / 65536.0;
        let window = (R_MIN_M - reach) as f32..=(R_MAX_M + reach) as f32;
        let depths: Vec<f32> = pixels
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let outside: Vec<f32> = depths
            .iter()
            .copied()
            .filter(|d| !window.contains(d))
            .collect();
        assert!(
            outside.is_empty(),
            "map {k}: {outside:?} outside {window:?}"
        );
        // A std_msgs/String is a CDR header, a u32 length and the text with its NUL.
        let (_, reply) = &by_topic[topic::REPLY][k];
        let reply: serde_json::Value = serde_json::from_slice(&reply[8..reply.len() - 1]).unwrap();
        assert_eq!(
            (&reply["reference"], &reply["sources"], &reply["bit_exact"]),
            (&pair[0], &pair[1], &serde_json::json!(true))
        );
    }
    let (_, summary) = &by_topic[topic::SUMMARY][0];
    let summary: serde_json::Value =
        serde_json::from_slice(&summary[8..summary.len() - 1]).unwrap();
    assert_eq!(summary["pairs"], report["pairs"]);
    assert_eq!(summary["mismatched_values"], 0);
}

#[test]
fn recording_with_unfit_geometry_is_refused() {
    let rec = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/aris1200-telephoto-6frames.aris"
    );
    let out = host_sim()
        .args(["sil", "--recording", rec])
        .output()
        .expect("run host-sim sil");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("geometry does not fit the model"),
        "stderr: {err}"
    );
}

/// The SIL streams every frame as a vehicle's host would: a frame whose own window does not
/// fit is refused by name before the device starts.
#[test]
fn a_frame_outside_the_window_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let rec = common::demo_with_a_moved_window(dir.path(), 4);
    let out = host_sim()
        .args(["sil", "--recording"])
        .arg(&rec)
        .output()
        .expect("run host-sim sil");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("frame 4 does not fit the model") && err.contains("range window 7."),
        "stderr: {err}"
    );
}

#[test]
fn short_soak_keeps_maps_bit_exact_and_the_stack_unchanged() {
    // One block (19 faults, a hello, the 3 frames again): the soak's bookkeeping on a run short
    // enough for CI; docs/LINK.md has the figures of a 5,000-message soak.
    let r = sil_json(["--frames", "3", "--soak", "40", "--seed", "5"]);
    let s = &r["soak"];
    let blocks = s["blocks"].as_u64().unwrap();
    assert!(blocks >= 1, "{s}");
    assert!(s["messages"].as_u64().unwrap() >= 40, "{s}");
    assert_eq!(s["valid_frames"].as_u64().unwrap(), 3 * blocks);
    assert_eq!(s["depth_maps"].as_u64().unwrap(), 2 * blocks, "{s}");
    assert_eq!(s["expected_depth_maps"], s["depth_maps"]);
    assert_eq!(s["mismatched_values"], 0);
    assert_eq!(s["stack_unchanged"], true);
    assert!(s["stack_high_water_before"].as_u64().unwrap() > 0);
    // The same table as the campaign: every class sent once per block, answered, recovered.
    let f = &r["faults"];
    let classes = f["classes"].as_object().unwrap();
    assert_eq!(classes.len(), epssn_sil_core::faults::CLASSES.len(), "{f}");
    for (name, c) in classes {
        assert_eq!(c["sent"].as_u64(), Some(blocks), "{name}: {c}");
        assert_eq!(c["answered_expected"], c["sent"], "{name}: {c}");
        assert_eq!(c["recovered"], c["sent"], "{name}: {c}");
    }
    assert_eq!(f["failed"], 0);
    assert_eq!(r["after_faults_bit_exact"], true);
    assert_eq!(r["alive"], true);
}

#[test]
fn the_device_rejects_the_same_jittered_pairs_as_the_host() {
    let tol = epssn::config::PAIR_RESIDUAL_TOLERANCE_DEG;
    let dir = tempfile::tempdir().unwrap();
    let rec = common::jittered_recording(dir.path(), 0.5 * tol, 2.0 * tol);
    let mut args: Vec<std::ffi::OsString> = ["--frames", "8", "--faults", "0", "--recording"]
        .iter()
        .map(Into::into)
        .collect();
    args.push(rec.into());
    let r = sil_json(args);
    // Seqs are frame index + 1; odd seqs are references (roll 0, level), even ones sources
    // (roll 7°), 2 and 6 with the low jitter, 4 and 8 with the high. The device pairs each new
    // frame with the cache (the lower roll is the reference), so 3 pairs with the cached 2 as
    // well; every pair with source 4 or 8 is refused for its residual, on device and host.
    assert_eq!(
        r["pairs"],
        serde_json::json!([[1, [2]], [3, [2]], [5, [6]], [7, [6]]]),
        "{r}"
    );
    assert_eq!(
        r["rejected_pairs"],
        serde_json::json!([[3, 4, "residual"], [5, 4, "residual"], [7, 8, "residual"]]),
        "{r}"
    );
    assert_eq!(r["rejections_agree"], true);
    assert_eq!(r["bit_exact"], true);
    assert_eq!(r["budget_violations"], serde_json::json!([]));
}

/// `--topic` picks a bag's sonar topic: without it a bag of two is refused naming both, an
/// unknown one is named, and the chosen one is read (its narrow fan then refused as unfit).
#[test]
fn a_bag_topic_is_chosen_by_name() {
    use epssn_ros2::encode::{bag, cdr, even_azimuths, level_ping, Compression, Entry};
    use epssn_ros2::msgs::PROJECTED_SONAR_IMAGE;
    let (beams, bins) = (16usize, 32usize);
    let ranges: Vec<f32> = (0..bins).map(|r| 1.0 + 0.05 * r as f32).collect();
    let flat = vec![9; beams * bins];
    let img = cdr::sonar_image(&level_ping(
        1,
        &even_azimuths(beams, 0.1),
        &ranges,
        1500.0,
        0,
        flat,
    ));
    let entry = |topic| Entry {
        topic,
        schema: PROJECTED_SONAR_IMAGE,
        log_time: 0,
        data: &img,
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two.mcap");
    std::fs::write(&path, bag(&[entry("/a"), entry("/b")], Compression::None)).unwrap();
    let refusal = |topic: Option<&str>| {
        let mut cmd = host_sim();
        cmd.args(["sil", "--recording"]).arg(&path);
        if let Some(t) = topic {
            cmd.args(["--topic", t]);
        }
        let out = cmd.output().expect("run host-sim sil");
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = refusal(None);
    assert!(err.contains("/a, /b") && err.contains("--topic"), "{err}");
    let err = refusal(Some("/c"));
    assert!(err.contains("/c"), "{err}");
    let err = refusal(Some("/b"));
    assert!(err.contains("geometry does not fit the model"), "{err}");
}

/// `host-sim push --qemu`: site-tank's blob signed with the test key (the key the test builds
/// of the firmware carry) is uploaded, committed, and after the device restarts its hello
/// names it.
#[test]
fn push_over_qemu_makes_the_signed_model_serve() {
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let image = dir.path().join("site-tank.signed");
    let signed = host_sim()
        .args(["sign", "--key"])
        .arg(root.join("update/test-key/private"))
        .arg("--blob")
        .arg(root.join("weights/site-tank/epssn-s.q8.bin"))
        .args(["--version", "1", "--out"])
        .arg(&image)
        .output()
        .expect("run host-sim sign");
    assert!(signed.status.success(), "{signed:?}");
    let out = host_sim()
        .args(["push", "--qemu", "--blob"])
        .arg(&image)
        .output()
        .expect("run host-sim push");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "host-sim push failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.first(), Some(&"device serves version 0 (slot None)"));
    assert!(
        lines.contains(&"uploaded 23848 bytes from offset 0 in 6 chunks"),
        "{stdout}"
    );
    assert_eq!(
        lines.last(),
        Some(&"device serves version 1 (slot Some(0))")
    );
}
