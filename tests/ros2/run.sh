#!/usr/bin/env bash
# ROS 2 bags (docs/ROS2.md), one step of scripts/test-all.sh:
#   1. a venv under target/ with the independent writer and reader, PyPI mcap and
#      mcap-ros2-support (seconds);
#   2. the bundled ARIS 3000 demo recordings written as bags by that writer (aris_to_bag.py:
#      zstd, lz4 and uncompressed chunks): `run` on each bag gives the depth maps `run` gives
#      on the .aris file bit for bit (digests of every /depth/* message of `--mcap`), and the
#      same pairs, pings and scores (summary.json);
#      a bag without /tf, its attitudes from --poses, gives them too;
#   3. a 130-degree, 512-beam bag whose ranges start at 5 m is refused: non-zero exit, the
#      range window named, no panic, nothing written;
#   4. `run --mcap`'s sonar frames decode as ProjectedSonarImage with that reader.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv=${EPSSN_ROS2_VENV:-target/venv-ros2}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/python" -c "import mcap_ros2" 2>/dev/null || "$venv/bin/pip" install -q mcap mcap-ros2-support
py="$venv/bin/python"

hs=${HOST_SIM:-}
if [ -z "$hs" ]; then
    cargo build -q -p host-sim
    hs="$(cargo metadata --format-version 1 --no-deps | sed -n 's/.*"target_directory":"\([^"]*\)".*/\1/p')/debug/host-sim"
fi

# The fields of summary.json both runs must share (the recording's path and the rolls'
# last float bits differ: the bag's come from its transforms).
same_summary() {
    "$py" - "$1" "$2" <<'PY'
import json, sys
def key(path):
    s = json.load(open(path))
    details = [{k: d[k] for k in ("frames", "pings", "bit_exact", "int8_vs_float_mae", "float", "int8")}
               for d in s["details"]]
    candidates = [(c["frames"], c["accepted"], c["reason"]) for c in s["candidates"]]
    return details, candidates, s["pairs"], s["float"], s["int8"], s["bit_exact"]
a, b = key(sys.argv[1]), key(sys.argv[2])
assert a == b, f"summaries differ:\n{a}\n{b}"
print(f"same pairs and scores: {len(a[0])} depth map(s), candidates {a[1]}")
PY
}

check_recording() { # name, recording folder, frames, extra run arguments...
    local name=$1 dir=$2 frames=$3
    shift 3
    "$hs" run --recording "$dir/recording.aris" --gt "$dir/gt" "$@" --json \
        --out "$tmp/$name-aris" --mcap "$tmp/$name-aris.mcap" >/dev/null
    "$py" tests/ros2/read_run_bag.py "$tmp/$name-aris.mcap" "$frames" | tail -n +2 >"$tmp/$name-aris.depth"
    for c in zstd lz4 none; do
        "$py" tests/ros2/aris_to_bag.py "$dir/recording.aris" "$tmp/$name-$c.mcap" \
            --compression "$c" --chunk-size 200000 >/dev/null
        "$hs" run --recording "$tmp/$name-$c.mcap" --gt "$dir/gt" "$@" --json \
            --out "$tmp/$name-$c" --mcap "$tmp/$name-$c-run.mcap" >/dev/null
        "$py" tests/ros2/read_run_bag.py "$tmp/$name-$c-run.mcap" "$frames" >"$tmp/$name-$c.read"
        tail -n +2 "$tmp/$name-$c.read" >"$tmp/$name-$c.depth"
        [ -s "$tmp/$name-$c.depth" ] || { echo "$name ($c): no depth maps"; exit 1; }
        if ! cmp -s "$tmp/$name-aris.depth" "$tmp/$name-$c.depth"; then
            diff "$tmp/$name-aris.depth" "$tmp/$name-$c.depth" | head
            echo "$name: the bag ($c chunks) gives other depth maps than the .aris file"
            exit 1
        fi
        same_summary "$tmp/$name-aris/summary.json" "$tmp/$name-$c/summary.json" >/dev/null
    done
    echo "$name: bags (zstd, lz4, uncompressed) give the .aris file's $(wc -l <"$tmp/$name-aris.depth") depth messages bit for bit"
    head -1 "$tmp/$name-zstd.read"
    same_summary "$tmp/$name-aris/summary.json" "$tmp/$name-zstd/summary.json"
}

check_recording demo data/demo 12

# A bag without /tf takes its attitudes from --poses (here each frame's rotator roll, level).
"$py" tests/ros2/aris_to_bag.py data/demo/recording.aris "$tmp/notf.mcap" --no-tf >/dev/null
"$py" - "$tmp/notf.csv" <<'PY'
import sys
rows = ["frame,x_m,y_m,z_m,roll_deg,pitch_deg,yaw_deg"]
rows += [f"{k},0,0,0,{7.0 * (k % 2)},0,0" for k in range(12)]
open(sys.argv[1], "w").write("\n".join(rows) + "\n")
PY
"$hs" run --recording "$tmp/notf.mcap" --poses "$tmp/notf.csv" --gt data/demo/gt --json \
    --out "$tmp/notf" --mcap "$tmp/notf-run.mcap" >/dev/null
"$py" tests/ros2/read_run_bag.py "$tmp/notf-run.mcap" 12 | tail -n +2 >"$tmp/notf.depth"
cmp -s "$tmp/demo-aris.depth" "$tmp/notf.depth" || { echo "the bag with --poses gives other depth maps"; exit 1; }
grep -q "take their attitude from" "$tmp/notf/summary.json" || { echo "no --poses warning"; exit 1; }
echo "demo: a bag without /tf, attitudes from --poses, gives the same depth maps"
check_recording demo-3view-looks4 data/demo-3view-looks4 36 --weights weights/general-3view-looks4

# A sonar whose fan does not cover the model's grid: refused by name, nothing written.
"$py" tests/ros2/wide_bag.py "$tmp/wide.mcap"
set +e
"$hs" run --recording "$tmp/wide.mcap" --out "$tmp/wide-out" --mcap "$tmp/wide-run.mcap" \
    >"$tmp/wide.log" 2>&1
rc=$?
set -e
cat "$tmp/wide.log"
[ "$rc" -ne 0 ] || { echo "the 130-degree bag was not refused"; exit 1; }
[ "$rc" -ne 101 ] && ! grep -q "panicked" "$tmp/wide.log" || { echo "host-sim panicked"; exit 1; }
grep -q "range window" "$tmp/wide.log" || { echo "the refusal does not name the range window"; exit 1; }
[ ! -e "$tmp/wide-out" ] && [ ! -e "$tmp/wide-run.mcap" ] || { echo "a refused run wrote output"; exit 1; }
echo "the 130-degree, 512-beam bag from 5 m is refused (exit $rc), nothing written"
