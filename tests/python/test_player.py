"""The player (`moreau view`) in a real browser: headless Chromium (Debian's `chromium` and
`chromium-driver`, installed by scripts/setup.sh) opens the self-contained HTML written for a
run, a script presses play, pauses, moves the slider to a known frame and takes a screenshot
(into the test's directory; into docs/player.png, the README's picture, with
MOREAU_UPDATE_DOCS=1); the page must show the frame asked for with the people present in
it (counted here from the run file with h5py), and log nothing to the console."""

from __future__ import annotations

import base64
import json
import os
import pathlib
import re
import shutil
import time

import h5py
import numpy as np
import pytest

import player_data
from conftest import DENSE, ROOM, ROOT, moreau

SCREENSHOT = ROOT / "docs" / "player.png"  # rewritten only with MOREAU_UPDATE_DOCS=1
WINDOW = (1200, 800)
DENSE_10K = DENSE.with_name("dense-10k.toml")


# ---- the HTML under test ----------------------------------------------------------------------

@pytest.fixture(scope="session")
def make_html():
    """The one function that writes the player of a run file: `make(run, out) -> out`, by
    `moreau view RUN.h5 -o OUT.html` (python/player_data.py is the independent cross-check)."""
    def make(run: pathlib.Path, out: pathlib.Path) -> pathlib.Path:
        moreau("view", run, "-o", out, "--force")
        return out
    return make


def read_player_data(html: pathlib.Path) -> dict:
    """The JSON a player HTML holds (the contents of its `moreau-data` script tag)."""
    text = html.read_text(encoding="utf-8")
    found = re.findall(r'<script id="moreau-data" type="application/json">(.*?)</script>', text, re.S)
    assert len(found) == 1, "exactly one data tag"
    return json.loads(found[0])


def floats(b64: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), dtype="<f4")


def present(run: pathlib.Path) -> np.ndarray:
    """People present (finite position) in each frame, from /frames/positions."""
    with h5py.File(run, "r") as f:
        frames = f["frames/time"].shape[0]
        return np.isfinite(f["frames/positions"][:frames, :, 0]).sum(axis=1)


# ---- the browser ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def browser():
    """Headless Chromium through chromedriver, 1200×800, with the console log kept."""
    chromium, driver_path = shutil.which("chromium"), shutil.which("chromedriver")
    if not chromium or not driver_path:
        pytest.fail("Debian's chromium and chromium-driver are missing: ./scripts/setup.sh "
                    "installs them (apt-get install chromium chromium-driver)")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.fail("the selenium Python package is missing: ./scripts/setup.sh installs "
                    "python/requirements.txt into .venv")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu",
                f"--window-size={WINDOW[0]},{WINDOW[1]}"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # Explicit paths: Selenium Manager never looks for (or downloads) a browser or driver.
    driver = webdriver.Chrome(options=options, service=Service(driver_path))
    driver.set_script_timeout(120)
    try:
        yield driver
    finally:
        driver.quit()


def open_player(browser, html: pathlib.Path) -> float:
    """Loads the player and waits until it has drawn its first frame; returns the seconds."""
    from selenium.webdriver.support.ui import WebDriverWait
    browser.get_log("browser")  # drop what earlier pages logged
    start = time.perf_counter()
    browser.get(html.resolve().as_uri())
    WebDriverWait(browser, 60).until(
        lambda d: d.execute_script("return document.body.dataset.frame !== undefined"))
    return time.perf_counter() - start


def console_problems(browser) -> list:
    """Console entries at warning level or above since the last call."""
    return [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]


def js(browser, script: str, *args):
    return browser.execute_script(script, *args)


def set_slider(browser, k: int) -> None:
    js(browser, "const s = document.getElementById('slider');"
                "s.value = arguments[0]; s.dispatchEvent(new Event('input'));", k)


def shown(browser) -> tuple[int, int]:
    d = js(browser, "return [document.body.dataset.frame, document.body.dataset.drawn]")
    return int(d[0]), int(d[1])


# ---- the tests --------------------------------------------------------------------------------

