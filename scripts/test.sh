#!/usr/bin/env bash
# Runs every test of moreau, Rust (cargo test) then Python (pytest: the HDF5 output, PedPy,
# the driver binary), and ends with one line that adds up all of them.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh

log=$(mktemp)
trap 'rm -f "$log"' EXIT
status=0 cargo=0 pytest=0
cargo test --workspace --release --locked --no-fail-fast 2>&1 | tee "$log" || cargo=$?

# The Python tests drive target/release/moreau, built by setup.sh above.
# -rP shows what passing tests print (the measured figures, e.g. memory over 10,000 FMU instances).
.venv/bin/python -m pytest tests/python -p no:cacheprovider -rP 2>&1 | tee -a "$log" || pytest=$?
if [ "$cargo" -ne 0 ]; then status=$cargo; fi
if [ "$pytest" -ne 0 ]; then status=$pytest; fi

echo
# cargo: "test result: ok. 12 passed; 0 failed; ..."; pytest: "==== 3 failed, 20 passed in 9.1s ====".
# A run that crashed (a test binary or the Python interpreter killed by a signal) prints no
# such line for what it did not finish: the last line then says so, whatever the counts.
awk -v cargo="$cargo" -v pytest="$pytest" '
     /^test result:/ || /^=+ .* in [0-9.]+s/ {
       for (i = 1; i < NF; i++) {
         if ($(i+1) ~ /^passed/) p += $i
         if ($(i+1) ~ /^(failed|errors?)/) f += $i
       } }
     function said(who, s) {
       if (s >= 128) return sprintf("; %s was killed by signal %d: the tests after it did not run", who, s - 128)
       if (s != 0 && f == 0) return sprintf("; %s exited with status %d", who, s)
       return ""
     }
     END { printf "all: %d passed, %d failed%s%s\n", p, f, said("cargo test", cargo), said("pytest", pytest) }' "$log"
exit "$status"
