"""One run of a sweep, as a Dask task executes it on a worker: the `moreau` driver binary,
the in-process Python module `moreau` (engine `python`: the same run file, no subprocess),
or the FMU through fmpy, in the run's own directory, and the row it adds to the table.
Failures become rows, never exceptions."""

from __future__ import annotations

import json
import math
import pathlib
import subprocess
import time

RESULT = "result.json"
SCENE = "scene.toml"
OUTPUT = "run.h5"


def evacuation(exit_times, people: int) -> tuple[float, float]:
    """(evacuation time: when the last person passed an exit, NaN if someone never did;
    mean flow: people per second between the first and the last passage)."""
    t = sorted(exit_times)
    evac = t[-1] if len(t) == people and t else math.nan
    flow = (len(t) - 1) / (t[-1] - t[0]) if len(t) >= 2 and t[-1] > t[0] else math.nan
    return evac, flow


def run_variant(name: str, values: dict, seed: int, scene: str, run_dir: str,
                moreau: str = "moreau", engine: str = "driver", fmu: str | None = None) -> dict:
    """Runs one variant in `run_dir` and returns (and stores in result.json) its row."""
    directory = pathlib.Path(run_dir)
    directory.mkdir(parents=True, exist_ok=True)
    (directory / SCENE).write_text(scene)
    row = {"name": name, **values, "seed": seed, "engine": engine, "status": "failed",
           "error": "", "wall_seconds": math.nan, "people": 0, "passed_exit": 0,
           "evacuation_time": math.nan, "mean_flow": math.nan, "output": ""}
    start = time.perf_counter()
    try:
        if engine == "driver":
            _driver(directory, moreau, row)
        elif engine == "python":
            _python(directory, row)
        elif engine == "fmu":
            _fmu(directory, fmu, row)
        else:
            row["error"] = f"unknown engine {engine!r} (driver, python or fmu)"
    except Exception as e:  # a task must report, not raise
        row["error"] = f"{type(e).__name__}: {e}"
    row["wall_seconds"] = time.perf_counter() - start
    (directory / RESULT).write_text(json.dumps(row, indent=1, default=str) + "\n")
    return row


def _driver(directory: pathlib.Path, moreau: str, row: dict) -> None:
    proc = subprocess.run(
        [moreau, "run", SCENE, "-o", OUTPUT, "--force", "--quiet", "--summary-json", "summary.json"],
        cwd=directory, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if proc.returncode != 0:
        lines = [l for l in proc.stderr.strip().splitlines() if l.strip()]
        row["error"] = f"exit {proc.returncode}: " + (lines[-1] if lines else "no message")
        return
    _read_run(directory / OUTPUT, row)


def _python(directory: pathlib.Path, row: dict) -> None:
    """The run in this worker's process through the `moreau` module (it releases the GIL,
    so a worker's threads run in parallel). A bad scene raises `SceneError`: the row says so."""
    import moreau

    summary = moreau.run(moreau.Scene.from_file(directory / SCENE), directory / OUTPUT, force=True)
    (directory / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    _read_run(directory / OUTPUT, row)


def _read_run(output: pathlib.Path, row: dict) -> None:
    import h5py

    with h5py.File(output, "r") as f:
        people = int(f["people/radius"].shape[0])
        rows = f["exits"][:]
        names = [str(n, "utf-8") if isinstance(n, bytes) else str(n)
                 for n in f["exits"].attrs.get("names", [])]
        status = f.attrs["status"]
    exits = list(rows["t"])
    row["people"] = people
    row["passed_exit"] = len(exits)
    # Through each exit, by name (run files of format moreau-run/4 on say which).
    for k, name in enumerate(names):
        row[f"passed.{name}"] = int((rows["exit"] == k).sum())
    row["evacuation_time"], row["mean_flow"] = evacuation(exits, people)
    row["output"] = str(output)
    row["status"] = "complete" if status == "complete" else f"incomplete ({status})"


def _fmu(directory: pathlib.Path, fmu: str | None, row: dict) -> None:
    import tomllib

    import numpy as np
    from fmpy.util import write_csv

    if not fmu:
        row["error"] = "engine fmu needs --fmu"
        return
    scene = tomllib.loads((directory / SCENE).read_text())
    horizon = float(scene["time"]["horizon"])
    interval = float(scene["time"]["output_interval"])
    result = _simulate(fmu, stop_time=horizon, output_interval=interval,
                       start_values={"scene": str(directory / SCENE)})
    write_csv(str(directory / "outputs.csv"), result)
    evacuated = result["people_evacuated"]
    # Everyone in the run by its end: out plus inside, at the last row (at the first, before
    # anyone entered from a source, a late source made the evacuation look finished).
    people = int(evacuated[-1] + result["people_inside"][-1])
    # Passage times at the output resolution: when the count first reaches k.
    times = [float(result["time"][np.argmax(evacuated >= k)]) for k in range(1, int(evacuated[-1]) + 1)]
    row["people"] = people
    row["passed_exit"] = int(evacuated[-1])
    # Through each exit, where the FMU declares its scene's exits (`fmu/package.py --scene`).
    for name in result.dtype.names:
        if name.startswith("passed."):
            row[name] = int(result[name][-1])
    row["evacuation_time"], row["mean_flow"] = evacuation(times, people)
    row["output"] = str(directory / "outputs.csv")
    row["status"] = "complete"


def _simulate(fmu: str, **kwargs):
    """fmpy's `simulate_fmu` on an instance this function frees, whatever happens: when
    `simulate_fmu` raises (a scene the FMU refuses), fmpy 0.3 neither frees the instance it
    made (its whole crowd) nor removes the directory it extracted the FMU to, and a worker
    running many tasks would keep both from every failed one."""
    import shutil

    from fmpy import extract, instantiate_fmu, read_model_description, simulate_fmu

    model = read_model_description(fmu)
    unzipped = extract(fmu)
    instance = None
    try:
        instance = instantiate_fmu(unzipped, model, "CoSimulation")
        return simulate_fmu(unzipped, model_description=model, fmu_instance=instance, **kwargs)
    finally:
        if instance is not None:
            instance.freeInstance()
        shutil.rmtree(unzipped, ignore_errors=True)
