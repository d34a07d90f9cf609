//! A ROS 2 bag (MCAP) as a sonar recording: the pings of one ProjectedSonarImage topic in log
//! time order, each ping's attitude from the bag's transforms and its roll from them.
//!
//! - **Topic**: the one given, else the only ProjectedSonarImage topic of the bag (an error
//!   names them when there are none or several).
//! - **Attitude** of a ping: the rotation of its image's `frame_id` in the root frame of its
//!   `/tf` (and `/tf_static`) tree at the ping's stamp ([`crate::tf`]; a chain of static
//!   transforms alone is a mount, no attitude), turned from the
//!   message's axes (Z forward, X up, Y starboard) into the sonar frame of docs/POSE.md
//!   (x forward, y port, z up).
//! - **Roll** of a ping: the twist about its forward axis (right-handed, ARIS SonarRoll's
//!   sense) of its rotation in the fixed frame, by the library's decomposition
//!   (`epssn::attitude::Relative`): for a level sonar on a rotator, the rotator's roll. It
//!   only proposes candidates; the baseline of a pair is then the twist of the two pings'
//!   relative rotation, which the pose gate checks (docs/POSE.md) as for an ARIS file.
//! - **Memory**: the bag is scanned once as a stream (one chunk in memory at a time); each ping
//!   is then read again from the file by its location when asked for, its chunk decompressed
//!   once for the pings it holds. A bag larger than memory reads as a small one.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::{bail, Context, Result};
use epssn::attitude::Attitude;

use crate::decode::{self, Contents, Location};
use crate::frame::SonarFrame;
use crate::header::slice_at;
use crate::msgs::{
    decode_sonar_image, decode_tf_message, ProjectedSonarImage, PROJECTED_SONAR_IMAGE, TF_MESSAGE,
};
use crate::ping::frame_of;
use crate::tf::{mul, Quat, TfTree};
use crate::McapError;

/// The rotation taking the message's axes to the sonar frame's: 180° about (X + Z)/√2, which
/// swaps X and Z and turns Y round.
const MESSAGE_TO_SONAR: Quat = [
    std::f64::consts::FRAC_1_SQRT_2,
    0.0,
    std::f64::consts::FRAC_1_SQRT_2,
    0.0,
];

/// The rotation `q` (`[x, y, z, w]`) of a frame in the message's axes as the attitude of the
/// sonar frame (`q ⊗ MESSAGE_TO_SONAR⁻¹`; the rotation is its own inverse).
pub fn attitude_of(q: Quat) -> Option<Attitude> {
    let [x, y, z, w] = mul(q, MESSAGE_TO_SONAR);
    Attitude::from_array([w as f32, x as f32, y as f32, z as f32])
}

/// Whether a schema name is the sonar image (`pkg/msg/Type`, or the older `pkg/Type`).
fn is_sonar_image(name: &str) -> bool {
    name == PROJECTED_SONAR_IMAGE || name == "marine_acoustic_msgs/ProjectedSonarImage"
}

fn is_tf(name: &str) -> bool {
    name == TF_MESSAGE || name == "tf2_msgs/TFMessage"
}

/// Where a bag's bytes are read from again.
#[derive(Debug)]
enum Source {
    File(PathBuf),
    Memory(Arc<[u8]>),
}

impl Source {
    /// The `len` bytes at `offset`.
    fn read_at(&self, offset: u64, len: u64) -> Result<Vec<u8>, McapError> {
        let io = |e: std::io::Error| McapError::Io(e.to_string());
        match self {
            Self::File(path) => {
                let mut f = File::open(path).map_err(io)?;
                f.seek(SeekFrom::Start(offset)).map_err(io)?;
                let mut out = Vec::new();
                f.take(len).read_to_end(&mut out).map_err(io)?;
                if (out.len() as u64) < len {
                    return Err(McapError::Changed("the file is shorter"));
                }
                Ok(out)
            }
            Self::Memory(bytes) => slice_at(bytes, offset, len)
                .map(<[u8]>::to_vec)
                .ok_or(McapError::Changed("the bytes are shorter")),
        }
    }
}

