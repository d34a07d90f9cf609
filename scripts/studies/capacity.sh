#!/usr/bin/env bash
# The capacity question on the paper's tank protocol: EPSSN-S, EPSSN-P and three wider EPSSN-P
# variants, each trained from scratch for the same wall-clock budget on the protocol's training
# pairs, then read on the first EVAL_N of its own training pairs and on the first EVAL_N test pairs.
# A variant whose training-pose MAE falls where EPSSN-P's does not is a lever that bends the curve.
#   bash scripts/studies/capacity.sh [OUT]   (default out/capacity)
# The variants (written from weights/epssn-p.json into OUT/specs/ by scripts/studies/capacity_specs.py):
#   p      EPSSN-P as shipped: C = 8 feature channels, N = 16 planes
#   wb32   a wider bottleneck: the cost net's d2 / m0 / u1 at 32 channels instead of 16
#   n32    N = 32 planes (the head keeps the plane axis: stride 1 there instead of 2)
#   c16    C = 16: every feature and cost-net channel doubled
#   s      EPSSN-S (weights/epssn-s.json), on the same poses drawn on its own 256 x 64 grid
# Budget: BUDGET_S seconds of an idle machine per variant (default 1200). Each variant's step time
# is measured first (`epssn-train bench`, THREADS threads) and its steps are BUDGET_S / that, so a
# busy machine stretches the wall-clock, not the comparison. Training: the paper's masked L1
# (lambda from the spec), Adam, lr 1e-3 halved after half the steps, batch 16, seed SEED (1).
# Results: OUT/<variant>/capacity.json (steps, seconds per step, fit wall time, MAE on training and
# test pairs: the paper's all-pixel formula, labels clamped to the window, mm, float32) and
# OUT/capacity.json, all variants. Resumable: a finished variant is skipped, a fit continues from
# its checkpoint.
#
# Environment: DATA_P (out/paper-data/tank: train/, test/, val/ of the EPSSN-P grid, as
# scripts/train-paper.sh tank writes them), DATA_S (OUT/data-s: written here with HOST_SIM_S, a
# host-sim built for EPSSN-S, default target/release/host-sim), EPSSN_TRAIN (one path, as
# scripts/epssn-train.sh takes it), THREADS (2),
# VARIANTS ("p wb32 n32 c16 s"), EVAL_N (200), BUDGET_S, SEED.
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:-out/capacity}
budget=${BUDGET_S:-1200} threads=${THREADS:-2} eval_n=${EVAL_N:-200} seed=${SEED:-1}
data_p=${DATA_P:-out/paper-data/tank} data_s=${DATA_S:-$out/data-s}
variants=${VARIANTS:-p wb32 n32 c16 s}
# The trainer as scripts/epssn-train.sh finds it (EPSSN_TRAIN, else epssn-train on PATH, else
# the venv target/venv-train, made on first use); the variants' specs and scores need that
# trainer's Python (epssn_train), which the resolver names.
train=(bash scripts/epssn-train.sh)
"${train[@]}" --help >/dev/null
py=$("${train[@]}" --python)
holds() { [ -d "$1" ] && [ "$(ls "$1" | wc -l)" -ge "$2" ]; } # DIR N: DIR holds N entries or more

"$py" scripts/studies/capacity_specs.py weights/epssn-p.json "$out/specs"
cp weights/epssn-s.json "$out/specs/s.json"

site=(--site data/sites/authors-tank.stl --region data/sites/authors-tank.region.json)
simulate_s() { # EPSSN-S's data: the same seeds as the EPSSN-P data, so the same poses on its grid
  [ -f "$data_s/.done" ] && return
  local hs=${HOST_SIM_S:-target/release/host-sim}
  for split in "train 4000 1" "test $eval_n 2"; do
    set -- $split
    holds "$data_s/$1" "$2" && continue
    "$hs" simulate --split "$1" --pairs "$2" --seed "$3" --out "$data_s" --no-preview "${site[@]}"
  done
  "$hs" simulate --split test --pairs 100 --seed 3 --out "$data_s-val" --no-preview "${site[@]}"
  ln -sfn "$(realpath "$data_s-val/test")" "$data_s/val"
  touch "$data_s/.done"
}

# Every step time first, back to back before any training, so that each is measured alike.
for v in $variants; do
  dir=$out/$v
  mkdir -p "$dir"
  [ -f "$dir/bench.json" ] && continue
  "${train[@]}" bench --spec "$out/specs/$v.json" --steps 6 --threads "$threads" --json \
    --ce-weight 0 --no-return-weight 0 | tail -1 >"$dir/bench.json.tmp"
  mv "$dir/bench.json.tmp" "$dir/bench.json"
done

for v in $variants; do
  dir=$out/$v
  [ -f "$dir/capacity.json" ] && { echo "$v: done"; continue; }
  data=$data_p
  if [ "$v" = s ]; then simulate_s; data=$data_s; fi
  steps=$("$py" -c "import json,sys; print(max(1, round($budget / json.load(open(sys.argv[1]))['seconds_per_step'])))" "$dir/bench.json")
  fit=$dir/fit
  if [ ! -f "$fit/model.safetensors" ]; then
    resume=(); [ -d "$fit/checkpoint" ] && resume=(--resume)
    echo "$v: $steps steps"
    "${train[@]}" fit --spec "$out/specs/$v.json" --data "$data" --out "$fit" --steps "$steps" \
      --lr 1e-3 --batch 16 --seed "$seed" --val-limit 50 --threads "$threads" --scene tank \
      --no-progress "${resume[@]}"
  fi
  for split in train test; do
    holds "$dir/pred-$split" "$eval_n" && continue
    "${train[@]}" predict --weights "$fit" --data "$data/$split" --out "$dir/pred-$split" \
      --limit "$eval_n" --dtype float32
  done
  "$py" scripts/studies/capacity_specs.py --score "$v" "$dir" "$data" "$budget" >"$dir/capacity.json.tmp"
  mv "$dir/capacity.json.tmp" "$dir/capacity.json"
  cat "$dir/capacity.json"
done
"$py" -c "import json,sys; print(json.dumps([json.load(open(f)) for f in sys.argv[1:]], indent=1))" \
  $(for v in $variants; do echo "$out/$v/capacity.json"; done) >"$out/capacity.json"
