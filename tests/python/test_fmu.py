"""The FMUs in fmpy: valid, co-simulated with variable communication steps and a door that
closes, equal to the native driver where they should be, equal over the whole run to the
reference result made by the native driver without the FMU (fmu/reference.py), robust to
misuse, and without leaks over 10,000 instantiations."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
import shapely
from fmpy.util import read_csv
from fmpy.validation import validate_fmu
from scipy.spatial import cKDTree

import moreau_run
from conftest import ROOM, ROOT, moreau

sys.path.insert(0, str(ROOT / "fmu"))
import reference  # noqa: E402

FMU2 = ROOT / "target" / "fmu" / "moreau-crowd-fmi2.fmu"
FMU3 = ROOT / "target" / "fmu" / "moreau-crowd-fmi3.fmu"


@pytest.fixture(scope="module")
def fmus():
    subprocess.run([sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build"], check=True,
                   capture_output=True)
    return FMU2, FMU3


@pytest.fixture(scope="module")
def room_fmu_run(fmus):
    return reference.experiment(fmus[0])


@pytest.fixture(scope="module")
def room_native(tmp_path_factory):
    out = tmp_path_factory.mktemp("native") / "room.h5"
    moreau("run", ROOM, "-o", out, "--quiet")
    return moreau_run.load(out)


@pytest.mark.parametrize("which", [0, 1], ids=["fmi2", "fmi3"])
def test_fmpy_validate_finds_no_problem(fmus, which):
    assert validate_fmu(str(fmus[which])) == []


def test_the_fmu_matches_the_native_driver_until_the_door_closes(room_fmu_run, room_native):
    r, native = room_fmu_run, room_native
    steps = np.diff(r["time"])
    assert set(np.round(steps, 9)) == {0.1, 0.2}, "variable communication steps"
    walls = shapely.from_wkt(native.attrs["wkt_geometry"]).boundary
    checked = 0
    for k in range(1, len(r)):
        t = r["time"][k]
        if t > reference.DOOR_CLOSES + 1e-9:
            break
        f = int(round(t * 10))  # native frames every 0.1 s
        assert native.time[f] == pytest.approx(t, abs=1e-9)
        # The same internal steps (0.05 s) as the native run: the same states.
        assert r["internal_steps"][k] == round(t / 0.05)
        passed = int(np.sum(native.exits["t"] <= t + 1e-9))
        assert r["people_evacuated"][k] == passed
        assert r["people_inside"][k] == 150 - passed
        q0, q1 = native.positions[int(round(r["time"][k - 1] * 10))], native.positions[f]
        speed = np.linalg.norm(q1 - q0, axis=1).mean() / steps[k - 1]
        assert r["mean_speed"][k] == pytest.approx(speed, abs=1e-9)
        pts = native.positions[f]
        pairs = cKDTree(pts).query_pairs(1.0, output_type="ndarray")
        gaps = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1) \
            - native.radius[pairs[:, 0]] - native.radius[pairs[:, 1]]
        to_walls = shapely.distance(walls, shapely.points(pts)) - native.radius
        assert r["min_gap"][k] == pytest.approx(min(gaps.min(), to_walls.min()), abs=1e-9)
        checked += 1
    assert checked >= 50


def test_a_closed_door_lets_nobody_through_and_nobody_overlaps(room_fmu_run):
    r = room_fmu_run
    after = r["time"] > reference.DOOR_CLOSES + 1e-9
    assert len(np.unique(r["people_evacuated"][after])) == 1
    assert r["people_evacuated"][after][0] < 100
    assert r["mean_speed"][-1] < 0.05, "the crowd stands at the closed door"
    assert np.all(r["min_gap"] >= -1e-6)  # the room's max_violation
    assert np.all(r["eps"] <= 1e-3 * 0.05 ** 3 * (1 + 1e-12))


# The FMU against the reference result made without it (fmu/reference.py: the native driver,
# the `moreau` module's Simulation, on the same scene with the same communication points and
# the door closed at the same time, its outputs computed in numpy and shapely). The FMU steps
# the same Simulation with the same calls, so the states are the native ones bit for bit; the
# outputs differ only in how they are computed from them:
# - the counts, the step count and ε are read from the same run: exactly equal;
# - mean_speed is Σ|Δq_i| / n / h over the same distances, summed in order by the FMU and
#   pairwise by numpy: a sum of n non-negative terms is within (n − 1) u of the exact one
#   either way (u = 2⁻⁵³), so the two are within 2 n u relative;
# - min_gap is a length of at most the room's diagonal (< 32 m) less the radii, computed by
#   different formulas (the FMU's segment distance, GEOS's): each within a few units in the
#   last place of 32 m (7.1e-15 m); 16 of them is 1.1e-13 m.
PEOPLE = 150
MEAN_SPEED_RTOL = 2 * PEOPLE * 2.0 ** -53
MIN_GAP_ATOL = 16 * np.spacing(32.0)


def test_the_fmu_reproduces_the_native_reference_result(room_fmu_run):
    ref = read_csv(str(reference.REFERENCE))
    r = room_fmu_run
    hint = "(after a change of the crowd's physics: .venv/bin/python fmu/reference.py)"
    assert len(ref) == len(r)
    assert r["time"][-1] == reference.STOP, "the whole 20 s"
    assert np.sum(r["time"] > reference.DOOR_CLOSES) > 40, "long after the door closed"
    np.testing.assert_array_equal(r["time"], ref["time"], err_msg="communication points")
    for name in ("people_inside", "people_evacuated", "internal_steps", "eps"):
        np.testing.assert_array_equal(r[name], ref[name], err_msg=f"{name} {hint}")
    np.testing.assert_allclose(r["mean_speed"], ref["mean_speed"], rtol=MEAN_SPEED_RTOL, atol=0,
                               err_msg=f"mean_speed {hint}")
    np.testing.assert_allclose(r["min_gap"], ref["min_gap"], rtol=0, atol=MIN_GAP_ATOL,
                               err_msg=f"min_gap {hint}")


def test_the_reference_result_is_the_native_drivers():
    """The stored reference is what fmu/reference.py computes from the native driver now, to
    the last bit (the run is deterministic, whatever the thread count; a stale or hand-edited
    file fails here)."""
    ref = read_csv(str(reference.REFERENCE))
    native = reference.native_experiment()
    assert ref.dtype.names == native.dtype.names
    for name in native.dtype.names:
        np.testing.assert_array_equal(ref[name], native[name], err_msg=name)


MISUSE = textwrap.dedent(r"""
    import json, sys, math
    from fmpy import read_model_description, extract
    from fmpy.fmi2 import FMU2Slave
    fmu = sys.argv[1]
    md = read_model_description(fmu)
    unzipped = extract(fmu)
    def slave(guid=md.guid):
        s = FMU2Slave(guid=guid, unzipDirectory=unzipped,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="misuse")
        return s
    def attempt(name, f):
        print(f"=== {name}", flush=True)
        try:
            f()
            print("RESULT ok", flush=True)
        except Exception as e:
            print(f"RESULT error {e}", flush=True)
    def do_step_before_init():
        s = slave(); s.instantiate(); s.doStep(0.0, 0.1)
    def ready():
        s = slave(); s.instantiate(); s.setupExperiment(startTime=0.0)
        s.enterInitializationMode(); s.exitInitializationMode(); return s
    attempt("doStep before initialization", do_step_before_init)
    attempt("negative step", lambda: ready().doStep(0.0, -0.1))
    attempt("NaN step", lambda: ready().doStep(0.0, float("nan")))
    attempt("NaN input", lambda: ready().setReal([10], [float("nan")]))
    attempt("unknown value reference", lambda: ready().getReal([999]))
    attempt("wrong GUID", lambda: slave(guid="{00000000-0000-0000-0000-000000000000}").instantiate())
    attempt("set an output", lambda: ready().setReal([22], [1.0]))
    attempt("wrong communication point", lambda: ready().doStep(5.0, 0.1))
    def fine_after_misuse():
        s = ready()
        try:
            s.doStep(0.0, float("nan"))
        except Exception:
            pass
        s.doStep(0.0, 0.1)
        assert s.getInteger([25])[0] == 2
    attempt("usable after a refused call", fine_after_misuse)
    print("ALIVE", flush=True)