/// The bag's source and the last chunk decompressed (consecutive pings share chunks).
#[derive(Debug)]
struct Store {
    source: Source,
    last_chunk: Mutex<Option<(u64, Arc<Vec<u8>>)>>,
}

impl Store {
    /// The message at `at`: a chunk's from the last chunk when it is that one, else read from
    /// the source.
    fn message(&self, at: &Location) -> Result<Vec<u8>, McapError> {
        if at.in_chunk.is_none() {
            let record = self.source.read_at(at.record, at.record_len)?;
            return Ok(decode::message_record(&record)?.data);
        }
        let mut last = self.last_chunk.lock().unwrap_or_else(|e| e.into_inner());
        let records = match last.as_ref() {
            Some((offset, records)) if *offset == at.record => Arc::clone(records),
            _ => {
                let record = self.source.read_at(at.record, at.record_len)?;
                let records = Arc::new(decode::chunk_records(&record)?);
                *last = Some((at.record, Arc::clone(&records)));
                records
            }
        };
        drop(last);
        Ok(decode::message_in_chunk(&records, at)?.data)
    }
}

/// A bag's sonar pings.
#[derive(Clone, Debug)]
pub struct BagRecording {
    /// The topic read.
    pub topic: String,
    store: Arc<Store>,
    locations: Vec<Location>,
    attitudes: Vec<Option<Attitude>>,
    rolls: Vec<Option<f64>>,
    warnings: Vec<String>,
}

impl BagRecording {
    /// Reads the bag at `path`.
    pub fn open(path: &Path, topic: Option<&str>) -> Result<Self> {
        let file = File::open(path).with_context(|| format!("reading {}", path.display()))?;
        Self::scan(
            BufReader::with_capacity(1 << 20, file),
            Source::File(path.to_path_buf()),
            topic,
        )
        .with_context(|| format!("reading {}", path.display()))
    }

    /// Reads a bag held in memory.
    pub fn from_bytes(bytes: &[u8], topic: Option<&str>) -> Result<Self> {
        Self::scan(bytes, Source::Memory(bytes.into()), topic)
    }

    fn scan(reader: impl Read, source: Source, topic: Option<&str>) -> Result<Self> {
        // Every sonar image's location, stamp and frame (the topic is chosen once the channels
        // are all known), and the transforms as they come.
        type Image = (u16, u64, Location, Result<(String, i64), McapError>);
        let mut images: Vec<Image> = Vec::new();
        let mut tree = TfTree::default();
        let mut bad_tf = None;
        let contents = decode::scan(
            reader,
            &|s| is_sonar_image(s) || is_tf(s),
            &mut |contents, m, at| {
                let Some(channel) = contents.channels.get(&m.channel_id) else {
                    return Ok(());
                };
                if is_tf(contents.schema_name(channel)) {
                    match decode_tf_message(&m.data) {
                        Ok(transforms) => tree.add(&transforms, channel.topic == "/tf_static"),
                        Err(e) => {
                            bad_tf.get_or_insert((m.log_time, e));
                        }
                    }
                } else {
                    // The header only (frame and stamp, for the attitude); the ping itself is
                    // read again when asked for.
                    let header = decode_sonar_image(&m.data)
                        .map(|msg| (msg.header.frame_id, msg.header.stamp_ns));
                    images.push((m.channel_id, m.log_time, at, header));
                }
                Ok(())
            },
        )?;
        if let Some((log_time, e)) = bad_tf {
            return Err(e).with_context(|| format!("a TFMessage at log time {log_time} ns"));
        }
        let (channel, topic) = choose_topic(&contents, topic)?;
        images.retain(|p| p.0 == channel);
        // Log time order; the sort is stable, so pings logged at one time keep file order.
        images.sort_by_key(|p| p.1);
        let mut attitudes = Vec::with_capacity(images.len());
        let mut frames_without = Vec::new();
        let mut locations = Vec::with_capacity(images.len());
        for (i, (_, _, at, header)) in images.into_iter().enumerate() {
            let (frame, stamp) = header.with_context(|| format!("{topic} ping {i}"))?;
            locations.push(at);
            let attitude = tree
                .rotation_in_root(&frame, stamp)
                .and_then(|(q, _)| attitude_of(q));
            if attitude.is_none() {
                frames_without.push(frame);
            }
            attitudes.push(attitude);
        }
        let mut warnings = Vec::new();
        if !frames_without.is_empty() {
            frames_without.dedup();
            warnings.push(format!(
                "{} of {} ping(s) have no transform of their frame ({}) in /tf: no roll, not \
                 paired by roll",
                attitudes.iter().filter(|a| a.is_none()).count(),
                attitudes.len(),
                frames_without.join(", ")
            ));
        }
        let rolls = attitudes
            .iter()
            .map(|a| Some(f64::from(Attitude::IDENTITY.relative(a.as_ref()?).roll_deg)))
            .collect();
        Ok(Self {
            topic,
            store: Arc::new(Store {
                source,
                last_chunk: Mutex::new(None),
            }),
            locations,
            attitudes,
            rolls,
            warnings,
        })
    }

