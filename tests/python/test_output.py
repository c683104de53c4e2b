"""The HDF5 run file as Python users meet it: h5py and PedPy open it as is, its parts agree
with each other, nobody overlaps, and the file reproduces its run."""

from __future__ import annotations

import json
import pathlib
import re
import shutil

import h5py
import numpy as np
import pedpy
import pytest
import shapely

import moreau_run
from conftest import ROOT, moreau


class StepAxes:
    """A matplotlib axes stand-in that keeps what `ax.step` draws (`plot_run`'s curves)."""

    def __init__(self):
        self.curves = []

    def step(self, x, y, **kw):
        self.curves.append((np.asarray(x), np.asarray(y)))

    def plot(self, *a, **kw):
        pass

    def set(self, **kw):
        pass

    def legend(self, **kw):
        pass


def test_h5py_opens_the_layout_with_its_attributes(room_run):
    with h5py.File(room_run, "r") as f:
        for name in ("trajectory", "frames/time", "frames/count", "frames/positions",
                     "people/id", "people/radius", "people/exit_time", "exits", "steps"):
            assert name in f, name
        assert f["trajectory"].dtype.names[:4] == ("id", "frame", "x", "y")
        assert f["trajectory"].dtype["id"] == np.int64
        assert f["trajectory"].dtype["x"] == np.float64
        assert f["trajectory"].attrs["fps"] == pytest.approx(10.0)
        for key in ("wkt_geometry", "scene", "solver", "moreau_version", "seed", "status",
                    "summary", "command", "format"):
            assert key in f.attrs, key
        assert f.attrs["seed"] == 20130701
        assert f.attrs["status"] == "complete"
        assert f["frames/positions"].compression == "gzip"
        assert f["frames/positions"].shuffle
        assert f["frames/positions"].shape == (201, 150, 2)


def test_frames_ids_and_trajectory_agree(room_run):
    run = moreau_run.load(room_run)
    frames = len(run.time)
    assert frames == 201
    np.testing.assert_allclose(run.time, np.arange(frames) / run.fps, atol=1e-9)
    traj = run.trajectory
    # Rows per frame are the people present, and frames run 0..F-1 in order.
    per_frame = np.bincount(traj["frame"], minlength=frames)
    np.testing.assert_array_equal(per_frame, run.count)
    assert np.all(np.diff(traj["frame"]) >= 0)
    assert set(np.unique(traj["id"])) <= set(range(len(run.radius)))
    # Every trajectory row is the dense array at (frame, id); every other entry is NaN.
    dense = run.positions[traj["frame"], traj["id"]]
    np.testing.assert_array_equal(dense[:, 0], traj["x"])
    np.testing.assert_array_equal(dense[:, 1], traj["y"])
    assert np.isnan(run.positions).any(axis=2).sum() == frames * len(run.radius) - len(traj)
    # The room keeps everyone (exits continue to a target area).
    assert np.all(run.count == 150)


def test_exit_records_agree_with_the_dense_exit_times(room_run):
    run = moreau_run.load(room_run)
    with h5py.File(room_run, "r") as f:
        exit_time = f["people/exit_time"][:]
    assert len(np.unique(run.exits["id"])) == len(run.exits)
    np.testing.assert_array_equal(exit_time[run.exits["id"]], run.exits["t"])
    assert np.isnan(exit_time).sum() == len(run.radius) - len(run.exits)
    assert run.summary["passed_exit"] == len(run.exits) > 100


def test_no_overlap_in_any_frame(room_run):
    run = moreau_run.load(room_run)
    bound = float(run.scene["solver"]["max_violation"])
    worst_step = float(run.steps["violation"].max())
    assert worst_step <= bound
    gaps = moreau_run.min_gaps(run)
    # Linearized gaps under-estimate the (convex) true gaps, so a frame overlaps by at most
    # the worst certified violation of the steps (plus rounding).
    assert gaps.min() >= -worst_step - 1e-12, gaps.min()
    # And nobody crosses a wall: distance from each centre to the walls ≥ radius − bound.
    walkable = shapely.from_wkt(run.attrs["wkt_geometry"])
    boundary = walkable.boundary
    for frame in run.positions[:: 10]:
        pts = shapely.points(frame)
        assert shapely.contains(walkable, pts).all()
        d = shapely.distance(boundary, pts)
        assert (d - run.radius).min() >= -bound - 1e-12


