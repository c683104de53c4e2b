"""Reading a moreau run file (HDF5) into numpy, and the scene geometry PedPy analyses need.

The layout is written by `crates/io` (see its module documentation). `load` reads the dense
arrays; PedPy reads the same file directly with `load_trajectory_from_ped_data_archive_hdf5`.
"""

from __future__ import annotations

import json
import pathlib
import tomllib
from dataclasses import dataclass

import h5py
import numpy as np
from scipy.spatial import cKDTree


@dataclass
class Run:
    """A run file read into memory."""

    path: pathlib.Path
    attrs: dict
    scene: dict
    time: np.ndarray  # (F,) time of each output frame
    count: np.ndarray  # (F,) people present in each frame
    positions: np.ndarray  # (F, N, 2) by person id, NaN when absent
    radius: np.ndarray  # (N,)
    steps: np.ndarray  # structured, one row per step
    exits: np.ndarray  # structured (id, exit, t), one row per exit passage (exit: the scene's [[exits]] index)
    trajectory: np.ndarray  # structured (id, frame, x, y)
    entry_time: np.ndarray | None = None  # (N,) when each entered (0: at the start); None in files before 2026-11-28
    group: np.ndarray | None = None  # (N,) each one's group: the scene's [[groups]] by index, then one per [[sources]]; -1 unknown; None in files written before it was added (2026-11-28, evening)

    def group_name(self, g: int) -> str:
        """The name of group index `g` (a `[[groups]]` entry's, or a `[[sources]]` entry's);
        a ValueError for −1 (not stored: a file a run resumed from before groups were) and any
        index the scene has no entry for."""
        names = [x["name"] for x in self.scene.get("groups", [])]
        names += [x["name"] for x in self.scene.get("sources", [])]
        if not 0 <= g < len(names):
            raise ValueError(f"group {g}: the scene has {len(names)} groups and sources"
                             + (" (−1: not stored in this file)" if g == -1 else ""))
        return names[g]

    @property
    def status(self) -> str:
        return self.attrs["status"]

    @property
    def summary(self) -> dict:
        return json.loads(self.attrs["summary"])

    @property
    def fps(self) -> float:
        return float(self.attrs["fps"])


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def load(path, *, locking: bool | None = None) -> Run:
    """Reads the whole run file (`locking=False` to read a file another process writes)."""
    path = pathlib.Path(path)
    kwargs = {} if locking is None else {"locking": locking}
    with h5py.File(path, "r", **kwargs) as f:
        attrs = {k: (_text(v) if isinstance(v, (str, bytes)) else v) for k, v in f.attrs.items()}
        attrs["fps"] = float(f["trajectory"].attrs["fps"])
        frames = f["frames/time"].shape[0]
        return Run(
            path=path,
            attrs=attrs,
            scene=tomllib.loads(attrs["scene"]),
            time=f["frames/time"][:],
            count=f["frames/count"][:frames],
            positions=f["frames/positions"][:frames],
            radius=f["people/radius"][:],
            steps=f["steps"][:],
            exits=f["exits"][:],
            trajectory=f["trajectory"][:],
            entry_time=f["people/entry_time"][:] if "people/entry_time" in f else None,
            group=f["people/group"][:] if "people/group" in f else None,
        )


def walls_of(scene: dict) -> np.ndarray:
    """The walls `(n, 4)` (x0, y0, x1, y1) of a scene's area given as rings (`outer`,
    `holes`): every edge of every ring, in the ring's order; empty for an area in WKT. The
    run file's `/walls` holds the same segments, a hole's in another order and direction:
    look a contact's wall (`b`) up there, not here."""
    area = scene.get("area", {})
    rings = [area.get("outer", [])] + list(area.get("holes", [])) if isinstance(area, dict) else []
    edges = [(*ring[i], *ring[(i + 1) % len(ring)]) for ring in rings for i in range(len(ring))]
    return np.asarray(edges, dtype=float).reshape(-1, 4)


