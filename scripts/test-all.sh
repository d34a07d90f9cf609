#!/usr/bin/env bash
# Runs every check of the project on a fresh machine: installs what it needs (the thumbv7em
# target, rustfmt/clippy, QEMU), then fmt, clippy, the no_std build, all host tests and the
# firmware in QEMU. Exits non-zero on the first failure.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }
# Every firmware build here embeds the test key for signed model updates, named explicitly (a
# release firmware without EPSSN_UPDATE_KEY does not build; docs/UPDATE.md).
export EPSSN_UPDATE_KEY=update/test-key/public
# Each configuration builds once here: incremental caches would only take disk (gigabytes across
# the target directories) for rebuilds that never come.
export CARGO_INCREMENTAL=0

step "disk"
# The run needs about EPSSN_CI_NEED_GB free (its target directories, the trainer's torch venv and
# the fuzzers' builds; measured in docs/ARCHITECTURE.md): a fuller disk is named here rather than
# as a linker's "No space left on device".
need_gb=${EPSSN_CI_NEED_GB:-20}
read -r free_gb mount < <(df -Pk . | awk 'NR == 2 { print int($4 / 1048576), $6 }')
echo "free: ${free_gb} GB on ${mount} (needed: about ${need_gb} GB)"
if [ "$free_gb" -lt "$need_gb" ]; then
    echo "error: ${free_gb} GB free on ${mount}, the checks need about ${need_gb} GB" >&2
    exit 1
fi

step "toolchain and tools"
# rust-toolchain.toml names the toolchain, its components and the Cortex-M7 and M55 targets; rustup
# installs whatever of them is missing.
rustup show active-toolchain
rustup target list --installed | grep -qx thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf
# The Cortex-M55 board (boards/mps3-an547).
rustup target list --installed | grep -qx thumbv8m.main-none-eabihf || rustup target add thumbv8m.main-none-eabihf
rustup component list --installed | grep -q '^rustfmt' || rustup component add rustfmt
rustup component list --installed | grep -q '^clippy' || rustup component add clippy
if ! command -v qemu-system-arm >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq qemu-system-arm >/dev/null
fi
qemu-system-arm --version | head -1
# The firmware links through flip-link (stack below the statics: overflow faults).
command -v flip-link >/dev/null 2>&1 || cargo install --locked flip-link

step "format"
cargo fmt --all -- --check
(cd boards/mps2-an500 && cargo fmt -- --check)

step "supply chain: licences, bans, sources and, when the RustSec database is reachable, advisories (cargo-deny, all five workspaces)"
bash scripts/deny.sh
# The SIL compares builds of the five workspaces bit for bit: they share every crate's version.
python3 scripts/check-locks.py

step "clippy (host workspace, all targets, -D warnings)"
cargo clippy --workspace --all-targets -- -D warnings

step "no_std library build for thumbv7em-none-eabihf (with and without defmt); clippy on the dsp and mve paths"
cargo build -p epssn --lib --target thumbv7em-none-eabihf
cargo build -p epssn --lib --target thumbv7em-none-eabihf --features defmt
# The assembly paths build only for their cores: lint them there (host clippy never sees them).
cargo clippy -p epssn --lib --target thumbv7em-none-eabihf --features dsp -- -D warnings
RUSTFLAGS="-C target-cpu=cortex-m55" cargo clippy -p epssn --lib --target thumbv8m.main-none-eabihf \
    --features mve --target-dir target/mve -- -D warnings

step "Cortex-M7 firmware (boards/mps2-an500): clippy and release build (and with defmt logging)"
(cd boards/mps2-an500 && cargo clippy --release -- -D warnings && cargo build --release)
(cd boards/mps2-an500 && cargo build --release --features defmt)

step "Cortex-M7 firmware self-test in QEMU (mps2-an500)"
(cd boards/mps2-an500 && timeout 300 cargo run --release)

step "STM32H743 board: format, clippy, release build and link (not run: no hardware here)"
# Its own workspace and target directory (boards/stm32h743/target). It links through
# flip-link against its memory.x, so a static or image that outgrows DTCM or flash fails here.
board_start=$SECONDS
(cd boards/stm32h743 && cargo fmt -- --check && cargo clippy --release -- -D warnings && cargo build --release)
(cd boards/selftest && cargo fmt -- --check)
(cd boards/cmsdk && cargo fmt -- --check)
bash scripts/elf-regions.sh boards/stm32h743/target/thumbv7em-none-eabihf/release/epssn-stm32h743 \
    FLASH:0x08000000:1048576 DTCM:0x20000000:131072 AXISRAM:0x24000000:524288
