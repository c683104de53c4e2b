"""The RiMEA verification tests that need no stairs or route choice (RiMEA 4.1.1, tests 1, 4,
6, 7 and 12), each a scene of `data/rimea/` run by the driver and judged from its run file
with PedPy (and h5py where PedPy has no measure). `docs/rimea.md` gives the table; every
test prints what it measured:

    .venv/bin/python -m pytest tests/python/test_rimea.py -rP

Every criterion is computed from the run; the thresholds are fixed below, with the reason
for each. Test 4 compared with Weidmann's diagram fails for this model and is marked
`xfail(strict=True)`: the day the model acquires a density–speed relation it will XPASS
and fail the suite, and the mark has to go.
"""

from __future__ import annotations

import math
import pathlib
import tomllib
import warnings

import h5py
import numpy as np
import pedpy
import pytest
import shapely
from scipy import stats

import moreau_run
from conftest import ROOT, moreau

SCENES = ROOT / "data" / "rimea"


def run_scene(name: str, tmp: pathlib.Path) -> pathlib.Path:
    out = tmp / f"{name}.h5"
    moreau("run", SCENES / f"{name}.toml", "-o", out, "--quiet")
    return out


def trajectory(path: pathlib.Path) -> pedpy.TrajectoryData:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=path)


def individual_speed(traj: pedpy.TrajectoryData, frame_step: int = 5):
    """PedPy's speed of each person at each frame, by a central difference over `frame_step`
    frames each side (single-sided at the ends of a trajectory)."""
    return pedpy.compute_individual_speed(
        traj_data=traj, frame_step=frame_step,
        speed_calculation=pedpy.SpeedCalculation.BORDER_SINGLE_SIDED)


def square(x0: float, y0: float, side: float = 2.0) -> pedpy.MeasurementArea:
    return pedpy.MeasurementArea([(x0, y0), (x0 + side, y0), (x0 + side, y0 + side),
                                  (x0, y0 + side)])


def area_series(traj, speed, area: pedpy.MeasurementArea):
    """Per frame: PedPy's classic density in `area` (P/m²), its mean speed (m/s, 0 when
    empty) and the number of people in it."""
    density = pedpy.compute_classic_density(traj_data=traj, measurement_area=area)["density"]
    mean = pedpy.compute_mean_speed_per_frame(traj_data=traj, individual_speed=speed,
                                              measurement_area=area).set_index("frame")["speed"]
    mean = mean.reindex(density.index, fill_value=0.0)
    return density.to_numpy(), mean.to_numpy(), density.to_numpy() * area.area


def weidmann(rho: float) -> float:
    """Weidmann's fundamental diagram (1993), the empirical diagram the guideline names:
    v = 1.34 (1 − exp(−1.913 (1/ρ − 1/5.4))) m/s, 0 at and above 5.4 P/m²."""
    if rho >= 5.4:
        return 0.0
    return 1.34 * (1.0 - math.exp(-1.913 * (1.0 / rho - 1.0 / 5.4)))


# --- Test 1: maintaining the walking speed in a corridor ------------------------------------

@pytest.fixture(scope="module")
def corridor(tmp_path_factory):
    return run_scene("test01-corridor", tmp_path_factory.mktemp("rimea01"))


def test_01_walking_speed_in_a_corridor(corridor):
    """The guideline: 40 m at 1.33 m/s in 26–34 s. We also require the speed PedPy measures
    along the way to stay within the guideline's 5 % of 1.33 m/s at every frame."""
    with h5py.File(corridor) as f:
        exit_time = f["people/exit_time"][:]
    assert exit_time.shape == (1,) and np.isfinite(exit_time[0]), "the walker never arrived"
    travel = float(exit_time[0])
    traj = trajectory(corridor)
    v = individual_speed(traj)["speed"].to_numpy()
    x = traj.data["x"].to_numpy()
    print(f"\nRiMEA 1: travel time over 40 m {travel:.2f} s (band 26–34 s; 40/1.33 = "
          f"{40 / 1.33:.2f} s); PedPy speed {v.min():.4f}–{v.max():.4f} m/s over "
          f"x = {x.min():.2f}–{x.max():.2f} m")
    assert 26.0 <= travel <= 34.0
    assert np.all(np.abs(v - 1.33) <= 0.05 * 1.33)


# --- Test 4: the fundamental diagram ---------------------------------------------------------

