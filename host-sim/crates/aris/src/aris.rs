//! ARIS recordings (Sound Metrics DDF_05, `.aris`): typed headers, a streaming reader and a
//! writer. See `docs/ARIS.md` (the facts) and the module tests.
//!
//! Layout: a 1024-byte file header, then frames, each a 1024-byte frame header followed by
//! `beams × samples_per_beam` u8 samples stored sample-major (`data[sample × beams + beam]`,
//! beam 0 right-most). Every integer and float is little-endian.
//!
//! Both headers keep their raw 1024 bytes: typed fields are decoded from them and written
//! back at their offsets by `encode()`, so reserved and unknown bytes survive a read→write
//! round trip bit for bit.
//!
//! The reader trusts nothing in the file: the frame count comes from the file length, sizes
//! are checked before any arithmetic, and samples are read per frame on demand, so multi-GB
//! recordings cost one 1 KiB header read per frame at open.
//!
//! ```
//! use epssn_aris::aris::{write_recording, ArisReader, FrameHeader};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let dir = tempfile::tempdir()?;
//! let path = dir.path().join("view1.aris");
//! // One ARIS 3000 frame, 128 beams × 512 samples of 3 mm (4 µs at 1500 m/s), window from
//! // 2.0 m (2667 µs), rolled by 7°.
//! let header = FrameHeader::new_aris3000(128, 512, 4, 2667, 1500.0)?.with_roll_deg(7.0);
//! let samples = vec![0u8; 128 * 512]; // data[sample * 128 + beam]
//! write_recording(&path, &[(&header, &samples)])?;
//!
//! let reader = ArisReader::open(&path)?;
//! let frame = reader.frame(0)?;
//! let ranges = frame.range_geometry()?; // epssn::geometry::SampleRanges
//! assert!((ranges.start - 2.00025).abs() < 1e-9 && (ranges.step - 0.003).abs() < 1e-12);
//! assert_eq!(frame.header.sonar_roll_deg, 7.0);
//! assert_eq!(reader.beam_centres_rad()?.len(), 128);
//! # Ok(())
//! # }
//! ```

use std::fs::File;
use std::io::{self, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use epssn::geometry::SampleRanges;

pub use crate::beams::{beam_table_for, BeamTable, BeamTableError, SystemType};

/// Size of the file header and of each frame header, bytes.
pub const HEADER_LEN: usize = 1024;
/// The DDF_05 signature, as a little-endian u32 (bytes `"DDF" 0x05`).
pub const DDF05_SIGNATURE: u32 = 0x0546_4444;
/// Beam counts that ARIS sonars produce.
pub const VALID_BEAM_COUNTS: [usize; 4] = [48, 64, 96, 128];
/// Largest samples-per-beam accepted; real files use at most a few thousand.
pub const MAX_SAMPLES_PER_BEAM: usize = 100_000;

/// Errors from reading or writing ARIS files. Nothing in this module panics on bad input.
#[derive(Debug, thiserror::Error)]
pub enum ArisError {
    /// The file could not be opened or created.
    #[error("cannot open {}: {source}", path.display())]
    Open {
        /// The path.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: io::Error,
    },
    /// Any other I/O error.
    #[error("I/O error: {0}")]
    Io(#[from] io::Error),
    /// The signature is not DDF_05.
    #[error(
        "not an ARIS DDF_05 file: {what} starts with bytes {found:02x?} ({}), expected \
         [44, 44, 46, 05] (\"DDF\\x05\")",
        printable(.found)
    )]
    BadSignature {
        /// Which header.
        what: String,
        /// The four bytes found.
        found: [u8; 4],
    },
    /// The file ends inside a header.
    #[error("truncated {what}: needs {needed} bytes at offset {offset}, only {available} present")]
    TruncatedHeader {
        /// Which header.
        what: String,
        /// Where it starts.
        offset: u64,
        /// Bytes needed.
        needed: u64,
        /// Bytes present from `offset` on.
        available: u64,
    },
    /// Neither the frame header's PingMode nor the file header's NumRawBeams gives a usable
    /// beam count.
    #[error(
        "unusable beam count: PingMode {ping_mode} names no known beam count and the file \
         header's NumRawBeams is {num_raw_beams} (expected one of 48, 64, 96, 128)"
    )]
    BadBeamCount {
        /// Frame header PingMode.
        ping_mode: u32,
        /// File header NumRawBeams.
        num_raw_beams: u32,
    },
    /// Samples per beam is 0 or absurdly large.
    #[error("unusable samples per beam {samples} in {what} (expected 1..={MAX_SAMPLES_PER_BEAM})")]
    BadSampleCount {
        /// Which header field.
        what: String,
        /// The value found.
        samples: u32,
    },
    /// The first frame's PingMode and the file header's NumRawBeams disagree.
    #[error(
        "beam count contradicts PingMode: frame 0 PingMode {ping_mode} means {ping_beams} \
         beams but the file header's NumRawBeams is {header_beams}"
    )]
    PingModeMismatch {
        /// Frame header PingMode.
        ping_mode: u32,
        /// Beams implied by it.
        ping_beams: usize,
        /// File header NumRawBeams.
        header_beams: u32,
    },
    /// A frame index past the last complete frame.
    #[error("frame index {index} out of range: the file has {count} complete frames")]
    FrameIndexOutOfRange {
        /// Requested index.
        index: usize,
        /// Complete frames in the file.
        count: usize,
    },
    /// A size or offset does not fit the integer types.
    #[error("size overflow: {0}")]
    SizeOverflow(String),
    /// Writer: the sample slice has the wrong length.
    #[error("frame data has {found} bytes, expected {expected} (beams × samples per beam)")]
    DataLength {
        /// beams × samples.
        expected: usize,
        /// Slice length.
        found: usize,
    },
    /// Writer: a frame's geometry differs from the first frame's (frames must be equal-sized).
    #[error(
        "frame geometry changed: the first frame has {first_beams} beams × {first_samples} \
         samples, this one {beams} × {samples}"
    )]
    GeometryChanged {
        /// First frame's beams.
        first_beams: usize,
        /// First frame's samples per beam.
        first_samples: usize,
        /// This frame's beams.
        beams: usize,
        /// This frame's samples per beam.
        samples: usize,
    },
    /// No beam table fits, or the embedded tables are malformed.
    #[error(transparent)]
    BeamTable(#[from] BeamTableError),
    /// The header's sound speed or sample period cannot give sample ranges.
    #[error("invalid range geometry: {0}")]
    RangeGeometry(String),
}

fn printable(bytes: &[u8; 4]) -> String {
    let text: String = bytes
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
        .collect();
    format!("{text:?}")
}

/// Result alias for this module.
pub type Result<T, E = ArisError> = std::result::Result<T, E>;

/// Beams implied by a frame header PingMode (docs/ARIS.md), `None` for unknown modes.
pub fn beams_for_ping_mode(ping_mode: u32) -> Option<usize> {
    match ping_mode {
        1..=2 => Some(48),
        3..=5 => Some(96),
        6..=8 => Some(64),
        9..=12 => Some(128),
        _ => None,
    }
}

// --- raw field access. Offsets are compile-time constants below 1024, so the slices
// cannot go out of bounds.

fn get_u32(raw: &[u8; HEADER_LEN], off: usize) -> u32 {
    let mut b = [0u8; 4];
    b.copy_from_slice(&raw[off..off + 4]);
    u32::from_le_bytes(b)
}

fn get_u64(raw: &[u8; HEADER_LEN], off: usize) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&raw[off..off + 8]);
    u64::from_le_bytes(b)
}

fn get_f32(raw: &[u8; HEADER_LEN], off: usize) -> f32 {
    // from_bits keeps NaN payloads, so encode() restores them exactly.
    f32::from_bits(get_u32(raw, off))
}

