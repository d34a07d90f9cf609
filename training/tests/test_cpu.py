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
