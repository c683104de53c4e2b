#!/usr/bin/env python3
"""Writes the reference result of the FMI 2 FMU on the paper's room, as Reference-FMUs keep
one per model: `.venv/bin/python fmu/reference.py` writes data/fmu/room-150-ref.csv.

The experiment (also the test's, tests/python/test_fmu.py): 20 s, outputs every 0.2 s, the
door closes at t = 10.1 s (an input event: fmpy then takes communication steps of 0.1 s
around it), the speed factor is 1.
"""

import pathlib
import sys

import numpy as np
from fmpy import simulate_fmu
from fmpy.util import write_csv

ROOT = pathlib.Path(__file__).resolve().parents[1]
FMU = ROOT / "target" / "fmu" / "moreau-crowd-fmi2.fmu"
REFERENCE = ROOT / "data" / "fmu" / "room-150-ref.csv"
DOOR_CLOSES = 10.1


def experiment(fmu=FMU):
    """The reference experiment's result (a numpy structured array, one row per output)."""
    signals = np.array(
        [(0.0, 1.0, True), (DOOR_CLOSES, 1.0, True), (DOOR_CLOSES, 1.0, False), (20.0, 1.0, False)],
        dtype=[("time", float), ("speed_factor", float), ("door_open", bool)],
    )
    return simulate_fmu(str(fmu), stop_time=20.0, output_interval=0.2, input=signals)


def main() -> int:
    result = experiment()
    REFERENCE.parent.mkdir(parents=True, exist_ok=True)
    write_csv(str(REFERENCE), result)
    print(f"wrote {REFERENCE} ({len(result)} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
