"""The territory a team patrols: a map's free cells, and where a robot's centre may be.

A cell is free by the same classes every map score uses (below 0.5); occupied and
unknown cells (the grey of a real ROS map) are neither watched nor entered. A robot is a
disc: its centre may be on a free cell whose distance to the nearest cell that is not
free is at least the robot's radius (the thesis is silent on how the radius enters the
map; this is the configuration-space reading of "cannot collide with obstacles").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import ConfigError, InputError
from ..grid import Grid
from ..io.rosmap import FREE, OCCUPIED, UNKNOWN, OccupancyMap

__all__ = ["Territory", "move_clear", "points_clear", "segment_clear"]


def segment_clear(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    clear: npt.NDArray[np.bool_],
    grid: Grid,
    step: float = 0.25,
) -> bool:
    """Every point of the segment lies inside the map on a ``clear`` cell (sampled every
    ``step`` cells)."""
    n = max(2, math.ceil(math.hypot(x1 - x0, y1 - y0) / (grid.resolution * step)) + 1)
    return _points_clear(x0, y0, x1, y1, np.linspace(0.0, 1.0, n), clear, grid)


def move_clear(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    clear: npt.NDArray[np.bool_],
    grid: Grid,
    step: float = 0.25,
) -> bool:
    """A robot's centre may move along the segment: both ends and the midpoints of
    ``step``-cell pieces of it lie inside the map on ``clear`` cells.

    Unlike :func:`segment_clear`, no sample falls on the corner a diagonal move between
    two cell centres crosses: such a move is the wave's diagonal step, which a path may
    take between two clear cells whatever the two cells beside the corner are (where
    the point on the corner would be read as one of them, arbitrarily).
    """
    n = max(1, math.ceil(math.hypot(x1 - x0, y1 - y0) / (grid.resolution * step)))
    ox, oy = grid.origin
    # Called for every robot's every step, and a few times more along a path: a kernel
    # rather than a dozen small numpy arrays.
    return bool(
        _move_clear(
            float(x0),
            float(y0),
            float(x1),
            float(y1),
            n,
            clear,
            float(ox),
            float(oy),
            float(grid.resolution),
        )
    )


def _points_clear(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    t: npt.NDArray[np.float64],
    clear: npt.NDArray[np.bool_],
    grid: Grid,
) -> bool:
    """The points at fractions ``t`` of the segment all lie inside the map on ``clear``
    cells."""
    return points_clear(x0 + t * (x1 - x0), y0 + t * (y1 - y0), clear, grid)


def points_clear(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    clear: npt.NDArray[np.bool_],
    grid: Grid,
) -> bool:
    """Whether every world point (``x``, ``y``; metres, 1-D arrays of one length) lies
    inside the map on a ``clear`` cell: ``grid.contains(r, c).all()`` and
    ``clear[r, c].all()`` for ``r, c = grid.world_to_cell(x, y)``, in one pass that
    stops at the first point off them (True for no points).

    Raises
    ------
    ValueError
        When ``x`` and ``y`` differ in size, or ``clear``'s shape is not
        ``grid.shape``.
    """
    xs = np.ascontiguousarray(x, dtype=np.float64).reshape(-1)
    ys = np.ascontiguousarray(y, dtype=np.float64).reshape(-1)
    if xs.shape != ys.shape:
        raise ValueError(f"points_clear: x has {xs.size} points, y has {ys.size}")
    if clear.shape != grid.shape:
        raise ValueError(f"points_clear: clear has shape {clear.shape}, the grid {grid.shape}")
    ox, oy = grid.origin
    # Called for each arc a car tries, several a step: a kernel rather than the half
    # dozen small numpy arrays of world_to_cell, contains and the lookup.
    return bool(
        _all_clear(
            xs,
            ys,
            clear,
            float(ox),
            float(oy),
            float(grid.resolution),
        )
    )


@nb.njit(cache=True)
def _cell_clear(
    x: float, y: float, clear: npt.NDArray[np.bool_], ox: float, oy: float, res: float
) -> bool:
    """The point (x, y) lies on a ``clear`` cell of the grid (the arithmetic of
    :meth:`~sonarmap.grid.Grid.world_to_cell`)."""
    rows, cols = clear.shape
    c = math.floor((x - ox) / res)
    r = rows - 1 - math.floor((y - oy) / res)
    return bool(0 <= r < rows and 0 <= c < cols and clear[r, c])


@nb.njit(cache=True)
def _all_clear(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    clear: npt.NDArray[np.bool_],
    ox: float,
    oy: float,
    res: float,
) -> bool:
    """Every point (``x[k]``, ``y[k]``) lies on a ``clear`` cell (:func:`_cell_clear`)."""
    for k in range(x.shape[0]):  # noqa: SIM110 -- numba compiles loops, not all()
        if not _cell_clear(x[k], y[k], clear, ox, oy, res):
            return False
    return True


@nb.njit(cache=True)
def _move_clear(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    n: int,
    clear: npt.NDArray[np.bool_],
    ox: float,
    oy: float,
    res: float,
) -> bool:
    """:func:`move_clear` with the segment cut into ``n`` pieces: both ends and the
    pieces' midpoints."""
    dx = x1 - x0
    dy = y1 - y0
    if not (_cell_clear(x0, y0, clear, ox, oy, res) and _cell_clear(x1, y1, clear, ox, oy, res)):
        return False
    for k in range(n):
        t = (k + 0.5) / n
        if not _cell_clear(x0 + t * dx, y0 + t * dy, clear, ox, oy, res):
            return False
    return True


