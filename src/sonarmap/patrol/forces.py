"""The pull of every place on a robot, and the direction the robot chooses.

Place T pulls robot R with F = f(TB_n(T)) * g(L(R, T)) along the first direction of
the shortest path from R to T; TB_n = TB / MTB in [0, 1]; L in decimetres, as in the
thesis. The candidate families (docs/patrol.md):

- f1 TB_n, f2 TB_n^2, f3 e^(a TB_n), f4 e^(a TB_n^2), f5 e^(a TB_n^4);
- g1 1/L, g2 1/L^2, g3 e^(-L/b), g4 e^(-L^2/b^2), g5 e^(-L^4/b^4);

adopted f3 g4 with a = 40, b = 65 dm. Forces are summed in the log domain (the common
scale of all forces does not change a direction, and e^40 or e^-236 stay finite there).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError

__all__ = ["FORCE_F", "FORCE_G", "Force", "choose_direction", "parse_force"]

F64 = npt.NDArray[np.float64]

#: log f(TB_n) for f1..f5 (a the exponent's scale).
FORCE_F: dict[str, Callable[[F64, float], F64]] = {
    "f1": lambda t, a: np.log(t),
    "f2": lambda t, a: 2.0 * np.log(t),
    "f3": lambda t, a: a * t,
    "f4": lambda t, a: a * t**2,
    "f5": lambda t, a: a * t**4,
}
#: log g(L) for g1..g5, L in decimetres (b the length scale, decimetres).
FORCE_G: dict[str, Callable[[F64, float], F64]] = {
    "g1": lambda length, b: -np.log(length),
    "g2": lambda length, b: -2.0 * np.log(length),
    "g3": lambda length, b: -length / b,
    "g4": lambda length, b: -((length / b) ** 2),
    "g5": lambda length, b: -((length / b) ** 4),
}


#: log of the share of the strongest pull below which the pulls of far places are
#: dropped (about 1e-18: beneath the resolution of a float64 sum).
NEGLIGIBLE = -41.5
#: Relative difference below which two sectors' pulls count as equal.
TIE = 1e-9


@dataclass(frozen=True)
class Force:
    """A force law f x g with its constants (the thesis's adopted f3 g4, a 40, b 65 dm)."""

    f: str = "f3"
    g: str = "g4"
    a: float = 40.0
    b: float = 65.0

    def __post_init__(self) -> None:
        if self.f not in FORCE_F or self.g not in FORCE_G:
            raise ConfigError(f"unknown force '{self.f}{self.g}'; valid: f1..f5 with g1..g5")
        if not (math.isfinite(self.a) and self.a > 0 and math.isfinite(self.b) and self.b > 0):
            raise ConfigError(f"force constants must be > 0, got a={self.a}, b={self.b}")

    @property
    def name(self) -> str:
        return f"{self.f}{self.g}"

    def pull_limit(self, best: float, count: int) -> float:
        """The path length (metres) beyond which ``count`` places together pull less
        than e^-41.5 (about 1e-18) of the strongest pull found, ``best`` (log): the
        most a place can pull is f(1) g(L), so places farther than this cannot change
        a direction. ``inf`` when nothing pulls yet."""
        if not math.isfinite(best):
            return math.inf
        f_max = float(FORCE_F[self.f](np.array([1.0]), self.a)[0])
        x = best - f_max - math.log(max(count, 1)) + NEGLIGIBLE  # we need log g(L) < x
        if self.g in ("g1", "g2"):
            dm = math.exp(min(-x / (1.0 if self.g == "g1" else 2.0), 700.0))
        elif x >= 0:
            dm = 0.0
        else:
            dm = self.b * {"g3": -x, "g4": math.sqrt(-x), "g5": (-x) ** 0.25}[self.g]
        return dm / 10.0

    def log_pull(self, tb_n: F64, length_m: F64) -> F64:
        """log F for normalised fog and path lengths in metres; -inf where there is no
        pull (TB_n = 0 under f1/f2, or the robot's own cell)."""
        dm = length_m * 10.0
        with np.errstate(divide="ignore", invalid="ignore"):
            out = FORCE_F[self.f](tb_n, self.a) + FORCE_G[self.g](dm, self.b)
        out = np.where(dm > 0, out, -np.inf)
        return np.where(np.isnan(out), -np.inf, out)


def parse_force(text: str, a: float = 40.0, b: float = 65.0) -> Force:
    """``f3g4`` -> Force("f3", "g4", a, b)."""
    m = re.fullmatch(r"\s*(f[1-5])\s*(g[1-5])\s*", text)
    if m is None:
        raise ConfigError(f"unknown force {text!r}; expected f1..f5 followed by g1..g5, e.g. f3g4")
    return Force(m.group(1), m.group(2), a, b)


def choose_direction(
    log_pull: F64,
    ux: F64,
    uy: F64,
    method: str = "mode",
    sectors: int = 8,
    weights: F64 | None = None,
    steps: npt.NDArray[np.integer[Any]] | None = None,
) -> tuple[float, float] | None:
    """The direction a robot goes: unit (x, y), or None when nothing pulls.

    ``vector``: the sum of all forces. ``mode``: forces are summed per direction sector
    (``sectors`` equal sectors, the first centred on +x) and the robot goes along the
    strongest sector, in the direction of the forces' sum within it (with the wave's
    8 first steps and 8 sectors, exactly that step). ``weights`` (mode only) scale each
    sector's sum (direction weakening). ``steps``: the wave's first-step indices
    (:data:`~sonarmap.patrol.paths.STEPS`) behind ``ux``, ``uy``, which name the sector
    at once with 8 sectors.
    """
    ok = np.isfinite(log_pull)
    if not ok.any():
        return None
    lp = log_pull[ok]
    w = np.exp(lp - lp.max())
    x, y = ux[ok], uy[ok]
    if method == "vector":
        sx, sy = float(np.dot(w, x)), float(np.dot(w, y))
    elif method == "mode":
        if steps is not None and sectors == 8:
            sector = steps[ok].astype(np.int64)  # the wave's step k lies in sector k
        else:
            angle = np.arctan2(y, x)
            width = 2 * math.pi / sectors
            sector = np.floor((angle + width / 2) / width).astype(np.int64) % sectors
        strength = np.bincount(sector, weights=w, minlength=sectors).astype(np.float64)
        if weights is not None:
            strength = strength * np.asarray(weights, dtype=np.float64)
        # Sectors within a relative TIE of the strongest are tied, and the first wins:
        # on a symmetric map with an even fog, two sectors pull exactly alike and only
        # rounding would otherwise choose (and choose differently as the sum's order
        # changes).
        best = int(np.flatnonzero(strength >= strength.max() * (1.0 - TIE))[0])
        pick = sector == best
        if steps is not None and sectors == 8:
            # Every pull in a wave sector points along its step: go exactly that way.
            k = int(np.flatnonzero(pick)[0])
            return float(x[k]), float(y[k])
        sx, sy = float(np.dot(w[pick], x[pick])), float(np.dot(w[pick], y[pick]))
    else:
        raise ConfigError(f"unknown direction method {method!r}; valid: mode, vector")
    norm = math.hypot(sx, sy)
    if norm < 1e-12:
        return None
    return sx / norm, sy / norm
