//! Streamed execution (what the firmware runs): no tensor bigger than the UNet's own is ever
//! whole. The feature net runs row chunk by row chunk through line buffers; d1 reads a small
//! window of cost-volume planes and rows computed on the fly; u0 is computed one output plane at
//! a time (its skip, a cost-volume plane, recomputed into the output plane) and fed straight to
//! the fused head. Every kernel call sees a sub-volume with explicit zero rows/planes where the
//! whole tensor has padding, which adds exactly 0 to every accumulator: the bits are those of
//! the whole-tensor path.

use super::*;

/// Scratch memory of one streamed inference ([`WORKSPACE_LEN`] bytes): put it in a `static`
/// (firmware) or a `Box` (host). Only scratch: nothing in it survives from one call to the
/// next.
pub struct Workspace {
    buf: [i8; WORKSPACE_LEN],
    /// The line engine's weights, line and accumulators, reused by every kernel call.
    scratch: LineScratch,
}

impl Default for Workspace {
    fn default() -> Self {
        Self::new()
    }
}

impl Workspace {
    /// A zeroed workspace.
    pub const fn new() -> Self {
        Self {
            buf: [0; WORKSPACE_LEN],
            scratch: LineScratch::new(),
        }
    }

    /// Bytes of RAM the workspace occupies.
    pub const BYTES: usize = core::mem::size_of::<Self>();
}

/// What a feature layer's line buffers hold: input rows `lo..lo + filled` (virtual rows:
/// negative or past the end are padding) and which output chunk.
#[derive(Clone, Copy)]
pub(super) struct StreamState {
    lo: isize,
    filled: usize,
    chunk: Option<usize>,
}

/// `(&buf[a], &mut buf[b])` for disjoint ranges; empty slices (which the kernels refuse with
/// a length error) if they overlap or leave `buf`, which the compile-time plan rules out.
pub(super) fn disjoint(buf: &mut [i8], a: Range<usize>, b: Range<usize>) -> (&[i8], &mut [i8]) {
    if a.end <= b.start && b.end <= buf.len() {
        let (x, y) = buf.split_at_mut(b.start);
        match (x.get(a), y.get_mut(..b.end - b.start)) {
            (Some(x), Some(y)) => (x, y),
            _ => (&[], &mut []),
        }
    } else if b.end <= a.start && a.end <= buf.len() {
        let (x, y) = buf.split_at_mut(a.start);
        match (y.get(..a.end - a.start), x.get_mut(b)) {
            (Some(y), Some(x)) => (y, x),
            _ => (&[], &mut []),
        }
    } else {
        (&[], &mut [])
    }
}

/// `name` of a fused stage, e.g. "f0+f1+f2+f3" (cut at 32 bytes).
pub(super) fn stage_name(prefix: &str, layers: Range<usize>) -> heapless::String<32> {
    let mut s = heapless::String::new();
    let _ = s.push_str(prefix);
    for (n, l) in LAYERS[layers].iter().enumerate() {
        if n > 0 || !prefix.is_empty() {
            let _ = s.push('+');
        }
        let _ = s.push_str(l.name);
    }
    s
}

impl<'a> Model<'a> {
    /// Features of one view (`[C][H][W]`, `config::FEATURE_LEN` elements) from its u8 polar
    /// image (`config::INPUT_LEN`), streamed: each layer computes [`FEATURE_CHUNKS`] chunks of
    /// output rows from a line buffer of input rows that the layer before fills on demand, so
    /// no intermediate activation is ever whole. `probe` sees the features once, under the
    /// name of the fused stage ("f0+f1+f2+f3").
    pub fn features_probed(
        &self,
        image: &[u8],
        ws: &mut Workspace,
        features: &mut [i8],
        mut probe: impl FnMut(&str, &[i8]),
    ) -> Result<(), Error> {
        expect_len(config::INPUT_LEN, image.len())?;
        expect_len(config::FEATURE_LEN, features.len())?;
        let mut state = [StreamState {
            lo: 0,
            filled: 0,
            chunk: None,
        }; FEATURE_LAYERS];
        let last = FEATURE_LAYERS - 1;
        let l = &LAYERS[last];
        let s = FEATURE_STREAMS.0[last];
        let plane = l.out_size[0] * l.out_size[1];
        let n = s.rows * l.out_size[1];
        // Each layer runs once per chunk: its weights are laid out once per view (the four
        // layers' fit the line engine's buffer side by side).
        ws.scratch.keep_weights();
        let mut chunks = Ok(());
        for j in 0..FEATURE_CHUNKS {
            chunks = self.feature_chunk(last, j, image, &mut ws.buf, &mut ws.scratch, &mut state);
            if chunks.is_err() {
                break;
            }
            for (c, dst) in features.chunks_exact_mut(plane).enumerate() {
                let src = s.chunk_start + c * n;
                dst[j * n..(j + 1) * n].copy_from_slice(&ws.buf[src..src + n]);
            }
        }
        ws.scratch.forget_weights();
        chunks?;
        probe(&stage_name("", 0..FEATURE_LAYERS), features);
        Ok(())
    }

