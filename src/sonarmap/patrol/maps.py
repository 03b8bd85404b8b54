"""Built-in territories standing in for the thesis's lost figures (only their captions and
sizes survive), drawn here at the stated sizes and kinds, with start and semaphore files.

- ``open-field``: 100 x 88 m, no obstacles, the three starts of Tables 2-3;
- ``fig3-2``: 100 x 88 m with a few obstacles, the five starts of fig. 3.2;
- ``fig3-4``: 118 x 118 m with many obstacles (blocks on a jittered lattice);
- ``fig3-10``: 240 x 159 m of buildings with many narrow corridors, like a real site,
  with semaphores over the narrowest corridors.

Every obstacle layout is fixed (drawn from a fixed seed), so runs on these maps can be
compared across versions. Starts are in the thesis's format (decimetres from the
top-left corner, y down).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from ..files import atomic_write_text
from ..floorplan import FloorPlan
from ..io.rosmap import write_map
from .territory import Territory

__all__ = [
    "BUILTIN_MAPS",
    "BuiltinMap",
    "builtin_map",
    "builtin_territory",
    "write_builtin_maps",
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


@cache
def builtin_territory(name: str, cell: float) -> tuple[Territory, list[tuple[float, float, float]]]:
    """A built-in map drawn at 0.1 m as a territory on cells of about ``cell`` metres,
    with its starts (dm from the top-left, y down, heading); cached per process."""
    m = builtin_map(name)
    plan = m.plan.render(m.plan.grid(RESOLUTION))
    return Territory.from_map(plan, cell=cell), list(m.starts)


def write_builtin_maps(folder: Path) -> list[Path]:
    """Write every built-in map (``NAME.yaml`` + ``.pgm``), its start file
    (``NAME.starts.txt``) and, where it has any, its semaphores
    (``NAME.semaphores.txt``) into ``folder``."""
    written: list[Path] = []
    for name in BUILTIN_MAPS:
        m = builtin_map(name)
        grid = m.plan.grid(RESOLUTION)
        written += write_map(m.plan.render(grid), folder / name, exact=False)
        lines = [str(len(m.starts))] + [f"{x:g} {y:g} {phi:g}" for x, y, phi in m.starts]
        atomic_write_text(folder / f"{name}.starts.txt", "\n".join(lines) + "\n")
        written.append(folder / f"{name}.starts.txt")
        if m.semaphores:
            text = "\n".join(";".join(f"{x:g} {y:g}" for x, y in poly) for poly in m.semaphores)
            atomic_write_text(folder / f"{name}.semaphores.txt", text + "\n")
            written.append(folder / f"{name}.semaphores.txt")
    return written
