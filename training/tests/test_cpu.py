"""Unit tests of the trainer that need no host-sim binary (CPU only)."""

from pathlib import Path

import numpy as np
import pytest
import torch

from epssn_train.device import select_device
from epssn_train.losses import lr_at, two_hot_labels
from epssn_train.model import Epssn, init_uniform
from epssn_train.spec import Spec

ROOT = Path(__file__).resolve().parents[2]


def test_device_selection():
    assert select_device("cpu", True) == "cpu"
    assert select_device("auto", False) == "cpu"
    assert select_device("auto", True) == "cuda:0"
    assert select_device("cuda", True, local_rank=1) == "cuda:1"
    with pytest.raises(RuntimeError):
        select_device("cuda", False)
    with pytest.raises(ValueError):
        select_device("tpu", True)


def test_lr_schedule_halves_at_the_fraction():
    assert lr_at(1e-3, 0.5, 4, 10) == 1e-3
    assert lr_at(1e-3, 0.5, 5, 10) == 5e-4


def test_two_hot_means_the_clamped_label_and_ends_are_one_hot():
    bins = torch.tensor([1.9 + 0.2 * i for i in range(10)], dtype=torch.float64)
    d = torch.tensor([[[1.5, 2.0, 2.37], [3.1, 3.5, 9.0]]], dtype=torch.float64)
    q = two_hot_labels(d, bins, 2.0, 3.5, ends=False)
    assert torch.allclose(q.sum(2), torch.ones_like(d))
    assert torch.allclose((q * bins.view(1, 1, -1, 1)).sum(2), d.clamp(2.0, 3.5))
    q = two_hot_labels(d, bins, 2.0, 3.5, ends=True)
    assert q[0, 0, 0, 0] == 1 and q[0, 1, -1, 2] == 1 and q[0, 1, -1, 1] == 1
    assert torch.allclose((q * bins.view(1, 1, -1, 1)).sum(2)[0, 0, 2], d[0, 0, 2])


@pytest.mark.parametrize("name", ["epssn-s.json", "epssn-p.json"])
def test_shapes_and_tensor_names_match_the_shipped_weights(name):
    spec = Spec(ROOT / "weights" / name)
    model = Epssn(spec)
    folder = {"epssn-s.json": "general", "epssn-p.json": "paper"}[name]
    from epssn_train.io import read_safetensors
    shipped = read_safetensors(ROOT / "weights" / folder / "model.safetensors")
    mine = model.to_tensors()
    assert sorted(mine) == sorted(shipped)
    for k, v in mine.items():
        assert tuple(v.shape) == tuple(shipped[k].shape), k
    model.load_tensors(shipped)
    views = [torch.zeros(1, 1, spec.range_bins, spec.beam_columns)] * 2
    d, logits = model.eval()(views)
    assert tuple(d.shape) == (1, spec.rows, spec.columns)
    assert tuple(logits.shape) == (1, 1, spec.rows, spec.depth_bins, spec.columns)


def test_warp_table_is_visible_in_the_middle_and_shifts_with_the_roll():
    spec = Spec(ROOT / "weights" / "epssn-s.json")
    col, frac, vis = spec.warp_table(1)
    mid = spec.planes // 2
    assert vis[mid].any() and not vis.all()
    assert (frac[vis] <= 1 << spec.fraction_bits).all()
    col2, _, vis2 = spec.warp_table(2)
    assert vis2.sum() < vis.sum()  # a larger roll leaves fewer rays inside the aperture


def test_a_few_steps_lower_the_loss_on_one_batch():
    spec = Spec(ROOT / "weights" / "epssn-s.json")
    torch.manual_seed(0)
    model = Epssn(spec)
    init_uniform(model, 3)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3, eps=1e-5)
    g = torch.Generator().manual_seed(1)
    views = [torch.randint(0, 256, (2, 1, spec.range_bins, spec.beam_columns), generator=g)
             .float() for _ in range(2)]
    depth = torch.full((2, spec.rows, spec.columns), 2.6)
    mask = torch.ones_like(depth)
    from epssn_train.losses import masked_l1
    losses = []
    for _ in range(8):
        d, _ = model(views)
        loss = masked_l1(d, depth, mask, spec.lam, spec.r_min, spec.r_max)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < losses[0] * 0.8, losses


@pytest.mark.parametrize("name", ["u1", "u0", "head"])
def test_subpixel_transposed_convolution_equals_pytorchs(name):
    import epssn_train.model as mm
    spec = Spec(ROOT / "weights" / "epssn-s.json")
    model = Epssn(spec).double()
    init_uniform(model, 5)
    blk = model.layers[name]
    l = next(l for l in spec.cost_net if l.name == name)
    shape = {"u1": (2, 16, 4, 16, 4), "u0": (2, 8, 8, 32, 8), "head": (2, 8, 16, 64, 16)}[name]
    x = torch.rand(*shape, dtype=torch.float64, requires_grad=True)
    y = mm._conv_transpose_subpixel(x, blk.conv, *blk.subpixel)
    ref = blk.conv(x)
    assert y.shape == ref.shape and l.kind == "conv_transpose3d"
    assert torch.allclose(y, ref, atol=1e-12)
    g = torch.rand_like(ref)
    gy = torch.autograd.grad(y, (x, blk.conv.weight), g)
    gr = torch.autograd.grad(ref, (x, blk.conv.weight), g)
    for a, b in zip(gy, gr):
        assert torch.allclose(a, b, atol=1e-10)