FD_WINDOW = (1.0, 8.0)  # s: the filled block covers every measuring area throughout
FD_AREAS_X = (11.0, 15.0, 19.0)  # left edges: the main area and two controls, 2 m × 2 m
FD_SPEED_TOLERANCE = 0.05  # m/s: "non-increasing" up to a quarter of the 0.2 m/s speed spread
FD_WEIDMANN_TOLERANCE = 0.26  # m/s: the spread (σ) of Weidmann's free walking speeds


@pytest.fixture(scope="module")
def fundamental_diagram(tmp_path_factory):
    """Per corridor: nominal density, measured density and mean speed, pooled over the three
    measuring areas and the window (the speed weighted by the people present)."""
    path = run_scene("test04-fundamental-diagram", tmp_path_factory.mktemp("rimea04"))
    with h5py.File(path) as f:
        text = f.attrs["scene"]
    scene = tomllib.loads(text.decode() if isinstance(text, bytes) else text)
    traj = trajectory(path)
    speed = individual_speed(traj)
    fps = traj.frame_rate
    # The corridors are the strips between the walls (the scene's holes), from y = 0 up.
    top = max(p[1] for p in scene["area"]["outer"])
    cuts = sorted([min(p[1] for p in h) for h in scene["area"]["holes"]]
                  + [max(p[1] for p in h) for h in scene["area"]["holes"]])
    strips = list(zip([0.0] + cuts[1::2], cuts[0::2] + [top]))
    rows = []
    for group, (y0, y1) in zip(scene["groups"], strips, strict=True):
        rho_nominal = float(group["name"].removeprefix("rho-"))
        dens, count, vsum = [], 0.0, 0.0
        for x0 in FD_AREAS_X:
            d, v, n = area_series(traj, speed, square(x0, 0.5 * (y0 + y1) - 1.0))
            t = np.arange(len(d)) / fps
            keep = (t >= FD_WINDOW[0]) & (t <= FD_WINDOW[1])
            dens.append(d[keep])
            count += n[keep].sum()
            vsum += (n[keep] * v[keep]).sum()
        rows.append((rho_nominal, float(np.concatenate(dens).mean()), vsum / count))
    return rows


def _fd_table(rows) -> str:
    lines = ["nominal ρ | measured ρ | speed | flow | Weidmann v(ρ)"]
    for nominal, rho, v in rows:
        lines.append(f"{nominal:9.1f} | {rho:10.2f} | {v:5.3f} | {rho * v:4.2f} | "
                     f"{weidmann(rho):.2f}")
    return "\n".join(lines)


def test_04_fundamental_diagram_qualitative(fundamental_diagram):
    """What we require of the diagram (the guideline only asks for the comparison): the
    measured densities rise with the nominal ones and span the guideline's range up to
    Weidmann's jam density (the lowest ≤ 0.6 P/m², the highest ≥ 5 P/m²), the lowest density
    walks at Weidmann's speed for it (within 0.1 m/s) and the speed does not increase with
    the density (by more than FD_SPEED_TOLERANCE)."""
    rows = fundamental_diagram
    print(f"\nRiMEA 4 (speed m/s, flow P/(m·s), pooled over {len(FD_AREAS_X)} areas, "
          f"t in {FD_WINDOW} s):\n" + _fd_table(rows))
    measured = [rho for _, rho, _ in rows]
    assert all(a < b for a, b in zip(measured, measured[1:])), measured
    assert measured[0] <= 0.6 and measured[-1] >= 5.0, measured
    _, rho0, v0 = rows[0]
    assert abs(v0 - weidmann(rho0)) <= 0.1, (rho0, v0, weidmann(rho0))
    speeds = [v for _, _, v in rows]
    for (a, b) in zip(speeds, speeds[1:]):
        assert b <= a + FD_SPEED_TOLERANCE, speeds


@pytest.mark.xfail(strict=True, reason=(
    "the model has no density–speed relation: a first-order contact model without "
    "anticipation keeps the mean desired speed (≈ 1.3 m/s) up to 6 P/m², where Weidmann "
    "falls to 0.6 m/s at 2 P/m² and to 0 at 5.4 P/m²"))