def test_the_player_data_is_the_run_file(room_run, make_html, tmp_path):
    """The JSON in the HTML against the run file read with h5py: frames, times, positions
    (float32), radii, the per-frame ε and violation of the last step at or before the frame."""
    data = read_player_data(make_html(room_run, tmp_path / "room.html"))
    with h5py.File(room_run, "r") as f:
        t = f["frames/time"][:]
        positions = f["frames/positions"][: len(t)]
        radius = f["people/radius"][:]
        steps = f["steps"][:]
    assert data["format"] == "moreau-player-1"
    assert data["title"] == "room-150" and data["note"] == ""
    assert data["people_total"] == data["people_shown"] == len(radius) == 150
    assert data["frames_total"] == len(t) == len(data["time"]) == 201
    np.testing.assert_allclose(data["time"], t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(floats(data["radius"]), radius.astype("f4"))
    np.testing.assert_array_equal(floats(data["positions"]).reshape(positions.shape),
                                  positions.astype("f4"))  # NaN where NaN
    assert data["pressure"] is None  # the room does not record contacts
    assert data["eps"][0] is None and data["violation"][0] is None  # no step before t = 0
    for k in (1, 57, 200):
        row = steps[np.flatnonzero(steps["t"] <= t[k])[-1]]
        assert data["eps"][k] == pytest.approx(row["eps"], rel=1e-12)
        assert data["violation"][k] == pytest.approx(row["violation"], rel=1e-12, abs=0)
    # The room's 12 outer corners: 12 walls; one exit, the door.
    assert len(data["geometry"]["area"]) == 1 and len(data["geometry"]["walls"]) == 12
    assert [e["name"] for e in data["geometry"]["exits"]] == ["door"]
    assert data["bbox"] == [0.0, 0.0, 20.0, 10.0]


def test_the_player_plays_the_room_and_shows_the_frame_asked_for(browser, room_run, make_html,
                                                                  tmp_path):
    from selenium.webdriver.support.ui import WebDriverWait
    html = make_html(room_run, tmp_path / "room.html")
    counts = present(room_run)
    seconds = open_player(browser, html)
    print(f"room: {html.stat().st_size / 1e6:.2f} MB, loaded and drawn in {seconds:.2f} s")
    assert js(browser, "return moreauPlayer.frameCount") == len(counts)
    assert shown(browser) == (0, counts[0])

    play = browser.find_element("id", "play")
    play.click()
    WebDriverWait(browser, 10).until(lambda d: js(d, "return moreauPlayer.frame") >= 3)
    play.click()
    assert not js(browser, "return moreauPlayer.playing")
    paused_at = js(browser, "return moreauPlayer.frame")
    time.sleep(0.3)
    assert js(browser, "return moreauPlayer.frame") == paused_at, "pause stops the clock"

    k = 40  # t = 4 s: the crowd reaches the door
    browser.find_element("id", "trails").click()
    set_slider(browser, k)
    assert shown(browser) == (k, counts[k])
    assert js(browser, "return [moreauPlayer.frame, moreauPlayer.drawn]") == [k, counts[k]]
    status = browser.find_element("id", "status").text
    assert "t = 4.00 s" in status and f"frame {k + 1}/{len(counts)}" in status
    assert re.search(r"ε = \d\.\de-\d+ m²", status), status
    # Pressure is not offered for a run without contacts.
    assert js(browser, "return document.querySelector('#color option[value=pressure]').disabled")
    browser.save_screenshot(str(SCREENSHOT if os.environ.get("MOREAU_UPDATE_DOCS") == "1"
                                else tmp_path / "player.png"))

    # The other controls draw without complaint: trails off, playback speed, frame stepping.
    browser.find_element("id", "trails").click()
    js(browser, "const s = document.getElementById('speed'); s.value = '8';"
                "s.dispatchEvent(new Event('change'));")
    browser.find_element("id", "next").click()
    assert shown(browser) == (k + 1, counts[k + 1])
    browser.find_element("id", "prev").click()
    browser.find_element("id", "prev").click()
    assert shown(browser) == (k - 1, counts[k - 1])
    assert console_problems(browser) == []


def test_people_who_leave_are_not_drawn(browser, make_html, tmp_path):
    """The room with people removed at the door: the count drawn follows the run file, frame by
    frame, through the slider, the keyboard and seek(); a decimated file says so on screen."""
    from selenium.webdriver.common.keys import Keys
    scene = tmp_path / "room-remove.toml"
    text = ROOM.read_text().replace('action = "continue"', 'action = "remove"')
    text = re.sub(r"target = \[\[.*\]\]\n", "", text).replace("horizon = 20.0", "horizon = 14.0")
    scene.write_text(text)
    run = tmp_path / "room-remove.h5"
    moreau("run", scene, "-o", run, "--quiet")
    counts = present(run)
    assert counts[-1] < counts[0], "people left"

    open_player(browser, make_html(run, tmp_path / "room-remove.html"))
    for k in (0, 60, 100, len(counts) - 1):
        set_slider(browser, k)
        assert shown(browser) == (k, counts[k])
    body = browser.find_element("tag name", "body")
    js(browser, "document.activeElement.blur()")
    body.send_keys(Keys.ARROW_LEFT)
    body.send_keys(Keys.ARROW_LEFT)
    assert shown(browser) == (len(counts) - 3, counts[-3])
    body.send_keys(Keys.SPACE)
    assert js(browser, "return moreauPlayer.playing")
    body.send_keys(Keys.SPACE)
    assert not js(browser, "return moreauPlayer.playing")
    js(browser, "moreauPlayer.seek(80)")
    assert shown(browser) == (80, counts[80])
    assert console_problems(browser) == []

    # Decimated (fewer values than the run has): said on screen, counts of the people kept.
    small = tmp_path / "room-remove-small.html"
    player_data.write_html(run, small, max_values=20_000)
    data = read_player_data(small)
    assert player_data.strides(len(counts), 150, 2, 20_000) == (1, 3)
    assert data["note"] == ("every 3rd person (50 of 150) shown: the run is larger than "
                            "--max-values") and data["people_shown"] == 50
    open_player(browser, small)
    assert browser.find_element("id", "note").text == data["note"]
    with h5py.File(run, "r") as f:
        kept = f["frames/positions"][: len(counts), ::3, 0]
    set_slider(browser, 40)
    assert shown(browser) == (40, np.isfinite(kept[40]).sum())
    assert console_problems(browser) == []


def test_colour_by_pressure(browser, make_html, tmp_path):
    """A run that records contact forces (`[output] contacts = true`) offers colour by
    pressure Σλ, with its legend; the pressure in the page is the file's."""
    scene = tmp_path / "room-contacts.toml"
    scene.write_text(ROOM.read_text() + "\n[output]\ncontacts = true\n")
    run = tmp_path / "room-contacts.h5"
    moreau("run", scene, "-o", run, "--quiet")
    html = make_html(run, tmp_path / "room-pressure.html")
    data = read_player_data(html)
    with h5py.File(run, "r") as f:
        pressure = f["frames/pressure"][:]
    np.testing.assert_array_equal(floats(data["pressure"]).reshape(pressure.shape),
                                  pressure.astype("f4"))
    open_player(browser, html)
    assert not js(browser, "return document.querySelector('#color option[value=pressure]').disabled")
    js(browser, "const s = document.getElementById('color'); s.value = 'pressure';"
                "s.dispatchEvent(new Event('change'));")
    set_slider(browser, 100)
    assert shown(browser) == (100, 150)
    assert browser.find_element("id", "legend-min").text.startswith("pressure Σλ (m/s)")
    assert console_problems(browser) == []


def test_moreau_view_and_the_python_stand_in_write_the_same_data(room_run, make_html,
                                                                  tmp_path):
    """Two independent writers of the page's data (Rust from the crates' reader and scene,
    Python from h5py and tomllib) agree on everything a player draws."""
    ours = read_player_data(make_html(room_run, tmp_path / "room.html"))
    theirs = player_data.player_json(room_run)
    assert sorted(ours) == sorted(theirs)
    for key in ("format", "title", "people_total", "people_shown", "frames_total", "note",
                "radius", "positions", "pressure"):
        assert ours[key] == theirs[key], key
    np.testing.assert_allclose(ours["time"], theirs["time"], rtol=0, atol=0)
    for key in ("eps", "violation"):
        assert [x is None for x in ours[key]] == [x is None for x in theirs[key]]
        np.testing.assert_allclose([x for x in ours[key] if x is not None],
                                   [x for x in theirs[key] if x is not None], rtol=1e-15)
    np.testing.assert_allclose(ours["bbox"], theirs["bbox"])
    undirected = lambda walls: sorted(tuple(sorted([(w[0], w[1]), (w[2], w[3])])) for w in walls)
    assert undirected(ours["geometry"]["walls"]) == undirected(theirs["geometry"]["walls"])
    assert ours["geometry"]["exits"] == theirs["geometry"]["exits"]
    assert ours["geometry"]["area"] == theirs["geometry"]["area"]
    # Decimated, both say so in the same words (regression: Rust wrote "every 2th frame",
    # Python left out how many people of how many, and why).
    for max_values in (20_000, 2_000):
        out = tmp_path / f"room-{max_values}.html"
        moreau("view", room_run, "-o", out, "--force", "--max-values", str(max_values))
        ours = read_player_data(out)
        theirs = player_data.player_json(room_run, max_values)
        for key in ("people_shown", "frames_total", "note", "radius", "positions"):
            assert ours[key] == theirs[key], key
        assert ours["note"].endswith("shown: the run is larger than --max-values"), ours["note"]


@pytest.mark.parametrize("source, edit, names, strides", [
    # 201 frames: a decimated page keeps every 2nd frame.
    (ROOT / "tests" / "fuzz-corpus" / "moving.toml",
     ("output_interval = 0.5", "output_interval = 0.05"), ["bar", "block", "exit:east"], (1, 2)),
    # A hole (walls oriented by the run), 31 frames: decimated, every frame, fewer people.
    (ROOM.with_name("room-closing-door.toml"), ("horizon = 40.0", "horizon = 3.0"),
     ["panel"], (1, 1)),
])
def test_the_python_stand_in_writes_the_moving_walls_of_moreau_view(source, edit, names,
                                                                    strides, tmp_path):
    """Regression: python/player_data.py left out `moving`, so its page drew no moving body
    and no exit panel. The fuzz corpus's moving scene (a turning bar, a drifting block, the
    panel `exit:east` of an exit that closes and opens) and the room whose door a panel
    closes, short: both writers agree on every field, decimated (--max-values 2000) or not,
    and `moving` is the file's /frames/moving_walls at the frames shown."""
    scene = tmp_path / source.name
    scene.write_text(source.read_text().replace(*edit))
    run = tmp_path / "moving.h5"
    moreau("run", scene, "-o", run, "--quiet")
    with h5py.File(run, "r") as f:
        walls = f["frames/moving_walls"][:].astype("f4")
        assert list(f["moving/name"].asstr()[:]) == names
    for max_values, stride in zip((None, 2_000), strides):
        out = tmp_path / f"moving-{max_values}.html"
        moreau("view", run, "-o", out, "--force",
               *(("--max-values", max_values) if max_values else ()))
        ours = read_player_data(out)
        theirs = player_data.player_json(run, *((max_values,) if max_values else ()))
        theirs = json.loads(json.dumps(theirs))  # through JSON, as the page holds it
        assert sorted(ours) == sorted(theirs)
        for key in ours:
            assert ours[key] == theirs[key], key
        np.testing.assert_array_equal(floats(theirs["moving"]).reshape(-1, *walls.shape[1:]),
                                      walls[::stride])
        # The view holds the moving bodies wherever they go (room-closing-door's panel starts
        # below the area, y = -0.75, and was drawn outside the view).
        xs, ys = walls[::stride][..., [0, 2]], walls[::stride][..., [1, 3]]
        x0, y0, x1, y1 = ours["bbox"]
        assert x0 <= xs.min() and xs.max() <= x1 and y0 <= ys.min() and ys.max() <= y1, ours["bbox"]


def test_a_file_without_its_moving_walls_played_without_them_and_said_nothing(tmp_path):
    """Regression: a run file whose `/moving/body` lists segments but whose
    `/frames/moving_walls` is gone gave a page with `"moving": ""`, drawing no moving body
    and saying nothing. `moreau view` now refuses it, as the Python stand-in does."""
    scene = tmp_path / "moving.toml"
    scene.write_text((ROOT / "tests" / "fuzz-corpus" / "moving.toml").read_text())
    run = tmp_path / "moving.h5"
    moreau("run", scene, "-o", run, "--quiet")
    with h5py.File(run, "r+") as f:
        del f["frames/moving_walls"]
    out = moreau("view", run, "-o", tmp_path / "page.html", check=False)
    assert out.returncode != 0 and "moving wall segments" in out.stderr, out.stderr
    with pytest.raises(ValueError, match="moving_walls"):
        player_data.player_json(run)


def test_decimation_keeps_100_frames_then_thins_people():
    assert player_data.strides(201, 150, 2, 10**6) == (1, 1)
    assert player_data.strides(201, 10_000, 2, 2_100_000) == (2, 1)  # 101 frames
    assert player_data.strides(201, 1_000_000, 2, 16_000_000) == (2, 13)
    assert player_data.strides(1001, 1_000_000, 3, 16_000_000) == (10, 19)


def test_ten_thousand_people(browser, make_html, tmp_path):
    """10,000 people (the dense hall, 3 s at 10 frames/s): the HTML's size and the player's
    frame rate, printed (headless Chromium without a GPU: software rasterization)."""
    scene = tmp_path / "dense-10k-short.toml"
    scene.write_text(DENSE_10K.read_text().replace("horizon = 5.0", "horizon = 3.0")
                     .replace("output_interval = 0.5", "output_interval = 0.1"))
    run = tmp_path / "dense-10k.h5"
    moreau("run", scene, "-o", run, "--quiet")
    counts = present(run)
    html = make_html(run, tmp_path / "dense-10k.html")
    seconds = open_player(browser, html)
    assert shown(browser) == (0, counts[0]) and counts[0] == 10_000
    fps = browser.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "moreauPlayer.measureFps(60).then((fps) => done([fps, moreauPlayer.lastDrawMs]));")
    print(f"10,000 people, {len(counts)} frames: HTML {html.stat().st_size / 1e6:.1f} MB, "
          f"loaded and drawn in {seconds:.2f} s, {fps[0]:.0f} frames/s over 60 frames "
          f"(mean draw {fps[1]:.1f} ms)")
    assert fps[0] > 0
    assert console_problems(browser) == []


