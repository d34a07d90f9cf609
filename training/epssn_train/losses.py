"""The training loss, as the burn trainer (host-sim/crates/train/src/train.rs, at commit 5b1029e) defined it:

`loss = mean_px w·|d̂ − clamp(d)|` (the paper's masked L1, w = λ on mask pixels, 1 elsewhere)
`+ ce_weight · mean_px w·CE(two-hot(clamp(d)), softmax over R)`
`+ no_return_weight · mean_px w·(BCE(p_last, d ≥ r_max) + BCE(p_first, d ≤ r_min))`;
with the no-return term an out-of-window label's two-hot sits wholly on its end bin."""

from __future__ import annotations

import torch


def pixel_weights(mask, lam):
    return mask * (lam - 1.0) + 1.0


def masked_l1(pred, depth, mask, lam, r_min, r_max):
    return ((pred - depth.clamp(r_min, r_max)).abs() * pixel_weights(mask, lam)).mean()


def two_hot_labels(depth, bins, r_min, r_max, ends):
    """[B][E][A] labels → [B][E][R][A] two-hot over the ascending `bins` (mean = clamped label);
    with `ends`, a label at or beyond an end of the window is one-hot on that end's bin."""
    r = bins.numel()
    d = depth.clamp(r_min, r_max)
    hi = torch.searchsorted(bins.contiguous(), d.contiguous(), right=True).clamp(1, r - 1)
    b0, b1 = bins[hi - 1], bins[hi]
    t = ((d - b0) / (b1 - b0)).clamp(0.0, 1.0)
    q = torch.zeros(*depth.shape[:1], depth.shape[1], r, depth.shape[2], dtype=depth.dtype,
                    device=depth.device)
    q.scatter_(2, (hi - 1).unsqueeze(2), (1.0 - t).unsqueeze(2))
    q.scatter_add_(2, hi.unsqueeze(2), t.unsqueeze(2))
    if ends:
        far = (depth >= r_max).unsqueeze(2)
        near = (depth <= r_min).unsqueeze(2)
        end = torch.zeros_like(q)
        end[:, :, -1:] = far.to(q.dtype)
        end[:, :, :1] += near.to(q.dtype) * (~far).to(q.dtype)
        q = torch.where(far | near, end, q)
    return q


def masked_two_hot_ce(logits, q, mask, lam):
    """`logits` [B][1][E][R][A], `q` [B][E][R][A], mask [B][E][A]."""
    lp = torch.log_softmax(logits[:, 0], dim=2)
    return (-(q * lp).sum(2) * pixel_weights(mask, lam)).mean()


def no_return_bce(logits, far, near, mask, lam):
    lp = torch.log_softmax(logits[:, 0], dim=2)

    def bce(lpb, y):
        # log(1 − p), kept finite where p rounds to 1.
        lq = (1.0 - lpb.exp()).clamp_min(1e-7).log()
        return -(y * lpb + (1.0 - y) * lq)

    return ((bce(lp[:, :, -1], far) + bce(lp[:, :, 0], near)) * pixel_weights(mask, lam)).mean()


def total_loss(depth_pred, logits, depth, mask, spec, bins, ce_weight, no_return_weight):
    """(total, L1 term)."""
    l1 = masked_l1(depth_pred, depth, mask, spec.lam, spec.r_min, spec.r_max)
    loss = l1
    ends = no_return_weight > 0
    if ce_weight > 0:
        q = two_hot_labels(depth, bins.to(depth.dtype), spec.r_min, spec.r_max, ends)
        loss = loss + ce_weight * masked_two_hot_ce(logits, q, mask, spec.lam)
    if ends:
        far = (depth >= spec.r_max).to(depth.dtype)
        near = (depth <= spec.r_min).to(depth.dtype)
        loss = loss + no_return_weight * no_return_bce(logits, far, near, mask, spec.lam)
    return loss, l1


def lr_at(lr, fraction, step, total):
    """`lr` before `fraction·total`, `lr/2` from there on (the spec's schedule)."""
    return lr if step < fraction * total else lr * 0.5
