"""Submitting a sweep to Dask and collecting its table; resuming skips what is done."""

from __future__ import annotations

import csv
import json
import math
import pathlib
import shutil

from .sweep import Sweep
from .task import OUTPUT, RESULT, SCENE, run_variant

TABLE = "results.csv"


def _done(run_dir: pathlib.Path, scene: str, engine: str) -> dict | None:
    """The stored row of a finished run (complete with its output intact, or failed) of this
    scene text by this engine, else None. (Matched by name alone, a sweep whose `[set]`
    changed, the horizon say, reused every row run with the old scene.)"""
    result = run_dir / RESULT
    if not result.is_file():
        return None
    stored = run_dir / SCENE
    if not stored.is_file() or stored.read_text() != scene:
        return None
    try:
        row = json.loads(result.read_text())
    except json.JSONDecodeError:
        return None
    if row.get("engine") != engine:
        return None
    if row.get("status") == "complete" and row.get("engine") in ("driver", "python"):
        import h5py

        try:
            with h5py.File(run_dir / OUTPUT, "r") as f:
                if f.attrs["status"] != "complete":
                    return None
        except (OSError, KeyError):
            return None
    return row


def default_moreau() -> str:
    """The driver binary: target/release/moreau of this repository, else `moreau` on PATH."""
    repo = pathlib.Path(__file__).resolve().parents[2] / "target" / "release" / "moreau"
    return str(repo) if repo.is_file() else (shutil.which("moreau") or "moreau")


def run_sweep(sweep: Sweep, out, client=None, *, moreau: str | None = None,
              engine: str = "driver", fmu: str | None = None, retry_failed: bool = False,
              log=print) -> list[dict]:
    """Runs every variant of `sweep` not already done under `out/runs/`, one Dask task each
    on `client` (a `dask.distributed.Client`), and writes `out/results.csv`. Returns the rows,
    in the sweep's order; reused rows have `reused = True`."""
    from dask.distributed import as_completed

    out = pathlib.Path(out)
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    moreau = moreau or default_moreau()
    variants = sweep.variants()
    rows: dict[str, dict] = {}
    futures = {}
    for v in variants:
        run_dir = runs / v.name
        if run_dir.resolve().parent != runs.resolve():
            raise ValueError(f"variant {v.name!r}: its directory would not be in {runs}")
        done = _done(run_dir, v.scene, engine)
        if done is not None and (done.get("status") == "complete" or not retry_failed):
            rows[v.name] = {**done, "reused": True}
            continue
        future = client.submit(run_variant, v.name, v.values, v.seed, v.scene, str(run_dir),
                               moreau, engine, fmu, key=f"moreau-{out.name}-{v.name}", pure=False)
        futures[future] = v
    log(f"{len(variants)} runs: {len(rows)} done before, {len(futures)} submitted")
    for future in as_completed(futures):
        v = futures[future]
        try:
            row = future.result()
        except Exception as e:  # the worker itself failed
            row = {"name": v.name, **v.values, "seed": v.seed, "engine": engine,
                   "status": "failed", "error": f"task failed: {type(e).__name__}: {e}"}
        rows[v.name] = {**row, "reused": False}
        log(f"  {v.name}: {row['status']}" + (f" ({row.get('error')})" if row.get("error") else ""))
    ordered = [rows[v.name] for v in variants]
    write_table(out / TABLE, ordered)
    return ordered


def write_table(path: pathlib.Path, rows: list[dict]) -> None:
    """The results as CSV, one row per run (columns: the union of the rows' keys)."""
    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    tmp = path.with_suffix(".csv.partial")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v)
                             for k, v in row.items()})
    tmp.replace(path)
