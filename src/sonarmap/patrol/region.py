"""A user's territory mask: only the inside of a building, say, of a map whose outside
is drawn free.

Two formats:

- a map_server map (``.yaml`` and its image) in the map's frame, at any resolution: its
  free cells are inside. A territory cell is inside when the mask's cell under its
  centre is free; cells beyond the mask's extent are outside;
- a polygon file (any other suffix): one ``x y`` vertex a line, in metres in the map's
  frame (the frame of its YAML ``origin``), ``#`` comments; a blank line ends a
  polygon, so one file may hold several. A cell is inside when its centre is inside
  any polygon.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import InputError, quote
from ..files import read_text
from ..grid import Grid
from ..io.rosmap import FREE, read_map

__all__ = ["polygon_mask", "read_polygons", "read_region"]


def read_polygons(path: str | Path) -> list[npt.NDArray[np.float64]]:
    """The polygons of a polygon file, each (K, 2) in metres, K >= 3.

    Raises
    ------
    InputError
        Naming the file and line: unreadable, not two finite numbers, a polygon of
        fewer than 3 vertices, no polygon at all.
    """
    p = Path(path)
    lines = read_text(p, "territory file").splitlines()
    polygons: list[npt.NDArray[np.float64]] = []
    current: list[tuple[float, float]] = []
    start = 0

    def close(line: int) -> None:
        if not current:
            return
        if len(current) < 3:
            raise InputError(
                f"a polygon needs at least 3 vertices, got {len(current)}", path=p, line=line
            )
        polygons.append(np.array(current, dtype=np.float64))
        current.clear()

    for number, raw in enumerate(lines, start=1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            close(start)
            continue
        if not current:
            start = number
        parts = text.replace(",", " ").split()
        try:
            x, y = (float(v) for v in parts)
        except ValueError:
            raise InputError(
                f"expected 'x y' in metres, got {quote(raw.strip())}", path=p, line=number
            ) from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputError(
                f"expected finite numbers, got {quote(raw.strip())}", path=p, line=number
            )
        current.append((x, y))
    close(start)
    if not polygons:
        raise InputError("the territory file holds no polygon", path=p)
    return polygons


def polygon_mask(vertices: npt.NDArray[np.float64], grid: Grid) -> npt.NDArray[np.bool_]:
    """The cells of ``grid`` whose centres lie inside a polygon of (K, 2) world
    vertices, metres."""
    # matplotlib is heavy to import and only this function needs it.
    from matplotlib.path import Path as Polygon

    cx, cy = grid.all_centres()
    inside = Polygon(vertices).contains_points(np.column_stack([cx.ravel(), cy.ravel()]))
    return np.asarray(inside.reshape(grid.shape), dtype=bool)


def read_region(path: str | Path, grid: Grid) -> npt.NDArray[np.bool_]:
    """The territory mask of a file (module notes for the formats) on ``grid``.

    Raises
    ------
    InputError
        Naming the file: unreadable or malformed, or a mask that covers no cell.
    """
    p = Path(path)
    inside = np.zeros(grid.shape, dtype=bool)
    if p.suffix.lower() in (".yaml", ".yml"):
        mask_map = read_map(p)
        r, c = mask_map.grid.world_to_cell(*grid.all_centres())
        ok = mask_map.grid.contains(r, c)
        inside[ok] = (mask_map.classes() == FREE)[r[ok], c[ok]]
    else:
        for poly in read_polygons(p):
            inside |= polygon_mask(poly, grid)
    if not inside.any():
        raise InputError("the territory mask covers no cell of the map", path=p)
    return inside