def test_the_step_table_is_honest(room_run):
    run = moreau_run.load(room_run)
    s = run.steps
    assert len(s) == 400
    assert np.all(s["status"] == b"converged")
    assert np.all(s["eps"] <= s["eps_target"] * (1 + 1e-12))
    np.testing.assert_allclose(s["eps_target"], 1e-3 * s["mu"] ** 3, rtol=1e-12)
    assert s["mu"].sum() == pytest.approx(20.0, abs=1e-9)
    assert np.all(np.diff(s["t"]) > 0)
    assert np.all(s["time_total"] >= s["time_solve"])
    assert np.all(s["active"] <= s["assembled"])


def test_pedpy_computes_classic_density_and_n_t(room_run):
    run = moreau_run.load(room_run)
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=room_run)
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=room_run)
    assert walkable.polygon.area == pytest.approx(10 * 10 + 9.8 * 10 + 0.2 * 1.2)
    assert traj.frame_rate == pytest.approx(10.0)

    # Classic density in the 2 m x 2 m square in front of the door, against a count of the
    # dense positions done here.
    square = moreau_run.upstream_area(run.scene)
    area = pedpy.MeasurementArea(square)
    density = pedpy.compute_classic_density(traj_data=traj, measurement_area=area)
    assert len(density) == len(run.time)
    poly = shapely.Polygon(square)
    inside = np.array([shapely.contains_xy(poly, f[:, 0], f[:, 1]).sum() for f in run.positions])
    np.testing.assert_allclose(density["density"].to_numpy(), inside / poly.area, rtol=1e-12)
    assert density["density"].max() > 1.5  # people queue at the door

    # N–t at the door line: a person crosses it a few frames after entering the exit area.
    line = pedpy.MeasurementLine(moreau_run.exit_line(run.scene))
    nt, crossing = pedpy.compute_n_t(traj_data=traj, measurement_line=line)
    counted = nt["cumulative_pedestrians"].to_numpy()
    t = nt["time"].to_numpy()
    passed = np.searchsorted(np.sort(run.exits["t"]), t, side="right")
    passed_1s_before = np.searchsorted(np.sort(run.exits["t"]), t - 1.0, side="right")
    assert np.all(counted <= passed)
    assert np.all(counted >= passed_1s_before)
    assert counted[-1] >= len(run.exits) - 10


def test_summary_json_matches_the_file(room_run):
    summary = json.loads(room_run.with_suffix(".json").read_text())
    run = moreau_run.load(room_run)
    assert summary == run.summary
    assert summary["status"] == "complete"
    assert summary["steps"] == len(run.steps)
    assert summary["frames"] == len(run.time)
    assert summary["max_violation"] == pytest.approx(run.steps["violation"].max())


def test_a_run_file_reproduces_its_run(room_run, tmp_path):
    again = tmp_path / "again.h5"
    moreau("run", "--from", room_run, "-o", again, "--quiet")
    a, b = moreau_run.load(room_run), moreau_run.load(again)
    assert a.attrs["scene"] == b.attrs["scene"]
    np.testing.assert_array_equal(a.trajectory, b.trajectory)
    np.testing.assert_array_equal(a.steps["eps"], b.steps["eps"])


def test_a_run_file_from_before_the_lipschitz_default_replays_its_classic_run(tmp_path):
    """Run files written while the classic desired velocity was the default store scenes
    without `[model]`; `run --from` replays them with the classic one, as they ran (a scene file
    without `[model]` gets the Lipschitz one)."""
    import moreau as moreau_module
    from conftest import ROOM

    def run(kind: str) -> pathlib.Path:
        d = moreau_module.Scene.from_file(ROOM).to_dict()
        d["time"]["horizon"] = 6.0
        d["model"] = {"desired_velocity": kind}
        scene = tmp_path / f"{kind}.toml"
        scene.write_text(moreau_module.Scene.from_dict(d).to_toml())
        out = tmp_path / f"{kind}.h5"
        moreau("run", scene, "-o", out, "--quiet")
        return out

    classic, lipschitz = run("classic"), run("lipschitz")
    old = tmp_path / "old.h5"
    shutil.copy(classic, old)
    with h5py.File(old, "r+") as f:
        text = f.attrs["scene"]
        assert '[model]\ndesired_velocity = "classic"\n' in text, text
        f.attrs["scene"] = text.replace('[model]\ndesired_velocity = "classic"\n', "")
    again = tmp_path / "again.h5"
    moreau("run", "--from", old, "-o", again, "--quiet")
    a, b, c = (moreau_run.load(p) for p in (classic, again, lipschitz))
    np.testing.assert_array_equal(a.trajectory, b.trajectory)
    assert 'desired_velocity = "classic"' in b.attrs["scene"], "the replay names its kind"
    # The two kinds differ within these 6 s, so the replay could have gone the other way.
    assert not np.array_equal(a.trajectory, c.trajectory)


