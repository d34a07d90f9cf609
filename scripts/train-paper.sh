#!/usr/bin/env bash
# Trains EPSSN-P (weights/epssn-p.json, the paper's 512 x 128 input) on one of the paper's Table I
# protocols, quantises it and evaluates it on the protocol's held-out test split.
#   bash scripts/train-paper.sh PROTOCOL [OUT]
# PROTOCOL and its data (docs/PAPER.md, "Reproducing Table I"):
#   tank     poses throughout data/sites/authors-tank.stl, drawn in authors-tank.region.json:
#            4000 training pairs (seed 1), 2000 test pairs (seed 2), 200 validation pairs (seed 3)
#   terrain  three terrains exported with `simulate --scene terrain --seed S --export-mesh`:
#            1000 training pairs on terrain 1, 1000 test pairs on terrain 2, 200 validation pairs
#            on terrain 3, poses from `simulate --site` with its default region (seeds 1, 2, 3)
#   sphere   `simulate --scene sphere`: 1000 training (seed 1), 1000 test (seed 2), 200 val (seed 3)
#   general  the three-scene mix of scripts/train-general.sh, per scene 3000 training and 300 test
#            pairs (seed 1) and 100 validation pairs (seed 2), interleaved scene by scene
# OUT defaults to weights/epssn-p-PROTOCOL (general: weights/paper). Training: epssn-train fit,
# 50 epochs, Adam, lr 1e-3 halved after half the steps (the spec's lr_halved_at_fraction 0.5: after
# 25 of 50 epochs), batch 16, lambda from the spec. Then `host-sim quantise --search` on the
# training split and `host-sim eval --int8 --json` on the test split into OUT/eval-PROTOCOL.json
# (general: OUT/eval-<scene>.json per scene).
#
# Resumable: every step is skipped when its result is there (a simulated split, a finished fit, a
# blob newer than the weights, an eval newer than the blob), and fit continues from
# OUT/checkpoint/ (written every epoch and every 5 minutes). Rerun the same command to go on.
#
# Environment:
#   HOST_SIM     a host-sim built for EPSSN-P; default: build one with
#                `EPSSN_SPEC=weights/epssn-p.json cargo build --release -p host-sim --target-dir target/epssn-p`
#   EPSSN_TRAIN  the trainer command (default: epssn-train on PATH, else the venv target/venv-train,
#                made on first use; e.g. "python -m epssn_train"): scripts/epssn-train.sh
#   DATA_ROOT    where the samples go (default out/paper-data/PROTOCOL; with TERRAINS=K,
#                out/paper-data/terrain-K-terrains)
#   TRAIN_N TEST_N VAL_N EPOCHS   sizes (per scene for general) and epochs, e.g. for a tiny check
#   INIT_FROM    start from this weights folder (e.g. weights/paper) instead of at random
#   KEEP_EPOCHS=1 keep each epoch's model in OUT/epochs/epoch-NNN/, to choose one on validation
#   DEVICE       cpu, cuda or auto (epssn-train's default: auto); THREADS torch CPU threads
#   LR           learning rate before its halving (default 1e-3); CE_WEIGHT, NO_RETURN_WEIGHT
#                add epssn-train's extra loss terms (default 0: the paper's masked L1 only)
#   TERRAINS     terrain only: train on this many terrains of their own (seeds 101..100+K,
#                TRAIN_N/K pairs each) instead of terrain 1; test and validation stay terrains 2, 3
#   CALIB_SAMPLES (256), SEARCH_PASSES (3), SEARCH_PIXELS (all): the quantiser's settings;
#                SEARCH=0 takes a plain calibration (percentile 99.99) instead of the search;
#                NO_RETURN_MASS writes the model's no-return threshold into the blob (chosen on
#                the validation split with the no_return_sweep example; default: the spec's)
set -euo pipefail
usage="usage: bash scripts/train-paper.sh tank|terrain|sphere|general [OUT]"
protocol=${1:?$usage}
case $protocol in
  tank) def=(4000 2000 200) ;;
  terrain | sphere) def=(1000 1000 200) ;;
  general) def=(3000 300 100) ;;
  *) echo "$usage" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."
spec=weights/epssn-p.json
if [ "$protocol" = general ]; then out=${2:-weights/paper}; else out=${2:-weights/epssn-p-$protocol}; fi
train_n=${TRAIN_N:-${def[0]}} test_n=${TEST_N:-${def[1]}} val_n=${VAL_N:-${def[2]}}
epochs=${EPOCHS:-50} lr=${LR:-1e-3}
terrains=${TERRAINS:-1}
# Several terrains' training split is links into their parts: not the one-terrain root's.
if [ "$protocol" = terrain ] && [ "$terrains" -gt 1 ]; then
  data=${DATA_ROOT:-out/paper-data/terrain-$terrains-terrains}
