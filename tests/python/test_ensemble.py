"""Ensembles on Dask: a sweep on a LocalCluster of 2 workers gives one row per run, records
failures without stopping, and a resumed sweep runs nothing twice."""

from __future__ import annotations

import csv

import pytest
from dask.distributed import Client, LocalCluster

from conftest import ROOM
from moreau_ensemble import load_sweep, run_sweep
from moreau_ensemble.sweep import set_door_width
from moreau_ensemble.task import evacuation


@pytest.fixture(scope="module")
def client():
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


def sweep_file(tmp_path):
    spec = tmp_path / "sweep.toml"
    spec.write_text(f"""
base = "{ROOM}"
seeds = 3
[set]
"time.horizon" = 1.0
"time.output_interval" = 0.5
"solver.kind" = "auto"
[vary]
door_width = [1.0, 1.4]
"groups.0.radius" = [0.2, -0.2]
""")
    return spec


def test_a_sweep_runs_on_two_workers_records_failures_and_resumes(client, tmp_path):
    sweep = load_sweep(sweep_file(tmp_path))
    out = tmp_path / "out"
    rows = run_sweep(sweep, out, client, log=lambda *a: None)
    assert len(rows) == 12
    assert len({r["name"] for r in rows}) == 12
    assert len(client.scheduler_info()["workers"]) == 2
    with (out / "results.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [r["name"] for r in table] == [r["name"] for r in rows]
    for r in rows:
        if r["groups.0.radius"] < 0:
            assert r["status"] == "failed", r
            assert "exit 2" in r["error"] and "radius" in r["error"], r["error"]
        else:
            assert r["status"] == "complete", r
            assert r["people"] == 150 and (out / "runs" / r["name"] / "run.h5").is_file()
    # Variants are named deterministically, one directory each.
    assert (out / "runs" / "door_width=1.4_groups.0.radius=0.2_seed=2").is_dir()

    # Resume: nothing runs again; the outputs are untouched.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/run.h5")}
    again = run_sweep(sweep, out, client, log=lambda *a: None)
    assert all(r["reused"] for r in again)
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/run.h5")} == stamps
    assert [r["status"] for r in again] == [r["status"] for r in rows]

    # A run whose output went missing is the only one run again.
    victim = next(r for r in rows if r["status"] == "complete")
    (out / "runs" / victim["name"] / "run.h5").unlink()
    third = run_sweep(sweep, out, client, log=lambda *a: None)
    rerun = [r["name"] for r in third if not r["reused"]]
    assert rerun == [victim["name"]]

    # Regression: a sweep whose `[set]` changed reused every row of the old scene (matched
    # by name alone): the rows of a 1 s horizon were kept for a 0.5 s one.
    spec = sweep_file(tmp_path)
    spec.write_text(spec.read_text().replace('"time.horizon" = 1.0', '"time.horizon" = 0.5'))
    fourth = run_sweep(load_sweep(spec), out, client, log=lambda *a: None)
    assert not any(r["reused"] for r in fourth)
    for r in fourth:
        assert 'horizon = 0.5' in (out / "runs" / r["name"] / "scene.toml").read_text()


def test_door_width_resizes_the_door_and_its_walls():
    import tomllib

    scene = tomllib.loads(ROOM.read_text())
    set_door_width(scene, 2.0)
    ys = sorted({p[1] for p in scene["exits"][0]["area"]})
    assert ys == [4.0, 6.0]
    outer_ys = {p[1] for p in scene["area"]["outer"]}
    assert {4.0, 6.0} <= outer_ys and not {4.4, 5.6} & outer_ys


def test_evacuation_time_and_flow():
    assert evacuation([1.0, 2.0, 3.0], 3) == (3.0, 1.0)
    evac, flow = evacuation([1.0, 3.0], 5)
    assert evac != evac and flow == 0.5  # NaN: two of five never got out


def test_door_width_narrowed_the_other_door_at_the_same_height():
    """Regression: every outline vertex at the first door's ends moved, so the east door of
    room-two-exits (at the same height) narrowed with the west one and its exit area reached
    into the wall."""
    import tomllib

    from conftest import ROOT

    scene = tomllib.loads((ROOT / "data" / "scenes" / "room-two-exits.toml").read_text())
    east_before = [p[:] for p in scene["area"]["outer"] if p[0] >= 12.0]
    set_door_width(scene, 0.8)
    assert sorted({p[1] for p in scene["exits"][0]["area"]}) == [3.6, 4.4]
    assert [p for p in scene["area"]["outer"] if p[0] >= 12.0] == east_before
    west = {p[1] for p in scene["area"]["outer"] if p[0] <= 0.0}
    assert {3.6, 4.4} <= west and not {3.4, 4.6} & west
