//! Ground truth on the model's grids: the front depth map and its mask, the elevation map, and
//! the polar input images (through `epssn::geometry::resample_to_grid`, the model's own path).

use anyhow::Result;
use epssn::config::{
    DEPTH_COLUMNS, DEPTH_ROWS, DEPTH_ROW_ELEVATION_RAD, INPUT_COLUMNS, INPUT_COLUMN_AZIMUTH_RAD,
    INPUT_RANGE_BINS, R_MAX_M, R_MIN_M,
};

use crate::render::{beam_centres_rad, frame_header, RenderedView, SonarSimParams};
use crate::scene::Scene;
use crate::world::World;
use epssn_aris::aris::Frame;
use epssn_aris::polar::frame_to_polar;

/// Depth map value and mask for a ray whose first hit is at `t` (None: no hit at all).
///
/// Inside `[r_min, r_max]` the depth is the hit range and the mask 1; nearer hits read r_min,
/// farther or missing ones r_max, both with mask 0.
pub fn depth_label(t: Option<f64>) -> (f64, bool) {
    match t {
        Some(t) if t < R_MIN_M => (R_MIN_M, false),
        Some(t) if t <= R_MAX_M => (t, true),
        _ => (R_MAX_M, false),
    }
}

/// Front depth map (E × A, `depth[e × A + a]`, metres) and mask of view `view`, each ray at
/// `DEPTH_ROW_ELEVATION_RAD[e]`, `INPUT_COLUMN_AZIMUTH_RAD[a]` in that view's frame.
pub fn front_depth(scene: &Scene, world: &World, view: usize) -> (Vec<f64>, Vec<bool>) {
    let wfv = scene.world_from_view(view);
    let mut depth = Vec::with_capacity(DEPTH_ROWS * DEPTH_COLUMNS);
    let mut mask = Vec::with_capacity(DEPTH_ROWS * DEPTH_COLUMNS);
    for &el in DEPTH_ROW_ELEVATION_RAD.iter() {
        for &az in INPUT_COLUMN_AZIMUTH_RAD.iter().take(DEPTH_COLUMNS) {
            let (d, m) = depth_label(world.first_hit_in_view(&wfv, az, el).map(|h| h.t));
            depth.push(d);
            mask.push(m);
        }
    }
    (depth, mask)
}

/// The reference view's depth (metres, f32) and mask (0/1) as a sample folder's `depth.npy` and
/// `mask.npy` hold them: [`front_depth`] of view 0. `simulate` and `label` both write these, so
/// a label from a pose equals the simulated sample's ground truth bit for bit.
pub fn reference_labels(scene: &Scene, world: &World) -> (Vec<f32>, Vec<f32>) {
    let (depth, mask) = front_depth(scene, world, 0);
    (
        depth.iter().map(|d| *d as f32).collect(),
        mask.iter().map(|m| if *m { 1.0 } else { 0.0 }).collect(),
    )
}

/// Polar input image (R × B u8) of a simulated frame, exactly as a reader of the written
/// `.aris` file gets it: through `polar::frame_to_polar` (the file's beam table and range
/// geometry) and so through `epssn::geometry::resample_to_grid`.
pub fn polar_image(samples: &[u8], params: &SonarSimParams) -> Result<Vec<u8>> {
    let frame = Frame {
        index: 0,
        header: frame_header(params, 0.0)?,
        beams: beam_centres_rad().len(),
        samples_per_beam: params.samples_per_beam,
        data: samples.to_vec(),
    };
    frame_to_polar(&frame)
}

/// Elevation map (R × B f32 radians) of a rendered reference view: for each polar pixel, the
/// intensity-weighted mean elevation of the surface points returning into it (the samples of
/// beams 2k and 2k + 1 whose range falls in the pixel's range bin); NaN where none does.
pub fn elevation_map(view: &RenderedView, params: &SonarSimParams) -> Vec<f32> {
    let ranges = params.sample_ranges();
    let beams = beam_centres_rad().len();
    let per_col = beams / INPUT_COLUMNS;
    let bin = (R_MAX_M - R_MIN_M) / INPUT_RANGE_BINS as f64;
    let mut out = vec![f32::NAN; INPUT_RANGE_BINS * INPUT_COLUMNS];
    let mut sw = vec![0.0f64; INPUT_RANGE_BINS * INPUT_COLUMNS];
    let mut swe = vec![0.0f64; INPUT_RANGE_BINS * INPUT_COLUMNS];
    for s in 0..ranges.samples {
        let r = ranges.start + ranges.step * s as f64;
        let i = ((r - R_MIN_M) / bin + 1e-9).floor();
        if i < 0.0 || i >= INPUT_RANGE_BINS as f64 {
            continue;
        }
        let i = i as usize;
        for b in 0..beams {
            let k = b / per_col;
            if k >= INPUT_COLUMNS {
                continue;
            }
            sw[i * INPUT_COLUMNS + k] += view.weight[s * beams + b];
            swe[i * INPUT_COLUMNS + k] += view.weighted_elevation[s * beams + b];
        }
    }
    for (o, (w, we)) in out.iter_mut().zip(sw.iter().zip(&swe)) {
        if *w > 0.0 {
            *o = (we / w) as f32;
        }
    }
    out
}
