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
        --spec weights/epssn-p.json [--limit N]
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", help="folder of samples (depth.npy, mask.npy)")
    ap.add_argument("--spec", required=True, help="the spec whose range window classes the rays")
    ap.add_argument("--limit", type=int)
    a = ap.parse_args()
    with open(a.spec) as f:
        window = json.load(f)["range_window"]
    r_min, r_max = window["r_min_m"], window["r_max_m"]
    width_mm = 1000.0 * (r_max - r_min)

    samples = sorted(s for s in os.listdir(a.data)
                     if os.path.isfile(os.path.join(a.data, s, "depth.npy")))[:a.limit]
    pixels = dark = dark_near = right = unlit = unlit_maps = 0
    for sample in samples:
        depth = np.load(os.path.join(a.data, sample, "depth.npy")).astype(np.float64)
        mask = np.load(os.path.join(a.data, sample, "mask.npy")) > 0.5  # metrics::mask_from_f32
        near = near_class(np.clip(depth, r_min, r_max), r_min, r_max)
        cols = ~mask.any(axis=0)
        pixels += depth.size
        guess = neighbour_rule(near, mask)
        if guess is None:
            unlit += depth.size
            unlit_maps += 1
            continue
        sel = np.broadcast_to(cols[None, :], depth.shape)
        dark += int(sel.sum())
        dark_near += int((near & sel).sum())
        right += int(((guess == near) & sel).sum())
    if pixels == 0:
        raise SystemExit(f"no samples in {a.data}")
    print(f"{len(samples)} maps; {100 * dark / pixels:.1f} % of the pixels in dark columns of maps "
          f"that show a surface ({100 * dark_near / max(dark, 1):.1f} % of them near), "
          f"{100 * unlit / pixels:.1f} % in {unlit_maps} maps with no surface")
    wrong = dark - right
    print(f"neighbour rule: {100 * right / max(dark, 1):.1f} % of the dark-column rays classed "
          f"right; read at r_min / r_max as it says, they would add "
          f"{width_mm * wrong / pixels:.2f} mm to the all-pixel MAE (a wrong class costs "
          f"{width_mm:.0f} mm)")
    always_far = dark_near
    print(f"for scale, reading every dark-column ray at r_max: {width_mm * always_far / pixels:.2f} mm")


if __name__ == "__main__":
    main()
