"""The driver binary from a script's point of view: exit codes, refusals that keep files
intact, a run killed mid-way, `inspect` and `--help`."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pedpy

import moreau_run
from conftest import DENSE, MOREAU, ROOM, ROOT, moreau


def test_an_existing_output_is_not_overwritten_without_force(tmp_path):
    out = tmp_path / "taken.h5"
    out.write_bytes(b"precious results")
    proc = moreau("run", ROOM, "-o", out, "--quiet", check=False)
    assert proc.returncode == 2
    assert "already exists" in proc.stderr and "--force" in proc.stderr
    assert out.read_bytes() == b"precious results"


def test_force_replaces_an_existing_output(tmp_path):
    out = tmp_path / "taken.h5"
    out.write_bytes(b"old")
    short = tmp_path / "short.toml"
    short.write_text(ROOM.read_text().replace("horizon = 20.0", "horizon = 0.5"))
    moreau("run", short, "-o", out, "--quiet", "--force")
    assert moreau_run.load(out).status == "complete"


def test_a_bad_output_path_is_a_clear_error_and_leaves_nothing(tmp_path):
    missing = tmp_path / "no" / "such" / "dir" / "out.h5"
    proc = moreau("run", ROOM, "-o", missing, "--quiet", check=False)
    assert proc.returncode == 2
    assert str(missing.parent) in proc.stderr and "does not exist" in proc.stderr
    assert not (tmp_path / "no").exists()
    proc = moreau("run", ROOM, "-o", tmp_path, "--quiet", check=False)
    assert proc.returncode == 2 and "is a directory" in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_bad_scene_is_refused_before_any_output(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(ROOM.read_text().replace("radius = 0.2", "radius = -0.2"))
    out = tmp_path / "out.h5"
    proc = moreau("run", bad, "-o", out, check=False)
    assert proc.returncode == 2
    assert "radius" in proc.stderr and "-0.2" in proc.stderr
    assert not out.exists()


def test_a_run_killed_mid_way_leaves_a_readable_file(tmp_path):
    """SIGKILL: the run's frames are in its partial file (.NAME.partial, status running),
    which h5py (with HDF5's default file locking), PedPy and `inspect` open; NAME itself is
    never made, and a new run to NAME refuses to replace the partial file without --force."""
    out = tmp_path / "killed.h5"
    partial = tmp_path / ".killed.h5.partial"
    proc = subprocess.Popen([str(MOREAU), "run", str(DENSE), "-o", str(out), "--quiet"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    frames, deadline = 0, time.monotonic() + 300
    try:
        while frames < 5 and time.monotonic() < deadline:
            assert proc.poll() is None, "the run ended before it could be killed"
            time.sleep(0.2)
            try:
                with h5py.File(partial, "r") as f:
                    frames = f["frames/time"].shape[0]
            except (OSError, KeyError):
                pass  # not created yet, or caught between two writes
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert frames >= 5, "no frames written in time"
    assert not out.exists()

    run = moreau_run.load(partial)
    assert run.status == "running"
    assert len(run.time) >= 5
    per_frame = np.bincount(run.trajectory["frame"], minlength=len(run.time))
    np.testing.assert_array_equal(per_frame, run.count)
    assert len(run.steps) >= 2 * (len(run.time) - 1)  # 2 steps per frame (0.05 s, 10 fps)
    assert not np.isnan(run.positions[-1][: run.count[-1]]).all()
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=partial)
    assert traj.data["frame"].max() == len(run.time) - 1
    pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=partial)
    # inspect reads it too, and says the run did not finish; on NAME it points to it.
    assert "status: running" in moreau("inspect", partial).stdout
    proc = moreau("inspect", out, check=False)
    assert proc.returncode == 2 and ".killed.h5.partial" in proc.stderr
    # A new run to NAME keeps the killed run's frames unless told (--force) to replace them.
    proc = moreau("run", DENSE, "-o", out, "--quiet", check=False)
    assert proc.returncode == 2 and "killed" in proc.stderr and "--force" in proc.stderr
    assert moreau_run.load(partial).status == "running"


def test_inspect_describes_a_file(room_run):
    text = moreau("inspect", room_run).stdout
    for needle in ("room-150", "status: complete", "150 people", "201 frames", "/trajectory",
                   "/frames/positions", "@wkt_geometry", "400 steps"):
        assert needle in text, needle


def test_inspect_refuses_a_file_that_is_not_a_run(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = [1, 2, 3]
    proc = moreau("inspect", other, check=False)
    assert proc.returncode == 2 and "format" in proc.stderr


def test_help_is_complete():
    top = moreau("--help").stdout
    for needle in ("run", "inspect", "example81", "Exit codes"):
        assert needle in top, needle
    run_help = moreau("run", "--help").stdout
    for flag in ("--output", "--force", "--from", "--quiet", "--summary-json", "Exit codes"):
        assert flag in run_help, flag
    assert moreau("--version").stdout.startswith("moreau ")
    # Regression: clap turns `{n}` in a help text into a line break, and `bench --help`
    # read "(`" then "` in the path: the crowd size)" for its saved states' placeholder.
    bench_help = moreau("bench", "--help").stdout
    assert "(`{size}` in the path: the crowd size)" in bench_help
    for command in ("run", "inspect", "view", "converge", "tradeoff", "bench", "example81",
                    "example82"):
        shown = moreau(command, "--help").stdout
        assert "(`\n" not in shown and "`{n}`" not in shown, command


def test_every_scripts_help_says_its_first_paragraph_whole():
    """Regression: the Python scripts' `--help` showed the first line of their docstring, so
    plot_run's description ended "density map (PedPy)," and the ensemble's "…: runs a"."""
    import re
    scripts = [("python/plot_run.py", "the per-step solver statistics."),
               ("python/player_data.py", "made in Python from a run file."),
               ("benches/output_overhead.py", "with their ratios (one machine, one run)."),
               ("fmu/cross_check.py", "`assemble` copies it in)."),
               ("fmu/package.py", "its FMI 2 and FMI 3 FMUs into target/fmu/:"),
               ("-m moreau_ensemble", "and writes DIR/results.csv.")]
    for script, ending in scripts:
        what = script.split() if script.startswith("-m") else [str(ROOT / script)]
        proc = subprocess.run([sys.executable, *what, "--help"], capture_output=True,
                              text=True, timeout=120,
                              env={**os.environ, "PYTHONPATH": str(ROOT / "python")})
        assert proc.returncode == 0, (script, proc.stderr)
        said = " ".join(proc.stdout.split())
        assert ending in re.sub(r"- ", "-", said), (script, said[:400])


def test_usage_errors_exit_2():
    assert moreau("run", check=False).returncode == 2
    assert moreau("frobnicate", check=False).returncode == 2


def test_bench_refuses_an_empty_crowd_or_no_steps_by_the_flags_name():
    """Regression: `bench --sizes 0` failed in its measurement with a scene error about a
    self-crossing polygon (the hall of no one), and `--steps 0` with "invalid type: null,
    expected f64" (the mean of no steps); both are refused now, naming the flag and value."""
    for args, flag in ((("--sizes", "1000,0"), "'0' for '--sizes"),
                       (("--steps", "0"), "'0' for '--steps")):
        proc = moreau("bench", *args, "--compare-at", "0", check=False)
        assert proc.returncode == 2 and flag in proc.stderr, proc.stderr
        assert "must be at least 1" in proc.stderr and proc.stdout == "", proc.stdout


def test_kills_at_random_moments_always_leave_a_readable_file(tmp_path):
    """SIGKILL at random moments (some during a frame's write): the file always opens and is
    a whole number of frames."""
    rng = np.random.default_rng(7)
    # The dense hall for 40 s instead of 10: the whole run took 1.4 s once the solver got
    # faster, and the last kill (1.5 s in) found it finished. A kill must land mid-run.
    long = tmp_path / "dense-40s.toml"
    text = DENSE.read_text()
    assert "horizon = 10.0" in text
    long.write_text(text.replace("horizon = 10.0", "horizon = 40.0"))
    for k in range(6):
        out = tmp_path / f"kill-{k}.h5"
        partial = tmp_path / f".kill-{k}.h5.partial"
        proc = subprocess.Popen([str(MOREAU), "run", str(long), "-o", str(out), "--quiet"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 300
        try:
            while not partial.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
            time.sleep(0.05 + float(rng.uniform(0.0, 1.5)))  # past the layout
            alive = proc.poll() is None
        finally:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
        assert alive, "the run ended before the kill: the test's scene is too short"
        assert not out.exists()
        run = moreau_run.load(partial)
        assert run.status == "running"
        per_frame = np.bincount(run.trajectory["frame"], minlength=len(run.time))
        np.testing.assert_array_equal(per_frame, run.count)
        assert len(run.positions) == len(run.time)


def test_bench_compares_with_clarabel_at_the_same_gap_and_says_after_which_steps():
    """The cold comparison's line says which step it projects again (the warm ratio moved
    20–26× with the window on one thread: benches/README.md, session 31), and Clarabel's
    cold answer reaches the same target gap as the warm step's."""
    import re
    out = moreau("bench", "--sizes", "1000", "--warmup", "10", "--steps", "3", "--compare-at",
                 "1000", "--kind", "auto", timeout=300).stdout
    head = re.search(r"1000 people, one projection to gap ≤ (\S+), the step after the 3 "
                     r"measured .*\(warm\) \S+ ms .* gap (\S+)\)", out)
    assert head, out
    target, warm_gap = float(head[1].rstrip(",")), float(head[2])
    cold = re.search(r"cold clarabel +\S+ ms +\d+ it +gap (\S+) +converged .*× the warm step",
                     out)
    assert cold, out
    assert warm_gap <= target and float(cold[1]) <= target, (warm_gap, cold[1], target)


def test_bench_measures_the_same_steps_from_a_saved_state(tmp_path):
    """`moreau bench --save-state` after the warm-up, then `--from-state` instead of it: the
    same steps are measured (rows, iterations, factorizations and certified ε identical), so
    that before/after comparisons need not depend on where a warm-up ends; a state saved
    from another scene (another solver) is refused by name, and nothing is written then."""
    import json
    state = tmp_path / "jam-{size}.state"
    # `{n}`, the placeholder's first name, still works (clap's help cannot show it).
    state_n = tmp_path / "jam-{n}.state"

    def row(*args, check=True):
        proc = moreau("bench", "--one", "1000", "--steps", "6", "--compare-at", "0", *args,
                      timeout=300, check=check)
        return proc if not check else json.loads(proc.stdout.strip().splitlines()[-1])

    saved = row("--warmup", "40", "--kind", "auto", "--save-state", state)
    assert (tmp_path / "jam-1000.state").is_file()
    again = row("--kind", "auto", "--from-state", state_n)
    keys = ("rows_per_step", "active_per_step", "iterations", "factorizations", "max_eps",
            "max_violation")
    assert {k: saved[k] for k in keys} == {k: again[k] for k in keys}
    assert saved["rows_per_step"] > 1000 and saved["factorizations"] > 0, saved
    other = row("--kind", "interior", "--from-state", state, check=False)
    assert other.returncode != 0 and "scene_hash" in other.stderr, other.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["jam-1000.state"]


def test_bench_measures_a_solver_setting_against_its_default(tmp_path):
    """`moreau bench --solver-tables FILE` gives the measured solver a scene's `[solver.*]`
    tables: on the crush of 10,000's first step `auto` sets rows aside by their own reach
    (its pressure is local), and with `own_reach_ratio = inf` it keeps every row, so the
    same step takes other factorizations, both certified; a bad value or an unknown table is
    refused by name before anything is measured."""
    import json

    def row(tables=None, check=True):
        args = ["--solver-tables", tables] if tables else []
        proc = moreau("bench", "--one", "10000", "--scene", "crush", "--warmup", "0",
                      "--steps", "1", "--compare-at", "0", "--kind", "auto", *args,
                      timeout=300, check=check)
        return proc if not check else json.loads(proc.stdout.strip().splitlines()[-1])

    own = row()
    every_row = tmp_path / "every-row.toml"
    every_row.write_text("[auto]\nown_reach_ratio = inf\n")
    shared = row(every_row)
    assert own["rows_per_step"] == shared["rows_per_step"] == 29593, (own, shared)
    assert own["factorizations"] != shared["factorizations"], (own, shared)
    bad = tmp_path / "bad.toml"
    for text, needles in [("[auto]\nown_reach_ratio = 0.5\n", ["own_reach_ratio", "0.5"]),
                          ("[autoo]\n", ["autoo"])]:
        bad.write_text(text)
        proc = moreau("bench", "--sizes", "1000", "--solver-tables", bad, check=False,
                      timeout=120)
        assert proc.returncode != 0, proc.stdout
        assert all(n in proc.stderr for n in needles), proc.stderr
        assert "people" not in proc.stdout, proc.stdout


def test_bench_keeps_every_measured_step_in_a_csv(tmp_path):
    """`moreau bench --steps-csv FILE`: one row per measured step of each size, in order, the
    same steps the table sums up (its mean time and factorizations), each certified (ε within
    its target); a file whose directory does not exist is refused by name before anything is
    measured."""
    import csv
    out = tmp_path / "steps.csv"
    proc = moreau("bench", "--sizes", "1000,2000", "--warmup", "20", "--steps", "6",
                  "--compare-at", "0", "--kind", "auto", "--steps-csv", out, timeout=300)
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["people", "step", "t", "ms", "ms_assemble", "ms_solve",
                             "ms_analyse", "ms_factorize", "solver", "status", "iterations",
                             "factorizations", "rows", "active", "eps", "eps_target",
                             "violation"], rows[0]
    # The table's rows: the size, then numbers (not the lines that name the size in words).
    table = {int(w[0]): w for w in map(str.split, proc.stdout.splitlines())
             if len(w) > 12 and w[0] in ("1000", "2000") and w[1] != "people:"}
    for n in (1000, 2000):
        mine = [r for r in rows if r["people"] == str(n)]
        assert [int(r["step"]) for r in mine] == list(range(20, 26)), mine
        t = [float(r["t"]) for r in mine]
        assert all(abs(b - a - 0.05) < 1e-9 for a, b in zip(t, t[1:])), t
        assert all(r["status"] == "converged" and r["solver"] for r in mine), mine
        assert all(float(r["eps"]) <= float(r["eps_target"]) for r in mine), mine
        assert all(int(r["active"]) <= int(r["rows"]) for r in mine), mine
        # The table's mean ms a step (column 6) and factorizations a step (column 13).
        mean_ms = sum(float(r["ms"]) for r in mine) / 6
        fact = sum(int(r["factorizations"]) for r in mine) / 6
        assert abs(mean_ms - float(table[n][5])) <= 0.006, (mean_ms, table[n])
        assert abs(fact - float(table[n][12])) <= 0.051, (fact, table[n])
    missing = tmp_path / "no-such-dir" / "steps.csv"
    proc = moreau("bench", "--sizes", "1000", "--steps-csv", missing, check=False,
                  timeout=120)
    assert proc.returncode == 2, proc
    assert "--steps-csv" in proc.stderr and "no-such-dir" in proc.stderr, proc.stderr
    assert "people" not in proc.stdout, proc.stdout


def test_bench_names_its_slowest_steps():
    """`moreau bench` says which steps make a mean above the median: three distinct steps,
    slowest first, none faster than the median, the first not faster than the mean."""
    import json
    proc = moreau("bench", "--one", "1000", "--warmup", "0", "--steps", "12",
                  "--compare-at", "0", "--kind", "auto", timeout=300)
    row = json.loads(proc.stdout.strip().splitlines()[-1])
    slow = row["slowest"]
    assert len(slow) == 3
    ms = [s["ms"] for s in slow]
    assert ms == sorted(ms, reverse=True) and min(ms) >= row["ms_median"], row
    assert ms[0] >= row["ms_mean"] and len({s["step"] for s in slow}) == 3, row
    assert all(s["solver"] and s["ms"] > 0 for s in slow), row
