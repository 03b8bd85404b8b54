"""Floor plans as geometry: rectangles of obstacle drawn and cleared in order.

A plan is kept in world coordinates (metres), so one plan renders on any grid: on the
mapping grid it is the truth the maps are scored against, and at 1 cm it is the
geometry the acoustic simulator casts its rays through. A cell is occupied when its
centre lies inside an obstacle after every operation; walls need not fall on cell
boundaries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .grid import Grid
from .io.rosmap import OccupancyMap

__all__ = ["FloorPlan"]


@dataclass
class FloorPlan:
    """A floor plan over ``bounds`` = (xmin, ymin, xmax, ymax), metres.

    Examples
    --------
    >>> plan = FloorPlan((0.0, 0.0, 1.0, 0.5))
    >>> plan.box(0.0, 0.0, 1.0, 0.1)
    >>> plan.clear(0.4, 0.0, 0.6, 0.1)
    >>> plan.render(Grid(0.1, (0.0, 0.0), (5, 10))).occupancy[-1].tolist()
    [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]
    """

    bounds: tuple[float, float, float, float]
    #: (x0, y0, x1, y1, value): value 1 draws obstacle, 0 clears it.
    ops: list[tuple[float, float, float, float, float]] = field(default_factory=list)

    def box(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """Draw an obstacle rectangle."""
        self.ops.append((x0, y0, x1, y1, 1.0))

    def clear(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """Clear a rectangle (an opening)."""
        self.ops.append((x0, y0, x1, y1, 0.0))

    def border(self, t: float) -> None:
        """Walls ``t`` thick along the four edges of the bounds."""
        xmin, ymin, xmax, ymax = self.bounds
        self.box(xmin, ymin, xmax, ymin + t)
        self.box(xmin, ymax - t, xmax, ymax)
        self.box(xmin, ymin, xmin + t, ymax)
        self.box(xmax - t, ymin, xmax, ymax)

    def grid(self, resolution: float) -> Grid:
        """The grid of ``resolution`` m covering the bounds."""
        return Grid.from_bounds(*self.bounds, resolution)

    def render(self, grid: Grid) -> OccupancyMap:
        """The plan on ``grid``: 1 where a cell's centre is inside an obstacle, else 0."""
        occ = np.zeros(grid.shape, dtype=np.float32)
        for x0, y0, x1, y1, value in self.ops:
            rows, cols = _cells(grid, x0, y0, x1, y1)
            occ[rows, cols] = value
        return OccupancyMap(grid, occ)


def _cells(grid: Grid, x0: float, y0: float, x1: float, y1: float) -> tuple[slice, slice]:
    """Rows and columns of the cells whose centres lie in [x0, x1) x [y0, y1)."""
    h = grid.resolution
    ox, oy = grid.origin
    # Centre of column c is ox + (c + 0.5) h; the slack keeps edges that fall on a
    # centre from flipping with rounding.
    c0 = max(0, math.ceil((x0 - ox) / h - 0.5 - 1e-9))
    c1 = min(grid.cols, math.ceil((x1 - ox) / h - 0.5 - 1e-9))
    i0 = max(0, math.ceil((y0 - oy) / h - 0.5 - 1e-9))
    i1 = min(grid.rows, math.ceil((y1 - oy) / h - 0.5 - 1e-9))
    return slice(grid.rows - max(i1, i0), grid.rows - i0), slice(c0, max(c1, c0))
