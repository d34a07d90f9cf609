#!/usr/bin/env python3
"""Whether a beam that shows no surface anywhere in the window (a dark column) can be told near
from far by its neighbours: the ground truth's own answer, no network (docs/studies/table-one.md,
"Dark columns: what the neighbours know").

A dark column's rays all met the scene nearer than r_min, or nothing before r_max, or some of
each; inside the window they look alike. The rule read here: each of its rays takes the class
(near or far of the window's middle, as `epssn_sim::metrics::ErrorBreakdown` classes rays) of the
same elevation row in the nearest beams on either side that do show a surface, weighted by the
inverse of their distance in beams. Reported: how often that is the ray's true class, and what the
dark columns would add to the all-pixel MAE were their rays read at r_min or r_max as the rule
says (a wrong class costs the window's width) — against what a model reads there
(`scripts/studies/empty-rays.py`). A map with no surface at all gives no neighbour; its dark
rays are counted apart.

    "$(bash scripts/epssn-train.sh --python)" scripts/studies/dark-columns.py DATA/test \\
        --spec weights/epssn-p.json [--limit N] [--learned TRAIN_DATA --train-limit N]

`--learned` also fits gradient-boosted trees (scikit-learn) on the dark rays of TRAIN_DATA's maps
and scores them here: per ray its row and column, the width of its dark run, and for the two
nearest surface beams on each side their distance, their class at its row, their lowest and
highest surface rows, the depth at the lowest, and their share of near rays; the map's share of
surface, and of near rays among the beams that show one. A ceiling on what the window's
neighbourhood tells, read from the ground truth rather than from the images the network sees.
"""
import argparse
import json
import os

import numpy as np


def near_class(label, r_min, r_max):
    """True where a clamped label reads below the window's middle (ErrorBreakdown's near)."""
    return label < (r_min + r_max) / 2.0


def neighbour_rule(near, mask):
    """`[E][A]` near/far guessed for the dark columns from the nearest surface columns on each
    side (inverse-distance vote, row by row); None where the map shows no surface at all."""
    lit = np.flatnonzero(mask.any(axis=0))
    if lit.size == 0:
        return None
    guess = np.zeros_like(near)
    for c in np.flatnonzero(~mask.any(axis=0)):
        left, right = lit[lit < c], lit[lit > c]
        votes, weights = [], []
        for side in (left[-1:] if left.size else [], right[:1] if right.size else []):
            for n in side:
                votes.append(near[:, n].astype(np.float64))
                weights.append(1.0 / abs(int(n) - int(c)))
        vote = np.average(np.stack(votes), axis=0, weights=weights)
        guess[:, c] = vote >= 0.5
    return guess


def column_summary(near, mask, depth01):
    """Per column: (lowest surface row, highest surface row, depth at the lowest in [0, 1], share
    of near rays); rows -1 where the column shows no surface."""
    e = mask.shape[0]
    lit = mask.any(axis=0)
    lo = np.where(lit, mask.argmax(axis=0), -1)
    hi = np.where(lit, e - 1 - mask[::-1].argmax(axis=0), -1)
    d_lo = np.where(lit, depth01[np.clip(lo, 0, e - 1), np.arange(mask.shape[1])], -1.0)
    return lo, hi, d_lo, near.mean(axis=0)


def dark_ray_features(near, mask, depth01):
    """(features [n][F], near [n]) of every ray in a dark column of one map showing a surface."""
    e, a = mask.shape
    lit = np.flatnonzero(mask.any(axis=0))
    dark = np.flatnonzero(~mask.any(axis=0))
    if lit.size == 0 or dark.size == 0:
        return None
    lo, hi, d_lo, share = column_summary(near, mask, depth01)
    rows = np.arange(e)
    # Over the lit columns only: the dark rays' own classes are what is being guessed.
    mask_share, near_share = mask.mean(), near[:, lit].mean()
    feats, labels = [], []
    for c in dark:
        run_left = c - (lit[lit < c][-1] if (lit < c).any() else -1) - 1
        run_right = (lit[lit > c][0] if (lit > c).any() else a) - c - 1
        cols = [rows / e, np.full(e, c / a), np.full(e, run_left + run_right + 1.0)]
        for side in (lit[lit < c][::-1][:2], lit[lit > c][:2]):
            for k in range(2):
                if k < side.size:
                    n = side[k]
                    vals = [abs(int(n) - int(c)), None, lo[n] / e, hi[n] / e, d_lo[n], share[n], 1.0]
                    cols += [np.full(e, v, np.float64) if v is not None else near[:, n].astype(np.float64)
                             for v in vals]
                else:
                    cols += [np.full(e, v, np.float64) for v in (a, -1, -1, -1, -1, -1, 0.0)]
        cols += [np.full(e, mask_share), np.full(e, near_share)]
        feats.append(np.stack(cols, axis=1))
        labels.append(near[:, c])
    return np.concatenate(feats), np.concatenate(labels)