def test_04_fundamental_diagram_against_weidmann(fundamental_diagram):
    """The guideline's comparison: at every density the speed within the spread of free
    walking speeds (σ = 0.26 m/s) of Weidmann's diagram at the measured density."""
    bad = [(rho, v, weidmann(rho)) for _, rho, v in fundamental_diagram
           if abs(v - weidmann(rho)) > FD_WEIDMANN_TOLERANCE]
    assert not bad, "off Weidmann's diagram (ρ, v, v_W): " + ", ".join(
        f"({rho:.2f}, {v:.2f}, {w:.2f})" for rho, v, w in bad)


# --- Test 6: movement around a corner --------------------------------------------------------

def _segment_distance(p: np.ndarray, seg: np.ndarray) -> np.ndarray:
    a, b = seg[:2], seg[2:]
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def test_06_corner(tmp_path_factory):
    """All 20 pass the exit; no centre leaves PedPy's walkable area; no disk crosses a wall
    by more than the largest violation the run's steps certified."""
    path = run_scene("test06-corner", tmp_path_factory.mktemp("rimea06"))
    with h5py.File(path) as f:
        exit_time = f["people/exit_time"][:]
        pos = f["frames/positions"][:]
        radius = f["people/radius"][:]
        walls = f["walls"][:]
        certified = float(f["steps"]["violation"].max())
    walkable = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=path)
    traj = trajectory(path)
    inside = shapely.covers(walkable.polygon, shapely.points(traj.data[["x", "y"]].to_numpy()))
    gap = np.min([_segment_distance(pos, w) for w in walls], axis=0) - radius[None, :]
    wall_gap = float(np.nanmin(gap))
    people_gap = float(np.min(moreau_run.min_gaps(moreau_run.load(path))))
    corner = np.array([10.0, 2.0])  # the inner corner
    to_corner = float(np.nanmin(np.linalg.norm(pos - corner, axis=-1) - radius[None, :]))
    passed = int(np.isfinite(exit_time).sum())
    print(f"\nRiMEA 6: {passed}/{len(exit_time)} through the exit, the last at "
          f"{np.nanmax(exit_time):.2f} s; {int((~inside).sum())} of {len(inside)} trajectory "
          f"points outside the walkable area; smallest wall gap {wall_gap:.2e} m and person "
          f"gap {people_gap:.2e} m (certified violation {certified:.2e} m); closest approach "
          f"to the inner corner {to_corner * 1000:.1f} mm")
    assert passed == len(exit_time) == 20
    assert inside.all()
    assert wall_gap >= -certified - 1e-12
    assert people_gap >= -certified - 1e-12


# --- Test 7: demographic parameters ----------------------------------------------------------

BAND = (1.41, 1.54)  # m/s: the 30–50-year band, as we read the guideline's figure


def test_07_demographic_speeds(tmp_path_factory):
    """The free walking speeds measured by PedPy (per person, the mean over t in [1, 12] s,
    where nobody touches anybody) lie in the band (within 5 mm/s), cover it (the smallest and
    the largest within a tenth of its width of its ends) and pass a Kolmogorov–Smirnov test
    against the uniform distribution on it (p > 0.05)."""
    path = run_scene("test07-demographic", tmp_path_factory.mktemp("rimea07"))
    traj = trajectory(path)
    speed = individual_speed(traj)
    t = speed["frame"] / traj.frame_rate
    v = speed[(t >= 1.0) & (t <= 12.0)].groupby("id")["speed"].mean().to_numpy()
    lo, hi = BAND
    width = hi - lo
    ks = stats.kstest(v, stats.uniform(loc=lo, scale=width).cdf)
    print(f"\nRiMEA 7: {len(v)} people, measured speeds {v.min():.3f}–{v.max():.3f} m/s, "
          f"mean {v.mean():.3f} (band {lo}–{hi}, mean {0.5 * (lo + hi):.3f}); "
          f"KS against U({lo}, {hi}): D = {ks.statistic:.3f}, p = {ks.pvalue:.2f}")
    assert len(v) == 50
    assert v.min() >= lo - 0.005 and v.max() <= hi + 0.005
    assert v.min() <= lo + 0.1 * width and v.max() >= hi - 0.1 * width
    assert ks.pvalue > 0.05


# --- Test 12: effect of bottlenecks ----------------------------------------------------------

