#!/usr/bin/env bash
# Installs what moreau needs on a Debian machine and builds it. Idempotent: safe to rerun.
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages (HDF5 for the output writer, pkg-config to find it).
missing=()
for pkg in pkg-config libhdf5-dev; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
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

# The Rust build (the binary ends up in target/release/moreau).
cargo build --release --workspace --locked
