"""A moving door as a continuous Real input of the FMUs (issue 15, item 7), in fmpy: the FMUs
`fmu/package.py --scene data/fmu/corridor-door.toml` builds declare `moving.door` as a
continuous input in both model descriptions, fmpy's validator finds nothing, and
`simulate_fmu` with an input signal closes the door: nobody behind it passes, the people
ahead leave, FMI 2 and FMI 3 give the same run, and the door's signal is what the FMU reads
back. (That the run is the native `Simulation` driven with the same values, bit for bit, is
checked in fmu/tests/moving.rs.)"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

import moreau_fmi
from conftest import ROOT

SCENE = ROOT / "data" / "fmu" / "corridor-door.toml"
PANEL_X, RADIUS, AHEAD, PEOPLE = 12.0, 0.2, 8, 28
STOP, H = 12.0, 0.25


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("corridor-fmus")
    package = [sys.executable, str(ROOT / "fmu" / "package.py"), "--no-build", "--out", str(out)]
    subprocess.run(package + ["--scene", str(SCENE)], check=True, capture_output=True)
    subprocess.run(package, check=True, capture_output=True)  # the room's, for comparison
    fmus = {v: out / f"moreau-crowd-corridor-door-fmi{v}.fmu" for v in ("2", "3")}
    fmus.update({f"room{v}": out / f"moreau-crowd-fmi{v}.fmu" for v in ("2", "3")})
    return fmus


@pytest.mark.parametrize("version", ["2", "3"])
def test_the_door_is_a_continuous_real_input_and_fmpy_validates_the_fmu(fmus, version):
    fmu = str(fmus[version])
    assert validate_fmu(fmu) == []
    md = read_model_description(fmu, validate=True)
    door = moreau_fmi.moving_inputs(md)["door"]
    assert door.name == "moving.door"
    assert door.valueReference == moreau_fmi.MOVING
    assert (door.causality, door.variability) == ("input", "continuous")
    assert door.type == ("Real" if version == "2" else "Float64")
    assert float(door.start) == 0.0 and float(door.min) == 0.0 and float(door.max) == 1.0
    assert door.unit is None
    # The rest of the description is the scene's: its people, its horizon.
    assert md.defaultExperiment.stopTime == "12.0"
    if version == "3":
        assert next(v for v in md.modelVariables if v.name == "n_people").start == str(PEOPLE)
    # The room's FMU has no moving body, hence no such input.
    room = read_model_description(str(fmus[f"room{version}"]))
    assert moreau_fmi.moving_inputs(room) == {}


def simulate(fmu, door_values, times=(0.0, 2.0, 2.25, STOP), **kw):
    md = read_model_description(str(fmu))
    door = moreau_fmi.signal(md, times, {"moving.door": door_values})
    return simulate_fmu(str(fmu), stop_time=STOP, output_interval=H, input=door,
                        output=["people_evacuated", "internal_steps", "min_gap", "moving.door"]
                        + (["positions"] if md.fmiVersion.startswith("3") else []), **kw)


def test_simulate_fmu_closes_the_door_with_its_input_signal_and_nobody_passes_it(fmus):
    closing = {v: simulate(fmus[v], [0.0, 0.0, 1.0, 1.0]) for v in ("2", "3")}
    r = closing["3"]
    t = r["time"]
    np.testing.assert_allclose(np.diff(t), H)
    # fmpy sets the input at each communication point t, before the step, and samples after
    # it: what the FMU reads back at t + h is the signal at t, and that is where the door is.
    np.testing.assert_array_equal(
        r["moving.door"], np.interp(np.maximum(t - H, 0.0), [0, 2, 2.25, STOP], [0, 0, 1, 1]))
    # Set at the communication point 2.25 s, the door is closed at 2.5 s.
    x = r["positions"][:, :, 0]
    behind = x[t == 2.0][0] < PANEL_X
    assert behind.sum() == PEOPLE - AHEAD
    closed = t >= 2.5 - 1e-9
    assert np.all(x[closed][:, behind] <= PANEL_X - RADIUS + 1e-6), "someone passed the door"
    assert x[-1, behind].max() > PANEL_X - RADIUS - 0.01, "the front stands at the door"
    assert r["people_evacuated"][-1] == AHEAD
    # FMI 2 gives the same run (its scalar outputs, to the bit).
    for name in ("people_evacuated", "internal_steps", "min_gap", "moving.door"):
        np.testing.assert_array_equal(closing["2"][name], r[name], err_msg=name)

    # The door left open (the input held at 0, its start value): people behind it leave too.
    opened = simulate(fmus["3"], [0.0, 0.0, 0.0, 0.0])
    assert opened["people_evacuated"][-1] > AHEAD + 3
    assert np.any(opened["positions"][:, behind, 0] > PANEL_X)
    before = t <= 2.25 + 1e-9
    np.testing.assert_array_equal(opened["positions"][before], r["positions"][before])


@pytest.mark.parametrize("version", ["2", "3"])
def test_a_door_signal_out_of_the_keyframes_range_fails_the_simulation_naming_it(
        fmus, version, capfd):
    with pytest.raises(Exception, match="SetReal|SetFloat64"):
        simulate(fmus[version], [0.0, 0.0, 2.0, 2.0])
    out = capfd.readouterr().out
    assert "moving.door = 2: outside the body's keyframe times [0, 1] (it keeps its value 0)" \
        in out, out


def test_signal_refuses_a_name_that_is_no_input(fmus):
    md = read_model_description(str(fmus["3"]))
    with pytest.raises(ValueError, match="'moving.gate' is not an input.*moving.door"):
        moreau_fmi.signal(md, [0.0], {"moving.gate": [0.0]})


def test_signal_refuses_times_that_go_back_and_values_that_are_not_finite(fmus):
    """Regression: `signal` took times 1, 0 (fmpy then interpolates backwards) and NaN values
    without a word."""
    md = read_model_description(str(fmus["3"]))
    with pytest.raises(ValueError, match=r"time = \[1.0, 0.0\]: must be finite and never"):
        moreau_fmi.signal(md, [1.0, 0.0], {"moving.door": [0.0, 1.0]})
    with pytest.raises(ValueError, match=r"time = \[0.0, nan\]"):
        moreau_fmi.signal(md, [0.0, float("nan")], {"moving.door": [0.0, 1.0]})
    with pytest.raises(ValueError, match=r"moving.door = \[0.0, nan\]: must be finite"):
        moreau_fmi.signal(md, [0.0, 1.0], {"moving.door": [0.0, float("nan")]})
    steps = moreau_fmi.signal(md, [0.0, 2.0, 2.0, 3.0], {"moving.door": [0.0, 0.0, 1.0, 1.0]})
    assert steps["time"].tolist() == [0.0, 2.0, 2.0, 3.0]  # a repeated time is a jump


def test_signal_read_the_string_false_as_true_and_let_none_and_inf_through(fmus):
    """Regression: `signal` stored "false" as True in a Boolean input, None (NaN) and "inf"
    passed its finiteness check, and a 2-D column was "2 values for 2 times"."""
    md = read_model_description(str(fmus["room2"]))
    for values, said in [
        ({"door_open": ["false", "false"]}, "door_open = ['false', 'false']: must be True/False"),
        ({"door_open": [2, 1]}, "door_open = [2, 1]: must be True/False"),
        ({"speed_factor": [None, 1.0]}, "speed_factor = [None, 1.0]: must be finite numbers"),
        ({"speed_factor": ["inf", "1"]}, "speed_factor = ['inf', '1']: must be finite numbers"),
        ({"speed_factor": [True, False]}, "speed_factor = [True, False]: must be finite numb"),
        ({"speed_factor": [[1, 2], [3, 4]]}, "speed_factor = [[1, 2], [3, 4]]: must be a list"),
    ]:
        with pytest.raises(ValueError) as e:
            moreau_fmi.signal(md, [0.0, 1.0], values)
        assert said in str(e.value), str(e.value)
    ok = moreau_fmi.signal(md, [0.0, 1.0], {"door_open": [1, False], "speed_factor": [1, 0.5]})
    assert ok["door_open"].tolist() == [True, False]
    assert ok["speed_factor"].tolist() == [1.0, 0.5]


def test_people_on_an_fmi2_fmu_raised_a_bare_stop_iteration(fmus):
    """Regression: `people` looked for `n_people`, which only the FMI 3 FMU has, with
    `next()`: a bare StopIteration on the FMI 2 FMU."""
    with pytest.raises(ValueError, match=r"moreau-crowd-fmi2.fmu: an FMI 2.0 FMU without"):
        moreau_fmi.people(fmus["room2"])
    assert moreau_fmi.people(fmus["room3"]) == 150  # the shipped room's 150 people