""")


def test_misuse_gives_an_error_status_and_a_log_line_and_the_host_survives(fmus, tmp_path):
    script = tmp_path / "misuse.py"
    script.write_text(MISUSE)
    proc = subprocess.run([sys.executable, str(script), str(fmus[0])], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.rstrip().endswith("ALIVE")
    blocks = {}
    for block in proc.stdout.split("=== ")[1:]:
        name, _, body = block.partition("\n")
        blocks[name] = body
    expected_log = {
        "doStep before initialization": "DoStep is not allowed in state Instantiated",
        "negative step": "communicationStepSize = -0.1",
        "NaN step": "communicationStepSize = NaN",
        "NaN input": "speed_factor = NaN",
        "unknown value reference": "unknown value reference 999",
        "wrong GUID": "wrong GUID",
        "set an output": "mean_speed is an output",
        "wrong communication point": "currentCommunicationPoint = 5",
    }
    for name, log in expected_log.items():
        body = blocks[name]
        assert "RESULT error" in body, (name, body)
        assert "[ERROR]" in body and log in body, (name, body)
    assert "RESULT ok" in blocks["usable after a refused call"]


LEAK = textwrap.dedent(r"""
    import sys
    from ctypes import byref
    from fmpy import read_model_description, extract
    from fmpy.fmi2 import FMU2Slave
    fmu = sys.argv[1]
    md = read_model_description(fmu)
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="leak")
    s.instantiate()  # keeps the library loaded; the cycles call the C functions directly
    import pathlib
    resources = pathlib.Path(s.unzipDirectory, "resources").as_uri().encode()
    def rss_kib():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4
    def cycle():
        c = s.fmi2Instantiate(b"x", 1, md.guid.encode(), resources,
                              byref(s.callbacks), 0, 0)
        assert c
        s.fmi2FreeInstance(c)
    for _ in range(500):
        cycle()
    before = rss_kib()
    for _ in range(10_000):
        cycle()
    after = rss_kib()
    print(before, after)
