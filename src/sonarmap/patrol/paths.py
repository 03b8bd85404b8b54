"""Path lengths and first steps from a robot to every place.

- :func:`wave`: the thesis's wave (Lee's algorithm with weights): Dijkstra on the grid's
  passable cells, 8-connected, steps of one cell and sqrt(2) cells. One wave from the
  robot gives the length L of the shortest path to every cell and the first step of
  that path (one of 8 directions). It follows map edits for free: it is recomputed on
  the current passable mask every step.
- :func:`straight_paths`: straight lines (open space, the thesis's Tables 2-3).

An 8-connected wave overestimates the Euclidean geodesic by up to about 8 %.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt

__all__ = ["STEPS", "straight_paths", "wave"]

#: The 8 steps as (row, column) offsets, counter-clockwise from east (+x); rows grow
#: downwards, so north (+y) is row - 1.
STEPS = np.array(
    [(0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1)], dtype=np.int64
)
#: Unit world vectors (x, y) of the 8 steps.
STEP_UNITS = np.array(
    [(math.cos(k * math.pi / 4), math.sin(k * math.pi / 4)) for k in range(8)], dtype=np.float64
)


@nb.njit(cache=True)
def _wave(
    passable: npt.NDArray[np.bool_],
    target: npt.NDArray[np.bool_],
    r0: int,
    c0: int,
    steps: npt.NDArray[np.int64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
    rows, cols = passable.shape
    dist = np.full((rows, cols), np.inf)
    first = np.full((rows, cols), -1, dtype=np.int8)
    # A binary heap of (distance, cell) with lazy deletion.
    cap = 8 * rows * cols + 1
    hd = np.empty(min(cap, 1 << 26), dtype=np.float64)
    hc = np.empty(hd.shape[0], dtype=np.int64)
    size = 0
    dist[r0, c0] = 0.0
    hd[0] = 0.0
    hc[0] = r0 * cols + c0
    size = 1
    diag = math.sqrt(2.0)
    while size > 0:
        d = hd[0]
        cell = hc[0]
        size -= 1
        # pop: move the last item to the root and sift down
        if size > 0:
            ld = hd[size]
            lc = hc[size]
            i = 0
            while True:
                j = 2 * i + 1
                if j >= size:
                    break
                if j + 1 < size and hd[j + 1] < hd[j]:
                    j += 1
                if hd[j] >= ld:
                    break
                hd[i] = hd[j]
                hc[i] = hc[j]
                i = j
            hd[i] = ld
            hc[i] = lc
        r = cell // cols
        c = cell % cols
        if d > dist[r, c]:
            continue
        for k in range(8):
            rr = r + steps[k, 0]
            cc = c + steps[k, 1]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols or not target[rr, cc]:
                continue
            # Once a path leaves the cells the robot's centre may cross (to reach a place
            # near a wall), it does not come back: paths between passable cells stay
            # passable.
            if passable[rr, cc] and not passable[r, c]:
                continue
            if k % 2 == 1:
                # A diagonal step may not cut the corner of a cell it could not cross.
                if not target[r, cc] or not target[rr, c]:
                    continue
                if passable[rr, cc] and (not passable[r, cc] or not passable[rr, c]):
                    continue
                nd = d + diag
            else:
                nd = d + 1.0
            if nd < dist[rr, cc]:
                dist[rr, cc] = nd
                first[rr, cc] = k if (r == r0 and c == c0) else first[r, c]
                if size >= hd.shape[0]:
                    # The heap is full: grow it (rare; lazy deletion keeps it small).
                    nh = np.empty(hd.shape[0] * 2, dtype=np.float64)
                    nc = np.empty(hd.shape[0] * 2, dtype=np.int64)
                    nh[:size] = hd[:size]
                    nc[:size] = hc[:size]
                    hd = nh
                    hc = nc
                i = size
                size += 1
                while i > 0:
                    p = (i - 1) // 2
                    if hd[p] <= nd:
                        break
                    hd[i] = hd[p]
                    hc[i] = hc[p]
                    i = p
                hd[i] = nd
                hc[i] = rr * cols + cc
    return dist, first


def wave(
    passable: npt.NDArray[np.bool_],
    start: tuple[int, int],
    resolution: float,
    target: npt.NDArray[np.bool_] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
    """Shortest 8-connected path lengths (metres) and first steps from ``start``.

    Paths run over ``passable`` cells (where the robot's centre may be). With
    ``target`` (a superset: the free cells), a cell the centre cannot reach -- beside a
    wall, in a gap narrower than the robot -- is reached by a passable path and a last
    stretch over target cells, so it still pulls the robot towards the nearest place
    from which it can be seen.

    Returns
    -------
    dist : ndarray of float64
        Path length to every cell; ``inf`` where no path exists.
    first : ndarray of int8
        Index into :data:`STEPS` of the path's first step; -1 at the start and where
        no path exists.
    """
    r0, c0 = start
    if not passable[r0, c0]:
        raise ValueError(f"the wave starts in an impassable cell {start}")
    ok = np.ascontiguousarray(passable)
    tg = ok if target is None else np.ascontiguousarray(target | passable)
    dist, first = _wave(ok, tg, int(r0), int(c0), STEPS)
    return dist * resolution, first


def straight_paths(
    x: float, y: float, cx: npt.NDArray[np.float64], cy: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Straight-line lengths and unit directions from (x, y) to points (cx, cy)."""
    dx = cx - x
    dy = cy - y
    dist = np.hypot(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(dist > 0, dx / dist, 0.0)
        uy = np.where(dist > 0, dy / dist, 0.0)
    return dist, ux, uy
