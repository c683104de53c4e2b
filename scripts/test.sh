#!/usr/bin/env bash
# Runs every test of moreau (Rust now; the Python suites join here as they come) and ends
# with one line that adds up all of them.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh

log=$(mktemp)
trap 'rm -f "$log"' EXIT
status=0
cargo test --workspace --release --locked 2>&1 | tee "$log" || status=$?

echo
awk '/^test result:/ { for (i = 1; i <= NF; i++) { if ($(i+1) ~ /^passed/) p += $i; if ($(i+1) ~ /^failed/) f += $i } }
     END { printf "all: %d passed, %d failed\n", p, f }' "$log"
exit "$status"
