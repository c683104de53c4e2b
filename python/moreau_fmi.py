"""fmpy and the moreau FMUs: FMI 3 arrays sized by the scene the FMU runs.

The FMI 3 FMU sizes `positions[n_people][2]` and `radii[n_people]` by its structural
parameter `n_people`, which it takes from the scene. fmpy (0.3.32) sizes an array once, from
the *model description's* start value of the structural parameter (150, the shipped room), and
never asks the FMU. `model_description(fmu, scene)` asks the FMU for `n_people` with that
scene and returns fmpy's model description with the arrays sized for it; give it to
`simulate_fmu(..., model_description=...)`:

    import moreau_fmi
    from fmpy import simulate_fmu
    fmu, scene = "target/fmu/moreau-crowd-fmi3.fmu", "data/scenes/room-60.toml"
    r = simulate_fmu(fmu, start_values={"scene": scene}, stop_time=5, output_interval=0.5,
                     model_description=moreau_fmi.model_description(fmu, scene))
    r["positions"].shape   # (11, 60, 2)

The FMI 2 FMU has scalar outputs only: nothing to size.

An FMU built for a scene with moving bodies (`fmu/package.py --scene FILE`) has one
continuous Real input per body, `moving.<name>`: the body's keyframe parameter (its position).
`moving_inputs(md)` lists them and `signal(md, time, {...})` makes the input array of
`simulate_fmu` for them (and the other inputs), typed from the model description:

    md = read_model_description("target/fmu/moreau-crowd-corridor-door-fmi3.fmu")
    door = moreau_fmi.signal(md, [0, 2, 2.25, 12], {"moving.door": [0, 0, 1, 1]})
    r = simulate_fmu(fmu, stop_time=12, output_interval=0.25, input=door)

Such an FMU also has, for each exit of its scene, a Boolean input `exit_open.<name>` and an
Integer output `passed.<name>` (how many passed it); `signal` types a Boolean input's column
as bools:

    md = read_model_description("target/fmu/moreau-crowd-room-two-exits-fmi3.fmu")
    east = moreau_fmi.signal(md, [0, 8, 8, 30], {"exit_open.east": [False, False, True, True]})
"""

from __future__ import annotations

import os
import shutil

from fmpy import extract, read_model_description
from fmpy.model_description import ModelDescription

N_PEOPLE = "n_people"
# The value reference of the first moving body's position input (fmu/src/model.rs, vr::MOVING).
MOVING = 1000


def people(fmu: str | os.PathLike, scene: str | os.PathLike | None = None,
           md: ModelDescription | None = None) -> int:
    """The FMU's `n_people` for `scene` (None: the scene the FMU ships): the FMU reads the
    scene, so the count is the FMU's own, whatever the scene file declares its people with."""
    from fmpy.fmi3 import FMU3Slave

    md = md or read_model_description(str(fmu))
    by_name = {v.name: v.valueReference for v in md.modelVariables}
    if not md.fmiVersion.startswith("3") or N_PEOPLE not in by_name or "scene" not in by_name:
        raise ValueError(f"{fmu}: an FMI {md.fmiVersion} FMU without the parameters "
                         f"{N_PEOPLE} and scene: only moreau's FMI 3 FMU has them")
    vr, scene_vr = by_name[N_PEOPLE], by_name["scene"]
    unzipped = extract(str(fmu))
    try:
        s = FMU3Slave(guid=md.guid, unzipDirectory=unzipped,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="n_people")
        s.instantiate()
        try:
            if scene is not None:
                s.setString([scene_vr], [str(scene)])
            return int(s.getUInt64([vr])[0])
        finally:
            s.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)


def model_description(fmu: str | os.PathLike,
                      scene: str | os.PathLike | None = None) -> ModelDescription:
    """fmpy's model description of `fmu`, its arrays sized for `scene` (FMI 2: as read)."""
    md = read_model_description(str(fmu))
    if not md.fmiVersion.startswith("3"):
        return md
    n = people(fmu, scene, md)
    by_vr = {v.valueReference: v for v in md.modelVariables}
    for v in md.modelVariables:
        if v.name == N_PEOPLE:
            v.start = str(n)
    for v in md.modelVariables:
        if v.dimensions:
            v.shape = tuple(int(d.start) if d.start is not None
                            else int(by_vr[d.valueReference].start) for d in v.dimensions)
    return md


def moving_inputs(md: ModelDescription) -> dict:
    """The moving bodies' position inputs of `md` by body name (`door` for `moving.door`):
    fmpy's variables, continuous Real inputs with value references 1000, 1001, ... in the
    scene's order."""
    return {v.name.removeprefix("moving."): v for v in md.modelVariables
            if v.causality == "input" and v.name.startswith("moving.")
            and v.valueReference >= MOVING}


def signal(md: ModelDescription, time, values: dict):
    """The structured array `simulate_fmu(..., input=...)` takes: a column `time` and one per
    input named in `values` (e.g. `{"moving.door": [0, 0, 1, 1]}`), each as long as `time`.
    Real inputs are floats, Boolean ones bools; a name that is not an input of `md` is
    refused, naming the inputs there are, and so are times that go back, times or values
    that are not finite numbers (a string, None), booleans for an input that is not Boolean,
    anything but True/False or 1/0 for one that is, and a column that is not a list."""
    import numpy as np

    inputs = {v.name: v for v in md.modelVariables if v.causality == "input"}
    columns = [("time", np.float64)]
    for name in values:
        if name not in inputs:
            raise ValueError(f"{name!r} is not an input of {md.modelName} "
                             f"(its inputs: {', '.join(sorted(inputs))})")
        columns.append((name, np.bool_ if inputs[name].type == "Boolean" else np.float64))
    time = np.asarray(time, dtype=np.float64)
    # fmpy interpolates between consecutive rows: times must be finite and never go back (a
    # time repeated makes a jump), and so must the values be finite.
    if time.ndim != 1 or not np.isfinite(time).all() or (np.diff(time) < 0).any():
        raise ValueError(f"time = {time.tolist()}: must be finite and never decrease")
    out = np.zeros(len(time), dtype=columns)
    out["time"] = time
    for name, given in values.items():
        column = np.asarray(given)
        if column.ndim != 1:
            raise ValueError(f"{name} = {column.tolist()}: must be a list of values, one per "
                             f"time (not an array of shape {column.shape})")
        if column.shape != time.shape:
            raise ValueError(f"{name}: {len(column)} values for {len(time)} times")
        # Numbers only ("false" is no False, None no number); booleans (True/False, 0/1)
        # only for a Boolean input.
        if out.dtype[name] == np.bool_:
            if column.dtype.kind not in "biuf" or not np.isin(column, [0, 1]).all():
                raise ValueError(f"{name} = {column.tolist()}: must be True/False (or 1/0): "
                                 f"a Boolean input")
        elif column.dtype.kind not in "iuf" or not np.isfinite(column).all():
            raise ValueError(f"{name} = {column.tolist()}: must be finite numbers: a "
                             f"{inputs[name].type} input")
        out[name] = column
    return out
