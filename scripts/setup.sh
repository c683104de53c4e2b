#!/usr/bin/env bash
# Installs what moreau needs on a Debian machine and builds it. Idempotent: safe to rerun.
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages (HDF5 for the output writer, pkg-config to find it, Python for analysis,
# Chromium and its driver for the player's browser test, ffmpeg for MP4 animations, binutils'
# strip for the FMU's library).
missing=()
for pkg in pkg-config libhdf5-dev chromium chromium-driver ffmpeg binutils; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
command -v python3 >/dev/null 2>&1 || missing+=(python3)
# Debian's python3 makes venvs only with python3-venv (ensurepip).
if ! python3 -c "import ensurepip" >/dev/null 2>&1; then missing+=(python3-venv); fi
if ((${#missing[@]})); then
  sudo=""
  [ "$(id -u)" = 0 ] || sudo="sudo"
  echo "setup: installing ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found; install Rust (https://rustup.rs) and rerun" >&2
  exit 1
fi

# The Rust build (the binary ends up in target/release/moreau). The Python module is built by
# maturin below (with the venv's interpreter: a plain cargo build of it would make the two
# rebuild pyo3 in turn).
cargo build --release --workspace --locked --exclude moreau-py

# The Python venv (h5py, PedPy, matplotlib, pytest, selenium), reinstalled when the requirements change.
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  python3 -m venv .venv
fi
want=$(cat python/requirements.txt python/pyproject.toml | sha256sum | cut -d' ' -f1)
if [ "$(cat .venv/.requirements.sha256 2>/dev/null)" != "$want" ]; then
  echo "setup: installing python/requirements.txt and the moreau Python package into .venv"
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -r python/requirements.txt
  # Editable: python/moreau_run.py, plot_run.py and moreau_ensemble/ as they are in the tree.
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -e python
  echo "$want" > .venv/.requirements.sha256
fi

# The Python module `moreau` (crates/py): its wheel, built by the command the README gives
# (HDF5 linked statically: CMake from the venv builds it once, ~7 min, then it is cached in
# target/), installed into .venv; rebuilt only when the Rust or Python sources change.
py_want=$(find Cargo.toml Cargo.lock crates -type f \( -name '*.rs' -o -name '*.toml' -o -name '*.py' \
  -o -name '*.pyi' -o -name Cargo.lock \) -not -path '*/target/*' | LC_ALL=C sort | xargs sha256sum | sha256sum | cut -d' ' -f1)
if [ "$(cat .venv/.moreau-py.sha256 2>/dev/null)" != "$py_want" ]; then
  echo "setup: building the moreau Python module (crates/py) and installing it into .venv"
  rm -f target/wheels/moreau-*.whl
  PATH="$PWD/.venv/bin:$PATH" .venv/bin/maturin build --release --locked -m crates/py/Cargo.toml \
    -o target/wheels </dev/null
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps --force-reinstall \
    target/wheels/moreau-*.whl
  echo "$py_want" > .venv/.moreau-py.sha256
fi

# The FMUs (target/fmu/*.fmu) from the library the build above made.
python3 fmu/package.py --no-build >/dev/null
