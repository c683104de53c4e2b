"""Fixtures of the Python tests: the driver binary, and the paper's room run once to HDF5."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "python"))

MOREAU = ROOT / "target" / "release" / "moreau"
ROOM = ROOT / "data" / "scenes" / "room-150.toml"
DENSE = ROOT / "data" / "scenes" / "dense-2000.toml"


def moreau(*args, check=True, timeout=600, **kwargs) -> subprocess.CompletedProcess:
    """Runs the driver binary (built by scripts/setup.sh) with no standard input."""
    if not MOREAU.is_file():
        pytest.fail(f"{MOREAU} is missing: run ./scripts/setup.sh first")
    proc = subprocess.run([str(MOREAU), *map(str, args)], capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=timeout, **kwargs)
    if check and proc.returncode != 0:
        pytest.fail(f"moreau {' '.join(map(str, args))} exited {proc.returncode}:\n"
                    f"{proc.stdout}\n{proc.stderr}")
    return proc


@pytest.fixture(scope="session")
def room_run(tmp_path_factory) -> pathlib.Path:
    """The paper's room (150 people, 20 s), run once to an HDF5 file with a JSON summary."""
    out = tmp_path_factory.mktemp("room") / "room-150.h5"
    moreau("run", ROOM, "-o", out, "--quiet", "--summary-json", out.with_suffix(".json"))
    return out
