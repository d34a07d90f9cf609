//! The memory plan: where every layer's output lives, the line buffers and tiles of the
//! streamed path, and the workspace sizes, all decided and checked at compile time.

use super::*;

/// Largest output channel count of any layer.
pub const MAX_CHANNELS: usize = {
    let mut m = 0;
    let mut i = 0;
    while i < LAYERS.len() {
        if LAYERS[i].out_channels > m {
            m = LAYERS[i].out_channels;
        }
        i += 1;
    }
    m
};

/// Layers of the feature net (the leading 2D layers).
pub const FEATURE_LAYERS: usize = {
    let mut n = 0;
    while n < LAYERS.len() && matches!(LAYERS[n].kind, LayerKind::Conv2d) {
        n += 1;
    }
    n
};

/// Where a layer's output lives in the [`Workspace`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Region {
    /// The cost-volume buffer, from `start`.
    Cost { start: usize, len: usize },
    /// The UNet buffer, from `start`.
    Unet { start: usize, len: usize },
    /// Streamed into the depth map (the fused head).
    Depth,
}

pub(super) const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// The memory plan of the cost net, computed at compile time from [`config::LAYERS`]: a layer
/// with a skip writes in place over the tensor it adds to, the last layer streams into the
/// depth map, every other layer gets its own slice of the UNet buffer.
pub(super) const PLAN: ([Region; config::LAYER_COUNT], usize) = {
    let mut regions = [Region::Depth; config::LAYER_COUNT];
    let mut used = 0;
    let mut i = FEATURE_LAYERS;
    while i < LAYERS.len() {
        let l = &LAYERS[i];
        regions[i] = if i + 1 == LAYERS.len() {
            Region::Depth
        } else if let Some(skip) = l.skip {
            if str_eq(skip, "cost") {
                Region::Cost {
                    start: 0,
                    len: config::COST_VOLUME_LEN,
                }
            } else {
                let mut j = FEATURE_LAYERS;
                let mut found = Region::Depth;
                while j < i {
                    if str_eq(LAYERS[j].name, skip) {
                        found = regions[j];
                    }
                    j += 1;
                }
                found
            }
        } else {
            let r = Region::Unet {
                start: used,
                len: l.output_len(),
            };
            used += l.output_len();
            r
        };
        i += 1;
    }
    (regions, used)
};

/// Bytes of the UNet buffer (d1, d2, m0 for EPSSN-S; u1 writes over d1).
pub const UNET_BUFFER_LEN: usize = PLAN.1;

/// Bytes of the whole-tensor path's cost-volume buffer, which also hosts the feature net's
/// activations there.
pub const COST_BUFFER_LEN: usize = {
    let features = config::INPUT_LEN + 2 * config::MAX_FEATURE_ACTIVATION;
    if features > config::COST_VOLUME_LEN {
        features
    } else {
        config::COST_VOLUME_LEN
    }
};

// The plan must give every skip a home and keep the head last and streamable.
const _: () = {
    let mut i = FEATURE_LAYERS;
    while i + 1 < LAYERS.len() {
        assert!(
            !matches!(PLAN.0[i], Region::Depth),
            "a skip names an unknown tensor"
        );
        i += 1;
    }
    assert!(FEATURE_LAYERS > 0 && FEATURE_LAYERS < LAYERS.len());
};

/// Chunks each feature layer's output is computed in (rows per chunk = output rows / this).
pub const FEATURE_CHUNKS: usize = 8;

/// Row tiles of d1's output (rows per tile = d1's output rows / this).
pub const COST_ROW_CHUNKS: usize = 2;

/// Index of d1, the first cost-net layer (reads the cost volume).
pub(super) const D1: usize = FEATURE_LAYERS;
/// Index of the head (last layer, streamed into the depth map).
pub(super) const HEAD: usize = config::LAYER_COUNT - 1;
/// Index of u0, the layer whose skip is the cost volume (just before the head).
pub(super) const U0: usize = HEAD - 1;

/// Line buffers of one feature layer: a window of `window_rows` input rows
/// (`[C_in][window_rows][W_in]`) and one chunk of `rows` output rows (`[C_out][rows][W_out]`).
#[derive(Clone, Copy, Debug)]
pub(super) struct RowStream {
    pub(super) rows: usize,
    pub(super) window_rows: usize,
    pub(super) window_start: usize,
    pub(super) chunk_start: usize,
}

/// Line buffers of every feature layer, packed from offset 0 of the workspace; and their
/// total length.
pub(super) const FEATURE_STREAMS: ([RowStream; FEATURE_LAYERS], usize) = {
    let empty = RowStream {
        rows: 0,
        window_rows: 0,
        window_start: 0,
        chunk_start: 0,
    };
    let mut s = [empty; FEATURE_LAYERS];
    let mut used = 0;
    let mut i = 0;
    while i < FEATURE_LAYERS {
        let l = &LAYERS[i];
        let rows = l.out_size[0] / FEATURE_CHUNKS;
        let window_rows = l.stride[0] as usize * (rows - 1) + l.kernel[0] as usize;
        let window_start = used;
        used += l.in_channels * window_rows * l.in_size[1];
        let chunk_start = used;
        used += l.out_channels * rows * l.out_size[1];
        s[i] = RowStream {
            rows,
            window_rows,
            window_start,
            chunk_start,
        };
        i += 1;
    }
    (s, used)
};