@dataclass(frozen=True, eq=False)
class Territory:
    """A patrolled map.

    Attributes
    ----------
    grid : Grid
    free : ndarray of bool, shape grid.shape
        Cells to watch (the map's free class).
    clearance : ndarray of float, shape grid.shape
        Distance in metres from each cell's centre to the nearest cell that is not free
        (or to the map's edge).
    unknown : ndarray of bool, shape grid.shape, optional
        Cells the map marks unknown (most of their map cells are); None when the
        territory was not made from a map.
    """

    grid: Grid
    free: npt.NDArray[np.bool_]
    clearance: npt.NDArray[np.float64]
    unknown: npt.NDArray[np.bool_] | None = None

    @classmethod
    def from_map(cls, m: OccupancyMap, cell: float | None = None) -> Territory:
        """The territory of a map, optionally on coarser cells of about ``cell`` metres
        (a whole number of map cells; a coarse cell is free when most of its map cells
        are and none is occupied, so thin walls survive). A map with no free cell is an
        InputError."""
        classes = m.classes()
        free = classes == FREE
        unknown = classes == UNKNOWN
        grid = m.grid
        if cell is not None:
            if not (np.isfinite(cell) and cell > 0):
                raise ConfigError(f"cell size must be > 0 metres, got {cell}")
            k = max(1, round(cell / grid.resolution))
            if k > 1:
                rows = -(-free.shape[0] // k)
                cols = -(-free.shape[1] // k)
                padded = np.zeros((rows * k, cols * k))
                padded[: free.shape[0], : free.shape[1]] = free
                share = padded.reshape(rows, k, cols, k).mean(axis=(1, 3))
                hit = np.zeros((rows * k, cols * k), dtype=bool)
                hit[: free.shape[0], : free.shape[1]] = classes == OCCUPIED
                # Any occupied pixel closes the cell: a thin wall must stay a wall.
                free = (share > 0.5) & ~hit.reshape(rows, k, cols, k).any(axis=(1, 3))
                grey = np.zeros((rows * k, cols * k))
                grey[: unknown.shape[0], : unknown.shape[1]] = unknown
                unknown = grey.reshape(rows, k, cols, k).mean(axis=(1, 3)) > 0.5
                # Rows are counted from the top: the coarse grid keeps the top edge.
                top = grid.origin[1] + grid.rows * grid.resolution
                res = grid.resolution * k
                grid = Grid(
                    resolution=res, origin=(grid.origin[0], top - rows * res), shape=(rows, cols)
                )
        if not free.any():
            raise InputError("the map has no free cell to patrol")
        # The edge counts as an obstacle: pad with a ring of non-free cells.
        padded = np.pad(free, 1, constant_values=False)
        # Distance from a free centre to the nearest non-free centre, less half a cell:
        # the gap to that cell's edge.
        dist = ndimage.distance_transform_edt(padded)[1:-1, 1:-1] * grid.resolution
        clearance = np.where(free, dist - 0.5 * grid.resolution, 0.0)
        return cls(grid, free, clearance, unknown)

    def passable(self, radius: float) -> npt.NDArray[np.bool_]:
        """Cells where the centre of a disc of ``radius`` metres may be."""
        return self.free & (self.clearance >= radius)

    def cell_of(self, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[npt.NDArray[np.intp], ...]:
        """Row and column of world points (not clipped)."""
        r, c = self.grid.world_to_cell(x, y)
        return np.asarray(r, np.intp), np.asarray(c, np.intp)

    def inside(self, rows: npt.ArrayLike, cols: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        return self.grid.contains(rows, cols)
