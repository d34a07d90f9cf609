"""The float EPSSN in PyTorch, layer by layer from the spec (host-sim's f64 reference network,
`epssn_reference::floatref`, and the burn trainer it replaces define the same network).

1. u8 polar images of all views, divided by 255;
2. the feature net on every view (Conv2d, BatchNorm, ReLU as the spec says);
3. every source view k ≥ 1 warped through the spec's pure-roll table with the *quantised*
   fraction: `F[c]·(1 − α/2^bits) + F[c+1]·α/2^bits` (`F[c+1]` only where α > 0), invisible
   entries 0 — the very table the firmware uses;
4. the cost volume: the population variance over the views, the last `mean_channels`
   channels their mean clipped at 0;
5. the cost net (Conv3d / ConvTranspose3d, BatchNorm, ReLU, then `+ skip`), the head's logits
   `[B][1][E][R][A]`;
6. softmax over R, depth = clamp(Σ p_i·bin_i, r_min, r_max); at inference the no-return
   decision: r_max where the last bin holds ≥ τ of the mass, else r_min where the first does.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import torch
from torch import nn
import torch.nn.functional as F

from .spec import Spec

BN_EPSILON = 1e-5
BN_MOMENTUM = 0.1




def fake_quant(x, scale, lo, hi):
    """`x` clipped to the int8 grid and rounded to its codes in the forward pass; the gradient
    is the clip's (straight-through), as `host-sim train --fake-quant` does."""
    clipped = x.clamp(lo * scale, hi * scale)
    rounded = torch.round(clipped / scale) * scale
    return clipped + (rounded - clipped).detach()


class Block(nn.Module):
    def __init__(self, l):
        super().__init__()
        k = dict(kernel_size=tuple(l.kernel), stride=tuple(l.stride), padding=tuple(l.padding),
                 bias=True)
        if l.kind == "conv2d":
            self.conv = nn.Conv2d(l.cin, l.cout, **k)
            bn = nn.BatchNorm2d
        elif l.kind == "conv3d":
            self.conv = nn.Conv3d(l.cin, l.cout, **k)
            bn = nn.BatchNorm3d
        elif l.kind == "conv_transpose3d":
            self.conv = nn.ConvTranspose3d(l.cin, l.cout, output_padding=tuple(l.output_padding),
                                           **k)
            bn = nn.BatchNorm3d
        else:
            raise ValueError(f"layer {l.name}: unknown kind {l.kind}")
        self.bn = bn(l.cout, eps=BN_EPSILON, momentum=BN_MOMENTUM) if l.batch_norm else None
        self.relu = l.relu

        self.subpixel = None
        if l.kind == "conv_transpose3d":
            self.subpixel = _subpixel_plan(l.kernel, l.stride, l.padding)

    def forward(self, x):
        if self.subpixel is not None and _SUBPIXEL:
            x = _conv_transpose_subpixel(x, self.conv, *self.subpixel)
        else:
            x = self.conv(x)
        if self.bn is not None:
            x = self.bn(x)
        return torch.relu(x) if self.relu else x


# Transposed convolutions as sub-pixel convolutions (below); False runs PyTorch's own.
_SUBPIXEL = True


