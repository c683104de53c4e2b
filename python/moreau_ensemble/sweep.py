"""Sweep files: the base scene, fixed settings, varied parameters, seeds, and the scene of
every variant with its deterministic name."""

from __future__ import annotations

import copy
import itertools
import pathlib
import re
import tomllib
from dataclasses import dataclass, field

from moreau_run import exit_line


@dataclass(frozen=True)
class Variant:
    """One run: its name (also its directory), its parameter values and its scene (TOML)."""

    name: str
    values: dict
    seed: int
    scene: str


@dataclass
class Sweep:
    """A parsed sweep file."""

    path: pathlib.Path
    base: pathlib.Path
    seeds: list[int]
    fixed: dict = field(default_factory=dict)
    vary: dict = field(default_factory=dict)

    def variants(self) -> list[Variant]:
        """Every combination of the varied values with every seed, in a fixed order."""
        base = read_base(self.base)
        keys = list(self.vary)
        out = []
        for combo in itertools.product(*(self.vary[k] for k in keys)):
            values = dict(zip(keys, combo))
            for seed in self.seeds:
                scene = copy.deepcopy(base)
                for key, value in {**self.fixed, **values}.items():
                    apply(scene, key, value)
                scene["seed"] = int(base.get("seed", 0)) + seed
                parts = [f"{_label(k, key=True)}={_label(v)}" for k, v in values.items()]
                parts.append(f"seed={seed}")
                name = "_".join(parts)
                scene["name"] = f"{base.get('name', 'scene')}-{name}"
                out.append(Variant(name=name, values=values, seed=seed, scene=to_toml(scene)))
        return out


def read_base(path: pathlib.Path) -> dict:
    """The base scene at `path`, its relative file paths (`[area] wkt_file`, the only one a
    scene has) made absolute from the base's directory, as moreau reads them: the variants'
    scenes are written elsewhere (`runs/<variant>/scene.toml`), where they would not be found."""
    scene = tomllib.loads(path.read_text())
    area = scene.get("area")
    if isinstance(area, dict) and isinstance(area.get("wkt_file"), str):
        area["wkt_file"] = str((path.parent / area["wkt_file"]).resolve())
    return scene


def _label(value, key: bool = False) -> str:
    """`value` as part of a directory name: letters, digits and `.+-` only (and `_` in a key),
    so no `/`, and no name is `.` or `..`; at most 60 characters."""
    allowed = r"[^A-Za-z0-9._+-]" if key else r"[^A-Za-z0-9.+-]"
    text = re.sub(allowed, "-", str(value))[:60]
    return "-" if set(text) <= {"."} else text


def _check(path: pathlib.Path, sweep: Sweep) -> None:
    """Applies every `set` and `vary` value to the base scene, as the runs will, so that a bad
    key or value is an error naming it before any run starts; and checks that the variants'
    directory names are distinct."""
    try:
        base = read_base(sweep.base)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise ValueError(f"{path}: base = {str(sweep.base)!r}: not a scene file (TOML): {e}") from e
    entries = [("set", k, v) for k, v in sweep.fixed.items()]
    entries += [("vary", k, v) for k, values in sweep.vary.items() for v in values]
    for table, key, value in entries:
        scene = copy.deepcopy(base)
        try:
            apply(scene, key, value)
            to_toml(scene)
        except (KeyError, IndexError, ValueError, TypeError, AttributeError) as e:
            kind = type(e).__name__
            raise ValueError(f"{path}: {table}.{key!s} = {value!r} does not apply to the base "
                             f"scene: {kind}: {e}") from e
    # Each variant's whole scene as the runs will read it (the values together: one may need
    # another), once for each combination of values (the seed changes nothing else).
    validate = _scene_validator()
    checked = set()
    for variant in sweep.variants():
        combination = tuple(sorted(variant.values.items(), key=lambda kv: kv[0]))
        if repr(combination) in checked:
            continue
        checked.add(repr(combination))
        try:
            validate(variant.scene)
        except ValueError as e:
            given = {**sweep.fixed, **variant.values}
            raise ValueError(f"{path}: the scene with {given} is not a scene: {e}") from e
    names: dict[str, dict] = {}
    for variant in sweep.variants():
        if variant.name in names:
            raise ValueError(f"{path}: the variants {names[variant.name]} and {variant.values} "
                             f"get the same directory name {variant.name!r}")
        names[variant.name] = variant.values


def _scene_validator():
    """A check that a variant's scene text has the scene format's keys and types, by moreau's
    own reader where the `moreau` module is installed (a key misspelt, `groups.0.cont`, was
    written into every variant and failed each run). Only the format: a value the scene's
    rules refuse (a radius of −0.2) is that variant's failure, recorded as such while the
    others run."""
    try:
        import moreau
    except ImportError:
        return lambda text: None

    def validate(text: str) -> None:
        try:
            moreau.Scene.from_toml(text)
        except moreau.SceneError as e:
            # A value out of its domain carries the field it is at; a key or type the format
            # does not have (the parser's error) carries none.
            if getattr(e, "field", None) is None:
                raise ValueError(str(e)) from e
    return validate