def read_map(folder, sample, r_min, r_max):
    depth = np.load(os.path.join(folder, sample, "depth.npy")).astype(np.float64)
    mask = np.load(os.path.join(folder, sample, "mask.npy")) > 0.5  # metrics::mask_from_f32
    label = np.clip(depth, r_min, r_max)
    return near_class(label, r_min, r_max), mask, (label - r_min) / (r_max - r_min)


def sample_names(folder, limit):
    return sorted(s for s in os.listdir(folder)
                  if os.path.isfile(os.path.join(folder, s, "depth.npy")))[:limit]


def learned_rule(train, limit, test_maps, r_min, r_max):
    """Dark rays of `test_maps` (read_map's triples) the trees class right, all of them, and
    the dark rays they were fitted on."""
    try:
        from sklearn.ensemble import HistGradientBoostingClassifier
    except ImportError:
        raise SystemExit("--learned needs scikit-learn: pip install scikit-learn")
    xs, ys = [], []
    for s in sample_names(train, limit):
        f = dark_ray_features(*read_map(train, s, r_min, r_max))
        if f is not None:
            xs.append(f[0])
            ys.append(f[1])
    if not xs:
        raise SystemExit(f"no dark columns in {train}")
    trees = HistGradientBoostingClassifier(max_iter=300, random_state=0)
    trees.fit(np.concatenate(xs), np.concatenate(ys))
    right = total = 0
    for m in test_maps:
        f = dark_ray_features(*m)
        if f is not None:
            right += int((trees.predict(f[0]) == f[1]).sum())
            total += f[1].size
    return right, total, sum(y.size for y in ys)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", help="folder of samples (depth.npy, mask.npy)")
    ap.add_argument("--spec", required=True, help="the spec whose range window classes the rays")
    ap.add_argument("--limit", type=int)
    ap.add_argument("--learned", help="fit gradient-boosted trees on this data's dark rays")
    ap.add_argument("--train-limit", type=int, default=1000)
    a = ap.parse_args()
    with open(a.spec) as f:
        window = json.load(f)["range_window"]
    r_min, r_max = window["r_min_m"], window["r_max_m"]
    width_mm = 1000.0 * (r_max - r_min)

    # Read once: the rule and the trees score the same maps.
    maps = [read_map(a.data, s, r_min, r_max) for s in sample_names(a.data, a.limit)]
    pixels = dark = dark_near = right = unlit = unlit_maps = 0
    for near, mask, _ in maps:
        cols = ~mask.any(axis=0)
        pixels += near.size
        guess = neighbour_rule(near, mask)
        if guess is None:
            unlit += near.size
            unlit_maps += 1
            continue
        sel = np.broadcast_to(cols[None, :], near.shape)
        dark += int(sel.sum())
        dark_near += int((near & sel).sum())
        right += int(((guess == near) & sel).sum())
    if pixels == 0:
        raise SystemExit(f"no samples in {a.data}")
    print(f"{len(maps)} maps; {100 * dark / pixels:.1f} % of the pixels in dark columns of maps "
          f"that show a surface ({100 * dark_near / max(dark, 1):.1f} % of them near), "
          f"{100 * unlit / pixels:.1f} % in {unlit_maps} maps with no surface")
    wrong = dark - right
    print(f"neighbour rule: {100 * right / max(dark, 1):.1f} % of the dark-column rays classed "
          f"right; read at r_min / r_max as it says, they would add "
          f"{width_mm * wrong / pixels:.2f} mm to the all-pixel MAE (a wrong class costs "
          f"{width_mm:.0f} mm)")
    print(f"for scale, reading every dark-column ray at r_max: {width_mm * dark_near / pixels:.2f} mm")
    if a.learned:
        right, total, fitted = learned_rule(a.learned, a.train_limit, maps, r_min, r_max)
        print(f"gradient-boosted trees fitted on {fitted} dark rays of {a.learned}: "
              f"{100 * right / max(total, 1):.1f} % classed right here, "
              f"{width_mm * (total - right) / pixels:.2f} mm of all-pixel MAE")


if __name__ == "__main__":
    main()
