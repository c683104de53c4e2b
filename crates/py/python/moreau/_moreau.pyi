"""Type stubs of the extension module moreau._moreau (crates/py/src)."""

from __future__ import annotations

import os
from typing import Any, Callable, TypedDict

import numpy as np
import numpy.typing as npt

__version__: str

class SceneError(ValueError):
    """A scene that cannot be read or is invalid; the message names the field and the value
    (as ``moreau run`` says it). ``field`` and ``value`` are ``None`` where no value is at
    fault (a text that does not parse as a scene: a misspelt or missing key); ``reason`` is
    then the parser's message, or ``None`` where there is none. From ``Scene.from_dict``,
    ``field`` names the dict's key (``groups[0].radius``) and ``value`` its value, or
    ``field`` the table a key is missing from."""

    field: str | None
    value: str | None
    reason: str | None

class Timings(TypedDict):
    predict: float
    assemble: float
    solve: float
    solve_analyse: float
    solve_factorize: float
    verify: float
    total: float

class StepReport(TypedDict):
    """One step: ``t`` at its end, ``mu`` its size (s), the certified ``eps`` and its target
    ``eps_target`` (m²), ``violation`` (m), solver ``iterations``, constraints ``assembled``
    and ``active``, ``redone``/``rejected`` trials, ``local_error`` (m: the adaptive step's error
    estimate, ``None`` for fixed steps), the ``solver`` that answered, ``status``, ``timings``
    (s)."""

    step: int
    t: float
    mu: float
    eps: float
    eps_target: float
    violation: float
    iterations: int
    assembled: int
    active: int
    redone: int
    rejected: int
    local_error: float | None
    solver: str
    status: str
    timings: Timings

# "lambda" is a keyword, hence the functional form.
Contacts = TypedDict(
    "Contacts",
    {
        "kind": npt.NDArray[np.uint8],
        "a": npt.NDArray[np.uint32],
        "b": npt.NDArray[np.uint32],
        "lambda": npt.NDArray[np.float64],
    },
)

class Scene:
    """A validated crowd scene (the TOML of ``data/scenes/``). Immutable."""

    @staticmethod
    def from_file(path: str | os.PathLike[str]) -> Scene: ...
    @staticmethod
    def from_toml(text: str, origin: str = "<string>") -> Scene: ...
    @staticmethod
    def from_dict(d: dict[str, Any]) -> Scene: ...
    def with_area(self, area: Any | str) -> Scene:
        """This scene with the walkable area of a shapely ``Polygon`` or WKT string."""
    def to_toml(self) -> str: ...
    def to_dict(self) -> dict[str, Any]: ...
    @property
    def name(self) -> str: ...
    @property
    def wkt(self) -> str: ...
    @property
    def horizon(self) -> float: ...
    @property
    def output_interval(self) -> float: ...
    @property
    def exits(self) -> list[str]: ...
    def __eq__(self, other: object) -> bool: ...
    def __hash__(self) -> int: ...

class Simulation:
    """A crowd run in this process; stepping releases the GIL. Pickles as scene + state."""

    def __init__(self, scene: Scene | str | os.PathLike[str], record: bool = False) -> None: ...
    def step(self) -> StepReport:
        """One step of the scene's stepping, as ``advance_to`` and ``moreau run`` take it."""
    def advance_to(self, t: float) -> None:
        """Steps to time ``t`` (s), the last step shortened to land on it (GIL released).
        Raises ``SceneError`` for a ``t`` before the current time, not finite, or more than
        10⁹ of the scene's longest steps away. Adaptive steps that miss ``time.tol`` (a step at
        the smallest, 10⁻⁶ s, is accepted whatever its error) give one ``RuntimeWarning`` a
        simulation, from ``advance_to`` or ``step``."""
    def run(self) -> None:
        """``advance_to(scene.horizon)``."""
    @property
    def scene(self) -> Scene: ...
    @property
    def time(self) -> float: ...
    @property
    def steps(self) -> int: ...
    @property
    def positions(self) -> npt.NDArray[np.float64]:
        """(n, 2) positions of the people present (m), rows in the order of ``ids``."""
    @property
    def velocities(self) -> npt.NDArray[np.float64]:
        """(n, 2) velocities over the last step, (q_after − q_before)/μ (m/s); NaN before
        the first step and after ``restore``."""
    @property
    def radii(self) -> npt.NDArray[np.float64]: ...
    @property
    def ids(self) -> npt.NDArray[np.uint32]: ...
    @property
    def total_people(self) -> int: ...
    @property
    def last_report(self) -> StepReport | None: ...
    @property
    def speed_factor(self) -> float: ...
    def exit_records(self) -> list[tuple[int, int, float]]:
        """``(id, exit index, t)`` of everyone who passed an exit, in order."""
    def source_tallies(self) -> list[tuple[str, int, int]]:
        """``(name, due, entered)`` of each inflow source: the people due by now and those who
        entered; where they differ, people wait for room in the source's area."""
    def contacts(self) -> Contacts:
        """The last step's contact forces: ``kind`` (0 person–person, 1 person–wall, 2
        person–moving wall), ``a``, ``b`` (ids; for a wall its row in the run file's
        ``/walls``, for a moving wall its column in ``/frames/moving_walls``), ``lambda``
        (m/s)."""
    def desired_velocities(self) -> npt.NDArray[np.float64]: ...
    def state(self) -> bytes: ...
    def restore(self, state: bytes) -> None: ...
    def set_speed_factor(self, factor: float) -> None:
        """Raises ``ValueError`` for NaN, infinite or negative factors (nothing changes)."""
    def set_exit_open(self, exit: str | int, open: bool) -> None: ...
    def exits_open(self) -> list[bool]: ...
    def remove_people_in(self, polygon: Any | str) -> int:
        """Removes the people whose centre is inside a shapely polygon or WKT; returns how many.
        Anything else is a TypeError, WKT that does not parse a ValueError."""
    def recorded_frames(
        self,
    ) -> tuple[
        npt.NDArray[np.int64],
        npt.NDArray[np.float64],
        npt.NDArray[np.int64],
        npt.NDArray[np.float64],
        npt.NDArray[np.float64],
    ]:
        """``(frame, t, id, x, y)`` of the frames kept with ``record=True``."""
    def __reduce__(self) -> tuple[Any, ...]: ...
    def __setstate__(self, state: bytes) -> None: ...

def run_to_file(
    scene: Scene | str | os.PathLike[str],
    output: str | os.PathLike[str],
    force: bool = False,
    command: str | None = None,
    progress: Callable[[float, int, int], None] | None = None,
) -> str: ...
