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


DEEP_DOOR = """
name = "deep"
[area]
outer = [[0.0, 0.0], [6.0, 0.0], [6.0, 2.5], [8.0, 2.5], [8.0, 0.0], [10.0, 0.0],
         [10.0, 6.0], [8.0, 6.0], [8.0, 3.5], [6.0, 3.5], [6.0, 6.0], [0.0, 6.0]]
[[exits]]
name = "door"
area = [[6.0, 2.5], [8.0, 2.5], [8.0, 3.5], [6.0, 3.5]]
"""


def test_door_width_of_a_door_deeper_than_wide_changed_its_depth():
    """Regression: the width was the longer side of the exit's box; a door 1 m wide in a
    2 m thick wall (x from 6 to 8) got a depth of 0.8 m and kept its 1 m opening."""
    import tomllib

    scene = tomllib.loads(DEEP_DOOR)
    set_door_width(scene, 0.8)
    # The opening (along y, from jamb to jamb) is 2.6–3.4 around the door's centre y = 3;
    # the passage still runs from x = 6 to x = 8.
    assert scene["exits"][0]["area"] == [[6.0, 2.6], [8.0, 2.6], [8.0, 3.4], [6.0, 3.4]]
    assert scene["area"]["outer"] == [
        [0.0, 0.0], [6.0, 0.0], [6.0, 2.6], [8.0, 2.6], [8.0, 0.0], [10.0, 0.0],
        [10.0, 6.0], [8.0, 6.0], [8.0, 3.4], [6.0, 3.4], [6.0, 6.0], [0.0, 6.0]]


def results_table(path, values: dict, times: list[float]) -> None:
    """A results table as a sweep writes it: one complete run per evacuation time (NaN: not
    everyone got out), all with the parameter values `values`."""
    from moreau_ensemble.runner import write_table

    rows = [{"name": f"run{k}", **values, "seed": k, "engine": "driver", "status": "complete",
             "people": 10, "evacuation_time": t, "mean_flow": 1.0} for k, t in enumerate(times)]
    write_table(path, rows)


def drawn_figure(monkeypatch, table, png):
    """The figure `moreau_ensemble.plot.plot` draws (kept from `plt.close`)."""
    from moreau_ensemble import plot

    figures = []
    monkeypatch.setattr(plot.plt, "close", figures.append)
    plot.plot(table, png)
    assert png.is_file()
    return figures[0]


def test_the_mean_evacuation_time_said_over_ten_seeds_when_two_runs_evacuated(tmp_path,
                                                                             monkeypatch):
    """Regression: runs where someone never got out have no evacuation time; the mean was
    over the two that evacuated, titled "over 10 seeds", and a clogging door looked fast."""
    from moreau_ensemble.plot import summary

    nan = float("nan")
    table = tmp_path / "results.csv"
    results_table(table, {"door_width": 0.8}, [20.0, 22.0] + [nan] * 8)
    [row] = summary(table).to_dict("records")
    assert (row["evacuation_mean"], row["evacuated"], row["runs"]) == (21.0, 2, 10)
    figure = drawn_figure(monkeypatch, table, tmp_path / "evacuation.png")
    evacuation = figure.axes[0]
    assert "2 of 10" in evacuation.get_title() and "10 seeds" not in evacuation.get_title()
    assert [t.get_text() for t in evacuation.texts] == ["evacuated 2 of 10"]


def test_plot_raised_key_error_door_width_on_a_sweep_that_does_not_vary_it(tmp_path,
                                                                          monkeypatch):
    """Regression: `--plot` drew against door_width only, and a sweep of crowd sizes (or of
    seeds alone) ended in KeyError: 'door_width'. It draws against what the sweep varies."""
    from moreau_ensemble.runner import write_table

    table = tmp_path / "results.csv"
    rows = [{"name": f"n{n}_seed={s}", "groups.0.count": n, "seed": s, "status": "complete",
             "evacuation_time": t, "mean_flow": 1.0}
            for n, s, t in [(2, 0, 4.0), (2, 1, 6.0), (4, 0, 8.0), (4, 1, 9.0)]]
    write_table(table, rows)
    [axes, _] = drawn_figure(monkeypatch, table, tmp_path / "a.png").axes[:2]
    assert axes.get_xlabel() == "groups.0.count"
    assert axes.lines[0].get_xdata().tolist() == [2, 4]
    assert axes.lines[0].get_ydata().tolist() == [5.0, 8.5]
    # Seeds alone: each seed's run.
    results_table(table, {}, [3.0, 5.0])
    axes = drawn_figure(monkeypatch, table, tmp_path / "b.png").axes[0]
    assert axes.get_xlabel() == "seed"
    assert axes.lines[0].get_xdata().tolist() == [0, 1]
    assert axes.lines[0].get_ydata().tolist() == [3.0, 5.0]


def test_a_base_scene_with_a_relative_wkt_file_failed_every_run(tmp_path):
    """Regression: the base's `[area] wkt_file = "room.wkt"` (beside the base) was copied as
    is into runs/<variant>/scene.toml, where no room.wkt is: every run failed."""
    from conftest import MOREAU
    from moreau_ensemble.task import run_variant

    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "room.wkt").write_text("POLYGON ((0 0, 6 0, 6 6, 0 6, 0 0))")
    (tmp_path / "scenes" / "base.toml").write_text("""
name = "wkt"
[area]
wkt_file = "room.wkt"
[[exits]]
name = "door"
segment = [[6.0, 2.5], [6.0, 3.5]]
action = "remove"
[[groups]]
name = "g"
count = 3
spawn = [[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0]]
radius = 0.2
speed = 1.0
destination = "door"
[time]
horizon = 0.2
step = 0.05
output_interval = 0.1
""")
    (tmp_path / "sweeps").mkdir()
    spec = tmp_path / "sweeps" / "sweep.toml"
    spec.write_text('base = "../scenes/base.toml"\nseeds = 1\n')
    [v] = load_sweep(spec).variants()
    run_dir = tmp_path / "out" / "runs" / v.name
    row = run_variant(v.name, v.values, v.seed, v.scene, str(run_dir), str(MOREAU))
    assert (row["status"], row["error"], row["people"]) == ("complete", "", 3)