echo "(DTCM: statics above; the stack is the rest of DTCM, below them; board step $((SECONDS - board_start)) s)"

step "DSP assembly kernels vs portable kernels on the Cortex-M7 in QEMU"
(cd qemu-check && cargo fmt -- --check && cargo clippy --release -- -D warnings && timeout 600 cargo run --release)

step "Helium assembly kernels vs portable kernels on the Cortex-M55 in QEMU"
(cd qemu-check && cargo clippy --release --target thumbv8m.main-none-eabihf --features mve -- -D warnings \
    && timeout 600 cargo run --release --target thumbv8m.main-none-eabihf --features mve)

step "Cortex-M55 (QEMU mps3-an547): format, clippy, release build, boot self-test"
# Its own workspace and target directory (boards/mps3-an547/target); the same self-test crate.
m55_start=$SECONDS
(cd boards/mps3-an547 && cargo fmt -- --check && cargo clippy --release -- -D warnings \
    && timeout 300 cargo run --release)
echo "(M55 step $((SECONDS - m55_start)) s)"

step "documentation (workspace, warnings denied)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps

step "host tests (workspace, including the QEMU software-in-the-loop test)"
cargo test --workspace

step "software in the loop: firmware in QEMU vs the host library, bit for bit"
# The binary `cargo test` just built for the integration tests: no second build of anything.
host_sim="$(cargo metadata --format-version 1 --no-deps | sed -n 's/.*"target_directory":"\([^"]*\)".*/\1/p')/debug/host-sim"
"$host_sim" sil --json

step "model updates over the link (docs/UPDATE.md): a key pair made here, site-tank's blob signed with it"
# The SIL's firmware build, relinked with this key (only the crates that embed it rebuild); the
# blobs it must refuse by name, resets during the upload and the commit (the old model serves
# bit-exact until the switch), then every streamed map bit-exact with site-tank's blob.
update_dir=$(mktemp -d)
"$host_sim" keygen --out "$update_dir/keys"
"$host_sim" sign --key "$update_dir/keys/private" --blob weights/site-tank/epssn-s.q8.bin \
    --version 1 --out "$update_dir/site-tank.signed"
EPSSN_UPDATE_KEY="$update_dir/keys/public" "$host_sim" sil --faults 0 \
    --update "$update_dir/site-tank.signed" --update-faults 4 --json
rm -rf "$update_dir"

step "device resets in QEMU: watchdog on a hang, fault record on a panic and a stack overflow"
# A test build of the firmware (feature reset-faults, its own target directory) hangs, panics
# and overflows its stack on request; each reset's cause and record must come back in the next
# hello, and the depth maps after it must be bit-exact (docs/LINK.md "Resets"; about 50 s).
"$host_sim" sil --frames 6 --faults 0 --reset-faults 1 --json

step "software in the loop on the Cortex-M55 (mps3-an547): bit for bit, weights/budgets-m55.json"
"$host_sim" sil --target m55 --faults 1 --json

step "three-view model (weights/general-3view) in QEMU: SIL on data/demo-3view"
# The same build with the three-view blob embedded: its view count makes the device pair frames
# in threes (0, +7, +14 degrees); its budgets allow one more warped view per map.
EPSSN_BLOB="$PWD/weights/general-3view/epssn-s.q8.bin" "$host_sim" sil \
    --recording data/demo-3view/recording.aris --budgets weights/general-3view/budgets.json \
    --faults 0 --json

step "EPSSN-P, the paper's 512 x 128 (weights/epssn-p.json): zero-tolerance tests, QEMU, SIL"
# The second configuration from the same code, in its own target directories (target/epssn-p,
# boards/mps2-an500/target/epssn-p) so neither build thrashes the other's artefacts
# (the SIL runs through epssn-sil, the sil crate's own binary).
p_start=$SECONDS
EPSSN_SPEC=weights/epssn-p.json cargo test -p epssn-tests -p epssn-spec -p epssn-sil-core \
    --target-dir target/epssn-p
# The kernels' whole-network checks at EPSSN-P's shapes (the random-shape ones are EPSSN-S's).
EPSSN_SPEC=weights/epssn-p.json cargo test -p epssn-reference --test bitexact_kernels network \
    --target-dir target/epssn-p
(cd boards/mps2-an500 && EPSSN_SPEC=weights/epssn-p.json timeout 600 \
    cargo run --release --target-dir target/epssn-p)
EPSSN_SPEC=weights/epssn-p.json cargo run -q -p epssn-sil --target-dir target/epssn-p -- \
    --frames 3 --faults 0 --json
# And on the Cortex-M55 with the Helium kernels (weights/budgets-m55-epssn-p.json).
EPSSN_SPEC=weights/epssn-p.json cargo run -q -p epssn-sil --target-dir target/epssn-p -- \
    --target m55 --frames 3 --faults 0 --json
# The general model (weights/paper, the blob those builds embed): its accuracy guard, every scene.
EPSSN_SPEC=weights/epssn-p.json cargo test -p host-sim --test accuracy_guard \
    --target-dir target/epssn-p -- --ignored --exact epssn_p_general_model_keeps_its_accuracy
# Each model trained on one of the paper's protocols (weights/epssn-p-PROTOCOL, docs/PAPER.md):
# embedded in turn, bit for bit on the M55; and its accuracy guard on fresh held-out data.
for model in weights/epssn-p-*/; do
  [ -f "${model}epssn-p.q8.bin" ] || continue # no such model shipped (the glob kept its pattern)
  protocol=$(basename "$model")
  protocol=${protocol#epssn-p-}
  EPSSN_BLOB="$PWD/${model}epssn-p.q8.bin" EPSSN_SPEC=weights/epssn-p.json cargo run -q \
      -p epssn-sil --target-dir target/epssn-p -- --target m55 --frames 3 --faults 0 --json
  EPSSN_SPEC=weights/epssn-p.json cargo test -p host-sim --test accuracy_guard \
      --target-dir target/epssn-p -- --ignored --exact "epssn_p_${protocol}_model_keeps_its_accuracy"
done
echo "(EPSSN-P step $((SECONDS - p_start)) s)"

step "ROS 2 bags (docs/ROS2.md): ARIS 3000 demos as bags give the .aris depth maps bit for bit"
# A venv under target/ with PyPI mcap and mcap-ros2-support (seconds): bags from the independent
# writer read by run (zstd, LZ4, stored chunks), a 130-degree bag from 5 m refused, run --mcap's
# ProjectedSonarImage decoded by the independent reader.
bash tests/ros2/run.sh

step "PyTorch trainer (training/): float agreement with the f64 reference, data-parallel fit"
# A venv under target/ with torch (the README's main job needs none); predict against
# host-sim eval --save-depth on fresh samples, max |delta| <= 0.1 mm, EPSSN-S 2 and 3 views and
# EPSSN-P (whose host-sim builds in target/epssn-p beside the step above); 10 torchrun steps.
bash training/tests/run.sh

step "EPSSN-PW, EPSSN-P with a wider bottleneck (weights/epssn-pw.json): zero-tolerance tests, SIL, its tank model's guard"
# Its m0 (32 channels) takes the line engine because the engine's buffers follow the spec
# (src/kernels/line/mod.rs): the library's tests and the whole network against the integer
# reference on the host, then every layer the harness holds, Helium against plain, on the
# Cortex-M55 in QEMU. Its M55 figures (SIL, weights/budgets-m55-epssn-pw.json): docs/M55.md.
# The host tests reuse target/epssn-p's debug dependencies (only the crates generated from the
# spec rebuild for this one), so this step comes after every other use of that directory
# (the EPSSN-P step, the trainer's tests); a later EPSSN-P build there rebuilds those two.
pw_start=$SECONDS
EPSSN_SPEC=weights/epssn-pw.json cargo test -p epssn --lib --target-dir target/epssn-p
EPSSN_SPEC=weights/epssn-pw.json cargo test -p epssn-reference --test bitexact_kernels network \
    --target-dir target/epssn-p
(cd qemu-check && EPSSN_SPEC=weights/epssn-pw.json timeout 600 cargo run --release \
    --target thumbv8m.main-none-eabihf --features mve --target-dir ../target/qemu-check-pw)
# Its tank model (weights/epssn-pw-tank, the blob weights/FIRMWARE_WEIGHTS names for this spec):
# bit for bit on the M55 within weights/budgets-m55-epssn-pw.json, and its accuracy guard.
EPSSN_SPEC=weights/epssn-pw.json cargo run -q -p epssn-sil --target-dir target/epssn-p -- \
    --target m55 --frames 3 --faults 0 --json
EPSSN_SPEC=weights/epssn-pw.json cargo test -p host-sim --test accuracy_guard \
    --target-dir target/epssn-p -- --ignored --exact epssn_pw_tank_model_keeps_its_accuracy
echo "(EPSSN-PW step $((SECONDS - pw_start)) s)"

step "fuzzing: every parser, 60 s per target (scripts/fuzz.sh; nightly + cargo-fuzz)"
bash scripts/fuzz.sh 60
