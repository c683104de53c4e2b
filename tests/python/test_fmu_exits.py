"""Each exit of a scene as an input and an output of the FMUs, in fmpy: the FMUs
`fmu/package.py --scene data/scenes/room-two-exits.toml` builds declare `exit_open.<name>`
(Boolean inputs, exit 0's the same input as `door_open`) and `passed.<name>` (Integer outputs)
for both exits, fmpy's validator finds nothing, and `simulate_fmu` with the east door closed
for the first 8 s lets nobody out through it until then; FMI 2 and FMI 3 give the same run,
and it is the in-process `moreau.Simulation` with the same door, exit by exit."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

import moreau
import moreau_fmi
from conftest import ROOT

SCENE = ROOT / "data" / "scenes" / "room-two-exits.toml"
OPEN_AT, STOP, H, PEOPLE = 8.0, 20.0, 1.0, 60


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("two-exits-fmus")
    package = [sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build", "--out", str(out)]
    subprocess.run(package + ["--scene", str(SCENE)], check=True, capture_output=True)
    return {v: out / f"moreau-crowd-room-two-exits-fmi{v}.fmu" for v in ("2", "3")}


@pytest.mark.parametrize("version", ["2", "3"])
def test_each_exit_is_an_input_and_an_output_and_fmpy_validates_the_fmu(fmus, version):
    fmu = str(fmus[version])
    assert validate_fmu(fmu) == []
    md = read_model_description(fmu, validate=True)
    by_name = {v.name: v for v in md.modelVariables}
    integer = "Integer" if version == "2" else "Int32"
    for k, name in enumerate(["west", "east"]):
        opened, passed = by_name[f"exit_open.{name}"], by_name[f"passed.{name}"]
        assert (opened.valueReference, opened.causality, opened.type) == (2000 + k, "input",
                                                                          "Boolean")
        assert opened.start in ("true", True)
        assert (passed.valueReference, passed.causality, passed.type) == (3000 + k, "output",
                                                                          integer)
        assert any(u.variable is passed for u in md.outputs)


def simulate(fmu):
    md = read_model_description(str(fmu))
    east = moreau_fmi.signal(md, [0.0, OPEN_AT, OPEN_AT, STOP],
                             {"exit_open.east": [False, False, True, True]})
    return simulate_fmu(str(fmu), stop_time=STOP, output_interval=H, input=east,
                        output=["people_evacuated", "passed.west", "passed.east",
                                "exit_open.east", "door_open", "exit_open.west"])


def test_a_closed_exit_lets_nobody_out_until_it_opens_as_the_native_run(fmus):
    runs = {v: simulate(fmus[v]) for v in ("2", "3")}
    r = runs["3"]
    for name in r.dtype.names:
        np.testing.assert_array_equal(r[name], runs["2"][name], err_msg=name)
    t = r["time"]
    # Set at the communication point 8 s, the door is open from the step after it.
    assert (r["passed.east"][t <= OPEN_AT] == 0).all()
    assert r["passed.west"][t <= OPEN_AT].max() > 0
    assert r["passed.east"][-1] > 0
    np.testing.assert_array_equal(r["passed.west"] + r["passed.east"], r["people_evacuated"])
    assert r["people_evacuated"][-1] == PEOPLE
    # What the FMU reads back is the input as set (exit 0's is door_open).
    np.testing.assert_array_equal(r["exit_open.west"], r["door_open"])
    assert r["exit_open.west"].all() and not r["exit_open.east"][t <= OPEN_AT].any()

    # The in-process simulation with the same door, counted exit by exit.
    sim = moreau.Simulation(moreau.Scene.from_file(SCENE))
    sim.set_exit_open("east", False)
    counts = []
    for time in t:
        if time == OPEN_AT + H:
            sim.set_exit_open("east", True)
        sim.advance_to(time)
        records = sim.exit_records()
        counts.append([sum(1 for _, e, _ in records if e == k) for k in (0, 1)])
    counts = np.array(counts)
    np.testing.assert_array_equal(counts[:, 0], r["passed.west"])
    np.testing.assert_array_equal(counts[:, 1], r["passed.east"])


@pytest.mark.parametrize("version", ["2", "3"])
def test_the_fmu_of_a_scene_refuses_another_scenes_exits_and_logs_why(fmus, version, capfd):
    """Its passed.west would have counted the room's door (regression: it did, silently).
    The log is read from fmpy's default logger (stdout): `simulate_fmu(logger=...)` on FMI 2
    leaves fmpy's native log proxy pointing at a callback freed with the FMU, and the next
    FMI 2 FMU that logs in this process crashes it (seen: a segfault in test_fmu_moving)."""
    room = ROOT / "data" / "scenes" / "room-150.toml"
    with pytest.raises(Exception, match="(?i)initializ"):
        simulate_fmu(str(fmus[version]), stop_time=1.0, start_values={"scene": str(room)})
    said = capfd.readouterr().out
    assert 'its exits are ["door"], the FMU declares exit_open/passed for ["west", "east"]' \
        in said, said
    # The same scene through the parameter is taken.
    r = simulate_fmu(str(fmus[version]), stop_time=1.0, start_values={"scene": str(SCENE)})
    assert r["people_inside"][-1] + r["people_evacuated"][-1] == PEOPLE


def test_the_fmu_of_the_rooms_own_scene_checks_other_scenes_too(tmp_path, capfd):
    """`package.py --scene data/scenes/room-150.toml` declares exit_open.door and passed.door;
    its scene went into the resources as room-150.toml, the name the FMU takes for the room's
    FMU (no scene variables, no check), so another scene's exit 0 was counted as passed.door
    without a word (regression). It now goes in as room-150-scene.toml."""
    import zipfile

    room = ROOT / "data" / "scenes" / "room-150.toml"
    package = [sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build", "--out",
               str(tmp_path), "--fmi", "2"]
    subprocess.run(package + ["--scene", str(room)], check=True, capture_output=True)
    fmu = tmp_path / "moreau-crowd-room-150-fmi2.fmu"
    with zipfile.ZipFile(fmu) as z:
        assert [n for n in z.namelist() if n.startswith("resources/")] == \
            ["resources/room-150-scene.toml"]
        assert "resources/room-150-scene.toml" in z.read("modelDescription.xml").decode()
    names = {v.name for v in read_model_description(str(fmu)).modelVariables}
    assert {"exit_open.door", "passed.door"} <= names
    # Its own scene by default, and through the parameter.
    r = simulate_fmu(str(fmu), stop_time=1.0)
    assert r["people_inside"][-1] + r["people_evacuated"][-1] == 150
    simulate_fmu(str(fmu), stop_time=1.0, start_values={"scene": str(room)})
    with pytest.raises(Exception, match="(?i)initializ"):
        simulate_fmu(str(fmu), stop_time=1.0, start_values={"scene": str(SCENE)})
    said = capfd.readouterr().out
    assert 'its exits are ["west", "east"], the FMU declares exit_open/passed for ["door"]' \
        in said, said


def test_the_fmus_of_a_scene_of_sources_alone_were_not_built(tmp_path):
    """`package.py --scene` on a scene of sources alone (no `[[groups]]`, as the README allows)
    stopped with KeyError 'groups' after writing the FMI 2 FMU. Both are built now, fmpy's
    validator finds nothing (FMI 3's `n_people` is 0, no longer below its `min`), and both run
    the people in through the source."""
    text = (ROOT / "data" / "scenes" / "gate-inflow.toml").read_text()
    start, end = text.index("\n[[groups]]"), text.index("\n[[sources]]")
    scene = tmp_path / "gate-only.toml"
    scene.write_text(text[:start] + text[end:])
    package = [sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build", "--out",
               str(tmp_path)]
    built = subprocess.run(package + ["--scene", str(scene)], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    for version in ("2", "3"):
        fmu = str(tmp_path / f"moreau-crowd-gate-only-fmi{version}.fmu")
        assert validate_fmu(fmu) == [], version
        r = simulate_fmu(fmu, stop_time=2.0, output_interval=0.5)
        assert r["people_inside"][0] == 0 and r["people_inside"][-1] == 6, (version, r)


@pytest.mark.parametrize("version", ["2", "3"])
def test_a_failed_fmu_run_of_the_ensemble_left_its_instance_and_extracted_fmu_behind(
        fmus, version, tmp_path, monkeypatch):
    """A sweep's task on the FMU engine whose scene the FMU refuses: fmpy 0.3's
    `simulate_fmu` raised without freeing the instance it had made or removing the directory
    it had extracted the FMU to, so a Dask worker kept both from every failed task
    (regression). Now the task frees its instance and removes the directory, failed or not."""
    import tempfile

    import fmpy.fmi2
    import fmpy.fmi3

    from moreau_ensemble.task import run_variant

    extracted = tmp_path / "extracted"
    extracted.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(extracted))
    freed = []
    for cls in (fmpy.fmi2.FMU2Slave, fmpy.fmi3.FMU3Slave):
        free = cls.freeInstance
        monkeypatch.setattr(cls, "freeInstance", lambda self, free=free: (freed.append(self),
                                                                          free(self))[1])
    fmu = str(fmus[version])
    room = (ROOT / "data" / "scenes" / "room-150.toml").read_text()
    bad = run_variant("bad", {}, 1, room, str(tmp_path / "bad"), engine="fmu", fmu=fmu)
    assert bad["status"] == "failed" and "nitializ" in bad["error"], bad
    assert len(freed) == 1 and list(extracted.iterdir()) == []
    # A run that completes frees its instance the same way, and its counts are the FMU's.
    short = SCENE.read_text().replace("horizon = 30.0", "horizon = 2.0")
    assert short != SCENE.read_text()
    ok = run_variant("ok", {}, 1, short, str(tmp_path / "ok"), engine="fmu", fmu=fmu)
    assert ok["status"] == "complete" and ok["people"] == PEOPLE, ok
    assert len(freed) == 2 and list(extracted.iterdir()) == []


LATE = """
name = "late-arrivals"
seed = 9
[area]
outer = [[0.0, 0.0], [12.0, 0.0], [12.0, 3.0], [0.0, 3.0]]
[[exits]]
name = "end"
area = [[11.5, 0.0], [12.0, 0.0], [12.0, 3.0], [11.5, 3.0]]
action = "remove"
[[groups]]
name = "near"
count = 4
spawn = [[8.0, 0.5], [10.0, 0.5], [10.0, 2.5], [8.0, 2.5]]
radius = 0.2
speed = 1.2
destination = "end"
[[sources]]
name = "late"
area = [[0.2, 0.2], [1.5, 0.2], [1.5, 2.8], [0.2, 2.8]]
rate = 2.0
start = 3.0
count = 3
radius = 0.2
speed = 1.0
destination = "end"
[time]
horizon = 8.0
step = 0.05
output_interval = 0.1
[solver]
grid_cell = 0.1
"""


def test_the_ensembles_fmu_engine_counted_only_the_people_at_the_start(tmp_path):
    """Four people leave by 3 s, three more enter from 3 s and are still inside at 8 s: the
    FMU engine took the people from its first row (4), so its evacuation looked finished at
    2.8 s; the driver engine said 7 and no evacuation time."""
    import math

    from conftest import MOREAU
    from moreau_ensemble.task import run_variant

    rows = {engine: run_variant(engine, {}, 1, LATE, str(tmp_path / engine),
                                moreau=str(MOREAU), engine=engine,
                                fmu=str(ROOT / "target" / "fmu" / "moreau-crowd-fmi2.fmu"))
            for engine in ("driver", "fmu")}
    for engine, row in rows.items():
        assert row["status"] == "complete", row
        assert (row["people"], row["passed_exit"]) == (7, 4), (engine, row)
        assert math.isnan(row["evacuation_time"]), (engine, row)