fn put_u32(raw: &mut [u8; HEADER_LEN], off: usize, v: u32) {
    raw[off..off + 4].copy_from_slice(&v.to_le_bytes());
}

fn put_u64(raw: &mut [u8; HEADER_LEN], off: usize, v: u64) {
    raw[off..off + 8].copy_from_slice(&v.to_le_bytes());
}

fn put_f32(raw: &mut [u8; HEADER_LEN], off: usize, v: f32) {
    put_u32(raw, off, v.to_bits());
}

fn get_str(raw: &[u8; HEADER_LEN], off: usize, len: usize) -> String {
    let field = &raw[off..off + len];
    let end = field.iter().position(|&b| b == 0).unwrap_or(len);
    String::from_utf8_lossy(&field[..end]).into_owned()
}

/// Writes a NUL-terminated string, but only if it differs from what the raw bytes already
/// say, so bytes after the terminator survive an unchanged round trip.
fn put_str(raw: &mut [u8; HEADER_LEN], off: usize, len: usize, s: &str) {
    if get_str(raw, off, len) == s {
        return;
    }
    let field = &mut raw[off..off + len];
    field.fill(0);
    let bytes = s.as_bytes();
    let n = bytes.len().min(len - 1);
    field[..n].copy_from_slice(&bytes[..n]);
}

mod file_off {
    pub const VERSION: usize = 0;
    pub const FRAME_COUNT: usize = 4;
    pub const NUM_RAW_BEAMS: usize = 16;
    pub const SAMPLES_PER_CHANNEL: usize = 24;
    pub const REVERSE: usize = 40;
    pub const SN: usize = 44;
    pub const DATE: usize = 48;
    pub const DATE_LEN: usize = 32;
    pub const HEADER_ID: usize = 80;
    pub const HEADER_ID_LEN: usize = 256;
    pub const FILE_SIZE: usize = 424;
    pub const VERSION_MINOR: usize = 448;
    pub const LARGE_LENS: usize = 452;
}

/// The 1024-byte file header, typed fields plus the raw bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct FileHeader {
    /// Version/signature, [`DDF05_SIGNATURE`] in valid files (offset 0).
    pub version: u32,
    /// FrameCount as recorded; not trusted by the reader (offset 4).
    pub frame_count: u32,
    /// NumRawBeams (offset 16).
    pub num_raw_beams: u32,
    /// SamplesPerChannel (offset 24).
    pub samples_per_channel: u32,
    /// Reverse (offset 40).
    pub reverse: u32,
    /// SN, the serial number (offset 44).
    pub serial_number: u32,
    /// strDate, up to the first NUL (offset 48, 32 bytes).
    pub date: String,
    /// strHeaderID, up to the first NUL (offset 80, 256 bytes).
    pub header_id: String,
    /// FileSize as recorded (offset 424).
    pub file_size: u64,
    /// VersionMinor (offset 448).
    pub version_minor: u32,
    /// LargeLens (offset 452); unreliable here, the frame header's is authoritative.
    pub large_lens: u32,
    raw: Box<[u8; HEADER_LEN]>,
}

impl FileHeader {
    /// Decodes the typed fields; never fails (validation is the reader's job).
    pub fn from_bytes(raw: &[u8; HEADER_LEN]) -> Self {
        use file_off::*;
        Self {
            version: get_u32(raw, VERSION),
            frame_count: get_u32(raw, FRAME_COUNT),
            num_raw_beams: get_u32(raw, NUM_RAW_BEAMS),
            samples_per_channel: get_u32(raw, SAMPLES_PER_CHANNEL),
            reverse: get_u32(raw, REVERSE),
            serial_number: get_u32(raw, SN),
            date: get_str(raw, DATE, DATE_LEN),
            header_id: get_str(raw, HEADER_ID, HEADER_ID_LEN),
            file_size: get_u64(raw, FILE_SIZE),
            version_minor: get_u32(raw, VERSION_MINOR),
            large_lens: get_u32(raw, LARGE_LENS),
            raw: Box::new(*raw),
        }
    }

    /// A zeroed header with the DDF_05 signature and the given frame geometry.
    pub fn new(beams: u32, samples_per_beam: u32) -> Self {
        let mut h = Self::from_bytes(&[0u8; HEADER_LEN]);
        h.version = DDF05_SIGNATURE;
        h.num_raw_beams = beams;
        h.samples_per_channel = samples_per_beam;
        h
    }

    /// The bytes as read (or as constructed), without the typed fields applied.
    pub fn raw(&self) -> &[u8; HEADER_LEN] {
        &self.raw
    }

    /// The raw bytes with every typed field written at its offset.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        use file_off::*;
        let mut raw = *self.raw;
        put_u32(&mut raw, VERSION, self.version);
        put_u32(&mut raw, FRAME_COUNT, self.frame_count);
        put_u32(&mut raw, NUM_RAW_BEAMS, self.num_raw_beams);
        put_u32(&mut raw, SAMPLES_PER_CHANNEL, self.samples_per_channel);
        put_u32(&mut raw, REVERSE, self.reverse);
        put_u32(&mut raw, SN, self.serial_number);
        put_str(&mut raw, DATE, DATE_LEN, &self.date);
        put_str(&mut raw, HEADER_ID, HEADER_ID_LEN, &self.header_id);
        put_u64(&mut raw, FILE_SIZE, self.file_size);
        put_u32(&mut raw, VERSION_MINOR, self.version_minor);
        put_u32(&mut raw, LARGE_LENS, self.large_lens);
        raw
    }
}

mod frame_off {
    pub const FRAME_INDEX: usize = 0;
    pub const FRAME_TIME: usize = 4;
    pub const VERSION: usize = 12;
    pub const WINDOW_START: usize = 52;
    pub const WINDOW_LENGTH: usize = 56;
    pub const PITCH: usize = 136;
    pub const ROLL: usize = 144;
    pub const HEADING: usize = 152;
    pub const COMPASS_HEADING: usize = 160;
    pub const COMPASS_PITCH: usize = 164;
    pub const COMPASS_ROLL: usize = 168;
    pub const SONAR_X: usize = 232;
    pub const SONAR_Y: usize = 236;
    pub const SONAR_Z: usize = 240;
    pub const SONAR_PAN: usize = 244;
    pub const SONAR_TILT: usize = 248;
    pub const SONAR_ROLL: usize = 252;
    pub const SAMPLE_RATE: usize = 420;
    pub const PING_MODE: usize = 436;
    pub const SAMPLE_PERIOD: usize = 452;
    pub const SOUND_SPEED: usize = 464;
    pub const SAMPLES_PER_BEAM: usize = 468;
    pub const SAMPLE_START_DELAY: usize = 476;
    pub const LARGE_LENS: usize = 480;
    pub const SYSTEM_TYPE: usize = 484;
    pub const REORDERED_SAMPLES: usize = 516;
    pub const TARGET_PAN: usize = 608;
    pub const TARGET_TILT: usize = 612;
    pub const TARGET_ROLL: usize = 616;
    pub const PAN_ABS: usize = 632;
    pub const TILT_ABS: usize = 636;
    pub const ROLL_ABS: usize = 640;
}