def _weights_folder(folder, spec, seed, views):
    from epssn_train.fit import write_model
    torch.manual_seed(seed)
    model = Epssn(spec)
    init_uniform(model, seed)
    write_model(folder, spec, model, "test")
    (folder / "manifest.json").write_text(f'{{"views": {views}, "scene": "test"}}')
    return model.to_tensors()


def test_average_writes_each_tensors_mean_and_refuses_other_specs(tmp_path):
    from epssn_train.cli import main
    from epssn_train.io import read_safetensors
    spec = Spec(ROOT / "weights" / "epssn-s.json")
    a = _weights_folder(tmp_path / "a", spec, 1, 2)
    run = tmp_path / "run"
    b = _weights_folder(run / "epochs" / "epoch-001", spec, 2, 2)
    (run / "epochs" / "epoch-001" / "manifest.json").unlink()  # fit --keep-epochs writes none
    (run / "manifest.json").write_text('{"views": 2}')
    assert main(["average", str(tmp_path / "a"), str(run / "epochs" / "epoch-001"),
                 "--out", str(tmp_path / "mean")]) == 0
    mean = read_safetensors(tmp_path / "mean" / "model.safetensors")
    assert sorted(mean) == sorted(a)
    for k in a:
        want = (a[k].detach().double() + b[k].detach().double()) / 2
        assert np.allclose(mean[k], want.numpy(), rtol=1e-6, atol=1e-7), k
    assert any(not np.allclose(mean[k], a[k].detach().numpy()) for k in a)
    assert (tmp_path / "mean" / "spec.json").read_bytes() == spec.bytes
    assert '"views": 2' in (tmp_path / "mean" / "manifest.json").read_text()

    other = Spec(ROOT / "weights" / "epssn-p.json")
    _weights_folder(tmp_path / "p", other, 3, 2)
    with pytest.raises(SystemExit, match="differs"):
        main(["average", str(tmp_path / "a"), str(tmp_path / "p"), "--out", str(tmp_path / "x")])
    _weights_folder(tmp_path / "v3", spec, 4, 3)
    with pytest.raises(SystemExit, match="different views"):
        main(["average", str(tmp_path / "a"), str(tmp_path / "v3"), "--out", str(tmp_path / "y")])
    with pytest.raises(SystemExit, match="not a weights folder"):
        main(["average", str(tmp_path / "a"), str(tmp_path / "nothing"), "--out",
              str(tmp_path / "z")])
    before = (tmp_path / "mean" / "model.safetensors").read_bytes()
    with pytest.raises(SystemExit, match="overwritten"):
        main(["average", str(tmp_path / "a"), str(tmp_path / "mean"), "--out",
              str(tmp_path / "mean")])
    with pytest.raises(SystemExit, match="needs --bn-data"):
        main(["average", str(tmp_path / "a"), str(tmp_path / "mean"), "--out",
              str(tmp_path / "w"), "--fake-quant", str(tmp_path / "a")])
    assert not any((tmp_path / d).exists() for d in ("x", "y", "z", "w"))
    assert (tmp_path / "mean" / "model.safetensors").read_bytes() == before


def test_average_measures_batch_norm_again_on_data(tmp_path):
    from epssn_train.cli import main
    from epssn_train.io import read_safetensors
    spec = Spec(ROOT / "weights" / "epssn-s.json")
    a = _weights_folder(tmp_path / "a", spec, 1, 2)
    _weights_folder(tmp_path / "b", spec, 2, 2)
    rng = np.random.default_rng(5)
    for i in range(5):  # one batch of 4 and one of 1: the mean must weigh every sample alike
        d = tmp_path / "data" / "train" / f"{i:06d}"
        d.mkdir(parents=True)
        for k in range(2):
            v = rng.integers(0, 256, (spec.range_bins, spec.beam_columns)).astype(np.float32)
            np.save(d / f"polar_view{k}.npy", v)
        np.save(d / "depth.npy", np.full((spec.rows, spec.columns), 2.5, np.float32))
        np.save(d / "mask.npy", np.zeros((spec.rows, spec.columns), np.float32))
    assert main(["average", str(tmp_path / "a"), str(tmp_path / "b"), "--out",
                 str(tmp_path / "m"), "--bn-data", str(tmp_path / "data"),
                 "--bn-batch", "4"]) == 0
    m = read_safetensors(tmp_path / "m" / "model.safetensors")
    # f0, the first layer, sees both views of every sample: its statistics are those of its
    # convolution's output over them.
    x = torch.from_numpy(np.stack([np.load(tmp_path / "data" / "train" / f"{i:06d}" /
                                           f"polar_view{k}.npy")
                                   for i in range(5) for k in range(2)]))[:, None] / 255.0
    w = torch.from_numpy(m["f0.conv.weight"]).float()
    bias = torch.from_numpy(m["f0.conv.bias"]).float()
    y = torch.nn.functional.conv2d(x, w, bias, stride=2, padding=1)
    assert np.allclose(m["f0.bn.running_mean"], y.mean((0, 2, 3)).numpy(), rtol=1e-4, atol=1e-6)
    assert not np.allclose(m["f0.bn.running_mean"], a["f0.bn.running_mean"].detach().numpy())
    assert "measured on 5 samples" in (tmp_path / "m" / "manifest.json").read_text()
