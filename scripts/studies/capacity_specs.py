"""The capacity study's variants of EPSSN-P and its score (scripts/studies/capacity.sh).

    capacity_specs.py BASE_SPEC OUT_DIR           writes OUT_DIR/{p,wb32,n32,c16}.json
    capacity_specs.py --score NAME DIR DATA BUDGET_S   prints DIR's capacity.json

The score is the paper's MAE, as `host-sim eval` computes it (epssn_sim::metrics): per depth
map the mean over all pixels of |prediction - label clamped to [r_min, r_max]|, mm, then the
mean over the maps."""

import copy
import json
import sys
from pathlib import Path

import numpy as np


def layer(net, name):
    return next(l for l in net if l["name"] == name)


def variants(base):
    """EPSSN-P and its three wider variants, each a complete spec."""
    c16 = copy.deepcopy(base)
    c16["name"] = "EPSSN-P-C16"
    c16["features"]["channels"] *= 2
    for l in c16["feature_net"] + c16["cost_net"]:
        # The input (one u8 image) and the head's output (one logit) keep their one channel.
        l["in"] = l["in"] * 2 if l["in"] > 1 else l["in"]
        l["out"] = l["out"] * 2 if l["out"] > 1 else l["out"]

    n32 = copy.deepcopy(base)
    n32["name"] = "EPSSN-P-N32"
    n32["planes"] *= 2
    # With as many planes as elevation rows the head no longer upsamples along planes.
    head = layer(n32["cost_net"], "head")
    head["kernel"][0], head["stride"][0], head["padding"][0] = 3, 1, 1

    wb = copy.deepcopy(base)
    wb["name"] = "EPSSN-P-WB32"
    layer(wb["cost_net"], "d2")["out"] = 32
    m0 = layer(wb["cost_net"], "m0")
    m0["in"] = m0["out"] = 32
    layer(wb["cost_net"], "u1")["in"] = 32
    return {"p": base, "wb32": wb, "n32": n32, "c16": c16}


def paper_mae(pred_dir, data_dir, r_min, r_max):
    maes = []
    for p in sorted(Path(pred_dir).iterdir()):
        pred = np.load(p / "depth_float.npy").astype(np.float64)
        gt = np.clip(np.load(Path(data_dir) / p.name / "depth.npy"), np.float32(r_min),
                     np.float32(r_max)).astype(np.float64)
        maes.append(1000.0 * np.abs(pred - gt).mean())
    return float(np.mean(maes)), float(np.std(maes)), len(maes)


def cost(spec_path):
    """(multiply-accumulates of one streamed depth map: the newest view's features and the
    cost net, as the firmware computes it per map; parameters) of the spec's network, counted
    on PyTorch's layers."""
    import torch
    from epssn_train import model as epssn_model
    from epssn_train.spec import Spec

    spec = Spec(Path(spec_path))
    net = epssn_model.Epssn(spec).eval()
    features = set(net.feature_names)
    macs = [0.0]

    def hook(name):
        def count(mod, inp, out):
            k = int(np.prod(mod.kernel_size))
            if isinstance(mod, torch.nn.ConvTranspose3d):
                n = inp[0].numel() * mod.out_channels * k
            else:
                n = out.numel() * mod.in_channels * k
            # The feature net runs on both views of the batch; a streamed map computes one.
            macs[0] += n / 2 if name in features else n
        return count

    for name, blk in net.layers.items():
        blk.conv.register_forward_hook(hook(name))
    views = [torch.zeros(1, 1, spec.range_bins, spec.beam_columns) for _ in range(2)]
    subpixel = epssn_model._SUBPIXEL
    # The sub-pixel path calls conv3d on the transposed layers' weights, past their hooks.
    epssn_model._SUBPIXEL = False
    try:
        with torch.no_grad():
            net(views)
    finally:
        epssn_model._SUBPIXEL = subpixel
    return int(macs[0]), sum(p.numel() for p in net.parameters())


def score(name, d, data, budget):
    d, data = Path(d), Path(data)
    spec = json.loads((d / "fit" / "spec.json").read_text())
    r_min, r_max = spec["range_window"]["r_min_m"], spec["range_window"]["r_max_m"]
    bench = json.loads((d / "bench.json").read_text())
    manifest = json.loads((d / "fit" / "manifest.json").read_text())
    res = {"variant": name, "spec": spec["name"], "budget_s": float(budget),
           "bench_seconds_per_step": bench["seconds_per_step"], "threads": bench["threads"],
           "steps": manifest.get("steps"), "fit_wall_time_s": manifest.get("wall_time_s"),
           "final_train_loss": manifest.get("final_train_loss"),
           "final_val_loss": manifest.get("final_val_loss")}
    res["macs_per_map"], res["parameters"] = cost(d / "fit" / "spec.json")
    for split in ("train", "test"):
        m, s, n = paper_mae(d / f"pred-{split}", data / split, r_min, r_max)
        res[f"mae_{split}_mm"], res[f"mae_{split}_std_mm"], res[f"pairs_{split}"] = m, s, n
    return res


def main(argv):
    if argv and argv[0] == "--score":
        print(json.dumps(score(*argv[1:5]), indent=1))
        return 0
    base, out = json.loads(Path(argv[0]).read_text()), Path(argv[1])
    out.mkdir(parents=True, exist_ok=True)
    for name, spec in variants(base).items():
        (out / f"{name}.json").write_text(json.dumps(spec, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