def test_moving_walls_are_in_the_page_and_drawn_in_red(browser, make_html, tmp_path):
    """A run with moving bodies carries their segments per frame into the page (as in the
    file's /frames/moving_walls), and the player draws them in red over the people."""
    scene = ROOM.with_name("rotating-bar.toml")
    run = tmp_path / "rotating-bar.h5"
    moreau("run", scene, "-o", run, "--quiet")
    html = make_html(run, tmp_path / "rotating-bar.html")
    data = read_player_data(html)
    with h5py.File(run, "r") as f:
        walls = f["frames/moving_walls"][:]
    np.testing.assert_array_equal(floats(data["moving"]).reshape(walls.shape), walls.astype("f4"))
    still = tmp_path / "still.h5"
    moreau("run", ROOM.with_name("room-60.toml"), "-o", still, "--quiet")
    assert "moving" not in read_player_data(make_html(still, tmp_path / "still.html"))
    open_player(browser, html)
    red = ("const c = document.getElementById('view'); const d = c.getContext('2d')"
           ".getImageData(0, 0, c.width, c.height).data; let n = 0;"
           "for (let i = 0; i < d.length; i += 4) if (d[i] === 214 && d[i+1] === 39 && d[i+2] === 40) n++;"
           "return n;")
    for k in (0, 40, 80):
        set_slider(browser, k)
        assert js(browser, red) > 50, f"frame {k}: the bar is not drawn"
    # (Chromium warns about this test's own repeated getImageData readbacks.)
    problems = [p for p in console_problems(browser) if "readback" not in p["message"]]
    assert problems == [], problems


