"""Local improvements of a chosen direction (thesis 002, the end of chapter 3).

Weakening ("fuzzy" choice): each sector's summed pull is multiplied by min(1, r / R_0),
r the distance from the robot to the nearest obstacle within the sector (R_0 = 5.5 m),
so sectors that run into a nearby wall lose weight.

Refinement: put a local goal G at ``r_goal`` metres (2.5) along the chosen direction;
replace it by the passable point of the square of side ``side`` metres (2) around G
with the smallest obstacle penalty -- the sum over a window of side 2 ``window`` (10 m)
of M / d^2, M = 1 for cells that are not free or lie outside the map -- ties to the
smallest turn; the robot heads for that point. The penalty map is the obstacle map
convolved once with a 1/d^2 kernel.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.signal import fftconvolve

from ..grid import Grid

__all__ = ["obstacle_penalty", "refine_direction", "sector_weakening"]


def obstacle_penalty(
    free: npt.NDArray[np.bool_], resolution: float, window: float = 10.0
) -> npt.NDArray[np.float64]:
    """Sum over the window of side 2 ``window`` around each cell of M / d^2 (metres)."""
    k = max(1, round(window / resolution))
    dr, dc = np.mgrid[-k : k + 1, -k : k + 1]
    d2 = (dr * resolution) ** 2 + (dc * resolution) ** 2
    kernel = np.where(d2 > 0, 1.0 / np.where(d2 > 0, d2, 1.0), 0.0)
    # Outside the map counts as obstacle: pad with it.
    blocked = np.pad((~free).astype(np.float64), k, constant_values=1.0)
    out = fftconvolve(blocked, kernel, mode="same")[k:-k, k:-k]
    return np.asarray(np.maximum(out, 0.0), dtype=np.float64)


def refine_direction(
    x: float,
    y: float,
    direction: tuple[float, float],
    penalty: npt.NDArray[np.float64],
    passable: npt.NDArray[np.bool_],
    grid: Grid,
    *,
    r_goal: float = 2.5,
    side: float = 2.0,
) -> tuple[float, float]:
    """The refined unit direction (the original one if no candidate is passable)."""
    gx, gy = x + r_goal * direction[0], y + r_goal * direction[1]
    h = side / 2
    cx, cy = np.meshgrid(
        np.arange(gx - h, gx + h + 1e-9, grid.resolution),
        np.arange(gy - h, gy + h + 1e-9, grid.resolution),
    )
    cx, cy = cx.ravel(), cy.ravel()
    r, c = grid.world_to_cell(cx, cy)
    ok = grid.contains(r, c)
    if not ok.any():
        return direction
    r, c, cx, cy = r[ok], c[ok], cx[ok], cy[ok]
    ok = passable[r, c]
    if not ok.any():
        return direction
    r, c, cx, cy = r[ok], c[ok], cx[ok], cy[ok]
    base = math.atan2(direction[1], direction[0])
    turn = np.abs(np.angle(np.exp(1j * (np.arctan2(cy - y, cx - x) - base))))
    # The least penalty, then the least turn.
    k = np.lexsort((turn, np.round(penalty[r, c], 9)))[0]
    vx, vy = cx[k] - x, cy[k] - y
    n = math.hypot(vx, vy)
    return (vx / n, vy / n) if n > 1e-9 else direction


def sector_weakening(
    x: float,
    y: float,
    free: npt.NDArray[np.bool_],
    grid: Grid,
    sectors: int = 8,
    r0: float = 5.5,
    rays: int = 5,
) -> npt.NDArray[np.float64]:
    """min(1, r / r0) per sector (the first centred on +x), r the distance to the
    nearest cell that is not free, or the map's edge, along ``rays`` rays across the
    sector, looked for up to r0."""
    width = 2 * math.pi / sectors
    steps = np.arange(1, int(np.ceil(r0 / (grid.resolution / 2))) + 1) * (grid.resolution / 2)
    out = np.ones(sectors)
    for k in range(sectors):
        angles = k * width + (np.arange(rays) + 0.5) / rays * width - width / 2
        px = x + np.cos(angles)[:, None] * steps[None, :]
        py = y + np.sin(angles)[:, None] * steps[None, :]
        r, c = grid.world_to_cell(px, py)
        inside = grid.contains(r, c)
        hit = ~inside
        hit[inside] = ~free[r[inside], c[inside]]
        if hit.any():
            first = np.where(hit.any(axis=1), steps[np.argmax(hit, axis=1)], np.inf)
            out[k] = min(1.0, float(first.min()) / r0)
    return out
