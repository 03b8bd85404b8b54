"""Holonomic robots moving with the thesis's collision rule.

A robot is a disc (radius 1 m) that either stands or moves at full speed (4.4 m/s)
in any direction, turning at once. Each step of dt seconds it goes in a straight line
along its chosen direction. A move is possible when every point of the segment keeps
the disc clear of obstacles and inside the map (the territory's passable cells).
Robots must keep ``min_separation`` (2 m) between centres: if the chosen moves of
several robots make a collision possible on a step, the moves of all of those robots
are cancelled for that step (repeated until no possible collision is left, since a
cancelled robot stays where another may be heading). A robot whose move was cancelled
is blocked; while blocked, each step it goes in a random direction instead with
probability ``p_random`` (10 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..grid import Grid
from .territory import segment_clear

__all__ = ["Holonomic", "close_pairs"]

F64 = npt.NDArray[np.float64]


@dataclass
class Holonomic:
    """The state and motion rules of a team of holonomic robots.

    Attributes
    ----------
    x, y, heading : ndarray of float64
        Positions (metres) and headings (radians) of the robots.
    blocked : ndarray of bool
        Whose move was cancelled on the last step.
    """

    x: F64
    y: F64
    heading: F64
    radius: float = 1.0
    speed: float = 4.4
    min_separation: float = 2.0
    p_random: float = 0.1
    blocked: npt.NDArray[np.bool_] = field(init=False)

    def __post_init__(self) -> None:
        for name in ("radius", "speed", "min_separation"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"robot {name} must be > 0, got {v}")
        if not (0.0 <= self.p_random <= 1.0):
            raise ConfigError(f"p_random must be in [0, 1], got {self.p_random}")
        self.blocked = np.zeros(len(self.x), dtype=bool)

    def __len__(self) -> int:
        return len(self.x)

    def step(
        self,
        directions: list[tuple[float, float] | None],
        passable: npt.NDArray[np.bool_],
        grid: Grid,
        dt: float,
        rng: np.random.Generator,
    ) -> npt.NDArray[np.bool_]:
        """Move every robot one step; returns who moved."""
        n = len(self)
        want = np.zeros(n, dtype=bool)
        dx = np.zeros(n)
        dy = np.zeros(n)
        for i, d in enumerate(directions):
            if self.blocked[i] and rng.random() < self.p_random:
                a = rng.uniform(-math.pi, math.pi)
                d = (math.cos(a), math.sin(a))
            if d is None:
                continue
            want[i] = True
            dx[i], dy[i] = d
        step = self.speed * dt
        nx = self.x + want * dx * step
        ny = self.y + want * dy * step
        moving = want.copy()
        for i in np.flatnonzero(want).tolist():
            if not segment_clear(self.x[i], self.y[i], nx[i], ny[i], passable, grid):
                moving[i] = False
        # Cancel the moves of every robot in a possible collision, until none is left.
        while True:
            px = np.where(moving, nx, self.x)
            py = np.where(moving, ny, self.y)
            pairs = close_pairs(px, py, self.min_separation)
            culprits = sorted({k for pair in pairs for k in pair if moving[k]})
            if not culprits:
                break
            moving[culprits] = False
        self.blocked = want & ~moving
        self.x = np.where(moving, nx, self.x)
        self.y = np.where(moving, ny, self.y)
        self.heading = np.where(moving, np.arctan2(dy, dx), self.heading)
        return moving


def close_pairs(x: F64, y: F64, sep: float) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of points nearer than ``sep`` to each other."""
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    i, j = np.nonzero(np.triu(d < sep - 1e-9, k=1))
    return list(zip(i.tolist(), j.tolist(), strict=True))
