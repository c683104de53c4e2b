"""The FMUs as co-simulation masters use them: FMU states (roll back, serialize, restore in a
new process, refused for another scene, no leak over 10,000 cycles), scenes of any size
through the `scene` parameter (FMI 3 arrays sized by the structural parameter `n_people`),
and the contract checked by fmpy's validator and its cross-check tools on the cross-check
tree of data/fmu/cross-check. Every comparison is with an independent run: a fresh instance,
another process, or the native driver."""

from __future__ import annotations

import json
import pathlib
import re
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.util import read_csv
from fmpy.validation import validate_fmu

import moreau_fmi
import moreau_run
from conftest import ROOT, moreau

sys.path.insert(0, str(ROOT / "fmu"))
import cross_check  # noqa: E402

FMUS = {"fmi2": ROOT / "target" / "fmu" / "moreau-crowd-fmi2.fmu",
        "fmi3": ROOT / "target" / "fmu" / "moreau-crowd-fmi3.fmu"}
ROOM60 = ROOT / "data" / "scenes" / "room-60.toml"
DENSE = ROOT / "data" / "scenes" / "dense-2000.toml"
# Value references (fmu/src/model.rs, the model descriptions).
SCENE, N_PEOPLE, SPEED, DOOR = 1, 5, 10, 11
INTS, REALS, POSITIONS = [20, 21, 25], [22, 23, 24], 31


@pytest.fixture(scope="module")
def fmus():
    subprocess.run([sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build"], check=True,
                   capture_output=True)
    return FMUS


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory):
    out = {}
    for which, fmu in fmus.items():
        out[which] = extract(str(fmu), unzipdir=str(tmp_path_factory.mktemp(which)))
    return out


