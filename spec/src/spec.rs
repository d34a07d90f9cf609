//! The model spec (`weights/epssn-s.json`) as types.
//!
//! `build.rs` parses the spec with these very types to generate the library's size constants
//! and warp tables; the host tools parse it at run time with them too. The types use
//! `heapless` containers so that they are usable without an allocator. Every struct refuses
//! fields it does not know: a spec written for an option this build lacks (a study option that
//! was reverted, a newer spec) is an error that names the field, never silently another
//! network.

use heapless::{String, Vec};
use serde::{Deserialize, Serialize};

/// Maximum number of layers in one network stage.
pub const MAX_LAYERS: usize = 12;

/// The whole model spec.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    /// Configuration name, e.g. "EPSSN-S".
    pub name: String<32>,
    /// Version of the spec format.
    pub spec_version: u32,
    /// Free text explaining choices made in this configuration.
    #[serde(default)]
    pub notes: String<512>,
    /// The sonar the model is built for.
    pub sonar: SonarSpec,
    /// The range window seen by the model.
    pub range_window: RangeWindow,
    /// Network input per view.
    pub input: InputSpec,
    /// The fixed roll baseline between views.
    pub baseline: BaselineSpec,
    /// Feature maps of the 2D CNN.
    pub features: FeatureSpec,
    /// Number of virtual elevation planes N.
    pub planes: u16,
    /// The front depth map.
    pub output: OutputSpec,
    /// Warp table precision.
    pub warp: WarpSpec,
    /// 2D feature extractor, applied to each view.
    pub feature_net: Vec<LayerSpec, MAX_LAYERS>,
    /// 3D UNet and head, applied to the cost volume.
    pub cost_net: Vec<LayerSpec, MAX_LAYERS>,
    /// Training recipe.
    pub training: TrainingSpec,
}

/// The sonar.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SonarSpec {
    /// System name as the ARIS reader reports it, e.g. "ARIS 3000".
    pub system: String<16>,
    /// Beam-angle table name, e.g. "ARIS3000_128".
    pub beam_table: String<32>,
    /// Beam count.
    pub beams: u16,
    /// Half the elevation aperture, degrees.
    pub elevation_half_aperture_deg: f64,
}

/// The range window.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeWindow {
    /// Start, metres.
    pub r_min_m: f64,
    /// End, metres.
    pub r_max_m: f64,
}

/// Network input per view.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// Range bins R.
    pub range_bins: u16,
    /// Beam columns B.
    pub beam_columns: u16,
}

/// The roll baseline between views.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaselineSpec {
    /// Roll of view k relative to the reference is `k × roll_step_deg`.
    pub roll_step_deg: f64,
    /// Views used by default (reference included).
    pub views: u8,
    /// Most views the library supports.
    pub max_views: u8,
    /// Rotator axis offset from the acoustic centre, metres, reference frame.
    pub lever_arm_m: [f64; 3],
    /// Two frames pair when their roll difference is within this of the baseline, degrees.
    pub pair_tolerance_deg: f64,
    /// Frames with attitude pair only when the relative rotation tilts the forward axis by at
    /// most this (its pitch/yaw residual), degrees; chosen from measurement in docs/POSE.md.
    /// Absent (older specs): the residual is reported but not checked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pair_residual_tolerance_deg: Option<f64>,
}

/// Feature maps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureSpec {
    /// Channels C.
    pub channels: u16,
    /// Stride relative to the input.
    pub stride: u16,
    /// How many of the C channels enter the cost volume as their mean over the views, clipped
    /// at 0, instead of their variance (the last ones). The variance only says how well the views agree on a
    /// plane; the mean carries what a single view sees, the cue a one-view network lives on.
    /// 0 (the default) is the variance-only cost volume of MVSNet.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub mean_channels: u16,
}

fn is_zero(v: &u16) -> bool {
    *v == 0
}

