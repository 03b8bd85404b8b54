"""Built-in territories standing in for the thesis's lost figures (only their captions and
sizes survive), drawn here at the stated sizes and kinds, with start and semaphore files.

- ``open-field``: 100 x 88 m, no obstacles, the three starts of Tables 2-3;
- ``fig3-2``: 100 x 88 m with a few obstacles, the five starts of fig. 3.2;
- ``fig3-4``: 118 x 118 m with many obstacles (blocks on a jittered lattice);
- ``fig3-10``: 240 x 159 m of buildings with many narrow corridors, like a real site,
  with semaphores over the narrowest corridors.

Street sites (:func:`street_site`) are drawn from a seed: blocks with streets 3-6 m
wide and dead-end stubs, for the cars. As everywhere (:mod:`sonarmap.splits`), seeds
below 1000 are training sites and 1000 and above held out.

Every obstacle layout is fixed (drawn from a fixed seed), so runs on these maps can be
compared across versions. Starts are in the thesis's format (decimetres from the
top-left corner, y down).
"""

from __future__ import annotations

import itertools
from functools import cache
from pathlib import Path

import numpy as np

from ..builtins import BUILTIN_MAPS, RESOLUTION, BuiltinMap, builtin_map
from ..files import atomic_write_text
from ..floorplan import FloorPlan
from ..io.rosmap import write_map
from .territory import Territory

__all__ = [
    "BUILTIN_MAPS",
    "RESOLUTION",
    "BuiltinMap",
    "builtin_map",
    "builtin_territory",
    "street_site",
    "street_territory",
    "write_builtin_maps",
]


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


def street_site(seed: int, width: float = 90.0, height: float = 70.0) -> FloorPlan:
    """A site of blocks 10-30 m a side between streets 3-6 m wide, ``width`` x
    ``height`` metres, drawn from ``seed``; a third of the street segments are half
    closed by their block, leaving a dead-end stub a car has to back out of.

    The edge of the site is an obstacle, so the outermost streets run along it.
    """
    rng = np.random.default_rng(seed)

    def cuts(size: float) -> list[tuple[float, float]]:
        """Blocks along one axis: (start, end) pairs with a street before each."""
        out = []
        at = float(rng.uniform(3.0, 6.0))
        last = size - float(rng.uniform(3.0, 6.0))  # the street along the far edge
        while True:
            block = float(rng.uniform(10.0, 20.0))
            street = float(rng.uniform(3.0, 6.0))
            if at + block + street + 10.0 > last:
                # The last block reaches the far edge's street: no open ground is left.
                out.append((at, last))
                return out
            out.append((at, at + block))
            at += block + street

    plan = FloorPlan((0.0, 0.0, width, height))
    xs, ys = cuts(width), cuts(height)
    for x0, x1 in xs:
        for y0, y1 in ys:
            plan.box(x0, y0, x1, y1)
    # Half-closed segments: between horizontal neighbours, from the top or the bottom.
    for (_, xa), (xb, _) in itertools.pairwise(xs):
        for y0, y1 in ys:
            if rng.random() < 1 / 3:
                mid = (y0 + y1) / 2
                plan.box(xa, y0, xb, mid) if rng.random() < 0.5 else plan.box(xa, mid, xb, y1)
    for (_, ya), (yb, _) in itertools.pairwise(ys):
        for x0, x1 in xs:
            if rng.random() < 1 / 3:
                mid = (x0 + x1) / 2
                plan.box(x0, ya, mid, yb) if rng.random() < 0.5 else plan.box(mid, ya, x1, yb)
    return plan


@cache
def street_territory(seed: int, cell: float = 0.5) -> Territory:
    """:func:`street_site` of ``seed`` drawn at 0.1 m as a territory on cells of about
    ``cell`` metres; cached per process."""
    plan = street_site(seed)
    return Territory.from_map(plan.render(plan.grid(RESOLUTION)), cell=cell)