def test_the_plot_script_writes_its_pngs(room_run, tmp_path):
    import plot_run

    assert plot_run.main([str(room_run), "-o", str(tmp_path / "plots")]) == 0
    for name in ("evacuation", "flow", "density", "speed", "solver", "overview"):
        png = tmp_path / "plots" / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert png.stat().st_size > 10_000, name


def test_an_adaptive_run_with_clarabel_asks_no_less_than_clarabel_certifies(tmp_path):
    # Clarabel's certificates stop at ε/μ² = 4–7·10⁻⁷ on 10,000 people, above the default
    # floor 2·10⁻⁷: with kind = "clarabel" the floor is 2·10⁻⁶ (SolverKind::certified_floor), so an
    # adaptive run on dense-10k no longer halves its steps to μ_min and fails. Here, on the
    # room: every step's target is max((θ tol)² (μ / μ_max)³, 2·10⁻⁶ μ²), and certified.
    from conftest import ROOM

    text = ROOM.read_text().replace("horizon = 20.0", "horizon = 2.0")
    text = re.sub(r'(?m)^kind = .*$', 'kind = "clarabel"', text)
    short = tmp_path / "clarabel.toml"
    short.write_text(text)
    out = tmp_path / "clarabel.h5"
    moreau("run", short, "-o", out, "--quiet", "--tol", "0.01")
    run = moreau_run.load(out)
    mu = run.steps["mu"]
    assert {bytes(s).decode() for s in run.steps["solver"]} == {"clarabel"}
    expected = np.maximum((0.1 * 0.01) ** 2 * (mu / 0.1) ** 3, 2e-6 * mu ** 2)
    np.testing.assert_allclose(run.steps["eps_target"], expected, rtol=1e-9)
    assert np.any(2e-6 * mu ** 2 > (0.1 * 0.01) ** 2 * (mu / 0.1) ** 3), "the floor should bind"
    assert np.all(run.steps["eps"] <= run.steps["eps_target"] * (1 + 1e-12))


def test_an_adaptive_run_writes_frames_on_output_times(tmp_path):
    from conftest import ROOM

    short = tmp_path / "short.toml"
    short.write_text(ROOM.read_text().replace("horizon = 20.0", "horizon = 4.0"))
    out = tmp_path / "adaptive.h5"
    moreau("run", short, "-o", out, "--quiet", "--tol", "0.01")
    run = moreau_run.load(out)
    np.testing.assert_allclose(run.time, np.arange(41) * 0.1, atol=1e-12)
    mu = run.steps["mu"]
    assert mu.min() < mu.max(), "the steps should vary"
    assert mu.max() <= 0.1 + 1e-12
    assert mu.sum() == pytest.approx(4.0, abs=1e-9)
    # ε_k = max((θ tol)² (μ / μ_max)³, 2·10⁻⁷ μ²) with θ = 0.1, μ_max = 0.1 (velocity-change
    # estimate: the accepted step is one projection of size μ).
    expected = np.maximum((0.1 * 0.01) ** 2 * (mu / 0.1) ** 3, 2e-7 * mu ** 2)
    np.testing.assert_allclose(run.steps["eps_target"], expected, rtol=1e-9)
    assert np.all(run.steps["eps"] <= run.steps["eps_target"] * (1 + 1e-12))
    assert moreau_run.min_gaps(run).min() >= -run.steps["violation"].max() - 1e-12
    assert run.summary["tol"] == 0.01