/// The 1024-byte frame header, typed fields plus the raw bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameHeader {
    /// FrameIndex (offset 0).
    pub frame_index: u32,
    /// FrameTime, PC time in µs since the Unix epoch (offset 4).
    pub frame_time_us: u64,
    /// Version/signature (offset 12).
    pub version: u32,
    /// WindowStart as reported, metres (offset 52); prefer [`FrameHeader::range_geometry`].
    pub window_start_m: f32,
    /// WindowLength as reported, metres (offset 56).
    pub window_length_m: f32,
    /// Pitch: platform pitch from the AUV integration, degrees, nose up positive (offset 136).
    pub platform_pitch_deg: f32,
    /// Roll: platform roll, degrees, starboard down positive (offset 144).
    pub platform_roll_deg: f32,
    /// Heading: platform heading from the AUV integration, degrees clockwise from north seen
    /// from above (offset 152).
    pub platform_heading_deg: f32,
    /// CompassHeading: the sonar's own compass, degrees (offset 160).
    pub compass_heading_deg: f32,
    /// CompassPitch: the sonar's own compass, degrees (offset 164).
    pub compass_pitch_deg: f32,
    /// CompassRoll: the sonar's own compass, degrees (offset 168).
    pub compass_roll_deg: f32,
    /// SonarX (offset 232).
    pub sonar_x: f32,
    /// SonarY (offset 236).
    pub sonar_y: f32,
    /// SonarZ (offset 240).
    pub sonar_z: f32,
    /// SonarPan, rotator output, degrees; NaN when absent (offset 244).
    pub sonar_pan_deg: f32,
    /// SonarTilt, rotator output, degrees; NaN when absent (offset 248).
    pub sonar_tilt_deg: f32,
    /// SonarRoll, rotator output, degrees; NaN when absent (offset 252).
    pub sonar_roll_deg: f32,
    /// SampleRate, Hz, = 1e6 / SamplePeriod (offset 420).
    pub sample_rate_hz: f32,
    /// PingMode (offset 436): 1–2 → 48 beams, 3–5 → 96, 6–8 → 64, 9–12 → 128.
    pub ping_mode: u32,
    /// SamplePeriod, µs (offset 452).
    pub sample_period_us: u32,
    /// SoundSpeed, m/s (offset 464).
    pub sound_speed_m_s: f32,
    /// SamplesPerBeam (offset 468).
    pub samples_per_beam: u32,
    /// SampleStartDelay, µs (offset 476).
    pub sample_start_delay_us: u32,
    /// LargeLens, 1 = telephoto (offset 480).
    pub large_lens: u32,
    /// TheSystemType (offset 484).
    pub system_type: SystemType,
    /// ReorderedSamples, 1 in every stored file (offset 516).
    pub reordered_samples: u32,
    /// TargetPan, commanded, degrees (offset 608).
    pub target_pan_deg: f32,
    /// TargetTilt, commanded, degrees (offset 612).
    pub target_tilt_deg: f32,
    /// TargetRoll, commanded, degrees (offset 616).
    pub target_roll_deg: f32,
    /// PanAbsPosition, encoder, degrees; NaN = no rotator (offset 632).
    pub pan_abs_position_deg: f32,
    /// TiltAbsPosition, encoder, degrees; NaN = no rotator (offset 636).
    pub tilt_abs_position_deg: f32,
    /// RollAbsPosition, encoder, degrees; NaN = no rotator (offset 640).
    pub roll_abs_position_deg: f32,
    raw: Box<[u8; HEADER_LEN]>,
}

impl FrameHeader {
    /// Decodes the typed fields; never fails (validation is the reader's job).
    pub fn from_bytes(raw: &[u8; HEADER_LEN]) -> Self {
        use frame_off::*;
        Self {
            frame_index: get_u32(raw, FRAME_INDEX),
            frame_time_us: get_u64(raw, FRAME_TIME),
            version: get_u32(raw, VERSION),
            window_start_m: get_f32(raw, WINDOW_START),
            window_length_m: get_f32(raw, WINDOW_LENGTH),
            platform_pitch_deg: get_f32(raw, PITCH),
            platform_roll_deg: get_f32(raw, ROLL),
            platform_heading_deg: get_f32(raw, HEADING),
            compass_heading_deg: get_f32(raw, COMPASS_HEADING),
            compass_pitch_deg: get_f32(raw, COMPASS_PITCH),
            compass_roll_deg: get_f32(raw, COMPASS_ROLL),
            sonar_x: get_f32(raw, SONAR_X),
            sonar_y: get_f32(raw, SONAR_Y),
            sonar_z: get_f32(raw, SONAR_Z),
            sonar_pan_deg: get_f32(raw, SONAR_PAN),
            sonar_tilt_deg: get_f32(raw, SONAR_TILT),
            sonar_roll_deg: get_f32(raw, SONAR_ROLL),
            sample_rate_hz: get_f32(raw, SAMPLE_RATE),
            ping_mode: get_u32(raw, PING_MODE),
            sample_period_us: get_u32(raw, SAMPLE_PERIOD),
            sound_speed_m_s: get_f32(raw, SOUND_SPEED),
            samples_per_beam: get_u32(raw, SAMPLES_PER_BEAM),
            sample_start_delay_us: get_u32(raw, SAMPLE_START_DELAY),
            large_lens: get_u32(raw, LARGE_LENS),
            system_type: SystemType::from_code(get_u32(raw, SYSTEM_TYPE)),
            reordered_samples: get_u32(raw, REORDERED_SAMPLES),
            target_pan_deg: get_f32(raw, TARGET_PAN),
            target_tilt_deg: get_f32(raw, TARGET_TILT),
            target_roll_deg: get_f32(raw, TARGET_ROLL),
            pan_abs_position_deg: get_f32(raw, PAN_ABS),
            tilt_abs_position_deg: get_f32(raw, TILT_ABS),
            roll_abs_position_deg: get_f32(raw, ROLL_ABS),
            raw: Box::new(*raw),
        }
    }

    /// A default ARIS 3000 frame header: signature, PingMode consistent with `beams`
    /// (64 → 6, 128 → 9), ReorderedSamples = 1, standard lens, the given timing, sound speed,
    /// SampleRate and the reported WindowStart/WindowLength computed by docs/ARIS.md's formulas,
    /// NaN for every rotator field (set a roll with [`FrameHeader::with_roll_deg`]), platform
    /// roll and position 0, frame index and time 0.
    pub fn new_aris3000(
        beams: usize,
        samples_per_beam: usize,
        sample_period_us: u32,
        sample_start_delay_us: u32,
        sound_speed_m_s: f32,
    ) -> Result<Self> {
        let ping_mode = match beams {
            64 => 6,
            128 => 9,
            _ => {
                return Err(BeamTableError::NoBeamTable {
                    system: SystemType::Aris3000,
                    beams,
                    telephoto: false,
                }
                .into())
            }
        };
        if samples_per_beam == 0 || samples_per_beam > MAX_SAMPLES_PER_BEAM {
            return Err(ArisError::BadSampleCount {
                what: "new_aris3000 samples_per_beam".into(),
                samples: u32::try_from(samples_per_beam).unwrap_or(u32::MAX),
            });
        }
        let mut h = Self::from_bytes(&[0u8; HEADER_LEN]);
        h.version = DDF05_SIGNATURE;
        h.ping_mode = ping_mode;
        h.samples_per_beam = samples_per_beam as u32; // ≤ MAX_SAMPLES_PER_BEAM, fits
        h.sample_period_us = sample_period_us;
        h.sample_start_delay_us = sample_start_delay_us;
        h.sound_speed_m_s = sound_speed_m_s;
        h.system_type = SystemType::Aris3000;
        h.reordered_samples = 1;
        h.large_lens = 0;
        // The geometry is recomputed from these inputs anyway; fill the reported values so
        // that other tools see a consistent file. Errors (period 0, bad sound speed) leave NaN.
        let ranges = h.range_geometry(samples_per_beam);
        h.window_start_m = ranges.map_or(f32::NAN, |r| r.start as f32);
        h.window_length_m = h
            .computed_window_length_m(samples_per_beam)
            .map_or(f32::NAN, |l| l as f32);
        h.sample_rate_hz = if sample_period_us > 0 {
            (1e6 / f64::from(sample_period_us)) as f32
        } else {
            f32::NAN
        };
        for field in [
            &mut h.sonar_pan_deg,
            &mut h.sonar_tilt_deg,
            &mut h.sonar_roll_deg,
            &mut h.target_pan_deg,
            &mut h.target_tilt_deg,
            &mut h.target_roll_deg,
            &mut h.pan_abs_position_deg,
            &mut h.tilt_abs_position_deg,
            &mut h.roll_abs_position_deg,
        ] {
            *field = f32::NAN;
        }
        Ok(h)
    }

