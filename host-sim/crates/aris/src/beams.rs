//! ARIS beam-angle tables (Sound Metrics' public file SDK, MIT licence; see `data/README.md`).
//!
//! The tables are embedded at compile time so that the tool works without the data folder.
//! Beam spacing is not uniform: consumers must interpolate through a table, never assume a
//! linear fan.

use std::sync::OnceLock;

use std::fmt;

/// ARIS model (frame header TheSystemType).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SystemType {
    /// 0: ARIS 1800.
    Aris1800,
    /// 1: ARIS 3000.
    Aris3000,
    /// 2: ARIS 1200.
    Aris1200,
    /// Any other code, kept so it can be written back unchanged.
    Unknown(u32),
}

impl SystemType {
    /// From the header code.
    pub fn from_code(code: u32) -> Self {
        match code {
            0 => Self::Aris1800,
            1 => Self::Aris3000,
            2 => Self::Aris1200,
            other => Self::Unknown(other),
        }
    }

    /// The header code.
    pub fn code(self) -> u32 {
        match self {
            Self::Aris1800 => 0,
            Self::Aris3000 => 1,
            Self::Aris1200 => 2,
            Self::Unknown(code) => code,
        }
    }

    /// Display name, e.g. "ARIS 3000".
    pub fn name(self) -> String {
        self.to_string()
    }
}

impl fmt::Display for SystemType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Aris1800 => f.write_str("ARIS 1800"),
            Self::Aris3000 => f.write_str("ARIS 3000"),
            Self::Aris1200 => f.write_str("ARIS 1200"),
            Self::Unknown(code) => write!(f, "unknown ARIS system type {code}"),
        }
    }
}

/// Why no beam table can be given.
#[derive(Debug, thiserror::Error)]
pub enum BeamTableError {
    /// No beam-angle table is known for this sonar configuration.
    #[error(
        "no beam table for {system} with {beams} beams{}",
        if *.telephoto { " and a telephoto lens" } else { "" }
    )]
    NoBeamTable {
        /// System type.
        system: SystemType,
        /// Beam count.
        beams: usize,
        /// Telephoto lens.
        telephoto: bool,
    },
    /// The embedded beam-table data is malformed (a build problem, not a file problem).
    #[error("embedded beam table data: {0}")]
    Data(String),
}

pub use epssn_spec::load::BeamTable;

/// The embedded tables: (name, CSV text).
const SOURCES: [(&str, &str); 6] = [
    (
        "ARIS1800_1200_48",
        include_str!("../../../../data/aris-beam-widths/ARIS1800_1200_48.csv"),
    ),
    (
        "ARIS1800_96",
        include_str!("../../../../data/aris-beam-widths/ARIS1800_96.csv"),
    ),
    (
        "ARIS3000_128",
        include_str!("../../../../data/aris-beam-widths/ARIS3000_128.csv"),
    ),
    (
        "ARIS3000_64",
        include_str!("../../../../data/aris-beam-widths/ARIS3000_64.csv"),
    ),
    (
        "ARIS_Telephoto_48",
        include_str!("../../../../data/aris-beam-widths/ARIS_Telephoto_48.csv"),
    ),
    (
        "ARIS_Telephoto_96",
        include_str!("../../../../data/aris-beam-widths/ARIS_Telephoto_96.csv"),
    ),
];

/// Parses one table's CSV through the one beam-table parser ([`epssn_spec::load`]).
pub fn parse_table(name: &str, csv: &str) -> Result<BeamTable, String> {
    epssn_spec::load::parse_beam_table(name, csv)
}

/// All embedded tables, parsed once.
pub fn tables() -> Result<&'static [BeamTable], BeamTableError> {
    static TABLES: OnceLock<Result<Vec<BeamTable>, String>> = OnceLock::new();
    TABLES
        .get_or_init(|| SOURCES.iter().map(|(n, csv)| parse_table(n, csv)).collect())
        .as_ref()
        .map(Vec::as_slice)
        .map_err(|e| BeamTableError::Data(e.clone()))
}

