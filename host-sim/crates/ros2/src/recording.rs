//! A sonar recording, whichever file holds it: an ARIS file (docs/ARIS.md) or a ROS 2 bag of
//! ProjectedSonarImage (docs/ROS2.md), told apart by the file's first bytes (MCAP's magic).
//! Every command that takes `--recording` reads it through this type.

use std::io::Read;
use std::path::Path;

use anyhow::{Context, Result};
use epssn::attitude::Attitude;
use epssn::ping_average::IntensityTable;
use epssn_aris::aris::ArisReader;

use crate::bag::BagRecording;
use crate::fit::misfit;
use crate::frame::{self, SonarFrame};
use crate::header::{is_mcap, MAGIC};

/// How a bag is read.
#[derive(Clone, Debug, Default)]
pub struct OpenOptions {
    /// The ProjectedSonarImage topic (default: the bag's only one).
    pub topic: Option<String>,
}

/// An opened recording.
pub enum Recording {
    /// An ARIS file.
    Aris(ArisReader),
    /// A ROS 2 bag.
    Bag(BagRecording),
}

impl Recording {
    /// Opens `path`: a bag when it starts with MCAP's magic, else an ARIS file.
    pub fn open(path: &Path, options: &OpenOptions) -> Result<Self> {
        let mut head = [0u8; MAGIC.len()];
        let n = std::fs::File::open(path)
            .and_then(|mut f| f.read(&mut head))
            .with_context(|| format!("opening {}", path.display()))?;
        if is_mcap(&head[..n]) {
            Ok(Self::Bag(BagRecording::open(
                path,
                options.topic.as_deref(),
            )?))
        } else {
            Ok(Self::Aris(ArisReader::open(path)?))
        }
    }

    /// Whether `path` starts as an MCAP file.
    pub fn is_bag(path: &Path) -> bool {
        let mut head = [0u8; MAGIC.len()];
        std::fs::File::open(path)
            .and_then(|mut f| f.read_exact(&mut head))
            .is_ok_and(|_| is_mcap(&head))
    }

    /// The ARIS reader, for an ARIS file.
    pub fn aris(&self) -> Option<&ArisReader> {
        match self {
            Self::Aris(r) => Some(r),
            Self::Bag(_) => None,
        }
    }

    /// Frames (pings).
    pub fn frame_count(&self) -> usize {
        match self {
            Self::Aris(r) => r.frame_count(),
            Self::Bag(b) => b.frame_count(),
        }
    }

    /// What reading the file noticed.
    pub fn warnings(&self) -> &[String] {
        match self {
            Self::Aris(r) => r.warnings(),
            Self::Bag(b) => b.warnings(),
        }
    }

    /// Frame `i`, native.
    pub fn frame(&self, i: usize) -> Result<SonarFrame> {
        match self {
            Self::Aris(r) => SonarFrame::of_aris(r.frame(i)?),
            Self::Bag(b) => b.frame(i),
        }
    }

    /// A bag's pings without a transform take their attitude (the sonar frame → the fixed
    /// frame, as a rotation matrix) from `poses`, e.g. `--poses`; an ARIS file's come from its
    /// headers and are left alone. Returns how many pings it placed.
    pub fn fill_attitudes(&mut self, poses: impl Fn(usize) -> Option<[[f64; 3]; 3]>) -> usize {
        match self {
            Self::Aris(_) => 0,
            Self::Bag(b) => b.fill_attitudes(|i| {
                let [x, y, z, w] = crate::tf::quat_of_matrix(&poses(i)?);
                Attitude::from_array([w as f32, x as f32, y as f32, z as f32])
            }),
        }
    }

    /// Frame `i`'s attitude (docs/POSE.md).
    pub fn attitude(&self, i: usize) -> Option<Attitude> {
        match self {
            Self::Aris(r) => Attitude::from_array(r.frame_header(i).ok()?.attitude()?),
            Self::Bag(b) => b.attitude(i),
        }
    }

    /// Frame `i`'s roll, degrees: the rotator's (ARIS SonarRoll, else RollAbsPosition), or a
    /// bag ping's twist from its transforms.
    pub fn roll_deg(&self, i: usize) -> Option<f64> {
        match self {
            Self::Aris(r) => {
                let h = r.frame_header(i).ok()?;
                [h.sonar_roll_deg, h.roll_abs_position_deg]
                    .into_iter()
                    .find(|r| r.is_finite())
                    .map(f64::from)
            }
            Self::Bag(b) => b.roll_deg(i),
        }
    }

    /// Why the recording cannot feed the model, or `None` when it can: an ARIS file's sonar
    /// (system, lens, beams: `epssn_aris::polar::sensor_mismatch`), or no frame whose fan fits
    /// (the first frame's reason). `misfits` are [`Recording::misfit_frames`], read once by the
    /// caller, who skips or refuses the frames that do not fit among frames that do.
    pub fn geometry_mismatch(&self, misfits: &[(usize, String)]) -> Option<String> {
        if let Self::Aris(r) = self {
            if let Some(why) = epssn_aris::polar::sensor_mismatch(r) {
                return Some(why);
            }
        }
        if misfits.is_empty() || misfits.len() < self.frame_count() {
            return None;
        }
        misfits.first().map(|(_, why)| why.clone())
    }

    /// Every frame whose own geometry does not fit the model, with why, in order: a sonar's
    /// range window (or a bag's fan) can change in mid-recording, and a frame outside the
    /// model's window would be resampled as zeros, so each frame is checked, not the first only.
    pub fn misfit_frames(&self) -> Vec<(usize, String)> {
        let mut out = Vec::new();
        for i in 0..self.frame_count() {
            // A frame that cannot be read as a frame at all fits no better.
            let why = match self {
                Self::Aris(r) => match r
                    .frame_header(i)
                    .and_then(|h| h.range_geometry(r.samples_per_beam()))
                {
                    Ok(ranges) => epssn_aris::polar::range_window_mismatch(&ranges),
                    Err(e) => Some(e.to_string()),
                },
                Self::Bag(b) => match b.frame(i) {
                    Ok(frame) => misfit(&frame),
                    Err(e) => Some(format!("{e:#}")),
                },
            };
            if let Some(why) = why {
                out.push((i, why));
            }
        }
        out
    }

    /// The frames `pings` averaged in intensity into one (the first's geometry and time).
    pub fn average_pings(&self, pings: &[usize], table: &IntensityTable) -> Result<SonarFrame> {
        let frames = pings
            .iter()
            .map(|&p| self.frame(p))
            .collect::<Result<Vec<_>>>()?;
        frame::average(frames, table)
    }
}