    /// Sets the rotator roll: SonarRoll and RollAbsPosition (and TargetRoll) to `roll_deg`,
    /// as a rotator that reached its commanded roll reports it.
    pub fn with_roll_deg(mut self, roll_deg: f32) -> Self {
        self.sonar_roll_deg = roll_deg;
        self.roll_abs_position_deg = roll_deg;
        self.target_roll_deg = roll_deg;
        self
    }

    /// The rotator roll the pairing reads: SonarRoll, else RollAbsPosition (NaN without both).
    pub fn rotator_roll_deg(&self) -> f32 {
        if self.sonar_roll_deg.is_finite() {
            self.sonar_roll_deg
        } else {
            self.roll_abs_position_deg
        }
    }

    /// The sonar's attitude as a unit quaternion `[w, x, y, z]` (docs/POSE.md): the platform's
    /// Heading, Pitch and Roll composed with the rotator's pan, tilt and roll (SonarPan/Tilt/
    /// Roll, else the encoder positions; a missing pan or tilt axis counts as 0). `None` when
    /// the platform angles or the rotator roll are not finite: such a frame pairs by the
    /// roll-only rule.
    pub fn attitude(&self) -> Option<[f32; 4]> {
        let or = |a: f32, b: f32| if a.is_finite() { a } else { b };
        let pan = or(self.sonar_pan_deg, self.pan_abs_position_deg);
        let tilt = or(self.sonar_tilt_deg, self.tilt_abs_position_deg);
        epssn::attitude::Attitude::from_header_deg(
            self.platform_heading_deg,
            self.platform_pitch_deg,
            self.platform_roll_deg,
            if pan.is_finite() { pan } else { 0.0 },
            if tilt.is_finite() { tilt } else { 0.0 },
            self.rotator_roll_deg(),
        )
        .map(|a| a.to_array())
    }

    /// Sets the platform attitude (Heading, Pitch, Roll), degrees.
    pub fn with_platform_attitude_deg(mut self, heading: f32, pitch: f32, roll: f32) -> Self {
        self.platform_heading_deg = heading;
        self.platform_pitch_deg = pitch;
        self.platform_roll_deg = roll;
        self
    }

    /// The bytes as read (or as constructed), without the typed fields applied.
    pub fn raw(&self) -> &[u8; HEADER_LEN] {
        &self.raw
    }

    /// The raw bytes with every typed field written at its offset.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        use frame_off::*;
        let mut raw = *self.raw;
        put_u32(&mut raw, FRAME_INDEX, self.frame_index);
        put_u64(&mut raw, FRAME_TIME, self.frame_time_us);
        put_u32(&mut raw, VERSION, self.version);
        put_f32(&mut raw, WINDOW_START, self.window_start_m);
        put_f32(&mut raw, WINDOW_LENGTH, self.window_length_m);
        put_f32(&mut raw, PITCH, self.platform_pitch_deg);
        put_f32(&mut raw, ROLL, self.platform_roll_deg);
        put_f32(&mut raw, HEADING, self.platform_heading_deg);
        put_f32(&mut raw, COMPASS_HEADING, self.compass_heading_deg);
        put_f32(&mut raw, COMPASS_PITCH, self.compass_pitch_deg);
        put_f32(&mut raw, COMPASS_ROLL, self.compass_roll_deg);
        put_f32(&mut raw, SONAR_X, self.sonar_x);
        put_f32(&mut raw, SONAR_Y, self.sonar_y);
        put_f32(&mut raw, SONAR_Z, self.sonar_z);
        put_f32(&mut raw, SONAR_PAN, self.sonar_pan_deg);
        put_f32(&mut raw, SONAR_TILT, self.sonar_tilt_deg);
        put_f32(&mut raw, SONAR_ROLL, self.sonar_roll_deg);
        put_f32(&mut raw, SAMPLE_RATE, self.sample_rate_hz);
        put_u32(&mut raw, PING_MODE, self.ping_mode);
        put_u32(&mut raw, SAMPLE_PERIOD, self.sample_period_us);
        put_f32(&mut raw, SOUND_SPEED, self.sound_speed_m_s);
        put_u32(&mut raw, SAMPLES_PER_BEAM, self.samples_per_beam);
        put_u32(&mut raw, SAMPLE_START_DELAY, self.sample_start_delay_us);
        put_u32(&mut raw, LARGE_LENS, self.large_lens);
        put_u32(&mut raw, SYSTEM_TYPE, self.system_type.code());
        put_u32(&mut raw, REORDERED_SAMPLES, self.reordered_samples);
        put_f32(&mut raw, TARGET_PAN, self.target_pan_deg);
        put_f32(&mut raw, TARGET_TILT, self.target_tilt_deg);
        put_f32(&mut raw, TARGET_ROLL, self.target_roll_deg);
        put_f32(&mut raw, PAN_ABS, self.pan_abs_position_deg);
        put_f32(&mut raw, TILT_ABS, self.tilt_abs_position_deg);
        put_f32(&mut raw, ROLL_ABS, self.roll_abs_position_deg);
        raw
    }

    /// LargeLens = 1: a telephoto lens.
    pub fn telephoto(&self) -> bool {
        self.large_lens == 1
    }

    /// Beams implied by PingMode.
    pub fn ping_mode_beams(&self) -> Option<usize> {
        beams_for_ping_mode(self.ping_mode)
    }

    /// Metres per µs of two-way travel: c/2 · 1e-6, checked.
    fn half_speed_m_per_us(&self) -> Result<f64> {
        let c = f64::from(self.sound_speed_m_s);
        if !c.is_finite() || c <= 0.0 {
            return Err(ArisError::RangeGeometry(format!(
                "SoundSpeed is {} m/s",
                self.sound_speed_m_s
            )));
        }
        Ok(c * 1e-6 / 2.0)
    }

    /// Sample ranges per docs/ARIS.md: start = SampleStartDelay·1e-6·c/2,
    /// step = SamplePeriod·1e-6·c/2.
    pub fn range_geometry(&self, samples_per_beam: usize) -> Result<SampleRanges> {
        let half = self.half_speed_m_per_us()?;
        if self.sample_period_us == 0 {
            return Err(ArisError::RangeGeometry("SamplePeriod is 0 µs".into()));
        }
        Ok(SampleRanges {
            start: f64::from(self.sample_start_delay_us) * half,
            step: f64::from(self.sample_period_us) * half,
            samples: samples_per_beam,
        })
    }

    /// Window length per docs/ARIS.md: SamplePeriod·SamplesPerBeam·1e-6·c/2.
    pub fn computed_window_length_m(&self, samples_per_beam: usize) -> Result<f64> {
        let r = self.range_geometry(samples_per_beam)?;
        Ok(r.step * samples_per_beam as f64)
    }
}

/// One frame: its header and its samples, `data[sample × beams + beam]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Position of the frame in the file (0-based).
    pub index: usize,
    /// The frame header.
    pub header: FrameHeader,
    /// Beams per sample row (the file's geometry).
    pub beams: usize,
    /// Samples per beam (the file's geometry).
    pub samples_per_beam: usize,
    /// The samples, sample-major; length `beams × samples_per_beam`.
    pub data: Vec<u8>,
}