""")


def test_ten_thousand_instantiations_leave_memory_flat(fmus, tmp_path):
    script = tmp_path / "leak.py"
    script.write_text(LEAK)
    proc = subprocess.run([sys.executable, str(script), str(fmus[0])], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    before, after = map(int, proc.stdout.split())
    print(f"resident memory over 10,000 instantiate/free cycles: {before} KiB -> {after} KiB "
          f"({after - before:+d} KiB)")
    assert after - before < 1024, f"{after - before} KiB more after 10,000 cycles"


def test_the_fmi3_arrays_are_the_native_positions_and_radii(fmus, room_native):
    from fmpy import simulate_fmu

    r = simulate_fmu(str(fmus[1]), stop_time=5.0, output_interval=0.5,
                     output=["positions", "radii", "people_evacuated"])
    assert r["positions"].shape == (11, 150, 2)
    for k, t in enumerate(r["time"]):
        f = int(round(t * 10))
        np.testing.assert_allclose(r["positions"][k], room_native.positions[f], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(r["radii"][k], room_native.radius)
        assert r["people_evacuated"][k] == int(np.sum(room_native.exits["t"] <= t + 1e-9))


def test_fmi3_refuses_a_wrong_instantiation_token_and_the_host_survives(fmus, tmp_path):
    script = tmp_path / "fmi3_misuse.py"
    script.write_text(textwrap.dedent(r"""
        import sys
        from fmpy import read_model_description, extract
        from fmpy.fmi3 import FMU3Slave
        fmu = sys.argv[1]
        md = read_model_description(fmu)
        s = FMU3Slave(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=extract(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="token")
        try:
            s.instantiate()
            print("RESULT ok")
        except Exception as e:
            print("RESULT error", e)
        s = FMU3Slave(guid=md.guid, unzipDirectory=extract(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="late")
        s.instantiate()
        try:
            s.doStep(0.0, 0.1)
            print("RESULT ok")
        except Exception as e:
            print("RESULT error", e)
        print("ALIVE")
    """))
    proc = subprocess.run([sys.executable, str(script), str(fmus[1])], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert out.count("RESULT error") == 2 and out.rstrip().endswith("ALIVE"), out
    assert "wrong instantiation token" in out and "DoStep is not allowed in state Instantiated" in out, out


def _instance(fmu, scene=None):
    from fmpy import extract, instantiate_fmu, read_model_description

    md = read_model_description(str(fmu))
    inst = instantiate_fmu(extract(str(fmu)), md)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    if scene is not None:
        inst.setString([refs["scene"]], [str(scene)])
    return inst, refs


def test_a_start_time_given_after_the_model_was_built_was_lost(fmus):
    """Regression: reading `n_people` (FMI 3) or setting an input (FMI 2) built the model at
    time 0, and the start time given after it was kept in the settings only: the first
    `doStep` at the start time was refused ("but the model is at t = 0")."""
    inst, refs = _instance(FMU3)
    inst.getUInt64([refs["n_people"]])
    inst.enterInitializationMode(startTime=2.0)
    inst.exitInitializationMode()
    inst.doStep(2.0, 0.1)
    assert inst.getFloat64([refs["time"]])[0] == pytest.approx(2.1)
    inst.terminate()
    inst.freeInstance()
    inst, refs = _instance(FMU2)
    inst.setBoolean([refs["door_open"]], [True])
    inst.setupExperiment(startTime=2.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    inst.doStep(2.0, 0.1)
    inst.terminate()
    inst.freeInstance()


def test_a_host_at_a_large_start_time_skipped_a_second_unnoticed(fmus):
    """Regression: the check that a communication point is where the last step ended allowed
    10⁻⁹ |t|, 1.7 s at t = 1.7·10⁹ s (Unix time): a host that skipped 1 s was accepted and the
    FMU simulated 1 s less than its clock said."""
    from fmpy.fmi1 import FMICallException

    t0 = 1.7e9
    inst, refs = _instance(FMU2)
    inst.setupExperiment(startTime=t0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    inst.doStep(t0, 0.5)
    with pytest.raises(FMICallException):
        inst.doStep(t0 + 1.5, 0.5)


def test_people_from_sources_made_people_inside_negative(fmus):
    """Regression: the FMU counted `people_inside` as the people at the start less those out,
    which went negative (−34 on gate-inflow) once people from its sources had left, and left
    them out of `mean_speed` (0 with dozens walking)."""
    scene = ROOT / "data" / "scenes" / "gate-inflow.toml"
    inst, refs = _instance(FMU2, scene)
    inst.setupExperiment(startTime=0.0)
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    sim = moreau_module().Simulation(scene)
    t, moving = 0.0, 0
    while t < 26.0 - 1e-9:
        before = dict(zip(sim.ids.tolist(), sim.positions))
        inst.doStep(t, 2.0)
        t += 2.0
        sim.advance_to(t)
        inside, evacuated = inst.getInteger([refs["people_inside"], refs["people_evacuated"]])
        assert evacuated == len(sim.exit_records())
        assert inside == sim.total_people - evacuated >= 0, t
        # The mean speed of everyone present before and after the step, entrants too.
        after = dict(zip(sim.ids.tolist(), sim.positions))
        both = [i for i in after if i in before]
        speed = (np.mean([np.hypot(*(after[i] - before[i])) for i in both]) / 2.0
                 if both else 0.0)
        assert inst.getReal([refs["mean_speed"]])[0] == pytest.approx(speed, abs=1e-12), t
        moving += speed > 0.1
    assert moving >= 5
    inst.terminate()
    inst.freeInstance()


def moreau_module():
    import moreau as module

    return module
