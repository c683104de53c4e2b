"""Plots of a moreau run file: evacuation curve, flow through each door (PedPy's N–t where
people walk on past the exit, the exit records where it removes them), density map (PedPy),
speed over time and the per-step solver statistics.

    .venv/bin/python python/plot_run.py out/room-150.h5 -o out/room-150-plots

writes evacuation.png, flow.png, density.png, speed.png, solver.png and overview.png (all
five on one figure) into the output directory.

    .venv/bin/python python/plot_run.py out/barrier-sweep.h5 --snapshots 0,5,10,15 -o out/sweep.png

draws the people (to scale, coloured by speed) and the walls, the moving ones in red, at those
times side by side.

    .venv/bin/python python/plot_run.py out/room-150.h5 --animate out/room-150.mp4

animates the run instead (MP4 through ffmpeg, GIF through Pillow): people to scale,
coloured by speed (viridis) or, with ``--color pressure`` on a run that recorded contacts,
by pressure Σλ (plasma); both scaled from 0 to the 99.5th percentile over the run, as in
``moreau view``'s player.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import h5py  # noqa: E402
import numpy as np  # noqa: E402
import pedpy  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import moreau_run  # noqa: E402


PEDPY, RECORDS = "PedPy N–t", "exit records"


def door_counts(run, traj) -> list[tuple[str, np.ndarray, np.ndarray, str]]:
    """For each exit of the scene: its name, the frame times, how many had gone through it by
    each, and where that count comes from. Where people walk on past the exit (`action =
    "continue"`), PedPy's N–t across the exit's line (`moreau_run.exit_line`): an independent
    count from the trajectories. Where the exit removes them, their trajectories end as their
    centre enters its area, before that line (no trajectory crosses it, and a line before the
    door misses people who come at it aslant), so the count is the run's exit records of that
    exit (run files of format moreau-run/4 on say which; in older ones every record is the
    first exit's)."""
    out = []
    with h5py.File(run.path) as f:
        walls = f["walls"][()] if "walls" in f else None
    t_frames = np.asarray(run.time, dtype=float)
    which = run.exits["exit"] if "exit" in (run.exits.dtype.names or ()) else None
    for k, exit_ in enumerate(run.scene.get("exits", [])):
        name = exit_.get("name", f"exit {k}")
        if exit_.get("action", "remove") == "continue":
            line = pedpy.MeasurementLine(moreau_run.exit_line(run.scene, k, walls))
            nt, _ = pedpy.compute_n_t(traj_data=traj, measurement_line=line)
            # PedPy's count at each frame (its times are the frames', to rounding).
            at = np.searchsorted(nt["time"].to_numpy(), t_frames + 1e-9, side="right") - 1
            counted = nt["cumulative_pedestrians"].to_numpy()[np.maximum(at, 0)].astype(float)
            out.append((name, t_frames, counted, PEDPY))
        else:
            mine = run.exits["t"] if which is None else run.exits["t"][which == k]
            if which is None and k > 0:
                mine = mine[:0]
            counted = np.searchsorted(np.sort(mine), t_frames, side="right").astype(float)
            out.append((name, t_frames, counted, RECORDS))
    return out


def evacuation(ax, run, counts):
    """N(t): people not yet through an exit (from the run's exit records) and, where an exit
    is counted by PedPy, the people not yet through a door by the exits' counts."""
    # Everyone who had entered by t, less those out: the file's entry times (in files before
    # 2026-11-28, the frame each person first appears in, which misses those who came and
    # went between two frames, and N(t) went below 0).
    if run.entry_time is not None:
        t_enter = np.sort(np.nan_to_num(run.entry_time, nan=0.0))
    else:
        present = np.isfinite(run.positions[:, :, 0])
        seen = present.any(axis=0)
        t_enter = np.sort(run.time[present.argmax(axis=0)[seen]])
    t_exit = np.sort(run.exits["t"])
    ts = np.union1d(np.union1d(t_enter, t_exit), [0.0, run.time[-1]])
    left = (np.searchsorted(t_enter, ts, side="right")
            - np.searchsorted(t_exit, ts, side="right"))
    ax.step(ts, left, where="post", label="not yet out (exit records)")
    if any(source == PEDPY for *_, source in counts):
        through = sum(n for _, _, n, _ in counts)
        entered = np.searchsorted(t_enter, run.time, side="right")
        ax.plot(run.time, entered - through, "--",
                label="not yet across a door line (PedPy N–t)")
    ax.set(xlabel="t (s)", ylabel="people", title="Evacuation curve N(t)")
    ax.legend(fontsize=8)


def flow(ax, run, counts):
    """Through each door: how many by then, and the flow (the slope over 2 s windows)."""
    ax.set(xlabel="t (s)", ylabel="people through", title="Flow through the doors"
           if len(counts) > 1 else "Flow through the door")
    window = max(1, int(round(2 * run.fps)))
    ax2 = ax.twinx() if any(len(n) > window for _, _, n, _ in counts) else None
    for k, (name, t, n, source) in enumerate(counts):
        colour = f"C{2 * k}"
        ax.plot(t, n, color=colour, label=f"{name} ({source})")
        if ax2 is not None and len(n) > window:
            rate = (n[window:] - n[:-window]) / (t[window:] - t[:-window])
            ax2.plot(t[window:], rate, color=f"C{2 * k + 1}", lw=0.8, label=f"{name}: flow (1/s)")
    if ax2 is not None:
        ax2.set_ylabel("flow (1/s)")
        ax2.legend(loc="lower right", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)


def frames_on_grid(time, fps) -> int:
    """The frames PedPy has (`/trajectory`'s): those at a whole number of 1/fps; a last frame
    at a horizon off that grid is in the run file only, and counted it biased the mean."""
    grid = np.asarray(time, dtype=float) * fps
    return int(np.sum(np.abs(grid - np.rint(grid)) <= 1e-6))


def density(ax, traj, walkable, frames, cell=0.5):
    """Mean classic density on a grid (PedPy density profile) over the run's `frames` frames,
    those with nobody in counting as zero. (PedPy has a profile for each frame someone is in,
    and its plot averages those only: the mean of a run everyone left halfway through was
    twice the run's.)"""
    if traj.data.empty:
        # Nobody in any frame: PedPy's profile of nothing failed inside matplotlib.
        ax.text(0.5, 0.5, "nobody in the run", ha="center", va="center", transform=ax.transAxes)
        ax.set_title("Density map (PedPy)")
        return
    profiles = pedpy.compute_density_profile(
        data=traj.data, walkable_area=walkable, grid_size=cell,
        density_method=pedpy.DensityMethod.CLASSIC)
    mean = np.sum(profiles, axis=0) / frames
    pedpy.plot_profiles(walkable_area=walkable, profiles=[mean], axes=ax,
                        label="density (1/m²)", vmin=0, cmap="YlOrRd")
    ax.set_title(f"Density map (PedPy, {cell} m cells, mean over the run)")


def speed(ax, run):
    """Mean and 10–90 % band of the speeds of the people present, from frame differences."""
    p = run.positions
    dt = np.diff(run.time)[:, None]
    v = np.linalg.norm(np.diff(p, axis=0), axis=2) / dt
    tm = 0.5 * (run.time[1:] + run.time[:-1])
    if v.size == 0:
        ax.text(0.5, 0.5, "nobody in the run", ha="center", va="center", transform=ax.transAxes)
        ax.set(xlabel="t (s)", ylabel="speed (m/s)", title="Speed over time")
        return
    # Frames after everyone left have no speeds: NaN there, without numpy's warnings (which
    # np.errstate does not reach).
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
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


def frame_speeds(run) -> np.ndarray:
    """(F, N) speeds from frame differences: backward, and forward for the first frame (the
    player's rule); NaN where a person is absent."""
    p = run.positions
    f = len(run.time)
    v = np.full(p.shape[:2], np.nan)
    if f > 1:
        dt = np.diff(run.time)[:, None]
        d = np.linalg.norm(np.diff(p, axis=0), axis=2) / dt
        v[1:] = d
        v[0] = d[0]
    return v


def colour_scale(values: np.ndarray) -> float:
    """The top of the colour scale: the 99.5th percentile of the finite values (1 if none)."""
    finite = values[np.isfinite(values)]
    top = float(np.percentile(finite, 99.5)) if finite.size else 0.0
    return top if top > 0 else 1.0


def animate(run, out: pathlib.Path, color: str = "speed", fps: float | None = None,
            max_frames: int | None = None, dpi: int = 100) -> int:
    """Writes the run as an animation (``.mp4`` through ffmpeg, ``.gif`` through Pillow);
    returns the number of frames written."""
    import h5py
    from matplotlib import animation
    from matplotlib.collections import EllipseCollection, LineCollection

    if out.suffix.lower() not in (".mp4", ".gif"):
        raise SystemExit(f"--animate {out}: the file must end in .mp4 or .gif")
    if color == "pressure":
        with h5py.File(run.path, "r") as f:
            if "frames/pressure" not in f:
                raise SystemExit(f"{run.path}: no contact forces recorded "
                                 "(run the scene with [output] contacts = true)")
            values = f["frames/pressure"][...]
        cmap, label = "plasma", "pressure Σλ (m/s)"
    else:
        values, cmap, label = frame_speeds(run), "viridis", "speed (m/s)"
    frames = np.arange(len(run.time))
    if max_frames and len(frames) > max_frames:
        frames = frames[:: int(np.ceil(len(frames) / max_frames))]
    if not len(frames):
        raise SystemExit(f"{run.path}: the run has no frames")
    top = colour_scale(values)

    with h5py.File(run.path, "r") as f:
        walls = f["walls"][...] if "walls" in f else np.zeros((0, 4))
    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    draw_scene(ax, run, walls)
    moving = moving_walls(run)
    bodies = LineCollection(moving[0].reshape(-1, 2, 2), colors="tab:red", linewidths=2.5)
    ax.add_collection(bodies)
    disks = EllipseCollection(widths=[], heights=[], angles=[], units="xy", offsets=np.zeros((0, 2)),
                              offset_transform=ax.transData, cmap=cmap)
    disks.set_clim(0.0, top)
    ax.add_collection(disks)
    fig.colorbar(disks, ax=ax, label=label, shrink=0.8)
    title = ax.set_title("")

    def draw(k):
        present = np.isfinite(run.positions[k, :, 0])
        disks.set_offsets(run.positions[k, present])
        d = 2.0 * run.radius[present]
        disks.set_widths(d)
        disks.set_heights(d)
        disks.set_angles(np.zeros_like(d))
        disks.set_array(np.nan_to_num(values[k, present]))
        bodies.set_segments(moving[k].reshape(-1, 2, 2))
        title.set_text(f"{run.attrs['scene_name']}  t = {run.time[k]:.2f} s  "
                       f"{int(present.sum())} people")
        return disks, title

    rate = fps or (run.fps / max(1, frames[1] - frames[0] if len(frames) > 1 else 1))
    anim = animation.FuncAnimation(fig, draw, frames=frames, blit=False)
    if out.suffix.lower() == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise SystemExit("--animate .mp4 needs ffmpeg (scripts/setup.sh installs it); "
                             "or write a .gif")
        writer = animation.FFMpegWriter(fps=rate, codec="libx264",
                                        extra_args=["-pix_fmt", "yuv420p"])
    else:
        writer = animation.PillowWriter(fps=rate)
    anim.save(out, writer=writer, dpi=dpi)
    plt.close(fig)
    return len(frames)


def moving_walls(run) -> np.ndarray:
    """The segments of the moving bodies at every frame, ``(frames, segments, 4)`` (no
    segments for a run without moving bodies)."""
    import h5py

    with h5py.File(run.path, "r") as f:
        if "frames/moving_walls" in f:
            return f["frames/moving_walls"][...]
    return np.zeros((len(run.time), 0, 4))


def draw_scene(ax, run, walls: np.ndarray, pad: float = 0.5):
    """The area's box, the exits (green) and the fixed walls on `ax`."""
    from matplotlib.collections import LineCollection

    ax.set_aspect("equal")
    outer = np.asarray(run.scene["area"]["outer"], dtype=float)
    ax.set_xlim(outer[:, 0].min() - pad, outer[:, 0].max() + pad)
    ax.set_ylim(outer[:, 1].min() - pad, outer[:, 1].max() + pad)
    for exit_ in run.scene.get("exits", []):
        if exit_.get("area"):
            pts = np.asarray(exit_["area"], dtype=float)
            ax.fill(pts[:, 0], pts[:, 1], color="tab:green", alpha=0.25, lw=0)
        elif exit_.get("segment"):
            pts = np.asarray(exit_["segment"], dtype=float)
            ax.plot(pts[:, 0], pts[:, 1], color="tab:green", lw=3, alpha=0.8)
    ax.add_collection(LineCollection(walls.reshape(-1, 2, 2), colors="0.2", linewidths=1.5))


def snapshots(run, times: list[float], out: pathlib.Path, dpi: int = 110) -> list[float]:
    """Draws the run at the frames nearest `times`, side by side (stacked for wide areas):
    people to scale coloured by speed, fixed walls in grey, moving walls in red. Returns the
    frame times drawn."""
    import h5py
    from matplotlib.collections import EllipseCollection, LineCollection

    with h5py.File(run.path, "r") as f:
        walls = f["walls"][...] if "walls" in f else np.zeros((0, 4))
    moving = moving_walls(run)
    speeds = frame_speeds(run)
    top = colour_scale(speeds)
    outer = np.asarray(run.scene["area"]["outer"], dtype=float)
    span = outer.max(axis=0) - outer.min(axis=0)
    wide = span[0] > 2.5 * span[1]
    n = len(times)
    shape = (n, 1) if wide else (1, n)
    size = (9, 1.0 + n * 9 * span[1] / span[0]) if wide else (4.2 * n, 4.2 * span[1] / span[0] + 1)
    fig, axes = plt.subplots(*shape, figsize=size, constrained_layout=True, squeeze=False)
    drawn = []
    for ax, t in zip(axes.flat, times):
        k = int(np.argmin(np.abs(run.time - t)))
        draw_scene(ax, run, walls)
        ax.add_collection(LineCollection(moving[k].reshape(-1, 2, 2), colors="tab:red",
                                         linewidths=2.5))
        present = np.isfinite(run.positions[k, :, 0])
        d = 2.0 * run.radius[present]
        disks = EllipseCollection(widths=d, heights=d, angles=np.zeros_like(d), units="xy",
                                  offsets=run.positions[k, present],
                                  offset_transform=ax.transData, cmap="viridis")
        disks.set_array(np.nan_to_num(speeds[k, present]))
        disks.set_clim(0.0, top)
        ax.add_collection(disks)
        ax.set_title(f"t = {run.time[k]:.1f} s, {int(present.sum())} people", fontsize=10)
        drawn.append(float(run.time[k]))
    fig.colorbar(disks, ax=axes, label="speed (m/s)", shrink=0.8)
    fig.suptitle(run.attrs["scene_name"])
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return drawn


def load_or_explain(path: pathlib.Path):
    """The run file at `path`, or an exit with a message that says what is wrong with it:
    not HDF5 or truncated, not a moreau run file, or a run with nothing to plot yet."""
    try:
        run = moreau_run.load(path)
    except OSError as e:
        sys.exit(f"plot_run.py: {path}: cannot be read as HDF5 (not an HDF5 file, or a truncated "
                 f"one): {e}")
    except (KeyError, ValueError) as e:
        sys.exit(f"plot_run.py: {path}: not a moreau run file (missing or unreadable {e})")
    if len(run.steps) == 0 or len(run.time) < 2:
        sys.exit(f"plot_run.py: {path}: the run has {len(run.steps)} steps and {len(run.time)} "
                 f"frames (status {run.status}): nothing to plot yet")
    return run


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("run", type=pathlib.Path, help="the run file (HDF5)")
    parser.add_argument("-o", "--out", type=pathlib.Path,
                        help="output directory (default: <run>-plots next to the file)")
    parser.add_argument("--animate", type=pathlib.Path, metavar="OUT.mp4|OUT.gif",
                        help="write an animation of the run instead of the plots")
    parser.add_argument("--color", choices=["speed", "pressure"], default="speed",
                        help="what colours the people in the animation (default: speed)")
    parser.add_argument("--fps", type=float,
                        help="frames per second of the animation (default: real time)")
    parser.add_argument("--snapshots", metavar="T1,T2,...",
                        help="draw the run at these times side by side into -o (a .png)")
    parser.add_argument("--max-frames", type=int,
                        help="at most this many frames in the animation (every k-th frame)")
    args = parser.parse_args(argv)
    if args.run.is_dir():
        parser.error(f"{args.run} is a directory, not a run file")
    if not args.run.is_file():
        parser.error(f"no such run file: {args.run}")
    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        parser.error(f"--fps {args.fps:g}: must be finite and > 0")
    if args.max_frames is not None and args.max_frames < 1:
        parser.error(f"--max-frames {args.max_frames}: must be at least 1")
    times = []
    if args.snapshots:
        try:
            times = [float(t) for t in args.snapshots.split(",")]
        except ValueError:
            parser.error(f"--snapshots {args.snapshots}: give times in seconds, e.g. 0,5,10")
        if not all(np.isfinite(t) and t >= 0 for t in times):
            parser.error(f"--snapshots {args.snapshots}: times must be finite and ≥ 0 (s)")
    run = load_or_explain(args.run)
    if args.snapshots:
        # Each time is drawn at its nearest frame: one beyond the last frame by more than a
        # frame's interval has none.
        end = float(run.time[-1]) + 1.0 / run.fps
        if max(times) > end:
            parser.error(f"--snapshots {args.snapshots}: the run's frames end at "
                         f"{run.time[-1]:g} s")
        out = args.out or args.run.with_name(args.run.stem + "-snapshots.png")
        drawn = snapshots(run, times, out)
        print(f"wrote {out} (t = {', '.join(f'{t:g}' for t in drawn)} s)")
        return 0
    if args.animate:
        n = animate(run, args.animate, args.color, args.fps, args.max_frames)
        print(f"wrote {args.animate} ({n} frames)")
        return 0
    out = args.out or args.run.with_name(args.run.stem + "-plots")
    out.mkdir(parents=True, exist_ok=True)

    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=args.run)
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=args.run)
    counts = door_counts(run, traj)

    panels = {
        "evacuation": lambda ax: evacuation(ax, run, counts),
        "flow": lambda ax: flow(ax, run, counts),
        "density": lambda ax: density(ax, traj, walkable, frames_on_grid(run.time, traj.frame_rate)),
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