impl Frame {
    /// Sample `s` of beam `b` (beam 0 right-most), `None` outside the frame.
    pub fn sample(&self, s: usize, b: usize) -> Option<u8> {
        if b >= self.beams {
            return None;
        }
        self.data
            .get(s.checked_mul(self.beams)?.checked_add(b)?)
            .copied()
    }

    /// Row `s`: every beam's sample `s`.
    pub fn row(&self, s: usize) -> Option<&[u8]> {
        let start = s.checked_mul(self.beams)?;
        self.data.get(start..start.checked_add(self.beams)?)
    }

    /// Iterator over the rows (samples × beams view).
    pub fn rows(&self) -> impl Iterator<Item = &[u8]> {
        self.data.chunks_exact(self.beams.max(1))
    }

    /// Sample ranges from SampleStartDelay, SamplePeriod and SoundSpeed (docs/ARIS.md).
    pub fn range_geometry(&self) -> Result<SampleRanges> {
        self.header.range_geometry(self.samples_per_beam)
    }

    /// Computed window length, metres.
    pub fn window_length_m(&self) -> Result<f64> {
        self.header.computed_window_length_m(self.samples_per_beam)
    }

    /// The beam table for this frame's system, beam count and lens.
    pub fn beam_table(&self) -> Result<&'static BeamTable> {
        Ok(beam_table_for(
            self.header.system_type,
            self.beams,
            self.header.telephoto(),
        )?)
    }

    /// Beam centres in radians, ascending (beam 0 first).
    pub fn beam_centres_rad(&self) -> Result<Vec<f64>> {
        Ok(self.beam_table()?.centres_rad())
    }
}

/// Warnings about one condition across frames, collapsed into one line.
#[derive(Default)]
struct Tally {
    entries: Vec<(String, usize, usize)>, // (message, count, first frame)
    dropped: usize,
}

impl Tally {
    /// Distinct messages kept; a corrupt file could otherwise yield one per frame.
    const MAX_DISTINCT: usize = 32;

    fn note(&mut self, message: String, frame: usize) {
        if let Some(e) = self.entries.iter_mut().find(|e| e.0 == message) {
            e.1 += 1;
        } else if self.entries.len() < Self::MAX_DISTINCT {
            self.entries.push((message, 1, frame));
        } else {
            self.dropped += 1;
        }
    }

    fn into_warnings(self, frames: usize, out: &mut Vec<String>) {
        if self.dropped > 0 {
            out.push(format!(
                "{} further frame-header anomalies not listed",
                self.dropped
            ));
        }
        for (message, count, first) in self.entries {
            if count == 1 {
                out.push(format!("frame {first}: {message}"));
            } else {
                out.push(format!(
                    "{message} in {count} of {frames} frames (first: frame {first})"
                ));
            }
        }
    }
}

/// A DDF_05 reader: validates the headers at open, reads frames on demand.
#[derive(Debug)]
pub struct ArisReader<R = File> {
    source: Mutex<R>,
    source_len: u64,
    file_header: FileHeader,
    first_frame_header: FrameHeader,
    beams: usize,
    samples_per_beam: usize,
    frame_len: u64,
    frame_count: usize,
    warnings: Vec<String>,
}

impl ArisReader<File> {
    /// Opens and validates a recording.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| ArisError::Open {
            path: path.to_path_buf(),
            source,
        })?;
        Self::new(file)
    }
}

fn read_header<R: Read + Seek>(
    source: &mut R,
    offset: u64,
    source_len: u64,
    what: &str,
) -> Result<[u8; HEADER_LEN]> {
    let available = source_len.saturating_sub(offset);
    if available < HEADER_LEN as u64 {
        return Err(ArisError::TruncatedHeader {
            what: what.to_string(),
            offset,
            needed: HEADER_LEN as u64,
            available,
        });
    }
    let mut raw = [0u8; HEADER_LEN];
    source.seek(SeekFrom::Start(offset))?;
    source.read_exact(&mut raw)?;
    Ok(raw)
}

fn check_signature(raw: &[u8; HEADER_LEN], what: &str) -> Result<()> {
    let found = [raw[0], raw[1], raw[2], raw[3]];
    if u32::from_le_bytes(found) != DDF05_SIGNATURE {
        return Err(ArisError::BadSignature {
            what: what.to_string(),
            found,
        });
    }
    Ok(())
}

/// Beams per frame: PingMode and NumRawBeams must agree when both are meaningful; when one
/// is not, the other is used with a warning.
fn beam_count(
    file_header: &FileHeader,
    first: &FrameHeader,
    warnings: &mut Vec<String>,
) -> Result<usize> {
    let header_beams = file_header.num_raw_beams;
    let header_beams_ok = VALID_BEAM_COUNTS
        .iter()
        .any(|&b| b as u64 == u64::from(header_beams));
    Ok(match (first.ping_mode_beams(), header_beams_ok) {
        (Some(p), true) if p as u64 != u64::from(header_beams) => {
            return Err(ArisError::PingModeMismatch {
                ping_mode: first.ping_mode,
                ping_beams: p,
                header_beams,
            })
        }
        (Some(p), ok) => {
            if !ok {
                warnings.push(format!(
                    "file header NumRawBeams is {header_beams}; using {p} beams from frame 0 PingMode {}",
                    first.ping_mode
                ));
            }
            p
        }
        (None, true) => {
            warnings.push(format!(
                "frame 0 PingMode {} names no beam count; using the file header's NumRawBeams {header_beams}",
                first.ping_mode
            ));
            header_beams as usize // one of VALID_BEAM_COUNTS
        }
        (None, false) => {
            return Err(ArisError::BadBeamCount {
                ping_mode: first.ping_mode,
                num_raw_beams: header_beams,
            })
        }
    })
}

/// Complete frames of `frame_len` bytes in a source of `source_len` bytes, with warnings for
/// a truncated last frame and a file header whose FrameCount or FileSize disagree.
fn count_frames(
    file_header: &FileHeader,
    source_len: u64,
    frame_len: u64,
    warnings: &mut Vec<String>,
) -> Result<usize> {
    let body = source_len.saturating_sub(HEADER_LEN as u64); // ≥ 1024 here
    let complete = body / frame_len;
    let remainder = body % frame_len;
    let frame_count = usize::try_from(complete)
        .map_err(|_| ArisError::SizeOverflow(format!("{complete} frames")))?;
    if remainder != 0 {
        warnings.push(format!(
            "truncated last frame: {remainder} trailing bytes of a {frame_len}-byte frame \
             ignored ({} bytes missing); {frame_count} complete frames kept",
            frame_len - remainder
        ));
    }
    if u64::from(file_header.frame_count) != complete {
        warnings.push(format!(
            "file header FrameCount is {}, but the file holds {frame_count} complete frames \
             ({} missing)",
            file_header.frame_count,
            u64::from(file_header.frame_count).abs_diff(complete)
        ));
    }
    if file_header.file_size != source_len {
        warnings.push(format!(
            "file header FileSize is {}, but the file has {source_len} bytes",
            file_header.file_size
        ));
    }
    Ok(frame_count)
}

/// The warning for a recording whose system, lens and beams are not the model's ARIS 3000 /
/// 128-beam geometry (or have no beam table); `None` when they are.
fn geometry_warning(first: &FrameHeader, beams: usize) -> Option<String> {
    match beam_table_for(first.system_type, beams, first.telephoto()) {
        Ok(t) if t.name == "ARIS3000_128" => None,
        Ok(t) => Some(format!(
            "geometry: {}{}, {beams} beams (beam table {}, {:.2}° … {:.2}°) is not the \
             ARIS 3000 / 128-beam geometry of the epssn model; depth from this recording \
             would use mismatched geometry",
            first.system_type,
            if first.telephoto() {
                ", telephoto lens"
            } else {
                ""
            },
            t.name,
            t.centre_span_deg().0,
            t.centre_span_deg().1,
        )),
        Err(e) => Some(format!("geometry: {e}")),
    }
}

