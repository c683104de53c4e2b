"""Issue 20 from a user's side: nothing typed loses a file (a typo with --force, a summary
path, a second run, a killed rerun), signals finish the file as `interrupted`, a live run can
be read, broken pipes end quietly, sweeps are checked before the cluster starts, and
plot_run.py explains a file it cannot plot. Each test is named after what broke."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

import moreau_run
from conftest import DENSE, MOREAU, ROOM, ROOT, moreau


def short_room(tmp_path, horizon=0.5):
    scene = tmp_path / "short.toml"
    scene.write_text(ROOM.read_text().replace("horizon = 20.0", f"horizon = {horizon}"))
    return scene


def start(*args):
    return subprocess.Popen([str(MOREAU), *map(str, args)], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_frames(path, frames, proc, timeout=300):
    """Waits until the file at `path` (a run's partial file) holds `frames` frames; h5py opens
    it with HDF5's default file locking while the run writes it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the run ended first: {proc.stderr.read()}"
        try:
            with h5py.File(path, "r") as f:
                if f["frames/time"].shape[0] >= frames:
                    return
        except (OSError, KeyError):
            pass
        time.sleep(0.1)
    pytest.fail(f"{path}: fewer than {frames} frames in {timeout} s")


def test_force_with_a_typo_left_an_empty_running_file(tmp_path):
    out = tmp_path / "run.h5"
    moreau("run", short_room(tmp_path), "-o", out, "--quiet")
    before = out.read_bytes()
    proc = moreau("run", short_room(tmp_path), "-o", out, "--quiet", "--force", "--tol=-1",
                  check=False)
    assert proc.returncode == 2 and "time.tol = -1" in proc.stderr
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.h5", "short.toml"]


def test_killing_a_force_rerun_lost_the_earlier_complete_file(tmp_path):
    out = tmp_path / "run.h5"
    moreau("run", short_room(tmp_path), "-o", out, "--quiet")
    proc = start("run", DENSE, "-o", out, "--quiet", "--force")
    try:
        wait_for_frames(tmp_path / ".run.h5.partial", 2, proc)
        assert moreau_run.load(out).status == "complete"
    finally:
        proc.kill()
        proc.wait()
    assert moreau_run.load(out).status == "complete"
    assert moreau_run.load(out).scene["name"] == "room-150"


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_and_sigterm_left_status_running(tmp_path, sig, code):
    out = tmp_path / "stopped.h5"
    proc = start("run", DENSE, "-o", out, "--quiet", "--summary-json", tmp_path / "s.json")
    try:
        wait_for_frames(tmp_path / ".stopped.h5.partial", 2, proc)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "interrupted" in err and "panicked" not in err
    run = moreau_run.load(out)
    assert run.status == "interrupted"
    assert len(run.time) >= 2
    assert not (tmp_path / ".stopped.h5.partial").exists()
    assert not (tmp_path / ".stopped.h5.lock").exists()
    assert '"status": "interrupted"' in (tmp_path / "s.json").read_text()
    assert "status: interrupted" in moreau("inspect", out).stdout


def test_two_concurrent_force_runs_both_exited_0_and_one_file_was_lost(tmp_path):
    out = tmp_path / "shared.h5"
    first = start("run", DENSE, "-o", out, "--quiet", "--force")
    try:
        wait_for_frames(tmp_path / ".shared.h5.partial", 1, first)
        second = moreau("run", short_room(tmp_path), "-o", out, "--quiet", "--force",
                        check=False)
        assert second.returncode == 2
        assert "another run is writing" in second.stderr
    finally:
        first.kill()
        first.wait()


def test_a_run_in_progress_could_not_be_opened_by_inspect_or_h5py(tmp_path):
    out = tmp_path / "live.h5"
    partial = tmp_path / ".live.h5.partial"
    proc = start("run", DENSE, "-o", out, "--quiet")
    try:
        wait_for_frames(partial, 2, proc)  # h5py, default locking
        text = moreau("inspect", partial).stdout
        assert "status: running" in text and "still going" in text
        hint = moreau("inspect", out, check=False)
        assert hint.returncode == 2 and ".live.h5.partial" in hint.stderr
    finally:
        proc.kill()
        proc.wait()


def test_summary_json_overwrote_the_scene_and_the_run_file(tmp_path):
    scene = short_room(tmp_path)
    text = scene.read_text()
    out = tmp_path / "run.h5"
    moreau("run", scene, "-o", out, "--quiet")
    run = out.read_bytes()
    for target, flags, needle in [
        (scene, [], "scene file"),
        (scene, ["-o", out, "--force"], "scene file"),
        (out, ["-o", out, "--force"], "--output file"),
    ]:
        proc = moreau("run", scene, "--quiet", "--summary-json", target, *flags, check=False)
        assert proc.returncode == 2 and needle in proc.stderr, proc.stderr
    keep = tmp_path / "keep.toml"
    keep.write_text("precious")
    proc = moreau("run", scene, "--quiet", "--summary-json", keep, check=False)
    assert proc.returncode == 2 and "already exists" in proc.stderr and "--force" in proc.stderr
    assert keep.read_text() == "precious"
    assert scene.read_text() == text and out.read_bytes() == run
    # With --force a summary file is replaced (whole).
    moreau("run", scene, "--quiet", "--summary-json", keep, "--force")
    assert '"status": "complete"' in keep.read_text()
    # An output may not name an input either.
    proc = moreau("run", scene, "-o", scene, "--force", "--quiet", check=False)
    assert proc.returncode == 2 and scene.read_text() == text


def test_a_summary_in_a_missing_directory_was_found_only_after_the_run(tmp_path):
    out = tmp_path / "run.h5"
    started = time.monotonic()
    proc = moreau("run", DENSE, "-o", out, "--quiet", "--summary-json",
                  tmp_path / "no" / "s.json", check=False)
    assert proc.returncode == 2 and "does not exist" in proc.stderr
    assert not out.exists() and not list(tmp_path.glob(".*"))
    assert time.monotonic() - started < 60  # refused, not run: the run takes minutes


def closed_stdout(*args):
    """Runs moreau with its standard output a pipe closed before it writes (as `| head` does
    once it has its line)."""
    proc = subprocess.Popen([str(MOREAU), *map(str, args)], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.wait(timeout=120)
    return proc.returncode, err


def test_inspect_and_example81_panicked_on_a_broken_pipe(room_run):
    for args in [("inspect", room_run), ("example81",)]:
        code, err = closed_stdout(*args)
        assert code == 0, (args, err)
        assert "panicked" not in err and "Broken pipe" not in err, (args, err)


def test_example81_with_t_end_1e9_ran_for_hours():
    proc = moreau("example81", "--t-end", "1e9", check=False, timeout=60)
    assert proc.returncode == 2
    assert "--t-end" in proc.stderr and "limit" in proc.stderr


def test_the_examples_refuse_bad_numbers_by_flag_not_in_a_step_or_as_an_unknown_argument():
    """Regression: `example81 --b nan` failed in its first step ("non-finite field"),
    `--a inf` as an uncertified projection, `--x0 -1` as "unexpected argument '-1'", and
    `--h 1e-300` printed h with three hundred digits."""
    for args, said in [
        (("example81", "--b", "nan"), "--b must be finite, got NaN"),
        (("example81", "--a", "inf"), "--a must be finite and > 0, got inf"),
        (("example81", "--x0", "-1"), "--x0 must be finite and in C = [0, ∞), got -1.0"),
        (("example81", "--h", "1e-300"), "with --h 1e-300: the finest run"),
        (("example82", "--t-end", "-1"), "--t-end must be finite and > 0, got -1.0"),
        (("example82", "--h", "1e-300"), "with --h 1e-300: the reference run (h / 512)"),
    ]:
        proc = moreau(*args, check=False, timeout=60)
        assert proc.returncode == 2 and said in proc.stderr, (args, proc.stderr)
        assert proc.stdout == "", (args, proc.stdout)


def test_the_examples_printed_a_step_of_1e300_with_three_hundred_digits(tmp_path):
    """Regression: `example81 --h 1e300` and `example82 --h 1e300` ran (one step of t_end
    each) and printed the step in their tables, and example82.md, as a 1 with three hundred
    zeros and six decimals."""
    proc = moreau("example81", "--h", "1e300", timeout=120)
    assert "1e300" in proc.stdout and not re.search(r"\d{25}", proc.stdout), proc.stdout
    proc = moreau("example82", "--h", "0.00001", "--t-end", "0.0001", "--out", tmp_path,
                  timeout=120)
    table = (tmp_path / "example82.md").read_text()
    for text in (proc.stdout, table):
        assert "1e-5" in text and not re.search(r"\d{25}", text), text
    # A step longer than the horizon is refused (the reference, h / 512, would be one step
    # of t_end), the step printed in a few characters.
    proc = moreau("example82", "--h", "1e300", "--out", tmp_path, check=False, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "--h 1e300 is longer than --t-end 5" in proc.stderr, proc.stderr
    # Ordinary steps keep their six decimals.
    proc = moreau("example81", timeout=120)
    assert re.search(r"^\s+0\.\d{6}\s", proc.stdout, re.M), proc.stdout


def test_run_with_tol_1e300_never_ended():
    """Regression: `--tol 1e300` asks a projection gap of (0.1 tol)² (μ/μ_max)³ = ∞, and the
    semismooth Newton method that answers `auto`'s rounds updated its multipliers forever
    (no velocity moved, no budget counted). Now the run ends, feasible within the scene's
    `max_violation`."""
    proc = moreau("run", ROOM, "--tol", "1e300", "-q", "--summary-json", "-", timeout=300)
    summary = json.loads(proc.stdout)
    assert summary["status"] == "complete", summary
    assert summary["max_violation"] <= 1e-6, summary


def test_a_tol_no_step_meets_ran_for_hours_at_the_smallest_step_without_a_word(tmp_path):
    """`--tol 1e-12` keeps a run at the controller's smallest step (1e-6 s) from the first
    contact on: `room-60` for 15 s would take ~15 minutes, silently. The run now says so once,
    with the step, its error and the tolerance, and goes on; a tolerance that steps meet says
    nothing."""
    scene = tmp_path / "short.toml"
    text = (ROOT / "data" / "scenes" / "room-60.toml").read_text()
    scene.write_text(re.sub(r"(?m)^horizon = .*$", "horizon = 0.06", text))
    proc = moreau("run", scene, "--tol", "1e-12", "-q", timeout=120)
    warnings = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1, proc.stderr
    for needle in ("the smallest step, 1e-6 s", "time.tol = 1e-12 m"):
        assert needle in warnings[0], warnings[0]
    assert "warning" not in moreau("run", scene, "--tol", "1e-3", "-q").stderr


def test_tradeoff_at_a_tol_no_step_meets_ran_for_hours_without_a_word(tmp_path):
    """`moreau run` warned that `--tol 1e-12` keeps a run at the smallest step; `moreau
    tradeoff --tols 1e-12` runs three adaptive runs so, silently, and printed the tolerance as
    `0.000000000001` (1e-300 with three hundred digits). Now each adaptive run warns once and
    the tolerance prints as 1e-12, in the log and in tradeoff.md."""
    out = tmp_path / "tradeoff"
    proc = moreau("tradeoff", ROOT / "data" / "scenes" / "room-60.toml", "--horizon", "0.06",
                  "--samples", "1", "--steps", "0.06", "--clarabel-steps", "0.06",
                  "--tols", "1e-12", "-o", out, timeout=300)
    warnings = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 3, proc.stderr
    assert all("time.tol = 1e-12 m" in w for w in warnings), warnings
    assert "0.000000000001" not in proc.stderr + (out / "tradeoff.md").read_text()
    assert "| 1e-12 |" in (out / "tradeoff.md").read_text()


def test_bench_sizes_beyond_the_limit_were_refused_after_measuring_every_smaller_one(tmp_path):
    """`bench --sizes 18446744073709551615` first measured the default comparison's 40,000
    people (minutes for a crush), then refused the size when it built its scene; the studies'
    "does not divide the sampling interval" printed 1e-301 with three hundred digits. Now the
    size is refused before anything runs (exit 2, naming the limit), and the interval prints
    short."""
    for flag, value in (("--sizes", "18446744073709551615"), ("--sizes", "1000,10000001"),
                        ("--compare-at", "20000000")):
        start = time.monotonic()
        proc = moreau("bench", flag, value, check=False, timeout=60)
        assert proc.returncode == 2, (flag, value, proc.stderr)
        bad = value.split(",")[-1]
        assert f"'{bad}' for '{flag}" in proc.stderr and "limit of 1e7 people" in proc.stderr
        assert "people" not in proc.stdout and time.monotonic() - start < 30, proc.stdout
    proc = moreau("tradeoff", ROOT / "data" / "scenes" / "room-60.toml", "--horizon", "1e-300",
                  "-o", tmp_path / "t", check=False, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "the sampling interval 1e-301 (T / samples)" in proc.stderr, proc.stderr
    assert not re.search(r"\d{25}", proc.stderr), proc.stderr


def test_the_studies_refuse_bad_numbers_before_the_reference_run(tmp_path):
    """Regression: `converge --samples 0` and `--eps-kappa -1` ran the reference run (minutes
    on a large scene) before refusing, `--h-min 0` failed after it on "step 0 does not
    divide", `--steps nan` said "every step must be larger than --h-min", `--steps -0.1`
    was an "unexpected argument '-0'"; `tradeoff` took a tolerance of 0 and 0 samples."""
    scene = ROOT / "data" / "scenes" / "room-60.toml"
    for args, said in [
        (("converge", "--samples", "0"), "'0' for '--samples <SAMPLES>': must be at least 1"),
        (("converge", "--eps-kappa", "-1"), "'-1' for '--eps-kappa <EPS_KAPPA>'"),
        (("converge", "--h-min", "0"), "'0' for '--h-min <H_MIN>'"),
        (("converge", "--steps", "0.1,nan"), "'nan' for '--steps <STEPS>'"),
        (("converge", "--steps", "0.1,-0.1"), "'-0.1' for '--steps <STEPS>'"),
        (("tradeoff", "--tols", "0.1,0"), "'0' for '--tols <TOLS>'"),
        (("tradeoff", "--samples", "0"), "'0' for '--samples <SAMPLES>'"),
    ]:
        out = tmp_path / "out"
        proc = moreau(args[0], scene, *args[1:], "-o", out, check=False, timeout=60)
        assert proc.returncode == 2 and said in proc.stderr, (args, proc.stderr)
        assert "reference run" not in proc.stdout + proc.stderr and not out.exists(), args


def test_os_and_hdf5_error_text_was_printed_twice(tmp_path):
    proc = moreau("run", tmp_path / "missing.toml", check=False)
    assert proc.returncode == 2
    assert proc.stderr.count("No such file or directory") == 1, proc.stderr
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not hdf5 at all" * 100)
    proc = moreau("inspect", garbage, check=False)
    assert proc.returncode == 2
    assert proc.stderr.count("file signature not found") <= 1, proc.stderr


def test_inspect_on_a_directory_said_no_such_file(tmp_path):
    proc = moreau("inspect", tmp_path, check=False)
    assert proc.returncode == 2 and "is a directory" in proc.stderr


def test_converge_horizon_minus_one_and_bench_density_0_gave_unrelated_errors(tmp_path):
    proc = moreau("converge", ROOM, "--horizon=-1", "--out", tmp_path, check=False, timeout=120)
    assert proc.returncode == 2 and "--horizon" in proc.stderr and "-1" in proc.stderr, proc.stderr
    proc = moreau("bench", "--density", "0", check=False, timeout=120)
    assert proc.returncode == 2 and "--density" in proc.stderr and "0" in proc.stderr, proc.stderr


def test_bench_density_1e_minus_300_wrote_its_hall_as_toml_that_did_not_parse():
    """The generated hall wrote its side, 3.2e150 m, with all its digits: TOML read an integer
    that overflowed, and the error ("integer number overflowed", under a caret) named nothing
    the user typed. Now the scene's own bound says what is wrong, with the number in a few
    characters; the converge flags' numbers too."""
    proc = moreau("bench", "--density", "1e-300", "--sizes", "10", check=False, timeout=120)
    assert proc.returncode != 0
    assert "coordinates must be within" in proc.stderr and "3.1622776601683793e150" in \
        proc.stderr, proc.stderr
    assert "overflow" not in proc.stderr and not re.search(r"\d{25}", proc.stderr), proc.stderr
    proc = moreau("converge", ROOM, "--h-min", "1e300", check=False, timeout=120)
    assert proc.returncode != 0 and "--h-min 1e300" in proc.stderr, proc.stderr


# Python: sweeps and plot_run.py.

def sweep(tmp_path, body, base=ROOM):
    spec = tmp_path / "sweep.toml"
    spec.write_text(f'base = "{base}"\nseeds = 1\n{body}')
    return spec


def ensemble(*args):
    return subprocess.run([sys.executable, "-m", "moreau_ensemble", *map(str, args)],
                          capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
                          cwd=ROOT / "python")


@pytest.mark.parametrize("body,needles", [
    ('[vary]\n"groups.5.count" = [10, 20]\n', ["vary.groups.5.count = 10", "IndexError"]),
    ("[vary]\ndoor_width = [0]\n", ["vary.door_width = 0", "must be finite and > 0"]),
    ('[set]\n"time.horizon.x" = 1\n', ["set.time.horizon.x = 1", "has no parts"]),
    # Regression: a misspelt key was written into every variant, and every run failed.
    ('[vary]\n"groups.0.cont" = [10, 20]\n', ["{'groups.0.cont': 10}", "unknown field `cont`"]),
    ('[set]\n"solver.kind" = "autoo"\n', ["{'solver.kind': 'autoo'}", "unknown variant"]),
])
def test_a_bad_sweep_variant_gave_a_traceback_after_the_cluster_started(tmp_path, body,
                                                                          needles):
    proc = ensemble(sweep(tmp_path, body), "--out", tmp_path / "out")
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    for n in needles:
        assert n in proc.stderr, (n, proc.stderr)
    assert not (tmp_path / "out").exists(), "nothing made before the sweep was checked"


@pytest.mark.parametrize("args,said", [
    (["--engine", "fmu"], "--engine fmu needs --fmu FILE"),
    (["--engine", "fmu", "--fmu", "missing.fmu"], "--fmu missing.fmu: no such file"),
    (["--moreau", "/nowhere/moreau"], "--moreau /nowhere/moreau: no such program"),
])
def test_engine_fmu_without_an_fmu_recorded_every_run_as_failed(tmp_path, args, said):
    """Regression: `--engine fmu` without `--fmu` (or with a driver that is not there) started
    the cluster and recorded every run as failed ("engine fmu needs --fmu")."""
    proc = ensemble(sweep(tmp_path, ""), "--out", tmp_path / "out", *args)
    assert proc.returncode == 2 and said in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists(), "no run recorded"


@pytest.mark.parametrize("workers", ["0", "-1"])
def test_workers_0_waited_forever(tmp_path, workers):
    """Regression: `--workers 0` started a cluster of no workers and waited for them."""
    proc = ensemble(sweep(tmp_path, ""), "--out", tmp_path / "out", "--workers", workers)
    assert proc.returncode == 2, proc.stderr
    assert f"--workers {workers}: must be at least 1" in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("body,said", [
    ('seeds = 2.5', "seeds = 2.5: must be a count (an integer ≥ 1) or a non-empty list"),
    ('seeds = "12"', "seeds = '12': must be a count"),  # was seeds 1 and 2
    ('seeds = [1.7, 2.2]', "seeds = [1.7, 2.2]: must be a count"),  # was seeds 1 and 2
    ('seeds = true', "seeds = True: must be a count"),
    ('vary = 3', "vary = 3: must be a table"),
    ('set = "x"', "set = 'x': must be a table"),
    ('seeds = [', "not TOML"),
])
def test_sweep_seeds_of_the_wrong_type_gave_a_traceback_or_other_seeds(tmp_path, body, said):
    """Regression: `seeds = 2.5`, `vary = 3` and `base = 3` gave tracebacks, `seeds = "12"`
    became the seeds 1 and 2 and `[1.7, 2.2]` the same, and a TOML syntax error did not name
    the sweep file."""
    from moreau_ensemble import load_sweep

    spec = tmp_path / "sweep.toml"
    spec.write_text(f'base = "{ROOM}"\n{body}\n')
    with pytest.raises(ValueError) as e:
        load_sweep(spec)
    assert str(e.value).startswith(f"{spec}: ") and said in str(e.value), str(e.value)
    spec.write_text("base = 3\n")
    with pytest.raises(ValueError, match="base = 3: must be the scene file's path"):
        load_sweep(spec)


def test_a_garbage_base_file_gave_a_traceback(tmp_path):
    base = tmp_path / "garbage.toml"
    base.write_bytes(b"\x00\xff not [toml")
    proc = ensemble(sweep(tmp_path, "", base=base), "--out", tmp_path / "out")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "base" in proc.stderr and "not a scene file" in proc.stderr


def test_a_sweep_key_with_dot_dot_slash_made_directories_outside_out(tmp_path):
    from moreau_ensemble import load_sweep

    spec = sweep(tmp_path, '[vary]\n"name" = ["../../escaped", "/abs", ".."]\n')
    variants = load_sweep(spec).variants()
    for v in variants:
        assert "/" not in v.name and v.name not in (".", ".."), v.name
        runs = tmp_path / "out" / "runs"
        assert (runs / v.name).resolve().parent == runs.resolve()
    spec = sweep(tmp_path, '[vary]\n"../x" = [1]\n')
    with pytest.raises(ValueError):
        load_sweep(spec)  # and were it accepted, its directory name has no '/'


def plot(*args):
    return subprocess.run([sys.executable, str(ROOT / "python" / "plot_run.py"), *map(str, args)],
                          capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)


def test_plot_run_gave_a_traceback_on_a_non_hdf5_or_truncated_file(tmp_path, room_run):
    garbage = tmp_path / "garbage.h5"
    garbage.write_text("this is not HDF5")
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(room_run.read_bytes()[:4096])
    for path in (garbage, truncated):
        proc = plot(path, "-o", tmp_path / "plots")
        assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr
        assert "cannot be read as HDF5" in proc.stderr, proc.stderr


def test_plot_run_refuses_bad_animation_and_snapshot_numbers_by_flag(tmp_path, room_run):
    """Regression: `--fps 0` wrote an animation, `--max-frames 0` wrote every frame,
    `--snapshots nan` drew t = 0 and `--snapshots 1000` the room's last frame (20 s) without
    a word. Each is refused now (exit 2), naming the flag, and nothing is written."""
    for args, said in [
        (("--animate", tmp_path / "a.gif", "--fps", "0"), "--fps 0: must be finite and > 0"),
        (("--animate", tmp_path / "a.gif", "--max-frames", "0"), "--max-frames 0: must be"),
        (("--snapshots", "nan", "-o", tmp_path / "s.png"), "times must be finite and ≥ 0"),
        (("--snapshots", "0,1000", "-o", tmp_path / "s.png"), "the run's frames end at 20 s"),
    ]:
        proc = plot(room_run, *args)
        assert proc.returncode == 2 and said in proc.stderr, (args, proc.stderr)
    assert list(tmp_path.iterdir()) == []


def test_plot_run_failed_on_a_run_with_no_steps(tmp_path):
    # A run killed after its first frame: one frame, no step (made from a short run's file).
    out = tmp_path / "nothing.h5"
    moreau("run", short_room(tmp_path), "-o", out, "--quiet")
    with h5py.File(out, "r+") as f:
        f["steps"].resize((0,))
        for name in ("frames/time", "frames/count"):
            f[name].resize((1,))
        f.attrs["status"] = "running"
    proc = plot(out, "-o", tmp_path / "plots")
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr
    assert "nothing to plot" in proc.stderr, proc.stderr


def test_a_killed_million_person_run_had_to_start_over(tmp_path):
    """SIGKILL a run at a random moment after it saved a state, `moreau run --resume` it: the
    file equals an uninterrupted run's, frame for frame and step for step (the dense 2,000
    scene; the state is saved with every frame)."""
    full = tmp_path / "full.h5"
    moreau("run", DENSE, "-o", full, "--quiet")
    out = tmp_path / "killed.h5"
    partial = tmp_path / ".killed.h5.partial"
    proc = subprocess.Popen([str(MOREAU), "run", str(DENSE), "-o", str(out), "--quiet"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    try:
        # Until a state was saved (and a frame or two more), then at a random moment.
        while time.monotonic() < deadline:
            try:
                with h5py.File(partial, "r", locking=False) as f:
                    if f["state"].attrs["slot"] > 0 and len(f["frames/time"]) >= 3:
                        break
            except (OSError, KeyError):
                pass
            time.sleep(0.05)
        time.sleep(float(np.random.default_rng(11).uniform(0.0, 0.8)))
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert partial.exists() and not out.exists()
    resumed = moreau("run", "--resume", out, "--quiet")
    assert resumed.returncode == 0
    assert out.exists() and not partial.exists()
    with h5py.File(full, "r") as a, h5py.File(out, "r") as b:
        assert b.attrs["status"] == "complete"
        for name in ("frames/positions", "frames/time", "frames/count", "people/exit_time"):
            assert np.array_equal(a[name][:], b[name][:], equal_nan=True), name
        for name in ("trajectory", "exits"):
            assert a[name][:].tobytes() == b[name][:].tobytes(), name
        sa, sb = a["steps"][:], b["steps"][:]
        assert len(sa) == len(sb)
        for field in ("step", "t", "mu", "eps", "violation", "iterations", "assembled"):
            assert np.array_equal(sa[field], sb[field]), field
    # Nothing left to resume now.
    again = moreau("run", "--resume", out, "--quiet", check=False)
    assert again.returncode == 2 and "nothing to resume" in again.stderr


def test_view_wrote_its_page_over_the_run_file_named_another_way(tmp_path, room_run):
    """Regression: `moreau view run.h5 -o ./run.h5 --force` compared the paths as text and
    replaced the run file by the HTML page."""
    import shutil

    run = tmp_path / "run.h5"
    shutil.copy(room_run, run)
    before = run.read_bytes()
    for output in ("./run.h5", str(run)):
        proc = moreau("view", "run.h5", "-o", output, "--force", check=False, cwd=tmp_path,
                      timeout=60)
        assert proc.returncode == 2 and "is the run file itself" in proc.stderr, proc.stderr
    assert run.read_bytes() == before


def test_run_said_0_people_for_a_scene_of_sources_only(tmp_path):
    """Regression: `moreau run`'s summary line counted the people at the start (0 on a scene
    whose people all come from sources) where `--summary-json` counted everyone."""
    import json

    scene = ROOT / "data" / "scenes" / "gate-inflow.toml"
    proc = moreau("run", scene, "--summary-json", tmp_path / "s.json", timeout=300)
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["people"] > 20
    assert f": {summary['people']} people," in proc.stdout, proc.stdout


def test_run_tol_minus_1_was_an_unexpected_argument():
    proc = moreau("run", ROOT / "data" / "scenes" / "room-60.toml", "--tol", "-1", "-q",
                  check=False, timeout=60)
    assert proc.returncode == 2 and "time.tol = -1: must be finite and > 0" in proc.stderr, \
        proc.stderr


def test_a_run_killed_in_a_flush_could_not_be_resumed(tmp_path):
    """A partial file left by a SIGKILL during HDF5's flush (kept from a helper's bug hunt:
    gate-inflow with `tol` and contacts, killed at frame 84; about one kill in a hundred): a
    chunk lies past the end of allocation the superblock records, so reading its last frame
    failed ("addr overflow"), and `--resume` failed on its first flush and moved the file to
    its name as failed, never to be resumed. The resume now moves the end of allocation to
    the end of the file and finishes the run as `--from` runs it from the start."""
    import gzip

    data = ROOT / "tests" / "damaged-runs" / "killed-in-a-flush.h5.partial.gz"
    (tmp_path / ".r.h5.partial").write_bytes(gzip.decompress(data.read_bytes()))
    moreau("run", "--resume", tmp_path / "r.h5", "-q")
    resumed = moreau_run.load(tmp_path / "r.h5")
    assert resumed.status == "complete"
    moreau("run", "--from", tmp_path / "r.h5", "-o", tmp_path / "fresh.h5", "-q")
    fresh = moreau_run.load(tmp_path / "fresh.h5")
    assert len(resumed.time) == len(fresh.time) == 301
    assert np.array_equal(resumed.positions, fresh.positions, equal_nan=True)
    assert np.array_equal(resumed.trajectory, fresh.trajectory)
    assert np.array_equal(resumed.exits, fresh.exits)
