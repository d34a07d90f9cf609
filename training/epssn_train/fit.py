"""`epssn-train fit`: the paper's recipe (masked L1, λ from the spec, Adam, lr halved at the
spec's fraction of the run) plus the burn trainer's CE and no-return terms; resumable
checkpoints with the optimizer state; data-parallel under torchrun (DistributedDataParallel,
gloo on CPU, nccl on GPUs; the global batch split across processes, batch norm synchronised)."""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from .device import device_or_exit
from .data import load_dir, split_dir, summary
from .io import (SPEC_FILE, WEIGHTS_FILE, plot_curves, read_safetensors, trained_views,
                 write_loss_csv, write_safetensors)
from .losses import lr_at, masked_l1, total_loss
from .model import Epssn, init_uniform
from .spec import Spec

# burn's Adam defaults, which the shipped models were trained with.
ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-5


class _AllReduceSum(torch.autograd.Function):
    """Sum over processes; the gradient of a sum is the sum of the gradients."""

    @staticmethod
    def forward(ctx, x):
        y = x.clone()
        dist.all_reduce(y)
        return y

    @staticmethod
    def backward(ctx, g):
        g = g.clone()
        dist.all_reduce(g)
        return g


class SyncBatchNorm(nn.Module):
    """Batch norm whose batch statistics are those of the global batch (all processes): two
    differentiable all-reduces (mean, then the squared deviations), so the result does not
    depend on how the batch is split. PyTorch's own SyncBatchNorm runs on GPUs only; this one
    runs on gloo and nccl alike. Running statistics as nn.BatchNorm (unbiased variance)."""

    def __init__(self, bn: nn.modules.batchnorm._BatchNorm):
        super().__init__()
        self.weight, self.bias = bn.weight, bn.bias
        self.register_buffer("running_mean", bn.running_mean)
        self.register_buffer("running_var", bn.running_var)
        self.eps, self.momentum = bn.eps, bn.momentum

    def forward(self, x):
        shape = [1, -1] + [1] * (x.dim() - 2)
        if not self.training:
            return ((x - self.running_mean.view(shape)) / torch.sqrt(self.running_var.view(shape)
                    + self.eps)) * self.weight.view(shape) + self.bias.view(shape)
        all_reduce = _AllReduceSum.apply
        dims = [0] + list(range(2, x.dim()))
        n_local = torch.tensor([x.numel() / x.shape[1]], dtype=x.dtype, device=x.device)
        n = dist.all_reduce(n_local) or n_local  # in place; the count needs no gradient
        mean = all_reduce(x.sum(dims)) / n
        dev = x - mean.view(shape)
        var = all_reduce((dev * dev).sum(dims)) / n
        with torch.no_grad():
            m = self.momentum
            self.running_mean.mul_(1 - m).add_(m * mean)
            self.running_var.mul_(1 - m).add_(m * var * n / (n - 1).clamp_min(1))
        return dev / torch.sqrt(var.view(shape) + self.eps) * self.weight.view(shape) \
            + self.bias.view(shape)


def _sync_bn(model: Epssn):
    for blk in model.layers.values():
        if blk.bn is not None:
            blk.bn = SyncBatchNorm(blk.bn)


class Progress:
    def __init__(self, total, start, enabled):
        self.total, self.n, self.enabled, self.t0 = total, start, enabled, time.time()
        self.bar = None
        if enabled:
            try:
                from tqdm import tqdm
                self.bar = tqdm(total=total, initial=start, unit="step", file=sys.stderr)
            except ImportError:
                pass

    def update(self, loss):
        self.n += 1
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(loss=f"{loss:.4f}")
            return
        width = 30
        done = int(width * self.n / max(self.total, 1))
        rate = (time.time() - self.t0) / max(self.n, 1)
        sys.stderr.write(f"\r[{'#' * done}{'.' * (width - done)}] {self.n}/{self.total} "
                         f"loss {loss:.4f} {rate:.2f} s/step")
        sys.stderr.flush()

    def close(self):
        if self.bar is not None:
            self.bar.close()
        elif self.enabled:
            sys.stderr.write("\n")


def _batch(samples, idx, views, dev):
    v = [np.stack([samples[i].views[k if views > 1 else 0] for i in idx])
         for k in range(max(views, 2))]
    xs = [torch.from_numpy(a.astype(np.float32))[:, None].to(dev) for a in v]
    depth = torch.from_numpy(np.stack([samples[i].depth for i in idx])).to(dev)
    mask = torch.from_numpy(np.stack([samples[i].mask for i in idx])).to(dev)
    return xs, depth, mask


