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

from .errors import ConfigError
from .grid import Grid
from .io.rosmap import OccupancyMap

__all__ = ["FloorPlan", "random_building"]


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


def random_building(
    width: float = 20.0,
    height: float = 16.0,
    *,
    seed: int = 0,
    wall: float = 0.1,
    min_room: float = 3.0,
    max_room: float = 7.0,
    door: tuple[float, float] = (0.8, 1.2),
    furniture: int = 1,
) -> FloorPlan:
    """A seeded floor plan of rooms: the outline split recursively (a BSP tree).

    Every split draws a wall across its rectangle with one door of a width drawn from
    ``door``, so each room connects to the rest. A rectangle splits across its longer
    side while that side exceeds ``max_room``, and stops once both halves could no
    longer reach ``min_room``. Each room then gets up to ``furniture`` boxes (0.4-1.2 m)
    against a wall away from its doors. Plans made with one seed are identical, so
    they can be named as training or held-out scenes.

    Examples
    --------
    >>> a = random_building(seed=3).render(Grid.from_bounds(0, 0, 20, 16, 0.1))
    >>> b = random_building(seed=3).render(Grid.from_bounds(0, 0, 20, 16, 0.1))
    >>> bool((a.occupancy == b.occupancy).all()), 0.03 < float(a.occupancy.mean()) < 0.2
    (True, True)
    """
    if not (width >= 2 * min_room and height >= min_room and min_room > door[1]):
        raise ConfigError(f"a {width} x {height} m building cannot hold rooms of {min_room} m")
    rng = np.random.default_rng(seed)
    plan = FloorPlan((0.0, 0.0, width, height))
    plan.border(wall)
    doors: list[tuple[float, float, float, float]] = []
    rooms: list[tuple[float, float, float, float]] = []
    todo = [(wall, wall, width - wall, height - wall)]
    while todo:
        x0, y0, x1, y1 = todo.pop()
        w, h = x1 - x0, y1 - y0
        across_x = w >= h
        span = w if across_x else h
        if span < 2 * min_room + wall or (span <= max_room and rng.random() < 0.5):
            rooms.append((x0, y0, x1, y1))
            continue
        cut = float(rng.uniform(min_room, span - min_room - wall))
        dw = float(rng.uniform(*door))
        along = h if across_x else w
        d0 = float(rng.uniform(0.2, max(0.2, along - dw - 0.2)))
        if across_x:
            cx = x0 + cut
            plan.box(cx, y0, cx + wall, y1)
            hole = (cx - 0.01, y0 + d0, cx + wall + 0.01, y0 + d0 + dw)
            todo += [(x0, y0, cx, y1), (cx + wall, y0, x1, y1)]
        else:
            cy = y0 + cut
            plan.box(x0, cy, x1, cy + wall)
            hole = (x0 + d0, cy - 0.01, x0 + d0 + dw, cy + wall + 0.01)
            todo += [(x0, y0, x1, cy), (x0, cy + wall, x1, y1)]
        doors.append(hole)
    for hole in doors:
        plan.clear(*hole)
    for x0, y0, x1, y1 in rooms:
        for _ in range(furniture):
            bw, bh = rng.uniform(0.4, 1.2, size=2)
            side = int(rng.integers(4))
            if side < 2:
                bx = float(rng.uniform(x0 + 0.5, max(x0 + 0.5, x1 - bw - 0.5)))
                by = y0 if side == 0 else y1 - bh
            else:
                by = float(rng.uniform(y0 + 0.5, max(y0 + 0.5, y1 - bh - 0.5)))
                bx = x0 if side == 2 else x1 - bw
            box = (bx, by, bx + bw, by + bh)
            # A box in front of a door could cut a room off.
            if not any(_near(box, d, 1.0) for d in doors):
                plan.box(*box)
    return plan


def _near(a: tuple[float, ...], b: tuple[float, ...], gap: float) -> bool:
    """Whether two rectangles come within ``gap`` of each other."""
    return not (a[2] + gap < b[0] or b[2] + gap < a[0] or a[3] + gap < b[1] or b[3] + gap < a[1])
