#!/usr/bin/env python3
"""How well can any no-return decision read the network's output? (docs/ACCURACY.md)

Fits decisions of growing power on the head's softmax of one split (FIT) and scores each on
another (VAL) by the return mask's precision and recall, each map's ratio averaged over the
maps (what `host-sim eval` reports as mask_precision / mask_recall), at the threshold where
the smaller of the two is largest:

  1. the spec's rule: the last bin's mass against τ (first-bin mass too, as the device does);
  2. a logistic regression on ten per-ray and neighbourhood statistics;
  3. gradient-boosted trees on the whole 64-bin log-softmax of the ray, the end-bin and peak
     masses of its 5 × 5 neighbourhood and its row and column.

Then where the errors sit: the share of phantoms and misses within one pixel of the
ground truth's silhouette. The inputs are `dump_head` files:

    cargo run --release -p epssn-eval --example dump_head -- weights/general DATA/sphere-fit/test fit.f32
    cargo run --release -p epssn-eval --example dump_head -- weights/general DATA/sphere-val/test val.f32
    pip install numpy scikit-learn
    python3 scripts/studies/no-return-ceiling.py fit.f32 val.f32

DATA/sphere-fit is `host-sim simulate --scene sphere --split test --pairs 200 --seed 3` (a
seed no training, test or validation split uses), DATA/sphere-val the validation split
(seed 2, as scripts/train-general.sh makes it).
"""
import sys

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.linear_model import LogisticRegression

E, R, A = 32, 64, 64
EPS = 1e-6


def load(path):
    x = np.fromfile(path, dtype="<f4").reshape(-1, E * R * A + 2 * E * A)
    n = x.shape[0]
    logit = x[:, : E * R * A].reshape(n, E, R, A).transpose(0, 1, 3, 2)
    mask = x[:, E * R * A : E * R * A + E * A].reshape(n, E, A) > 0.5
    p = np.exp(logit - logit.max(-1, keepdims=True))
    return (p / p.sum(-1, keepdims=True)).astype(np.float32), mask


def per_map(pred, gt):
    prec = [(a & b).sum() / a.sum() for a, b in zip(pred, gt) if a.sum()]
    rec = [(a & b).sum() / b.sum() for a, b in zip(pred, gt) if b.sum()]
    return 100 * np.mean(prec), 100 * np.mean(rec)


def best(score, gt, thresholds):
    rows = [(min(per_map(score >= t, gt)), t, *per_map(score >= t, gt)) for t in thresholds]
    return max(rows)


def neighbours(x, r, fn=None):
    xp = np.pad(x, ((0, 0), (r, r), (r, r)), mode="edge")
    s = np.stack(
        [xp[:, r + dy : r + dy + E, r + dx : r + dx + A] for dy in range(-r, r + 1) for dx in range(-r, r + 1)],
        -1,
    )
    return s if fn is None else fn(s, -1)


def small(p):
    pl, pf, inner = p[..., -1], p[..., 0], p[..., 1:-1]
    k = inner.argmax(-1)
    idx = np.stack([np.clip(k - 1, 0, R - 3), k, np.clip(k + 1, 0, R - 3)], -1)
    peak3 = np.take_along_axis(inner, idx, -1).sum(-1)
    lpl = np.log(pl + EPS)
    f = [lpl, np.log(pf + EPS), np.log(inner.max(-1) + EPS), -(p * np.log(p + EPS)).sum(-1),
         np.log(peak3 + EPS), k / (R - 2), np.log(1 - pl - pf + EPS),
         neighbours(lpl, 1, np.min), neighbours(lpl, 1, np.mean), neighbours(np.log(inner.max(-1) + EPS), 1, np.max)]
    return np.stack(f, -1)


def large(p):
    n = p.shape[0]
    pos = [np.broadcast_to(np.arange(E)[None, :, None, None], (n, E, A, 1)),
           np.broadcast_to(np.arange(A)[None, None, :, None], (n, E, A, 1))]
    return np.concatenate(
        [np.log(p + EPS), neighbours(np.log(p[..., -1] + EPS), 2), neighbours(np.log(p[..., 1:-1].max(-1) + EPS), 2)]
        + [x.astype(np.float32) for x in pos], -1)


def main():
    pf, gf = load(sys.argv[1])
    pv, gv = load(sys.argv[2])
    print(f"fit {len(gf)} maps, validation {len(gv)} maps; min(P, R) at the best threshold, P, R (per-map means, %)")
    keep = lambda p: 1 - np.maximum(p[..., -1], p[..., 0])
    r = best(keep(pv), gv, 1 - np.linspace(0.1, 0.5, 33))
    print("1. end-bin mass, τ = %.3f: %.2f (P %.2f, R %.2f)" % (1 - r[1], r[0], r[2], r[3]))
    for name, feats in (("2. logistic regression, 10 statistics", small), ("3. boosted trees, whole ray + 5 x 5", large)):
        xf, xv = feats(pf), feats(pv)
        model = (LogisticRegression(max_iter=2000) if feats is small else HistGradientBoostingClassifier(max_iter=400))
        model.fit(xf.reshape(-1, xf.shape[-1]), gf.reshape(-1))
        s = model.predict_proba(xv.reshape(-1, xv.shape[-1]))[:, 1].reshape(gv.shape)
        r = best(s, gv, np.linspace(0.2, 0.8, 25))
        print("%s: %.2f (P %.2f, R %.2f)" % (name, r[0], r[2], r[3]))
    tau = 0.25
    ret = ~((pv[..., -1] >= tau) | (pv[..., 0] >= tau))
    dil = lambda m: neighbours(m, 1, np.any)
    fp, fn = ret & ~gv, gv & ~ret
    print("at τ = %.2f: phantoms next to a true return %.1f %%, misses next to a true no-return %.1f %%, "
          "true returns on the silhouette %.1f %%" % (tau, 100 * (fp & dil(gv)).sum() / fp.sum(),
          100 * (fn & dil(~gv)).sum() / fn.sum(), 100 * (gv & dil(~gv)).sum() / gv.sum()))


if __name__ == "__main__":
    main()
