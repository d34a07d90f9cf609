//! The rules a model spec must keep for the library to be built from it (`std` feature).
//!
//! [`check`] is the one gate between a spec file and the generated `epssn::config`: it refuses a
//! spec that breaks any rule with a [`SpecError`] naming the rule, and hands `codegen` the
//! sizes, grids and warp tables it derived on the way, so generation itself cannot fail.

use std::string::{String, ToString};
use std::vec::Vec;

use crate::geometry::WarpEntry;
use crate::grids::{GridError, ModelGrids, MAX_WARP};
use crate::spec::{LayerKind, LayerSpec, ModelSpec};

/// A rule of the spec that the library's build relies on, broken.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SpecError {
    /// The spec's beam count is not the beam table's.
    BeamTable,
    /// `beam_columns` is 0 or does not divide the beams.
    BeamColumns,
    /// The feature stride is 0 or does not divide the input's range bins and columns.
    Stride,
    /// The depth map's azimuth columns are not the input's beam columns.
    AzimuthColumns,
    /// `max_views` is not 2 or 3.
    MaxViews,
    /// `views` is not within `2..=max_views`.
    Views,
    /// The grids cannot be derived from the spec and its beam table.
    Grids(GridError),
    /// A layer's name is empty, not an identifier (it names a generated constant) or not unique.
    LayerName(String),
    /// A feature-net layer is not a 2D convolution.
    FeatureLayerKind(String),
    /// The feature net's output is not the input divided by the stride.
    FeatureSize,
    /// The feature net's last layer does not give `features.channels` channels.
    FeatureChannels,
    /// `features.mean_channels` exceeds `features.channels`.
    MeanChannels,
    /// A cost-net layer is a 2D convolution.
    CostLayerKind(String),
    /// The cost net's output is not (elevation rows, range bins, azimuth columns).
    CostSize,
    /// The head (the cost net's last layer) has more or fewer than one output channel.
    HeadChannels,
    /// An activation's element count overflows.
    ActivationSize(String),
    /// A view's warp table cannot be built.
    WarpTable(GridError),
    /// The soft-argmax has fewer than two range bins (its step would divide by zero).
    DepthBins,
    /// `end_bin_offset` steps reach below zero range.
    EndBinOffset,
    /// `no_return_mass` is neither 0 nor in (0, 1].
    NoReturnMass,
}

impl core::fmt::Display for SpecError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("model spec: ")?;
        match self {
            Self::BeamTable => f.write_str("beam count differs from the beam table"),
            Self::BeamColumns => f.write_str("beams must be a multiple of beam_columns (not 0)"),
            Self::Stride => f.write_str("input size must be a multiple of the stride (not 0)"),
            Self::AzimuthColumns => f.write_str(
                "azimuth_columns must equal beam_columns (depth columns are input columns)",
            ),
            Self::MaxViews => f.write_str("max_views is 2 or 3"),
            Self::Views => f.write_str("views within 2..=max_views"),
            Self::Grids(e) => write!(f, "the grids cannot be derived ({e:?})"),
            Self::LayerName(n) => write!(
                f,
                "layer name {n:?} must be a unique identifier (letters, digits, `_`; not a digit first)"
            ),
            Self::FeatureLayerKind(n) => write!(f, "feature_net layers are conv2d (`{n}` is not)"),
            Self::FeatureSize => f.write_str("feature_net output size must be input / stride"),
            Self::FeatureChannels => {
                f.write_str("feature_net output channels must be features.channels")
            }
            Self::MeanChannels => {
                f.write_str("features.mean_channels must not exceed features.channels")
            }
            Self::CostLayerKind(n) => write!(f, "cost_net layers are 3D (`{n}` is conv2d)"),
            Self::CostSize => f.write_str(
                "cost_net output must be (elevation_rows, range_bins, azimuth_columns)",
            ),
            Self::HeadChannels => f.write_str("the head has one output channel"),
            Self::ActivationSize(n) => write!(f, "layer `{n}`'s activation size overflows"),
            Self::WarpTable(e) => write!(
                f,
                "warp table ({e:?}; a lever arm needs the range-dependent table, which the library \
                 does not run yet)"
            ),
            Self::DepthBins => f.write_str("output.range_bins must be at least 2"),
            Self::EndBinOffset => f.write_str("end_bin_offset reaches below zero range"),
            Self::NoReturnMass => f.write_str("no_return_mass must be 0 (no decision) or in (0, 1]"),
        }
    }
}

impl std::error::Error for SpecError {}