    /// Features of one view; see [`Model::features_probed`].
    pub fn features(
        &self,
        image: &[u8],
        ws: &mut Workspace,
        features: &mut [i8],
    ) -> Result<(), Error> {
        self.features_probed(image, ws, features, |_, _| {})
    }

    /// Computes output chunk `j` of feature layer `l` into its chunk buffer, first filling the
    /// layer's input window with the rows it needs (from the image, padding, or the previous
    /// layer's chunks, computed on demand).
    fn feature_chunk(
        &self,
        l: usize,
        j: usize,
        image: &[u8],
        buf: &mut [i8],
        scratch: &mut LineScratch,
        state: &mut [StreamState; FEATURE_LAYERS],
    ) -> Result<(), Error> {
        let layer = &LAYERS[l];
        let s = FEATURE_STREAMS.0[l];
        let (c_in, h_in, w_in) = (layer.in_channels, layer.in_size[0], layer.in_size[1]);
        let r = s.window_rows;
        let need_lo = (layer.stride[0] as usize * j * s.rows) as isize - layer.padding[0] as isize;
        // Slide the window: keep the rows this chunk shares with the previous one.
        let st = state[l];
        let drop = need_lo - st.lo;
        let mut filled = if drop < 0 || drop as usize >= st.filled {
            0
        } else {
            let d = drop as usize;
            for c in 0..c_in {
                let base = s.window_start + c * r * w_in;
                buf.copy_within(base + d * w_in..base + st.filled * w_in, base);
            }
            st.filled - d
        };
        let params = layer_params(layer, &self.layers[l]);
        let checked = self.checked(l);
        // Padding is the value that the input offset turns into 0.
        let pad = (-params.input_offset) as i8;
        while filled < r {
            let row = need_lo + filled as isize;
            if row < 0 || row as usize >= h_in {
                for c in 0..c_in {
                    let at = s.window_start + (c * r + filled) * w_in;
                    buf[at..at + w_in].fill(pad);
                }
                filled += 1;
                continue;
            }
            let row = row as usize;
            let n = if l == 0 {
                let n = (r - filled).min(h_in - row);
                for c in 0..c_in {
                    let at = s.window_start + (c * r + filled) * w_in;
                    let from = (c * h_in + row) * w_in;
                    for (q, &u) in buf[at..at + n * w_in]
                        .iter_mut()
                        .zip(&image[from..from + n * w_in])
                    {
                        *q = (u ^ 0x80) as i8; // u − INPUT_OFFSET
                    }
                }
                n
            } else {
                let p = FEATURE_STREAMS.0[l - 1];
                let jj = row / p.rows;
                if state[l - 1].chunk != Some(jj) {
                    self.feature_chunk(l - 1, jj, image, buf, scratch, state)?;
                }
                let n = (r - filled).min((jj + 1) * p.rows - row);
                for c in 0..c_in {
                    let from = p.chunk_start + (c * p.rows + row - jj * p.rows) * w_in;
                    let at = s.window_start + (c * r + filled) * w_in;
                    buf.copy_within(from..from + n * w_in, at);
                }
                n
            };
            filled += n;
        }
        state[l] = StreamState {
            lo: need_lo,
            filled,
            chunk: Some(j),
        };
        let mut shape = ConvShape::from(layer);
        shape.in_size[0] = r;
        shape.out_size[0] = s.rows;
        shape.padding[0] = 0;
        let window = s.window_start..s.window_start + c_in * r * w_in;
        let chunk = s.chunk_start..s.chunk_start + layer.out_channels * s.rows * layer.out_size[1];
        let (src, dst) = disjoint(buf, window, chunk);
        conv2d_s8_checked(&shape, src, &checked, dst, scratch)?;
        Ok(())
    }

