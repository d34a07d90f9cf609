#!/usr/bin/env python3
"""Where a model's all-pixel error sits, by what the ground truth's column shows (docs/studies/table-one.md).

`host-sim eval --breakdown` splits the error into surface, silhouette, empty far and empty near.
This splits the empty rays further by their azimuth column, since a column's image holds what
every elevation ray of it met inside the window:

  - empty near, below the column's lowest surface ray: the terrain is met before r_min under a
    surface the model sees, so the ray's class follows from that surface;
  - empty near, above a surface ray (an occluding bump);
  - empty near / empty far in a column with no surface ray at all: the column's image is dark
    whether its rays met the terrain before r_min or nothing before r_max;
  - empty far in a column with a surface ray.

It also reports how far above r_min the model reads the empty-near rays (their percentiles):
the soft-argmax's first bin stands for r_min − K·step, so a model that puts no mass there reads
them one step (12.1 mm on EPSSN-P's grid) above r_min at best.

    host-sim eval --weights W --data DATA --breakdown --save-depth PRED   # a host-sim built for W's spec
    "$(bash scripts/epssn-train.sh --python)" scripts/studies/empty-rays.py DATA/test PRED \
        --spec W/spec.json   # the trainer's Python, which has numpy

DATA/test holds the samples (`depth.npy`, `mask.npy`), PRED the `<sample>/depth_float.npy` that
`--save-depth` writes; the window comes from the spec. The rays are classed as
`epssn_sim::metrics::ErrorBreakdown` classes them (a ray outside the mask is near when its
clamped label reads below the window's middle, far otherwise), so the empty classes add up to its
empty near and empty far. Needs numpy.
"""
import argparse
import json
import os

import numpy as np


def empty_near(label, mask, r_min, r_max):
    """Rays outside the mask whose clamped label reads r_min (ErrorBreakdown's `empty_near`)."""
    return ~mask & (label < (r_min + r_max) / 2.0)


def classify(label, mask, r_min, r_max):
    """Boolean masks `[E][A]` of each ray class, `label` clamped; row 0 is the lowest elevation."""
    near = empty_near(label, mask, r_min, r_max)
    far = ~mask & ~near
    with_surface = mask.any(axis=0)[None, :]
    lowest = np.where(mask.any(axis=0), mask.argmax(axis=0), mask.shape[0])
    below = np.arange(mask.shape[0])[:, None] < lowest[None, :]
    return {
        "surface or silhouette (mask)": mask,
        "empty near, below the column's lowest surface": near & with_surface & below,
        "empty near, above a surface (occluding bump)": near & with_surface & ~below,
        "empty near, column without surface": near & ~with_surface,
        "empty far, column with surface": far & with_surface,
        "empty far, column without surface": far & ~with_surface,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", help="folder of samples (depth.npy, mask.npy)")
    ap.add_argument("pred", help="folder of <sample>/depth_float.npy (eval --save-depth)")
    ap.add_argument("--spec", required=True, help="the model's spec (its range window)")
    a = ap.parse_args()
    with open(a.spec) as f:
        window = json.load(f)["range_window"]
    r_min, r_max = window["r_min_m"], window["r_max_m"]

    sums, counts, total_mm, pixels, maps = {}, {}, 0.0, 0, 0
    near_above_r_min = []
    for sample in sorted(os.listdir(a.pred)):
        pred = np.load(os.path.join(a.pred, sample, "depth_float.npy")).astype(np.float64)
        depth = np.load(os.path.join(a.data, sample, "depth.npy")).astype(np.float64)
        mask = np.load(os.path.join(a.data, sample, "mask.npy")) > 0.5  # metrics::mask_from_f32
        if pred.shape != depth.shape:
            raise SystemExit(f"{sample}: prediction {pred.shape} against label {depth.shape}")
        label = np.clip(depth, r_min, r_max)
        err_mm = 1000.0 * np.abs(pred - label)
        for name, sel in classify(label, mask, r_min, r_max).items():
            sums[name] = sums.get(name, 0.0) + err_mm[sel].sum()
            counts[name] = counts.get(name, 0) + int(sel.sum())
        near = empty_near(label, mask, r_min, r_max)
        near_above_r_min.append(1000.0 * (pred[near] - r_min))
        total_mm += err_mm.sum()
        pixels += err_mm.size
        maps += 1
    if maps == 0:
        raise SystemExit(f"no predictions in {a.pred}")

    print(f"{maps} maps, all-pixel MAE {total_mm / pixels:.2f} mm")
    print(f"{'class':48} {'pixels':>7} {'MAE mm':>8} {'adds mm':>8}")
    for name in sums:
        c = counts[name]
        mae = sums[name] / c if c else 0.0
        print(f"{name:48} {100.0 * c / pixels:6.1f}% {mae:8.1f} {sums[name] / pixels:8.2f}")
    near = np.concatenate(near_above_r_min)
    if near.size:
        p = np.percentile(near, [5, 10, 25, 50, 75, 90])
        print("empty near, prediction above r_min (mm), percentiles 5/10/25/50/75/90:",
              " ".join(f"{v:.1f}" for v in p))


if __name__ == "__main__":
    main()
