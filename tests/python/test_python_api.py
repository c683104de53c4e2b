"""The Python module `moreau` (crates/py) against the driver binary and against itself: the
room stepped in-process gives `moreau run`'s positions bit for bit, `moreau.run` writes the
CLI's file, state and pickling continue runs identically (also through a Dask worker), bad
scenes and bad inputs raise and leave the simulation usable, two threads step two
simulations at once, and the wheel built by the README's command installs into a fresh
venv and runs."""

from __future__ import annotations

import json
import math
import os
import pathlib
import pickle
import re
import subprocess
import sys
import threading
import time

import h5py
import numpy as np
import pytest

import moreau
from conftest import MOREAU, ROOM, ROOT, moreau as moreau_cli

ROOM60 = ROOT / "data" / "scenes" / "room-60.toml"


def by_id(sim: moreau.Simulation, people: int) -> np.ndarray:
    """The simulation's positions laid out like /frames/positions: (people, 2), NaN if absent."""
    out = np.full((people, 2), np.nan)
    out[sim.ids] = sim.positions
    return out


def short_room(horizon: float, **extra) -> moreau.Scene:
    d = moreau.Scene.from_file(ROOM).to_dict()
    d["time"]["horizon"] = horizon
    for key, value in extra.items():
        d[key] = value
    return moreau.Scene.from_dict(d)


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


def test_the_room_stepped_from_python_is_moreau_run_bit_for_bit(room_run):
    with h5py.File(room_run) as f:
        times = f["frames/time"][:]
        expected = f["frames/positions"][:]
        people = f["people/radius"].shape[0]
    assert len(times) == 201 and expected.shape == (201, 150, 2)

    # advance_to each frame time, as the driver's loop stops there.
    sim = moreau.Simulation(moreau.Scene.from_file(ROOM))
    assert same_bits(by_id(sim, people), expected[0])
    for k in range(1, len(times)):
        sim.advance_to(float(times[k]))
        assert sim.time == times[k]
        assert same_bits(by_id(sim, people), expected[k]), f"frame {k} (t = {times[k]})"

    # step() takes the same steps: compare wherever a step lands on a frame time.
    stepped = moreau.Simulation(ROOM)
    k = 1
    while k < len(times):
        report = stepped.step()
        assert report["t"] == stepped.time and report["status"] == "converged"
        if abs(stepped.time - times[k]) < 1e-9:
            assert same_bits(by_id(stepped, people), expected[k]), f"frame {k} by step()"
            k += 1
    assert stepped.steps == sim.steps


def test_run_writes_the_file_of_moreau_run(room_run, tmp_path):
    out = tmp_path / "py.h5"
    summary = moreau.run(moreau.Scene.from_file(ROOM), out)
    assert summary["status"] == "complete" and summary["people"] == 150
    # The message told Python callers to "pass --force", the CLI's flag.
    with pytest.raises(FileExistsError, match=r"pass force=True to overwrite") as e:
        moreau.run(ROOM, out)
    assert "--force" not in str(e.value)
    compared = []
    with h5py.File(room_run) as cli, h5py.File(out) as py:
        names = []
        cli.visit(names.append)
        py_names = []
        py.visit(py_names.append)
        assert sorted(names) == sorted(py_names)
        for name in names:
            a, b = cli[name], py[name]
            assert type(a) is type(b), name
            attrs = [dict(a.attrs), dict(b.attrs)]
            if "note" in attrs[0]:  # a saved state's totals: the same but the wall times
                for d in attrs:
                    d["note"] = {k: v for k, v in json.loads(d["note"]).items()
                                 if k not in ("timings", "wall_seconds")}
            assert attrs[0] == attrs[1], name
            if isinstance(a, h5py.Dataset):
                assert a.dtype == b.dtype and a.shape == b.shape, name
                assert a.chunks == b.chunks and a.compression == b.compression, name
                x, y = a[()], b[()]
                if x.dtype.names:  # compound: every column but the wall-clock timings
                    cols = [c for c in x.dtype.names if not c.startswith("time_")]
                    assert len(cols) >= 10 if name == "steps" else cols == list(x.dtype.names)
                    for c in cols:
                        assert np.array_equal(x[c], y[c], equal_nan=x[c].dtype.kind == "f"), (name, c)
                else:
                    assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
                compared.append(name)
        assert {"trajectory", "frames/positions", "steps", "exits", "walls"} <= set(compared)
        differ = {"command", "summary"}
        assert set(cli.attrs) == set(py.attrs)
        for key in set(cli.attrs) - differ:
            assert cli.attrs[key] == py.attrs[key], key
        assert py.attrs["command"].startswith("moreau.run(")
        s_cli, s_py = json.loads(cli.attrs["summary"]), json.loads(py.attrs["summary"])
        assert set(s_cli) == set(s_py)
        for key in ("status", "people", "passed_exit", "steps", "frames", "simulated_time",
                    "max_eps", "max_violation", "solvers"):
            assert s_cli[key] == s_py[key] == summary[key], key


