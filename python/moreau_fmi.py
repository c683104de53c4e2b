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
"""

from __future__ import annotations

import os
import shutil

from fmpy import extract, read_model_description
from fmpy.model_description import ModelDescription

N_PEOPLE = "n_people"


def people(fmu: str | os.PathLike, scene: str | os.PathLike | None = None,
           md: ModelDescription | None = None) -> int:
    """The FMU's `n_people` for `scene` (None: the scene the FMU ships): the FMU reads the
    scene, so the count is the FMU's own, whatever the scene file declares its people with."""
    from fmpy.fmi3 import FMU3Slave

    md = md or read_model_description(str(fmu))
    vr = next(v.valueReference for v in md.modelVariables if v.name == N_PEOPLE)
    scene_vr = next(v.valueReference for v in md.modelVariables if v.name == "scene")
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