def test_people_who_enter_during_the_run_are_in_the_file(tmp_path):
    """data/scenes/gate-inflow.toml: 20 people wait from the start, 60 enter through a gate
    (3 a second for 20 s). Every one of them is in every per-person dataset, appears in the
    frames from when they entered, and PedPy reads them all."""
    from conftest import ROOT

    out = tmp_path / "gate.h5"
    moreau("run", ROOT / "data" / "scenes" / "gate-inflow.toml", "-o", out, "--quiet")
    run = moreau_run.load(out)
    n, frames = 80, len(run.time)
    with h5py.File(out, "r") as f:
        assert f.attrs["format"] == "moreau-run/4"
        np.testing.assert_array_equal(f["people/id"][:], np.arange(n))
        exit_time = f["people/exit_time"][:]
    assert run.radius.shape == (n,) and exit_time.shape == (n,)
    assert run.positions.shape == (frames, n, 2)
    assert run.summary["people"] == n
    assert run.summary["passed_exit"] == len(run.exits) > 0
    np.testing.assert_array_equal(exit_time[run.exits["id"]], run.exits["t"])

    # The trajectory and the dense array agree; everyone is in some frame.
    traj = run.trajectory
    np.testing.assert_array_equal(np.bincount(traj["frame"], minlength=frames), run.count)
    dense = run.positions[traj["frame"], traj["id"]]
    np.testing.assert_array_equal(dense[:, 0], traj["x"])
    assert np.isnan(run.positions).any(axis=2).sum() == frames * n - len(traj)
    first = np.full(n, frames)
    np.minimum.at(first, traj["id"], traj["frame"])
    assert np.all(first < frames)
    # The 20 of the start are in frame 0; the newcomers come later, in order of id, the
    # k-th (from 1) due at k/3 s and in the first frame (every 0.1 s) after its step.
    assert np.all(first[:20] == 0)
    assert np.all(np.diff(first[20:]) >= 0)
    due = np.arange(1, 61) / 3.0
    entered = run.time[first[20:]]
    assert np.all(entered >= due - 1e-9) and np.all(entered <= due + 0.15), entered - due
    assert run.count[0] == 20 and run.count.max() > 20

    # Nobody overlaps beyond the certified violation in any frame.
    assert moreau_run.min_gaps(run).min() >= -run.steps["violation"].max() - 1e-12

    traj_pedpy = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=out)
    assert traj_pedpy.data["id"].nunique() == n
    assert traj_pedpy.data.groupby("id")["frame"].min().to_numpy().tolist() == first.tolist()

    # The player shows them all (each from the frame they entered).
    shown = moreau("view", out, "-o", tmp_path / "gate.html")
    assert f"{frames} frames, {n} of {n} people" in shown.stdout


def test_the_exits_table_says_which_exit_each_person_took(tmp_path):
    """`/exits` rows are `(id, exit, t)`, `exit` indexing the scene's `[[exits]]` and the
    dataset's `names` (format `moreau-run/4`): in the room with a door on each side, everyone
    recorded through `west` was last seen west of the middle and everyone through `east` east
    of it, and the in-process run records the same rows."""
    import moreau as api
    from conftest import ROOT

    scene = ROOT / "data" / "scenes" / "room-two-exits.toml"
    out = tmp_path / "two.h5"
    moreau("run", scene, "-o", out, "--quiet")
    with h5py.File(out, "r") as f:
        exits = f["exits"][:]
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in f["exits"].attrs["names"]]
        positions = f["frames/positions"][:]
    assert exits.dtype.names == ("id", "exit", "t")
    assert names == ["west", "east"]
    assert len(exits) == 60
    # Where each person was last seen (the frame before they are NaN for good).
    seen = ~np.isnan(positions[:, :, 0])
    last = seen.shape[0] - 1 - np.argmax(seen[::-1], axis=0)
    x_last = positions[last, np.arange(seen.shape[1]), 0]
    for row in exits:
        side = "west" if x_last[row["id"]] < 6.0 else "east"
        assert names[row["exit"]] == side, row
    assert {names[e] for e in exits["exit"]} == {"west", "east"}

    sim = api.Simulation(api.Scene.from_file(scene))
    sim.advance_to(sim.scene.horizon)
    assert sim.exit_records() == [(int(i), int(e), float(t)) for i, e, t in exits]


def test_the_plots_count_each_door_where_people_go_through_it(room_run, tmp_path):
    """Regression: the flow plot counted PedPy's crossings of the exit area's mid-line, which
    no trajectory crosses where the exit removes people (they vanish as their centre enters the
    area): 0 through each door of room-two-exits, against 30 exit records each. Such exits are
    now counted by their exit records, one curve per door; where people walk on (the room),
    PedPy's N–t stays, within a second of the records."""
    import plot_run
    from conftest import ROOT

    out = tmp_path / "two.h5"
    moreau("run", ROOT / "data" / "scenes" / "room-two-exits.toml", "-o", out, "--quiet")
    run = moreau_run.load(out)
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=out)
    counts = plot_run.door_counts(run, traj)
    assert [(name, source) for name, _, _, source in counts] == [
        ("west", plot_run.RECORDS), ("east", plot_run.RECORDS)]
    for k, (_, t, n, _) in enumerate(counts):
        mine = np.sort(run.exits["t"][run.exits["exit"] == k])
        assert n[-1] == len(mine) == 30
        # The count at each frame: those whose record is at or before it.
        np.testing.assert_array_equal(n, [np.sum(mine <= x) for x in t])
    assert plot_run.main([str(out), "-o", str(tmp_path / "plots")]) == 0

    room = moreau_run.load(room_run)
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=room_run)
    [(name, t, n, source)] = plot_run.door_counts(room, traj)
    assert (name, source) == ("door", plot_run.PEDPY)
    exits = np.sort(room.exits["t"])
    assert np.all(n <= np.searchsorted(exits, t, side="right"))
    assert np.all(n >= np.searchsorted(exits, t - 1.0, side="right"))


