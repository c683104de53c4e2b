#!/usr/bin/env bash
# Runs every test of moreau, Rust (cargo test) then Python (pytest: the HDF5 output, PedPy,
# the driver binary), and ends with one line that adds up all of them.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh

log=$(mktemp)
trap 'rm -f "$log"' EXIT
status=0
cargo test --workspace --release --locked --no-fail-fast 2>&1 | tee "$log" || status=$?

# The Python tests drive target/release/moreau, built by setup.sh above.
# -rP shows what passing tests print (the measured figures, e.g. memory over 10,000 FMU instances).
.venv/bin/python -m pytest tests/python -p no:cacheprovider -rP 2>&1 | tee -a "$log" || status=$?

echo
# cargo: "test result: ok. 12 passed; 0 failed; ..."; pytest: "==== 3 failed, 20 passed in 9.1s ====".
awk '/^test result:/ || /^=+ .* in [0-9.]+s/ {
       for (i = 1; i < NF; i++) {
         if ($(i+1) ~ /^passed/) p += $i
         if ($(i+1) ~ /^(failed|errors?)/) f += $i
       } }
     END { printf "all: %d passed, %d failed\n", p, f }' "$log"
exit "$status"