def test_a_pickle_with_more_threads_than_the_unpickling_worker_runs_was_refused():
    """Regression: a simulation pickled with `solver.threads` above what the unpickling
    process runs (a Dask worker with fewer cores) was refused there ("more than this machine
    runs usefully"). It unpickles with the threads lowered, and goes on with the same bits."""
    cores = len(os.sched_getaffinity(0))
    if cores < 2:
        pytest.skip("needs 2 cores: the unpickling process is given one")
    d = short_room(1.0).to_dict()
    d.setdefault("solver", {})["threads"] = 2 * cores
    scene = moreau.Scene.from_dict(d)
    sim = moreau.Simulation(scene)
    sim.advance_to(0.5)
    straight = moreau.Simulation(scene)
    straight.advance_to(1.0)
    child = (
        "import os, pickle, sys\n"
        "os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})\n"
        "sim = pickle.loads(sys.stdin.buffer.read())\n"
        "sim.advance_to(1.0)\n"
        "sys.stdout.buffer.write(pickle.dumps((sim.scene.to_dict()['solver']['threads'], "
        "sim.positions)))\n"
    )
    out = subprocess.run([sys.executable, "-c", child], input=pickle.dumps(sim),
                         capture_output=True, timeout=120)
    assert out.returncode == 0, out.stderr.decode()
    threads, positions = pickle.loads(out.stdout)
    assert threads == 2
    assert same_bits(positions, straight.positions)