def _val_loss(model, val, views, batch, dev, spec):
    if not val:
        return float("nan")
    was = model.training
    model.eval()
    s = 0.0
    with torch.no_grad():
        for i in range(0, len(val), batch):
            idx = list(range(i, min(i + batch, len(val))))
            xs, depth, mask = _batch(val, idx, views, dev)
            d, _ = model(xs)
            s += float(masked_l1(d, depth, mask, spec.lam, spec.r_min, spec.r_max)) * len(idx)
    model.train(was)
    return s / len(val)


def _activation_scales(folder: Path) -> dict:
    j = json.loads((folder / "quantisation.json").read_text())
    table = j["quantisation"]["activation_scales"]
    return {k: float(v) for k, v in table.items() if k != "input"}


def fit(args) -> int:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    dev = device_or_exit(args.device, torch.cuda.is_available(), local)
    if args.threads:
        torch.set_num_threads(args.threads)
    if world > 1:
        dist.init_process_group("nccl" if dev.startswith("cuda") else "gloo")
    if dev.startswith("cuda"):
        torch.cuda.set_device(dev)
    spec = Spec(args.spec)
    batch = args.batch or spec.batch
    if batch % world or batch // world < 2:
        raise SystemExit(f"batch {batch} does not split into {world} processes of 2 or more")
    per_rank = batch // world
    views = args.views or spec.views
    lr = args.lr if args.lr is not None else spec.lr
    train_dir = split_dir(args.data, "train") or Path(args.data)
    train = load_dir(train_dir, views, spec, args.limit)
    if len(train) < 2:
        raise SystemExit(f"{train_dir} has fewer than 2 samples")
    val_dir = split_dir(args.data, "val")
    val = load_dir(val_dir, views, spec, args.val_limit) if val_dir else []
    n = len(train)
    # A last batch of one sample would break batch norm: dropped (and, data-parallel, any
    # last batch that does not split evenly).
    spe = max(n // batch + int(world == 1 and n % batch >= 2), 1)
    total = args.steps if args.steps is not None else (args.epochs or 60) * spe
    out = Path(args.out)
    ckpt = out / "checkpoint"

    model = Epssn(spec)
    init_uniform(model, args.seed)
    if args.init_from:
        model.load_tensors(read_safetensors(Path(args.init_from) / WEIGHTS_FILE))
    fq = _activation_scales(args.fake_quant) if args.fake_quant else {}
    model.set_fake_quant(fq)
    if world > 1:
        _sync_bn(model)
    model = model.to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=lr, betas=ADAM_BETAS, eps=ADAM_EPS)
    state = {"step": 0, "history": [], "elapsed_s": 0.0, "epoch_losses": []}
    if args.resume and (ckpt / "state.pt").exists():
        saved = torch.load(ckpt / "state.pt", map_location=dev, weights_only=False)
        for key, want in (("seed", args.seed), ("batch", batch), ("views", views), ("lr", lr)):
            if saved[key] != want:
                raise SystemExit(f"checkpoint was made with {key} {saved[key]}: pass the same")
        model.load_state_dict(saved["model"])
        opt.load_state_dict(saved["optim"])
        state = saved["state"]
        if rank == 0:
            print(f"resumed at step {state['step']}", file=sys.stderr)
    net = model
    if world > 1:
        net = nn.parallel.DistributedDataParallel(
            model, device_ids=[local] if dev.startswith("cuda") else None)
    if args.compile:
        net = torch.compile(net)
    net.train()

    def save_checkpoint():
        if rank != 0:
            return
        tmp = out / "checkpoint.tmp"
        tmp.mkdir(parents=True, exist_ok=True)
        torch.save({"model": model.state_dict(), "optim": opt.state_dict(), "state": state,
                    "seed": args.seed, "batch": batch, "views": views, "lr": lr},
                   tmp / "state.pt")
        if ckpt.exists():
            shutil.rmtree(ckpt)
        tmp.replace(ckpt)

    out.mkdir(parents=True, exist_ok=True)
    started, last_ckpt = time.time(), time.time()
    elapsed0 = state["elapsed_s"]
    bar = Progress(total, state["step"], rank == 0 and not args.no_progress)
    while state["step"] < total:
        epoch, offset = divmod(state["step"], spe)
        order = np.random.default_rng(args.seed * 1000003 + epoch).permutation(n)
        for s in range(offset, spe):
            if state["step"] >= total:
                break
            gidx = order[s * batch:(s + 1) * batch]
            idx = np.array_split(gidx, world)[rank]
            xs, depth, mask = _batch(train, idx, views, dev)
            for g in opt.param_groups:
                g["lr"] = lr_at(lr, spec.lr_halved_at_fraction, state["step"], total)
            d, logits = net(xs)
            loss, _ = total_loss(d, logits, depth, mask, spec, model.bins, args.ce_weight,
                                 args.no_return_weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            value = loss.detach()
            if world > 1:
                dist.all_reduce(value)
                value /= world
            value = float(value)
            if not np.isfinite(value):
                raise SystemExit(f"loss is {value} at step {state['step']}")
            state["epoch_losses"].append(value)
            state["step"] += 1
            bar.update(value)
            state["elapsed_s"] = elapsed0 + time.time() - started
            if time.time() - last_ckpt > args.checkpoint_minutes * 60:
                save_checkpoint()
                last_ckpt = time.time()
        # End of an epoch, or of the run mid-epoch: one loss.csv row.
        if rank == 0:
            vl = _val_loss(model, val, views, per_rank, dev, spec)
            state["history"].append({"epoch": len(state["history"]) + 1, "step": state["step"],
                                     "train_loss": float(np.mean(state["epoch_losses"])),
                                     "val_loss": vl})
            if args.keep_epochs:
                epoch = state["history"][-1]["epoch"]
                write_model(out / "epochs" / f"epoch-{epoch:03d}", spec, model, args.scene)
        state["epoch_losses"] = []
        save_checkpoint()
        last_ckpt = time.time()
    bar.close()
    if rank == 0:
        write_outputs(args, spec, model, state, out, train_dir, val_dir, views, batch, lr, total,
                      len(train), len(val), fq, world)
    if world > 1:
        dist.barrier()
        dist.destroy_process_group()
    return 0


def write_model(folder: Path, spec, model, scene):
    """The model as a weights folder `host-sim eval` reads: its weights and its spec."""
    folder.mkdir(parents=True, exist_ok=True)
    write_safetensors(folder / WEIGHTS_FILE, model.to_tensors(),
                      {"spec_name": spec.name, "scene": scene})
    (folder / SPEC_FILE).write_bytes(spec.bytes)


def write_outputs(args, spec, model, state, out, train_dir, val_dir, views, batch, lr, total,
                  n_train, n_val, fq, world):
    write_model(out, spec, model, args.scene)
    write_loss_csv(out / "loss.csv", state["history"])
    plot_curves(out / "loss.png", state["history"])
    last = state["history"][-1] if state["history"] else None
    loss_text = "mean over pixels of w*|d_hat - clamp(d, r_min, r_max)|"
    if args.ce_weight > 0:
        loss_text += " + ce_weight * mean over pixels of w*CE(two-hot(clamp(d)), softmax over range bins)"
    if args.no_return_weight > 0:
        loss_text += (" + no_return_weight * mean over pixels of w*(BCE(p_last, d >= r_max) + "
                      "BCE(p_first, d <= r_min)), the two-hot of an out-of-window label on its "
                      "end bin")
    loss_text += ", w = lambda on mask pixels, 1 elsewhere"
    if fq:
        loss_text += ("; every activation rounded to its int8 grid in the forward pass "
                      "(fake_quant), straight-through gradient")
    loss_text += "; val_loss is the first term"
    manifest = {
        "trainer": f"epssn-train (PyTorch {torch.__version__})",
        "scene": args.scene,
        "spec_name": spec.name,
        "spec_file": str(args.spec),
        "spec_crc32": f"{spec.crc32:#010x}",
        "data_dir": str(args.data),
        "data": {"train": summary(train_dir), "val": summary(val_dir) if val_dir else None},
        "train_samples": n_train,
        "val_samples": n_val,
        "views": views,
        "seed": args.seed,
        "init_from": str(args.init_from) if args.init_from else None,
        "batch": batch,
        "processes": world,
        "epochs": args.epochs,
        "steps": state["step"],
        "lr": lr,
        "lr_halved_at_step": int(np.ceil(spec.lr_halved_at_fraction * total)),
        "optimizer": {"name": "Adam", "betas": list(ADAM_BETAS), "eps": ADAM_EPS},
        "loss": loss_text,
        "lambda": spec.lam,
        "ce_weight": args.ce_weight,
        "no_return_weight": args.no_return_weight,
        "fake_quant": ({"from": str(args.fake_quant), "activation_scales": fq} if fq else None),
        "final_train_loss": last["train_loss"] if last else None,
        "final_val_loss": last["val_loss"] if last else None,
        "wall_time_s": state["elapsed_s"],
        "weights": WEIGHTS_FILE,
    }
    # JSON has no NaN (no validation split): null.
    for k in ("final_train_loss", "final_val_loss"):
        if manifest[k] is not None and not np.isfinite(manifest[k]):
            manifest[k] = None
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2, allow_nan=False) + "\n")
    print(f"wrote {out}", file=sys.stderr)