    /// The front depth map (`[E][A]`, metres) from the reference view's features and one or
    /// two source views' features (view k rolled by k × the baseline), streamed: the cost
    /// volume is never whole. d1 is computed tile by tile from windows of cost-volume planes
    /// and rows computed on the fly; d2, m0 and u1 run whole (they are small); u0 is computed
    /// one output plane at a time, its skip (a cost-volume plane) recomputed into that plane,
    /// and each plane goes straight through the fused head into its depth rows. `probe` sees
    /// d1 (as "cost+d1"), d2, m0 and u1; the last stage (cost+u0+head) is not probed.
    pub fn depth_from_features_probed(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut Workspace,
        depth: &mut [U16F16],
        mut probe: impl FnMut(&str, &[i8]),
    ) -> Result<(), Error> {
        if sources.is_empty() || sources.len() > config::MAX_VIEWS - 1 {
            return Err(Error::SourceCount(sources.len()));
        }
        expect_len(config::FEATURE_LEN, reference.len())?;
        expect_len(config::DEPTH_LEN, depth.len())?;
        for s in sources {
            expect_len(config::FEATURE_LEN, s.len())?;
        }
        let mut views = [SourceView {
            features: &[],
            warp: &[],
        }; config::MAX_VIEWS - 1];
        for (k, (v, s)) in views.iter_mut().zip(sources).enumerate() {
            *v = SourceView {
                features: s,
                warp: &config::WARP_TABLES[k],
            };
        }
        // Validated once; d1 and u0 each compute the whole volume from it piece by piece.
        let cost = CostVolume::new(
            &CostShape::EPSSN,
            reference,
            &views[..sources.len()],
            self.cost[sources.len() - 1],
        )?;
        let Workspace { buf, scratch } = ws;
        // d1 runs once per plane and row chunk: its weights laid out once.
        scratch.keep_weights();
        let d1 = self.stream_d1(&cost, buf, scratch);
        scratch.forget_weights();
        d1?;
        let (s, l) = unet_range(PLAN.0[D1]);
        probe(&stage_name("cost", D1..D1 + 1), &buf[s..s + l]);
        // The small middle of the UNet, whole tensors in the UNet buffer as planned.
        let mut input = PLAN.0[D1];
        for (i, l) in LAYERS.iter().enumerate().take(U0).skip(D1 + 1) {
            let p = &self.layers[i];
            let checked = self.checked(i);
            let shape = ConvShape::from(l);
            let out = PLAN.0[i];
            let (a, b) = (unet_range(input), unet_range(out));
            let (src, dst) = if input == out {
                (&[][..], &mut [][..])
            } else {
                disjoint(buf, a.0..a.0 + a.1, b.0..b.0 + b.1)
            };
            match l.kind {
                LayerKind::Conv3d => conv3d_s8_checked(&shape, src, &checked, dst, scratch)?,
                LayerKind::ConvTranspose3d => {
                    let skip = if l.skip.is_some() {
                        skip_in_place(p)
                    } else {
                        Skip::None
                    };
                    conv_transpose3d_s8_checked(&shape, src, &checked, skip, dst, scratch)?
                }
                LayerKind::Conv2d => return Err(Error::Kernel(KernelError::NotTwoDimensional)),
            }
            probe(l.name, dst);
            input = out;
        }
        self.stream_u0_head(&cost, buf, scratch, depth)
    }

    /// The front depth map from features; see [`Model::depth_from_features_probed`].
    pub fn depth_from_features(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut Workspace,
        depth: &mut [U16F16],
    ) -> Result<(), Error> {
        self.depth_from_features_probed(reference, sources, ws, depth, |_, _| {})
    }

    /// The front depth map of a view set, streamed: the one place that turns u8 polar images
    /// (`views[0]` the reference, `views[1..]` the sources, view k rolled by k × the baseline)
    /// into depth. `features` receives each view's features (`views.len() ×
    /// config::FEATURE_LEN`, view by view) so callers can check or cache them. A single view
    /// is its own source (the single-view baseline).
    pub fn depth(
        &self,
        views: &[&[u8]],
        features: &mut [i8],
        ws: &mut Workspace,
        depth: &mut [U16F16],
    ) -> Result<(), Error> {
        if views.is_empty() || views.len() > config::MAX_VIEWS {
            return Err(Error::SourceCount(views.len().saturating_sub(1)));
        }
        expect_len(views.len() * config::FEATURE_LEN, features.len())?;
        for (view, f) in views
            .iter()
            .zip(features.chunks_exact_mut(config::FEATURE_LEN))
        {
            self.features(view, ws, f)?;
        }
        let mut chunks = features.chunks_exact(config::FEATURE_LEN);
        let reference = chunks.next().unwrap_or(&[]);
        let mut sources: [&[i8]; config::MAX_VIEWS - 1] = [&[]; config::MAX_VIEWS - 1];
        let mut n = 0;
        for (s, f) in sources.iter_mut().zip(chunks) {
            *s = f;
            n += 1;
        }
        if n == 0 {
            sources[0] = reference;
            n = 1;
        }
        self.depth_from_features(reference, &sources[..n], ws, depth)
    }

