//! `run --mcap` read back independently: the file is opened with the `mcap` crate's reader and
//! every message decoded by this file's own CDR reader (not the writer's code), then checked
//! against the recording's frame headers, `run --json` and the ground truth; a recording
//! without attitude still gets every per-pair message; and `--frame world` on a simulated roll
//! sweep of one scene puts the merged cloud on the scene's surfaces as closely as each pair's
//! own cloud, where a wrongly turned cloud does not.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS, INPUT_COLUMNS, INPUT_RANGE_BINS};
use epssn_aris::aris::{write_recording, ArisReader, FrameHeader};
use epssn_aris::npy;
use epssn_sim::metrics;

const ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
/// The topics `run --mcap` writes once per pair.
const PER_PAIR_TOPICS: [&str; 5] = [
    "/depth/int8",
    "/depth/float",
    "/depth/ground_truth",
    "/points/int8",
    "/points/float",
];

fn host_sim() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_host-sim"));
    c.current_dir(ROOT);
    c
}

/// Runs to success; the JSON on stdout.
fn run_json(cmd: &mut Command) -> serde_json::Value {
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

// --- An independent little-endian CDR reader (ROS 2's encapsulation, alignment from the
// first byte after the 4-byte header).

struct Cdr<'a> {
    body: &'a [u8],
    pos: usize,
}

impl<'a> Cdr<'a> {
    fn new(data: &'a [u8]) -> Self {
        assert_eq!(&data[..4], &[0, 1, 0, 0], "CDR_LE encapsulation");
        Self {
            body: &data[4..],
            pos: 0,
        }
    }
    fn take(&mut self, n: usize, align: usize) -> &'a [u8] {
        self.pos = self.pos.div_ceil(align) * align;
        let s = &self.body[self.pos..self.pos + n];
        self.pos += n;
        s
    }
    fn u8(&mut self) -> u8 {
        self.take(1, 1)[0]
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take(4, 4).try_into().unwrap())
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take(4, 4).try_into().unwrap())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take(8, 8).try_into().unwrap())
    }
    fn string(&mut self) -> String {
        let n = self.u32() as usize;
        let s = self.take(n, 1);
        assert_eq!(s.last(), Some(&0), "strings end in NUL");
        String::from_utf8(s[..n - 1].to_vec()).unwrap()
    }
    fn bytes(&mut self) -> Vec<u8> {
        let n = self.u32() as usize;
        self.take(n, 1).to_vec()
    }
    /// std_msgs/Header: (stamp in ns, frame_id).
    fn header(&mut self) -> (u64, String) {
        let sec = self.i32();
        let nanosec = self.u32();
        (sec as u64 * 1_000_000_000 + nanosec as u64, self.string())
    }
    fn end(&self) {
        assert_eq!(self.pos, self.body.len(), "trailing bytes");
    }
}

struct Image {
    stamp: u64,
    frame_id: String,
    height: usize,
    width: usize,
    encoding: String,
    data: Vec<u8>,
}

fn image(data: &[u8]) -> Image {
    let mut c = Cdr::new(data);
    let (stamp, frame_id) = c.header();
    let (height, width) = (c.u32() as usize, c.u32() as usize);
    let encoding = c.string();
    assert_eq!(c.u8(), 0, "little endian");
    let step = c.u32() as usize;
    let data = c.bytes();
    c.end();
    assert_eq!(data.len(), step * height);
    Image {
        stamp,
        frame_id,
        height,
        width,
        encoding,
        data,
    }
}