def test_a_horizon_off_the_output_times_lost_its_last_frame(tmp_path):
    """Regression: the frame at a horizon that no output time reaches (0.25 s with frames
    every 0.1 s), or reaches only by rounding (0.3 s: 3 × 0.1 = 0.30000000000000004), was
    never written: `moreau run` ended its file at the frame of 0.2 s with the steps after it,
    and the Python module's `run` failed on "a state saved between frames". Both now write
    the frame at the horizon, the same file."""
    import moreau as module

    from conftest import ROOT

    text = (ROOT / "data" / "scenes" / "room-60.toml").read_text()
    for horizon, times in (("0.25", [0.0, 0.1, 0.2, 0.25]), ("0.3", [0.0, 0.1, 0.2, 0.3])):
        scene = tmp_path / f"h{horizon}.toml"
        scene.write_text(re.sub(r"(?m)^horizon = .*$", f"horizon = {horizon}", text))
        cli, py = tmp_path / f"cli{horizon}.h5", tmp_path / f"py{horizon}.h5"
        moreau("run", scene, "-q", "-o", cli)
        summary = module.run(module.Scene.from_file(scene), py)
        assert summary["frames"] == len(times), summary
        with h5py.File(cli) as a, h5py.File(py) as b:
            assert np.allclose(a["frames/time"][:], times, rtol=0, atol=1e-12), a["frames/time"][:]
            assert a.attrs["status"] == b.attrs["status"] == "complete"
            for name in ("frames/time", "frames/positions"):
                assert np.array_equal(a[name][:], b[name][:], equal_nan=True), name
            # The last step ends at the horizon, where the last frame is.
            last = a["steps"][-1]
            assert last["t"] == pytest.approx(float(horizon), abs=1e-12), last


def test_a_last_frame_cut_short_read_in_pedpy_as_the_next_frame(tmp_path):
    """Regression: `/trajectory` numbered its rows by the frames written, and PedPy reads a
    row's time as `frame / fps`: the frame at a horizon of 0.25 s (every 0.1 s) was frame 3,
    read as 0.3 s, and with frames every 0.3 s to 1.0 s the last read as 1.2 s (speeds near
    the end came out too low). Rows now sit at `t × fps`, a frame off that grid in `/frames`
    only; `to_pedpy` of a recording Simulation the same."""
    import moreau as module

    from conftest import ROOT

    text = (ROOT / "data" / "scenes" / "room-60.toml").read_text()
    for horizon, interval, on_grid in (("0.25", "0.1", [0.0, 0.1, 0.2]),
                                       ("1.0", "0.3", [0.0, 0.3, 0.6, 0.9])):
        scene = tmp_path / f"h{horizon}.toml"
        scene.write_text(re.sub(r"(?m)^output_interval = .*$", f"output_interval = {interval}",
                                re.sub(r"(?m)^horizon = .*$", f"horizon = {horizon}", text)))
        out = tmp_path / f"h{horizon}.h5"
        moreau("run", scene, "-q", "-o", out)
        with h5py.File(out) as f:
            times = f["frames/time"][:]
            positions = f["frames/positions"][:]
        assert times[-1] == pytest.approx(float(horizon), abs=1e-12), times
        traj, _ = module.to_pedpy(out)
        sim = module.Simulation(module.Scene.from_file(scene), record=True)
        sim.run()
        mem, _ = module.to_pedpy(sim)
        for data in (traj, mem):
            frames = np.unique(data.data["frame"].to_numpy())
            assert np.allclose(frames / data.frame_rate, on_grid, rtol=0, atol=1e-9), frames
            # Each row is the dense frame at its time.
            for k in frames:
                rows = data.data[data.data["frame"] == k]
                dense = positions[int(np.argmin(np.abs(times - k / data.frame_rate)))]
                ids = rows["id"].to_numpy()
                assert np.array_equal(rows["x"].to_numpy(), dense[ids, 0]), k