impl<R: Read + Seek> ArisReader<R> {
    /// Validates a recording held by any seekable source (a file, a `Cursor<Vec<u8>>`).
    pub fn new(mut source: R) -> Result<Self> {
        let source_len = source.seek(SeekFrom::End(0))?;
        let raw = read_header(&mut source, 0, source_len, "file header")?;
        check_signature(&raw, "file header")?;
        let file_header = FileHeader::from_bytes(&raw);
        let raw = read_header(&mut source, HEADER_LEN as u64, source_len, "frame 0 header")?;
        // The frame signature is the frame's Version field at offset 12.
        let sig = [raw[12], raw[13], raw[14], raw[15]];
        if u32::from_le_bytes(sig) != DDF05_SIGNATURE {
            return Err(ArisError::BadSignature {
                what: "frame 0 header (Version at offset 12)".into(),
                found: sig,
            });
        }
        let first = FrameHeader::from_bytes(&raw);
        let mut warnings = Vec::new();
        let beams = beam_count(&file_header, &first, &mut warnings)?;
        let samples = first.samples_per_beam;
        if samples == 0 || samples as usize > MAX_SAMPLES_PER_BEAM {
            return Err(ArisError::BadSampleCount {
                what: "frame 0 SamplesPerBeam".into(),
                samples,
            });
        }
        let samples_per_beam = samples as usize;
        if file_header.samples_per_channel != samples {
            warnings.push(format!(
                "file header SamplesPerChannel is {}, frame 0 SamplesPerBeam is {samples}; using {samples}",
                file_header.samples_per_channel
            ));
        }
        let frame_len = (beams as u64)
            .checked_mul(samples_per_beam as u64)
            .and_then(|d| d.checked_add(HEADER_LEN as u64))
            .ok_or_else(|| ArisError::SizeOverflow("frame size".into()))?;
        let frame_count = count_frames(&file_header, source_len, frame_len, &mut warnings)?;
        let mut tally = Tally::default();
        check_frame(&first, &first, 0, beams, samples, &mut tally);
        let mut previous_time_us = first.frame_time_us;
        for i in 1..frame_count {
            let offset = (i as u64)
                .checked_mul(frame_len)
                .and_then(|o| o.checked_add(HEADER_LEN as u64))
                .ok_or_else(|| ArisError::SizeOverflow(format!("offset of frame {i}")))?;
            let raw = read_header(
                &mut source,
                offset,
                source_len,
                &format!("frame {i} header"),
            )?;
            let h = FrameHeader::from_bytes(&raw);
            check_frame(&first, &h, i, beams, samples, &mut tally);
            if h.frame_time_us < previous_time_us {
                tally.note("FrameTime goes backwards".into(), i);
            }
            previous_time_us = h.frame_time_us;
        }
        tally.into_warnings(frame_count.max(1), &mut warnings);
        if let Some(w) = geometry_warning(&first, beams) {
            warnings.push(w);
        }
        Ok(Self {
            source: Mutex::new(source),
            source_len,
            file_header,
            first_frame_header: first,
            beams,
            samples_per_beam,
            frame_len,
            frame_count,
            warnings,
        })
    }

    /// The file header.
    pub fn file_header(&self) -> &FileHeader {
        &self.file_header
    }

    /// Frame 0's header (defines the file's geometry).
    pub fn first_frame_header(&self) -> &FrameHeader {
        &self.first_frame_header
    }

    /// Beams per frame.
    pub fn beams(&self) -> usize {
        self.beams
    }

    /// Samples per beam.
    pub fn samples_per_beam(&self) -> usize {
        self.samples_per_beam
    }

    /// Complete frames in the file (from its length, not FrameCount).
    pub fn frame_count(&self) -> usize {
        self.frame_count
    }

    /// Bytes per frame, header included.
    pub fn frame_len(&self) -> u64 {
        self.frame_len
    }

    /// Length of the file, bytes.
    pub fn source_len(&self) -> u64 {
        self.source_len
    }

    /// Everything odd found at open, one line each.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// System type of frame 0.
    pub fn system(&self) -> SystemType {
        self.first_frame_header.system_type
    }

    /// Frame 0 has a telephoto lens.
    pub fn telephoto(&self) -> bool {
        self.first_frame_header.telephoto()
    }

    /// The beam table for frame 0's system, beam count and lens.
    pub fn beam_table(&self) -> Result<&'static BeamTable> {
        Ok(beam_table_for(self.system(), self.beams, self.telephoto())?)
    }

    /// Beam centres in radians, ascending (beam 0 first).
    pub fn beam_centres_rad(&self) -> Result<Vec<f64>> {
        Ok(self.beam_table()?.centres_rad())
    }

    /// Byte offset of frame `index`.
    pub fn frame_offset(&self, index: usize) -> Result<u64> {
        if index >= self.frame_count {
            return Err(ArisError::FrameIndexOutOfRange {
                index,
                count: self.frame_count,
            });
        }
        (index as u64)
            .checked_mul(self.frame_len)
            .and_then(|o| o.checked_add(HEADER_LEN as u64))
            .ok_or_else(|| ArisError::SizeOverflow(format!("offset of frame {index}")))
    }

    fn with_source<T>(&self, f: impl FnOnce(&mut R) -> Result<T>) -> Result<T> {
        // A poisoned lock only means another thread panicked mid-read; the seek below resets
        // the position, so the source is still usable.
        let mut guard = self.source.lock().unwrap_or_else(|p| p.into_inner());
        f(&mut guard)
    }

    /// Reads frame `index`'s header only.
    pub fn frame_header(&self, index: usize) -> Result<FrameHeader> {
        let offset = self.frame_offset(index)?;
        let raw = self.with_source(|s| {
            read_header(s, offset, self.source_len, &format!("frame {index} header"))
        })?;
        Ok(FrameHeader::from_bytes(&raw))
    }

    /// Reads frame `index`: header and samples.
    pub fn frame(&self, index: usize) -> Result<Frame> {
        let offset = self.frame_offset(index)?;
        let len = self
            .beams
            .checked_mul(self.samples_per_beam)
            .ok_or_else(|| ArisError::SizeOverflow("frame data size".into()))?;
        let (raw, data) = self.with_source(|s| {
            let raw = read_header(s, offset, self.source_len, &format!("frame {index} header"))?;
            let mut data = vec![0u8; len];
            s.read_exact(&mut data)?;
            Ok((raw, data))
        })?;
        Ok(Frame {
            index,
            header: FrameHeader::from_bytes(&raw),
            beams: self.beams,
            samples_per_beam: self.samples_per_beam,
            data,
        })
    }

    /// Iterator reading every frame in turn.
    pub fn frames(&self) -> impl Iterator<Item = Result<Frame>> + '_ {
        (0..self.frame_count).map(move |i| self.frame(i))
    }
}