fn floats(img: &Image) -> Vec<f32> {
    assert_eq!(img.encoding, "32FC1");
    img.data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

/// A decoded PointCloud2: stamp, frame, and each point's named FLOAT32 / UINT32 fields as f64.
struct Cloud {
    stamp: u64,
    frame_id: String,
    points: Vec<BTreeMap<String, f64>>,
}

fn cloud(data: &[u8]) -> Cloud {
    let mut c = Cdr::new(data);
    let (stamp, frame_id) = c.header();
    let (height, width) = (c.u32() as usize, c.u32() as usize);
    let fields: Vec<(String, usize, u8)> = (0..c.u32())
        .map(|_| {
            let name = c.string();
            let offset = c.u32() as usize;
            let datatype = c.u8();
            assert_eq!(c.u32(), 1, "count");
            (name, offset, datatype)
        })
        .collect();
    assert_eq!(c.u8(), 0, "little endian");
    let step = c.u32() as usize;
    let row_step = c.u32() as usize;
    let data = c.bytes();
    let _dense = c.u8();
    c.end();
    assert_eq!(
        (height, row_step, data.len()),
        (1, width * step, width * step)
    );
    let points = data
        .chunks_exact(step)
        .map(|p| {
            fields
                .iter()
                .map(|(name, off, ty)| {
                    let b: [u8; 4] = p[*off..off + 4].try_into().unwrap();
                    let v = match ty {
                        7 => f32::from_le_bytes(b) as f64,
                        6 => u32::from_le_bytes(b) as f64,
                        t => panic!("datatype {t}"),
                    };
                    (name.clone(), v)
                })
                .collect()
        })
        .collect();
    Cloud {
        stamp,
        frame_id,
        points,
    }
}

/// TFMessage: (stamp, parent, child, translation, [w, x, y, z]) per transform.
type Tf = (u64, String, String, [f64; 3], [f64; 4]);

fn tf(data: &[u8]) -> Vec<Tf> {
    let mut c = Cdr::new(data);
    let n = c.u32();
    let out = (0..n)
        .map(|_| {
            let (stamp, parent) = c.header();
            let child = c.string();
            let t = [c.f64(), c.f64(), c.f64()];
            let [x, y, z, w] = [c.f64(), c.f64(), c.f64(), c.f64()];
            (stamp, parent, child, t, [w, x, y, z])
        })
        .collect();
    c.end();
    out
}

fn string(data: &[u8]) -> String {
    let mut c = Cdr::new(data);
    let s = c.string();
    c.end();
    s
}

/// The file's messages by topic, in file order: (log time, data). Checks the ROS 2 profile,
/// the encodings, the summary and the schemas' dependent definitions on the way.
fn messages(path: &Path) -> BTreeMap<String, Vec<(u64, Vec<u8>)>> {
    let bytes = std::fs::read(path).unwrap();
    let header = mcap::read::LinearReader::new(&bytes)
        .unwrap()
        .find_map(|r| match r.unwrap() {
            mcap::records::Record::Header(h) => Some(h),
            _ => None,
        })
        .unwrap();
    assert_eq!(header.profile, "ros2");
    let summary = mcap::read::Summary::read(&bytes).unwrap().expect("summary");
    assert!(!summary.chunk_indexes.is_empty(), "chunked");
    let mut by_topic: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    let mut last = 0;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert!(
            m.log_time >= last,
            "log times go back on {}",
            m.channel.topic
        );
        last = m.log_time;
        assert_eq!(m.publish_time, m.log_time);
        assert_eq!(m.channel.message_encoding, "cdr");
        let schema = m.channel.schema.as_ref().expect("a schema");
        assert_eq!(schema.encoding, "ros2msg");
        let text = String::from_utf8(schema.data.to_vec()).unwrap();
        if schema.name != "std_msgs/msg/String" {
            assert!(text.contains(&format!("{}\nMSG: std_msgs/Header\n", "=".repeat(80))));
        }
        by_topic
            .entry(m.channel.topic.clone())
            .or_default()
            .push((m.log_time, m.data.to_vec()));
    }
    by_topic
}

fn count(m: &BTreeMap<String, Vec<(u64, Vec<u8>)>>, topic: &str) -> usize {
    m.get(topic).map_or(0, Vec::len)
}

