"""The model spec, its grids and warp tables: a line-by-line mirror of `epssn-spec`'s
`grids.rs` and `geometry.rs` (f64 throughout, the same formulas in the same order)."""

from __future__ import annotations

import json
import math
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def find_root(start: Path) -> Path:
    """The repository root: `EPSSN_ROOT`, else the first folder above `start` (or the working
    folder) holding `data/aris-beam-widths`."""
    env = os.environ.get("EPSSN_ROOT")
    if env:
        return Path(env)
    for base in (Path(start).resolve(), Path.cwd().resolve()):
        for p in [base, *base.parents]:
            if (p / "data" / "aris-beam-widths").is_dir():
                return p
    raise FileNotFoundError(
        f"no data/aris-beam-widths above {start} or the working folder: set EPSSN_ROOT")


def load_beam_table(root: Path, name: str) -> list[float]:
    """Beam centres in degrees, beam 0 first (the CSV `beam,center_deg,left_deg,right_deg`)."""
    path = root / "data" / "aris-beam-widths" / f"{name}.csv"
    centres = []
    for i, line in enumerate(path.read_text().splitlines()):
        line = line.strip()
        if i == 0 or not line:
            continue
        f = [x.strip() for x in line.split(",")]
        if len(f) != 4 or int(f[0]) != len(centres):
            raise ValueError(f"{path}: bad line {i + 1}")
        centres.append(float(f[1]))
    if len(centres) < 2 or any(b <= a for a, b in zip(centres, centres[1:])):
        raise ValueError(f"{path}: beam centres do not strictly ascend")
    return centres


def _padded(v, fill, n=3):
    v = list(v)
    return v + [fill] * (n - len(v))


@dataclass
class Layer:
    name: str
    kind: str  # conv2d | conv3d | conv_transpose3d
    cin: int
    cout: int
    kernel: list
    stride: list
    padding: list
    output_padding: list
    batch_norm: bool
    relu: bool
    skip: str | None

    @staticmethod
    def of(j: dict) -> "Layer":
        dims = len(j["kernel"])
        return Layer(
            name=j["name"], kind=j["kind"], cin=j["in"], cout=j["out"],
            kernel=list(j["kernel"]), stride=list(j.get("stride", [1] * dims)),
            padding=list(j.get("padding", [0] * dims)),
            output_padding=list(j.get("output_padding", [0] * dims)),
            batch_norm=bool(j.get("batch_norm", False)), relu=bool(j.get("relu", False)),
            skip=j.get("skip"))