/// Records what is odd in frame `i`'s header relative to frame 0 and the file's geometry.
fn check_frame(
    first: &FrameHeader,
    h: &FrameHeader,
    i: usize,
    beams: usize,
    samples: u32,
    tally: &mut Tally,
) {
    if h.version != DDF05_SIGNATURE {
        tally.note(
            format!("frame header Version is {:#010x}, not DDF_05", h.version),
            i,
        );
    }
    match h.ping_mode_beams() {
        Some(b) if b == beams => {}
        Some(b) => tally.note(
            format!(
                "PingMode {} implies {b} beams, contradicting the file's {beams}",
                h.ping_mode
            ),
            i,
        ),
        None => tally.note(format!("PingMode {} names no beam count", h.ping_mode), i),
    }
    if h.samples_per_beam != samples {
        tally.note(
            format!(
                "SamplesPerBeam {} differs from the file's {samples}",
                h.samples_per_beam
            ),
            i,
        );
    }
    if h.frame_index as usize != i {
        tally.note("FrameIndex does not match the frame's position".into(), i);
    }
    if h.reordered_samples != 1 {
        tally.note(
            format!(
                "ReorderedSamples is {}, not 1 (samples are read sample-major regardless)",
                h.reordered_samples
            ),
            i,
        );
    }
    if h.system_type != first.system_type || h.large_lens != first.large_lens {
        tally.note("system type or lens differs from frame 0".into(), i);
    }
    if let Err(e) = h.range_geometry(samples as usize) {
        tally.note(format!("range geometry unavailable ({e})"), i);
    }
    let floats: [(&str, &str, f32); 7] = [
        ("SoundSpeed", "", h.sound_speed_m_s),
        ("WindowStart", "", h.window_start_m),
        ("WindowLength", "", h.window_length_m),
        ("SampleRate", "", h.sample_rate_hz),
        ("Roll", " (platform roll unknown)", h.platform_roll_deg),
        ("SonarRoll", " (no rotator roll recorded)", h.sonar_roll_deg),
        (
            "RollAbsPosition",
            " (no rotator roll encoder)",
            h.roll_abs_position_deg,
        ),
    ];
    for (name, note, v) in floats {
        if v.is_nan() {
            tally.note(format!("{name} is NaN{note}"), i);
        } else if v.is_infinite() {
            tally.note(format!("{name} is infinite"), i);
        }
    }
}

/// A DDF_05 writer: file header, then frames; [`ArisWriter::finish`] fixes the counts.
#[derive(Debug)]
pub struct ArisWriter<W: Write + Seek = BufWriter<File>> {
    sink: W,
    header: FileHeader,
    geometry: Option<(usize, usize)>,
    frames: u64,
    bytes: u64,
}

impl ArisWriter<BufWriter<File>> {
    /// Creates (truncates) `path` and writes `file_header` (counts fixed at finish).
    pub fn create(path: impl AsRef<Path>, file_header: &FileHeader) -> Result<Self> {
        let path = path.as_ref();
        let file = File::create(path).map_err(|source| ArisError::Open {
            path: path.to_path_buf(),
            source,
        })?;
        Self::new(BufWriter::new(file), file_header)
    }
}

impl<W: Write + Seek> ArisWriter<W> {
    /// Starts a recording in `sink` (positioned at its start).
    pub fn new(mut sink: W, file_header: &FileHeader) -> Result<Self> {
        let raw = file_header.encode();
        check_signature(&raw, "file header to write")?;
        sink.write_all(&raw)?;
        Ok(Self {
            sink,
            header: file_header.clone(),
            geometry: None,
            frames: 0,
            bytes: HEADER_LEN as u64,
        })
    }

    /// Appends one frame. `data` is sample-major, `beams × header.samples_per_beam` bytes,
    /// beams from `header.ping_mode`. Every frame must have the first frame's geometry.
    pub fn write_frame(&mut self, header: &FrameHeader, data: &[u8]) -> Result<()> {
        let raw = header.encode();
        if header.version != DDF05_SIGNATURE {
            return Err(ArisError::BadSignature {
                what: "frame header to write (Version)".into(),
                found: header.version.to_le_bytes(),
            });
        }
        let beams = header.ping_mode_beams().ok_or(ArisError::BadBeamCount {
            ping_mode: header.ping_mode,
            num_raw_beams: self.header.num_raw_beams,
        })?;
        let samples = header.samples_per_beam as usize;
        if samples == 0 || samples > MAX_SAMPLES_PER_BEAM {
            return Err(ArisError::BadSampleCount {
                what: "frame header to write".into(),
                samples: header.samples_per_beam,
            });
        }
        if let Some((b, s)) = self.geometry {
            if (b, s) != (beams, samples) {
                return Err(ArisError::GeometryChanged {
                    first_beams: b,
                    first_samples: s,
                    beams,
                    samples,
                });
            }
        }
        let expected = beams
            .checked_mul(samples)
            .ok_or_else(|| ArisError::SizeOverflow("frame data size".into()))?;
        if data.len() != expected {
            return Err(ArisError::DataLength {
                expected,
                found: data.len(),
            });
        }
        self.sink.write_all(&raw)?;
        self.sink.write_all(data)?;
        self.geometry = Some((beams, samples));
        self.frames += 1;
        // expected ≤ 128 × MAX_SAMPLES_PER_BEAM, so the frame length fits; the total is checked.
        self.bytes = self
            .bytes
            .checked_add((HEADER_LEN + expected) as u64)
            .ok_or_else(|| ArisError::SizeOverflow("file size".into()))?;
        Ok(())
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.frames
    }

    /// Rewrites the file header with FrameCount, FileSize, NumRawBeams and
    /// SamplesPerChannel matching what was written, flushes, and returns the sink.
    pub fn finish(mut self) -> Result<W> {
        self.header.frame_count = u32::try_from(self.frames)
            .map_err(|_| ArisError::SizeOverflow(format!("{} frames", self.frames)))?;
        self.header.file_size = self.bytes;
        if let Some((beams, samples)) = self.geometry {
            // Both bounded by the checks in write_frame.
            self.header.num_raw_beams = beams as u32;
            self.header.samples_per_channel = samples as u32;
        }
        self.sink.seek(SeekFrom::Start(0))?;
        self.sink.write_all(&self.header.encode())?;
        self.sink.seek(SeekFrom::End(0))?;
        self.sink.flush()?;
        Ok(self.sink)
    }
}