/// One layer with the spatial sizes it reads and writes (2 axes in the feature net, 3 in the
/// cost net).
#[derive(Clone, Debug, PartialEq)]
pub struct LayerSizes {
    /// The layer as the spec gives it.
    pub layer: LayerSpec,
    /// Input size per spatial axis.
    pub input: Vec<usize>,
    /// Output size per spatial axis.
    pub output: Vec<usize>,
}

/// The sizes of a spec that keeps every rule.
#[derive(Clone, Debug, PartialEq)]
pub struct Sizes {
    /// Sonar beams.
    pub beams: usize,
    /// Adjacent beams averaged into one input column.
    pub beams_per_column: usize,
    /// Input range bins R.
    pub input_range_bins: usize,
    /// Input beam columns B.
    pub input_columns: usize,
    /// Feature channels C.
    pub feature_channels: usize,
    /// Feature stride.
    pub feature_stride: usize,
    /// Feature range bins R / stride.
    pub feature_range_bins: usize,
    /// Feature columns B / stride.
    pub feature_columns: usize,
    /// Elevation planes N.
    pub planes: usize,
    /// Depth map elevation rows E.
    pub depth_rows: usize,
    /// Depth map azimuth columns A.
    pub depth_columns: usize,
    /// Range bins of the soft-argmax.
    pub depth_range_bins: usize,
    /// Most views, reference included.
    pub max_views: usize,
    /// Every layer in execution order: the feature net, then the cost net.
    pub layers: Vec<LayerSizes>,
    /// Largest activation of the feature net (the input included), elements.
    pub max_feature_activation: usize,
    /// Largest activation of the cost net (the cost volume included), elements.
    pub max_cost_activation: usize,
}

/// A spec that keeps every rule, with what was derived from it.
#[derive(Clone, Debug)]
pub struct Checked {
    /// Its sizes.
    pub sizes: Sizes,
    /// Its grids, with the beam table's centres.
    pub grids: ModelGrids,
    /// The warp table of each source view 1..max_views.
    pub warp_tables: Vec<heapless::Vec<WarpEntry, MAX_WARP>>,
}

/// Checks `spec` with its beam table's centres (degrees, beam 0 first) against every rule the
/// library's build relies on, in a fixed order (the first rule broken is reported).
pub fn check(spec: &ModelSpec, beam_centres_deg: &[f64]) -> Result<Checked, SpecError> {
    let beams = spec.sonar.beams as usize;
    ensure(beam_centres_deg.len() == beams, SpecError::BeamTable)?;
    let r = spec.input.range_bins as usize;
    let b = spec.input.beam_columns as usize;
    ensure(b != 0 && beams.is_multiple_of(b), SpecError::BeamColumns)?;
    let stride = spec.features.stride as usize;
    ensure(
        stride != 0 && r.is_multiple_of(stride) && b.is_multiple_of(stride),
        SpecError::Stride,
    )?;
    ensure(
        spec.output.azimuth_columns as usize == b,
        SpecError::AzimuthColumns,
    )?;
    let max_views = spec.baseline.max_views;
    ensure((2..=3).contains(&max_views), SpecError::MaxViews)?;
    ensure(
        (2..=max_views).contains(&spec.baseline.views),
        SpecError::Views,
    )?;
    ensure(spec.output.range_bins >= 2, SpecError::DepthBins)?;
    let grids = ModelGrids::derive(spec, beam_centres_deg).map_err(SpecError::Grids)?;
    let mut sizes = Sizes {
        beams,
        beams_per_column: beams / b,
        input_range_bins: r,
        input_columns: b,
        feature_channels: spec.features.channels as usize,
        feature_stride: stride,
        feature_range_bins: r / stride,
        feature_columns: b / stride,
        planes: spec.planes as usize,
        depth_rows: spec.output.elevation_rows as usize,
        depth_columns: b,
        depth_range_bins: spec.output.range_bins as usize,
        max_views: max_views as usize,
        layers: Vec::new(),
        max_feature_activation: r * b,
        max_cost_activation: 0,
    };
    check_layers(spec, &mut sizes)?;
    let warp_tables = (1..sizes.max_views)
        .map(|k| grids.warp_table(spec, k).map_err(SpecError::WarpTable))
        .collect::<Result<Vec<_>, _>>()?;
    check_output(spec)?;
    Ok(Checked {
        sizes,
        grids,
        warp_tables,
    })
}

fn ensure(rule_kept: bool, broken: SpecError) -> Result<(), SpecError> {
    if rule_kept {
        Ok(())
    } else {
        Err(broken)
    }
}

