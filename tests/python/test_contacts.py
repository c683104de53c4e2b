"""Contact forces in the run file ([output] contacts = true) and the animation writer."""

from __future__ import annotations

import pathlib
import shutil
import subprocess
import tomllib

import h5py
import numpy as np
import pytest

from conftest import ROOM, moreau

import plot_run


@pytest.fixture(scope="module")
def contacts_run(tmp_path_factory) -> pathlib.Path:
    """The paper's room for 8 s, recording contact forces."""
    d = tmp_path_factory.mktemp("contacts")
    text = ROOM.read_text().replace("horizon = 20.0", "horizon = 8.0")
    scene = d / "room-contacts.toml"
    scene.write_text(text + "\n[output]\ncontacts = true\n")
    out = d / "room-contacts.h5"
    moreau("run", scene, "-o", out, "--quiet")
    return out


def test_contacts_read_in_two_lines_and_add_up_to_the_pressure(contacts_run):
    with h5py.File(contacts_run, "r") as f:
        c = f["contacts"][:]
        pressure = f["frames/pressure"][:]
        positions = f["frames/positions"][:]
        walls = f["walls"][:]
        units = f["contacts"].attrs["units"]
        scene = tomllib.loads(f.attrs["scene"])
    assert "m/s" in (units.decode() if isinstance(units, bytes) else units)
    assert scene["output"]["contacts"] is True
    frames, people = pressure.shape
    assert positions.shape[:2] == (frames, people)
    assert len(c) > 1000 and (c["lambda"] > 0).all()
    assert set(np.unique(c["kind"])) == {0, 1}, "people against people and against walls"
    pairs, at_wall = c[c["kind"] == 0], c[c["kind"] == 1]
    assert (pairs["a"] < pairs["b"]).all() and (pairs["b"] < people).all()
    assert (at_wall["b"] >= 0).all() and (at_wall["b"] < len(walls)).all()
    assert c["frame"].min() >= 1, "the first frame comes before any step"
    # Σλ per person and frame from the rows, against /frames/pressure.
    total = np.zeros((frames, people))
    np.add.at(total, (c["frame"], c["a"]), c["lambda"])
    np.add.at(total, (pairs["frame"], pairs["b"]), pairs["lambda"])
    present = np.isfinite(positions[:, :, 0])
    assert np.array_equal(np.isfinite(pressure[1:]), present[1:])
    assert np.allclose(pressure[1:][present[1:]], total[1:][present[1:]], rtol=1e-12, atol=0)
    # A pushing contact is between people who touch (the linearized gap closes within the
    # certified violation): |q_a − q_b| − r_a − r_b ≤ a margin of one step's travel.
    with h5py.File(contacts_run, "r") as f:
        radius = f["people/radius"][:]
    k = pairs[pairs["frame"] == frames // 2]
    qa, qb = positions[k["frame"], k["a"]], positions[k["frame"], k["b"]]
    ok = np.isfinite(qa[:, 0]) & np.isfinite(qb[:, 0])
    gap = np.linalg.norm(qa - qb, axis=1)[ok] - radius[k["a"]][ok] - radius[k["b"]][ok]
    assert len(gap) > 10 and gap.max() < 0.01 and gap.min() > -1e-5


def test_a_run_without_contacts_has_no_contact_datasets(room_run):
    with h5py.File(room_run, "r") as f:
        assert "contacts" not in f and "frames/pressure" not in f
        assert f["walls"].shape[1] == 4
    out = moreau("inspect", room_run).stdout
    assert "contacts:" not in out


def test_inspect_reports_the_contacts(contacts_run):
    out = moreau("inspect", contacts_run).stdout
    assert "contacts:" in out and "largest λ" in out and "/frames/pressure" in out


def test_the_gif_animation_has_the_frames_asked_for(contacts_run, tmp_path):
    from PIL import Image

    out = tmp_path / "room.gif"
    assert plot_run.main([str(contacts_run), "--animate", str(out), "--max-frames", "9",
                          "--color", "pressure"]) == 0
    with h5py.File(contacts_run, "r") as f:
        frames = len(f["frames/time"])
    expected = len(range(0, frames, -(-frames // 9)))
    with Image.open(out) as im:
        assert im.n_frames == expected


def test_the_mp4_animation_has_the_frames_asked_for(contacts_run, tmp_path):
    if shutil.which("ffmpeg") is None or shutil.which("ffprobe") is None:
        pytest.fail("ffmpeg is missing: scripts/setup.sh installs it (Debian's ffmpeg)")
    out = tmp_path / "room.mp4"
    assert plot_run.main([str(contacts_run), "--animate", str(out), "--max-frames", "12"]) == 0
    with h5py.File(contacts_run, "r") as f:
        frames = len(f["frames/time"])
    expected = len(range(0, frames, -(-frames // 12)))
    probe = subprocess.run(
        ["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0",
         "-show_entries", "stream=nb_read_frames", "-of", "csv=p=0", str(out)],
        capture_output=True, text=True, check=True, stdin=subprocess.DEVNULL)
    assert int(probe.stdout.strip()) == expected


def test_animating_pressure_without_contacts_says_what_to_do(room_run, tmp_path):
    with pytest.raises(SystemExit, match="contacts = true"):
        plot_run.main([str(room_run), "--animate", str(tmp_path / "x.gif"), "--color",
                       "pressure"])
