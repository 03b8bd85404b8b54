"""How a robot chooses where to go: the thesis's potential field, and the literature's
baselines measured on the same simulator and metric.

- ``potential`` (thesis 002): every place pulls with f(TB_n) g(L) along its path's first
  step; mode or vector sum (:mod:`.forces`).
- ``random``: a random walk -- keep going straight, take a new random heading when
  blocked or, each step, with probability ``turn`` (5 %).
- ``reactive``: a reactive agent on the fog's places -- head for the place unseen
  longest (ties to the nearest), along its path's first step.
- ``gravity`` (Sampaio et al. 2010): every place has a mass growing with its idleness and
  pulls with mass / L^k (k = 2); the robot follows the vector sum of the pulls.
- ``cycle``: the offline reference, robots spread along one tour (:mod:`.tour`); the
  simulation drives it, since it needs no pull.
- ``cr``, ``hcr`` and ``sebs``: conscientious and heuristic conscientious reactive agents
  and the state exchange Bayesian strategy, walking the patrol graph vertex to vertex
  (:mod:`.walkers`); the simulation drives them too.

Each returns a unit direction (x, y) or None (stand).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from .forces import Force, choose_direction

__all__ = ["POLICIES", "choose", "goal_pulls", "normalised", "reactive_pick"]

F64 = npt.NDArray[np.float64]

POLICIES = ("potential", "random", "reactive", "gravity", "cycle", "cr", "hcr", "sebs")
#: Per-step chance that the random walk turns while not blocked.
RANDOM_TURN = 0.05
#: Exponent of distance in the gravitational pull.
GRAVITY_K = 2.0


def normalised(tb: F64, top: float | None = None) -> F64:
    """TB_n = TB / MTB(t) (``top``; default the largest of ``tb``), 0 when all is seen."""
    m = float(tb.max()) if top is None and len(tb) else (top or 0.0)
    return tb / m if m > 0 else np.zeros_like(tb)


def reactive_pick(tb: F64, lengths: F64) -> int | None:
    """The conscientious reactive agent's place: the index of the one unseen longest,
    ties to the nearest, the robot's own cell left out (None when nothing else)."""
    if not len(tb):
        return None
    oldest = tb >= tb.max() - 1e-9
    pick = np.flatnonzero(oldest & (lengths > 0))
    if len(pick) == 0:
        return None
    return int(pick[np.argmin(lengths[pick])])


def goal_pulls(policy: str, force: Force, tb: F64, lengths: F64, top: float | None) -> F64:
    """Log of each place's pull under ``policy`` (potential or gravity): the path
    motion goes for the strongest place its chosen direction leads to."""
    if policy == "gravity":
        with np.errstate(divide="ignore"):
            pulls = np.log(tb) - GRAVITY_K * np.log(lengths)
        return np.where(lengths > 0, pulls, -np.inf)
    return force.log_pull(normalised(tb, top), lengths)


def choose(
    policy: str,
    *,
    force: Force,
    method: str,
    sectors: int,
    tb: F64,
    lengths: F64,
    ux: F64,
    uy: F64,
    heading: float,
    blocked: bool,
    rng: np.random.Generator,
    weights: F64 | None = None,
    top: float | None = None,
    log_pull: F64 | None = None,
    steps: npt.NDArray[np.integer[Any]] | None = None,
) -> tuple[float, float] | None:
    """The direction of one robot.

    ``tb`` (seconds unseen), ``lengths`` (metres) and ``ux``, ``uy`` (first-step unit
    vectors) describe the places the robot can reach, as the robot's own fog has them;
    ``weights`` weaken the potential field's sectors (mode only). The potential field
    normalises TB by ``top``, the robot's MTB(t) (default: the largest of ``tb``), and
    takes its pulls from ``log_pull`` when they were worked out already.
    """
    if policy == "random":
        if blocked or rng.random() < RANDOM_TURN:
            heading = rng.uniform(-math.pi, math.pi)
        return math.cos(heading), math.sin(heading)
    if len(tb) == 0:
        return None
    if policy == "potential":
        if log_pull is None:
            log_pull = force.log_pull(normalised(tb, top), lengths)
        return choose_direction(log_pull, ux, uy, method, sectors, weights=weights, steps=steps)
    if policy == "reactive":
        k = reactive_pick(tb, lengths)
        return None if k is None else (float(ux[k]), float(uy[k]))
    if policy == "gravity":
        pulls = goal_pulls(policy, force, tb, lengths, top)
        return choose_direction(pulls, ux, uy, "vector", sectors)
    raise ConfigError(f"unknown policy {policy!r}; valid: {', '.join(POLICIES)}")