def test_plot_run_counted_everyone_from_sources_at_the_start_and_failed_on_nobody(tmp_path):
    """Regression: the evacuation curve of a run with sources started at everyone who ever
    entered (420 on a scene with 60 at the start), and a run with nobody in it (a source that
    starts after the horizon) failed in PedPy's density profile."""
    import matplotlib

    matplotlib.use("Agg")
    import sys

    from conftest import ROOT

    sys.path.insert(0, str(ROOT / "python"))
    import plot_run

    text = (ROOT / "data" / "scenes" / "gate-inflow.toml").read_text()
    scene = tmp_path / "gate.toml"
    scene.write_text(re.sub(r"(?m)^horizon = .*$", "horizon = 8.0", text))
    out = tmp_path / "gate.h5"
    moreau("run", scene, "-q", "-o", out)
    run = moreau_run.load(out)

    ax = StepAxes()
    plot_run.evacuation(ax, run, [])
    ts, left = ax.curves[0]
    with h5py.File(out) as f:
        count, times = f["frames/count"][:], f["frames/time"][:]
    # With "remove" exits, the people not yet out are those present at each frame.
    for t, n in zip(times, count):
        assert left[np.searchsorted(ts, t, side="right") - 1] == n, (t, n)

    # Nobody: no group, and a source that starts after the horizon.
    nobody = re.sub(r"(?s)\[\[groups\]\].*?release = 5\.0\n", "", text)
    nobody = re.sub(r"(?m)^horizon = .*$", "horizon = 1.0", nobody)
    nobody = nobody.replace("rate = 3.0\nstop = 20.0", "rate = 3.0\nstart = 5.0\nstop = 20.0")
    assert "[[groups]]" not in nobody and "start = 5.0" in nobody
    (tmp_path / "nobody.toml").write_text(nobody)
    moreau("run", tmp_path / "nobody.toml", "-q", "-o", tmp_path / "nobody.h5")
    assert plot_run.main([str(tmp_path / "nobody.h5"), "-o", str(tmp_path / "plots")]) == 0
    assert (tmp_path / "plots" / "density.png").is_file()


def test_tol_on_the_command_line_replaced_the_scenes_error_estimate(tmp_path):
    from conftest import ROOM

    text = ROOM.read_text().replace("horizon = 20.0", "horizon = 1.0")
    text = text.replace("[time]\n", '[time]\ntol = 0.01\nestimate = "step-doubling"\n')
    scene = tmp_path / "doubling.toml"
    scene.write_text(text)
    # --tol alone keeps the scene's estimate; it was replaced by the flag's default.
    out = tmp_path / "kept.h5"
    moreau("run", scene, "-o", out, "--quiet", "--tol", "0.02")
    run = moreau_run.load(out)
    assert run.scene["time"]["estimate"] == "step-doubling"
    assert run.scene["time"]["tol"] == 0.02
    # --estimate names another.
    out = tmp_path / "named.h5"
    moreau("run", scene, "-o", out, "--quiet", "--tol", "0.02", "--estimate", "velocity")
    assert moreau_run.load(out).scene["time"]["estimate"] == "velocity-change"


def test_a_deep_doors_measurement_line_ran_along_its_passage():
    """The measurement line of an exit area was the mid-line along its longer side: for a door
    1 m deep and 0.9 m wide it ran along the passage and PedPy counted nobody through a
    `continue` exit. It is the line moreau closes the exit with: across, between the jambs."""
    outer = [[0.0, 0.0], [6.0, 0.0], [6.0, 2.55], [7.0, 2.55], [7.0, 0.0], [10.0, 0.0],
             [10.0, 6.0], [7.0, 6.0], [7.0, 3.45], [6.0, 3.45], [6.0, 6.0], [0.0, 6.0]]
    door = {"area": [[6.0, 2.55], [7.0, 2.55], [7.0, 3.45], [6.0, 3.45]]}
    scene = {"area": {"outer": outer}, "exits": [door]}
    assert moreau_run.exit_line(scene) == ((6.5, 2.55), (6.5, 3.45))
    # The walls as the run file's /walls give the same; with none, the longer side.
    walls = moreau_run.walls_of(scene)
    assert walls.shape == (12, 4)
    assert moreau_run.exit_line(scene, 0, walls) == ((6.5, 2.55), (6.5, 3.45))
    assert moreau_run.exit_line({"exits": [door]}) == ((6.0, 3.0), (7.0, 3.0))
    # A door as wide as deep in a wall, as the room's: across it.
    room = {"area": {"outer": [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]},
            "exits": [{"area": [[9.6, 4.4], [10.0, 4.4], [10.0, 5.6], [9.6, 5.6]]}]}
    assert moreau_run.exit_line(room) == ((9.8, 4.4), (9.8, 5.6))


