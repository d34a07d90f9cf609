//! The angle and range grids of a model configuration, derived from its spec and beam table.
//!
//! `build.rs` compiles this file to generate the library's static tables for the compiled
//! configuration; the host tools call [`ModelGrids::derive`] at run time for any spec (for
//! example a tiny configuration in tests). Both therefore get the same numbers.

use crate::geometry::{self, RigidTransform, WarpEntry};
use crate::spec::ModelSpec;
use heapless::Vec;

/// Most elements of any one grid.
pub const MAX_GRID: usize = 512;
/// Most entries of one warp table (planes × feature columns).
pub const MAX_WARP: usize = 64 * 64;

/// Why a spec cannot be turned into grids.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridError {
    /// The beam table has a different number of beams than the spec.
    BeamCount,
    /// Beams are not a multiple of input columns, or the input is not a multiple of the stride.
    Divisibility,
    /// A grid is larger than [`MAX_GRID`] or a warp table larger than [`MAX_WARP`].
    TooLarge,
    /// The baseline's lever arm changes range; the range-independent table does not apply.
    NotRangePreserving,
    /// Views outside 2..=3.
    Views,
}

/// Grids of one configuration. All angles are radians, ascending where they are azimuths.
#[derive(Clone, Debug)]
pub struct ModelGrids {
    /// Start of the range window, metres.
    pub r_min: f64,
    /// End of the range window, metres.
    pub r_max: f64,
    /// Half the elevation aperture.
    pub half_elevation: f64,
    /// Beam centres of the sonar table.
    pub beam_azimuths: Vec<f64, MAX_GRID>,
    /// Azimuth of each input column (mean of its beams); also the depth map's columns.
    pub input_azimuths: Vec<f64, MAX_GRID>,
    /// Azimuth of each feature column (mean of its `stride` input columns).
    pub feature_azimuths: Vec<f64, MAX_GRID>,
    /// Centre range of each input range bin, metres.
    pub input_ranges: Vec<f64, MAX_GRID>,
    /// Centre range of each feature range bin, metres.
    pub feature_ranges: Vec<f64, MAX_GRID>,
    /// Elevation of each virtual plane.
    pub plane_elevations: Vec<f64, MAX_GRID>,
    /// Elevation of each depth-map row.
    pub depth_row_elevations: Vec<f64, MAX_GRID>,
    /// Range each soft-argmax bin stands for, metres (the end bins reach `end_bin_offset` steps
    /// beyond the window).
    pub depth_bin_ranges: Vec<f64, MAX_GRID>,
}

fn collect(n: usize, f: impl Fn(usize) -> f64) -> Result<Vec<f64, MAX_GRID>, GridError> {
    let mut v = Vec::new();
    for i in 0..n {
        v.push(f(i)).map_err(|_| GridError::TooLarge)?;
    }
    Ok(v)
}

impl ModelGrids {
    /// Derives every grid of `spec` with the sonar's beam centres in degrees (beam 0 first).
    pub fn derive(spec: &ModelSpec, beam_centres_deg: &[f64]) -> Result<Self, GridError> {
        let beams = spec.sonar.beams as usize;
        if beam_centres_deg.len() != beams {
            return Err(GridError::BeamCount);
        }
        let r = spec.input.range_bins as usize;
        let b = spec.input.beam_columns as usize;
        let stride = spec.features.stride as usize;
        if b == 0
            || stride == 0
            || !beams.is_multiple_of(b)
            || !r.is_multiple_of(stride)
            || !b.is_multiple_of(stride)
        {
            return Err(GridError::Divisibility);
        }
        let group = beams / b;
        let beam_azimuths = collect(beams, |i| geometry::deg_to_rad(beam_centres_deg[i]))?;
        let input_azimuths = collect(b, |k| geometry::grouped_azimuth(&beam_azimuths, group, k))?;
        let feature_azimuths = collect(b / stride, |k| {
            geometry::grouped_azimuth(&input_azimuths, stride, k)
        })?;
        let half = geometry::deg_to_rad(spec.sonar.elevation_half_aperture_deg);
        let grid = geometry::Grid {
            r_min: spec.range_window.r_min_m,
            r_max: spec.range_window.r_max_m,
            half_elevation: half,
            column_azimuths: &input_azimuths,
        };
        let n = spec.planes as usize;
        let e = spec.output.elevation_rows as usize;
        let dr = spec.output.range_bins as usize;
        Ok(Self {
            r_min: grid.r_min,
            r_max: grid.r_max,
            half_elevation: half,
            input_ranges: collect(r, |i| grid.range_bin_centre(i, r))?,
            feature_ranges: collect(r / stride, |i| grid.range_bin_centre(i, r / stride))?,
            plane_elevations: collect(n, |j| grid.elevation(j, n))?,
            depth_row_elevations: collect(e, |j| grid.elevation(j, e))?,
            depth_bin_ranges: collect(dr, |i| {
                grid.depth_bin_weight(i, dr, spec.output.end_bin_offset)
            })?,
            beam_azimuths,
            input_azimuths,
            feature_azimuths,
        })
    }

    /// The reference → source transform of view `k` (k = 1, 2) of `spec`.
    pub fn view_transform(spec: &ModelSpec, k: usize) -> RigidTransform {
        RigidTransform::rolled_about_axis(
            spec.baseline.roll_step_deg * k as f64,
            spec.baseline.lever_arm_m,
        )
    }

    /// The range-independent warp table of view `k` (`[plane × feature_columns + column]`).
    pub fn warp_table(
        &self,
        spec: &ModelSpec,
        k: usize,
    ) -> Result<Vec<WarpEntry, MAX_WARP>, GridError> {
        if !(1..=2).contains(&k) {
            return Err(GridError::Views);
        }
        let len = self.plane_elevations.len() * self.feature_azimuths.len();
        let mut table: Vec<WarpEntry, MAX_WARP> = Vec::new();
        table
            .resize(len, WarpEntry::default())
            .map_err(|_| GridError::TooLarge)?;
        geometry::warp_table_pure_roll(
            &Self::view_transform(spec, k),
            &self.feature_azimuths,
            &self.plane_elevations,
            self.half_elevation,
            spec.warp.fraction_bits,
            &mut table,
        )
        .map_err(|e| match e {
            geometry::WarpError::NotRangePreserving => GridError::NotRangePreserving,
            _ => GridError::TooLarge,
        })?;
        Ok(table)
    }

    /// The resampling grid for [`geometry::resample_to_grid`].
    pub fn input_grid(&self) -> geometry::Grid<'_> {
        geometry::Grid {
            r_min: self.r_min,
            r_max: self.r_max,
            half_elevation: self.half_elevation,
            column_azimuths: &self.input_azimuths,
        }
    }
}
