"""moreau in Python: build, step and inspect crowd simulations in-process.

People are disks that never overlap, stepped by Moreau's catching-up scheme (predict with the
desired velocity, project onto the feasible set with a certified accuracy). The extension
module ``moreau._moreau`` (Rust, PyO3) holds the simulation; this package adds ``run`` (the
HDF5 run file of ``moreau run``, with a tqdm progress bar) and ``to_pedpy``.

>>> import moreau
>>> sim = moreau.Simulation(moreau.Scene.from_file("data/scenes/room-150.toml"))
>>> sim.advance_to(5.0)            # releases the GIL while it computes
>>> sim.positions.shape            # numpy (n, 2), float64
(150, 2)
"""

from __future__ import annotations

import json
import os
from typing import Any, Callable

from ._moreau import Scene, SceneError, Simulation, __version__, run_to_file

__all__ = ["Scene", "SceneError", "Simulation", "run", "to_pedpy", "__version__"]


def run(scene: Scene | str | os.PathLike[str], output: str | os.PathLike[str] = "run.h5",
        progress: bool = False, force: bool = False) -> dict[str, Any]:
    """Runs ``scene`` (a ``Scene`` or a scene file) to its horizon into the HDF5 run file
    ``output``, written by the same observer as ``moreau run``: the same datasets and
    attributes (``command`` says ``moreau.run(...)``). An existing ``output`` raises
    ``FileExistsError`` unless ``force``. With ``progress`` a tqdm bar shows the simulated
    time. Releases the GIL while it computes; Ctrl-C stops the run, and the file keeps every
    frame so far (its ``status`` says why). Adaptive steps that miss ``time.tol`` give one
    ``RuntimeWarning``, as ``Simulation`` does. Returns the run's summary (the file's
    ``summary`` attribute) as a dict."""
    callback: Callable[[float, int, int], None] | None = None
    bar = None
    if progress:
        from tqdm.auto import tqdm

        horizon = (scene if isinstance(scene, Scene) else Scene.from_file(scene)).horizon
        bar = tqdm(total=round(horizon, 6), unit="s", desc="moreau",
                   bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} s [{elapsed}<{remaining}{postfix}]")

        def callback(t: float, steps: int, left: int) -> None:
            bar.n = min(round(t, 6), bar.total)
            bar.set_postfix(steps=steps, people_left=left, refresh=False)
            bar.refresh()

    try:
        text = run_to_file(scene, os.fspath(output), force=force,
                           command=f"moreau.run({os.fspath(output)!r})", progress=callback)
    finally:
        if bar is not None:
            bar.close()
    return json.loads(text)


def to_pedpy(run_or_sim: Simulation | str | os.PathLike[str]):
    """PedPy's ``(TrajectoryData, WalkableArea)`` of a run file (path) or of an in-memory
    ``Simulation`` built with ``record=True`` (its frames, every ``time.output_interval``;
    PedPy numbers frames ``t × fps``, so a last frame at a horizon off that grid is left
    out, as in the run file's ``/trajectory``).
    For a run file this is ``pedpy.load_trajectory_from_ped_data_archive_hdf5`` and
    ``load_walkable_area_from_ped_data_archive_hdf5``."""
    import pathlib

    import pedpy

    if isinstance(run_or_sim, Simulation):
        import pandas as pd
        import shapely

        import numpy as np

        _frame, t, ids, x, y = run_or_sim.recorded_frames()
        scene = run_or_sim.scene
        # PedPy reads a row's time as frame / fps: frames at t × fps, as in the run file's
        # /trajectory; a frame off that grid (a horizon no output time reaches) is left out.
        fps = 1.0 / scene.output_interval
        grid = t * fps
        frame = np.rint(grid)
        on = np.abs(grid - frame) <= 1e-6
        data = pd.DataFrame({"id": ids[on], "frame": frame[on].astype(np.int64), "x": x[on],
                             "y": y[on]})
        traj = pedpy.TrajectoryData(data=data, frame_rate=fps)
        walkable = pedpy.WalkableArea(shapely.from_wkt(scene.wkt))
        return traj, walkable
    path = pathlib.Path(run_or_sim)
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=path)
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=path)
    return traj, walkable
