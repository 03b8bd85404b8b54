"""What the path-finders other than the wave share: their call shape and the last
stretch to places beside walls.

A finder is built once per run from the static passable mask
(``Finder.build(passable, resolution)``) and then asked, every step, for the paths
from a robot's cell to every place (``finder.paths(start, target)``): the length
(metres, ``inf`` where no path exists) and the unit world vector (x east, y north) of
the path's first direction. Unlike the wave's first step, which is one of the 8 grid
directions, this is any direction, so the simulator uses it the way it uses
:func:`~sonarmap.patrol.paths.straight_paths`.

Places in ``target`` that the robot's centre may not occupy (free cells beside walls,
narrower gaps) are reached much as the wave reaches them: by a path over passable cells to
the passable cell nearest to the place (nearest along 8-connected steps over target
cells, without cutting corners), then a last stretch over target cells. They take that
cell's first direction, so they pull the robot towards where it can see them.

This differs from the wave in two ways, both confined to those places. The wave takes
the best of all the ways in, so its last stretch may run a long way along a wall inside
the band the robot cannot enter; here it comes straight in from the nearest passable
cell, which can be longer (on the built-in ``fig3-2`` map, up to 30 % for a place along
a building's far wall). And a place whose nearest passable cell the robot cannot reach
gets no path, even if a farther passable cell would have led there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Self

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from ..errors import InputError

__all__ = [
    "Fringe",
    "FringeCache",
    "PathFinder",
    "Paths",
    "check_start",
    "fringe",
    "unit_towards",
]

#: Lengths (metres), then the x and y components of the first direction.
Paths = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]


class PathFinder(Protocol):
    """The call shape every alternative to the wave follows."""

    @classmethod
    def build(cls, passable: npt.NDArray[np.bool_], resolution: float) -> Self:
        """Prepare for a static ``passable`` mask of cells ``resolution`` metres wide."""
        ...

    def paths(self, start: tuple[int, int], target: npt.NDArray[np.bool_]) -> Paths:
        """Lengths and first directions of the paths from ``start`` to every cell."""
        ...


def check_start(passable: npt.NDArray[np.bool_], start: tuple[int, int]) -> tuple[int, int]:
    """``start`` as ints; an InputError when it lies off the grid or on a cell the
    robot's centre may not occupy."""
    r0, c0 = int(start[0]), int(start[1])
    rows, cols = passable.shape
    if not (0 <= r0 < rows and 0 <= c0 < cols):
        raise InputError(f"path start {start} lies outside the {rows} x {cols} grid")
    if not passable[r0, c0]:
        raise InputError(f"path start {start} is not a passable cell")
    return r0, c0


def unit_towards(
    dr: npt.NDArray[np.float64], dc: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Unit world vectors (x, y) of grid offsets (rows, columns); 0 for a zero offset.

    Rows grow downwards, so a row offset of -1 points north (+y).
    """
    norm = np.hypot(dr, dc)
    safe = np.where(norm > 0, norm, 1.0)
    return np.where(norm > 0, dc / safe, 0.0), np.where(norm > 0, -dr / safe, 0.0)


@dataclass(frozen=True)
class Fringe:
    """Target cells off the passable mask, tied to the passable cell they are reached from.

    Attributes
    ----------
    cells : ndarray of intp
        Flat indices of the reachable target cells that are not passable.
    source : ndarray of intp
        Flat index of the passable cell each is reached from.
    extra : ndarray of float64
        Length in cells of the last stretch, from the source to the cell.
    """

    cells: npt.NDArray[np.intp]
    source: npt.NDArray[np.intp]
    extra: npt.NDArray[np.float64]

    def extend(
        self,
        dist: npt.NDArray[np.float64],
        ux: npt.NDArray[np.float64],
        uy: npt.NDArray[np.float64],
        start: tuple[int, int],
        resolution: float,
    ) -> None:
        """Fill the fringe cells of the (contiguous) grids ``dist`` (metres), ``ux`` and
        ``uy`` from their sources, in place."""
        d, x, y = dist.reshape(-1), ux.reshape(-1), uy.reshape(-1)
        d[self.cells] = d[self.source] + self.extra * resolution
        x[self.cells] = x[self.source]
        y[self.cells] = y[self.source]
        # Reached from the robot's own cell, which has no direction to hand on: head
        # straight for the place.
        cols = dist.shape[1]
        own = self.source == start[0] * cols + start[1]
        if own.any():
            cells = self.cells[own]
            x[cells], y[cells] = unit_towards(
                (cells // cols - start[0]).astype(np.float64),
                (cells % cols - start[1]).astype(np.float64),
            )


def fringe(passable: npt.NDArray[np.bool_], target: npt.NDArray[np.bool_]) -> Fringe:
    """Tie every target cell that is not passable to its nearest passable cell.

    Nearest along the wave's moves: 8-connected steps over target cells, a diagonal
    only when both cells beside it are target cells, and never back onto a passable
    cell (so a path between passable cells stays on them).
    """
    tg = target | passable
    rows, cols = tg.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    src: list[npt.NDArray[np.intp]] = []
    dst: list[npt.NDArray[np.intp]] = []
    weight: list[npt.NDArray[np.float64]] = []
    into = tg & ~passable
    for dr, dc in ((0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1)):
        # Cell a steps to cell b = a + (dr, dc); both inside the grid.
        ra = slice(max(0, -dr), rows - max(0, dr))
        ca = slice(max(0, -dc), cols - max(0, dc))
        rb = slice(max(0, dr), rows - max(0, -dr))
        cb = slice(max(0, dc), cols - max(0, -dc))
        ok = tg[ra, ca] & into[rb, cb]
        if dr and dc:
            # The two cells the diagonal passes between: (ra, cb) and (rb, ca).
            ok &= tg[ra, cb] & tg[rb, ca]
        src.append(idx[ra, ca][ok])
        dst.append(idx[rb, cb][ok])
        weight.append(np.full(int(ok.sum()), math.sqrt(2.0) if dr and dc else 1.0))
    n = rows * cols
    graph = csr_matrix(
        (np.concatenate(weight), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)
    )
    sources = np.flatnonzero(passable)
    empty = np.empty(0, dtype=np.intp)
    if not len(sources) or not into.any():
        return Fringe(empty, empty, np.empty(0))
    dist, _pred, origin = dijkstra(graph, indices=sources, min_only=True, return_predecessors=True)
    cells = np.flatnonzero(into.ravel() & np.isfinite(dist))
    return Fringe(cells.astype(np.intp), origin[cells].astype(np.intp), dist[cells])


class FringeCache:
    """The fringe of the last target asked for: a run asks for the same one every step."""

    def __init__(self) -> None:
        self._key = b""
        self._fringe: Fringe | None = None

    def get(self, passable: npt.NDArray[np.bool_], target: npt.NDArray[np.bool_]) -> Fringe:
        """The :func:`fringe` of ``target`` on ``passable`` (a static mask)."""
        key = np.packbits(target).tobytes() + str(target.shape).encode()
        if self._fringe is None or key != self._key:
            self._key, self._fringe = key, fringe(passable, target)
        return self._fringe