/// The embedded table with this name.
pub fn table_by_name(name: &str) -> Result<&'static BeamTable, BeamTableError> {
    tables()?
        .iter()
        .find(|t| t.name == name)
        .ok_or_else(|| BeamTableError::Data(format!("no embedded table named {name}")))
}

/// Name of the table that applies to a system, beam count and lens (docs/ARIS.md's rules).
pub fn table_name_for(
    system: SystemType,
    beams: usize,
    telephoto: bool,
) -> Result<&'static str, BeamTableError> {
    let none = || BeamTableError::NoBeamTable {
        system,
        beams,
        telephoto,
    };
    if let SystemType::Unknown(_) = system {
        return Err(none());
    }
    if telephoto {
        return match beams {
            48 => Ok("ARIS_Telephoto_48"),
            96 => Ok("ARIS_Telephoto_96"),
            _ => Err(none()),
        };
    }
    match (system, beams) {
        (SystemType::Aris3000, 128) => Ok("ARIS3000_128"),
        (SystemType::Aris3000, 64) => Ok("ARIS3000_64"),
        (SystemType::Aris1800, 96) => Ok("ARIS1800_96"),
        (SystemType::Aris1800, 48) | (SystemType::Aris1200, 48) => Ok("ARIS1800_1200_48"),
        _ => Err(none()),
    }
}

/// The beam table for a system, beam count and lens.
pub fn beam_table_for(
    system: SystemType,
    beams: usize,
    telephoto: bool,
) -> Result<&'static BeamTable, BeamTableError> {
    let table = table_by_name(table_name_for(system, beams, telephoto)?)?;
    if table.beams() != beams {
        // Only reachable if the embedded data were wrong; say so rather than misalign beams.
        return Err(BeamTableError::Data(format!(
            "{} has {} beams, expected {beams}",
            table.name,
            table.beams()
        )));
    }
    Ok(table)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_embedded_table_parses_with_its_named_beam_count() {
        let tables = tables().unwrap();
        assert_eq!(tables.len(), SOURCES.len());
        for t in tables {
            let suffix: usize = t.name.rsplit('_').next().unwrap().parse().unwrap();
            assert_eq!(t.beams(), suffix, "{}", t.name);
            assert!(
                t.centre_deg[0] < 0.0,
                "{}: beam 0 must be right-most",
                t.name
            );
            assert!(*t.centre_deg.last().unwrap() > 0.0, "{}", t.name);
        }
    }

    #[test]
    fn table_choice_follows_the_rules() {
        use SystemType::*;
        let name = |s, b, t| table_name_for(s, b, t).unwrap();
        assert_eq!(name(Aris3000, 128, false), "ARIS3000_128");
        assert_eq!(name(Aris3000, 64, false), "ARIS3000_64");
        assert_eq!(name(Aris1800, 96, false), "ARIS1800_96");
        assert_eq!(name(Aris1800, 48, false), "ARIS1800_1200_48");
        assert_eq!(name(Aris1200, 48, false), "ARIS1800_1200_48");
        assert_eq!(name(Aris1200, 48, true), "ARIS_Telephoto_48");
        assert_eq!(name(Aris1800, 96, true), "ARIS_Telephoto_96");
        assert!(table_name_for(Aris3000, 48, false).is_err());
        assert!(table_name_for(Aris1200, 128, false).is_err());
        assert!(table_name_for(Unknown(7), 128, false).is_err());
        assert!(beam_table_for(Aris1200, 64, true).is_err());
    }

    #[test]
    fn malformed_csv_is_rejected() {
        assert!(parse_table("x", "h\n0,1,2,3\n1,0.5,2,3\n").is_err()); // descending
        assert!(parse_table("x", "h\n0,1,2,3\n2,2,2,3\n").is_err()); // gap
        assert!(parse_table("x", "h\n0,1,2\n").is_err());
        assert!(parse_table("x", "h\n0,nan,2,3\n1,2,3,4\n").is_err());
        assert!(parse_table("x", "h\n0,1,2,3\n1,2,3,4\n").is_ok());
    }
}
