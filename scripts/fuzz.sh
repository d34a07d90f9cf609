#!/usr/bin/env bash
# Coverage-guided fuzzing of every parser (fuzz/: cargo-fuzz, libFuzzer): the link decoder,
# the weight blob, the spec JSON, the beam tables, the ARIS reader, the frame pairing, the
# site mesh readers (STL, OBJ, PLY), the poses file of `label` (CSV) and the ROS 2 bag reader
# (MCAP chunks stored, LZ4 and zstd; CDR of ProjectedSonarImage and TFMessage).
#   bash scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
# Installs what it needs (a nightly toolchain, cargo-fuzz), seeds each corpus, runs each target
# for SECONDS (default 30) and fails on the first crash; crashes land in fuzz/artifacts/<target>/
# for `cargo fuzz run <target> <file>` to replay. Seeds: the committed fuzz/corpus/<target>/seed-*
# (a few small inputs per target, fuzz/corpus/README.md), plus, written here, the large valid
# inputs the repo already holds (encoded frame and depth messages, the shipped weight blob, the
# spec, a beam table, the head of the demo recording). The corpora grow in fuzz/corpus/ (only
# the seed-* files are committed).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(link_decoder link_update model_from_blob model_from_blob_fixed spec_json beam_table aris_reader pairing mesh_stl mesh_obj mesh_ply poses_csv ros2_bag)

rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
command -v cargo-fuzz >/dev/null 2>&1 || cargo install --locked cargo-fuzz

corpus=fuzz/corpus
mkdir -p "$corpus"/{link_decoder,link_update,model_from_blob,model_from_blob_fixed,spec_json,beam_table,aris_reader,pairing,mesh_stl,mesh_obj,mesh_ply,poses_csv,ros2_bag}
cargo run -q --example link_seeds -- "$corpus/link_decoder"
# Small bags of a ping and a transform, whole (every compression) and as the target's split form.
cargo run -q -p epssn-ros2 --example fuzz_seeds -- "$corpus/ros2_bag"
cp "$(awk '$1 == "epssn-s.json" { print $2 }' weights/FIRMWARE_WEIGHTS)" "$corpus/model_from_blob/shipped.q8.bin"
cp "$corpus/model_from_blob/shipped.q8.bin" "$corpus/model_from_blob_fixed/shipped.q8.bin"
cp weights/epssn-s.json "$corpus/spec_json/epssn-s.json"
cp data/aris-beam-widths/ARIS3000_128.csv "$corpus/beam_table/"
# The demo recording's first frames (the whole file is large; the reader's checks come first).
head -c 200000 data/demo/recording.aris > "$corpus/aris_reader/demo-head.aris"
# Pairing: (seq u32, roll f32, views) records of a 0, 7, 14 degree sweep.
python3 - "$corpus/pairing/sweep" <<'PY'
import struct, sys
out = b''.join(struct.pack('<If', i, (i % 3) * 7.0) + bytes([i % 2]) for i in range(1, 40))
open(sys.argv[1], 'wb').write(out)
PY

# Inputs that once failed (fuzz/regressions/<target>/) are replayed first by every run.
for d in fuzz/regressions/*/; do
    [ -d "$d" ] && cp "$d"* "$corpus/$(basename "$d")/"
done

# Every target built once, in one cargo run (its own target folder, fuzz/target: sanitizer
# builds must not replace the host ones); each is then run as the libFuzzer binary it is.
(cd fuzz && env -u CARGO_TARGET_DIR cargo +nightly fuzz build 2>&1 | tail -3)
bin_dir=fuzz/target/x86_64-unknown-linux-gnu/release
for t in "${targets[@]}"; do
    printf '\n==> fuzz %s for %s s\n' "$t" "$seconds"
    log=$(mktemp)
    mkdir -p "fuzz/artifacts/$t"
    # -max_len above the largest seed (the 23.6 KiB shipped blob, a 24.9 KiB message stream):
    # libFuzzer cuts longer inputs, and a cut blob never passes its length and CRC checks.
    if ! "$bin_dir/$t" -artifact_prefix="fuzz/artifacts/$t/" -max_total_time="$seconds" \
        -rss_limit_mb=2048 -max_len=32768 "$corpus/$t" >"$log" 2>&1; then
        tail -40 "$log"
        echo "fuzz target $t failed (crash input in fuzz/artifacts/$t/; replay: cargo +nightly fuzz run $t <file>)"
        exit 1
    fi
    # The final status line: executions (#N) and edges covered (cov).
    grep -E '^(#[0-9]+.*DONE|Done [0-9]+ runs)' "$log" | tail -2
    rm -f "$log"
done
