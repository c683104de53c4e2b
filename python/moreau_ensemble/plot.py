"""The sweep's figure: evacuation time and mean flow against the parameter the sweep varies
(door width when it does, else the first one varied, else the seed), one line per value of
the other varied parameters (the evacuation study: door width, one line per crowd size), mean
± standard deviation over the seeds. The evacuation time's mean is over the runs in which
everyone got out: a point where some did not says how many did ("evacuated k of N")."""

from __future__ import annotations

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

STATISTICS = ["evacuation_mean", "evacuation_std", "flow_mean", "flow_std", "runs", "evacuated"]


def varied(df: pd.DataFrame) -> list[str]:
    """The parameters the sweep varies: the table's columns between `name` and `seed` (each
    row is the variant's name, its values, its seed, then what the run gave)."""
    columns = list(df.columns)
    return columns[columns.index("name") + 1:columns.index("seed")]


def summary(table) -> pd.DataFrame:
    """Over the complete runs of each combination of the varied parameters (of each seed when
    none varies): the evacuation time's mean and standard deviation over the runs in which
    everyone got out (`evacuated` of them; a run where someone never did has no evacuation
    time), the mean flow's mean and standard deviation, and the number of runs (`runs`)."""
    df = pd.read_csv(table)
    keys = varied(df) or ["seed"]
    df = df[df["status"] == "complete"]
    return df.groupby(keys).agg(
        evacuation_mean=("evacuation_time", "mean"), evacuation_std=("evacuation_time", "std"),
        flow_mean=("mean_flow", "mean"), flow_std=("mean_flow", "std"),
        runs=("seed", "size"), evacuated=("evacuation_time", "count")).reset_index()


def plot(table, png) -> pathlib.Path:
    s = summary(table)
    keys = [c for c in s.columns if c not in STATISTICS]
    x = "door_width" if "door_width" in keys else keys[0]
    lines = [k for k in keys if k != x]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for k, (values, part) in enumerate(s.groupby(lines) if lines else [((), s)]):
        label = ", ".join(f"{key} = {v}" for key, v in zip(lines, values)) or None
        a.errorbar(part[x], part["evacuation_mean"], yerr=part["evacuation_std"], marker="o",
                   capsize=3, color=f"C{k}", label=label)
        b.errorbar(part[x], part["flow_mean"], yerr=part["flow_std"], marker="o", capsize=3,
                   color=f"C{k}", label=label)
        # Where some runs never evacuated, how many did, along the bottom (a point of none
        # has no mean to draw).
        short = part[part["evacuated"] < part["runs"]]
        for at, got, runs in zip(short[x], short["evacuated"], short["runs"]):
            a.annotate(f"evacuated {got} of {runs}", (at, 0.03 + 0.07 * k), ha="center",
                       xycoords=("data", "axes fraction"), fontsize=8, color=f"C{k}")
    xlabel = "door width (m)" if x == "door_width" else x
    runs, evacuated = int(s["runs"].sum()), int(s["evacuated"].sum())
    a.set(xlabel=xlabel, ylabel="evacuation time (s)",
          title=f"Evacuation time (mean ± sd over the runs in which\n"
                f"everyone got out: {evacuated} of {runs})")
    b.set(xlabel=xlabel, ylabel="mean flow (people/s)", title="Mean flow through the door")
    if lines:
        a.legend()
        b.legend()
    png = pathlib.Path(png)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
