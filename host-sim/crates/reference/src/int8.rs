//! The int8 library's depth map in metres, for host code that scores it.

use anyhow::{anyhow, Result};
use epssn::config;
use epssn::model::{Model, Workspace};
use fixed::types::U16F16;

/// The library's depth map (metres, `[E][A]`) of one view set through [`Model::depth`]
/// (`views[0]` the reference; one view is its own source, as the float model's single-view
/// ablation does).
pub fn depth_metres<V: AsRef<[u8]>>(
    model: &Model<'_>,
    views: &[V],
    ws: &mut Workspace,
) -> Result<Vec<f32>> {
    let views: Vec<&[u8]> = views.iter().map(AsRef::as_ref).collect();
    let mut features = vec![0i8; views.len() * config::FEATURE_LEN];
    let mut depth = vec![U16F16::ZERO; config::DEPTH_LEN];
    model
        .depth(&views, &mut features, ws, &mut depth)
        .map_err(|e| anyhow!("int8 depth: {e:?}"))?;
    Ok(depth.iter().map(|d| d.to_num::<f32>()).collect())
}
