//! `host-sim inspect FILE [--json]`: a summary of an ARIS recording.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;

use crate::aris::{ArisReader, FrameHeader};

/// Options of `host-sim inspect`.
#[derive(Debug, Clone)]
pub struct InspectOptions {
    /// The .aris recording.
    pub file: PathBuf,
    /// Print machine-readable JSON instead of text (NaN fields become null).
    pub json: bool,
}

/// One frame's line of the report.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct FrameSummary {
    /// Position in the file.
    pub index: usize,
    /// FrameIndex as recorded.
    pub frame_index: u32,
    /// FrameTime, µs since the Unix epoch.
    pub time_us: u64,
    /// SonarRoll (rotator output), degrees; null when NaN.
    pub sonar_roll_deg: Option<f64>,
    /// RollAbsPosition (rotator encoder), degrees; null when NaN.
    pub roll_abs_position_deg: Option<f64>,
    /// Roll (platform), degrees; null when NaN.
    pub platform_roll_deg: Option<f64>,
    /// Pitch (platform), degrees; null when NaN.
    pub platform_pitch_deg: Option<f64>,
    /// Heading (platform), degrees; null when NaN.
    pub platform_heading_deg: Option<f64>,
    /// The sonar compass's heading, pitch and roll, degrees; null when NaN.
    pub compass_deg: [Option<f64>; 3],
    /// The attitude the pairing gate uses, `[w, x, y, z]` (docs/POSE.md); null without one.
    pub attitude_q: Option<[f32; 4]>,
}

/// Everything `inspect` reports.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct InspectReport {
    /// The file inspected.
    pub file: String,
    /// File length, bytes.
    pub file_size_bytes: u64,
    /// Complete frames (from the file length).
    pub frame_count: usize,
    /// The file header's FrameCount, for comparison.
    pub header_frame_count: u32,
    /// Beams per frame.
    pub beams: usize,
    /// Samples per beam.
    pub samples_per_beam: usize,
    /// System name, e.g. "ARIS 1200".
    pub system: String,
    /// TheSystemType code.
    pub system_type_code: u32,
    /// Frame 0's LargeLens = 1.
    pub telephoto: bool,
    /// Frame 0 SoundSpeed, m/s; null when NaN.
    pub sound_speed_m_s: Option<f64>,
    /// Frame 0 SamplePeriod, µs.
    pub sample_period_us: u32,
    /// Frame 0 SampleStartDelay, µs.
    pub sample_start_delay_us: u32,
    /// Computed window start, m (docs/ARIS.md); null when the geometry is unusable.
    pub window_start_m: Option<f64>,
    /// Computed range step per sample, m.
    pub range_step_m: Option<f64>,
    /// Computed window length, m.
    pub window_length_m: Option<f64>,
    /// The header's own WindowStart, m.
    pub header_window_start_m: Option<f64>,
    /// The header's own WindowLength, m.
    pub header_window_length_m: Option<f64>,
    /// Beam table name; null when none applies.
    pub beam_table: Option<String>,
    /// Centres of the first and last beam, degrees.
    pub beam_span_deg: Option<[f64; 2]>,
    /// Per-frame times and rolls.
    pub frames: Vec<FrameSummary>,
    /// Everything odd the reader found.
    pub warnings: Vec<String>,
}

/// NaN and infinities have no JSON form: report them as null.
fn finite(v: f32) -> Option<f64> {
    v.is_finite().then_some(f64::from(v))
}

