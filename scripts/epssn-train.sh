#!/usr/bin/env bash
# Runs the PyTorch trainer (training/, docs/TRAINING.md) with the arguments given, e.g.
#   bash scripts/epssn-train.sh fit --spec weights/epssn-s.json --data DIR --out DIR --epochs 1
# The trainer is EPSSN_TRAIN (a command, split on spaces: path/to/epssn-train or
# "python -m epssn_train"), else `epssn-train` on PATH, else the venv target/venv-train, created
# on first use as training/tests/run.sh creates it (torch, then `pip install ./training`).
# `--python` instead of the trainer's arguments prints the Python that runs that trainer (for
# scripts that import epssn_train themselves).
set -euo pipefail
if [ -n "${EPSSN_TRAIN:-}" ]; then
  read -r -a trainer <<<"$EPSSN_TRAIN"
elif command -v epssn-train >/dev/null; then
  trainer=(epssn-train)
else
  root=$(cd "$(dirname "$0")/.." && pwd)
  venv=$root/target/venv-train
  if [ ! -x "$venv/bin/epssn-train" ]; then
    [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
    "$venv/bin/python" -c "import torch" 2>/dev/null || "$venv/bin/pip" install -q torch
    "$venv/bin/pip" install -q "$root/training"
  fi
  trainer=("$venv/bin/epssn-train")
fi
if [ "${1:-}" = --python ]; then
  # "python -m epssn_train" names its Python; an installed epssn-train script names it on its
  # first line (#!/path/to/python).
  case $(basename "${trainer[0]}") in
    python*) command -v "${trainer[0]}" ;;
    *) sed -n '1s/^#! *//p' "$(command -v "${trainer[0]}")" ;;
  esac
  exit
fi
exec "${trainer[@]}" "$@"
