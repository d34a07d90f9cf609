"""Weights folders (`model.safetensors` with the burn trainer's tensor names, `spec.json`,
`manifest.json`), loss.csv and loss.png."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np

WEIGHTS_FILE = "model.safetensors"
SPEC_FILE = "spec.json"
BN_EPSILON = 1e-5


def read_safetensors(path: Path) -> dict:
    from safetensors.numpy import load_file
    return load_file(str(path))


def write_safetensors(path: Path, tensors: dict, meta: dict):
    from safetensors.numpy import save_file
    meta = {**{k: str(v) for k, v in meta.items()}, "bn_epsilon": f"{BN_EPSILON:e}"}
    arrays = {k: np.ascontiguousarray(v.numpy() if hasattr(v, "numpy") else v, np.float32)
              for k, v in tensors.items()}
    tmp = Path(str(path) + ".tmp")
    save_file(arrays, str(tmp), metadata=meta)
    tmp.replace(path)


def trained_views(dir: Path, default: int) -> int:
    """`views` of the folder's manifest.json (1..=3), else `default` — as `host-sim eval`."""
    try:
        j = json.loads((Path(dir) / "manifest.json").read_text())
    except (OSError, ValueError):
        return default
    v = j.get("views")
    if v is None:
        return default
    if not isinstance(v, int) or not 1 <= v <= 3:
        raise ValueError(f"{dir}/manifest.json: views {v}, the model runs 1..=3")
    return v


def write_loss_csv(path: Path, rows):
    with open(path, "w") as f:
        f.write("epoch,step,train_loss,val_loss\n")
        for r in rows:
            # Rust's spelling of a missing validation loss, which host-sim's reader parses.
            v = "NaN" if not np.isfinite(r["val_loss"]) else r["val_loss"]
            f.write(f"{r['epoch']},{r['step']},{r['train_loss']},{v}\n")


def plot_curves(path: Path, rows):
    """loss.png: matplotlib when installed, else a plain PNG drawn here (train blue, val
    orange, against the step)."""
    xs = [r["step"] for r in rows]
    tr = [r["train_loss"] for r in rows]
    va = [r["val_loss"] for r in rows]
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(8, 5))
        ax.plot(xs, tr, label="train loss")
        if any(np.isfinite(va)):
            ax.plot(xs, va, label="val loss (L1 term)")
        ax.set_xlabel("step")
        ax.set_ylabel("loss")
        ax.legend()
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return
    except ImportError:
        pass
    w, h, m = 640, 400, 30
    img = np.full((h, w, 3), 255, np.uint8)
    img[m:h - m, m] = 0
    img[h - m, m:w - m] = 0
    vals = [v for v in tr + va if np.isfinite(v)]
    if xs and vals:
        x0, x1 = min(xs), max(max(xs), min(xs) + 1)
        y0, y1 = min(vals), max(max(vals), min(vals) + 1e-9)

        def px(x, y):
            return (m + (x - x0) / (x1 - x0) * (w - 2 * m - 1),
                    h - m - (y - y0) / (y1 - y0) * (h - 2 * m - 1))

        for series, colour in ((tr, (31, 119, 180)), (va, (255, 127, 14))):
            pts = [px(x, y) for x, y in zip(xs, series) if np.isfinite(y)]
            for (ax_, ay), (bx, by) in zip(pts, pts[1:] or pts):
                n = int(max(abs(bx - ax_), abs(by - ay), 1))
                for t in np.linspace(0, 1, n + 1):
                    cx, cy = int(ax_ + (bx - ax_) * t), int(ay + (by - ay) * t)
                    img[max(cy - 1, 0):cy + 2, max(cx - 1, 0):cx + 2] = colour
    write_png(path, img)


def write_png(path: Path, rgb: np.ndarray):
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(tag, data):
        c = struct.pack(">I", len(data)) + tag + data
        return c + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    Path(path).write_bytes(png)
