"""Plots of a moreau run file: evacuation curve, flow through the door, density map (PedPy),
speed over time and the per-step solver statistics.

    .venv/bin/python python/plot_run.py out/room-150.h5 -o out/room-150-plots

writes evacuation.png, flow.png, density.png, speed.png, solver.png and overview.png (all
five on one figure) into the output directory.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pedpy  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import moreau_run  # noqa: E402


def evacuation(ax, run, nt):
    """N(t): people not yet through an exit (from the run's exit records) and PedPy's count
    of crossings of the door line."""
    total = len(run.radius)
    t_exit = np.sort(run.exits["t"])
    ts = np.concatenate([[0.0], t_exit, [run.time[-1]]])
    left = total - np.concatenate([[0], np.arange(1, len(t_exit) + 1), [len(t_exit)]])
    ax.step(ts, left, where="post", label="not yet out (exit records)")
    ax.plot(nt["time"], total - nt["cumulative_pedestrians"], "--",
            label="not yet across the door line (PedPy N–t)")
    ax.set(xlabel="t (s)", ylabel="people", title="Evacuation curve N(t)")
    ax.legend(fontsize=8)


def flow(ax, run, nt):
    """Flow through the door line: the PedPy N–t curve and its slope over 2 s windows."""
    ax.plot(nt["time"], nt["cumulative_pedestrians"], label="N–t (PedPy)")
    ax.set(xlabel="t (s)", ylabel="crossings", title="Flow through the door")
    window = max(1, int(round(2 * run.fps)))
    n = nt["cumulative_pedestrians"].to_numpy()
    t = nt["time"].to_numpy()
    if len(n) > window:
        rate = (n[window:] - n[:-window]) / (t[window:] - t[:-window])
        ax2 = ax.twinx()
        ax2.plot(t[window:], rate, color="tab:orange", lw=0.8, label="flow (1/s)")
        ax2.set_ylabel("flow (1/s)")
        ax2.legend(loc="lower right", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)


def density(ax, traj, walkable, cell=0.5):
    """Mean classic density on a grid (PedPy density profile) over the whole run."""
    profiles = pedpy.compute_density_profile(
        data=traj.data, walkable_area=walkable, grid_size=cell,
        density_method=pedpy.DensityMethod.CLASSIC)
    pedpy.plot_profiles(walkable_area=walkable, profiles=profiles, axes=ax,
                        label="density (1/m²)", vmin=0, cmap="YlOrRd")
    ax.set_title(f"Density map (PedPy, {cell} m cells, mean over the run)")


def speed(ax, run):
    """Mean and 10–90 % band of the speeds of the people present, from frame differences."""
    p = run.positions
    dt = np.diff(run.time)[:, None]
    v = np.linalg.norm(np.diff(p, axis=0), axis=2) / dt
    tm = 0.5 * (run.time[1:] + run.time[:-1])
    with np.errstate(all="ignore"):
        mean = np.nanmean(v, axis=1)
        lo, hi = np.nanpercentile(v, [10, 90], axis=1)
    ax.fill_between(tm, lo, hi, alpha=0.3, label="10–90 %")
    ax.plot(tm, mean, label="mean")
    ax.set(xlabel="t (s)", ylabel="speed (m/s)", title="Speed over time")
    ax.legend(fontsize=8)


def solver(ax, run):
    """Per step: certified ε against its target, violation, and iterations."""
    s = run.steps
    ax.semilogy(s["t"], s["eps"], lw=0.8, label="certified ε (m²)")
    ax.semilogy(s["t"], s["eps_target"], "k--", lw=0.8, label="target ε_k")
    ax.semilogy(s["t"], np.maximum(s["violation"], 1e-18), lw=0.8, label="violation (m)")
    ax.set(xlabel="t (s)", title="Solver, per step")
    ax2 = ax.twinx()
    ax2.plot(s["t"], s["iterations"], color="tab:gray", lw=0.5, alpha=0.7)
    ax2.set_ylabel("iterations", color="tab:gray")
    ax.legend(fontsize=7, loc="lower left")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=pathlib.Path, help="the run file (HDF5)")
    parser.add_argument("-o", "--out", type=pathlib.Path,
                        help="output directory (default: <run>-plots next to the file)")
    args = parser.parse_args(argv)
    if not args.run.is_file():
        parser.error(f"no such run file: {args.run}")
    out = args.out or args.run.with_name(args.run.stem + "-plots")
    out.mkdir(parents=True, exist_ok=True)

    run = moreau_run.load(args.run)
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=args.run)
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=args.run)
    line = pedpy.MeasurementLine(moreau_run.exit_line(run.scene))
    nt, _ = pedpy.compute_n_t(traj_data=traj, measurement_line=line)

    panels = {
        "evacuation": lambda ax: evacuation(ax, run, nt),
        "flow": lambda ax: flow(ax, run, nt),
        "density": lambda ax: density(ax, traj, walkable),
        "speed": lambda ax: speed(ax, run),
        "solver": lambda ax: solver(ax, run),
    }
    for name, draw in panels.items():
        fig, ax = plt.subplots(figsize=(6.4, 4.2), constrained_layout=True)
        draw(ax)
        fig.savefig(out / f"{name}.png", dpi=110)
        plt.close(fig)
    fig, axes = plt.subplots(2, 3, figsize=(17, 9), constrained_layout=True)
    for ax, draw in zip(axes.flat, panels.values()):
        draw(ax)
    info = axes.flat[5]
    info.axis("off")
    summary = run.summary
    lines = [f"{run.attrs['scene_name']}  ({run.status})",
             f"{len(run.radius)} people, {len(run.steps)} steps, {len(run.time)} frames"]
    for key in ("passed_exit", "ms_per_step", "iterations_per_step", "max_eps", "max_violation"):
        if key in summary:
            value = summary[key]
            lines.append(f"{key}: {value:.3g}" if isinstance(value, float) else f"{key}: {value}")
    info.text(0.0, 1.0, "\n".join(lines), va="top", family="monospace", fontsize=10)
    fig.savefig(out / "overview.png", dpi=90)
    plt.close(fig)
    print(f"wrote {', '.join(n + '.png' for n in [*panels, 'overview'])} to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