/// The two networks' layers: names, kinds, sizes chained from the input and the cost volume.
fn check_layers(spec: &ModelSpec, sizes: &mut Sizes) -> Result<(), SpecError> {
    let (fr, fb, c) = (
        sizes.feature_range_bins,
        sizes.feature_columns,
        sizes.feature_channels,
    );
    check_layer_names(spec)?;
    let mut size = std::vec![sizes.input_range_bins, sizes.input_columns];
    for l in spec.feature_net.iter() {
        ensure(
            l.kind == LayerKind::Conv2d,
            SpecError::FeatureLayerKind(l.name.to_string()),
        )?;
        let elements = push_layer(sizes, l, &mut size)?;
        sizes.max_feature_activation = sizes.max_feature_activation.max(elements);
    }
    ensure(size == [fr, fb], SpecError::FeatureSize)?;
    ensure(
        spec.feature_net.last().map(|l| l.out_channels as usize) == Some(c),
        SpecError::FeatureChannels,
    )?;
    ensure(
        spec.features.mean_channels as usize <= c,
        SpecError::MeanChannels,
    )?;
    let mut size = std::vec![sizes.planes, fr, fb];
    sizes.max_cost_activation = c * sizes.planes * fr * fb;
    for l in spec.cost_net.iter() {
        ensure(
            l.kind != LayerKind::Conv2d,
            SpecError::CostLayerKind(l.name.to_string()),
        )?;
        let elements = push_layer(sizes, l, &mut size)?;
        sizes.max_cost_activation = sizes.max_cost_activation.max(elements);
    }
    ensure(
        size == [
            sizes.depth_rows,
            sizes.depth_range_bins,
            sizes.depth_columns,
        ],
        SpecError::CostSize,
    )?;
    ensure(
        spec.cost_net.last().map(|l| l.out_channels) == Some(1),
        SpecError::HeadChannels,
    )
}

/// Records layer `l` reading `size` (which becomes its output size); its output's elements.
fn push_layer(sizes: &mut Sizes, l: &LayerSpec, size: &mut Vec<usize>) -> Result<usize, SpecError> {
    let output = l.output_size(size).to_vec();
    let elements = output
        .iter()
        .try_fold(l.out_channels as usize, |n, &s| n.checked_mul(s))
        .ok_or_else(|| SpecError::ActivationSize(l.name.to_string()))?;
    sizes.layers.push(LayerSizes {
        layer: l.clone(),
        input: core::mem::replace(size, output.clone()),
        output,
    });
    Ok(elements)
}

/// Layer names become constants (`LAYER_<NAME>`): identifiers, unique once upper-cased.
fn check_layer_names(spec: &ModelSpec) -> Result<(), SpecError> {
    let mut seen: Vec<String> = Vec::new();
    for l in spec.feature_net.iter().chain(spec.cost_net.iter()) {
        let name = l.name.as_str();
        let identifier = name.chars().next().is_some_and(|c| !c.is_ascii_digit())
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        let upper = name.to_uppercase();
        if !identifier || seen.contains(&upper) {
            return Err(SpecError::LayerName(name.to_string()));
        }
        seen.push(upper);
    }
    Ok(())
}

/// The soft-argmax's range constants and the no-return decision.
fn check_output(spec: &ModelSpec) -> Result<(), SpecError> {
    let w = &spec.range_window;
    let offset = spec.output.end_bin_offset as f64;
    ensure(
        w.r_min_m - offset * depth_step_m(spec) >= 0.0,
        SpecError::EndBinOffset,
    )?;
    let tau = spec.output.no_return_mass;
    ensure(
        tau == 0.0 || (tau > 0.0 && tau <= 1.0),
        SpecError::NoReturnMass,
    )
}

/// The step between soft-argmax bins, metres: `(r_max − r_min) / (bins − 1)`.
pub fn depth_step_m(spec: &ModelSpec) -> f64 {
    let w = &spec.range_window;
    (w.r_max_m - w.r_min_m) / (spec.output.range_bins as f64 - 1.0)
}

