"""Routes for a team's mission from the potential-field patroller (thesis 002, chapter 3;
:mod:`sonarmap.patrol`): the end-to-end team patrols, maps and shares.

:func:`patrol_routes` runs :func:`~sonarmap.patrol.simulation.run_patrol` with N robots
on the mission's plan for the mission's duration, one patrol step per route step, and
turns each robot's trajectory into the ``t, x, y, theta`` route a
:class:`~.mission.RobotAgent` drives.

Choices where the two chapters differ (the patroller's defaults are the thesis's
1 m robots at 4.4 m/s with a 10 m vision; the mapping robots are the random-waypoint
routes' 0.3 m robots at 0.5 m/s, poses at 2 Hz):

- the robots are the mapping robots: ``radius`` 0.3 m, ``speed`` 0.5 m/s, and the
  patrol's step ``dt`` is the route's period (1 / ``rate``, 0.5 s);
- the patroller's vision, which decides what counts as seen and so where the robots
  go, is the sonar mapping range (``vision`` 3 m) and stops at walls
  (``line_of_sight``): a place behind a wall has not been mapped;
- every other patrol setting is :class:`~sonarmap.patrol.simulation.PatrolConfig`'s
  default (potential field, mode direction, full network among the patrollers: the
  patrol's own coordination is not the mapping exchange's network);
- starts are the patroller's random starts (free cells, 2 radii apart), drawn from
  ``seed``; with a user's territory mask (``region``, :mod:`.territory`), on the
  largest piece a robot fits in inside it, and the patrol stays inside it (its
  ``--territory``);
- the heading is the direction of the last move (the holonomic patroller turns on the
  spot), kept while a robot stands still; before its first move a robot faces its
  first move's direction.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..io.rosmap import OccupancyMap
from ..patrol.fog import Fog
from ..patrol.reach import reach
from ..patrol.robots import Team
from ..patrol.simulation import PatrolConfig, PatrolResult, run_patrol
from ..patrol.starts import random_starts
from ..patrol.territory import Territory
from .config import check_team_size
from .territory import ROBOT_RADIUS, mask_on

__all__ = ["patrol_config", "patrol_routes"]

F64 = npt.NDArray[np.float64]


def patrol_config(
    duration: float,
    *,
    rate: float = 2.0,
    speed: float = 0.5,
    radius: float = ROBOT_RADIUS,
    vision: float = 3.0,
) -> PatrolConfig:
    """The patroller's settings for mapping robots (see the module's choices)."""
    if not (math.isfinite(rate) and rate > 0):
        raise ConfigError(f"route rate must be > 0 Hz, got {rate}")
    return PatrolConfig(
        duration=duration,
        dt=1.0 / rate,
        speed=speed,
        radius=radius,
        vision=vision,
        line_of_sight=True,
    )


def _headings(x: F64, y: F64) -> F64:
    """Per step, the direction of the last move; held while still."""
    dx, dy = np.diff(x), np.diff(y)
    moved = np.hypot(dx, dy) > 1e-9
    theta = np.zeros(len(x))
    if not moved.any():
        return theta
    step = np.arctan2(dy, dx)
    # Step k's heading: that of the last move ending at or before k.
    idx = np.where(moved, np.arange(len(dx)), -1)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(moved))
    idx[idx < 0] = first
    theta[1:] = step[idx]
    theta[0] = step[first]
    return theta


def patrol_routes(
    plan: OccupancyMap,
    robots: int,
    duration: float,
    *,
    seed: int = 0,
    config: PatrolConfig | None = None,
    region: npt.NDArray[np.bool_] | None = None,
) -> tuple[list[F64], PatrolResult]:
    """Each robot's route as the potential-field patroller drives the team.

    Parameters
    ----------
    plan : OccupancyMap
        The floor (the patrol's territory, on cells of ``config.cell``).
    robots : int
        Robots, >= 1.
    duration : float
        Seconds.
    seed : int
        The patrol's seed (starts and random moves).
    config : PatrolConfig, optional
        Default :func:`patrol_config` (``duration`` then unused).
    region : ndarray of bool, optional
        A user's territory mask on the plan's cells: the starts and the patrol stay
        inside it (the patrol's ``region``). None (default): the whole plan.

    Returns
    -------
    routes : list of ndarray (T, 4)
        ``t, x, y, theta`` per robot, t from 0 every ``config.dt`` seconds, the first
        row the start.
    result : PatrolResult
        The patrol's own measures (idleness).
    """
    check_team_size(robots)
    cfg = patrol_config(duration) if config is None else config
    territory = Territory.from_map(plan, cell=cfg.cell)
    t: list[float] = []
    xs: list[F64] = []
    ys: list[F64] = []

    def keep(now: float, team: Team, fog: Fog) -> None:
        t.append(now)
        xs.append(team.x.copy())
        ys.append(team.y.copy())

    # The starts drawn here, as run_patrol would, so that the routes can begin at them.
    inside = None if region is None else mask_on(region, plan.grid, territory.grid)
    where = (
        territory.passable(cfg.radius)
        if inside is None
        else reach(territory, cfg.radius, region=inside).passable
    )
    starts = random_starts(robots, territory, where, cfg.min_separation, seed)
    result = run_patrol(territory, cfg, starts=starts, seed=seed, on_step=keep, region=inside)
    x0 = np.asarray(starts, dtype=np.float64)
    tt = np.concatenate([[0.0], np.asarray(t, dtype=np.float64)])
    X = np.vstack([x0[:, 0], *xs])
    Y = np.vstack([x0[:, 1], *ys])
    routes = [
        np.column_stack([tt, X[:, i], Y[:, i], _headings(X[:, i], Y[:, i])]) for i in range(robots)
    ]
    return routes, result
