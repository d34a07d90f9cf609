#!/usr/bin/env bash
# The PyTorch trainer's check (one step of scripts/test-all.sh, docs/TRAINING.md):
#   1. a venv under target/ with torch and `pip install ./training` (install time printed);
#   2. its unit tests (CPU);
#   3. the two float networks agree: `epssn-train predict` against `host-sim eval
#      --save-depth` on freshly simulated samples, max |delta| <= 0.1 mm at every pixel, for
#      EPSSN-S with 2 and 3 views (weights/general, weights/general-3view) and EPSSN-P
#      (weights/paper, host-sim built with EPSSN_SPEC in target/epssn-p);
#   4. 10 data-parallel steps (torchrun, 2 processes, gloo) lower the loss and write a folder
#      that `host-sim quantise` and `host-sim eval` take.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=${EPSSN_TRAIN_VENV:-target/venv-train}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

start=$SECONDS
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
if ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
    t=$SECONDS
    "$venv/bin/pip" install -q torch
    echo "torch installed in $((SECONDS - t)) s, venv $(du -sh "$venv" | cut -f1)"
fi
"$venv/bin/pip" install -q ./training pytest
py="$venv/bin/python"

"$py" -m pytest -q training/tests

# HOST_SIM / HOST_SIM_P name prebuilt binaries (EPSSN-S's, EPSSN-P's); else they are built.
hs=${HOST_SIM:-}
if [ -z "$hs" ]; then
    cargo build -q -p host-sim
    hs="$(cargo metadata --format-version 1 --no-deps | sed -n 's/.*"target_directory":"\([^"]*\)".*/\1/p')/debug/host-sim"
fi
hs_p=${HOST_SIM_P:-}
if [ -z "$hs_p" ]; then
    EPSSN_SPEC=weights/epssn-p.json cargo build -q -p host-sim --target-dir target/epssn-p
    hs_p=target/epssn-p/debug/host-sim
fi

agree() { # label host-sim weights data
    "$2" eval --weights "$3" --data "$4" --save-depth "$tmp/$1-rust" > /dev/null
    "$venv/bin/epssn-train" predict --weights "$3" --data "$4" --out "$tmp/$1-torch" 2> /dev/null
    "$py" training/tests/compare_depth.py "$tmp/$1-rust" "$tmp/$1-torch" --max-mm 0.1 --label "$1"
}
# Seeds no shipped model was trained or validated on.
"$hs" simulate --scene artificial --pairs 2 --seed 91001 --split test --no-preview --out "$tmp/s2" > /dev/null
"$hs" simulate --scene terrain --pairs 2 --seed 91003 --split test --views 3 --no-preview --out "$tmp/s3" > /dev/null
"$hs_p" simulate --scene artificial --pairs 2 --seed 91004 --split test --no-preview --out "$tmp/p2" > /dev/null
agree "EPSSN-S 2 views" "$hs" weights/general "$tmp/s2"
agree "EPSSN-S 3 views" "$hs" weights/general-3view "$tmp/s3"
agree "EPSSN-P 2 views" "$hs_p" weights/paper "$tmp/p2"

"$hs" simulate --scene sphere --pairs 16 --seed 91005 --split train --no-preview --out "$tmp/fit" > /dev/null
OMP_NUM_THREADS=1 "$venv/bin/torchrun" --standalone --nproc_per_node 2 -m epssn_train fit \
    --spec weights/epssn-s.json --data "$tmp/fit" --out "$tmp/ddp" --steps 10 --device cpu \
    --keep-epochs --no-progress 2> "$tmp/ddp.log" || { cat "$tmp/ddp.log"; exit 1; }
"$py" - "$tmp/ddp/loss.csv" <<'PY'
import sys
rows = [l.split(",") for l in open(sys.argv[1]).read().split()[1:]]
first, last = float(rows[0][2]), float(rows[-1][2])
print(f"torchrun 2 processes, {len(rows)} steps: loss {first:.4f} -> {last:.4f}")
sys.exit(0 if last < first else 1)
PY
# One step per epoch here: ten kept epochs, the last one's tensors those of the model the run
# wrote (the files' metadata order varies).
"$py" - "$tmp/ddp" <<'PY'
import sys
from pathlib import Path
from safetensors.numpy import load_file
out = Path(sys.argv[1])
kept = sorted(p.name for p in (out / "epochs").iterdir())
last, final = load_file(out / "epochs/epoch-010/model.safetensors"), load_file(out / "model.safetensors")
same = last.keys() == final.keys() and all((last[k] == final[k]).all() for k in final)
print(f"fit --keep-epochs: {len(kept)} epochs kept, the last equal to the model: {same}")
sys.exit(0 if kept == [f"epoch-{e:03d}" for e in range(1, 11)] and same else 1)
PY
"$hs" eval --weights "$tmp/ddp/epochs/epoch-005" --data "$tmp/s2" > /dev/null
"$hs" quantise --weights "$tmp/ddp" --calib "$tmp/fit" --calibration-samples 4 > /dev/null
"$hs" eval --weights "$tmp/ddp" --data "$tmp/s2" | tail -1
echo "trainer check $((SECONDS - start)) s"