class Spec:
    """A parsed model spec file with its derived grids."""

    def __init__(self, path: Path, root: Path | None = None):
        self.path = Path(path)
        self.bytes = self.path.read_bytes()
        self.crc32 = zlib.crc32(self.bytes) & 0xFFFFFFFF
        j = json.loads(self.bytes)
        self.json = j
        self.name = j["name"]
        self.r_min = float(j["range_window"]["r_min_m"])
        self.r_max = float(j["range_window"]["r_max_m"])
        self.range_bins = int(j["input"]["range_bins"])
        self.beam_columns = int(j["input"]["beam_columns"])
        self.channels = int(j["features"]["channels"])
        self.stride = int(j["features"]["stride"])
        self.mean_channels = int(j["features"].get("mean_channels", 0))
        self.planes = int(j["planes"])
        o = j["output"]
        self.rows = int(o["elevation_rows"])
        self.columns = int(o["azimuth_columns"])
        self.depth_bins = int(o["range_bins"])
        self.end_bin_offset = int(o.get("end_bin_offset", 0))
        self.no_return_mass = float(o.get("no_return_mass", 0.0))
        self.views = int(j["baseline"]["views"])
        self.max_views = int(j["baseline"]["max_views"])
        self.roll_step_deg = float(j["baseline"]["roll_step_deg"])
        self.lever_arm = [float(x) for x in j["baseline"].get("lever_arm_m", [0, 0, 0])]
        self.fraction_bits = int(j["warp"]["fraction_bits"])
        self.feature_net = [Layer.of(l) for l in j["feature_net"]]
        self.cost_net = [Layer.of(l) for l in j["cost_net"]]
        t = j["training"]
        self.lam = float(t["lambda"])
        self.lr = float(t["lr"])
        self.lr_halved_at_fraction = float(t["lr_halved_at_fraction"])
        self.batch = int(t["batch"])
        self.root = root or find_root(self.path.parent)
        beams = load_beam_table(self.root, j["sonar"]["beam_table"])
        if len(beams) != int(j["sonar"]["beams"]):
            raise ValueError("beam count differs from the beam table")
        self._grids(beams, float(j["sonar"]["elevation_half_aperture_deg"]))

    @property
    def layers(self):
        return self.feature_net + self.cost_net

    def _grids(self, beams_deg, half_deg):
        b, s = self.beam_columns, self.stride
        if len(beams_deg) % b or self.range_bins % s or b % s:
            raise ValueError("beams / columns / stride do not divide")
        group = len(beams_deg) // b
        beam_az = [d * math.pi / 180.0 for d in beams_deg]
        input_az = [grouped(beam_az, group, k) for k in range(b)]
        self.feature_azimuths = [grouped(input_az, s, k) for k in range(b // s)]
        self.half_elevation = half_deg * math.pi / 180.0
        self.plane_elevations = [self.elevation(j, self.planes) for j in range(self.planes)]
        self.depth_bin_ranges = [self.depth_bin_weight(i) for i in range(self.depth_bins)]

    def elevation(self, j, n):
        if n < 2:
            return 0.0
        h = self.half_elevation
        return -h + 2.0 * h * j / (n - 1)

    def depth_bin_weight(self, i):
        n = self.depth_bins
        if n < 2:
            return self.r_max
        v = self.r_min + (self.r_max - self.r_min) * i / (n - 1)
        reach = self.end_bin_offset * (self.r_max - self.r_min) / (n - 1)
        return v - reach if i == 0 else v + reach if i == n - 1 else v

    def warp_table(self, k):
        """(column, fraction, visible) arrays `[plane][feature column]` of view `k`."""
        if any(abs(t) >= 1e-12 for t in self.lever_arm):
            # rolled_about_axis with a lever arm changes range: the library refuses it too.
            raise ValueError("a lever arm needs the range-dependent warp table")
        a = -(self.roll_step_deg * k) * math.pi / 180.0
        sn, cs = math.sin(a), math.cos(a)
        az, n = self.feature_azimuths, len(self.feature_azimuths)
        col = np.zeros((self.planes, n), np.int64)
        frac = np.zeros((self.planes, n), np.int64)
        vis = np.zeros((self.planes, n), bool)
        one = float(1 << self.fraction_bits)
        for j, phi in enumerate(self.plane_elevations):
            for bcol, theta in enumerate(az):
                ce = math.cos(phi)
                d = [ce * math.cos(theta), ce * math.sin(theta), math.sin(phi)]
                p = [d[0], cs * d[1] - sn * d[2], sn * d[1] + cs * d[2]]
                rng = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
                if rng == 0.0:
                    saz, sel = 0.0, 0.0
                else:
                    saz = math.atan2(p[1], p[0])
                    sel = math.asin(min(max(p[2] / rng, -1.0), 1.0))
                if abs(sel) > self.half_elevation + 1e-12:
                    continue
                fi = fractional_index(az, saz)
                if fi is None:
                    continue
                col[j, bcol] = fi[0]
                frac[j, bcol] = int(math.floor(min(max(fi[1], 0.0), 1.0) * one + 0.5))
                vis[j, bcol] = True
        return col, frac, vis


def grouped(xs, group, k):
    lo, hi = k * group, min(k * group + group, len(xs))
    if lo >= hi:
        return 0.0
    s = 0.0
    for x in xs[lo:hi]:
        s += x
    return s / (hi - lo)


def fractional_index(xs, x):
    n = len(xs)
    if n < 2 or math.isnan(x) or x < xs[0] or x > xs[n - 1]:
        return None
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if xs[mid] <= x:
            lo = mid
        else:
            hi = mid
    span = xs[lo + 1] - xs[lo]
    f = (x - xs[lo]) / span if span > 0.0 else 0.0
    return lo, min(max(f, 0.0), 1.0)