def test_12_bottleneck(tmp_path_factory):
    """While the corridor works (from the first person out of it to the last person into
    it), in front of its entrance the crowd is congested — density above 2 P/m², where
    Weidmann's speed is below half the free speed, and mean speed below half the slowest
    desired speed — and behind its exit it is not: the mean speed at least 90 % of the
    slowest desired speed and the density at most half the one in front.

    The corridor (1 m, 2.5 diameters) can clog for good: an arch of frictionless disks
    across its entrance is an equilibrium of the model (a clogged state stays clogged even
    with Clarabel at ε = 4e-14), and whether one forms is chance — with seeds 1–24, 5 or 6
    runs clog with each of `auto`, `interior` and `gauss-seidel` (benches/README.md, session
    10; 3 of 24 with `auto` in session 15, seeds 2, 15 and 19). One seed passed or failed by luck, so the scene runs with six seeds: every run in
    which everyone went through the corridor must meet the criteria, and at most four of the
    six may clog (with one run in four clogging, five or six clog once in 200 changes). A clog
    can also give way late (seed 15 with the code of 2026-11-26: stuck 13 s, then 21 people in
    the corridor at the horizon): in a run that clogged, whoever has been in the corridor for
    the whole last second must be walking through it. (Regression, 2026-11-27: the criterion
    counted someone who crossed the entrance line in the last second sliding along the wall,
    0.23 m along the corridor and as much across it, as stopped inside.)"""
    tmp = tmp_path_factory.mktemp("rimea12")
    base = (SCENES / "test12-bottleneck.toml").read_text()
    assert "\nseed = 12\n" in base
    slowest = 1.41
    clogged = []
    for seed in range(12, 18):
        scene = tmp / f"test12-bottleneck-{seed}.toml"
        scene.write_text(base.replace("\nseed = 12\n", f"\nseed = {seed}\n"))
        path = tmp / f"test12-bottleneck-{seed}.h5"
        moreau("run", scene, "-o", path, "--quiet")
        traj = trajectory(path)
        speed = individual_speed(traj)
        fps = traj.frame_rate
        data = traj.data
        into = data[data["x"] >= 10.0].groupby("id")["frame"].min()  # corridor entrance
        out = data[data["x"] >= 15.0].groupby("id")["frame"].min()  # corridor exit
        if len(into) < 150:
            # Clogged, for good or until late: whoever has been in the corridor for the whole
            # last second must be walking through it (at least 0.3 m along it), not stopped.
            last = data["frame"].max()
            now = data[(data["frame"] == last) & (data["x"] >= 10.0) & (data["x"] < 15.0)]
            before = data[data["frame"] == last - int(fps)].set_index("id")["x"]
            now = now[before.reindex(now["id"]).to_numpy() >= 10.0]
            walked = now.set_index("id")["x"] - before.reindex(now["id"]).to_numpy()
            assert (walked >= 0.3).all(), f"seed {seed}: stopped inside the corridor: {walked}"
            clogged.append((seed, len(into)))
            continue
        assert len(out) == len(into), f"seed {seed}: someone stopped inside the corridor"
        window = (int(out.min()), int(into.max()))
        assert window[1] - window[0] >= 10 * fps, (seed, window)
        measured = {}
        for name, x0 in (("before", 8.0), ("after", 15.0), ("final door", 23.0)):
            d, v, n = area_series(traj, speed, square(x0, 4.0))
            keep = slice(window[0], window[1] + 1)
            measured[name] = (float(d[keep].mean()),
                              float((n[keep] * v[keep]).sum() / n[keep].sum()))
        with h5py.File(path) as f:
            exit_time = f["people/exit_time"][:]
        flow = (len(into) - 1) / ((into.max() - into.min()) / fps)
        print(f"\nRiMEA 12, seed {seed}: corridor working t = {window[0] / fps:.1f}–"
              f"{window[1] / fps:.1f} s, flow into it {flow:.2f} P/s through 1 m; last out of "
              f"room 2 at {np.nanmax(exit_time):.2f} s\n" + "\n".join(
                  f"  {name:10s}: density {d:.2f} P/m², speed {v:.2f} m/s"
                  for name, (d, v) in measured.items()))
        d_before, v_before = measured["before"]
        d_after, v_after = measured["after"]
        assert d_before >= 2.0 and v_before <= 0.5 * slowest, (seed, measured)
        assert v_after >= 0.9 * slowest and d_after <= 0.5 * d_before, (seed, measured)
    print(f"\nRiMEA 12: clogged (seed, people through) {clogged} of 6 runs")
    assert len(clogged) <= 4, clogged
