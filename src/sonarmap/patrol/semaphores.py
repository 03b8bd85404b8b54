"""Semaphores against crowding: marked areas (narrow tunnels, small rooms) that one
robot, or the robots that entered together, may hold at a time.

An empty semaphore is inactive. When robots enter it, their step's entrants own it and
its area becomes impassable on the path-finding map of every other robot that hears of
an owner (robots entering on the same step may all stay). It frees itself when its
owners have left; robots still inside then own it.

File format (the thesis's): one semaphore per line, its polygon's vertices as ``x y``
pairs separated by ``;`` (no spaces around it), in decimetres from the map's top-left
corner with y down, e.g. ``953 615;753 551;787 315;1063 97;1181 100;1181 241``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import InputError, quote
from ..files import read_text
from ..grid import Grid
from .region import polygon_mask

__all__ = ["Semaphores", "polygon_cells", "read_semaphores"]


def read_semaphores(path: str | Path, grid: Grid) -> list[npt.NDArray[np.bool_]]:
    """The cells of each semaphore of a file (cell centres inside the polygon).

    Raises
    ------
    InputError
        Naming the file (and line): a line that is not three or more finite ``x y``
        vertices, a polygon covering no cell, a file holding no polygon.
    """
    p = Path(path)
    lines = read_text(p, "semaphore file").splitlines()
    out = []
    for number, text in enumerate(lines, start=1):
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        try:
            xy = [tuple(float(v) for v in pair.split()) for pair in text.strip().split(";")]
        except ValueError:
            raise InputError(
                f"expected 'x y;x y;...', got {quote(text)}", path=p, line=number
            ) from None
        if not all(math.isfinite(c) for v in xy for c in v):
            raise InputError(f"expected finite numbers, got {quote(text)}", path=p, line=number)
        if any(len(v) != 2 for v in xy) or len(xy) < 3:
            raise InputError(
                f"a semaphore needs at least 3 'x y' vertices, got {quote(text)}",
                path=p,
                line=number,
            )
        mask = polygon_cells([(v[0], v[1]) for v in xy], grid)
        if not mask.any():
            raise InputError("the semaphore covers no cell of the map", path=p, line=number)
        out.append(mask)
    if not out:
        # Otherwise the run says no semaphore file was given, when it was.
        raise InputError("the semaphore file holds no polygon", path=p)
    return out


def polygon_cells(vertices_dm: Sequence[tuple[float, float]], grid: Grid) -> npt.NDArray[np.bool_]:
    """Cells whose centres lie inside a polygon given in decimetres from the map's
    top-left corner, y down (the thesis's frame)."""
    top = grid.origin[1] + grid.rows * grid.resolution
    world = np.array([(grid.origin[0] + x / 10.0, top - y / 10.0) for x, y in vertices_dm])
    return polygon_mask(world, grid)


class Semaphores:
    """The semaphores' state over a run."""

    def __init__(self, areas: list[npt.NDArray[np.bool_]]) -> None:
        self.areas = areas
        self.cells = [np.argwhere(a) for a in areas]
        self.owners: list[set[int]] = [set() for _ in areas]

    def update(self, rows: npt.NDArray[np.intp], cols: npt.NDArray[np.intp]) -> None:
        """After the robots moved to cells (rows, cols)."""
        for k, area in enumerate(self.areas):
            inside = {i for i in range(len(rows)) if area[rows[i], cols[i]]}
            kept = self.owners[k] & inside
            self.owners[k] = kept if kept else inside

    def _closed(self, robot: int, heard: npt.NDArray[np.bool_]) -> list[int]:
        """The active semaphores ``robot`` does not own whose owners it hears of."""
        return [
            k
            for k, owners in enumerate(self.owners)
            if owners and robot not in owners and any(heard[j] for j in owners)
        ]

    def closed_cells(self, robot: int, heard: npt.NDArray[np.bool_]) -> npt.NDArray[np.intp]:
        """As :meth:`closed_for`, as (row, column) pairs (K, 2)."""
        parts = [self.cells[k] for k in self._closed(robot, heard)]
        return np.concatenate(parts) if parts else np.empty((0, 2), dtype=np.intp)

    def closed_for(self, robot: int, heard: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_] | None:
        """Cells closed on ``robot``'s path-finding map: the active semaphores it does not
        own whose owners it hears of (None when there are none)."""
        closed = self._closed(robot, heard)
        if not closed:
            return None
        return np.asarray(np.logical_or.reduce([self.areas[k] for k in closed]), dtype=bool)
