"""Sample folders of `host-sim simulate` (docs/SIMULATOR.md; the format is the contract):
`DIR/<split>/<000000>/polar_view{k}.npy` (f32 R×B, 0..=255), `depth.npy`, `mask.npy` (f32 E×A).
Polar images are rounded and clamped to u8 on load: the firmware only sees u8 images."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def split_dir(data: Path, split: str) -> Path | None:
    p = Path(data) / split
    return p if p.is_dir() else None


def sample_dirs(d: Path) -> list[Path]:
    """Sub-folders of `d` holding `polar_view0.npy`, sorted by name."""
    return sorted(p for p in Path(d).iterdir() if (p / "polar_view0.npy").is_file())


def _load(path: Path, shape) -> np.ndarray:
    a = np.load(path, allow_pickle=False)
    if a.dtype != np.float32 or tuple(a.shape) != tuple(shape):
        raise ValueError(f"{path} is {a.dtype} {a.shape}, expected float32 {tuple(shape)}")
    return a


class Sample:
    __slots__ = ("dir", "views", "depth", "mask")

    def __init__(self, d: Path, views: int, spec):
        self.dir = Path(d)
        imgs = []
        for k in range(views):
            v = _load(self.dir / f"polar_view{k}.npy", (spec.range_bins, spec.beam_columns))
            # Half away from zero, as Rust's f32::round (exact: v − trunc(v) is exact in f32).
            t = np.trunc(v)
            r = t + np.sign(v) * (np.abs(v - t) >= 0.5)
            imgs.append(np.clip(r, 0, 255).astype(np.uint8))
        self.views = np.stack(imgs)
        self.depth = _load(self.dir / "depth.npy", (spec.rows, spec.columns))
        self.mask = _load(self.dir / "mask.npy", (spec.rows, spec.columns))


def load_dir(d: Path, views: int, spec, limit: int | None = None) -> list[Sample]:
    dirs = sample_dirs(d)
    if limit is not None:
        dirs = dirs[:limit]
    return [Sample(p, views, spec) for p in dirs]


def summary(d: Path) -> dict:
    """Scenes, seeds, views and speckle looks of a data folder (from each sample's scene.json),
    as the burn trainer's manifest records them."""
    scenes, seeds, views, looks = set(), set(), set(), set()
    dirs = sample_dirs(d) if Path(d).is_dir() else []
    for p in dirs:
        try:
            s = json.loads((p / "scene.json").read_text())
        except (OSError, ValueError):
            continue
        for key, acc in (("family", scenes), ("scene", scenes), ("seed", seeds),
                         ("speckle_looks", looks)):
            if isinstance(s.get(key), (str, int)):
                acc.add(s[key])
        if isinstance(s.get("view_rolls_deg"), list):
            views.add(len(s["view_rolls_deg"]))
    return {"dir": str(d), "samples": len(dirs), "scenes": sorted(scenes, key=str),
            "seeds": sorted(seeds, key=str), "speckle_looks": sorted(looks, key=str),
            "views": sorted(views)}