    /// Pings read.
    pub fn frame_count(&self) -> usize {
        self.locations.len()
    }

    /// Ping `i`'s message, read from the bag and decoded.
    pub fn message(&self, i: usize) -> Result<ProjectedSonarImage> {
        let Some(at) = self.locations.get(i) else {
            bail!(
                "ping {i}: the bag holds {} on {}",
                self.locations.len(),
                self.topic
            );
        };
        let data = self
            .store
            .message(at)
            .with_context(|| format!("{} ping {i}", self.topic))?;
        decode_sonar_image(&data).with_context(|| format!("{} ping {i}", self.topic))
    }

    /// Ping `i` as a native frame.
    pub fn frame(&self, i: usize) -> Result<SonarFrame> {
        frame_of(&self.message(i)?, i).with_context(|| format!("{} ping {i}", self.topic))
    }

    /// Gives the pings without a transform in /tf the attitude `of(i)` says (`--poses`), and
    /// their roll from it; returns how many it placed.
    pub fn fill_attitudes(&mut self, of: impl Fn(usize) -> Option<Attitude>) -> usize {
        let mut placed = 0;
        for (i, a) in self.attitudes.iter_mut().enumerate() {
            if a.is_none() {
                if let Some(given) = of(i) {
                    *a = Some(given);
                    self.rolls[i] = Some(f64::from(Attitude::IDENTITY.relative(&given).roll_deg));
                    placed += 1;
                }
            }
        }
        placed
    }

    /// Ping `i`'s attitude (docs/POSE.md's convention).
    pub fn attitude(&self, i: usize) -> Option<Attitude> {
        self.attitudes.get(i).copied().flatten()
    }

    /// Ping `i`'s roll, degrees.
    pub fn roll_deg(&self, i: usize) -> Option<f64> {
        self.rolls.get(i).copied().flatten()
    }

    /// What reading the bag noticed.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }
}

/// The channel and topic of the sonar images to read.
fn choose_topic(contents: &Contents, want: Option<&str>) -> Result<(u16, String)> {
    let sonar: Vec<_> = contents
        .channels
        .values()
        .filter(|c| is_sonar_image(contents.schema_name(c)))
        .collect();
    if let Some(want) = want {
        return match contents.channels.values().find(|c| c.topic == want) {
            Some(c) if is_sonar_image(contents.schema_name(c)) => Ok((c.id, c.topic.clone())),
            Some(c) => bail!(
                "topic {want} carries {}, not {PROJECTED_SONAR_IMAGE}",
                contents.schema_name(c)
            ),
            None => bail!(
                "the bag has no topic {want} (its topics: {})",
                topics(contents)
            ),
        };
    }
    match sonar.as_slice() {
        [c] => Ok((c.id, c.topic.clone())),
        [] => bail!(
            "the bag has no {PROJECTED_SONAR_IMAGE} topic (its topics: {})",
            topics(contents)
        ),
        several => bail!(
            "the bag has {} {PROJECTED_SONAR_IMAGE} topics ({}): choose one with --topic",
            several.len(),
            several
                .iter()
                .map(|c| c.topic.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

fn topics(contents: &Contents) -> String {
    let all: Vec<String> = contents
        .channels
        .values()
        .map(|c| format!("{} ({})", c.topic, contents.schema_name(c)))
        .collect();
    if all.is_empty() {
        "none".into()
    } else {
        all.join(", ")
    }
}