def test_player_data_refuses_what_moreau_view_refuses(room_run, tmp_path, capsys):
    """Regression: python/player_data.py wrote an HTML of no data with `--max-values 0`, and
    a missing or non-HDF5 run file ended in a traceback. Like `moreau view`, it refuses them
    (exit 2), naming the flag or the file, and writes nothing."""
    garbage = tmp_path / "garbage.h5"
    garbage.write_text("not HDF5")
    for args, said in [
        ([str(room_run), "--max-values", "0", "-o", str(tmp_path / "x.html")],
         "--max-values 0: must be at least 1000"),
        ([str(tmp_path / "missing.h5")], "no such run file"),
        ([str(garbage)], "cannot be read as HDF5"),
    ]:
        with pytest.raises(SystemExit) as ended:
            player_data.main(args)
        assert ended.value.code == 2 and said in capsys.readouterr().err, args
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.h5"]


def test_player_data_on_an_hdf5_file_that_is_no_run_gave_a_traceback(tmp_path, capsys):
    """Regression: an HDF5 file that is not a run file (no /frames) ended in h5py's KeyError
    traceback; it is refused (exit 2), naming the file and what it lacks."""
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = [1.0, 2.0]
    with pytest.raises(SystemExit) as ended:
        player_data.main([str(other), "-o", str(tmp_path / "other.html")])
    err = capsys.readouterr().err
    assert ended.value.code == 2 and f"{other}: not a moreau run file (no /frames/time)" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.h5"]
