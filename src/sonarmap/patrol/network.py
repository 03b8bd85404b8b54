"""Who hears whom: the team's network and the relaying along chains of robots.

Robots exchange only their current coordinates. ``full``: every robot hears every other.
``limited``: a direct link needs the two robots within ``r_max`` (70 m) and a straight
line between them that crosses no obstacle. ``none``: no links. Messages relay along
chains, so a robot knows the coordinates of every robot in its connected component.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..errors import ConfigError
from ..grid import Grid
from .territory import segment_clear

__all__ = ["NETWORKS", "components", "direct_links", "line_of_sight"]

NETWORKS = ("full", "limited", "none")


def line_of_sight(
    x0: float, y0: float, x1: float, y1: float, clear: npt.NDArray[np.bool_], grid: Grid
) -> bool:
    """No cell that is not ``clear`` on the segment (sampled at half a cell)."""
    return segment_clear(x0, y0, x1, y1, clear, grid, step=0.5)


def direct_links(
    kind: str,
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    *,
    clear: npt.NDArray[np.bool_],
    grid: Grid,
    r_max: float = 70.0,
) -> list[tuple[int, int]]:
    """The direct links, pairs ``(i, j)`` with ``i < j``, of a ``full``, ``limited`` or
    ``none`` network (what the relaying of :func:`components` chains)."""
    n = len(x)
    if kind == "full":
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    if kind == "none":
        return []
    if kind != "limited":
        raise ConfigError(f"unknown network {kind!r}; valid: {', '.join(NETWORKS)}")
    return [
        (i, j)
        for i in range(n)
        for j in range(i + 1, n)
        if math.hypot(x[i] - x[j], y[i] - y[j]) <= r_max
        and line_of_sight(x[i], y[i], x[j], y[j], clear, grid)
    ]


def components(
    kind: str,
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    *,
    clear: npt.NDArray[np.bool_],
    grid: Grid,
    r_max: float = 70.0,
) -> npt.NDArray[np.int64]:
    """The component label of each robot (robots with one label hear each other)."""
    n = len(x)
    if kind == "full":
        return np.zeros(n, dtype=np.int64)
    if kind == "none":
        return np.arange(n, dtype=np.int64)
    pairs = direct_links(kind, x, y, clear=clear, grid=grid, r_max=r_max)
    src = [i for i, _ in pairs]
    dst = [j for _, j in pairs]
    links = coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))
    _, labels = connected_components(links, directed=False)
    return np.asarray(labels, dtype=np.int64)