/// Rows per tile of d1's output and the cost-volume rows (`stride·(rows − 1) + kernel`) a
/// tile reads.
pub(super) const D1_ROWS: usize = LAYERS[D1].out_size[1] / COST_ROW_CHUNKS;
pub(super) const D1_WINDOW_ROWS: usize =
    LAYERS[D1].stride[1] as usize * (D1_ROWS - 1) + LAYERS[D1].kernel[1] as usize;
/// d1's input window `[C][kd][D1_WINDOW_ROWS][W]` and one output tile `[O][1][D1_ROWS][W_out]`.
pub(super) const D1_WINDOW_LEN: usize =
    LAYERS[D1].in_channels * LAYERS[D1].kernel[0] as usize * D1_WINDOW_ROWS * LAYERS[D1].in_size[2];
pub(super) const D1_TILE_LEN: usize = LAYERS[D1].out_channels * D1_ROWS * LAYERS[D1].out_size[2];

/// Input planes one output plane of u0 reads: `ceil(kernel / stride)`.
pub(super) const U0_MAX_IN_PLANES: usize =
    (LAYERS[U0].kernel[0] as usize).div_ceil(LAYERS[U0].stride[0] as usize);
/// One output plane of u0 `[O][1][H][W]` (which first holds the cost-volume plane of its skip),
/// and u0's input planes gathered for it `[I][U0_MAX_IN_PLANES][H_in][W_in]`.
pub(super) const U0_PLANE_LEN: usize =
    LAYERS[U0].out_channels * LAYERS[U0].out_size[1] * LAYERS[U0].out_size[2];
pub(super) const U0_GATHER_LEN: usize =
    LAYERS[U0].in_channels * U0_MAX_IN_PLANES * LAYERS[U0].in_size[1] * LAYERS[U0].in_size[2];

/// `(first input plane, input planes, padding, output padding)` on the plane axis of the
/// transposed convolution that gives exactly output plane `t` of u0 from input planes
/// `first..first + planes` (planes past the end read as zeros): the input planes `i` with a tap
/// `k = t + pad − stride·i` inside the kernel.
pub(super) const fn u0_plane(t: usize) -> (usize, usize, usize, usize) {
    let l = &LAYERS[U0];
    let (k, s, p) = (
        l.kernel[0] as usize,
        l.stride[0] as usize,
        l.padding[0] as usize,
    );
    let last = (t + p) / s;
    let first = if t + p + 1 >= k {
        (t + p + 1 - k).div_ceil(s)
    } else {
        0
    };
    let planes = last + 1 - first;
    let pad = t + p - s * first;
    // One output plane: (planes − 1)·s + k + out_pad − 2·pad = 1.
    let out_pad = 1 + 2 * pad - k - (planes - 1) * s;
    (first, planes, pad, out_pad)
}

/// Whether the head is fused with the soft-argmax ([`head_soft_argmax_s8`]: kernel == stride,
/// no padding, one output channel, so each logit depends on one input voxel). Otherwise the
/// streamed path computes it a step at a time (`stream_u0_head`) with the overlapping head
/// fused with the soft-argmax ([`HeadPlan`], [`crate::kernels::head_s8::head_step_s8`] step by
/// step).
pub(super) const HEAD_FUSED: bool = {
    let h = &LAYERS[HEAD];
    let mut fused = h.out_channels == 1;
    let mut a = 0;
    while a < 3 {
        fused = fused && h.kernel[a] == h.stride[a] && h.padding[a] == 0;
        fused = fused && h.output_padding[a] == 0;
        a += 1;
    }
    fused
};
/// u0 planes a step of the general head reads: `P = ceil(kernel / stride)` on the plane axis
/// (as [`crate::kernels::head_s8::head_step_planes`]).
pub(super) const HEAD_IN_PLANES: usize =
    (LAYERS[HEAD].kernel[0] as usize).div_ceil(LAYERS[HEAD].stride[0] as usize);
/// u0's output planes in the streamed path: one plane for the fused head; for the general
/// head the ring of the last [`HEAD_IN_PLANES`] planes `[P][C][H][W]` (plane `t` in slot
/// `t mod P`) that u0 writes into and the head reads.
pub(super) const U0_OUT_LEN: usize = if HEAD_FUSED {
    U0_PLANE_LEN
} else {
    HEAD_IN_PLANES * U0_PLANE_LEN
};

/// The soft-argmax shape of `rows` depth rows.
pub(super) const fn head_soft_shape(rows: usize) -> SoftArgmaxShape {
    SoftArgmaxShape {
        rows,
        bins: config::DEPTH_RANGE_BINS,
        columns: config::DEPTH_COLUMNS,
    }
}