FAST_THROUGH = """
name = "fast-through"
seed = 7
[area]
outer = [[0.0, 0.0], [6.0, 0.0], [6.0, 2.0], [0.0, 2.0]]
[[exits]]
name = "end"
area = [[5.5, 0.0], [6.0, 0.0], [6.0, 2.0], [5.5, 2.0]]
action = "remove"
[[sources]]
name = "near"
area = [[4.6, 0.0], [5.3, 0.0], [5.3, 2.0], [4.6, 2.0]]
rate = 4.0
stop = 4.0
radius = 0.2
speed = 1.5
destination = "end"
[time]
horizon = 5.0
step = 0.05
output_interval = 1.0
"""


def test_people_who_came_and_went_between_frames_made_n_of_t_negative(tmp_path):
    """A source beside the exit, frames every second: half the entrants enter and leave
    between two frames. The run file had no entry times, plot_run dated each entry by the
    first frame it appears in and left out those in none, while their exits counted: N(t)
    fell to −8. The file now stores `people/entry_time`, and N(t) is the people present at
    each frame, never below 0."""
    import matplotlib

    matplotlib.use("Agg")
    import sys

    from conftest import ROOT

    sys.path.insert(0, str(ROOT / "python"))
    import plot_run

    (tmp_path / "s.toml").write_text(FAST_THROUGH)
    out = tmp_path / "s.h5"
    moreau("run", tmp_path / "s.toml", "-q", "-o", out)
    run = moreau_run.load(out)
    # Every entry time is a step time within the source's interval, in id order.
    t_in = run.entry_time
    assert t_in is not None and len(t_in) == len(run.radius) == 16
    assert np.all(np.diff(t_in) >= 0) and 0.0 <= t_in[0] and t_in[-1] <= 4.0 + 1e-9
    # Someone came and went between two frames: in no frame at all.
    never = ~np.isfinite(run.positions[:, :, 0]).any(axis=0)
    assert never.any(), "the test needs people who are in no frame"

    ax = StepAxes()
    plot_run.evacuation(ax, run, [])
    ts, left = ax.curves[0]
    assert left.min() >= 0, left
    for t, n in zip(run.time, run.count):
        assert left[np.searchsorted(ts, t, side="right") - 1] == n, (t, n)


def test_min_gaps_was_inf_in_every_frame_where_nobody_touched():
    """Regression: the search reached 2 r_max only, so it found pairs in contact alone, and
    a frame where nobody touched had a smallest gap of +inf."""
    nan = np.nan
    positions = np.array([
        # Apart: 0–1 is 1 m between centres (gap 0.5), 2 is far away.
        [[0.0, 0.0], [1.0, 0.0], [5.0, 5.0], [nan, nan]],
        # The nearest centres (0–1, 1 m, gap 0.8) are not the smallest gap: 2–3, 2.5 m
        # between centres of radius 1, gap 0.5.
        [[0.0, 0.0], [1.0, 0.0], [10.0, 0.0], [12.5, 0.0]],
        # One person: no pair.
        [[0.0, 0.0], [nan, nan], [nan, nan], [nan, nan]],
    ])
    run = moreau_run.Run(path=None, attrs={}, scene={}, time=np.arange(3.0), count=None,
                         positions=positions, radius=np.array([0.2, 0.3, 1.0, 1.0]),
                         steps=None, exits=None, trajectory=None)
    gaps = moreau_run.min_gaps(run)
    assert gaps[0] == pytest.approx(1.0 - 0.2 - 0.3)
    assert gaps[1] == pytest.approx(2.5 - 1.0 - 1.0)
    assert gaps[2] == np.inf

    # Against every pair, on random crowds of mixed radii, some frames with nobody touching.
    rng = np.random.default_rng(7)
    positions = rng.uniform(0.0, 20.0, size=(30, 12, 2))
    positions[rng.random((30, 12)) < 0.2] = nan
    run.time, run.positions = np.arange(30.0), positions
    run.radius = rng.uniform(0.1, 0.6, size=12)
    expected = []
    for frame in positions:
        present = np.flatnonzero(~np.isnan(frame[:, 0]))
        expected.append(min((np.hypot(*(frame[i] - frame[j])) - run.radius[i] - run.radius[j]
                             for a, i in enumerate(present) for j in present[a + 1:]),
                            default=np.inf))
    assert (np.array(expected) > 0).sum() > 10
    np.testing.assert_allclose(moreau_run.min_gaps(run), expected, rtol=0, atol=1e-12)


def test_the_density_map_mean_over_the_run_averaged_only_the_frames_someone_was_in(tmp_path):
    """Regression: PedPy has a density profile for each frame someone is in only, and the
    map titled "mean over the run" averaged those: 5 people who all left within the first
    of 11 frames made a map of 5 people, not of 5/11 of a person."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import plot_run

    scene = tmp_path / "out.toml"
    scene.write_text("""
