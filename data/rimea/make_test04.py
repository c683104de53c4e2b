"""Writes data/rimea/test04-fundamental-diagram.toml: RiMEA test 4 (the fundamental diagram)
as one scene of parallel corridors, one per density, each filled with disordered people at
exactly its density.

Random sequential placement (what a scene's `count` + `spawn` does) cannot reach 4–6 P/m²
with radius 0.2 m (it jams near a packing fraction of 0.55, i.e. 4.4 P/m²), so the positions
are written out: a triangular lattice at the corridor's density, melted by hard-disk Monte
Carlo moves (fixed seed) so that no lanes are left along the walking direction where the
density allows it. Rerun after changing a number below:

    .venv/bin/python data/rimea/make_test04.py
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
OUT = HERE / "test04-fundamental-diagram.toml"

DENSITIES = [0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]  # P/m², the guideline's list
WIDTH = 4.0  # m, each corridor (the guideline: 10 m)
WALL = 0.2  # m, the walls between corridors
BLOCK = 24.0  # m, the filled part of each corridor, x in [0, BLOCK]
LENGTH = 36.0  # m, x of the exit (nobody reaches it before the horizon)
RADIUS = 0.2  # m, the guideline's 40 cm body
SPEED = (1.2, 1.4)  # m/s, uniform: the guideline's "for example 1.2–1.4 m/s"
SWEEPS = 60  # Monte Carlo sweeps
MARGIN = 1e-3  # m, kept between disks so that positions rounded to 0.1 mm never overlap
SEED = 4


def lattice(n: int, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """At least n sites of a triangular lattice of centres filling [x0, x1] × [y0, y1]."""
    a = math.sqrt(2.0 * (x1 - x0) * (y1 - y0) / (math.sqrt(3.0) * n))
    rows = max(1, int((y1 - y0) / (a * math.sqrt(3.0) / 2.0)) + 1)
    while True:
        cols = math.ceil(n / rows)
        dx = (x1 - x0) / cols
        dy = (y1 - y0) / (rows - 1) if rows > 1 else 0.0
        if dx >= 2 * RADIUS + MARGIN and (rows == 1 or math.hypot(dx / 2, dy) >= 2 * RADIUS + MARGIN):
            break
        rows -= 1
    pts = [(x0 + dx * (c + 0.5 * (r % 2)) + 0.25 * dx, y0 + dy * r if rows > 1 else (y0 + y1) / 2)
           for r in range(rows) for c in range(cols)]
    return np.array(pts[:n])


def melt(p: np.ndarray, box, rng: np.random.Generator) -> np.ndarray:
    """Hard-disk Monte Carlo: random moves, rejected on overlap or leaving the box."""
    x0, x1, y0, y1 = box
    d2 = (2 * RADIUS + MARGIN) ** 2
    cell = 2 * RADIUS
    grid: dict[tuple[int, int], set[int]] = {}
    key = lambda q: (int(q[0] // cell), int(q[1] // cell))  # noqa: E731
    for i, q in enumerate(p):
        grid.setdefault(key(q), set()).add(i)
    step = 0.1
    for _ in range(SWEEPS):
        accepted = 0
        for i in rng.permutation(len(p)):
            q = p[i] + rng.uniform(-step, step, 2)
            if not (x0 <= q[0] <= x1 and y0 <= q[1] <= y1):
                continue
            cx, cy = key(q)
            ok = True
            for gx in (cx - 1, cx, cx + 1):
                for gy in (cy - 1, cy, cy + 1):
                    for j in grid.get((gx, gy), ()):
                        if j != i and (p[j, 0] - q[0]) ** 2 + (p[j, 1] - q[1]) ** 2 < d2:
                            ok = False
                            break
                    if not ok:
                        break
                if not ok:
                    break
            if ok:
                grid[key(p[i])].discard(i)
                p[i] = q
                grid.setdefault(key(q), set()).add(i)
                accepted += 1
        rate = accepted / len(p)  # keep the acceptance near one half
        step = min(0.5, max(1e-3, step * (1.2 if rate > 0.5 else 0.8)))
    return p


def main() -> None:
    rng = np.random.default_rng(SEED)
    pitch = WIDTH + WALL
    total_w = len(DENSITIES) * pitch - WALL
    lines = [
        "# RiMEA test 4 — the fundamental diagram (as we read RiMEA 4.1.1).",
        "# The guideline: a corridor 1000 m long and 10 m wide, filled at 0.5, 1, 2, 3, 4, 5 and",
        "# 6 P/m² with free walking speeds as equal as possible (e.g. 1.2–1.4 m/s); the mean speed",
        "# in a 2 m × 2 m measuring area over 60 s (the first 10 s ignored as transient), compared",
        "# with an empirical fundamental diagram; also a single-file variant.",
        f"# Our choice: {len(DENSITIES)} parallel corridors, {WIDTH:g} m wide, separated by {WALL:g} m walls,",
        f"# corridor k filled at DENSITIES[k] P/m² over x in [0, {BLOCK:g}] (written out by make_test04.py:",
        "# a triangular lattice melted by hard-disk Monte Carlo), radius 0.2 m, speed uniform in",
        f"# [{SPEED[0]:g}, {SPEED[1]:g}] m/s, everyone walking +x to the exit at x = {LENGTH:g}; no periodic",
        "# boundary, so the three 2 m × 2 m measuring areas (mid-width, x in [11, 13], the main",
        "# one, and [15, 17], [19, 21], the controls) are read while the filled block passes over",
        "# them: t in [1, 8] s (tests/python/test_rimea.py). The single-file variant is not run.",
        f"# Densities by corridor, from y = 0 up: {DENSITIES}.",
        "# GENERATED by data/rimea/make_test04.py — edit that file, not this one.",
        'name = "rimea-04-fundamental-diagram"',
        f"seed = {SEED}",
        "",
        "[area]",
        f"outer = [[-1.0, 0.0], [{LENGTH + 2:g}, 0.0], [{LENGTH + 2:g}, {total_w:g}], [-1.0, {total_w:g}]]",
        "holes = [",
    ]
    for k in range(1, len(DENSITIES)):
        y0 = k * pitch - WALL
        lines.append(f"  [[-0.5, {y0:g}], [{LENGTH + 1:g}, {y0:g}], [{LENGTH + 1:g}, {y0 + WALL:g}], "
                     f"[-0.5, {y0 + WALL:g}]],")
    lines += [
        "]",
        "",
        "[[exits]]",
        'name = "end"',
        f"area = [[{LENGTH:g}, 0.0], [{LENGTH + 2:g}, 0.0], [{LENGTH + 2:g}, {total_w:g}], [{LENGTH:g}, {total_w:g}]]",
        'action = "remove"',
    ]
    for k, rho in enumerate(DENSITIES):
        y0 = k * pitch
        n = round(rho * WIDTH * BLOCK)
        gap = 1e-3  # keep clear of the walls and the block's ends
        box = (RADIUS + gap, BLOCK - RADIUS - gap, y0 + RADIUS + gap, y0 + WIDTH - RADIUS - gap)
        p = np.round(melt(lattice(n, *box), box, rng), 4)
        d = np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        assert d.min() >= 2 * RADIUS, (rho, d.min())
        print(f"rho = {rho:g}: {n} people, smallest gap {d.min() - 2 * RADIUS:.4f} m")
        lines += [
            "",
            "[[groups]]",
            f'name = "rho-{rho:g}"',
            "positions = [",
            *(f"  [{x:.4f}, {y:.4f}]," for x, y in p),
            "]",
            f"radius = {RADIUS:g}",
            f"speed = {{ min = {SPEED[0]:g}, max = {SPEED[1]:g} }}",
            'destination = "end"',
        ]
    lines += [
        "",
        "[time]",
        "horizon = 8.0",
        "step = 0.05",
        "output_interval = 0.1",
        "",
        "[solver]",
        'kind = "auto"',
        "eps_kappa = 1e-3",
        "max_violation = 1e-6",
        "grid_cell = 0.1",
        "",
    ]
    OUT.write_text("\n".join(lines))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
