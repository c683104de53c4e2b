"""The data of the moreau player (`moreau view`), made in Python from a run file.

An independent stand-in for the Rust emitter of `moreau view RUN.h5 -o RUN.html`: the same
JSON (format `moreau-player-1`, documented at the top of the template's script,
crates/cli/src/view/player.html) from the same run file, with numpy and h5py only.

    .venv/bin/python python/player_data.py out/room-150.h5 -o out/room-150.html

Decimation, when frames × people × values would exceed `max_values` (float32 values of
`positions` and `pressure` together): first every s-th frame (s at most frames // 100, so at
least 100 frames stay when there were that many), the smallest s that fits; then, if still too
many, every p-th person, the smallest p that fits. Frames kept: 0, s, 2s, ...; people kept:
ids 0, p, 2p, ...

Moving bodies (the scene's `[[moving]]`, and the panels `exit:NAME` of exits that `closes` or
`opens`, stored alike in the run file): their segments at each frame shown, from
`/frames/moving_walls`, in `moving`; absent when the run has none (no rows in `/moving/body`).
The walls are the run file's `/walls` (the edges of the area's rings for a file without).
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import pathlib
import tomllib

import h5py
import numpy as np

FORMAT = "moreau-player-1"
TEMPLATE = pathlib.Path(__file__).resolve().parents[1] / "crates" / "cli" / "src" / "view" / "player.html"
PLACEHOLDER = '<script id="moreau-data" type="application/json">__MOREAU_DATA__</script>'
MAX_VALUES = 40_000_000  # `moreau view`'s default; ~213 MB of base64 float32
MIN_FRAMES = 100  # frame decimation stops here; people are decimated beyond


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _b64(array) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype="<f4").tobytes()).decode("ascii")


def _per_frame(values, idx) -> list:
    """values[i] for each index (None before the first step or when not finite)."""
    return [float(values[i]) if i >= 0 and math.isfinite(values[i]) else None for i in idx]


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def strides(frames: int, people: int, per_person_frame: int, max_values: int) -> tuple[int, int]:
    """(frame stride, person stride) by the rule in the module documentation."""
    def size(sf, sp):
        return math.ceil(frames / sf) * math.ceil(people / sp) * per_person_frame

    if frames == 0 or people == 0 or size(1, 1) <= max_values:
        return 1, 1
    sf_max = max(1, frames // MIN_FRAMES)
    sf = next((s for s in range(1, sf_max + 1) if size(s, 1) <= max_values), sf_max)
    if size(sf, 1) <= max_values:
        return sf, 1
    per_person = math.ceil(frames / sf) * per_person_frame
    keep = max(1, max_values // per_person)  # people that fit
    sp = max(1, math.ceil(people / keep))
    while sp > 1 and size(sf, sp - 1) <= max_values:
        sp -= 1
    while sp < people and size(sf, sp) > max_values:
        sp += 1
    return sf, sp


def geometry(scene: dict) -> tuple[dict, list[float]]:
    """Area rings, walls (the edges of every ring) and exits of a scene, and their bbox."""
    area = scene["area"]
    rings = [[[float(x), float(y)] for x, y in area["outer"]]]
    rings += [[[float(x), float(y)] for x, y in hole] for hole in area.get("holes", [])]
    walls = []
    for ring in rings:
        for a, b in zip(ring, ring[1:] + ring[:1]):
            if a != b:
                walls.append([a[0], a[1], b[0], b[1]])
    exits = []
    for exit_ in scene.get("exits", []):
        points = exit_["area"] if "area" in exit_ else exit_["segment"]
        exits.append({"name": exit_["name"], "points": [[float(x), float(y)] for x, y in points]})
    pts = np.array([p for ring in rings for p in ring] + [p for e in exits for p in e["points"]])
    bbox = [float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max())]
    return {"area": rings, "walls": walls, "exits": exits}, bbox


def step_values(steps, time) -> tuple[list, list]:
    """Per frame: ε and violation of the last step ending at or before it (steps end exactly
    on output times; `moreau view`'s tolerance, 10⁻⁹ relative above 1 s); all None without
    steps."""
    if steps is None or not len(steps):
        return [None] * len(time), [None] * len(time)
    order = np.argsort(steps["t"], kind="stable")
    tol = 1e-9 * np.maximum(np.abs(time), 1.0)
    idx = np.searchsorted(steps["t"][order], time + tol, side="right") - 1
    return _per_frame(steps["eps"][order], idx), _per_frame(steps["violation"][order], idx)


def moving_walls(f, run_path, frames: int, sf: int):
    """The moving bodies' segments `[x0, y0, x1, y1]` at frames 0, sf, 2sf, ... of `frames`
    (float64 `[frames shown, segments, 4]`), or None when the run has no moving bodies."""
    if "moving/body" not in f or f["moving/body"].shape[0] == 0:
        return None
    if "frames/moving_walls" not in f:
        raise ValueError(f"{run_path}: moving bodies but no /frames/moving_walls")
    ds = f["frames/moving_walls"]
    if ds.shape[0] < frames:
        raise ValueError(f"{run_path}: /frames/moving_walls has {ds.shape[0]} frames of {frames}")
    return ds[:frames:sf]


def player_json(run_path, max_values: int = MAX_VALUES) -> dict:
    """The player's data for a run file (see the module documentation); a ValueError
    naming the file when it is an HDF5 file but not a run file."""
    with h5py.File(run_path, "r") as f:
        for name in ("frames/time", "frames/positions", "people/radius"):
            if name not in f:
                raise ValueError(f"{run_path}: not a moreau run file (no /{name})")
        if "scene" not in f.attrs:
            raise ValueError(f"{run_path}: not a moreau run file (no attribute scene)")
        scene = tomllib.loads(_text(f.attrs["scene"]))
        name = _text(f.attrs["scene_name"]) if "scene_name" in f.attrs else scene.get("name", "")
        time_all = f["frames/time"][:]
        frames = len(time_all)
        people = f["people/radius"].shape[0]
        has_pressure = "frames/pressure" in f
        sf, sp = strides(frames, people, 3 if has_pressure else 2, max_values)
        time = time_all[::sf]
        positions = f["frames/positions"][:frames:sf, ::sp, :]
        radius = f["people/radius"][::sp]
        pressure = f["frames/pressure"][:frames:sf, ::sp] if has_pressure else None
        steps = f["steps"][:] if "steps" in f else None
        moving = moving_walls(f, run_path, frames, sf)
        walls = f["walls"][:] if "walls" in f else np.empty((0, 4))

    eps, violation = step_values(steps, time)

    parts = []
    if sf > 1:
        parts.append(f"every {_ordinal(sf)} frame")
    if sp > 1:
        parts.append(f"every {_ordinal(sp)} person ({radius.shape[0]} of {people})")
    # (The words of `moreau view`'s note.)
    note = (", ".join(parts) + " shown: the run is larger than --max-values") if parts else ""

    geo, bbox = geometry(scene)
    if moving is not None:
        # The moving bodies as drawn (float32), wherever they go, as `moreau view` fits them.
        pts = moving.astype("<f4").astype(float).reshape(-1, 2)
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts):
            bbox = [min(bbox[0], float(pts[:, 0].min())), min(bbox[1], float(pts[:, 1].min())),
                    max(bbox[2], float(pts[:, 0].max())), max(bbox[3], float(pts[:, 1].max()))]
    if len(walls):
        geo["walls"] = [[float(v) for v in w] for w in walls]
    data = {
        "format": FORMAT,
        "title": name,
        "people_total": int(people),
        "people_shown": int(radius.shape[0]),
        "frames_total": int(frames),
        "note": note,
        "bbox": bbox,
        "geometry": geo,
        "time": [float(t) for t in time],
        "eps": eps,
        "violation": violation,
        "radius": _b64(radius),
        "positions": _b64(positions),
        "pressure": _b64(pressure) if pressure is not None else None,
    }
    if moving is not None:
        data["moving"] = _b64(moving)
    return data


def fill_template(data: dict, template: str | None = None) -> str:
    """The template with its data line replaced by `data` (every `<` written as \\u003c)."""
    template = TEMPLATE.read_text(encoding="utf-8") if template is None else template
    if template.count(PLACEHOLDER) != 1:
        raise ValueError("the template must hold the data line exactly once")
    text = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    return template.replace(PLACEHOLDER, f'<script id="moreau-data" type="application/json">{text}</script>')


def write_html(run_path, out_path, max_values: int = MAX_VALUES) -> pathlib.Path:
    """Writes the self-contained player of a run file; returns its path."""
    out_path = pathlib.Path(out_path)
    out_path.write_text(fill_template(player_json(run_path, max_values)), encoding="utf-8")
    return out_path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("run", type=pathlib.Path, help="the run file (HDF5)")
    parser.add_argument("-o", "--out", type=pathlib.Path, help="the HTML (default: RUN.html)")
    parser.add_argument("--max-values", type=int, default=MAX_VALUES,
                        help=f"float32 values kept before decimating (default {MAX_VALUES})")
    args = parser.parse_args(argv)
    # The rules of `moreau view`'s --max-values and run file.
    if args.max_values < 1000:
        parser.error(f"--max-values {args.max_values}: must be at least 1000")
    if not args.run.is_file():
        parser.error(f"no such run file: {args.run}")
    try:
        h5py.File(args.run, "r").close()
    except OSError as e:
        parser.error(f"{args.run}: cannot be read as HDF5: {e}")
    try:
        out = write_html(args.run, args.out or args.run.with_suffix(".html"), args.max_values)
    except ValueError as e:
        parser.error(str(e))
    print(f"{out}: {out.stat().st_size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
