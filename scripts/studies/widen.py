"""Grows an EPSSN-P weights folder into EPSSN-PW's wider bottleneck (weights/epssn-pw.json: d2,
m0 and u1 at 32 channels instead of 16) without changing what the network computes, so that a
fit from it (`epssn-train fit --spec weights/epssn-pw.json --init-from OUT`) starts where the
EPSSN-P model ended and only the extra channels are new.

    "$(bash scripts/epssn-train.sh --python)" scripts/studies/widen.py weights/epssn-p-terrain OUT

(the trainer's Python: it imports torch and epssn_train).

The old channels keep their weights; each new channel of d2 and m0 gets small random weights
(seed 0), zero bias and batch norm's identity; every weight that reads a new channel (m0's and
u1's inputs 16..32) is zero, so the new channels change nothing until training moves those
weights off zero (net2net's function-preserving widening). Prints the largest difference of the
two networks' outputs on random input as the check.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "training"))

from epssn_train.io import read_safetensors, write_safetensors  # noqa: E402

WIDE_SPEC = ROOT / "weights" / "epssn-pw.json"


def grow(t: np.ndarray, shape: tuple, rng: np.random.Generator, fan_in: int) -> np.ndarray:
    """`t` in the leading corner of a tensor of `shape`; the rest random at He scale / 10."""
    out = rng.normal(0.0, 0.1 * np.sqrt(2.0 / fan_in), shape).astype(np.float32)
    out[tuple(slice(0, n) for n in t.shape)] = t
    return out


def widen(narrow: dict, wide_shapes: dict) -> dict:
    rng = np.random.default_rng(0)
    out = {}
    for name, t in narrow.items():
        shape = wide_shapes[name]
        if t.shape == shape:
            out[name] = t
            continue
        layer, kind = name.split(".", 1)
        if kind == "conv.weight":
            # d2's and m0's (out, in, ...) layout; u1's new part is all zeroed just below.
            w = grow(t, shape, rng, fan_in=int(np.prod(shape[1:])))
            # Inputs that come from a new channel read zero: m0's (out, in, ...) and u1's
            # transposed (in, out, ...) layouts.
            if layer == "m0":
                w[:, t.shape[1]:] = 0.0
            if layer == "u1":
                w[t.shape[0]:] = 0.0
            out[name] = w
        else:
            fill = {"bn.gamma": 1.0, "bn.running_var": 1.0}.get(kind, 0.0)
            w = np.full(shape, fill, np.float32)
            w[: t.shape[0]] = t
            out[name] = w
    return out


def wide_shapes(narrow: dict, spec: dict) -> dict:
    """Each tensor's shape in the wide spec: channel counts from its layer's `in` / `out`."""
    layers = {layer["name"]: layer for layer in spec["feature_net"] + spec["cost_net"]}
    shapes = {}
    for name, t in narrow.items():
        layer, kind = name.split(".", 1)
        spec_layer = layers.get(layer)
        if spec_layer is None:
            shapes[name] = t.shape
        elif kind == "conv.weight":
            lead = (spec_layer["in"], spec_layer["out"]) if spec_layer["kind"] == "conv_transpose3d" \
                else (spec_layer["out"], spec_layer["in"])
            shapes[name] = lead + t.shape[2:]
        else:
            shapes[name] = (spec_layer["out"],)
    return shapes


def main() -> None:
    src, dst = Path(sys.argv[1]), Path(sys.argv[2])
    narrow = read_safetensors(src / "model.safetensors")
    spec = json.loads(WIDE_SPEC.read_text())
    wide = widen(narrow, wide_shapes(narrow, spec))
    dst.mkdir(parents=True, exist_ok=True)
    write_safetensors(dst / "model.safetensors", wide, {"widened_from": src})
    # Only the weights are what `fit --init-from` reads; the spec names their shapes. The narrow
    # model's manifest is not copied: it describes another spec's training.
    shutil.copy(WIDE_SPEC, dst / "spec.json")
    check(src, dst)


def check(src: Path, dst: Path) -> None:
    """Both networks (eval mode, float64) on the same random views: the depth maps must agree."""
    import torch
    from epssn_train.model import Epssn
    from epssn_train.spec import Spec

    depths = []
    torch.manual_seed(0)
    for folder, spec_path in ((src, ROOT / "weights" / "epssn-p.json"), (dst, WIDE_SPEC)):
        spec = Spec(spec_path)
        net = Epssn(spec)
        net.load_tensors(read_safetensors(folder / "model.safetensors"))
        net = net.to(torch.float64).eval()
        if not depths:
            shape = (1, 1, spec.range_bins, spec.beam_columns)
            views = [torch.randint(0, 256, shape).to(torch.float64) for _ in range(2)]
        with torch.no_grad():
            depths.append(net.depth(views))
    diff = float((depths[0] - depths[1]).abs().max())
    print(f"wrote {dst}: the widened network reads the narrow one's depth to {diff:.3g} m")
    if not diff < 1e-9:
        raise SystemExit("the widened network computes something else")


if __name__ == "__main__":
    main()
