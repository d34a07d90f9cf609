#!/usr/bin/env python3
"""The five cargo workspaces agree on every registry crate they share.

A crate that two lock files both hold at the same major version (the same semver-compatible
line, e.g. fixed 1.x, syn 2.x) must be at the same version in both: the SIL compares the host
library with the firmware bit for bit, so both must be built from the same sources. Versions of
different semver lines of one crate (syn 1 and syn 2, pulled in by different dependents) may
coexist. Exits 1 and lists the disagreements; with --fix, prints the `cargo update --precise`
commands that move each lock to the newest version any of them holds.
"""
import sys
import tomllib
from collections import defaultdict
from pathlib import Path

LOCKS = ["Cargo.lock", "boards/mps2-an500/Cargo.lock", "qemu-check/Cargo.lock",
         "boards/stm32h743/Cargo.lock", "boards/mps3-an547/Cargo.lock", "fuzz/Cargo.lock"]


def line(version: str) -> str:
    """The semver-compatible line of a version: 1.31.0 -> 1, 0.7.1 -> 0.7, 0.0.3 -> 0.0.3."""
    parts = version.split("+")[0].split("-")[0].split(".")
    if parts[0] != "0":
        return parts[0]
    if len(parts) > 1 and parts[1] != "0":
        return "0." + parts[1]
    return ".".join(parts[:3])


def key(version: str):
    return tuple(int(p) if p.isdigit() else 0 for p in version.split("+")[0].split("-")[0].split("."))


def main() -> int:
    root = Path(__file__).resolve().parent.parent
    seen = defaultdict(lambda: defaultdict(set))  # (name, line) -> version -> locks
    for lock in LOCKS:
        data = tomllib.loads((root / lock).read_text())
        for p in data.get("package", []):
            if p.get("source", "").startswith("registry+"):
                seen[(p["name"], line(p["version"]))][p["version"]].add(lock)
    bad = {k: v for k, v in sorted(seen.items()) if len(v) > 1}
    for (name, _), versions in bad.items():
        where = "; ".join(f"{v}: {', '.join(sorted(l))}" for v, l in sorted(versions.items(), key=lambda kv: key(kv[0])))
        print(f"{name}: {where}")
        if "--fix" in sys.argv:
            newest = max(versions, key=key)
            for v, locks in versions.items():
                if v != newest:
                    for l in sorted(locks):
                        d = str(Path(l).parent)
                        print(f"  (cd {d} && cargo update -p {name}@{v} --precise {newest})")
    if bad:
        print(f"{len(bad)} crate(s) at different versions across the lock files")
        return 1
    print(f"{len(LOCKS)} lock files agree on every shared crate ({len(seen)} crate lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
