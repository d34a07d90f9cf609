#!/usr/bin/env bash
# Runs the PyTorch trainer (training/, docs/TRAINING.md) with the arguments given, e.g.
#   bash scripts/epssn-train.sh fit --spec weights/epssn-s.json --data DIR --out DIR --epochs 1
# The trainer is EPSSN_TRAIN (a command, split on spaces: path/to/epssn-train or
# "python -m epssn_train"), else `epssn-train` on PATH, else the venv target/venv-train, created
# on first use as training/tests/run.sh creates it (torch, then `pip install ./training`).
set -euo pipefail
if [ -n "${EPSSN_TRAIN:-}" ]; then
  read -r -a trainer <<<"$EPSSN_TRAIN"
  exec "${trainer[@]}" "$@"
fi
if command -v epssn-train >/dev/null; then
  exec epssn-train "$@"
fi
root=$(cd "$(dirname "$0")/.." && pwd)
venv=$root/target/venv-train
if [ ! -x "$venv/bin/epssn-train" ]; then
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
  "$venv/bin/python" -c "import torch" 2>/dev/null || "$venv/bin/pip" install -q torch
  "$venv/bin/pip" install -q "$root/training"
fi
exec "$venv/bin/epssn-train" "$@"
