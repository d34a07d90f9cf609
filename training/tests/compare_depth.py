"""Largest |Δ| between two folders of `<sample>/depth_float.npy` (float32 metres): exits 1 when
a sample is missing on either side, a shape differs, or any pixel differs by more than
`--max-mm` millimetres."""

import argparse
import sys
from pathlib import Path

import numpy as np


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    p.add_argument("--max-mm", type=float, default=0.1)
    p.add_argument("--label", default="")
    args = p.parse_args()
    names = sorted(d.name for d in args.a.iterdir() if (d / "depth_float.npy").is_file())
    other = sorted(d.name for d in args.b.iterdir() if (d / "depth_float.npy").is_file())
    if not names or names != other:
        print(f"{args.label}: samples differ: {names} vs {other}")
        return 1
    worst = 0.0
    for n in names:
        x = np.load(args.a / n / "depth_float.npy")
        y = np.load(args.b / n / "depth_float.npy")
        if x.shape != y.shape or x.dtype != np.float32 or y.dtype != np.float32:
            print(f"{args.label}: {n}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}")
            return 1
        worst = max(worst, float(np.abs(x.astype(np.float64) - y).max()) * 1000.0)
    ok = worst <= args.max_mm
    print(f"{args.label}: {len(names)} maps, max |delta| {worst:.6f} mm "
          f"({'within' if ok else 'OVER'} {args.max_mm} mm)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