name = "all-out"
seed = 1
[area]
outer = [[0.0, 0.0], [6.0, 0.0], [6.0, 6.0], [0.0, 6.0]]
[[exits]]
name = "door"
area = [[5.0, 0.0], [6.0, 0.0], [6.0, 6.0], [5.0, 6.0]]
action = "remove"
[[groups]]
name = "g"
count = 5
spawn = [[4.5, 0.5], [4.7, 0.5], [4.7, 5.5], [4.5, 5.5]]
radius = 0.1
speed = 10.0
destination = "door"
[time]
horizon = 1.0
step = 0.05
output_interval = 0.1
""")
    out = tmp_path / "out.h5"
    moreau("run", scene, "-q", "-o", out)
    with h5py.File(out) as f:
        count = f["frames/count"][:]
    assert count.tolist() == [5] + [0] * 10
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=out)
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=out)
    fig, ax = plt.subplots()
    plot_run.density(ax, traj, walkable, len(count), cell=0.5)
    # Densities (1/m²) × cell areas: the people in the area, on average over the frames.
    people = float(ax.images[0].get_array().sum()) * 0.5 ** 2
    plt.close(fig)
    assert people == pytest.approx(5 / 11)
    # A last frame at a horizon off the frame grid (1.04 s) is not PedPy's: the mean counted
    # it and gave 5/12; the frames PedPy has are counted.
    assert plot_run.frames_on_grid(np.append(np.arange(11) * 0.1, 1.04), 10.0) == 11
    assert plot_run.frames_on_grid(np.arange(11) * 0.1, 10.0) == 11


def test_upstream_area_raised_key_error_groups_on_a_scene_of_sources_only():
    """Regression: the square in front of the exit took its side from the first group, and
    a scene whose people all come from sources had none: KeyError 'groups'."""
    def scene(source_x):
        return {"exits": [{"name": "door", "segment": [[5.0, 0.0], [5.0, 2.0]]}],
                "sources": [{"area": [[source_x, 0.0], [source_x + 1, 0.0],
                                      [source_x + 1, 2.0], [source_x, 2.0]]}]}

    def square(points):
        return sorted((round(x, 9), round(y, 9)) for x, y in points)

    # The 2 m square on the door's 2 m line, on the sources' side.
    assert square(moreau_run.upstream_area(scene(1.0))) == [(3, 0), (3, 2), (5, 0), (5, 2)]
    assert square(moreau_run.upstream_area(scene(8.0))) == [(5, 0), (5, 2), (7, 0), (7, 2)]
    with pytest.raises(ValueError, match="no group or source"):
        moreau_run.upstream_area({"exits": scene(1.0)["exits"]})


def test_the_run_file_said_nobody_s_group(tmp_path):
    """The file stored no group: people are numbered along a space-filling curve, not by
    `[[groups]]`, so a per-group analysis (the wave released at 12 s, a source's people)
    could not be made from it. `/people/group` holds each one's: checked against where each
    stood at the start (inside its group's spawn region) and against who entered later."""
    waves = tmp_path / "waves.toml"
    waves.write_text((ROOT / "data" / "scenes" / "room-waves.toml").read_text()
                     .replace("horizon = 40.0", "horizon = 1.0"))
    out = tmp_path / "waves.h5"
    moreau("run", waves, "-q", "-o", out)
    run = moreau_run.load(out)
    assert run.group is not None and len(run.group) == len(run.radius)
    start = run.positions[0]
    for g, spec in enumerate(run.scene["groups"]):
        mine = np.flatnonzero(run.group == g)
        assert len(mine) == spec["count"], (g, len(mine))
        region = shapely.Polygon(spec["spawn"])
        assert all(region.covers(shapely.Point(*start[i])) for i in mine), run.group_name(g)
        assert run.group_name(g) == spec["name"]
    # The people of a source: the group after the scene's groups, from their entry on.
    gate = tmp_path / "gate.toml"
    gate.write_text((ROOT / "data" / "scenes" / "gate-inflow.toml").read_text()
                    .replace("horizon = 30.0", "horizon = 3.0"))
    out = tmp_path / "gate.h5"
    moreau("run", gate, "-q", "-o", out)
    run = moreau_run.load(out)
    entered = run.entry_time > 0
    assert entered.sum() > 0 and (~entered).sum() == 20
    assert (run.group[~entered] == 0).all() and (run.group[entered] == 1).all()
    assert run.group_name(1) == "gate"
    # −1 (not stored) is no group: it named the last one (Python's negative index).
    with pytest.raises(ValueError, match="not stored"):
        run.group_name(-1)