else
  data=${DATA_ROOT:-out/paper-data/$protocol}
fi
calib_n=${CALIB_SAMPLES:-256} passes=${SEARCH_PASSES:-3} pixels=${SEARCH_PIXELS:-all}
search=(--search --search-passes "$passes" --search-pixels "$pixels")
[ "${SEARCH:-1}" = 0 ] && search=()

if [ -n "${HOST_SIM:-}" ]; then
  hs=$HOST_SIM
else
  # Built once here and then run by path, so that editing the tree does not rebuild mid-run.
  EPSSN_SPEC=$spec cargo build --release -q -p host-sim --target-dir target/epssn-p
  hs=target/epssn-p/release/host-sim
fi
trainer=(bash scripts/epssn-train.sh)

# The data must be on EPSSN-P's grid (a host-sim built for another spec draws its own): one probe
# sample first, so that a wrong binary stops before it simulates, and marks, whole splits.
want=$(python3 -c 'import json, sys; o = json.load(open(sys.argv[1]))["output"]
print("(%d, %d, )" % (o["elevation_rows"], o["azimuth_columns"]))' "$spec")
probe=$(mktemp -d)
"$hs" simulate --scene sphere --pairs 1 --seed 1 --out "$probe" --no-preview >/dev/null 2>&1 ||
  { echo "$hs simulate failed" >&2; exit 1; }
if ! head -c 128 "$probe/train/000000/depth.npy" | grep -aqF "'shape': $want"; then
  rm -rf "$probe"
  echo "$hs draws depth maps other than $want: build it with EPSSN_SPEC=$spec" >&2
  exit 1
fi
rm -rf "$probe"

# A split is done when its marker records at least the pairs asked for (samples are written in
# parallel, so the last folder existing does not prove the others are complete).
marker() { echo "$1/.done-$2"; } # ROOT SPLIT
done_pairs() { cat "$(marker "$1" "$2")" 2>/dev/null || echo 0; }
simulate() { # ROOT SPLIT PAIRS SEED ARGS...: ROOT/SPLIT/ holds PAIRS samples of SEED
  local root=$1 split=$2 n=$3 seed=$4
  shift 4
  [ "$(done_pairs "$root" "$split")" -ge "$n" ] && return
  rm -f "$(marker "$root" "$split")"
  "$hs" simulate --split "$split" --pairs "$n" --seed "$seed" --out "$root" --no-preview "$@"
  echo "$n" >"$(marker "$root" "$split")"
}
export_terrain() { # SEED FILE
  [ -s "$2" ] && return
  mkdir -p "$(dirname "$2")"
  "$hs" simulate --scene terrain --seed "$1" --export-mesh "$2.tmp.stl"
  mv "$2.tmp.stl" "$2"
}
link_val() { ln -sfn "$(realpath "$1")" "$2/val"; } # VAL_SPLIT_DIR ROOT: fit reads ROOT/val

scenes=(sphere terrain artificial)
case $protocol in
  tank)
    site=(--site data/sites/authors-tank.stl --region data/sites/authors-tank.region.json)
    simulate "$data" train "$train_n" 1 "${site[@]}"
    simulate "$data" test "$test_n" 2 "${site[@]}"
    simulate "$data-val" test "$val_n" 3 "${site[@]}"
    link_val "$data-val/test" "$data"
    ;;
  terrain)
    # Terrain S is sample 0 of seed S's training split, exported whole; the test and validation
    # terrains are never trained on.
    for s in 1 2 3; do export_terrain "$s" "$data-meshes/terrain-seed$s.stl"; done
    if [ "$terrains" -gt 1 ]; then
      # TERRAINS=K: train on K terrains of their own (seeds 101..100+K, never 1-3), TRAIN_N/K
      # pairs on each (seed S), merged into one training split of links.
      per=$((train_n / terrains))
      [ "$per" -ge 1 ] || { echo "TRAIN_N=$train_n is fewer than TERRAINS=$terrains" >&2; exit 2; }
      mkdir -p "$data/train"
      for ((k = 1; k <= terrains; k++)); do
        s=$((100 + k)) part=$data-parts/s$s
        if [ "$(done_pairs "$part" train)" -lt "$per" ]; then
          "$hs" simulate --scene terrain --seed "$s" --export-mesh "$part.stl" >/dev/null
          simulate "$part" train "$per" "$s" --site "$part.stl"
          rm -f "$part.stl"
        fi
        part_train=$(realpath "$part/train") # once per terrain, not once per link
        for ((i = 0; i < per; i++)); do
          ln -sfn "$part_train/$(printf %06d "$i")" "$data/train/$(printf %06d $(((k - 1) * per + i)))"
        done
      done
      train_n=$((per * terrains))
      echo "$train_n" >"$(marker "$data" train)"
    else
      simulate "$data" train "$train_n" 1 --site "$data-meshes/terrain-seed1.stl"
    fi
    simulate "$data" test "$test_n" 2 --site "$data-meshes/terrain-seed2.stl"
    simulate "$data-val" test "$val_n" 3 --site "$data-meshes/terrain-seed3.stl"
    link_val "$data-val/test" "$data"
    ;;
  sphere)
    simulate "$data" train "$train_n" 1 --scene sphere
    simulate "$data" test "$test_n" 2 --scene sphere
    simulate "$data-val" test "$val_n" 3 --scene sphere
    link_val "$data-val/test" "$data"
    ;;
  general)
    # As scripts/train-general.sh: seed 1 train and test, seed 2 validation, per scene; the mix
    # interleaves them (sample i of scene k is 3i + k) so every evenly spread calibration sample
    # set holds every scene.
    for scene in "${scenes[@]}"; do
      simulate "$data/$scene" train "$train_n" 1 --scene "$scene"
      simulate "$data/$scene" test "$test_n" 1 --scene "$scene"
      simulate "$data/$scene-val" test "$val_n" 2 --scene "$scene"
    done
    mix=$data/mix
    rm -rf "$mix" && mkdir -p "$mix/train" "$mix/val"
    link_mix() { # DEST N SRC_SPLIT_DIR...
      local dest=$1 n=$2 i k
      shift 2
      local srcs=()
      for k in "$@"; do srcs+=("$(realpath "$k")"); done
      for ((i = 0; i < n; i++)); do
        for k in 0 1 2; do
          ln -s "${srcs[$k]}/$(printf %06d "$i")" "$dest/$(printf %06d $((3 * i + k)))"
        done
      done
    }
    link_mix "$mix/train" "$train_n" "$data/sphere/train" "$data/terrain/train" "$data/artificial/train"
    link_mix "$mix/val" "$val_n" "$data/sphere-val/test" "$data/terrain-val/test" "$data/artificial-val/test"
    ;;