def _ends_off_walls(a, b, walls: np.ndarray) -> float:
    """How far the farther end of the line a–b lies from the nearest wall (as
    `crates/crowd/src/exits.rs`' `ends_off_walls`)."""
    if len(walls) == 0:
        return np.inf
    p0, d = walls[:, :2], walls[:, 2:] - walls[:, :2]
    far = 0.0
    for p in (np.asarray(a, dtype=float), np.asarray(b, dtype=float)):
        length2 = np.maximum((d * d).sum(axis=1), 1e-300)
        s = np.clip(((p - p0) * d).sum(axis=1) / length2, 0.0, 1.0)
        far = max(far, float(np.hypot(*(p0 + s[:, None] * d - p).T).min()))
    return far


def exit_line(scene: dict, index: int = 0, walls: np.ndarray | None = None
              ) -> tuple[tuple[float, float], tuple[float, float]]:
    """A measurement line through exit `index`: its segment; for an area, the mid-line of its
    bounding box across the doorway it fills, the one whose ends lie nearer the walls (the
    door's jambs), and along the box's longer side when that does not tell: the line
    `moreau` closes the exit with (`crates/crowd/src/exits.rs`, `closure`). `walls` are the
    run file's `/walls`; by default those of the scene's rings. (The line along the longer
    side ran along the passage of a door deeper than wide, and PedPy counted nobody.)"""
    exit_ = scene["exits"][index]
    if "segment" in exit_:
        a, b = exit_["segment"]
        return (tuple(a), tuple(b))
    walls = walls_of(scene) if walls is None else np.asarray(walls, dtype=float).reshape(-1, 4)
    pts = np.asarray(exit_["area"], dtype=float)
    (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
    xm, ym = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    across_x = ((float(xm), float(y0)), (float(xm), float(y1)))
    across_y = ((float(x0), float(ym)), (float(x1), float(ym)))
    off_x, off_y = _ends_off_walls(*across_x, walls), _ends_off_walls(*across_y, walls)
    if off_x < off_y or (off_x == off_y and y1 - y0 >= x1 - x0):
        return across_x
    return across_y


def upstream_area(scene: dict, depth: float = 2.0, index: int = 0) -> list[tuple[float, float]]:
    """A `depth` × `depth` square in front of exit `index`, on the side people start from
    (the side of the first group's spawn region or positions; in a scene without groups, of
    the first source's area)."""
    (ax, ay), (bx, by) = exit_line(scene, index)
    mid = np.array([(ax + bx) / 2, (ay + by) / 2])
    tangent = np.array([bx - ax, by - ay])
    tangent /= np.linalg.norm(tangent)
    normal = np.array([-tangent[1], tangent[0]])
    starts = [g.get("spawn") or g.get("positions") for g in scene.get("groups", [])]
    starts += [s.get("area") for s in scene.get("sources", [])]
    if not any(starts):
        raise ValueError("upstream_area: the scene has no group or source to say which side "
                         "of the exit people come from")
    start = np.asarray(next(filter(None, starts)), dtype=float).mean(axis=0)
    if np.dot(start - mid, normal) < 0:
        normal = -normal
    h = depth / 2
    corners = [mid - h * tangent, mid + h * tangent, mid + h * tangent + depth * normal,
               mid - h * tangent + depth * normal]
    return [tuple(map(float, c)) for c in corners]


def min_gaps(run: Run) -> np.ndarray:
    """The smallest gap |x_i − x_j| − r_i − r_j between two people present, per frame
    (+inf with fewer than two people). Found with a k-d tree, independently of moreau: each
    person's nearest centre gives a pair whose gap `g` bounds the smallest from above, and
    every pair with a gap ≤ `g` has its centres within `g + 2 r_max`, the reach searched.
    (The reach was 2 r_max alone, which finds only pairs in contact: +inf in every frame
    where nobody touched.)"""
    out = np.full(len(run.time), np.inf)
    for k, frame in enumerate(run.positions):
        present = np.flatnonzero(~np.isnan(frame[:, 0]))
        if len(present) < 2:
            continue
        pts, radius = frame[present], run.radius[present]
        tree = cKDTree(pts)
        distance, nearest = tree.query(pts, k=2)
        bound = (distance[:, 1] - radius - radius[nearest[:, 1]]).min()
        reach = bound + 2.0 * radius.max()
        pairs = tree.query_pairs(reach * (1 + 1e-12) + 1e-12, output_type="ndarray")
        i, j = pairs[:, 0], pairs[:, 1]
        out[k] = (np.linalg.norm(pts[i] - pts[j], axis=1) - radius[i] - radius[j]).min()
    return out