    /// d1 into its UNet region, [`COST_ROW_CHUNKS`] row tiles at a time: per tile, the window
    /// of `kd` cost-volume planes slides along the planes (the planes two output planes share
    /// are kept), and new planes are computed channel by channel for just the tile's rows.
    fn stream_d1(
        &self,
        cost: &CostVolume<'_>,
        buf: &mut [i8],
        scratch: &mut LineScratch,
    ) -> Result<(), Error> {
        let l = &LAYERS[D1];
        let (kd, sd, pd) = (
            l.kernel[0] as usize,
            l.stride[0] as usize,
            l.padding[0] as isize,
        );
        let (sh, ph) = (l.stride[1] as usize, l.padding[1] as isize);
        let [planes, height, width] = l.in_size;
        let [out_planes, out_rows, out_width] = l.out_size;
        let rows = D1_WINDOW_ROWS;
        let slot = rows * width;
        let window = LIVE_END..LIVE_END + D1_WINDOW_LEN;
        let tile = window.end..window.end + D1_TILE_LEN;
        let (d1_start, _) = unet_range(PLAN.0[D1]);
        let checked = self.checked(D1);
        let mut shape = ConvShape::from(l);
        shape.in_size = [kd, rows, width];
        shape.out_size = [1, D1_ROWS, out_width];
        shape.padding[0] = 0;
        shape.padding[1] = 0;
        // Padding is the stored cost that d1's input offset turns into 0 (the zero point).
        let pad = (-self.layers[D1].input_offset) as i8;
        for y in 0..COST_ROW_CHUNKS {
            let row_lo = (sh * y * D1_ROWS) as isize - ph;
            // Cost-volume rows of this tile that exist (the rest is padding).
            let r0 = row_lo.max(0) as usize;
            let r1 = ((row_lo + rows as isize).max(0) as usize).min(height);
            let (mut lo, mut held) = (0isize, 0usize);
            for d in 0..out_planes {
                let need = (sd * d) as isize - pd;
                let drop = need - lo;
                held = if drop < 0 || drop as usize >= held {
                    0
                } else {
                    let k = drop as usize;
                    for c in 0..l.in_channels {
                        let base = window.start + c * kd * slot;
                        buf.copy_within(base + k * slot..base + held * slot, base);
                    }
                    held - k
                };
                lo = need;
                while held < kd {
                    let j = lo + held as isize;
                    for c in 0..l.in_channels {
                        let at = window.start + (c * kd + held) * slot;
                        let out = &mut buf[at..at + slot];
                        if j < 0 || j as usize >= planes || r1 <= r0 {
                            out.fill(pad);
                            continue;
                        }
                        let top = r0 as isize - row_lo;
                        let (pad_top, rest) = out.split_at_mut(top as usize * width);
                        pad_top.fill(pad);
                        let (real, pad_bottom) = rest.split_at_mut((r1 - r0) * width);
                        pad_bottom.fill(pad);
                        cost.rows(c, j as usize, r0..r1, real)?;
                    }
                    held += 1;
                }
                let (src, dst) = disjoint(buf, window.clone(), tile.clone());
                conv3d_s8_checked(&shape, src, &checked, dst, scratch)?;
                let n = D1_ROWS * out_width;
                for o in 0..l.out_channels {
                    let at = d1_start + ((o * out_planes + d) * out_rows + y * D1_ROWS) * out_width;
                    buf.copy_within(tile.start + o * n..tile.start + (o + 1) * n, at);
                }
            }
        }
        Ok(())
    }

