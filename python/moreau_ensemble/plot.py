"""The evacuation-time study's figure: evacuation time and mean flow against door width, one
line per crowd size, mean ± standard deviation over the seeds."""

from __future__ import annotations

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402


def summary(table) -> pd.DataFrame:
    """Mean, standard deviation and count over seeds, per door width and crowd size."""
    df = pd.read_csv(table)
    df = df[df["status"] == "complete"]
    people = "groups.0.count" if "groups.0.count" in df else "people"
    g = df.groupby(["door_width", people])
    out = g.agg(evacuation_mean=("evacuation_time", "mean"),
                evacuation_std=("evacuation_time", "std"),
                flow_mean=("mean_flow", "mean"), flow_std=("mean_flow", "std"),
                runs=("seed", "count")).reset_index()
    return out.rename(columns={people: "people"})


def plot(table, png) -> pathlib.Path:
    s = summary(table)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for n, part in s.groupby("people"):
        a.errorbar(part["door_width"], part["evacuation_mean"], yerr=part["evacuation_std"],
                   marker="o", capsize=3, label=f"{n} people")
        b.errorbar(part["door_width"], part["flow_mean"], yerr=part["flow_std"], marker="o",
                   capsize=3, label=f"{n} people")
    runs = int(s["runs"].max()) if len(s) else 0
    a.set(xlabel="door width (m)", ylabel="evacuation time (s)",
          title=f"Evacuation time (mean ± sd over {runs} seeds)")
    b.set(xlabel="door width (m)", ylabel="mean flow (people/s)", title="Mean flow through the door")
    a.legend()
    b.legend()
    png = pathlib.Path(png)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
