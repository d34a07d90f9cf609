"""Which device a process trains on: the one rule `fit`, `predict` and `bench` share."""

from __future__ import annotations


def select_device(requested: str, cuda_available: bool, local_rank: int = 0) -> str:
    """`cpu`, `cuda` (refused without a GPU) or `auto` (cuda when present). Under torchrun each
    process takes the GPU of its local rank."""
    if requested not in ("cpu", "cuda", "auto"):
        raise ValueError(f"--device {requested}: cpu, cuda or auto")
    if requested == "cpu" or (requested == "auto" and not cuda_available):
        return "cpu"
    if not cuda_available:
        raise RuntimeError("--device cuda: no CUDA device is visible to PyTorch")
    return f"cuda:{local_rank}"


def device_or_exit(requested: str, cuda_available: bool, local_rank: int = 0) -> str:
    """select_device, its refusal as a one-line exit."""
    try:
        return select_device(requested, cuda_available, local_rank)
    except (RuntimeError, ValueError) as e:
        raise SystemExit(f"epssn-train: {e}")