/// Where the d1/u1 tensor lives: the streamed phases' scratch starts after it.
pub(super) const LIVE_END: usize = match (PLAN.0[D1], PLAN.0[U0 - 1]) {
    (Region::Unet { start, len }, Region::Unet { start: s2, len: l2 }) => {
        if start + len > s2 + l2 {
            start + len
        } else {
            s2 + l2
        }
    }
    _ => 0,
};

pub(super) const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Bytes of the streamed [`Workspace`]: the largest of the feature net's line buffers, the
/// UNet buffer, and the d1/u1 tensor plus the larger of d1's window and u0's plane buffers.
pub const WORKSPACE_LEN: usize = max(
    max(FEATURE_STREAMS.1, UNET_BUFFER_LEN),
    LIVE_END + max(D1_WINDOW_LEN + D1_TILE_LEN, U0_GATHER_LEN + U0_OUT_LEN),
);

// The streamed plan's assumptions about the network, checked against the spec at compile time.
const _: () = {
    let mut i = 0;
    while i < FEATURE_LAYERS {
        let l = &LAYERS[i];
        let s = &FEATURE_STREAMS.0[i];
        assert!(s.rows > 0 && s.rows * FEATURE_CHUNKS == l.out_size[0]);
        assert!(l.in_size[2] == 1 && l.out_size[2] == 1 && l.kernel[2] == 1);
        assert!(l.padding[0] < l.kernel[0]);
        if i > 0 {
            let p = &LAYERS[i - 1];
            assert!(p.out_channels == l.in_channels);
            assert!(p.out_size[0] == l.in_size[0] && p.out_size[1] == l.in_size[1]);
        }
        i += 1;
    }
    assert!(LAYERS[0].input_len() == config::INPUT_LEN);
    assert!(LAYERS[FEATURE_LAYERS - 1].output_len() == config::FEATURE_LEN);
    // Padding of the network input is the value −INPUT_OFFSET, which must be an int8.
    assert!(INPUT_OFFSET == 128);
    // d1 reads the cost volume and writes to the UNet buffer, one output plane per step.
    let d1 = &LAYERS[D1];
    assert!(matches!(d1.kind, LayerKind::Conv3d) && d1.skip.is_none());
    assert!(d1.in_channels == config::FEATURE_CHANNELS);
    assert!(d1.input_len() == config::COST_VOLUME_LEN);
    assert!(d1.in_size[0] == config::PLANES && d1.in_size[1] == config::FEATURE_RANGE_BINS);
    assert!(D1_ROWS > 0 && D1_ROWS * COST_ROW_CHUNKS == d1.out_size[1]);
    assert!(d1.padding[0] < d1.kernel[0] && d1.padding[1] < d1.kernel[1]);
    assert!(matches!(PLAN.0[D1], Region::Unet { .. }));
    // u0 adds the cost volume and feeds the head; nothing else reads the cost volume.
    let u0 = &LAYERS[U0];
    assert!(matches!(u0.kind, LayerKind::ConvTranspose3d));
    assert!(matches!(PLAN.0[U0], Region::Cost { .. }));
    assert!(
        u0.out_channels == config::FEATURE_CHANNELS && u0.output_len() == config::COST_VOLUME_LEN
    );
    assert!(u0.out_size[0] == config::PLANES && u0.out_size[1] == config::FEATURE_RANGE_BINS);
    assert!(matches!(PLAN.0[U0 - 1], Region::Unet { .. }));
    let mut j = D1;
    while j < U0 {
        assert!(matches!(PLAN.0[j], Region::Unet { .. }));
        j += 1;
    }
    let mut t = 0;
    while t < u0.out_size[0] {
        let (_, planes, _, out_pad) = u0_plane(t);
        assert!(planes > 0 && planes <= U0_MAX_IN_PLANES);
        assert!(out_pad < u0.stride[0] as usize);
        t += 1;
    }
    // The fused head turns one u0 plane into `kernel[0]` whole depth rows; the general head
    // (head_step_s8) turns the last `P` u0 planes into the `stride[0]` depth rows
    // `stride·t − padding + 0..stride` of step t.
    let head = &LAYERS[HEAD];
    assert!(matches!(head.kind, LayerKind::ConvTranspose3d) && head.out_channels == 1);
    assert!(head.in_size[0] == u0.out_size[0] && head.in_channels == u0.out_channels);
    assert!(head.in_size[1] == u0.out_size[1] && head.in_size[2] == u0.out_size[2]);
    assert!(head.out_size[0] == config::DEPTH_ROWS);
    assert!(head.out_size[1] == config::DEPTH_RANGE_BINS);
    assert!(head.out_size[2] == config::DEPTH_COLUMNS);
    assert!(head.out_size[0] * head.out_size[2] == config::DEPTH_LEN);
    assert!(HEAD_IN_PLANES * (head.stride[0] as usize) >= head.kernel[0] as usize);
    assert!(LIVE_END > 0);
};

/// `(start, len)` of a UNet region (an empty range for any other region).
pub(super) const fn unet_range(r: Region) -> (usize, usize) {
    match r {
        Region::Unet { start, len } => (start, len),
        _ => (0, 0),
    }
}
