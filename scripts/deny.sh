#!/usr/bin/env bash
# Supply-chain checks with cargo-deny (config: deny.toml) for each of the five cargo workspaces:
# the host workspace, boards/mps2-an500/, qemu-check/, boards/stm32h743/, boards/mps3-an547/ and fuzz/.
#
# - licences, bans (duplicate versions, wildcard requirements) and sources (crates.io only) are
#   always checked, on each workspace's Cargo.lock; any violation fails the script.
# - advisories (the RustSec database) are checked when the database can be fetched now, or when
#   a recent copy is already where cargo-deny keeps it; otherwise the output says plainly that
#   they were NOT checked, and why (set EPSSN_DENY_REQUIRE_ADVISORIES=1 to fail instead).
#
# Installs cargo-deny from crates.io (`cargo install --locked`) when it is missing.
#   EPSSN_ADVISORY_DB_MAX_AGE_DAYS  newest accepted age of a copy not fetched now (default 90)
#   EPSSN_DENY_REQUIRE_ADVISORIES   1: fail when advisories cannot be checked
#   EPSSN_DENY_LOCKED               1: check the lock files as committed (--locked), not updated
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD

deny_version=0.20.2
workspaces=(. boards/mps2-an500 qemu-check boards/stm32h743 boards/mps3-an547 fuzz)
# Graphs that end up in a firmware image: a second version of a crate there fails the check
# unless deny.toml skips it with a reason (the host and fuzz graphs only report duplicates).
firmware_graphs=" boards/mps2-an500 qemu-check boards/stm32h743 boards/mps3-an547 "
# One deny.toml serves five graphs, so an allowance or skip may be unused in all but one of
# them: cargo-deny's per-graph notices about that are quieted here, and the script reports an
# entry that none of the five graphs uses (further below).
unused_codes=(license-not-encountered license-exception-not-encountered unmatched-skip unnecessary-skip
    unmatched-skip-root)

start=$SECONDS
step() { printf '\n--- %s\n' "$*"; }

if ! cargo deny --version 2>/dev/null | grep -qx "cargo-deny $deny_version"; then
    step "installing cargo-deny $deny_version from crates.io"
    install_start=$SECONDS
    cargo install --locked cargo-deny --version "$deny_version"
    echo "(cargo-deny installed in $((SECONDS - install_start)) s)"
fi
cargo deny --version

# cargo-deny on workspace $1 with the global options that select its graph, then the rest of
# the arguments. It runs inside the workspace, as its builds do, so that cargo reads the same
# .cargo/config.toml and rust-toolchain.toml; like them it brings Cargo.lock up to date with
# the manifests unless EPSSN_DENY_LOCKED=1, which checks the lock files as they are (--locked).
deny_in() {
    local ws=$1
    shift
    local a=(--manifest-path "$root/$ws/Cargo.toml" --config "$root/deny.toml")
    [ "${EPSSN_DENY_LOCKED:-0}" = 1 ] && a+=(--locked)
    # The root manifest is a package and the workspace: check every member, not only `epssn`.
    [ "$ws" = . ] && a+=(--workspace)
    (cd "$ws" && cargo deny "${a[@]}" "$@")
}

failed=()
unused_log=$(mktemp)
trap 'rm -f "$unused_log"' EXIT

# Appends to $unused_log the deny.toml entries that the graph of workspace $1 does not use, as
# "line span", from cargo-deny's JSON diagnostics with the codes in $2 for the checks $3...
log_unused() {
    local ws=$1 codes=$2
    shift 2
    deny_in "$ws" --offline --format json check "$@" 2>&1 >/dev/null |
        jq -r --arg codes "$codes" \
            'select(.type == "diagnostic" and ((.fields.code) as $c | $codes | split(" ") | index($c)))
             | .fields.labels[0] | "\(.line) \(.span)"' |
        sort -u >>"$unused_log" || true
}

# Prints the entries logged as unused by every one of the graphs.
report_unused() {
    local unused
    unused=$(sort "$unused_log" | uniq -c | awk -v n="${#workspaces[@]}" '$1 == n { $1 = ""; print "  deny.toml:" substr($0, 2) }')
    if [ -n "$unused" ]; then
        echo "warning: $1 in deny.toml but used by no graph (remove them):"
        echo "$unused"
    else
        echo "none: every one is used by at least one graph"
    fi
    : >"$unused_log"
}