def test_state_restore_and_pickle_continue_a_run_identically():
    scene = short_room(6.0)
    straight = moreau.Simulation(scene)
    straight.advance_to(6.0)

    sim = moreau.Simulation(scene)
    sim.advance_to(2.5)
    sim_time_at_save = sim.time
    assert sim_time_at_save == pytest.approx(2.5, abs=1e-9)
    saved = sim.state()
    pickled = pickle.dumps(sim)
    sim.advance_to(6.0)
    assert same_bits(sim.positions, straight.positions)

    again = moreau.Simulation(scene)
    again.restore(saved)
    assert again.time == sim_time_at_save and again.last_report is None
    again.advance_to(6.0)
    assert same_bits(again.positions, straight.positions)
    assert again.exit_records() == straight.exit_records()

    unpickled = pickle.loads(pickled)
    assert unpickled.time == sim_time_at_save and unpickled.scene == scene
    unpickled.advance_to(6.0)
    assert same_bits(unpickled.positions, straight.positions)
    assert same_bits(unpickled.ids.astype(np.float64), straight.ids.astype(np.float64))

    # A state of another scene, or damaged bytes: refused, nothing changes.
    other = moreau.Simulation(ROOM60)
    with pytest.raises(moreau.SceneError, match="scene_hash"):
        other.restore(saved)
    with pytest.raises(moreau.SceneError, match="state"):
        again.restore(saved[: len(saved) // 2])
    assert again.time == straight.time
    assert pickle.loads(pickle.dumps(scene)) == scene


def test_a_pickled_simulation_goes_to_a_dask_worker_and_comes_back():
    from dask.distributed import Client, LocalCluster

    scene = short_room(4.0)
    here = moreau.Simulation(scene)
    here.advance_to(1.0)
    local = pickle.loads(pickle.dumps(here))
    local.advance_to(4.0)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        # A lambda travels by value (the test module is not importable on the worker).
        advanced = lambda sim, t: (sim.advance_to(t), sim)[1]  # noqa: E731
        pid = client.submit(os.getpid).result()
        back = client.submit(advanced, here, 4.0, pure=False).result()
    assert pid != os.getpid(), "the task ran in another process"
    assert back.time == local.time and back.time == pytest.approx(4.0, abs=1e-9)
    assert same_bits(back.positions, local.positions)
    straight = moreau.Simulation(scene)
    straight.advance_to(4.0)
    assert same_bits(back.positions, straight.positions)


def test_bad_scenes_raise_scene_error_naming_the_field(tmp_path):
    bad = ROOM.read_text().replace("radius = 0.2", "radius = -0.2")
    with pytest.raises(moreau.SceneError) as e:
        moreau.Scene.from_toml(bad)
    assert e.value.field == "groups[0].radius" and e.value.value == "-0.2"
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    cli = moreau_cli("run", path, check=False)
    assert cli.returncode == 2 and str(e.value) in cli.stderr, (str(e.value), cli.stderr)
    with pytest.raises(moreau.SceneError, match="groups"):
        moreau.Scene.from_file(path)
    with pytest.raises(moreau.SceneError, match="radius"):
        moreau.Simulation(path)

    # A scene that does not parse had no `field`, `value` or `reason` at all (AttributeError),
    # although the README promises them: the parser's message is the reason, and no value is
    # at fault.
    with pytest.raises(moreau.SceneError) as e:
        moreau.Scene.from_toml("seed = 1")
    assert e.value.field is None and "area" in e.value.reason
    d = moreau.Scene.from_file(ROOM).to_dict()
    d["time"]["step"] = float("nan")
    with pytest.raises(moreau.SceneError, match=r"time\.step"):
        moreau.Scene.from_dict(d)
    with pytest.raises(FileNotFoundError):
        moreau.Scene.from_file(tmp_path / "missing.toml")


def test_a_bad_dict_was_named_by_lines_of_toml_nobody_wrote():
    """`Scene.from_dict` turns the dict into TOML and parses that: its errors quoted "line 35,
    column 1" of text the user never saw, and had no `field`. They now name the dict's keys,
    with the index of each list of tables, as a validation error names its field."""
    def error(edit):
        d = moreau.Scene.from_file(ROOT / "data" / "scenes" / "room-closing-door.toml").to_dict()
        edit(d)
        with pytest.raises(moreau.SceneError) as e:
            moreau.Scene.from_dict(d)
        assert "line" not in str(e.value), str(e.value)
        assert e.value.reason in str(e.value)
        return e.value.field, e.value.value, e.value.reason

    field, value, reason = error(lambda d: d["time"].__setitem__("horizn", 3.0))
    assert (field, value) == ("time.horizn", "3.0") and "unknown field `horizn`" in reason
    field, value, _ = error(lambda d: d["groups"][0].__setitem__("radius", "big"))
    assert (field, value) == ("groups[0].radius", '"big"')
    field, value, reason = error(lambda d: d["moving"][0]["keyframes"][1].pop("t"))
    assert (field, value) == ("moving[0].keyframes[1]", None) and "missing field `t`" in reason
    field, value, _ = error(lambda d: d["moving"][0]["keyframes"][1].__setitem__("angle", "x"))
    assert (field, value) == ("moving[0].keyframes[1].angle", '"x"')
    field, value, _ = error(lambda d: d["solver"].__setitem__("kind", "fast"))
    assert (field, value) == ("solver.kind", '"fast"')
    # A key missing from the scene itself names no field (it named the first line's, `name`).
    field, value, reason = error(lambda d: d.pop("seed"))
    assert (field, value) == (None, None) and "missing field `seed`" in reason


def test_solver_settings_from_a_dict_are_written_whole_and_bad_ones_are_named(tmp_path):
    # Each solver's settings are a table of the scene's solver: absent, the defaults (and not
    # written); given, written whole into the run file's scene, so the file says what ran.
    d = moreau.Scene.from_file(ROOM).to_dict()
    assert "interior" not in d["solver"] and "newton" not in d["solver"]
    d["solver"]["interior"] = {"max_iterations": 60}
    d["time"]["horizon"] = 0.5
    scene = moreau.Scene.from_dict(d)
    interior = scene.to_dict()["solver"]["interior"]
    assert interior["max_iterations"] == 60 and 0 < interior["step_fraction"] < 1, interior
    assert "newton" not in scene.to_dict()["solver"]
    out = tmp_path / "tuned.h5"
    assert moreau.run(scene, out)["status"] == "complete"
    with h5py.File(out) as f:
        written = f.attrs["scene"]
    written = written.decode() if isinstance(written, bytes) else written
    assert moreau.Scene.from_toml(written) == scene
    assert "[solver.interior]" in written and "max_iterations = 60" in written, written

    d["solver"]["interior"] = {"step_fraction": 2.0}
    with pytest.raises(moreau.SceneError) as e:
        moreau.Scene.from_dict(d)
    assert e.value.field == "solver.interior.step_fraction" and e.value.value == "2", e.value
    d["solver"]["interior"] = {"max_iteration": 60}
    with pytest.raises(moreau.SceneError, match="max_iteration"):
        moreau.Scene.from_dict(d)


def test_areas_from_shapely_and_wkt_and_dicts_round_trip():
    import shapely

    room = moreau.Scene.from_file(ROOM)
    assert moreau.Scene.from_dict(room.to_dict()) == room
    assert moreau.Scene.from_toml(room.to_toml()) == room
    area = shapely.from_wkt(room.wkt)
    assert room.with_area(area) == room
    assert room.with_area(room.wkt) == room
    # A pillar in the room (a hole): kept as a hole, and people start outside it.
    pillar = shapely.box(4.0, 4.0, 5.0, 5.0)
    holed = room.with_area(area.difference(pillar))
    assert holed.to_dict()["area"]["holes"] and holed != room
    sim = moreau.Simulation(holed)
    assert not shapely.contains_xy(pillar, *sim.positions.T).any()
    with pytest.raises(moreau.SceneError, match=r"area\.outer.*zero area"):
        room.with_area("POLYGON ((0 0, 1 1, 2 2, 0 0))")
    with pytest.raises(moreau.SceneError, match="Polygon"):
        room.with_area(shapely.MultiPolygon([area, shapely.box(30, 30, 31, 31)]))
    # Regression: None or a list of points met an AttributeError on `geom_type`.
    for bad, name in [(None, "NoneType"), ([[0, 0], [40, 0], [40, 30]], "list")]:
        with pytest.raises(TypeError, match=f"area: a shapely Polygon or its WKT, not {name}"):
            room.with_area(bad)


def test_a_nan_speed_factor_raises_and_the_simulation_keeps_working():
    scene = short_room(3.0)
    plain = moreau.Simulation(scene)
    plain.advance_to(3.0)
    sim = moreau.Simulation(scene)
    sim.advance_to(1.0)
    for bad in (float("nan"), -0.5, float("inf")):
        with pytest.raises(ValueError, match="speed_factor"):
            sim.set_speed_factor(bad)
    assert sim.speed_factor == 1.0
    sim.advance_to(3.0)
    assert same_bits(sim.positions, plain.positions)
    assert np.isfinite(sim.positions).all()
    # A valid factor changes the run: half speed walks about half as far in free flow.
    slow = moreau.Simulation(scene)
    slow.set_speed_factor(0.5)
    slow.step()
    assert np.median(np.linalg.norm(slow.velocities, axis=1)) == pytest.approx(0.5, abs=0.02)


def test_a_tol_no_step_meets_ran_at_the_smallest_step_without_a_python_warning(tmp_path):
    """`time.tol = 1e-12` keeps every step at the smallest (10⁻⁶ s) whatever it errs: `moreau
    run` warned once, the FMU logged nothing and Python said nothing (only `local_error`
    showed it). Now one RuntimeWarning a simulation, and none for a tolerance steps meet."""
    import warnings

    d = moreau.Scene.from_file(ROOT / "data" / "scenes" / "room-60.toml").to_dict()
    d["time"]["tol"] = 1e-12
    sim = moreau.Simulation(moreau.Scene.from_dict(d))
    with pytest.warns(RuntimeWarning, match=r"the smallest step, 1e-6 s.*time\.tol = 1e-12 m") as said:
        sim.advance_to(0.052)  # a first step of 0.05 s (free flow: no error), then 10⁻⁶ s
    assert len(said) == 1, [str(w.message) for w in said]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim.advance_to(0.054)
        sim.step()
        d["time"]["tol"] = 1e-3
        met = moreau.Simulation(moreau.Scene.from_dict(d))
        met.advance_to(0.5)
        met.step()
    # moreau.run (its file written by the CLI's observer) says it once too.
    d["time"]["tol"], d["time"]["horizon"] = 1e-12, 0.052
    with pytest.warns(RuntimeWarning, match=r"time\.tol = 1e-12 m") as said:
        moreau.run(moreau.Scene.from_dict(d), tmp_path / "tol.h5")
    assert len(said) == 1, [str(w.message) for w in said]


def test_a_blocked_sources_people_left_waiting_were_counted_nowhere(tmp_path):
    """A source whose area holds one person at a time, 10 a second: people due who found no
    room were in no frame and no count (a run of 50 due and 23 entered said 23 people and
    nothing else). `source_tallies` says due and entered after every step, the summary holds
    them, and `moreau.run` and `moreau run` warn once a source, naming it."""
    import warnings

    d = moreau.Scene.from_file(ROOT / "data" / "scenes" / "gate-inflow.toml").to_dict()
    d["sources"][0]["area"] = [[0.5, 1.9], [0.7, 1.9], [0.7, 2.1], [0.5, 2.1]]
    d["sources"][0]["rate"] = 10.0
    d["time"]["horizon"] = 2.0
    sim = moreau.Simulation(moreau.Scene.from_dict(d))
    assert sim.source_tallies() == [("gate", 0, 0)]
    while sim.time < 2.0 - 1e-9:
        sim.step()
        name, due, entered = sim.source_tallies()[0]
        assert name == "gate"
        assert due == math.floor(10.0 * sim.time + 1e-9)
        assert entered == sim.total_people - 20  # the 20 of the group "waiting" at the start
    assert due == 20 and entered <= 10, (due, entered)
    pattern = r"source 'gate': \d+ of the 20 people due by t = 2 s did not enter"
    with pytest.warns(RuntimeWarning, match=pattern) as said:
        summary = moreau.run(moreau.Scene.from_dict(d), tmp_path / "blocked.h5")
    assert len(said) == 1, [str(w.message) for w in said]
    summary = json.loads(summary) if isinstance(summary, str) else summary
    (tally,) = summary["sources"]
    assert tally["name"] == "gate" and tally["due"] == 20 and tally["entered"] <= 10
    scene = tmp_path / "blocked.toml"
    scene.write_text(moreau.Scene.from_dict(d).to_toml())
    cli = subprocess.run([MOREAU, "run", scene, "-q", "--summary-json", "-"],
                         capture_output=True, text=True, check=True)
    assert json.loads(cli.stdout)["sources"] == summary["sources"]
    assert re.search(pattern, cli.stderr), cli.stderr
    # A source that brings everyone due says nothing.
    d["sources"][0]["rate"] = 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        summary = moreau.run(moreau.Scene.from_dict(d), tmp_path / "free.h5")
    summary = json.loads(summary) if isinstance(summary, str) else summary
    assert summary["sources"] == [{"name": "gate", "due": 2, "entered": 2}]


def test_velocities_report_and_contacts_of_the_last_step(tmp_path):
    scene = short_room(6.0, output={"contacts": True})
    sim = moreau.Simulation(scene)
    assert np.isnan(sim.velocities).all() and sim.last_report is None
    sim.advance_to(4.0)
    before = sim.positions.copy()
    report = sim.step()
    assert set(report) >= {"t", "mu", "eps", "eps_target", "violation", "iterations",
                           "solver", "status", "active", "timings"}
    assert report == {**sim.last_report, "timings": report["timings"]}
    assert report["eps"] <= report["eps_target"] and report["mu"] == pytest.approx(0.05)
    # Fixed steps have no error estimate; adaptive ones give theirs (at most tol above μ_min).
    assert report["local_error"] is None
    d = scene.to_dict()
    d["time"]["tol"] = 0.01
    adaptive = moreau.Simulation(moreau.Scene.from_dict(d))
    adaptive.advance_to(1.0)
    assert 0.0 <= adaptive.last_report["local_error"] <= 0.01, adaptive.last_report
    assert np.array_equal(sim.velocities, (sim.positions - before) / report["mu"])

    # contacts() against the driver's /contacts of the same frame.
    toml = tmp_path / "contacts.toml"
    toml.write_text(scene.to_toml())
    out = tmp_path / "contacts.h5"
    moreau_cli("run", toml, "-o", out, "--quiet")
    sim = moreau.Simulation(scene)
    sim.advance_to(5.0)
    c = sim.contacts()
    with h5py.File(out) as f:
        frame = int(np.argmin(abs(f["frames/time"][:] - 5.0)))
        rows = f["contacts"][:]
    rows = rows[rows["frame"] == frame]
    assert len(rows) > 10 and len(c["lambda"]) == len(rows)
    assert np.array_equal(c["kind"], rows["kind"]) and np.array_equal(c["a"], rows["a"])
    assert np.array_equal(c["b"], rows["b"]) and np.array_equal(c["lambda"], rows["lambda"])


def test_exits_closed_and_people_removed_during_a_run():
    import shapely

    scene = short_room(8.0)
    sim = moreau.Simulation(scene)
    sim.advance_to(1.0)
    with pytest.raises(ValueError, match="door"):
        sim.set_exit_open("no such exit", False)
    passed = sim.exit_records()
    inside = sim.positions[:, 0] < 10.0
    sim.set_exit_open("door", False)
    assert sim.exits_open() == [False]
    sim.advance_to(8.0)
    assert sim.exit_records() == passed, "nobody passes a closed door"
    assert (sim.positions[inside, 0] < 10.0).all()
    sim.set_exit_open(0, True)
    sim.advance_to(9.0)
    assert len(sim.exit_records()) > len(passed)

    sim = moreau.Simulation(scene)
    sim.advance_to(1.0)
    x, ids = sim.positions[:, 0], sim.ids
    left = shapely.box(0.0, 0.0, 5.0, 10.0)
    expect = ids[~(x < 5.0)]
    assert sim.remove_people_in(left.wkt) == len(ids) - len(expect)
    assert np.array_equal(sim.ids, expect) and sim.total_people == 150
    sim.advance_to(3.0)
    assert set(sim.ids) <= set(expect)
    assert sim.remove_people_in(left) == 0
    # Regression: a list of points met a numpy broadcast error, None removed nobody, and bad
    # WKT was reported as the scene's `area`.
    for bad, error, said in [([[0, 0], [5, 0], [5, 10]], TypeError, "not list"),
                             (None, TypeError, "not NoneType"),
                             ("POLYGON ((0 0", ValueError, "polygon = 'POLYGON ((0 0'")]:
        with pytest.raises(error, match=re.escape(said)):
            sim.remove_people_in(bad)
    assert set(sim.ids) <= set(expect)


def test_two_threads_step_two_simulations_at_once_as_sequential_runs():
    scenes = [short_room(8.0), moreau.Scene.from_file(ROOM60)]
    sequential = []
    for s in scenes:
        sim = moreau.Simulation(s)
        sim.advance_to(8.0)
        sequential.append(sim.positions)
    sims = [moreau.Simulation(s) for s in scenes]
    spans = [None, None]

    def work(k):
        start = time.perf_counter()
        sims[k].advance_to(8.0)
        spans[k] = (start, time.perf_counter())

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    # While a thread steps a simulation, another thread's call is refused, not blocked.
    busy = 0
    while any(t.is_alive() for t in threads):
        try:
            sims[0].time
        except RuntimeError as e:
            assert "another thread" in str(e)
            busy += 1
        time.sleep(0.001)
    for t in threads:
        t.join()
    for sim, expected in zip(sims, sequential):
        assert sim.time == pytest.approx(8.0, abs=1e-9) and same_bits(sim.positions, expected)
    # Both ran at the same time (the GIL was released while they computed).
    assert spans[0][0] < spans[1][1] and spans[1][0] < spans[0][1]
    assert busy > 0


def step_on_in_a_forked_child(sim, t_end, tmp_path, what):
    """Forks: the child and this process each advance `sim` to `t_end`; returns the child's
    positions (the child must finish within 120 s, without an error)."""
    answer, failure = tmp_path / "child.npy", tmp_path / "child-error.txt"
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            sim.advance_to(t_end)
            np.save(answer, sim.positions)
            code = 0
        except BaseException as e:
            failure.write_text(repr(e))
        finally:
            os._exit(code)
    sim.advance_to(t_end)
    deadline = time.monotonic() + 120.0
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
            pytest.fail(f"the forked child ({what}) did not finish its steps in 120 s")
        time.sleep(0.05)
    assert os.waitstatus_to_exitcode(status) == 0, failure.read_text()
    return np.load(answer)


def test_a_simulation_on_two_threads_steps_on_in_a_forked_child(tmp_path):
    """Regression: `auto` on two threads splits its largest component's factorizations with a
    helper thread, which a child forked from the process (multiprocessing's fork start method)
    does not have; the child must run both halves itself, not wait for the helper forever. The
    child's run from the fork on is the parent's, bit for bit."""
    d = moreau.Scene.from_file(ROOT / "data" / "scenes" / "cromosim-2000.toml").to_dict()
    d["solver"]["threads"] = 2
    d["time"]["horizon"] = 7.0
    sim = moreau.Simulation(moreau.Scene.from_dict(d))
    # From about 3 s on the door's component is large enough to split.
    sim.advance_to(4.0)
    child = step_on_in_a_forked_child(sim, 7.0, tmp_path, "auto")
    assert same_bits(child, sim.positions)


@pytest.mark.parametrize("kind", ["interior", "gauss-seidel", "apgd"])
def test_a_solver_on_a_thread_pool_steps_on_in_a_forked_child(tmp_path, kind):
    """Regression: given two threads directly (not through `auto`) these solvers spread their
    loops over a thread pool whose threads a child forked from the process does not have: the
    child waited for them forever. It must run the loops itself, bit for bit the parent's run."""
    d = moreau.Scene.from_file(ROOT / "data" / "scenes" / "cromosim-2000.toml").to_dict()
    d["solver"]["threads"] = 2
    d["solver"]["kind"] = kind
    d["time"]["horizon"] = 2.0
    sim = moreau.Simulation(moreau.Scene.from_dict(d))
    sim.advance_to(1.0)
    child = step_on_in_a_forked_child(sim, 1.5, tmp_path, kind)
    assert same_bits(child, sim.positions)


def test_to_pedpy_from_a_run_file_and_from_memory(room_run):
    traj_file, walk_file = moreau.to_pedpy(room_run)
    sim = moreau.Simulation(ROOM, record=True)
    sim.advance_to(3.0)
    traj, walk = moreau.to_pedpy(sim)
    assert traj.frame_rate == traj_file.frame_rate == 10.0
    assert walk.polygon.equals(walk_file.polygon)
    head = traj_file.data[traj_file.data["frame"] <= 30].sort_values(["frame", "id"])
    mine = traj.data.sort_values(["frame", "id"])
    assert len(mine) == len(head) == 31 * 150
    for col in ("id", "frame", "x", "y"):
        assert np.array_equal(mine[col].to_numpy(), head[col].to_numpy()), col
    with pytest.raises(ValueError, match="record"):
        moreau.Simulation(ROOM).recorded_frames()


def test_advance_to_0_6_recorded_the_frame_of_0_6_s_one_call_late():
    """Frame 6 is due at 6 × 0.1 = 0.6000000000000001 s: `advance_to(0.6)` ended at 0.6 s
    but recorded that frame only on the next call (so did 0.3 and 0.7 s)."""
    sim = moreau.Simulation(short_room(1.0), record=True)
    for k in range(1, 11):
        sim.advance_to(k / 10)
        frame, t, _, _, _ = sim.recorded_frames()
        assert frame.max() == k, (k / 10, np.unique(t))
        assert abs(t.max() - k / 10) < 1e-12, (k / 10, np.unique(t))


def test_the_ensemble_runs_in_process_with_engine_python(tmp_path):
    from moreau_ensemble.task import run_variant

    scene = short_room(1.0).to_toml()
    rows = [run_variant("v", {}, 1, scene, str(tmp_path / engine), moreau=str(MOREAU), engine=engine)
            for engine in ("python", "driver")]
    assert rows[0]["status"] == rows[1]["status"] == "complete", rows
    for key in ("people", "passed_exit"):
        assert rows[0][key] == rows[1][key]
    with h5py.File(rows[0]["output"]) as a, h5py.File(rows[1]["output"]) as b:
        assert np.array_equal(a["frames/positions"][:], b["frames/positions"][:], equal_nan=True)
    # Through which exit, by name, where the scene has two: both engines the same counts.
    two = (ROOT / "data" / "scenes" / "room-two-exits.toml").read_text()
    rows = [run_variant("two", {}, 1, two, str(tmp_path / f"two-{engine}"), moreau=str(MOREAU),
                        engine=engine) for engine in ("python", "driver")]
    for row in rows:
        assert row["status"] == "complete", row
        assert row["passed.west"] + row["passed.east"] == row["passed_exit"] == 60, row
        assert row["passed.west"] > 0 and row["passed.east"] > 0, row
    assert rows[0]["passed.west"] == rows[1]["passed.west"]
    # The FMU built for the scene declares its exits: the same counts through fmpy.
    fmus = tmp_path / "fmus"
    subprocess.run([sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build", "--out",
                    str(fmus), "--scene", str(ROOT / "data" / "scenes" / "room-two-exits.toml")],
                   check=True, capture_output=True)
    fmu = run_variant("two", {}, 1, two, str(tmp_path / "two-fmu"), engine="fmu",
                      fmu=str(fmus / "moreau-crowd-room-two-exits-fmi2.fmu"))
    assert fmu["status"] == "complete", fmu
    assert [fmu[k] for k in ("passed_exit", "passed.west", "passed.east")] == [
        rows[1][k] for k in ("passed_exit", "passed.west", "passed.east")]
    bad = run_variant("bad", {}, 1, scene.replace("radius = 0.2", "radius = -0.2"),
                      str(tmp_path / "bad"), engine="python")
    assert bad["status"] == "failed" and "SceneError" in bad["error"] and "radius" in bad["error"]


# The README's command for the wheel (one place): HDF5 linked statically (CMake from .venv).
WHEEL_COMMAND = ["maturin", "build", "--release", "--locked", "-m", "crates/py/Cargo.toml"]


def test_the_wheel_installs_into_a_fresh_venv_and_runs_the_room(tmp_path, room_run):
    venv_bin = pathlib.Path(sys.executable).parent
    env = {**os.environ, "PATH": f"{venv_bin}{os.pathsep}{os.environ['PATH']}"}
    wheels = tmp_path / "wheels"
    build = subprocess.run([*WHEEL_COMMAND, "-o", str(wheels)], cwd=ROOT, env=env,
                           capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=1800)
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = wheels.glob("moreau-*.whl")
    assert "abi3" in wheel.name

    fresh = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(fresh)], check=True)
    pip = [str(fresh / "bin" / "python"), "-m", "pip", "install", "--quiet",
           "--disable-pip-version-check"]
    subprocess.run([*pip, "--no-deps", str(wheel)], check=True, stdin=subprocess.DEVNULL)
    subprocess.run([*pip, f"numpy=={np.__version__}"], check=True, stdin=subprocess.DEVNULL)

    out = tmp_path / "fresh.h5"
    script = f"""
import pathlib, subprocess, numpy as np, moreau
lib = next(pathlib.Path(moreau.__file__).parent.glob("_moreau*.so"))
print(subprocess.run(["ldd", str(lib)], capture_output=True, text=True).stdout)
sim = moreau.Simulation(moreau.Scene.from_file({str(ROOM)!r}))
for _ in range(20):
    sim.step()
np.save({str(tmp_path / "steps.npy")!r}, sim.positions)
d = sim.scene.to_dict(); d["time"]["horizon"] = 1.0
print(moreau.run(moreau.Scene.from_dict(d), {str(out)!r})["status"])
"""
    proc = subprocess.run([str(fresh / "bin" / "python"), "-c", script], cwd=tmp_path,
                          capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "libhdf5" not in proc.stdout and "libc.so" in proc.stdout, proc.stdout
    assert proc.stdout.strip().endswith("complete")
    # 20 steps of 0.05 s is frame 10 of the driver's run; the file is the driver's up to 1 s.
    with h5py.File(room_run) as f, h5py.File(out) as g:
        assert same_bits(np.load(tmp_path / "steps.npy"), f["frames/positions"][10])
        assert np.array_equal(g["frames/positions"][:], f["frames/positions"][:11])


def test_the_readme_example_runs(tmp_path):
    text = (ROOT / "README.md").read_text()
    start = text.index("```python\n", text.index("## Python")) + len("```python\n")
    code = text[start:text.index("```", start)]
    (tmp_path / "data").symlink_to(ROOT / "data")
    (tmp_path / "out").mkdir()
    proc = subprocess.run([sys.executable, "-c", "import matplotlib; matplotlib.use('Agg')\n" + code],
                          cwd=tmp_path, capture_output=True, text=True, stdin=subprocess.DEVNULL,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "through the door" in proc.stdout
    assert (tmp_path / "room.png").stat().st_size > 10_000
    with h5py.File(tmp_path / "out" / "room-150-py.h5") as f:
        assert f.attrs["status"] == "complete" and f["frames/positions"].shape == (201, 150, 2)


def test_an_error_in_the_progress_callback_stops_the_run_and_keeps_the_file(tmp_path):
    calls = []

    def progress(t, steps, left):
        calls.append((t, steps, left))
        raise KeyError("stop here")

    out = tmp_path / "stopped.h5"
    with pytest.raises(KeyError, match="stop here"):
        moreau._moreau.run_to_file(ROOM, out, progress=progress)
    (t, steps, left), = calls
    assert 0 < t < 20.0 and steps > 0 and 0 < left <= 150
    with h5py.File(out) as f:
        assert f.attrs["status"].startswith("failed: stopped from Python")
        assert 0 < f["frames/time"][-1] <= t and f["steps"].shape[0] == steps


def test_advance_to_1e300_ran_until_killed():
    """Regression: `advance_to(1e300)` took 2·10³⁰¹ steps of 0.05 s, one after the other.
    Refused now, naming t_end, like a horizon beyond 10⁹ steps."""
    sim = moreau.Simulation(moreau.Scene.from_file(ROOM60))
    with pytest.raises(Exception, match=r"t_end = 1e300.*2\.000e301 steps.*limit of 1e9"):
        sim.advance_to(1e300)
    assert sim.time == 0.0 and sim.steps == 0


def test_step_recorded_each_frame_one_call_late_and_never_the_horizons():
    """Regression: `step()` gave the frame where it landed only at the next call, so stepping
    to a horizon of 0.3 s recorded 0, 0.1 and 0.2 s (`advance_to` recorded 0.3 s too)."""
    scene = short_room(0.3)
    a = moreau.Simulation(scene, record=True)
    while a.time < scene.horizon - 1e-12:
        a.step()
        assert abs(a.recorded_frames()[1].max() - a.time) < 0.05 + 1e-12
    b = moreau.Simulation(scene, record=True)
    b.advance_to(scene.horizon)
    for x, y in zip(a.recorded_frames(), b.recorded_frames()):
        assert np.array_equal(x, y)
    assert np.allclose(np.unique(a.recorded_frames()[1]), [0.0, 0.1, 0.2, 0.3], atol=1e-12)


def test_a_rollback_kept_the_frames_of_the_branch_it_gave_up():
    """Regression: `restore` left the frames recorded after the saved state, so a roll-back
    gave `recorded_frames` (and `to_pedpy`) two rows for each person at each frame after it."""
    scene = short_room(0.8)
    sim = moreau.Simulation(scene, record=True)
    sim.advance_to(0.5)
    saved = sim.state()
    sim.set_speed_factor(0.0)
    sim.advance_to(0.8)
    sim.restore(saved)
    sim.advance_to(0.8)
    straight = moreau.Simulation(scene, record=True)
    straight.advance_to(0.8)
    for x, y in zip(sim.recorded_frames(), straight.recorded_frames()):
        assert np.array_equal(x, y)
    traj, _ = moreau.to_pedpy(sim)
    assert not traj.data.duplicated(["id", "frame"]).any()


def test_run_to_file_counted_people_left_past_zero_once_entrants_had_left(tmp_path):
    """Regression: the last progress call counted the people at the start less everyone out:
    once people from sources had left it wrapped to 18446744073709551569 (gate-inflow)."""
    d = moreau.Scene.from_file(ROOT / "data" / "scenes" / "gate-inflow.toml").to_dict()
    calls = []
    moreau.run_to_file(moreau.Scene.from_dict(d), str(tmp_path / "g.h5"),
                       progress=lambda t, steps, left: calls.append(left))
    with h5py.File(tmp_path / "g.h5") as f:
        everyone, out = len(f["people/id"]), len(f["exits"])
    assert out > 20, "people from sources left"
    assert calls[-1] == everyone - out, calls[-3:]


def test_moreau_run_wrote_the_run_file_over_its_own_scene_file(tmp_path):
    """Regression: `moreau.run("s.toml", "s.toml", force=True)` replaced the scene file by
    the run file; `moreau run s.toml -o s.toml --force` refuses, and so does it now."""
    path = tmp_path / "s.toml"
    path.write_text(short_room(0.2).to_toml())
    before = path.read_bytes()
    for output in (path, tmp_path / "." / "s.toml"):
        with pytest.raises(ValueError, match="a run never writes over its input"):
            moreau.run(str(path), output, force=True)
    assert path.read_bytes() == before


def test_ctrl_c_in_moreau_run_wrote_status_failed(tmp_path):
    """Ctrl-C (a KeyboardInterrupt, here raised by the progress callback, as SIGINT raises it
    in Python code or the signal check between steps) finishes the file as `interrupted`, as
    `moreau run` does; it said "failed: stopped from Python: KeyboardInterrupt"."""
    from conftest import DENSE
    import moreau_run
    from moreau._moreau import run_to_file

    out = tmp_path / "stopped.h5"

    def progress(t, steps, left):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_to_file(str(DENSE), str(out), progress=progress)
    run = moreau_run.load(out)
    assert run.status == "interrupted", run.status
    assert 0 < len(run.steps["t"]) < 200
    # Another exception from the callback is a failure that names it.
    out = tmp_path / "failed.h5"

    def broken(t, steps, left):
        raise ValueError("no plot")

    with pytest.raises(ValueError):
        run_to_file(str(DENSE), str(out), progress=broken)
    assert moreau_run.load(out).status.startswith("failed: stopped from Python: ValueError")