esac
if [ "$protocol" = general ]; then
  fit_data=$data/mix fit_n=$((3 * train_n)) fit_val=$((3 * val_n))
else
  fit_data=$data fit_n=$train_n fit_val=$val_n
fi

# fit is done when OUT's manifest is epssn-train's for these epochs and samples and was written
# after the last checkpoint (write_outputs runs once the last step is taken).
fit_done() {
  [ -f "$out/manifest.json" ] && [ "$out/manifest.json" -nt "$out/checkpoint/state.pt" ] &&
    python3 - "$out/manifest.json" "$epochs" "$fit_n" <<'EOF'
import json, sys
m = json.load(open(sys.argv[1]))
ok = (str(m.get("trainer", "")).startswith("epssn-train") and m.get("epochs") == int(sys.argv[2])
      and m.get("train_samples") == int(sys.argv[3]))
sys.exit(0 if ok else 1)
EOF
}
if ! fit_done; then
  "${trainer[@]}" fit --spec "$spec" --data "$fit_data" --out "$out" --epochs "$epochs" --lr "$lr" \
    --batch 16 --seed 1 --resume --limit "$fit_n" --val-limit "$fit_val" --scene "$protocol" \
    --no-progress ${INIT_FROM:+--init-from "$INIT_FROM"} ${DEVICE:+--device "$DEVICE"} \
    ${THREADS:+--threads "$THREADS"} ${CE_WEIGHT:+--ce-weight "$CE_WEIGHT"} \
    ${NO_RETURN_WEIGHT:+--no-return-weight "$NO_RETURN_WEIGHT"} ${KEEP_EPOCHS:+--keep-epochs}
fi

blob=$out/$(basename "$spec" .json).q8.bin
if ! [ "$blob" -nt "$out/model.safetensors" ] || ! [ "$out/quantisation.json" -nt "$out/model.safetensors" ]; then
  "$hs" quantise --weights "$out" --calib "$fit_data" --calibration-samples "$calib_n" \
    --percentile 99.99 "${search[@]}" ${NO_RETURN_MASS:+--no-return-mass "$NO_RETURN_MASS"}
fi

evaluate() { # TEST_ROOT JSON: written through a temporary file, so a failed eval leaves none
  [ "$2" -nt "$blob" ] && return
  "$hs" eval --weights "$out" --data "$1" --json --int8 --limit "$test_n" >"$2.tmp"
  mv "$2.tmp" "$2"
}
if [ "$protocol" = general ]; then
  for scene in "${scenes[@]}"; do evaluate "$data/$scene" "$out/eval-$scene.json"; done
else
  evaluate "$data" "$out/eval-$protocol.json"
fi
echo "done: $out" >&2
