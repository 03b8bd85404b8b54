"""The offline reference: one cyclic tour that sees the whole territory, the robots
spread evenly along it (Chevaleyre 2004: optimal for one robot, near optimal for
several).

Waypoints lie on a square lattice of spacing vision * sqrt(2), so that every place is
within the vision radius of one; each moves to the nearest cell a robot's centre can
reach. The tour orders them by nearest neighbour and improves the order by 2-opt, with
path lengths from the wave. A robot heads along the wave's first step for its next
waypoint and takes the following one on arrival.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import InputError
from .paths import wave
from .territory import Territory

__all__ = ["plan_tour"]


def _waypoints(
    territory: Territory, passable: npt.NDArray[np.bool_], vision: float
) -> npt.NDArray[np.int64]:
    g = territory.grid
    step = max(1, math.floor(vision * math.sqrt(2) / g.resolution))
    # The nearest passable cell of every cell (an index map from the distance transform).
    _, (near_r, near_c) = ndimage.distance_transform_edt(~passable, return_indices=True)
    # Lattice lines spread evenly over each side, at most ``step`` apart, so that the
    # map's edges are within reach too.
    rows = ((np.arange(math.ceil(g.rows / step)) + 0.5) * g.rows / math.ceil(g.rows / step)).astype(
        int
    )
    cols = ((np.arange(math.ceil(g.cols / step)) + 0.5) * g.cols / math.ceil(g.cols / step)).astype(
        int
    )
    half = step // 2 + 1
    out: list[tuple[int, int]] = []
    for r in rows.tolist():
        for c in cols.tolist():
            if not territory.free[
                max(0, r - half) : r + half + 1, max(0, c - half) : c + half + 1
            ].any():
                continue  # nothing to watch around this lattice point
            rr, cc = int(near_r[r, c]), int(near_c[r, c])
            if (rr, cc) not in out:
                out.append((rr, cc))
    return np.array(out, dtype=np.int64)


def plan_tour(
    territory: Territory, passable: npt.NDArray[np.bool_], vision: float, start: tuple[int, int]
) -> tuple[npt.NDArray[np.int64], float]:
    """Waypoint cells (rows, cols) in tour order, and the tour's length in metres.

    Only waypoints reachable from ``start`` (a passable cell) are kept.
    """
    points = _waypoints(territory, passable, vision)
    dist0, _ = wave(passable, start, territory.grid.resolution)
    points = points[np.isfinite(dist0[points[:, 0], points[:, 1]])]
    if len(points) == 0:
        raise InputError("no place of the territory can be reached from the starts")
    n = len(points)
    d = np.empty((n, n))
    for i in range(n):
        di, _ = wave(passable, (int(points[i, 0]), int(points[i, 1])), territory.grid.resolution)
        d[i] = di[points[:, 0], points[:, 1]]
    # Nearest neighbour from the waypoint nearest the start, then 2-opt.
    order = [int(np.argmin(dist0[points[:, 0], points[:, 1]]))]
    left = set(range(n)) - set(order)
    while left:
        last = order[-1]
        nxt = min(left, key=lambda j: d[last, j])
        order.append(nxt)
        left.remove(nxt)
    improved = True
    while improved and n > 3:
        improved = False
        for i in range(n - 1):
            for j in range(i + 2, n if i > 0 else n - 1):
                a, b = order[i], order[i + 1]
                c, e = order[j], order[(j + 1) % n]
                if d[a, c] + d[b, e] < d[a, b] + d[c, e] - 1e-9:
                    order[i + 1 : j + 1] = order[i + 1 : j + 1][::-1]
                    improved = True
    length = float(sum(d[order[k], order[(k + 1) % n]] for k in range(n)))
    return points[order], length
