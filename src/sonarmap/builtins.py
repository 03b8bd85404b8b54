"""Built-in maps by name, for every command's ``--map``.

The patrol territories of thesis 002's chapter 3 (``open-field``, ``fig3-2``,
``fig3-4``, ``fig3-10``, drawn at 0.1 m with their start positions and semaphores) and
the team floor plans (``office``, ``building:SEED``). A foundation module: it imports
the floor-plan tools only, so that :mod:`sonarmap.patrol` and :mod:`sonarmap.team` both
use it and neither imports the other for its maps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .floorplan import FloorPlan, random_building

if TYPE_CHECKING:
    from .io.rosmap import OccupancyMap

__all__ = [
    "BUILTIN_MAPS",
    "BUILTIN_NAMES",
    "RESOLUTION",
    "BuiltinMap",
    "builtin_map",
    "builtin_plan",
    "is_builtin",
]

#: Metres per pixel of the written maps (the thesis's 10 cm).
RESOLUTION = 0.1


@dataclass
class BuiltinMap:
    """A territory with its start positions (dm from the top-left, y down, heading) and
    semaphore polygons (dm, same frame)."""

    name: str
    plan: FloorPlan
    starts: Sequence[tuple[float, float, float]]
    semaphores: Sequence[Sequence[tuple[float, float]]]


def _open_field() -> BuiltinMap:
    plan = FloorPlan((0.0, 0.0, 100.0, 88.0))
    return BuiltinMap("open-field", plan, [(480, 110, 0), (660, 640, 0), (205, 310, 0)], [])


def _fig32() -> BuiltinMap:
    plan = FloorPlan((0.0, 0.0, 100.0, 88.0))
    # A few buildings, kept clear of the five starts.
    for x0, y0, w, h in ((30, 55, 12, 8), (55, 20, 8, 20), (20, 15, 15, 6), (75, 50, 6, 14)):
        plan.box(x0, y0, x0 + w, y0 + h)
    starts = [(160, 100, 0), (160, 730, 0), (830, 410, 0), (620, 100, 0), (620, 730, 0)]
    return BuiltinMap("fig3-2", plan, starts, [])


def _fig34() -> BuiltinMap:
    plan = FloorPlan((0.0, 0.0, 118.0, 118.0))
    rng = np.random.default_rng(34)
    # Blocks on a 14 m lattice, jittered, 4-9 m a side: passages of 3 m and more.
    for gx in range(6, 112, 14):
        for gy in range(6, 112, 14):
            if rng.random() < 0.2:
                continue
            w, h = rng.uniform(4, 9, 2)
            x0 = gx + rng.uniform(0, 10 - w + 0.1)
            y0 = gy + rng.uniform(0, 10 - h + 0.1)
            plan.box(x0, y0, x0 + w, y0 + h)
    starts = [(30, 30, 0), (1150, 30, 0), (30, 1150, 0), (1150, 1150, 0), (600, 580, 0)]
    return BuiltinMap("fig3-4", plan, starts, [])


def _fig310() -> BuiltinMap:
    plan = FloorPlan((0.0, 0.0, 240.0, 159.0))
    # Rows of buildings separated by streets; between neighbours, narrow lanes of 3.5 m.
    semaphores: list[list[tuple[float, float]]] = []
    top = 159.0
    for row, (y0, y1) in enumerate(((8.0, 42.0), (50.0, 84.0), (92.0, 118.0), (126.0, 151.0))):
        x = 6.0
        k = 0
        while x < 230.0:
            width = 18.0 + 9.0 * ((row * 7 + k * 3) % 4)
            x1 = min(x + width, 234.0)
            plan.box(x, y0, x1, y1)
            lane = 3.5
            if x1 + lane < 234.0 and (row + k) % 2 == 0:
                # A lane through the block row: narrow, so a semaphore guards it.
                semaphores.append(
                    [
                        (x1 * 10, (top - y0) * 10),
                        ((x1 + lane) * 10, (top - y0) * 10),
                        ((x1 + lane) * 10, (top - y1) * 10),
                        (x1 * 10, (top - y1) * 10),
                    ]
                )
                x = x1 + lane
            else:
                x = x1 + 8.0  # a wide gap
            k += 1
    starts = [(30, 40, 0), (2370, 40, 0), (30, 1550, 0), (2370, 1550, 0), (1200, 1130, 0)]
    return BuiltinMap("fig3-10", plan, starts, semaphores)


BUILTIN_MAPS = {"open-field": _open_field, "fig3-2": _fig32, "fig3-4": _fig34, "fig3-10": _fig310}


def builtin_map(name: str) -> BuiltinMap:
    """One of :data:`BUILTIN_MAPS` by name."""
    return BUILTIN_MAPS[name]()


#: Every built-in map's name, as ``--map`` takes it.
BUILTIN_NAMES = (*BUILTIN_MAPS, "office", "building:SEED")


def is_builtin(name: str) -> bool:
    """Whether ``name`` names a built-in map (``building:`` followed by any text counts,
    so that a bad seed is reported as such)."""
    return name in BUILTIN_MAPS or name == "office" or name.startswith("building:")


def builtin_plan(name: str) -> OccupancyMap:
    """A built-in map at 0.1 m by name.

    Parameters
    ----------
    name : str
        One of :data:`BUILTIN_NAMES`: a patrol territory, ``"office"`` (20 m x 20 m,
        eight rooms off a corridor, :func:`~sonarmap.scenarios.office`) or
        ``"building:SEED"`` (a random building, :func:`~sonarmap.floorplan.random_building`
        of that seed, a whole number).

    Returns
    -------
    OccupancyMap
        The map.

    Raises
    ------
    InputError
        Any other name, listing the built-ins.
    """
    if name in BUILTIN_MAPS:
        m = builtin_map(name)
        return m.plan.render(m.plan.grid(RESOLUTION))
    if name == "office":
        # Imported here: the scenario factory is large and only this plan needs it.
        from .scenarios import office
        from .sensors import Noise

        return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    kind, _, seed = name.partition(":")
    if kind == "building" and seed.isdigit():
        fp = random_building(seed=int(seed))
        return fp.render(fp.grid(0.1))
    raise InputError(
        f"no such file, nor a built-in map; built-ins: {', '.join(BUILTIN_NAMES)}", path=name
    )
