"""`python -m moreau_ensemble SWEEP.toml --out DIR [--scheduler tcp://host:8786]`: runs a
sweep on Dask (a LocalCluster unless a scheduler is named) and writes DIR/results.csv."""

from __future__ import annotations

import argparse
import pathlib
import shutil
import sys

from .runner import TABLE, default_moreau, run_sweep
from .sweep import load_sweep


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m moreau_ensemble",
                                description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("sweep", type=pathlib.Path, help="the sweep file (TOML)")
    p.add_argument("--out", type=pathlib.Path, required=True,
                   help="run directory: runs/<variant>/ and results.csv; rerun to resume")
    p.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://host:8786); "
                   "default: a LocalCluster on this machine")
    p.add_argument("--workers", type=int, default=2, help="LocalCluster workers (default 2)")
    p.add_argument("--engine", choices=["driver", "python", "fmu"], default="driver",
                   help="run the moreau binary (default), the moreau Python module in the "
                   "workers' processes, or the FMU through fmpy")
    p.add_argument("--moreau", default=None,
                   help=f"the driver binary as the workers see it (default {default_moreau()})")
    p.add_argument("--fmu", help="the FMI 2 .fmu for --engine fmu")
    p.add_argument("--retry-failed", action="store_true", help="run failed variants again")
    p.add_argument("--plot", action="store_true", help="also draw DIR/evacuation.png")
    args = p.parse_args(argv)
    # Refused before any run: a run of each would fail (or, for --workers 0, wait forever).
    if args.workers < 1:
        p.error(f"--workers {args.workers}: must be at least 1")
    if args.engine == "fmu" and not args.fmu:
        p.error("--engine fmu needs --fmu FILE (the FMI 2 .fmu)")
    if not args.scheduler:  # the workers are on this machine: their files are these
        if args.engine == "fmu" and not pathlib.Path(args.fmu).is_file():
            p.error(f"--fmu {args.fmu}: no such file")
        moreau = args.moreau or default_moreau()
        if args.engine == "driver" and shutil.which(moreau) is None:
            p.error(f"--moreau {moreau}: no such program (the moreau driver binary)")

    try:
        sweep = load_sweep(args.sweep)
    except (OSError, ValueError) as e:
        p.error(str(e))
    from dask.distributed import Client, LocalCluster

    if args.scheduler:
        client = Client(args.scheduler)
        cluster = None
    else:
        cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        rows = run_sweep(sweep, args.out, client, moreau=args.moreau, engine=args.engine,
                         fmu=args.fmu, retry_failed=args.retry_failed)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    failed = sum(r["status"] != "complete" for r in rows)
    print(f"wrote {args.out / TABLE}: {len(rows)} runs, {failed} failed")
    if args.plot:
        from .plot import plot

        print(f"wrote {plot(args.out / TABLE, args.out / 'evacuation.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