fn finite64(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn frame_summary(index: usize, h: &FrameHeader) -> FrameSummary {
    FrameSummary {
        index,
        frame_index: h.frame_index,
        time_us: h.frame_time_us,
        sonar_roll_deg: finite(h.sonar_roll_deg),
        roll_abs_position_deg: finite(h.roll_abs_position_deg),
        platform_roll_deg: finite(h.platform_roll_deg),
        platform_pitch_deg: finite(h.platform_pitch_deg),
        platform_heading_deg: finite(h.platform_heading_deg),
        compass_deg: [
            finite(h.compass_heading_deg),
            finite(h.compass_pitch_deg),
            finite(h.compass_roll_deg),
        ],
        attitude_q: h.attitude(),
    }
}

/// Opens `file` and builds the report (reads headers only, never samples).
pub fn report(file: &std::path::Path) -> anyhow::Result<InspectReport> {
    let reader =
        ArisReader::open(file).with_context(|| format!("cannot inspect {}", file.display()))?;
    let h = reader.first_frame_header();
    let samples = reader.samples_per_beam();
    let ranges = h.range_geometry(samples).ok();
    let table = reader.beam_table().ok();
    let mut frames = Vec::with_capacity(reader.frame_count());
    for i in 0..reader.frame_count() {
        let fh = reader
            .frame_header(i)
            .with_context(|| format!("reading frame {i} of {}", file.display()))?;
        frames.push(frame_summary(i, &fh));
    }
    Ok(InspectReport {
        file: file.display().to_string(),
        file_size_bytes: reader.source_len(),
        frame_count: reader.frame_count(),
        header_frame_count: reader.file_header().frame_count,
        beams: reader.beams(),
        samples_per_beam: samples,
        system: reader.system().name(),
        system_type_code: reader.system().code(),
        telephoto: reader.telephoto(),
        sound_speed_m_s: finite(h.sound_speed_m_s),
        sample_period_us: h.sample_period_us,
        sample_start_delay_us: h.sample_start_delay_us,
        window_start_m: ranges.as_ref().and_then(|r| finite64(r.start)),
        range_step_m: ranges.as_ref().and_then(|r| finite64(r.step)),
        window_length_m: ranges
            .as_ref()
            .and_then(|r| finite64(r.step * samples as f64)),
        header_window_start_m: finite(h.window_start_m),
        header_window_length_m: finite(h.window_length_m),
        beam_table: table.map(|t| t.name.to_string()),
        beam_span_deg: table.map(|t| {
            let (a, b) = t.centre_span_deg();
            [a, b]
        }),
        frames,
        warnings: reader.warnings().to_vec(),
    })
}

/// µs since the Unix epoch as `YYYY-MM-DD hh:mm:ss.uuuuuu UTC` (proleptic Gregorian).
pub fn format_time_us(us: u64) -> String {
    let secs = us / 1_000_000;
    let micros = us % 1_000_000;
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Days → civil date (H. Hinnant's algorithm); exact for every u64 input's range.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}.{micros:06} UTC",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

fn opt(v: Option<f64>, digits: usize, unit: &str) -> String {
    match v {
        Some(v) => format!("{v:.digits$} {unit}"),
        None => "NaN/unavailable".to_string(),
    }
}

/// Writes the human-readable summary.
pub fn write_text(r: &InspectReport, out: &mut dyn Write) -> std::io::Result<()> {
    writeln!(
        out,
        "file:              {} ({} bytes)",
        r.file, r.file_size_bytes
    )?;
    writeln!(
        out,
        "system:            {} (TheSystemType {}), {} lens",
        r.system,
        r.system_type_code,
        if r.telephoto { "telephoto" } else { "standard" }
    )?;
    writeln!(out, "beams:             {}", r.beams)?;
    writeln!(out, "samples per beam:  {}", r.samples_per_beam)?;
    writeln!(
        out,
        "frames:            {} complete (file header FrameCount {})",
        r.frame_count, r.header_frame_count
    )?;
    writeln!(
        out,
        "sound speed:       {}",
        opt(r.sound_speed_m_s, 2, "m/s")
    )?;
    writeln!(
        out,
        "sample period:     {} µs, start delay {} µs, range step {}",
        r.sample_period_us,
        r.sample_start_delay_us,
        opt(r.range_step_m.map(|s| s * 1000.0), 3, "mm")
    )?;
    writeln!(
        out,
        "window (computed): start {}, length {}",
        opt(r.window_start_m, 4, "m"),
        opt(r.window_length_m, 4, "m")
    )?;
    writeln!(
        out,
        "window (header):   start {}, length {}",
        opt(r.header_window_start_m, 4, "m"),
        opt(r.header_window_length_m, 4, "m")
    )?;
    match (&r.beam_table, r.beam_span_deg) {
        (Some(name), Some([a, b])) => writeln!(
            out,
            "beam table:        {name}, centres {a:.3}° … {b:.3}° (span {:.3}°)",
            b - a
        )?,
        _ => writeln!(out, "beam table:        none applies")?,
    }
    writeln!(out, "frames:")?;
    writeln!(
        out,
        "  {:>6} {:>6}  {:<31} {:>10} {:>10} {:>10}",
        "index", "FrmIdx", "time", "SonarRoll", "RollAbs", "Roll"
    )?;
    let deg = |v: Option<f64>| v.map_or_else(|| "NaN".to_string(), |v| format!("{v:.3}"));
    for f in &r.frames {
        writeln!(
            out,
            "  {:>6} {:>6}  {:<31} {:>10} {:>10} {:>10}",
            f.index,
            f.frame_index,
            format_time_us(f.time_us),
            deg(f.sonar_roll_deg),
            deg(f.roll_abs_position_deg),
            deg(f.platform_roll_deg)
        )?;
    }
    if r.warnings.is_empty() {
        writeln!(out, "warnings:          none")?;
    } else {
        writeln!(out, "warnings:")?;
        for w in &r.warnings {
            writeln!(out, "  - {w}")?;
        }
    }
    Ok(())
}

/// Runs the subcommand, printing to `out`.
pub fn run(args: &InspectOptions, out: &mut dyn Write) -> anyhow::Result<()> {
    let r = report(&args.file)?;
    if args.json {
        serde_json::to_writer_pretty(&mut *out, &r)?;
        writeln!(out)?;
    } else {
        write_text(&r, out)?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_formatting_matches_known_dates() {
        assert_eq!(format_time_us(0), "1970-01-01 00:00:00.000000 UTC");
        // 2000-03-01 is day 11017; checks the leap-year March boundary.
        assert_eq!(
            format_time_us(11_017 * 86_400_000_000 + 3_723_000_042),
            "2000-03-01 01:02:03.000042 UTC"
        );
        assert_eq!(
            format_time_us(951_868_800_000_000 - 1),
            "2000-02-29 23:59:59.999999 UTC"
        );
        // Must not panic at the extreme.
        assert!(format_time_us(u64::MAX).ends_with("UTC"));
    }

    #[test]
    fn non_finite_values_become_none() {
        assert_eq!(finite(f32::NAN), None);
        assert_eq!(finite(f32::INFINITY), None);
        assert_eq!(finite(1.5), Some(1.5));
    }
}