def _subpixel_plan(kernel, stride, padding):
    """A transposed convolution whose output is its input × stride in every dimension is a
    plain convolution with stride 1 giving ∏stride phases per output channel, interleaved:
    output `t = q·s + r` sums inputs `z = q + d` through tap `kz = r + p − d·s`. PyTorch's CPU
    transposed 3D convolution runs a slow generic path (the head's was a quarter of a step);
    the plain convolution runs oneDNN's. Returns (gather index into the flattened kernel with
    one extra zero tap, pads (left, right) per dimension, strides)."""
    offsets = []
    for k, s, p in zip(kernel, stride, padding):
        ds = [(r + p - kz) // s for r in range(s) for kz in range(k) if (r + p - kz) % s == 0]
        offsets.append((min(ds), max(ds)))
    ks = [hi - lo + 1 for lo, hi in offsets]
    kvol = int(np.prod(kernel))
    phases = int(np.prod(stride))
    idx = np.full((phases, *ks), kvol, np.int64)
    for ph in range(phases):
        r = np.unravel_index(ph, stride)
        for t in np.ndindex(*ks):
            taps = []
            for dim in range(3):
                d = t[dim] + offsets[dim][0]
                kz = r[dim] + padding[dim] - d * stride[dim]
                taps.append(kz if 0 <= kz < kernel[dim] else -1)
            if min(taps) >= 0:
                idx[(ph, *t)] = np.ravel_multi_index(taps, kernel)
    pads = [(-lo, hi) for lo, hi in offsets]
    return torch.from_numpy(idx), pads, list(stride)


def _conv_transpose_subpixel(x, conv, idx, pads, stride):
    ci, co = conv.weight.shape[:2]
    b, _, dz, dy, dx = x.shape
    out = [(n - 1) * s - 2 * p + k + op for n, s, p, k, op in
           zip((dz, dy, dx), stride, conv.padding, conv.kernel_size, conv.output_padding)]
    if out != [dz * stride[0], dy * stride[1], dx * stride[2]]:
        return conv(x)
    phases = idx.shape[0]
    w = conv.weight.permute(1, 0, 2, 3, 4).reshape(co, ci, -1)
    w = torch.cat([w, w.new_zeros(co, ci, 1)], 2)[:, :, idx.reshape(-1)]
    w = w.reshape(co, ci, phases, *idx.shape[1:]).transpose(1, 2)
    w = w.reshape(co * phases, ci, *idx.shape[1:])
    xp = F.pad(x, (pads[2][0], pads[2][1], pads[1][0], pads[1][1], pads[0][0], pads[0][1]))
    y = F.conv3d(xp, w, conv.bias.repeat_interleave(phases))
    sz, sy, sx = stride
    y = y.reshape(b, co, sz, sy, sx, dz, dy, dx).permute(0, 1, 5, 2, 6, 3, 7, 4)
    return y.reshape(b, co, dz * sz, dy * sy, dx * sx)


class Epssn(nn.Module):
    def __init__(self, spec: Spec, channels_last: bool = False):
        super().__init__()
        self.spec = spec
        # Channels-last activations take oneDNN's 3D convolutions on CPU (5x faster forward
        # on m0 alone) but slow batch norm: off by default, `bench --channels-last` measures
        # it. The layout changes no value.
        self.channels_last = channels_last
        self.layers = nn.ModuleDict(OrderedDict((l.name, Block(l)) for l in spec.layers))
        self.feature_names = [l.name for l in spec.feature_net]
        self.cost_names = [l.name for l in spec.cost_net]
        self.skips = {l.name: l.skip for l in spec.cost_net}
        self.fake_quant = {}
        # Warp tables as a [W][N·W] matrix per source view k = 1..max_views-1, two non-zeros
        # per column (the left and right taps): the gather as one matrix product, whose
        # backward is another (the indexed gather's backward scatters, 2x slower here).
        for k in range(1, spec.max_views):
            col, frac, vis = spec.warp_table(k)
            one = float(1 << spec.fraction_bits)
            n, w = col.shape
            m = np.zeros((w, n * w))
            for j in range(n):
                for b in range(w):
                    if vis[j, b]:
                        a = frac[j, b] / one
                        m[col[j, b], j * w + b] += 1.0 - a
                        if frac[j, b] > 0:
                            m[col[j, b] + 1, j * w + b] += a
            self.register_buffer(f"warp{k}", torch.from_numpy(m), persistent=False)
        if channels_last:
            for l in spec.layers:
                fmt = torch.channels_last if l.kind == "conv2d" else torch.channels_last_3d
                self.layers[l.name].to(memory_format=fmt)
        self.register_buffer("bins", torch.tensor(spec.depth_bin_ranges, dtype=torch.float64),
                             persistent=False)

    def set_fake_quant(self, scales: dict):
        """Round the named activations to their int8 grids (cost 0..255, others −128..127)."""
        known = set(self.feature_names) | set(self.cost_names) | {"cost"}
        for n, s in scales.items():
            if n not in known or not (s > 0 and np.isfinite(s)):
                raise ValueError(f"fake quantisation of {n} at scale {s}")
        self.fake_quant = {n: (float(s), 0.0 if n == "cost" else -128.0,
                               255.0 if n == "cost" else 127.0) for n, s in scales.items()}

    def _q(self, name, x):
        g = self.fake_quant.get(name)
        return fake_quant(x, *g) if g else x

    def warp(self, f, k):
        """`f` [B][C][H][W] → [B][C][N][H][W] through view k's table."""
        m = getattr(self, f"warp{k}").to(f.dtype)
        w = f.shape[-1]
        out = (f @ m).reshape(*f.shape[:-1], m.shape[1] // w, w)
        # [B][C][H][N][W] → [B][C][N][H][W]
        return out.permute(0, 1, 3, 2, 4)

    def forward(self, views):
        """`views`: list of 2 or 3 tensors [B][1][R][W] of u8 values (any float dtype).
        Returns (soft depth [B][E][A] metres clamped to the window, logits [B][1][E][R][A])."""
        nv = len(views)
        if not 2 <= nv <= 3:
            raise ValueError(f"the model takes 2 or 3 views, got {nv}")
        b = views[0].shape[0]
        x = torch.cat(views, 0) / 255.0
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        for name in self.feature_names:
            x = self._q(name, self.layers[name](x))
        n = self.spec.planes
        ref = x[:b].unsqueeze(2).expand(-1, -1, n, -1, -1)
        vols = [ref] + [self.warp(x[k * b:(k + 1) * b], k) for k in range(1, nv)]
        s = vols[0]
        for v in vols[1:]:
            s = s + v
        mean = s / nv
        var = None
        for v in vols:
            d = (v - mean) ** 2
            var = d if var is None else var + d
        var = var / nv
        c, m = self.spec.channels, self.spec.mean_channels
        cost = var if m == 0 else torch.cat([var[:, :c - m], torch.relu(mean[:, c - m:])], 1)
        cost = self._q("cost", cost)
        if self.channels_last:
            cost = cost.contiguous(memory_format=torch.channels_last_3d)
        named = {"cost": cost}
        y = cost
        for name in self.cost_names:
            y = self.layers[name](y)
            skip = self.skips[name]
            if skip:
                y = y + named[skip]
            y = self._q(name, y)
            named[name] = y
        logits = y
        p = torch.softmax(logits, dim=3)
        bins = self.bins.to(logits.dtype).reshape(1, 1, 1, -1, 1)
        depth = (p * bins).sum(3).reshape(b, logits.shape[2], logits.shape[4])
        return depth.clamp(self.spec.r_min, self.spec.r_max), logits

    @torch.no_grad()
    def depth(self, views):
        """Inference depth with the no-return decision, as floatref computes it (softmax in
        f64 on the logits, clamp, then the end-bin masses against τ)."""
        _, logits = self.forward(views)
        lg = logits[:, 0].double()  # [B][E][R][A]
        p = torch.softmax(lg, dim=2)
        bins = self.bins.reshape(1, 1, -1, 1)
        soft = (p * bins).sum(2).clamp(self.spec.r_min, self.spec.r_max)
        tau = self.spec.no_return_mass
        if tau > 0:
            far, near = p[:, :, -1], p[:, :, 0]
            soft = torch.where(near >= tau, torch.full_like(soft, self.spec.r_min), soft)
            soft = torch.where(far >= tau, torch.full_like(soft, self.spec.r_max), soft)
        return soft.float()

    # --- weights: the tensor names of weights/<name>/model.safetensors ---------------------

    def to_tensors(self):
        out = {}
        for name, blk in self.layers.items():
            out[f"{name}.conv.weight"] = blk.conv.weight
            out[f"{name}.conv.bias"] = blk.conv.bias
            if blk.bn is not None:
                out[f"{name}.bn.gamma"] = blk.bn.weight
                out[f"{name}.bn.beta"] = blk.bn.bias
                out[f"{name}.bn.running_mean"] = blk.bn.running_mean
                out[f"{name}.bn.running_var"] = blk.bn.running_var
        return {k: v.detach().float().contiguous().cpu() for k, v in out.items()}

    @torch.no_grad()
    def load_tensors(self, tensors: dict):
        mine = self.to_tensors()
        missing = sorted(set(mine) - set(tensors))
        if missing:
            raise KeyError(f"weights lack {', '.join(missing)}")
        for name, blk in self.layers.items():
            pairs = [(blk.conv.weight, "conv.weight"), (blk.conv.bias, "conv.bias")]
            if blk.bn is not None:
                pairs += [(blk.bn.weight, "bn.gamma"), (blk.bn.bias, "bn.beta"),
                          (blk.bn.running_mean, "bn.running_mean"),
                          (blk.bn.running_var, "bn.running_var")]
            for t, suffix in pairs:
                src = torch.as_tensor(np.asarray(tensors[f"{name}.{suffix}"]))
                if tuple(src.shape) != tuple(t.shape):
                    raise ValueError(f"{name}.{suffix}: shape {tuple(src.shape)}, the spec "
                                     f"wants {tuple(t.shape)}")
                t.copy_(src.to(t.dtype))


def init_uniform(model: Epssn, seed: int):
    """uniform(±1/√fan_in) weights and biases (the burn trainer's and PyTorch's default), gamma
    1, beta 0, running mean 0, running var 1."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for l in model.spec.layers:
            blk = model.layers[l.name]
            fan_in = l.cin * int(np.prod(l.kernel))
            bound = 1.0 / max(fan_in, 1) ** 0.5
            for t in (blk.conv.weight, blk.conv.bias):
                t.copy_((torch.rand(t.shape, generator=g, dtype=torch.float64) * 2 - 1) * bound)
            if blk.bn is not None:
                blk.bn.reset_parameters()
