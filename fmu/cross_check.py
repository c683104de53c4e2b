#!/usr/bin/env python3
"""The FMUs' cross-check tree, laid out as the FMI Cross-Check rules (4.1) lay out a tool's
test FMUs: data/fmu/cross-check/fmus/{2.0/cs/linux64,3.0/cs/x86_64-linux}/moreau/<version>/
moreau_crowd/ with moreau_crowd_ref.csv, moreau_crowd_in.csv and moreau_crowd_ref.opt (the
.fmu itself is built, not kept: `assemble` copies it in).

    .venv/bin/python fmu/cross_check.py write           # the reference files, from the native driver
    .venv/bin/python fmu/cross_check.py assemble DIR    # the tree plus the built FMUs, in DIR

The reference result is computed by the native driver (`moreau run`, no FMI layer involved):
the paper's room for 20 s with the inputs held at speed_factor = 1 and door_open = true,
sampled every 0.2 s (the experiment's communication step): people inside and evacuated from
the run file's exit records, the mean speed over each 0.2 s from its positions, and the
smallest gap between two people or a person and a wall from its positions and its walkable
area (shapely). The tests simulate each FMU with fmpy on the input file and check the result
with fmpy's cross-check validator, and to 1e-9 against this reference.
"""

from __future__ import annotations

import argparse
import pathlib
import shutil
import subprocess
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
TREE = ROOT / "data" / "fmu" / "cross-check"
MODEL = "moreau_crowd"
TOOL = "moreau"
VERSION = "0.1.0"
# FMI version, platform (as the FMU's binaries/ directory names it), the built FMU.
VARIANTS = {
    "2.0": ("linux64", ROOT / "target" / "fmu" / "moreau-crowd-fmi2.fmu"),
    "3.0": ("x86_64-linux", ROOT / "target" / "fmu" / "moreau-crowd-fmi3.fmu"),
}
SCENE = ROOT / "data" / "scenes" / "room-150.toml"
MOREAU = ROOT / "target" / "release" / "moreau"
STOP, STEP = 20.0, 0.2
OUTPUTS = ("people_inside", "people_evacuated", "mean_speed", "min_gap")
# Written as integers (Booleans as 0 and 1, as the rules ask).
INTEGERS = {"people_inside", "people_evacuated", "door_open"}


def model_dir(root: pathlib.Path, fmi_version: str) -> pathlib.Path:
    """fmus/{FMI_Version}/{FMI_Type}/{Platform}/{Tool_Name}/{Tool_Version}/{Model_Name}."""
    platform, _ = VARIANTS[fmi_version]
    return root / "fmus" / fmi_version / "cs" / platform / TOOL / VERSION / MODEL


def reference(run_file: pathlib.Path) -> np.ndarray:
    """The reference rows (time, then OUTPUTS) from a native run file of the room."""
    import shapely
    from scipy.spatial import cKDTree

    sys.path.insert(0, str(ROOT / "python"))
    import moreau_run

    run = moreau_run.load(run_file)
    walls = shapely.from_wkt(run.attrs["wkt_geometry"]).boundary
    people = len(run.radius)
    rows = []
    times = np.round(np.arange(0.0, STOP + STEP / 2, STEP), 10)
    for k, t in enumerate(times):
        f = int(np.argmin(np.abs(run.time - t)))
        assert abs(run.time[f] - t) < 1e-9, f"no native frame at t = {t}"
        passed = int(np.sum(run.exits["t"] <= t + 1e-9))
        if k == 0:
            speed = 0.0
        else:
            q0, q1 = run.positions[f_prev], run.positions[f]
            both = np.isfinite(q0[:, 0]) & np.isfinite(q1[:, 0])
            speed = float(np.linalg.norm(q1[both] - q0[both], axis=1).mean() / STEP) if both.any() else 0.0
        here = np.isfinite(run.positions[f][:, 0])
        pts, r = run.positions[f][here], run.radius[here]
        pairs = cKDTree(pts).query_pairs(1.0, output_type="ndarray")
        gaps = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1) - r[pairs[:, 0]] - r[pairs[:, 1]]
        to_walls = shapely.distance(walls, shapely.points(pts)) - r
        gap = float(min(gaps.min(initial=np.inf), to_walls.min(initial=np.inf)))
        rows.append((t, people - passed, passed, speed, gap if np.isfinite(gap) else 1.0))
        f_prev = f
    return np.array(rows, dtype=[("time", float), *((n, float) for n in OUTPUTS)])


def write_csv(path: pathlib.Path, rows: np.ndarray) -> None:
    """A CSV as the cross-check rules want it: quoted names, C float literals, no comments."""
    names = rows.dtype.names
    lines = [",".join(f'"{n}"' for n in names)]
    for row in rows:
        lines.append(",".join(str(int(x)) if n in INTEGERS else repr(float(x))
                              for n, x in zip(names, row)))
    path.write_text("\n".join(lines) + "\n")


def write() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        run_file = pathlib.Path(tmp) / "room.h5"
        subprocess.run([str(MOREAU), "run", str(SCENE), "-o", str(run_file), "--quiet"],
                       check=True, stdin=subprocess.DEVNULL)
        ref = reference(run_file)
    inputs = np.array([(0.0, 1.0, 1.0), (STOP, 1.0, 1.0)],
                      dtype=[("time", float), ("speed_factor", float), ("door_open", float)])
    for version in VARIANTS:
        d = model_dir(TREE, version)
        d.mkdir(parents=True, exist_ok=True)
        write_csv(d / f"{MODEL}_ref.csv", ref)
        write_csv(d / f"{MODEL}_in.csv", inputs)
        (d / f"{MODEL}_ref.opt").write_text(
            f"StartTime,0.0\nStopTime,{STOP}\nStepSize,{STEP}\nRelTol,0.0001\n")
        print(f"wrote {d.relative_to(ROOT)}/{MODEL}_{{ref.csv,in.csv,ref.opt}}")


def assemble(out: pathlib.Path) -> pathlib.Path:
    """The tree with each built FMU as {Model_Name}.fmu, in `out` (returned)."""
    shutil.copytree(TREE, out, dirs_exist_ok=True)
    for version, (_, fmu) in VARIANTS.items():
        if not fmu.is_file():
            sys.exit(f"{fmu} is missing: run python3 fmu/package.py")
        shutil.copy(fmu, model_dir(out, version) / f"{MODEL}.fmu")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("write", help="write the reference files from the native driver")
    a = sub.add_parser("assemble", help="copy the tree and the built FMUs into DIR")
    a.add_argument("dir", type=pathlib.Path)
    args = parser.parse_args()
    if args.command == "write":
        write()
    else:
        print(f"assembled {assemble(args.dir)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
