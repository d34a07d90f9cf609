#!/usr/bin/env bash
# Reproduces one scene's trained and quantised weights in weights/<scene>/ and its held-out table.
#   bash scripts/train-scene.sh SCENE TRAIN_SAMPLES TEST_SAMPLES EPOCHS [TEST_VIEWS] [DATA_ROOT]
# HOST_SIM=path/to/host-sim runs a prebuilt binary for simulate, quantise and eval (so editing the
# tree does not rebuild mid-run); training is `epssn-train fit` (EPSSN_TRAIN=path/to/epssn-train,
# else the venv target/venv-train: scripts/epssn-train.sh).
# Data are simulated with seed 1 into DATA_ROOT/<scene>/{train,test}; training never sees test/,
# calibration uses 64 training samples. Training is seeded (--seed 1); an interrupted training
# continues with --resume.
set -euo pipefail
scene=$1 train_n=$2 test_n=$3 epochs=$4 test_views=${5:-2} root=${6:-out/epssn-data}
data=$root/$scene
hs=(${HOST_SIM:-cargo run --release -q -p host-sim --})
cd "$(dirname "$0")/.."
[ -d "$data/train/$(printf %06d $((train_n - 1)))" ] ||
  "${hs[@]}" simulate --scene "$scene" --split train --pairs "$train_n" --seed 1 --out "$data" --no-preview
[ -d "$data/test/$(printf %06d $((test_n - 1)))" ] ||
  "${hs[@]}" simulate --scene "$scene" --split test --pairs "$test_n" --seed 1 --views "$test_views" \
    --out "$data" --no-preview
resume=()
[ -d "weights/$scene/checkpoint" ] && resume=(--resume)
bash scripts/epssn-train.sh fit --scene "$scene" --spec weights/epssn-s.json --data "$data" --out "weights/$scene" \
  --epochs "$epochs" --batch 16 --seed 1 "${resume[@]}"
"${hs[@]}" quantise --weights "weights/$scene" --calib "$data" --calibration-samples 64 --percentile 99.99 \
  --search --search-passes 2
for v in $(seq 1 "$test_views"); do
  "${hs[@]}" eval --weights "weights/$scene" --data "$data" --views "$v" --json \
    $([ "$v" -ge 2 ] && echo --int8) >"weights/$scene/eval-views$v.json"
done