/// Writes a whole recording: a file header derived from the first frame (DDF_05 signature,
/// NumRawBeams, SamplesPerChannel) and every frame. The simulator's one-frame views use this.
pub fn write_recording(path: impl AsRef<Path>, frames: &[(&FrameHeader, &[u8])]) -> Result<()> {
    let (beams, samples) = match frames.first() {
        Some((h, _)) => (
            h.ping_mode_beams().unwrap_or(0) as u32, // ≤ 128
            h.samples_per_beam,
        ),
        None => (0, 0),
    };
    let mut w = ArisWriter::create(path, &FileHeader::new(beams, samples))?;
    for (header, data) in frames {
        w.write_frame(header, data)?;
    }
    w.finish()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    fn synthetic(beams: usize, samples: usize, frames: usize) -> Vec<u8> {
        let fh = FileHeader::new(beams as u32, samples as u32);
        let mut w = ArisWriter::new(Cursor::new(Vec::new()), &fh).unwrap();
        for i in 0..frames {
            let mut h = FrameHeader::new_aris3000(beams, samples, 4, 2667, 1500.0)
                .unwrap()
                .with_roll_deg(7.0 * i as f32);
            h.frame_index = i as u32;
            let data: Vec<u8> = (0..beams * samples).map(|k| (k * 7 + i) as u8).collect();
            w.write_frame(&h, &data).unwrap();
        }
        w.finish().unwrap().into_inner()
    }

    #[test]
    fn header_encode_of_decoded_bytes_is_identity_even_with_nan_payloads() {
        let mut raw = [0u8; HEADER_LEN];
        for (i, b) in raw.iter_mut().enumerate() {
            *b = (i * 31 + 7) as u8;
        }
        // A signalling-NaN-like payload at SonarRoll.
        raw[252..256].copy_from_slice(&0x7f80_0001u32.to_le_bytes());
        assert_eq!(FrameHeader::from_bytes(&raw).encode(), raw);
        assert_eq!(FileHeader::from_bytes(&raw).encode(), raw);
    }

    #[test]
    fn typed_fields_land_at_their_offsets() {
        let mut h = FrameHeader::from_bytes(&[0u8; HEADER_LEN]);
        h.sound_speed_m_s = 1500.5;
        h.sample_period_us = 0x0102_0304;
        h.system_type = SystemType::Aris1200;
        h.frame_time_us = 0x1122_3344_5566_7788;
        let raw = h.encode();
        assert_eq!(&raw[464..468], &1500.5f32.to_le_bytes());
        assert_eq!(&raw[452..456], &[4, 3, 2, 1]);
        assert_eq!(&raw[484..488], &[2, 0, 0, 0]);
        assert_eq!(&raw[4..12], &0x1122_3344_5566_7788u64.to_le_bytes());
        let mut f = FileHeader::new(128, 512);
        f.date = "2026-11-21".into();
        f.file_size = 0xAABB_CCDD_EEFF;
        let raw = f.encode();
        assert_eq!(&raw[0..4], b"DDF\x05");
        assert_eq!(&raw[48..59], b"2026-11-21\0");
        assert_eq!(&raw[424..432], &0xAABB_CCDD_EEFFu64.to_le_bytes());
        assert_eq!(FileHeader::from_bytes(&raw).date, "2026-11-21");
    }

    #[test]
    fn string_fields_keep_bytes_after_the_terminator_unless_changed() {
        let mut raw = [0u8; HEADER_LEN];
        raw[48..53].copy_from_slice(b"ab\0zz");
        let mut f = FileHeader::from_bytes(&raw);
        assert_eq!(f.date, "ab");
        assert_eq!(&f.encode()[48..53], b"ab\0zz");
        f.date = "c".into();
        assert_eq!(&f.encode()[48..53], b"c\0\0\0\0");
    }

    #[test]
    fn system_type_codes_and_names() {
        for code in 0..5 {
            assert_eq!(SystemType::from_code(code).code(), code);
        }
        assert_eq!(SystemType::Aris3000.name(), "ARIS 3000");
        assert_eq!(SystemType::from_code(2).to_string(), "ARIS 1200");
        assert_eq!(SystemType::from_code(0).to_string(), "ARIS 1800");
    }

    #[test]
    fn ping_modes_map_to_beam_counts() {
        let expect = [
            None,
            Some(48),
            Some(48),
            Some(96),
            Some(96),
            Some(96),
            Some(64),
        ];
        for (mode, e) in expect.iter().enumerate() {
            assert_eq!(beams_for_ping_mode(mode as u32), *e, "mode {mode}");
        }
        assert_eq!(beams_for_ping_mode(8), Some(64));
        assert_eq!(beams_for_ping_mode(9), Some(128));
        assert_eq!(beams_for_ping_mode(12), Some(128));
        assert_eq!(beams_for_ping_mode(13), None);
    }

    #[test]
    fn aris3000_header_defaults() {
        let h = FrameHeader::new_aris3000(128, 512, 4, 2667, 1500.0)
            .unwrap()
            .with_roll_deg(7.0);
        assert_eq!(h.ping_mode_beams(), Some(128));
        assert_eq!(h.reordered_samples, 1);
        assert_eq!(h.system_type, SystemType::Aris3000);
        assert!(!h.telephoto());
        assert!(h.sonar_pan_deg.is_nan() && h.tilt_abs_position_deg.is_nan());
        assert_eq!((h.sonar_roll_deg, h.roll_abs_position_deg), (7.0, 7.0));
        let r = h.range_geometry(512).unwrap();
        assert!((r.start - 2667e-6 * 1500.0 / 2.0).abs() < 1e-12);
        assert!((r.step - 4e-6 * 1500.0 / 2.0).abs() < 1e-12);
        assert!((f64::from(h.window_start_m) - r.start).abs() < 1e-6);
        assert_eq!(h.sample_rate_hz, 250_000.0);
        assert!(FrameHeader::new_aris3000(48, 512, 4, 0, 1500.0).is_err());
        assert!(FrameHeader::new_aris3000(128, 0, 4, 0, 1500.0).is_err());
    }

    #[test]
    fn synthetic_roundtrip_through_reader() {
        let bytes = synthetic(128, 40, 3);
        assert_eq!(bytes.len(), 1024 + 3 * (1024 + 128 * 40));
        let r = ArisReader::new(Cursor::new(bytes.clone())).unwrap();
        assert_eq!(
            (r.beams(), r.samples_per_beam(), r.frame_count()),
            (128, 40, 3)
        );
        assert_eq!(r.file_header().frame_count, 3);
        assert_eq!(r.file_header().file_size, bytes.len() as u64);
        assert!(r.warnings().iter().all(|w| !w.contains("FrameCount")));
        let f = r.frame(2).unwrap();
        assert_eq!(f.sample(1, 3), Some(((128 + 3) * 7 + 2) as u8));
        assert_eq!(f.sample(40, 0), None);
        assert_eq!(f.sample(0, 128), None);
        assert_eq!(f.row(39).unwrap().len(), 128);
        assert_eq!(f.rows().count(), 40);
        assert_eq!(f.header.sonar_roll_deg, 14.0);
        assert_eq!(r.beam_table().unwrap().name, "ARIS3000_128");
        let c = r.beam_centres_rad().unwrap();
        assert!(c.windows(2).all(|w| w[0] < w[1]));
        assert!(matches!(
            r.frame(3),
            Err(ArisError::FrameIndexOutOfRange { index: 3, count: 3 })
        ));
    }

    #[test]
    fn distinct_warnings_are_capped() {
        let mut t = Tally::default();
        for i in 0..100 {
            t.note(format!("odd value {i}"), i);
            t.note("same".into(), i);
        }
        let mut out = Vec::new();
        t.into_warnings(100, &mut out);
        assert_eq!(out.len(), Tally::MAX_DISTINCT + 1);
        assert!(out
            .iter()
            .any(|w| w == "same in 100 of 100 frames (first: frame 0)"));
        assert!(out[0].starts_with("69 further"), "{}", out[0]);
    }

    #[test]
    fn write_recording_builds_a_consistent_file_header() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("one.aris");
        let h = FrameHeader::new_aris3000(64, 30, 4, 0, 1500.0).unwrap();
        write_recording(&path, &[(&h, &[9u8; 64 * 30])]).unwrap();
        let r = ArisReader::open(&path).unwrap();
        assert_eq!(r.file_header().num_raw_beams, 64);
        assert_eq!(r.file_header().samples_per_channel, 30);
        assert_eq!(r.frame(0).unwrap().data, vec![9u8; 64 * 30]);
        assert_eq!(r.beam_table().unwrap().name, "ARIS3000_64");
        assert!(write_recording(&path, &[(&h, &[0u8; 3])]).is_err());
    }

    #[test]
    fn writer_rejects_inconsistent_frames() {
        let fh = FileHeader::new(128, 10);
        let mut w = ArisWriter::new(Cursor::new(Vec::new()), &fh).unwrap();
        let h = FrameHeader::new_aris3000(128, 10, 4, 0, 1500.0).unwrap();
        assert!(matches!(
            w.write_frame(&h, &[0; 5]),
            Err(ArisError::DataLength {
                expected: 1280,
                found: 5
            })
        ));
        w.write_frame(&h, &[0; 1280]).unwrap();
        let h64 = FrameHeader::new_aris3000(64, 10, 4, 0, 1500.0).unwrap();
        assert!(matches!(
            w.write_frame(&h64, &[0; 640]),
            Err(ArisError::GeometryChanged { .. })
        ));
        let mut bad = h.clone();
        bad.ping_mode = 0;
        assert!(matches!(
            w.write_frame(&bad, &[0; 1280]),
            Err(ArisError::BadBeamCount { .. })
        ));
        assert_eq!(w.frames_written(), 1);
        let bad_file = FileHeader::from_bytes(&[0; HEADER_LEN]);
        assert!(matches!(
            ArisWriter::new(Cursor::new(Vec::new()), &bad_file),
            Err(ArisError::BadSignature { .. })
        ));
    }
}