/// The demo run: every frame's images and transform at its FrameTime, every pair's depth maps
/// equal to what `run --json` scored (MAE recomputed from the decoded images), its clouds the
/// decoded int8 map's own returns, the summary equal to the JSON printed.
#[test]
fn demo_run_mcap_decodes_to_the_frames_and_the_json() {
    let out = tempfile::tempdir().unwrap();
    let file = out.path().join("run.mcap");
    let v = run_json(
        host_sim()
            .args(["run", "--json", "--out"])
            .arg(out.path())
            .arg("--mcap")
            .arg(&file),
    );
    let pairs = v["pairs"].as_u64().unwrap() as usize;
    let details = v["details"].as_array().unwrap();
    let m = messages(&file);
    let reader = ArisReader::open(Path::new(ROOT).join("data/demo/recording.aris")).unwrap();
    let n = reader.frame_count();
    let times: Vec<u64> = (0..n)
        .map(|i| reader.frame_header(i).unwrap().frame_time_us * 1000)
        .collect();

    for topic in ["/sonar/polar", "/sonar/fan", "/tf"] {
        let got: Vec<u64> = m[topic].iter().map(|(t, _)| *t).collect();
        assert_eq!(
            got, times,
            "{topic}: one message per frame at its FrameTime"
        );
    }
    for (i, (t, data)) in m["/sonar/polar"].iter().enumerate() {
        let img = image(data);
        assert_eq!((img.stamp, img.frame_id.as_str()), (*t, "sonar"));
        assert_eq!((img.height, img.width), (INPUT_RANGE_BINS, INPUT_COLUMNS));
        assert_eq!(img.encoding, "mono8");
        let polar = epssn_aris::polar::frame_to_polar(&reader.frame(i).unwrap()).unwrap();
        assert_eq!(img.data, polar, "frame {i}");
    }
    // The same polar images as ProjectedSonarImage (read back by the bag reader `run
    // --recording` uses): the model's columns at the spec's azimuths, its bins' centres.
    assert_eq!(m["/tf_static"].len(), 1);
    let sonar_images = &m["/sonar/image"];
    assert_eq!(sonar_images.len(), n);
    for (i, ((t, data), (_, polar))) in sonar_images.iter().zip(&m["/sonar/polar"]).enumerate() {
        let msg = epssn_ros2::msgs::decode_sonar_image(data).unwrap();
        assert_eq!(msg.header.stamp_ns as u64, *t);
        assert_eq!(msg.header.frame_id, "sonar_image");
        assert_eq!(msg.image.data, image(polar).data, "frame {i}");
        assert_eq!(msg.ranges.len(), INPUT_RANGE_BINS);
        let az = epssn_ros2::ping::azimuths(&msg.beam_directions).unwrap();
        for (a, want) in az.iter().zip(epssn::config::INPUT_COLUMN_AZIMUTH_RAD) {
            assert!(
                (a - want).abs() < 1e-12,
                "frame {i}: column at {a}, {want} expected"
            );
        }
    }
    for (t, data) in &m["/sonar/fan"] {
        let img = image(data);
        assert_eq!((img.stamp, img.encoding.as_str()), (*t, "mono8"));
        // EPSSN-S: 6 mm pixels over the ±15° fan from 2.0 to 3.536 m (docs/MCAP.md).
        if epssn::config::SPEC_NAME == "EPSSN-S" {
            assert_eq!((img.width, img.height), (308, 268));
        }
        assert!(img.data.iter().any(|&v| v > 0));
    }
    for (i, (_, data)) in m["/tf"].iter().enumerate() {
        let t = tf(data);
        assert_eq!(t.len(), 1);
        let (stamp, parent, child, _, q) = &t[0];
        assert_eq!(
            (*stamp, parent.as_str(), child.as_str()),
            (times[i], "world", "sonar")
        );
        let want = reader.frame_header(i).unwrap().attitude().unwrap();
        for k in 0..4 {
            assert_eq!(q[k], want[k] as f64, "frame {i}");
        }
    }
    let candidates = v["candidates"].as_array().unwrap();
    assert_eq!(count(&m, "/pairing/check"), candidates.len());
    for ((_, data), c) in m["/pairing/check"].iter().zip(candidates) {
        let decoded: serde_json::Value = serde_json::from_str(&string(data)).unwrap();
        assert_eq!(&decoded, c);
    }
    for topic in PER_PAIR_TOPICS {
        assert_eq!(count(&m, topic), pairs, "{topic}");
    }
    for (k, d) in details.iter().enumerate() {
        let reference = d["frames"][0].as_u64().unwrap() as usize;
        let get = |topic: &str| image(&m[topic][k].1);
        let (int8, float, truth) = (
            get("/depth/int8"),
            get("/depth/float"),
            get("/depth/ground_truth"),
        );
        for img in [&int8, &float, &truth] {
            assert_eq!((img.height, img.width), (DEPTH_ROWS, DEPTH_COLUMNS));
            assert_eq!(img.stamp, times[reference]);
        }
        let (int8, float, truth) = (floats(&int8), floats(&float), floats(&truth));
        let mask =
            npy::read_f32(&Path::new(ROOT).join(format!("data/demo/gt/mask_{reference:04}.npy")))
                .unwrap();
        let mask = metrics::mask_from_f32(&mask.data);
        for (model, depth) in [("int8", &int8), ("float", &float)] {
            let score = metrics::evaluate(depth, &truth, &mask).unwrap();
            let json = d[model]["mae"].as_f64().unwrap();
            assert!(
                (score.mae - json).abs() <= 1e-9 * json,
                "{model} pair {k}: {} vs {json}",
                score.mae
            );
        }
        let c = cloud(&m["/points/int8"][k].1);
        assert_eq!((c.stamp, c.frame_id.as_str()), (times[reference], "sonar"));
        let want = metrics::depth_points(&int8, &metrics::prediction_mask(&int8)).unwrap();
        assert_eq!(c.points.len(), want.len());
        for (p, w) in c.points.iter().zip(&want) {
            for (axis, wv) in ["x", "y", "z"].iter().zip(w) {
                assert_eq!(p[*axis], *wv as f32 as f64);
            }
            let r = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            assert!((p["range"] - r).abs() < 1e-5 && (0.0..=255.0).contains(&p["intensity"]));
        }
    }
    assert_eq!(
        count(&m, "/sweep/points"),
        0,
        "no merged cloud without --frame world"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&string(&m["/run/summary"][0].1)).unwrap();
    assert_eq!(summary, v);
    assert_eq!(m["/run/summary"][0].0, *times.iter().max().unwrap());
}