def load_sweep(path) -> Sweep:
    """Reads a sweep file; errors name the key at fault and its value."""
    path = pathlib.Path(path)
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not TOML: {e}") from e
    unknown = set(spec) - {"base", "seeds", "set", "vary"}
    if unknown:
        raise ValueError(f"{path}: unknown keys {sorted(unknown)} (base, seeds, set, vary)")
    if "base" not in spec:
        raise ValueError(f"{path}: 'base' (the scene file) is missing")
    if not isinstance(spec["base"], str):
        raise ValueError(f"{path}: base = {spec['base']!r}: must be the scene file's path (a "
                         f"string)")
    base = (path.parent / spec["base"]).resolve()
    if not base.is_file():
        raise ValueError(f"{path}: base = {spec['base']!r}: no such scene file ({base})")
    seeds = spec.get("seeds", 1)
    if _is_int(seeds) and seeds >= 1:
        seeds = list(range(seeds))
    elif not (isinstance(seeds, list) and seeds and all(_is_int(s) and s >= 0 for s in seeds)):
        raise ValueError(f"{path}: seeds = {seeds!r}: must be a count (an integer ≥ 1) or a "
                         f"non-empty list of seeds (integers ≥ 0)")
    fixed = spec.get("set", {})
    vary = spec.get("vary", {})
    for key, table in (("set", fixed), ("vary", vary)):
        if not isinstance(table, dict):
            raise ValueError(f"{path}: {key} = {table!r}: must be a table")
    for key, values in vary.items():
        if not isinstance(values, list) or not values:
            raise ValueError(f"{path}: vary.{key} must be a non-empty list, got {values!r}")
    sweep = Sweep(path=path, base=base, seeds=seeds, fixed=fixed, vary=vary)
    _check(path, sweep)
    return sweep


def _is_int(value) -> bool:
    """An integer of TOML's, not a boolean (Python's bool is an int)."""
    return isinstance(value, int) and not isinstance(value, bool)


def apply(scene: dict, key: str, value) -> None:
    """Sets `key` in the scene: a dotted path (`time.step`, `groups.0.count`), or
    `door_width`, which widens or narrows the first exit's door (see `set_door_width`)."""
    if key == "door_width":
        set_door_width(scene, float(value))
        return
    node = scene
    parts = key.split(".")
    if any(not p for p in parts):
        raise ValueError(f"{key!r}: an empty part in the dotted key")

    def index(node: list, part: str) -> int:
        if not part.isdigit() or int(part) >= len(node):
            raise IndexError(f"{part!r} is not an index of a list of {len(node)}")
        return int(part)

    for part in parts[:-1]:
        if isinstance(node, list):
            node = node[index(node, part)]
        elif isinstance(node, dict):
            node = node.setdefault(part, {})
        else:
            raise TypeError(f"{part!r}: {node!r} has no parts")
    last = parts[-1]
    if isinstance(node, list):
        node[index(node, last)] = value
    elif isinstance(node, dict):
        node[last] = value
    else:
        raise TypeError(f"{last!r}: {node!r} has no parts")


def set_door_width(scene: dict, width: float) -> None:
    """Resizes the first exit, an axis-aligned rectangle in a gap of the walls: along the
    wall (the side its measurement line `moreau_run.exit_line` runs along, from jamb to jamb),
    every coordinate equal to the door's ends (in the exit's area, and the vertices of the
    walkable outline beside it: its jambs) moves to `centre ± width/2`. (Every outline vertex
    at those coordinates moved until session 38: the other door of room-two-exits, at the
    same height, narrowed too. And the width was the box's longer side: a door deeper than
    wide, 1 m in a 2 m thick wall, had its depth changed.)"""
    if not width > 0 or width != width or width == float("inf"):
        raise ValueError(f"door_width = {width}: must be finite and > 0")
    area = scene["exits"][0].get("area")
    if not area:
        raise ValueError("door_width needs the first exit to be an area")
    (x0, _), (x1, _) = exit_line(scene, 0)
    axis = 1 if x0 == x1 else 0
    lo, hi = min(p[axis] for p in area), max(p[axis] for p in area)
    centre = 0.5 * (lo + hi)
    new = {lo: centre - width / 2, hi: centre + width / 2}
    other = 1 - axis
    depth = (min(p[other] for p in area), max(p[other] for p in area))
    for polygon in [area, scene["area"]["outer"], *scene["area"].get("holes", [])]:
        for point in polygon:
            if point[axis] in new and depth[0] <= point[other] <= depth[1]:
                point[axis] = new[point[axis]]


def to_toml(value: dict) -> str:
    """A small TOML writer for scenes (tables, arrays of tables, numbers, strings, lists)."""
    lines: list[str] = []

    def scalar(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(scalar(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {scalar(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"cannot write {v!r} as TOML")

    def table(prefix: str, d: dict) -> None:
        simple = {k: v for k, v in d.items() if not _is_table(v) and not _is_table_array(v)}
        for k, v in simple.items():
            lines.append(f"{k} = {scalar(v)}")
        for k, v in d.items():
            name = f"{prefix}.{k}" if prefix else k
            if _is_table(v):
                lines.append(f"\n[{name}]")
                table(name, v)
            elif _is_table_array(v):
                for item in v:
                    lines.append(f"\n[[{name}]]")
                    table(name, item)

    table("", value)
    return "\n".join(lines) + "\n"


def _is_table(v) -> bool:
    return isinstance(v, dict) and any(isinstance(x, (dict, list)) for x in v.values()) or (
        isinstance(v, dict) and len(v) > 2)


def _is_table_array(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)
