"""How far a model's first range bin sits below its second on the rays labelled r_min (the ground
truth met the scene nearer than the window): the logit gap that decides whether the soft-argmax
can read r_min at all (docs/studies/table-one.md, "The first bin, trained directly").

    "$(bash scripts/epssn-train.sh --python)" scripts/studies/first-bin-logits.py \\
        --data DATA/test --limit 8 WEIGHTS...

The first bin stands for r_min − K·step (`end_bin_offset` K), the second for r_min + step, so a
near ray reads r_min when the first holds 1/(K+1) of their two masses: a gap of ln K (1.39 for
K = 4). Float logits, as `epssn-train predict` computes them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "training"))

import torch  # noqa: E402

from epssn_train.cli import _model  # noqa: E402
from epssn_train.data import load_dir  # noqa: E402


def near_ray_logits(weights: Path, data: Path, limit: int) -> tuple[np.ndarray, int]:
    """[n][R] logits of every ray labelled at or before r_min in the first `limit` samples, and
    the spec's end-bin offset K."""
    spec, model, _ = _model(weights / "spec.json", weights)
    model = model.double().eval()
    rows = []
    with torch.no_grad():
        for s in load_dir(data, 2, spec, limit):
            views = [torch.from_numpy(v.astype(np.float64))[None, None] for v in s.views]
            _, logits = model(views)  # [1][1][E][R][A]
            near = torch.from_numpy(s.depth <= spec.r_min)
            rows.append(logits[0, 0].permute(0, 2, 1)[near].numpy())
    return np.concatenate(rows), spec.end_bin_offset


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("weights", nargs="+", type=Path)
    p.add_argument("--data", required=True, type=Path)
    p.add_argument("--limit", type=int, default=8)
    args = p.parse_args()
    print("model: near rays; second-minus-first logit, percentiles 5/50/95; "
          "share of near rays whose first bin holds >= 1/(K+1) of the two")
    for w in args.weights:
        logits, k = near_ray_logits(w, args.data, args.limit)
        gap = logits[:, 1] - logits[:, 0]
        reach = float(np.mean(gap <= np.log(max(k, 1))))
        pct = " / ".join(f"{v:.1f}" for v in np.percentile(gap, [5, 50, 95]))
        print(f"{w}: {len(gap)}; {pct}; {100 * reach:.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
