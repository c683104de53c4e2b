"""Ensembles of moreau runs on Dask: parameter sweeps and seeds.

A sweep file (TOML) names a base scene, fixed settings, the parameters to vary and the number
of seeds; every combination is one run, submitted as one Dask task that runs the `moreau`
driver binary (or the FMU through fmpy) in its own directory. The results table has one row
per run, failures included; a sweep resumed in the same directory reruns nothing.

    python -m moreau_ensemble data/sweeps/evacuation.toml --out out/evacuation --plot
"""

from .sweep import Sweep, Variant, load_sweep
from .runner import run_sweep

__all__ = ["Sweep", "Variant", "load_sweep", "run_sweep"]
