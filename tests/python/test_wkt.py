"""The walkable area as WKT: a run file's `wkt_geometry` is the scene's polygon, holes
included, for shapely and PedPy; and a scene that gives its area as that WKT (a string, or a
file beside it) runs the same as the scene that gives its rings."""

from __future__ import annotations

import re
import tomllib

import h5py
import numpy as np
import pedpy
import pytest
import shapely

import moreau_run
from conftest import ROOT, moreau

TWO_EXITS = ROOT / "data" / "scenes" / "room-two-exits.toml"


def short_scene(text: str) -> str:
    """room-two-exits cut to 2 s."""
    short = text.replace("horizon = 30.0", "horizon = 2.0")
    assert short != text
    return short


@pytest.fixture(scope="module")
def two_exits_run(tmp_path_factory):
    """room-two-exits (two tables as holes), 2 s, run once: (scene file, run file)."""
    tmp = tmp_path_factory.mktemp("two-exits")
    scene = tmp / "room-two-exits.toml"
    scene.write_text(short_scene(TWO_EXITS.read_text()))
    out = tmp / "room-two-exits.h5"
    moreau("run", scene, "-o", out, "--quiet")
    return scene, out


def test_the_run_files_wkt_is_the_scene_polygon_for_shapely_and_pedpy(two_exits_run):
    scene, out = two_exits_run
    area = tomllib.loads(scene.read_text())["area"]
    expected = shapely.Polygon(area["outer"], area["holes"])
    assert len(expected.interiors) == 2
    with h5py.File(out, "r") as f:
        wkt = f.attrs["wkt_geometry"]
    polygon = shapely.from_wkt(wkt)
    assert polygon.geom_type == "Polygon"
    # The same vertices in the same order, coordinates equal to the last bit.
    assert shapely.equals_exact(polygon, expected, tolerance=0.0)
    # 12 m × 8 m, two vestibules of 0.2 × 1.2 + 1 × 2.4, less two tables of 1.5 × 3.
    assert polygon.area == pytest.approx(96 + 2 * (0.24 + 2.4) - 2 * 4.5, abs=1e-12)

    walkable = pedpy.WalkableArea(wkt)
    assert walkable.polygon.equals(expected)
    assert len(walkable.polygon.interiors) == 2
    from_file = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=out)
    assert from_file.polygon.equals(expected)


def test_a_scene_with_its_area_as_that_wkt_runs_the_same(two_exits_run, tmp_path):
    scene, out = two_exits_run
    with h5py.File(out, "r") as f:
        wkt = f.attrs["wkt_geometry"]
    text = scene.read_text()
    # The [area] table, up to the first exit.
    table = re.compile(r"^\[area\]\n.*?(?=^\[\[exits\]\])", re.S | re.M)
    assert len(table.findall(text)) == 1

    # As a string: a top-level key, before the first table.
    as_string = table.sub("", text).replace("seed = ", f"area = {wkt!r}\nseed = ", 1)
    assert "outer" not in as_string
    # As a file beside the scene.
    geometry = tmp_path / "geometry"
    geometry.mkdir()
    (geometry / "room.wkt").write_text(wkt + "\n")
    as_file = table.sub('[area]\nwkt_file = "geometry/room.wkt"\n\n', text)
    assert "outer" not in as_file

    runs = {"rings": moreau_run.load(out)}
    for name, variant in (("string", as_string), ("file", as_file)):
        path = tmp_path / f"{name}.toml"
        path.write_text(variant)
        h5 = tmp_path / f"{name}.h5"
        # From another directory: the WKT file is found beside the scene file.
        moreau("run", path, "-o", h5, "--quiet", cwd=ROOT)
        runs[name] = moreau_run.load(h5)
    rings = runs.pop("rings")
    for name, run in runs.items():
        assert run.attrs["wkt_geometry"] == rings.attrs["wkt_geometry"], name
        assert run.attrs["scene"] == rings.attrs["scene"], name
        np.testing.assert_array_equal(run.trajectory, rings.trajectory)
    assert len(rings.trajectory) > 0
