//! The whole-tensor path: every layer's full output materialised, the plain twin the streamed
//! path is tested against.

use super::*;

/// Scratch of the whole-tensor reference path ([`Model::features_whole_probed`],
/// [`Model::depth_from_features_whole_probed`]): the full cost volume plus the UNet buffer.
/// It is the plain twin the streamed [`Workspace`] is tested against; put it in a `Box`.
pub struct WholeWorkspace {
    cost: [i8; COST_BUFFER_LEN],
    unet: [i8; UNET_BUFFER_LEN],
    logits: [i8; WHOLE_LOGITS_LEN],
}

/// The whole `[E][R][A]` logits volume, which the whole-tensor path needs only when the head
/// is not fused with the soft-argmax.
pub(super) const WHOLE_LOGITS_LEN: usize = if HEAD_FUSED {
    0
} else {
    config::DEPTH_LEN * config::DEPTH_RANGE_BINS
};

impl Default for WholeWorkspace {
    fn default() -> Self {
        Self::new()
    }
}

impl WholeWorkspace {
    /// A zeroed workspace.
    pub const fn new() -> Self {
        Self {
            cost: [0; COST_BUFFER_LEN],
            unet: [0; UNET_BUFFER_LEN],
            logits: [0; WHOLE_LOGITS_LEN],
        }
    }

    /// Bytes of RAM the workspace occupies.
    pub const BYTES: usize = COST_BUFFER_LEN + UNET_BUFFER_LEN + WHOLE_LOGITS_LEN;
}

