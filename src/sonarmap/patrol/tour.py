"""The offline reference: one cyclic tour that sees the whole territory, the robots
spread evenly along it (Chevaleyre 2004: optimal for one robot, near optimal for
several).

Waypoints lie on a square lattice of spacing vision * sqrt(2), so that every place is
within the vision radius of one; each moves to the nearest cell a robot's centre can
reach (:func:`~sonarmap.patrol.graph.lattice_cells`, the patrol graph's vertices). The
tour orders them by nearest neighbour and improves the order by 2-opt, with path lengths
from the wave. A robot heads along the wave's first step for its next
waypoint and takes the following one on arrival.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from .graph import lattice_cells
from .paths import wave
from .territory import Territory

__all__ = ["plan_tour"]


def plan_tour(
    territory: Territory, passable: npt.NDArray[np.bool_], vision: float, start: tuple[int, int]
) -> tuple[npt.NDArray[np.int64], float]:
    """Waypoint cells (rows, cols) in tour order, and the tour's length in metres.

    Only waypoints reachable from ``start`` (a passable cell) are kept.
    """
    points = lattice_cells(territory, passable, vision)
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