for ws in "${workspaces[@]}"; do
    lints=()
    for code in "${unused_codes[@]}"; do lints+=(--allow "$code"); done
    what="$ws: licenses, bans, sources"
    if [[ "$firmware_graphs" == *" $ws "* ]]; then
        lints+=(--deny duplicate)
        what+=" (duplicate versions denied)"
    fi
    step "$what"
    if ! deny_in "$ws" check "${lints[@]}" licenses bans sources; then
        failed+=("$ws (licenses/bans/sources)")
    fi
    log_unused "$ws" "${unused_codes[*]}" licenses bans
done

step "allowed licences, licence exceptions and duplicate skips that none of the ${#workspaces[@]} graphs uses"
report_unused "allowed or skipped"

step "advisories (RustSec database)"
max_age_days=${EPSSN_ADVISORY_DB_MAX_AGE_DAYS:-90}
# Where cargo-deny $deny_version keeps its clone of the db-urls entry of deny.toml
# (https://github.com/rustsec/advisory-db): db-path, then the URL's last segment and its hash.
db="${CARGO_HOME:-$HOME/.cargo}/advisory-dbs/advisory-db-3157b0e258782691"
advisories_state="not checked"
why_not=""
fetched=no
if fetch_out=$(timeout 300 cargo deny --manifest-path Cargo.toml fetch db 2>&1); then
    fetched=yes
    echo "fetched the advisory database into $db"
else
    echo "could not fetch the advisory database:"
    printf '%s\n' "$fetch_out" | grep -v '^\s*$' | tail -n 3 | sed 's/^/  /'
fi
if [ -d "$db/.git" ] && commit_time=$(git -C "$db" log -1 --format=%ct HEAD 2>/dev/null); then
    commit_date=$(git -C "$db" log -1 --format=%cs HEAD)
    age_days=$(( ($(date +%s) - commit_time) / 86400 ))
    echo "database at $db: last commit $commit_date ($age_days days ago)"
    if [ "$fetched" = no ] && [ "$age_days" -gt "$max_age_days" ]; then
        why_not="it could not be fetched and the copy at $db is $age_days days old (last commit $commit_date; more than $max_age_days accepted)"
    fi
else
    why_not="it could not be fetched (error above) and there is no copy at $db"
fi

if [ -z "$why_not" ]; then
    advisories_state="checked against the database of $commit_date"
    for ws in "${workspaces[@]}"; do
        step "$ws: advisories"
        # --offline: the database was fetched above (or is the copy), nothing more to fetch.
        if ! out=$(deny_in "$ws" --offline check --allow advisory-not-detected advisories 2>&1); then
            printf '%s\n' "$out"
            if grep -q 'failed to load advisory database\|repository is stale\|failed to get .* metadata' <<<"$out"; then
                why_not="cargo-deny could not load the database at $db (see above)"
                advisories_state="not checked"
                break
            fi
            failed+=("$ws (advisories)")
        else
            printf '%s\n' "$out"
        fi
        log_unused "$ws" advisory-not-detected advisories
    done
    if [ -z "$why_not" ]; then
        step "ignored advisories that none of the ${#workspaces[@]} graphs has"
        report_unused "ignored"
    fi
fi

if [ -n "$why_not" ]; then
    cat <<EOF

========================================================================================
ADVISORIES NOT CHECKED: the RustSec advisory database was not available: $why_not.
No crate of any workspace was checked for known vulnerabilities, unmaintained or unsound
crates, or yanked versions. Licences, bans and sources were checked.
To check advisories: run this script where github.com is reachable, or put a git clone of
https://github.com/rustsec/advisory-db at most $max_age_days days old at
$db
========================================================================================
EOF
    if [ "${EPSSN_DENY_REQUIRE_ADVISORIES:-0}" = 1 ]; then
        failed+=("advisories (not checked, EPSSN_DENY_REQUIRE_ADVISORIES=1)")
    fi
fi

echo
if [ ${#failed[@]} -gt 0 ]; then
    echo "deny.sh: FAILED: ${failed[*]} ($((SECONDS - start)) s)"
    exit 1
fi
echo "deny.sh: licences, bans, sources ok in ${#workspaces[@]} workspaces; advisories $advisories_state ($((SECONDS - start)) s)"
