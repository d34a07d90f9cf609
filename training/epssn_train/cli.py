"""`epssn-train`: fit, predict, bench, average (docs/TRAINING.md)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from .device import device_or_exit


def tune_malloc() -> bool:
    """glibc hands every large freed tensor back to the kernel and faults it in again on the
    next step; raising its thresholds (what scripts/train-general.sh set for the burn trainer
    with GLIBC_TUNABLES up to commit 5b1029e) keeps them: measured 1.3-1.6x per CPU step. mallopt at run time does
    the same where GLIBC_TUNABLES is unset. False where this is not glibc."""
    if os.environ.get("GLIBC_TUNABLES") or not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3
        ok = libc.mallopt(m_mmap_threshold, 32 << 20)
        ok &= libc.mallopt(m_trim_threshold, 1 << 30)
        ok &= libc.mallopt(m_top_pad, 256 << 20)
        return bool(ok)
    except (OSError, AttributeError):
        return False


def _model(spec_path, weights_dir=None):
    import torch
    from .io import SPEC_FILE, WEIGHTS_FILE, read_safetensors
    from .model import Epssn
    from .spec import Spec
    spec = Spec(Path(spec_path))
    model = Epssn(spec)
    if weights_dir is not None:
        model.load_tensors(read_safetensors(Path(weights_dir) / WEIGHTS_FILE))
    return spec, model, torch


def predict(args) -> int:
    from .data import load_dir, split_dir
    from .io import SPEC_FILE, trained_views
    spec, model, torch = _model(Path(args.weights) / SPEC_FILE, args.weights)
    views = args.views or trained_views(args.weights, spec.views)
    if not 1 <= views <= 3:
        raise SystemExit("--views must be 1, 2 or 3")
    d = split_dir(args.data, "test") or Path(args.data)
    samples = load_dir(d, views, spec, args.limit)
    if not samples:
        raise SystemExit(f"no samples in {d}")
    dtype = torch.float64 if args.dtype == "float64" else torch.float32
    model = model.to(dtype).eval()
    out = Path(args.out)
    for s in samples:
        v = s.views if views > 1 else np.stack([s.views[0], s.views[0]])
        xs = [torch.from_numpy(x.astype(np.float64)).to(dtype)[None, None] for x in v]
        depth = model.depth(xs)[0].numpy().astype(np.float32)
        (out / s.dir.name).mkdir(parents=True, exist_ok=True)
        np.save(out / s.dir.name / "depth_float.npy", depth)
    print(f"wrote {len(samples)} depth maps to {out}", file=sys.stderr)
    return 0


def bench(args) -> int:
    import torch
    from .losses import total_loss
    from .model import Epssn, init_uniform
    from .spec import Spec
    if args.threads:
        torch.set_num_threads(args.threads)
    spec = Spec(Path(args.spec))
    dev = device_or_exit(args.device, torch.cuda.is_available())
    model = Epssn(spec, channels_last=args.channels_last)
    init_uniform(model, 1)
    model = model.to(dev).train()
    opt = torch.optim.Adam(model.parameters(), lr=spec.lr, eps=1e-5)
    net = torch.compile(model) if args.compile else model
    g = torch.Generator().manual_seed(0)
    b = args.batch
    views = [torch.randint(0, 256, (b, 1, spec.range_bins, spec.beam_columns), generator=g)
             .float().to(dev) for _ in range(spec.views)]
    depth = (spec.r_min + torch.rand(b, spec.rows, spec.columns, generator=g)
             * (spec.r_max - spec.r_min + 0.5)).to(dev)
    mask = (depth < spec.r_max).float()

    def step():
        opt.zero_grad(set_to_none=True)
        d, logits = net(views)
        loss, _ = total_loss(d, logits, depth, mask, spec, model.bins, args.ce_weight,
                             args.no_return_weight)
        loss.backward()
        opt.step()
        if dev.startswith("cuda"):
            torch.cuda.synchronize()

    step()  # warm-up: allocator and kernels (and the compilation with --compile)
    if args.compile:
        step()
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(args.steps):
        step()
    sps = (time.perf_counter() - t0) / max(args.steps, 1)
    # CPU seconds of all threads: on a shared machine less sensitive to others' load.
    cpu = (time.process_time() - c0) / max(args.steps, 1)
    res = {"seconds_per_step": sps, "batch": b, "threads": torch.get_num_threads(),
           "cpu_seconds_per_step": cpu, "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
           "spec": spec.name, "device": dev, "steps": args.steps, "compiled": args.compile,
           "torch": torch.__version__}
    print(json.dumps(res) if args.json else
          f"{spec.name}: {sps:.3f} s per batch-{b} step on {dev}, {res['threads']} threads")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="epssn-train", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)

    f = sub.add_parser("fit", help="train a float EPSSN on `host-sim simulate` data")
    f.add_argument("--spec", required=True, type=Path, help="model spec JSON (weights/epssn-s.json)")
    f.add_argument("--data", required=True, type=Path, help="data folder (train/ and val/ splits)")
    f.add_argument("--out", required=True, type=Path, help="weights folder to write")
    g = f.add_mutually_exclusive_group()
    g.add_argument("--steps", type=int, help="optimizer steps in all")
    g.add_argument("--epochs", type=int, help="epochs (default 60, as `host-sim train`)")
    f.add_argument("--init-from", type=Path, help="start from this weights folder's model")
    f.add_argument("--resume", action="store_true", help="continue OUT/checkpoint")
    f.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    f.add_argument("--batch", type=int, help="global batch (default: the spec's, 16)")
    f.add_argument("--views", type=int, help="views fed (1 = reference as its own source)")
    f.add_argument("--seed", type=int, default=1)
    f.add_argument("--lr", type=float, help="learning rate (default: the spec's)")
    f.add_argument("--ce-weight", type=float, default=0.0)
    f.add_argument("--no-return-weight", type=float, default=0.0)
    f.add_argument("--fake-quant", type=Path,
                   help="quantised folder whose activation scales training rounds to")
    f.add_argument("--limit", type=int, help="use at most this many training samples")
    f.add_argument("--val-limit", type=int, default=200)
    f.add_argument("--checkpoint-minutes", type=float, default=5.0)
    f.add_argument("--keep-epochs", action="store_true",
                   help="also write each epoch's model to OUT/epochs/epoch-NNN/, a weights "
                        "folder `host-sim eval` reads, to choose an epoch on validation")
    f.add_argument("--threads", type=int, help="torch CPU threads")
    f.add_argument("--scene", default="general", help="name recorded in the manifest")
    f.add_argument("--no-progress", action="store_true")
    f.add_argument("--compile", action="store_true",
                   help="torch.compile the model: a minute or more first, then faster steps")

    pr = sub.add_parser("predict", help="float depth maps of every sample folder")
    pr.add_argument("--weights", required=True, type=Path)
    pr.add_argument("--data", required=True, type=Path)
    pr.add_argument("--out", required=True, type=Path)
    pr.add_argument("--views", type=int)
    pr.add_argument("--limit", type=int)
    pr.add_argument("--dtype", choices=["float64", "float32"], default="float64",
                    help="float64 (default) follows the f64 reference to ~1e-9 m")

    b = sub.add_parser("bench", help="seconds per training step on random batches")
    b.add_argument("--spec", required=True, type=Path)
    b.add_argument("--steps", type=int, default=5)
    b.add_argument("--batch", type=int, default=16)
    b.add_argument("--json", action="store_true")
    b.add_argument("--threads", type=int)
    b.add_argument("--device", default="cpu")
    b.add_argument("--compile", action="store_true",
                   help="torch.compile the model (a minute or more to compile, not timed)")
    b.add_argument("--no-malloc-tuning", action="store_true",
                   help="leave glibc's allocator thresholds as they are (for comparison)")
    b.add_argument("--channels-last", action="store_true",
                   help="channels-last activations (oneDNN 3D convolutions) for comparison")
    b.add_argument("--ce-weight", type=float, default=0.02)
    b.add_argument("--no-return-weight", type=float, default=0.7)

    a = sub.add_parser("average", help="the tensor-by-tensor mean of weights folders of one spec")
    a.add_argument("weights", nargs="+", type=Path,
                   help="weights folders, e.g. a run's epochs/epoch-NNN kept by fit --keep-epochs")
    a.add_argument("--out", required=True, type=Path)
    a.add_argument("--bn-data", type=Path,
                   help="measure batch norm's running statistics again on this data's training "
                        "samples (else they are the folders' mean)")
    a.add_argument("--bn-samples", type=int, default=512)
    a.add_argument("--bn-batch", type=int, default=16)
    a.add_argument("--fake-quant", type=Path,
                   help="with --bn-data: round activations to this quantised folder's scales, "
                        "as a quantisation-aware run trained")
    a.add_argument("--threads", type=int, help="torch CPU threads")

    args = p.parse_args(argv)
    # Before torch loads its OpenMP runtime: idle threads sleep rather than spin. On a machine
    # whose cores other work shares, spinning made a 2-thread EPSSN-S step 3-4x slower
    # (1.2-1.8 s against 0.38-0.40 s, docs/TRAINING.md). OMP_WAIT_POLICY=ACTIVE restores it.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    try:
        import torch  # noqa: F401
    except ImportError:
        print("epssn-train needs PyTorch: pip install torch (docs/TRAINING.md)", file=sys.stderr)
        return 2
    if args.cmd in ("fit", "bench") and not getattr(args, "no_malloc_tuning", False):
        tune_malloc()
    if args.cmd == "predict":
        return predict(args)
    if args.cmd == "bench":
        return bench(args)
    if args.cmd == "average":
        if args.threads:
            torch.set_num_threads(args.threads)
        from .average import average
        return average(args)
    from .fit import fit
    return fit(args)
