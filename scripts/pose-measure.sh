#!/bin/sh
# docs/POSE.md's measurement: depth error of the shipped int8 model (weights/general) against a
# known pose error of the source view, 100 test pairs per level, seed 77.
#   scripts/pose-measure.sh [OUT]     (HOST_SIM: the release binary, default target/release)
# Writes OUT/eval-<scene>-<deg>.json, OUT/axes-eval-<pitch|yaw>-<deg>.json and prints a table.
set -e
HS=${HOST_SIM:-target/release/host-sim}
OUT=${1:-out/pose}
mkdir -p "$OUT"
row() {  # scene degrees axes tag
  $HS simulate --scene "$1" --split test --seed 77 --pairs 100 --pose-jitter-deg "$2" \
    --pose-jitter-axes "$3" --no-preview --out "$OUT/data-$4" 2>/dev/null
  $HS eval --data "$OUT/data-$4" --int8 --json > "$OUT/$4.json"
  rm -rf "$OUT/data-$4"
  echo "$1 $3 $2 $(python3 -c "import json;j=json.load(open('$OUT/$4.json'));print(round(j['int8']['mae'],2), round(j['float']['mae'],2))")"
}
for scene in terrain sphere; do
  for d in 0 0.025 0.05 0.075 0.1 0.15 0.2 0.25 0.5 0.75 1 1.5 2 3 4; do
    row $scene $d both eval-$scene-$d
  done
done
for axes in pitch yaw; do
  for d in 0.1 0.25 0.5; do
    row terrain $d $axes axes-eval-$axes-$d
  done
done
