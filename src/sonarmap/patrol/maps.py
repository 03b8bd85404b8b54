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

from functools import cache
from pathlib import Path

from ..builtins import BUILTIN_MAPS, RESOLUTION, BuiltinMap, builtin_map
from ..files import atomic_write_text
from ..io.rosmap import write_map
from .territory import Territory

__all__ = [
    "BUILTIN_MAPS",
    "RESOLUTION",
    "BuiltinMap",
    "builtin_map",
    "builtin_territory",
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