/// The front depth map.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Elevation rows E.
    pub elevation_rows: u16,
    /// Azimuth columns A.
    pub azimuth_columns: u16,
    /// Range bins of the soft-argmax.
    pub range_bins: u16,
    /// How far, in bin steps, the first and last soft-argmax bins reach beyond the range
    /// window: bin 0 stands for `r_min − K·step`, bin `R − 1` for `r_max + K·step`, the others
    /// for their own range; the depth is then clamped to `[r_min, r_max]`. With `K > 0` a ray
    /// that meets nothing reads exactly `r_max` once most of its mass sits in the last bin,
    /// instead of needing all of it (a soft-argmax is a mean, so it never reaches an end
    /// otherwise). 0 (the default) is the plain soft-argmax.
    #[serde(default)]
    pub end_bin_offset: u16,
    /// The no-return decision: a ray whose soft-argmax mass in the last bin is at least this
    /// fraction met nothing inside the window and reads exactly `r_max`; otherwise one whose
    /// mass in the first bin is at least this fraction met a surface nearer than the window
    /// and reads exactly `r_min`. In `(0, 1]`; 0 (the default) decides nothing, every ray
    /// reads its soft-argmax. The integer rule is `e_{R−1}·2^16 ≥ τ16·S` with
    /// `τ16 = round(τ·2^16)` (docs/QUANTISATION.md "No-return decision").
    #[serde(default)]
    pub no_return_mass: f64,
}

/// Warp table precision.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WarpSpec {
    /// Bits of the bilinear fraction.
    pub fraction_bits: u32,
}

/// Kind of a layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LayerKind {
    /// 2D convolution.
    Conv2d,
    /// 3D convolution.
    Conv3d,
    /// 3D transposed convolution.
    ConvTranspose3d,
}

/// One layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayerSpec {
    /// Name, unique in the spec.
    pub name: String<8>,
    /// Kind.
    pub kind: LayerKind,
    /// Input channels.
    #[serde(rename = "in")]
    pub in_channels: u16,
    /// Output channels.
    #[serde(rename = "out")]
    pub out_channels: u16,
    /// Kernel size per spatial axis.
    pub kernel: Vec<u8, 3>,
    /// Stride per spatial axis.
    pub stride: Vec<u8, 3>,
    /// Zero padding per spatial axis.
    pub padding: Vec<u8, 3>,
    /// Extra output size of a transposed convolution per axis.
    #[serde(default)]
    pub output_padding: Vec<u8, 3>,
    /// Batch norm after the convolution (folded away before quantising).
    pub batch_norm: bool,
    /// ReLU after batch norm.
    pub relu: bool,
    /// Name of a tensor added after the ReLU ("cost" for the cost volume).
    #[serde(default)]
    pub skip: Option<String<8>>,
}

/// Training recipe.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingSpec {
    /// Human-readable loss.
    pub loss: String<96>,
    /// Weight of in-window pixels in the masked L1 loss.
    pub lambda: f64,
    /// Optimiser name.
    pub optimizer: String<16>,
    /// Learning rate.
    pub lr: f64,
    /// The learning rate halves at this fraction of training.
    pub lr_halved_at_fraction: f64,
    /// Batch size.
    pub batch: u16,
}

impl LayerSpec {
    /// Output size along each spatial axis for an input of `input` (same rank as the kernel);
    /// saturating, so that no spec makes it overflow (the build's check refuses an activation
    /// whose element count does not fit a `usize`).
    pub fn output_size(&self, input: &[usize]) -> Vec<usize, 3> {
        let mut out = Vec::new();
        for (axis, &n) in input.iter().enumerate() {
            let k = *self.kernel.get(axis).unwrap_or(&1) as usize;
            let s = *self.stride.get(axis).unwrap_or(&1) as usize;
            let p = *self.padding.get(axis).unwrap_or(&0) as usize;
            let op = *self.output_padding.get(axis).unwrap_or(&0) as usize;
            let o = match self.kind {
                LayerKind::Conv2d | LayerKind::Conv3d => {
                    (n.saturating_add(2 * p).saturating_sub(k) / s.max(1)).saturating_add(1)
                }
                LayerKind::ConvTranspose3d => {
                    (n.saturating_sub(1).saturating_mul(s).saturating_add(k + op))
                        .saturating_sub(2 * p)
                }
            };
            let _ = out.push(o);
        }
        out
    }

    /// Number of weights (without bias).
    pub fn weight_count(&self) -> usize {
        let k: usize = self.kernel.iter().map(|&k| k as usize).product();
        k * self.in_channels as usize * self.out_channels as usize
    }
}
