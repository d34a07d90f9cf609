"""`epssn-train average`: one weights folder whose every tensor is the mean of the same tensor in
several folders of one spec: weight averaging over a run's last epochs (`fit --keep-epochs`). On a
schedule whose validation error swings from epoch to epoch, the mean of nearby solutions reads
more steadily than any one of them. The mean of several networks' batch-norm statistics is not the
statistics of the mean network, so `--bn-data` measures them again on training samples (as
stochastic weight averaging does; docs/TRAINING.md)."""

from __future__ import annotations

import json
import sys
import zlib
from pathlib import Path

import numpy as np

from .io import SPEC_FILE, WEIGHTS_FILE, read_safetensors, write_safetensors


def run_manifest(folder: Path) -> dict | None:
    """The manifest that describes how `folder` was trained: its own, else, for an epoch folder
    `RUN/epochs/epoch-NNN` that `fit --keep-epochs` wrote, its run's."""
    own = folder / "manifest.json"
    run = folder.parent.parent / "manifest.json" if folder.parent.name == "epochs" else None
    for candidate in (own, run):
        if candidate is None:
            continue
        try:
            return json.loads(candidate.read_text())
        except (OSError, ValueError):
            continue
    return None


def mean_tensors(folders: list[Path], tensors: list[dict]) -> dict:
    """Tensor-by-tensor mean in float64; every folder must hold the same names and shapes."""
    names = set(tensors[0])
    for folder, t in zip(folders[1:], tensors[1:]):
        if set(t) != names:
            diff = sorted(names.symmetric_difference(t))
            raise ValueError(f"{folder}: tensor names differ from {folders[0]}'s: {diff}")
        for name in names:
            if t[name].shape != tensors[0][name].shape:
                raise ValueError(f"{folder}: {name} has shape {t[name].shape}, "
                                 f"{folders[0]}'s {tensors[0][name].shape}")
    return {name: np.mean([t[name].astype(np.float64) for t in tensors], axis=0)
            for name in sorted(names)}


def reestimate_batch_norm(model, samples, views: int, batch: int):
    """Every batch-norm layer's running mean and variance measured afresh over `samples`, no
    gradient, the weights untouched: each batch's statistics weighted by its samples (a short
    last batch counts for what it holds, not for a whole batch)."""
    import torch
    from .fit import _batch
    layers = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    for m in layers:
        m.reset_running_stats()
    model.train()
    seen = 0
    with torch.no_grad():
        for start in range(0, len(samples), batch):
            idx = range(start, min(start + batch, len(samples)))
            for m in layers:
                m.momentum = len(idx) / (seen + len(idx))
            xs, _, _ = _batch(samples, idx, views, "cpu")
            model(xs)
            seen += len(idx)
    model.eval()


def batch_norm_from_data(folder: Path, mean: dict, args, views: int | None):
    """`mean` with its batch-norm statistics measured on `--bn-samples` training samples of
    `--bn-data`, the activations rounded as `--fake-quant` names (as the folders were trained),
    and a line for the manifest."""
    import torch
    from .data import load_dir, split_dir
    from .fit import _activation_scales
    from .model import Epssn
    from .spec import Spec
    spec = Spec(folder / SPEC_FILE)
    views = views or spec.views
    d = split_dir(args.bn_data, "train") or Path(args.bn_data)
    samples = load_dir(d, views, spec, args.bn_samples)
    if not samples:
        raise SystemExit(f"no samples in {d}")
    model = Epssn(spec)
    model.load_tensors({k: v.astype(np.float32) for k, v in mean.items()})
    if args.fake_quant is not None:
        model.set_fake_quant(_activation_scales(args.fake_quant))
    reestimate_batch_norm(model, samples, views, args.bn_batch)
    line = (f"running statistics measured on {len(samples)} samples of {d} in batches of "
            f"{args.bn_batch}" + (f", activations rounded to {args.fake_quant}'s int8 grids"
                                  if args.fake_quant is not None else ""))
    return {k: v.detach().double().numpy() for k, v in model.to_tensors().items()}, line


def check_args(args, folders: list[Path]):
    """Refusals before anything is read or written, each with its reason."""
    if len(folders) < 2:
        raise SystemExit("average needs two weights folders or more")
    if args.fake_quant is not None and args.bn_data is None:
        raise SystemExit("--fake-quant rounds the activations batch norm is measured on: "
                         "it needs --bn-data")
    if args.bn_samples < 1 or args.bn_batch < 1:
        raise SystemExit("--bn-samples and --bn-batch must be at least 1")
    out = Path(args.out).resolve()
    if any(f.resolve() == out for f in folders):
        raise SystemExit(f"--out {args.out} is one of the folders averaged: it would be "
                         "overwritten")


def read_folder(folder: Path) -> tuple[bytes, dict]:
    """A weights folder's spec bytes and tensors, or a clear error naming what is missing."""
    try:
        return (folder / SPEC_FILE).read_bytes(), read_safetensors(folder / WEIGHTS_FILE)
    except OSError as e:
        raise SystemExit(f"{folder}: not a weights folder ({e})")
    except Exception as e:  # safetensors' own error type for a damaged file
        raise SystemExit(f"{folder}/{WEIGHTS_FILE}: unreadable ({e})")


def average(args) -> int:
    folders = [Path(f) for f in args.weights]
    check_args(args, folders)
    read = [read_folder(f) for f in folders]
    spec_bytes = read[0][0]
    for folder, (other, _) in zip(folders[1:], read[1:]):
        if other != spec_bytes:
            raise SystemExit(f"{folder}/{SPEC_FILE} differs from {folders[0]}'s: "
                             "only models of one spec average")
    try:
        mean = mean_tensors(folders, [t for _, t in read])
    except ValueError as e:
        raise SystemExit(str(e))
    manifests = [run_manifest(f) for f in folders]
    views = {m.get("views") for m in manifests if m is not None}
    if len(views) > 1:
        raise SystemExit(f"the folders were trained with different views: {sorted(views)}")
    spec = json.loads(spec_bytes)
    first = next((m for m in manifests if m is not None), {})
    trained_views = views.pop() if views else None
    bn = None
    if args.bn_data is not None:
        mean, bn = batch_norm_from_data(folders[0], mean, args, trained_views)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_safetensors(out / WEIGHTS_FILE, mean,
                      {"spec_name": spec.get("name", ""), "averaged_from": len(folders)})
    (out / SPEC_FILE).write_bytes(spec_bytes)
    manifest = {
        "trainer": "epssn-train average",
        "scene": first.get("scene"),
        "spec_name": spec.get("name"),
        "spec_crc32": f"{zlib.crc32(spec_bytes):#010x}",
        "views": trained_views,
        # host-sim reads the training data's speckle looks from here (pings per view).
        "data": first.get("data"),
        "averaged_from": [str(f) for f in folders],
        "batch_norm": bn or "the mean of the folders' running statistics",
        "weights": WEIGHTS_FILE,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    print(f"wrote {out}: the mean of {len(folders)} folders", file=sys.stderr)
    return 0