    /// u0 one output plane at a time: the plane's buffer first receives the cost-volume plane
    /// (u0's skip), then u0's transposed convolution of just the input planes that reach this
    /// output plane adds onto it in place, then the head turns it into depth rows: the fused
    /// head its `kernel[0]` rows at once, the general head (an overlapping kernel) the
    /// `stride[0]` rows whose last input plane this is, from the ring of the last
    /// `P = ceil(kernel / stride)` planes that u0 writes into (plane `t` in slot `t mod P`).
    fn stream_u0_head(
        &self,
        cost: &CostVolume<'_>,
        buf: &mut [i8],
        scratch: &mut LineScratch,
        depth: &mut [U16F16],
    ) -> Result<(), Error> {
        let out = LIVE_END + U0_GATHER_LEN..LIVE_END + U0_GATHER_LEN + U0_OUT_LEN;
        let head = &LAYERS[HEAD];
        let soft = self.soft();
        // The general head's weights laid out once per depth map, not once per step.
        let mut head_weights = HeadWeights::new();
        let head_checked = self.checked(HEAD);
        let plan = if HEAD_FUSED {
            None
        } else {
            let shape = ConvShape::from(head);
            Some(HeadPlan::new(
                &shape,
                &head_checked,
                &soft,
                &mut head_weights,
            )?)
        };
        // One step per u0 *output* plane (the head's input planes); u0's weights are laid
        // out for its two plane phases once, not once per plane (the model's are immutable).
        scratch.keep_weights();
        let planes = self.u0_planes(cost, buf, scratch, depth, &plan, out.clone());
        scratch.forget_weights();
        planes?;
        if let Some(plan) = &plan {
            // Rows whose last input plane lies past u0's last (the kernel reads no plane
            // outside the map, so the ring's stale slots are not read).
            for t in LAYERS[U0].out_size[0]..head_steps(&ConvShape::from(head)) {
                plan.step(&buf[out.clone()], t, depth)?;
            }
        }
        Ok(())
    }

    /// The u0 planes of [`Self::stream_u0_head`], each followed by its head step.
    fn u0_planes(
        &self,
        cost: &CostVolume<'_>,
        buf: &mut [i8],
        scratch: &mut LineScratch,
        depth: &mut [U16F16],
        plan: &Option<HeadPlan<'_>>,
        out: Range<usize>,
    ) -> Result<(), Error> {
        let l = &LAYERS[U0];
        let [in_planes, in_rows, in_width] = l.in_size;
        let in_plane = in_rows * in_width;
        let (u1_start, _) = unet_range(PLAN.0[U0 - 1]);
        let checked = self.checked(U0);
        let skip = skip_in_place(&self.layers[U0]);
        let head = &LAYERS[HEAD];
        let head_params = layer_params(head, &self.layers[HEAD]);
        let mut head_shape = ConvShape::from(head);
        head_shape.in_size[0] = 1;
        head_shape.out_size[0] = head.kernel[0] as usize;
        let depth_rows = head_shape.out_size[0] * head.out_size[2];
        let soft = self.soft();
        let cost_plane = config::FEATURE_RANGE_BINS * config::FEATURE_COLUMNS;
        for t in 0..l.out_size[0] {
            let slot = if HEAD_FUSED { 0 } else { t % HEAD_IN_PLANES };
            let plane = out.start + slot * U0_PLANE_LEN..out.start + (slot + 1) * U0_PLANE_LEN;
            for (c, o) in buf[plane.clone()].chunks_exact_mut(cost_plane).enumerate() {
                cost.rows(c, t, 0..config::FEATURE_RANGE_BINS, o)?;
            }
            let (first, planes, pad, out_pad) = u0_plane(t);
            let gather = LIVE_END..LIVE_END + l.in_channels * planes * in_plane;
            for c in 0..l.in_channels {
                for q in 0..planes {
                    let at = gather.start + (c * planes + q) * in_plane;
                    if first + q < in_planes {
                        let from = u1_start + (c * in_planes + first + q) * in_plane;
                        buf.copy_within(from..from + in_plane, at);
                    } else {
                        buf[at..at + in_plane].fill(0);
                    }
                }
            }
            let mut shape = ConvShape::from(l);
            shape.in_size[0] = planes;
            shape.out_size[0] = 1;
            shape.padding[0] = pad;
            shape.output_padding[0] = out_pad;
            let (src, dst) = disjoint(buf, gather, plane.clone());
            conv_transpose3d_s8_checked(&shape, src, &checked, skip, dst, scratch)?;
            if HEAD_FUSED {
                let rows = t * depth_rows..(t + 1) * depth_rows;
                let actual = depth.len();
                let depth_t = depth.get_mut(rows).ok_or(Error::InputLength {
                    expected: config::DEPTH_LEN,
                    actual,
                })?;
                head_soft_argmax_s8(
                    &head_shape,
                    &buf[plane.clone()],
                    &head_params,
                    &soft,
                    depth_t,
                )?;
            } else if let Some(plan) = &plan {
                // The `stride[0]` depth rows whose last input plane is `t`, from the ring
                // of the last `P` u0 planes, fused with the soft-argmax.
                plan.step(&buf[out.clone()], t, depth)?;
            }
        }
        Ok(())
    }
}