/// A recording whose headers carry no platform attitude: every per-pair message is written
/// (roll-only pairing), no transform, and no merged cloud, with the reason in the warnings.
#[test]
fn a_recording_without_attitude_writes_every_pair_and_says_why_no_world_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let reader = ArisReader::open(Path::new(ROOT).join("data/demo/recording.aris")).unwrap();
    let frames: Vec<(FrameHeader, Vec<u8>)> = (0..reader.frame_count())
        .map(|i| {
            let f = reader.frame(i).unwrap();
            let h = f
                .header
                .clone()
                .with_platform_attitude_deg(f32::NAN, f32::NAN, f32::NAN);
            assert!(h.attitude().is_none());
            (h, f.data)
        })
        .collect();
    let rec = dir.path().join("no-attitude.aris");
    let refs: Vec<(&FrameHeader, &[u8])> = frames.iter().map(|(h, d)| (h, d.as_slice())).collect();
    write_recording(&rec, &refs).unwrap();
    let file = dir.path().join("run.mcap");
    let out = dir.path().join("out");
    let v = run_json(
        host_sim()
            .args([
                "run",
                "--json",
                "--frame",
                "world",
                "--gt",
                "data/demo/gt",
                "--recording",
            ])
            .arg(&rec)
            .arg("--out")
            .arg(&out)
            .arg("--mcap")
            .arg(&file),
    );
    let pairs = v["pairs"].as_u64().unwrap() as usize;
    assert!(pairs > 0);
    let warnings = v["warnings"].to_string();
    assert!(
        warnings.contains("no world-frame cloud") && warnings.contains("no attitude"),
        "{warnings}"
    );
    assert!(!out.join("world.ply").exists());
    let m = messages(&file);
    for topic in PER_PAIR_TOPICS {
        assert_eq!(count(&m, topic), pairs, "{topic}");
    }
    assert_eq!(count(&m, "/sonar/polar"), reader.frame_count());
    assert_eq!((count(&m, "/tf"), count(&m, "/sweep/points")), (0, 0));
    assert_eq!(count(&m, "/run/summary"), 1);
}