/// The shipped spec `file` (in `weights/`) with its beam table's centres.
#[cfg(test)]
pub(crate) fn shipped(file: &str) -> (ModelSpec, Vec<f64>, u32) {
    let root = crate::load::repo_root();
    let loaded = crate::load::load_spec(&root.join("weights").join(file)).unwrap();
    let table = loaded.spec.sonar.beam_table.clone();
    let beams = crate::load::load_beam_table(&root, &table).unwrap();
    (loaded.spec, beams.centre_deg, loaded.hash)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::format;

    #[test]
    fn the_shipped_specs_keep_every_rule() {
        for file in crate::load::BUILD_SPECS {
            let (spec, beams, _) = shipped(file);
            let c = check(&spec, &beams).unwrap_or_else(|e| panic!("{file}: {e}"));
            let z = &c.sizes;
            assert_eq!(z.layers.len(), spec.feature_net.len() + spec.cost_net.len());
            assert_eq!(z.layers[0].input, [z.input_range_bins, z.input_columns]);
            let head = z.layers.last().unwrap();
            assert_eq!(
                head.output,
                [z.depth_rows, z.depth_range_bins, z.depth_columns]
            );
            // The sizes chain: each layer reads what the one before wrote, the cost net the
            // cost volume.
            let first_cost = spec.feature_net.len();
            assert_eq!(
                z.layers[first_cost].input,
                [z.planes, z.feature_range_bins, z.feature_columns]
            );
            for w in z
                .layers
                .windows(2)
                .filter(|w| w[1].input.len() == w[0].output.len())
            {
                assert_eq!(w[1].input, w[0].output, "{file}: {}", w[1].layer.name);
            }
            assert!(z.max_feature_activation >= z.input_range_bins * z.input_columns);
            let cost_volume =
                z.feature_channels * z.planes * z.feature_range_bins * z.feature_columns;
            assert!(z.max_cost_activation >= cost_volume);
            assert_eq!(c.warp_tables.len(), z.max_views - 1);
            for t in &c.warp_tables {
                assert_eq!(t.len(), z.planes * z.feature_columns);
            }
        }
    }

    type Edit = fn(&mut ModelSpec);
    type Broken = (SpecError, &'static str, Edit);

    fn set_name(l: &mut LayerSpec, s: &str) {
        l.name.clear();
        l.name.push_str(s).unwrap();
    }

    /// Specs that break a rule of the sizes, views, grids or output: the shipped EPSSN-S, one edit
    /// each.
    fn broken_sizes() -> Vec<Broken> {
        use SpecError as E;
        std::vec![
            (E::BeamColumns, "multiple of beam_columns", |s| s
                .input
                .beam_columns =
                0),
            (E::BeamColumns, "multiple of beam_columns", |s| s
                .input
                .beam_columns =
                48),
            (E::Stride, "multiple of the stride", |s| s.features.stride =
                0),
            (E::Stride, "multiple of the stride", |s| s.features.stride =
                3),
            (
                E::AzimuthColumns,
                "azimuth_columns must equal beam_columns",
                |s| { s.output.azimuth_columns = 32 }
            ),
            (E::MaxViews, "max_views is 2 or 3", |s| s
                .baseline
                .max_views = 4),
            (E::MaxViews, "max_views is 2 or 3", |s| s
                .baseline
                .max_views = 1),
            (E::Views, "views within 2..=max_views", |s| s
                .baseline
                .views = 1),
            (E::Views, "views within 2..=max_views", |s| {
                s.baseline.max_views = 2;
                s.baseline.views = 3;
            }),
            (E::DepthBins, "range_bins must be at least 2", |s| s
                .output
                .range_bins =
                1),
            (
                E::Grids(GridError::TooLarge),
                "grids cannot be derived (TooLarge)",
                |s| { s.planes = 600 }
            ),
            (
                E::EndBinOffset,
                "end_bin_offset reaches below zero range",
                |s| { s.output.end_bin_offset = 1000 }
            ),
            (
                E::NoReturnMass,
                "no_return_mass must be 0 (no decision) or in (0, 1]",
                |s| { s.output.no_return_mass = 1.5 }
            ),
            (E::NoReturnMass, "no_return_mass", |s| s
                .output
                .no_return_mass =
                -0.25),
            (E::NoReturnMass, "no_return_mass", |s| s
                .output
                .no_return_mass =
                f64::NAN),
            (
                E::WarpTable(GridError::NotRangePreserving),
                "warp table (NotRangePreserving; a lever arm",
                |s| { s.baseline.lever_arm_m = [0.0, 0.05, 0.0] }
            ),
        ]
    }

    /// Specs that break a rule of the layers: the shipped EPSSN-S, one edit each.
    fn broken_layers() -> Vec<Broken> {
        use SpecError as E;
        std::vec![
            (
                E::LayerName("f0".into()),
                "layer name \"f0\" must be a unique identifier",
                |s| { set_name(&mut s.cost_net[0], "f0") }
            ),
            (
                E::LayerName("F1".into()),
                "layer name \"F1\"",
                |s| set_name(&mut s.feature_net[2], "F1")
            ),
            (
                E::LayerName("2x".into()),
                "layer name \"2x\"",
                |s| set_name(&mut s.feature_net[0], "2x")
            ),
            (E::LayerName("u-1".into()), "layer name \"u-1\"", |s| {
                set_name(&mut s.cost_net[3], "u-1")
            }),
            (E::LayerName("".into()), "layer name \"\"", |s| set_name(
                &mut s.cost_net[5],
                ""
            )),
            (
                E::FeatureLayerKind("f1".into()),
                "feature_net layers are conv2d (`f1` is not)",
                |s| { s.feature_net[1].kind = LayerKind::Conv3d }
            ),
            (
                E::FeatureSize,
                "feature_net output size must be input / stride",
                |s| {
                    s.feature_net[0].stride.clear();
                    s.feature_net[0].stride.extend([1, 1]);
                }
            ),
            (
                E::FeatureChannels,
                "output channels must be features.channels",
                |s| { s.feature_net[3].out_channels = 16 }
            ),
            (E::MeanChannels, "mean_channels must not exceed", |s| {
                s.features.mean_channels = s.features.channels + 1
            }),
            (
                E::CostLayerKind("m0".into()),
                "cost_net layers are 3D (`m0` is conv2d)",
                |s| { s.cost_net[2].kind = LayerKind::Conv2d }
            ),
            (
                E::CostSize,
                "cost_net output must be (elevation_rows, range_bins, azimuth_columns)",
                |s| { s.output.elevation_rows = 16 }
            ),
            (E::HeadChannels, "the head has one output channel", |s| s
                .cost_net[5]
                .out_channels =
                2),
            (
                E::ActivationSize("up1".into()),
                "layer `up1`'s activation size overflows",
                |s| {
                    // Transposed convolutions of stride 255 on three axes after the head: the
                    // second one's output has more elements than a usize counts.
                    for n in ["up0", "up1"] {
                        let mut l = s.cost_net[3].clone();
                        set_name(&mut l, n);
                        l.skip = None;
                        l.stride.clear();
                        l.stride.extend([255, 255, 255]);
                        s.cost_net.push(l).unwrap();
                    }
                }
            ),
        ]
    }

    #[test]
    fn every_shipped_weights_folder_holds_a_shipped_specs_bytes() {
        // A folder's spec.json names the spec its blob is stamped for: a stale copy makes
        // `host-sim eval --weights` refuse the folder.
        let weights = crate::load::repo_root().join("weights");
        let specs: std::vec::Vec<_> = crate::load::BUILD_SPECS
            .iter()
            .map(|f| std::fs::read(weights.join(f)).unwrap())
            .collect();
        let mut folders = 0;
        for entry in std::fs::read_dir(&weights).unwrap() {
            let spec = entry.unwrap().path().join("spec.json");
            if let Ok(bytes) = std::fs::read(&spec) {
                assert!(
                    specs.contains(&bytes),
                    "{} is not a shipped spec",
                    spec.display()
                );
                folders += 1;
            }
        }
        assert!(folders >= 5, "{folders} weights folders");
    }

    #[test]
    fn a_spec_that_breaks_a_rule_is_refused_with_its_message() {
        let (good, beams, _) = shipped("epssn-s.json");
        let mut rules = broken_sizes();
        rules.extend(broken_layers());
        for (want, message, edit) in rules {
            let mut spec = good.clone();
            edit(&mut spec);
            let err = check(&spec, &beams).expect_err(&format!("{want:?} accepted"));
            assert_eq!(err, want);
            let text = format!("{err}");
            assert!(text.starts_with("model spec: "), "{text}");
            assert!(text.contains(message), "{want:?}: {text}");
        }
        let err = check(&good, &beams[1..]).unwrap_err();
        assert_eq!(err, SpecError::BeamTable);
        assert_eq!(
            format!("{err}"),
            "model spec: beam count differs from the beam table"
        );
    }

    #[test]
    fn the_boundaries_of_the_rules_are_accepted() {
        let (good, beams, _) = shipped("epssn-s.json");
        let mut spec = good.clone();
        spec.output.no_return_mass = 1.0;
        spec.features.mean_channels = spec.features.channels;
        spec.baseline.max_views = 2;
        spec.baseline.views = 2;
        let c = check(&spec, &beams).unwrap();
        assert_eq!(c.warp_tables.len(), 1);
        let mut spec = good;
        spec.output.no_return_mass = 0.0;
        // The largest offset that keeps bin 0 at or above zero range.
        let most = (spec.range_window.r_min_m / depth_step_m(&spec)).floor() as u16;
        spec.output.end_bin_offset = most;
        assert!(check(&spec, &beams).is_ok());
        spec.output.end_bin_offset = most + 1;
        assert_eq!(check(&spec, &beams).unwrap_err(), SpecError::EndBinOffset);
    }
}
