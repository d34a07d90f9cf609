#!/usr/bin/env bash
# Trains the general model (one model for every scene) into weights/general/ and writes its
# held-out tables, one per scene.
#   bash scripts/train-general.sh TRAIN_PER_SCENE TEST_PER_SCENE EPOCHS [DATA_ROOT] [SPEC]
# HOST_SIM=path/to/host-sim runs a prebuilt binary for simulate, quantise and eval (so editing the
# tree does not rebuild mid-run). Training is `epssn-train fit` (the PyTorch trainer,
# docs/TRAINING.md) through scripts/epssn-train.sh: EPSSN_TRAIN=path/to/epssn-train, else the venv
# target/venv-train.
# WEIGHTS=weights/paper trains into another folder; for another spec the binary must be built
# from it (EPSSN_SPEC, docs/PAPER.md), as must the data (the simulator draws the spec's grid).
# SEARCH_PASSES (default 3) and SEARCH_PIXELS (default all) set the quantiser's search passes and
# the pixels it scores (the shipped blob's settings, chosen on the validation split with
# CALIB_SAMPLES: docs/ACCURACY.md); INIT_FROM=weights/general starts
# from another model's weights (same layers, e.g. EPSSN-S's for EPSSN-P) instead of at random;
# LR sets the learning rate before its halving (default: the spec's; `fit --lr`), e.g. to fine-tune;
# CALIB_SAMPLES (default 256) sets the quantiser's calibration samples; CE_WEIGHT adds the
# two-hot cross-entropy term to the loss (`fit --ce-weight`, docs/ACCURACY.md); NO_RETURN_WEIGHT
# adds the no-return term (`fit --no-return-weight`: the end bins' mass against the label's
# "met nothing" / "nearer than the window", what the spec's `no_return_mass` decides on);
# FAKE_QUANT=weights/general trains quantisation-aware on that folder's activation scales
# (`fit --fake-quant`, docs/QUANTISATION.md); INIT_FROM is `fit --init-from`, VIEWS `fit --views`.
# VIEWS=3 trains a three-view model (rolls 0, +7, +14 degrees; give it a DATA_ROOT of its own,
# the data are simulated with the third view): the manifest and the blob record the count, and
# eval, run and the firmware's pairing follow it.
# SIM_PARAMS=FILE simulates every split with `simulate --params FILE` (docs/SIMULATOR.md), e.g.
# {"speckle_looks": 4} for four pings averaged per view; give it a DATA_ROOT of its own.
# Each scene is simulated with seed 1 into DATA_ROOT/<scene>/{train,test} (as train-scene.sh
# does) and a validation split with seed 2 into DATA_ROOT/<scene>-val/test (disjoint from both:
# the simulator mixes the split tag into the seed). DATA_ROOT/general/{train,val} holds symbolic
# links to the samples, interleaved scene by scene (sample i of scene k is 3i + k, so the
# quantiser's evenly spread calibration samples hold every scene). Training never sees a test
# split; an interrupted run continues
# with the same command (--resume).
set -euo pipefail
train_n=$1 test_n=$2 epochs=$3 root=${4:-out/epssn-data} spec=${5:-weights/epssn-s.json}
weights=${WEIGHTS:-weights/general} passes=${SEARCH_PASSES:-3} calib_n=${CALIB_SAMPLES:-256}
pixels=${SEARCH_PIXELS:-all}
views=(${VIEWS:+--views "$VIEWS"})
sim_params=(${SIM_PARAMS:+--params "$SIM_PARAMS"})
val_n=${VAL_PER_SCENE:-100}
hs=(${HOST_SIM:-cargo run --release -q -p host-sim --})
cd "$(dirname "$0")/.."
scenes=(sphere terrain artificial)
have() { [ -d "$1/$(printf %06d $(($2 - 1)))" ]; }
for scene in "${scenes[@]}"; do
  have "$root/$scene/train" "$train_n" ||
    "${hs[@]}" simulate --scene "$scene" --split train --pairs "$train_n" --seed 1 --out "$root/$scene" --no-preview "${views[@]}" "${sim_params[@]}"
  have "$root/$scene/test" "$test_n" ||
    "${hs[@]}" simulate --scene "$scene" --split test --pairs "$test_n" --seed 1 --out "$root/$scene" --no-preview "${views[@]}" "${sim_params[@]}"
  have "$root/$scene-val/test" "$val_n" ||
    "${hs[@]}" simulate --scene "$scene" --split test --pairs "$val_n" --seed 2 --out "$root/$scene-val" --no-preview "${views[@]}" "${sim_params[@]}"
done
mix=$root/general
rm -rf "$mix" && mkdir -p "$mix/train" "$mix/val"
link() { # SPLIT_DIR_OF_SCENE... DEST N: sample i of scene k becomes DEST/(3i + k)
  local dest=$1 n=$2 k
  # Absolute targets: a link is read from its own folder, so a relative root would dangle.
  for k in 0 1 2; do srcs[$k]=$(realpath "${srcs[$k]}"); done
  for i in $(seq 0 $((n - 1))); do
    for k in 0 1 2; do
      ln -s "${srcs[$k]}/$(printf %06d "$i")" "$dest/$(printf %06d $((3 * i + k)))"
    done
  done
}
srcs=("$root/sphere/train" "$root/terrain/train" "$root/artificial/train"); link "$mix/train" "$train_n"
srcs=("$root/sphere-val/test" "$root/terrain-val/test" "$root/artificial-val/test"); link "$mix/val" "$val_n"
# --resume continues an interrupted run from its checkpoint, or a finished one (weights and loss
# history, fresh optimizer state) when EPOCHS is larger than it ran; otherwise it starts fresh.
bash scripts/epssn-train.sh fit --scene general --data "$mix" --spec "$spec" --epochs "$epochs" --batch 16 --seed 1 \
  --val-limit $((3 * val_n)) --resume --out "$weights" "${views[@]}" ${INIT_FROM:+--init-from "$INIT_FROM"} ${LR:+--lr "$LR"} ${CE_WEIGHT:+--ce-weight "$CE_WEIGHT"} \
  ${NO_RETURN_WEIGHT:+--no-return-weight "$NO_RETURN_WEIGHT"} ${FAKE_QUANT:+--fake-quant "$FAKE_QUANT"}
"${hs[@]}" quantise --weights "$weights" --calib "$mix" --calibration-samples "$calib_n" --percentile 99.99 \
  --search --search-passes "$passes" --search-pixels "$pixels"
for scene in "${scenes[@]}"; do
  "${hs[@]}" eval --weights "$weights" --data "$root/$scene" --json --int8 \
    >"$weights/eval-$scene.json"
done