impl<'a> Model<'a> {
    /// Features of one view through the whole-tensor reference path: every layer's full
    /// output is materialised and shown to `probe`. Same bits as [`Model::features_probed`].
    pub fn features_whole_probed(
        &self,
        image: &[u8],
        ws: &mut WholeWorkspace,
        features: &mut [i8],
        mut probe: impl FnMut(&'static str, &[i8]),
    ) -> Result<(), Error> {
        expect_len(config::INPUT_LEN, image.len())?;
        expect_len(config::FEATURE_LEN, features.len())?;
        let (input, rest) = ws.cost.split_at_mut(config::INPUT_LEN);
        let (a, rest) = rest.split_at_mut(config::MAX_FEATURE_ACTIVATION);
        let b = &mut rest[..config::MAX_FEATURE_ACTIVATION];
        for (q, &u) in input.iter_mut().zip(image) {
            *q = (u ^ 0x80) as i8; // u − 128
        }
        let mut bufs = [a, b];
        for (i, l) in LAYERS.iter().enumerate().take(FEATURE_LAYERS) {
            let params = layer_params(l, &self.layers[i]);
            let shape = ConvShape::from(l);
            let last = i + 1 == FEATURE_LAYERS;
            let [a, b] = &mut bufs;
            let (src, dst): (&[i8], &mut [i8]) = match (i == 0, i % 2 == 0) {
                (true, _) => (&*input, &mut a[..l.output_len()]),
                (false, true) => (&b[..l.input_len()], &mut a[..l.output_len()]),
                (false, false) => (&a[..l.input_len()], &mut b[..l.output_len()]),
            };
            if last {
                conv2d_s8(&shape, src, &params, features)?;
                probe(l.name, features);
            } else {
                conv2d_s8(&shape, src, &params, dst)?;
                probe(l.name, dst);
            }
        }
        Ok(())
    }

    /// The front depth map through the whole-tensor reference path: the full cost volume
    /// and every cost-net layer's full output exist and are shown to `probe` ("cost", then
    /// each layer but the fused head). Same bits as [`Model::depth_from_features_probed`].
    pub fn depth_from_features_whole_probed(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut WholeWorkspace,
        depth: &mut [U16F16],
        mut probe: impl FnMut(&'static str, &[i8]),
    ) -> Result<(), Error> {
        if sources.is_empty() || sources.len() > config::MAX_VIEWS - 1 {
            return Err(Error::SourceCount(sources.len()));
        }
        expect_len(config::FEATURE_LEN, reference.len())?;
        expect_len(config::DEPTH_LEN, depth.len())?;
        let mut views = [SourceView {
            features: &[],
            warp: &[],
        }; config::MAX_VIEWS - 1];
        for (k, (v, s)) in views.iter_mut().zip(sources).enumerate() {
            expect_len(config::FEATURE_LEN, s.len())?;
            *v = SourceView {
                features: s,
                warp: &config::WARP_TABLES[k],
            };
        }
        let cost = &mut ws.cost[..config::COST_VOLUME_LEN];
        cost_volume_s8(
            &CostShape::EPSSN,
            reference,
            &views[..sources.len()],
            self.cost[sources.len() - 1],
            cost,
        )?;
        probe("cost", cost);
        let mut input = Region::Cost {
            start: 0,
            len: config::COST_VOLUME_LEN,
        };
        for (i, l) in LAYERS.iter().enumerate().skip(FEATURE_LAYERS) {
            let p = &self.layers[i];
            let params = layer_params(l, p);
            let shape = ConvShape::from(l);
            let out = PLAN.0[i];
            if out == Region::Depth {
                let soft = self.soft();
                if HEAD_FUSED {
                    head_soft_argmax_s8(&shape, region(ws, input), &params, &soft, depth)?;
                } else {
                    // The plain twin: the whole logits volume, then the soft-argmax.
                    let WholeWorkspace { cost, unet, logits } = ws;
                    let src = match input {
                        Region::Cost { start, len } => &cost[start..start + len],
                        Region::Unet { start, len } => &unet[start..start + len],
                        Region::Depth => &[][..],
                    };
                    conv_transpose3d_s8(&shape, src, &params, Skip::None, logits)?;
                    soft_argmax_s8(&head_soft_shape(config::DEPTH_ROWS), logits, &soft, depth)?;
                }
                break;
            }
            let (src, dst) = regions(ws, input, out);
            match l.kind {
                LayerKind::Conv3d => conv3d_s8(&shape, src, &params, dst)?,
                LayerKind::ConvTranspose3d => {
                    let skip = if l.skip.is_some() {
                        skip_in_place(p)
                    } else {
                        Skip::None
                    };
                    conv_transpose3d_s8(&shape, src, &params, skip, dst)?
                }
                LayerKind::Conv2d => return Err(Error::Kernel(KernelError::NotTwoDimensional)),
            }
            probe(l.name, dst);
            input = out;
        }
        Ok(())
    }
}

pub(super) fn region(ws: &WholeWorkspace, r: Region) -> &[i8] {
    match r {
        Region::Cost { start, len } => &ws.cost[start..start + len],
        Region::Unet { start, len } => &ws.unet[start..start + len],
        Region::Depth => &[],
    }
}

/// A layer's input and output slices; the plan never makes them overlap.
pub(super) fn regions(
    ws: &mut WholeWorkspace,
    input: Region,
    output: Region,
) -> (&[i8], &mut [i8]) {
    match (input, output) {
        (Region::Cost { start, len }, Region::Unet { start: o, len: ol }) => {
            (&ws.cost[start..start + len], &mut ws.unet[o..o + ol])
        }
        (Region::Unet { start, len }, Region::Cost { start: o, len: ol }) => {
            (&ws.unet[start..start + len], &mut ws.cost[o..o + ol])
        }
        (Region::Unet { start, len }, Region::Unet { start: o, len: ol }) => {
            if start < o {
                let (a, b) = ws.unet.split_at_mut(o);
                (&a[start..start + len], &mut b[..ol])
            } else {
                let (a, b) = ws.unet.split_at_mut(start);
                (&b[..len], &mut a[o..o + ol])
            }
        }
        // Cost → cost or anything → depth does not occur in a valid plan (checked at compile
        // time); give the kernel empty slices so it reports a length error.
        _ => (&[], &mut []),
    }
}
