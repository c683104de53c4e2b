"""Moving sets (issue 15) through the driver: the scenes with moving walls run to HDF5 files
that h5py and PedPy open, with the walls' positions per frame equal to their keyframes'
(recomputed here), nobody behind the sweeping barrier, and a crush that ends with status
`infeasible` naming the people, keeping every frame before it."""

from __future__ import annotations

import pathlib

import h5py
import numpy as np
import pedpy
import pytest
import tomllib

import moreau_run
from conftest import ROOT, moreau

SCENES = ROOT / "data" / "scenes"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, pathlib.Path]:
    out = tmp_path_factory.mktemp("moving")
    files = {}
    for name in ("barrier-sweep", "room-closing-door", "rotating-bar"):
        files[name] = out / f"{name}.h5"
        moreau("run", SCENES / f"{name}.toml", "-o", files[name], "--quiet")
    return files


def keyframe_segments(body: dict, t: float) -> np.ndarray:
    """A moving body's segments at time `t`, from its keyframes (linear in time between them,
    held outside), written out here rather than taken from moreau."""
    keys = body["keyframes"]
    times = np.array([k["t"] for k in keys])
    offsets = np.array([k.get("offset", [0.0, 0.0]) for k in keys], dtype=float)
    angles = np.radians([k.get("angle", 0.0) for k in keys])
    off = np.array([np.interp(t, times, offsets[:, 0]), np.interp(t, times, offsets[:, 1])])
    angle = np.interp(t, times, angles)
    points = np.asarray(body.get("line") or body["polygon"], dtype=float)
    pivot = np.asarray(body.get("pivot", points[0]), dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    placed = pivot + off + (points - pivot) @ np.array([[c, s], [-s, c]])
    if "polygon" in body:
        placed = np.vstack([placed, placed[:1]])
    return np.hstack([placed[:-1], placed[1:]])


@pytest.mark.parametrize("name", ["barrier-sweep", "room-closing-door", "rotating-bar"])
def test_the_moving_walls_in_the_file_follow_their_keyframes(runs, name):
    with h5py.File(runs[name]) as f:
        scene = tomllib.loads(f.attrs["scene"])
        times = f["frames/time"][...]
        walls = f["frames/moving_walls"][...]
        names = [n.decode() if isinstance(n, bytes) else n for n in f["moving/name"][...]]
        body = f["moving/body"][...]
        assert f.attrs["status"] == "complete"
    assert names == [b["name"] for b in scene["moving"]]
    assert walls.shape == (len(times), len(body), 4)
    for k, t in enumerate(times):
        expected = np.vstack([keyframe_segments(b, t) for b in scene["moving"]])
        # The panel of the closing door keeps its orientation whatever the scene draws: compare
        # segments as drawn (no reordering), to rounding.
        np.testing.assert_allclose(walls[k], expected, atol=1e-9, err_msg=f"{name} t = {t}")


def test_nobody_is_ever_behind_the_sweeping_barrier_and_pedpy_reads_the_run(runs, tmp_path):
    path = runs["barrier-sweep"]
    run = moreau_run.load(path)
    with h5py.File(path) as f:
        barrier_x = f["frames/moving_walls"][:, 0, 0]
    present = np.isfinite(run.positions[:, :, 0])
    back_edge = np.where(present, run.positions[:, :, 0] - run.radius[None, :], np.inf)
    assert np.all(back_edge.min(axis=1) >= barrier_x - 1e-6)
    # The barrier caught people: the front of the swept crowd moved at its speed, not theirs.
    assert len(run.exits) == 150
    assert run.exits["t"].max() < 25.0

    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=path)
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=path)
    assert walkable.polygon.area == pytest.approx(150.0)
    speed = pedpy.compute_individual_speed(traj_data=traj, frame_step=5)
    assert speed["speed"].max() > 1.1  # pushed at the barrier's 1.2 m/s, above every desired speed
    import plot_run

    assert plot_run.main([str(path), "-o", str(tmp_path / "plots")]) == 0
    out = tmp_path / "sweep.png"
    assert plot_run.main([str(path), "--snapshots", "0,6,12", "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_people_turn_to_the_open_door_when_the_other_closes(runs):
    run = moreau_run.load(runs["room-closing-door"])
    assert len(run.exits) == 60
    # Everyone crosses the dividing wall (x = 8) through the upper door, y in [6.3, 7.5].
    x, y = run.positions[:, :, 0], run.positions[:, :, 1]
    for person in range(x.shape[1]):
        k = np.argmax(np.nan_to_num(x[:, person], nan=-1.0) > 8.1)
        assert 6.3 <= y[k, person] <= 7.5, (person, y[k, person])


CRUSH = """
name = "crush"
seed = 1
[area]
outer = [[0.0, 0.0], [10.0, 0.0], [10.0, 0.5], [2.0, 0.5], [2.0, 3.0], [0.0, 3.0]]
[[exits]]
name = "top"
segment = [[0.0, 3.0], [2.0, 3.0]]
action = "remove"
[[groups]]
name = "corridor"
positions = [[3.0, 0.25], [4.0, 0.25], [5.0, 0.25]]
radius = 0.2
speed = 0.0
destination = "top"
[[groups]]
name = "room"
positions = [[1.0, 2.0]]
radius = 0.2
speed = 0.0
destination = "top"
[[moving]]
name = "barrier"
line = [[2.5, 0.0], [2.5, 0.5]]
keyframes = [{ t = 0.0 }, { t = 8.0, offset = [8.0, 0.0] }]
[time]
horizon = 9.0
step = 0.05
output_interval = 0.5
"""


def test_a_crush_ends_the_run_as_infeasible_keeping_every_frame(tmp_path):
    scene = tmp_path / "crush.toml"
    scene.write_text(CRUSH)
    out = tmp_path / "crush.h5"
    proc = moreau("run", scene, "-o", out, check=False)
    assert proc.returncode == 1, proc.stderr
    assert "infeasible" in proc.stderr and "barrier" in proc.stderr, proc.stderr
    run = moreau_run.load(out)
    assert run.status == "infeasible"
    # Three people in a dead end of 10 − 2.5 − t metres need 1.2 m: no room after t = 6.3 s.
    assert run.time[-1] == pytest.approx(6.0)
    corridor = sorted(int(i) for i in np.flatnonzero(run.positions[0, :, 1] < 0.5))
    assert f"people {corridor}" in proc.stderr, proc.stderr
