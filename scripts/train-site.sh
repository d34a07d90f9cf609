#!/usr/bin/env bash
# Trains a model for one site (the paper's artificial protocol: one fixed scene, pairs at random
# poses throughout it) into WEIGHTS, starting from the general model, and writes its held-out
# tables beside the general model's on the same test poses.
#   bash scripts/train-site.sh SITE_MESH TRAIN_PAIRS TEST_PAIRS EPOCHS [DATA_ROOT]
# e.g. bash scripts/train-site.sh data/sites/tank.stl 4000 2000 8 out/site-tank
# Training poses are drawn with seed 1, test poses with seed 2 and validation poses with seed 3
# (the simulator also mixes the split tag into each sample's seed), so no test pose is trained on.
# WEIGHTS (default weights/site-tank), INIT_FROM (default weights/general), LR (default 2.5e-4,
# a fine-tune's rate), CE_WEIGHT (default 0.02) and NO_RETURN_WEIGHT (default 0.1) as in
# train-general.sh; REGION=FILE draws the poses from a region file (docs/SITES.md);
# SIM_PARAMS=FILE simulates with `simulate --params FILE` (e.g. a noise model from
# `fit-sensor`). HOST_SIM=path/to/host-sim runs a prebuilt binary for simulate, quantise and eval;
# training is `epssn-train fit` (EPSSN_TRAIN=path/to/epssn-train, else the venv target/venv-train:
# scripts/epssn-train.sh), on the spec weights/epssn-s.json (SPEC=... for another).
# An interrupted run continues with the same command (--resume).
set -euo pipefail
site=$1 train_n=$2 test_n=$3 epochs=$4 root=${5:-out/site-tank}
weights=${WEIGHTS:-weights/site-tank} init=${INIT_FROM:-weights/general} lr=${LR:-2.5e-4}
ce=${CE_WEIGHT:-0.02} nr=${NO_RETURN_WEIGHT:-0.1} val_n=${VAL_PAIRS:-100}
spec=${SPEC:-weights/epssn-s.json}
region=(${REGION:+--region "$REGION"})
sim_params=(${SIM_PARAMS:+--params "$SIM_PARAMS"})
hs=(${HOST_SIM:-cargo run --release -q -p host-sim --})
cd "$(dirname "$0")/.."
have() { [ -d "$1/$(printf %06d $(($2 - 1)))" ]; }
simulate() { # SPLIT PAIRS SEED OUT
  have "$4/$1" "$2" ||
    "${hs[@]}" simulate --site "$site" --split "$1" --pairs "$2" --seed "$3" --out "$4" --no-preview \
      "${region[@]}" "${sim_params[@]}"
}
simulate train "$train_n" 1 "$root"
simulate test "$val_n" 3 "$root-val"
# fit reads DATA/val/ for its validation loss: a link to the validation poses.
ln -sfn "$(realpath "$root-val/test")" "$root/val"
bash scripts/epssn-train.sh fit --scene site --spec "$spec" --data "$root" --epochs "$epochs" --batch 16 --seed 1 \
  --val-limit "$val_n" --resume --out "$weights" --init-from "$init" --lr "$lr" \
  --ce-weight "$ce" --no-return-weight "$nr"
simulate test "$test_n" 2 "$root"
"${hs[@]}" quantise --weights "$weights" --calib "$root" --calibration-samples 256 --percentile 99.99 \
  --search --search-passes 3
"${hs[@]}" eval --weights "$weights" --data "$root" --json --int8 >"$weights/eval-site.json"
"${hs[@]}" eval --weights "$init" --data "$root" --json --int8 >"$weights/eval-site-$(basename "$init").json"