class Slave:
    """One FMU instance driven as a master drives it (fmpy's low-level classes)."""

    def __init__(self, which, unzipped, scene=None, name="slave"):
        fmu = FMUS[which]
        self.md = read_model_description(str(fmu))
        self.v3 = which == "fmi3"
        cls = FMU3Slave if self.v3 else FMU2Slave
        self.s = cls(guid=self.md.guid, unzipDirectory=unzipped[which],
                     modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.s.instantiate()
        if scene is not None:
            self.s.setString([SCENE], [str(scene)])
        self.t = 0.0

    def init(self):
        if self.v3:
            self.s.enterInitializationMode(startTime=0.0)
        else:
            self.s.setupExperiment(startTime=0.0)
            self.s.enterInitializationMode()
        self.s.exitInitializationMode()
        return self

    def inputs(self, speed, door):
        (self.s.setFloat64 if self.v3 else self.s.setReal)([SPEED], [speed])
        self.s.setBoolean([DOOR], [door])

    def outputs(self):
        """Every output a master can read (FMI 3: the positions too), as plain numbers."""
        if self.v3:
            out = self.s.getInt32(INTS) + self.s.getFloat64(REALS)
            n = self.s.getUInt64([N_PEOPLE])[0]
            out += self.s.getFloat64([POSITIONS], nValues=2 * n)
        else:
            out = self.s.getInteger(INTS) + self.s.getReal(REALS)
        return [float(x) for x in out]

    def run(self, until, h=0.25):
        """Steps to `until`; the outputs after each step."""
        rows = []
        while self.t < until - 1e-9:
            self.s.doStep(self.t, h)
            self.t = round(self.t + h, 10)
            rows.append(self.outputs())
        return rows

    def free(self):
        self.s.freeInstance()


def same(a, b):
    """Equal bit for bit (NaN equal to NaN: people gone)."""
    return np.array_equal(np.array(a, dtype=float), np.array(b, dtype=float), equal_nan=True)


T, T2 = 3.0, 6.0
BRANCH_A = (1.0, False)  # the door closes at T
BRANCH_B = (0.5, True)  # everyone slows to half speed at T


def fresh(which, unzipped, branch):
    s = Slave(which, unzipped).init()
    s.run(T)
    s.inputs(*branch)
    rows = s.run(T2)
    s.free()
    return rows


@pytest.mark.parametrize("which", ["fmi2", "fmi3"])
def test_rolling_back_gives_exactly_two_fresh_runs(fmus, unzipped, which):
    s = Slave(which, unzipped).init()
    s.run(T)
    at_t = s.outputs()
    state = s.s.getFMUState()
    s.inputs(*BRANCH_A)
    a = s.run(T2)
    s.s.setFMUState(state)
    s.t = T
    assert same(s.outputs(), at_t), "the outputs at the saved point, before any step"
    s.inputs(*BRANCH_B)
    b = s.run(T2)
    s.s.freeFMUState(state)
    s.free()
    assert not same(a, b), "the two inputs lead to different runs"
    assert same(a, fresh(which, unzipped, BRANCH_A)), "after the first input"
    assert same(b, fresh(which, unzipped, BRANCH_B)), "after rolling back and the second input"


PROCESS = textwrap.dedent(r"""
    import json, pathlib, sys
    sys.path[:0] = [sys.argv[1], sys.argv[1] + "/../../python"]
    from test_fmu_state import Slave, FMUS
    from fmpy import extract
    which, mode, t1, t2, path = sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5]), sys.argv[6]
    unzipped = {which: extract(str(FMUS[which]))}
    if mode == "save":          # run to t1, write the serialized state
        s = Slave(which, unzipped).init()
        s.run(t1)
        state = s.s.getFMUState()
        pathlib.Path(path).write_bytes(s.s.serializeFMUState(state))
        s.s.freeFMUState(state)
        rows = []
    elif mode == "resume":      # a new instance, never initialized: the state is all it gets
        s = Slave(which, unzipped)
        state = s.s.deserializeFMUState(pathlib.Path(path).read_bytes())
        s.s.setFMUState(state)
        s.s.freeFMUState(state)
        s.t = t1
        rows = s.run(t2)
    else:                       # uninterrupted, from 0
        s = Slave(which, unzipped).init()
        s.run(t1)
        rows = s.run(t2)
    s.free()
    print(json.dumps(rows))
""")


@pytest.mark.parametrize("which", ["fmi2", "fmi3"])
def test_a_serialized_state_continues_in_a_new_process_as_if_never_stopped(fmus, which, tmp_path):
    script = tmp_path / "process.py"
    script.write_text(PROCESS)
    saved = tmp_path / "state.bin"

    def process(mode):
        proc = subprocess.run([sys.executable, str(script), str(ROOT / "tests" / "python"), which,
                               mode, str(T), str(T2), str(saved)],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return json.loads(proc.stdout.strip().splitlines()[-1])

    process("save")
    blob = saved.read_bytes()
    assert blob[:8] == b"moreauFS", "the format's magic"
    resumed, straight = process("resume"), process("straight")
    assert len(resumed) == len(straight) == round((T2 - T) / 0.25)
    assert same(resumed, straight)


@pytest.mark.parametrize("which", ["fmi2", "fmi3"])
def test_a_state_of_another_scene_is_refused_with_a_log_line(fmus, unzipped, which, capfd):
    a = Slave(which, unzipped, name="room150").init()
    a.run(1.0)
    state = a.s.getFMUState()
    blob = a.s.serializeFMUState(state)
    a.s.freeFMUState(state)
    a.free()

    b = Slave(which, unzipped, scene=ROOM60, name="room60").init()
    b.run(0.5)
    before = b.outputs()
    capfd.readouterr()
    other = b.s.deserializeFMUState(blob)  # the bytes are a state of this FMU: accepted
    with pytest.raises(Exception, match="status 3"):
        b.s.setFMUState(other)
    log = capfd.readouterr().out
    assert "[ERROR]" in log and "saved from another scene" in log and "room-60.toml" in log, log
    assert same(b.outputs(), before), "nothing changed"
    b.s.freeFMUState(other)
    b.run(1.0)  # and it goes on

    with pytest.raises(Exception, match="status 3"):
        b.s.deserializeFMUState(blob[:-5])
    assert "serializedState:" in capfd.readouterr().out
    damaged = bytearray(blob)
    damaged[8:12] = (1).to_bytes(4, "little")  # a state of a build before the moving inputs
    with pytest.raises(Exception, match="status 3"):
        b.s.deserializeFMUState(bytes(damaged))
    assert "format 1; this FMU reads format 4" in capfd.readouterr().out
    b.free()


LEAK = textwrap.dedent(r"""
    import sys
    sys.path[:0] = [sys.argv[1], sys.argv[1] + "/../../python"]
    from test_fmu_state import Slave, FMUS
    from fmpy import extract
    which = sys.argv[2]
    s = Slave(which, {which: extract(str(FMUS[which]))}).init()
    s.run(1.0)
    def rss_kib():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4
    def get_set_free():
        state = s.s.getFMUState()
        s.s.setFMUState(state)
        s.s.freeFMUState(state)
    def serialize_deserialize():
        state = s.s.getFMUState()
        again = s.s.deserializeFMUState(s.s.serializeFMUState(state))
        s.s.setFMUState(again)
        s.s.freeFMUState(again)
        s.s.freeFMUState(state)
    figures = []
    for cycle in (get_set_free, serialize_deserialize):
        for _ in range(500):
            cycle()
        before = rss_kib()
        for _ in range(10_000):
            cycle()
        figures += [before, rss_kib()]
    s.run(1.5)  # still sound
    s.free()
    print(*figures)
""")


@pytest.mark.parametrize("which", ["fmi2", "fmi3"])
def test_ten_thousand_state_cycles_leave_memory_flat(fmus, which, tmp_path):
    script = tmp_path / "leak.py"
    script.write_text(LEAK)
    proc = subprocess.run([sys.executable, str(script), str(ROOT / "tests" / "python"), which],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    b1, a1, b2, a2 = map(int, proc.stdout.split())
    print(f"{which}: resident memory over 10,000 get/set/free cycles: {b1} KiB -> {a1} KiB "
          f"({a1 - b1:+d} KiB); over 10,000 get/serialize/deserialize/set/free cycles: "
          f"{b2} KiB -> {a2} KiB ({a2 - b2:+d} KiB)")
    assert a1 - b1 < 1024 and a2 - b2 < 1024


# ---- Scenes of any size -------------------------------------------------------------------

@pytest.fixture(scope="module")
def native(tmp_path_factory):
    runs = {}
    for scene in (ROOM60, DENSE):
        out = tmp_path_factory.mktemp("native") / f"{scene.stem}.h5"
        moreau("run", scene, "-o", out, "--quiet")
        runs[scene.stem] = moreau_run.load(out)
    return runs


@pytest.mark.parametrize("scene,stop", [(ROOM60, 5.0), (DENSE, 2.0)], ids=["60", "2000"])
@pytest.mark.parametrize("which", ["fmi2", "fmi3"])
def test_fmpy_simulates_a_scene_of_any_size_through_the_scene_parameter(fmus, native, which,
                                                                         scene, stop):
    fmu = str(fmus[which])
    # FMI 3: fmpy sizes arrays from the XML; moreau_fmi asks the FMU for n_people.
    md = moreau_fmi.model_description(fmu, scene)
    r = simulate_fmu(fmu, start_values={"scene": str(scene)}, stop_time=stop, output_interval=0.5,
                     model_description=md)
    run = native[scene.stem]
    n = len(run.radius)
    assert n == {"room-60": 60, "dense-2000": 2000}[scene.stem]
    assert len(r) == round(stop / 0.5) + 1
    for k, t in enumerate(r["time"]):
        f = int(np.argmin(np.abs(run.time - t)))
        assert run.time[f] == pytest.approx(t, abs=1e-9)
        passed = int(np.sum(run.exits["t"] <= t + 1e-9))
        assert r["people_evacuated"][k] == passed
        assert r["people_inside"][k] == n - passed
        assert r["internal_steps"][k] == round(t / 0.05)
        if which == "fmi3":
            assert r["positions"][k].shape == (n, 2)
            np.testing.assert_allclose(r["positions"][k], run.positions[f], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(r["radii"][k][np.isfinite(r["radii"][k])],
                                          run.radius[np.isfinite(run.positions[f][:, 0])])
    assert r["people_evacuated"][-1] > 0, "people went through the door"


def test_n_people_is_the_scenes_and_a_wrong_value_is_refused(fmus, unzipped, capfd):
    s = Slave("fmi3", unzipped, scene=ROOM60)
    assert s.s.getUInt64([N_PEOPLE]) == [60]
    s.s.enterConfigurationMode()
    s.s.setUInt64([N_PEOPLE], [150])
    s.s.exitConfigurationMode()
    capfd.readouterr()
    s.s.enterInitializationMode(startTime=0.0)
    with pytest.raises(Exception, match="status 3"):
        s.s.exitInitializationMode()
    assert re.search(r"n_people = 150: the scene .*room-60\.toml has 60 people",
                     capfd.readouterr().out)
    s.free()
    s = Slave("fmi3", unzipped, scene=ROOM60).init()
    with pytest.raises(Exception, match="status 3"):
        s.s.getFloat64([POSITIONS], nValues=300)  # sized for the room's 150
    assert "n_people = 60 for this scene" in capfd.readouterr().out
    s.free()


# ---- The contract, checked by fmpy ----------------------------------------------------------

@pytest.mark.parametrize("which", ["fmi2", "fmi3"])
def test_fmpy_validate_finds_no_problem_and_the_capabilities_are_declared(fmus, which):
    assert validate_fmu(str(fmus[which])) == []
    cs = read_model_description(str(fmus[which])).coSimulation
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_the_cross_check_tree_passes_fmpys_cross_check_validation(fmus, version, tmp_path):
    from fmpy.cross_check.validate_vendor_repo import (validate_cross_check_result,
                                                       validate_test_fmu)

    repo = cross_check.assemble(tmp_path / "moreau")
    fmu_dir = cross_check.model_dir(repo, version)
    assert validate_test_fmu(str(fmu_dir)) == []

    # Import it as the rules say an importer does, with fmpy, and file the result.
    name = cross_check.MODEL
    ref = read_csv(str(fmu_dir / f"{name}_ref.csv"))
    opts = {k: float(v) for k, v in (line.split(",") for line in
                                     (fmu_dir / f"{name}_ref.opt").read_text().splitlines())}
    result = simulate_fmu(str(fmu_dir / f"{name}.fmu"), start_time=opts["StartTime"],
                          stop_time=opts["StopTime"], output_interval=opts["StepSize"],
                          input=read_csv(str(fmu_dir / f"{name}_in.csv")),
                          output=list(ref.dtype.names[1:]))
    import fmpy
    platform = fmu_dir.parts[-4]
    out = repo.joinpath("results", version, "cs", platform, "FMPy", fmpy.__version__,
                        cross_check.TOOL, cross_check.VERSION, name)
    out.mkdir(parents=True)
    header = ",".join(f'"{n}"' for n in result.dtype.names)
    np.savetxt(out / f"{name}_out.csv", result.astype([(n, float) for n in result.dtype.names]),
               delimiter=",", header=header, comments="", fmt="%.17g")
    (out / "passed").touch()
    assert validate_cross_check_result(str(out)) == []

    # fmpy's band is 10 % wide; the FMU is the native run, to rounding.
    assert len(result) == len(ref)
    np.testing.assert_allclose(result["time"], ref["time"], atol=1e-12)
    for n in ("people_inside", "people_evacuated"):
        np.testing.assert_array_equal(result[n], ref[n], err_msg=n)
    for n in ("mean_speed", "min_gap"):
        np.testing.assert_allclose(result[n], ref[n], rtol=1e-9, atol=1e-12, err_msg=n)


# ---- The README's rollback --------------------------------------------------------------------

def test_the_readmes_rollback_snippet_runs_and_rolls_back(fmus, unzipped, monkeypatch):
    monkeypatch.chdir(ROOT)
    text = (ROOT / "README.md").read_text()
    snippet = re.search(r"```python\n(# Roll back.*?)```", text, re.S)
    assert snippet, "the README's rollback snippet"
    scope = {}
    exec(compile(snippet.group(1), "README.md", "exec"), scope)
    closed, opened, again = scope["closed"], scope["opened"], scope["again"]
    # Against fresh instances: the door closed at 3 s, and left open.
    for result, branch in ((closed, BRANCH_A), (opened, (1.0, True))):
        rows = np.array(fresh("fmi3", unzipped, branch))
        assert result["time"][0] == 3.0 and len(result) == len(rows) + 1
        np.testing.assert_array_equal(result["people_evacuated"][1:], rows[:, 1])
        np.testing.assert_array_equal(result["mean_speed"][1:], rows[:, 3])
        np.testing.assert_array_equal(result["positions"][-1].ravel(), rows[-1, 6:])
    assert closed["people_evacuated"][-1] < opened["people_evacuated"][-1]
    # The serialized checkpoint, in a new instance: the open-door run again.
    for name in ("people_evacuated", "mean_speed", "min_gap", "positions"):
        np.testing.assert_array_equal(again[name], opened[name], err_msg=name)
