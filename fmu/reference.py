#!/usr/bin/env python3
"""Writes the reference result for the FMI 2 FMU on the paper's room, as Reference-FMUs keep
one per model, computed without the FMU: `.venv/bin/python fmu/reference.py` writes
data/fmu/room-150-ref.csv.

The experiment (also the test's, tests/python/test_fmu.py): the room (data/scenes/room-150.toml,
the FMU's default scene) for 20 s, outputs every 0.2 s, the door closes at t = 10.1 s (an input
event: fmpy takes a communication step of 0.1 s to it and one of 0.1 s from it), the speed
factor is 1.

The reference comes from the native driver, the `moreau` Python module (crates/py), with no
FMI layer and no co-simulation master: `moreau.Simulation` on the same scene file, stepped with
`advance_to` to the same communication points, the door closed with `set_exit_open("door",
False)` at t = 10.1 s (what the FMU does when its input `door_open` turns false: the same
`Simulation::set_exit_open`, the exit's closing wall from the next step on). The outputs are
computed here from the native run, in numpy and shapely, by their definitions in the model
description:

- people_evacuated / people_inside: the native run's exit records (who entered the door by
  then; not the positions: a person in the doorway when it closes is pushed back into the room
  and stays counted, as the FMU counts them);
- internal_steps: the native run's step count;
- mean_speed: the mean distance the people moved over the communication step, over its length;
- min_gap: the smallest gap between two people (centre distance less both radii, from the
  positions) or between a person and a wall (shapely: distance to the walkable area's boundary,
  and once the door is closed to its closing wall, the mid-line of the door's bounding box along
  its longer side, less the radius);
- eps: the certified ε of the native run's last step (a solver certificate, not a function of
  the positions).
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
FMU = ROOT / "target" / "fmu" / "moreau-crowd-fmi2.fmu"
SCENE = ROOT / "data" / "scenes" / "room-150.toml"
REFERENCE = ROOT / "data" / "fmu" / "room-150-ref.csv"
STOP = 20.0
OUTPUT_INTERVAL = 0.2
DOOR_CLOSES = 10.1
# The columns of the FMU's result, in fmpy's order.
COLUMNS = [("time", float), ("mean_speed", float), ("min_gap", float), ("eps", float),
           ("people_inside", np.int32), ("people_evacuated", np.int32),
           ("internal_steps", np.int32)]


def experiment(fmu=FMU):
    """The experiment run on the FMU by fmpy (a numpy structured array, one row per output)."""
    from fmpy import simulate_fmu

    signals = np.array(
        [(0.0, 1.0, True), (DOOR_CLOSES, 1.0, True), (DOOR_CLOSES, 1.0, False), (STOP, 1.0, False)],
        dtype=[("time", float), ("speed_factor", float), ("door_open", bool)],
    )
    return simulate_fmu(str(fmu), stop_time=STOP, output_interval=OUTPUT_INTERVAL, input=signals)


def communication_points() -> list[float]:
    """The communication points fmpy's co-simulation loop reaches in `experiment`: the regular
    points `(n + 1) · 0.2` (computed as fmpy computes them), and the input event 10.1 s in
    between."""
    points = [(n + 1) * OUTPUT_INTERVAL for n in range(int(round(STOP / OUTPUT_INTERVAL)))]
    points.append(DOOR_CLOSES)
    return sorted(points)


def closing_wall(scene):
    """The wall that closes the room's door: the mid-line of the door area's bounding box along
    its longer side (README, "changes during a run")."""
    import shapely

    area = next(e for e in scene.to_dict()["exits"] if e["name"] == "door")["area"]
    x0, y0, x1, y1 = shapely.Polygon(area).bounds
    if y1 - y0 >= x1 - x0:
        return shapely.LineString([(0.5 * (x0 + x1), y0), (0.5 * (x0 + x1), y1)])
    return shapely.LineString([(x0, 0.5 * (y0 + y1)), (x1, 0.5 * (y0 + y1))])


def min_gap(positions: np.ndarray, radii: np.ndarray, walls) -> float:
    """The smallest gap between two people or a person and a wall (m); 1 when nobody is within
    1 m of anything (the FMU's value then)."""
    import shapely
    from scipy.spatial import cKDTree

    pairs = cKDTree(positions).query_pairs(1.0, output_type="ndarray")
    gaps = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1) \
        - radii[pairs[:, 0]] - radii[pairs[:, 1]]
    to_walls = shapely.distance(walls, shapely.points(positions)) - radii
    gap = float(min(gaps.min(initial=np.inf), to_walls.min(initial=np.inf)))
    return gap if gap <= 1.0 else 1.0


def native_experiment(scene=SCENE) -> np.ndarray:
    """The experiment run by the native driver, its outputs computed from the native positions
    (a numpy structured array with the FMU result's columns)."""
    import moreau
    import shapely

    sim = moreau.Simulation(str(scene))
    people = sim.total_people
    open_walls = shapely.from_wkt(sim.scene.wkt).boundary
    closed_walls = shapely.union(open_walls, closing_wall(sim.scene))

    def by_id() -> np.ndarray:
        q = np.full((people, 2), np.nan)
        q[sim.ids] = sim.positions
        return q

    def row(t: float, speed: float, walls) -> tuple:
        passed = len(sim.exit_records())
        report = sim.last_report
        return (t, speed, min_gap(sim.positions, sim.radii, walls),
                report["eps"] if report is not None else 0.0,
                people - passed, passed, sim.steps)

    rows = [row(0.0, 0.0, open_walls)]
    walls, t = open_walls, 0.0
    for point in communication_points():
        if t >= DOOR_CLOSES or np.isclose(t, DOOR_CLOSES):
            sim.set_exit_open("door", False)
            walls = closed_walls
        before = by_id()
        # The FMU steps to its own time plus the communication step size fmpy gives it.
        sim.advance_to(sim.time + (point - t))
        after = by_id()
        both = np.isfinite(before[:, 0]) & np.isfinite(after[:, 0])
        moved = np.linalg.norm(after[both] - before[both], axis=1)
        speed = float(moved.mean() / (point - t)) if both.any() else 0.0
        t = point
        rows.append(row(t, speed, walls))
    return np.array(rows, dtype=COLUMNS)


def write_csv(path: pathlib.Path, rows: np.ndarray) -> None:
    """The CSV fmpy writes (`fmpy.util.write_csv`; read back with `fmpy.util.read_csv`): quoted
    names, then each value as Python prints it (floats to the last bit)."""
    names = rows.dtype.names
    lines = [",".join(f'"{n}"' for n in names)]
    for r in rows:
        lines.append(",".join(str(int(r[n])) if rows.dtype[n].kind == "i" else repr(float(r[n]))
                              for n in names))
    path.write_text("\n".join(lines) + "\n")


def main() -> int:
    result = native_experiment()
    REFERENCE.parent.mkdir(parents=True, exist_ok=True)
    write_csv(REFERENCE, result)
    print(f"wrote {REFERENCE} ({len(result)} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
