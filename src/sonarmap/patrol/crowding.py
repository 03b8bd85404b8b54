"""The cells a robot closes round the others on its own path-finding map: the artificial
obstacles of ``crowding`` 'obstacles' (:func:`obstacle_discs`) and the discs a robot that
gave way plans around (:func:`give_way`, :func:`earlier_near`).

:func:`~sonarmap.patrol.simulation.run_patrol` joins them, each step and robot, with the
semaphores and a car's forward wave into the cells its wave may not enter.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from .fog import disc_side
from .robots import Team
from .settings import PatrolConfig

__all__ = ["ONCOMING_NEAR", "earlier_near", "give_way", "halves_discs", "obstacle_discs"]

#: Metres within which a robot coming the other way ahead of a car driving on round
#: the block (``round_block``) shuts its way: one farther off may turn off before they
#: meet, so the car keeps on rather than turn round for it (chosen on training street
#: sites, docs/results/2026-12-06-cars.md).
ONCOMING_NEAR = 10.0


def earlier_near(team: Team, i: int, near: float) -> npt.NDArray[np.bool_]:
    """Which of robots 0 .. i-1 are within ``near`` metres of robot i.

    Parameters
    ----------
    team : Team
        The robots (world metres).
    i : int
        The robot asking; only the robots before it (the collision rule's earlier ones,
        whose moves win) are looked at.
    near : float
        Metres, centre to centre.

    Returns
    -------
    ndarray of bool, shape (i,)
        True for each earlier robot nearer than ``near``.
    """
    out: npt.NDArray[np.bool_] = np.hypot(team.x[:i] - team.x[i], team.y[:i] - team.y[i]) < near
    return out


def give_way(team: Team, until: npt.NDArray[np.int64], step: int, near: float) -> None:
    """Robots blocked with an earlier robot within ``near`` metres plan around the
    earlier robots near them until ``step`` (the ``give-way`` traffic rule).

    Parameters
    ----------
    team : Team
        The robots, just moved (:attr:`~sonarmap.patrol.robots.Team.blocked` set).
    until : ndarray of int, shape (N,)
        Per robot, the last step it plans around the earlier robots near it; set to
        ``step`` in place for each robot that gives way, left alone for the others.
    step : int
        The step up to which a robot giving way now keeps doing so.
    near : float
        Metres within which an earlier robot counts as the one given way to.
    """
    for i in np.flatnonzero(team.blocked).tolist():
        if earlier_near(team, i, near).any():
            until[i] = step


def _followed(team: Team, i: int, near: float = ONCOMING_NEAR) -> npt.NDArray[np.bool_]:
    """Which robots ahead of robot i (in front of it along its heading) it may follow
    rather than turn round for: those heading within 90 deg of its heading, and any
    farther than ``near`` metres."""
    h = float(team.heading[i])
    along = (team.x - team.x[i]) * math.cos(h) + (team.y - team.y[i]) * math.sin(h)
    far = np.hypot(team.x - team.x[i], team.y - team.y[i]) > near
    out: npt.NDArray[np.bool_] = (along > 0) & ((np.cos(team.heading - h) > 0) | far)
    out[i] = False
    return out


def halves_discs(config: PatrolConfig) -> bool:
    """Whether a robot's artificial obstacles are only the other robot's side of each
    disc (:func:`obstacle_discs`): tracking cars. A whole disc round each of two of
    them nearer than ``2 r_obst`` shuts every cell about both, and neither has a path
    or a direction: both stand for good. The thesis's car escapes at random instead,
    and keeps the thesis's whole discs."""
    return config.model == "car" and config.car_planner == "track"


def obstacle_discs(
    team: Team,
    i: int,
    cells: npt.NDArray[np.intp],
    disc: npt.NDArray[np.int64],
    shape: tuple[int, int],
    *,
    halve: bool,
    following: bool = False,
    near: float = ONCOMING_NEAR,
    heard: npt.NDArray[np.bool_] | None = None,
) -> list[npt.NDArray[np.intp]]:
    """The cells robot i closes round the other robots with artificial obstacles.

    Parameters
    ----------
    team : Team
        The robots (positions and headings, world metres and radians).
    i : int
        The robot planning.
    cells : ndarray of int, shape (N, 2)
        Every robot's (row, column) cell.
    disc : ndarray of int, shape (K, 2)
        The disc's cell offsets (:func:`~sonarmap.patrol.fog.disc_offsets` of ``r_obst``).
    shape : tuple of int
        The map's (rows, columns); cells off it are dropped.
    halve : bool
        Keep only each disc's cells nearer the other robot than robot i
        (:func:`halves_discs`).
    following : bool
        For a car driving on rather than turning round (``round_block``): no disc
        round the robots ahead of it going its way, nor round those ahead farther than
        ``near`` (default False: a disc round every other robot).
    near : float
        Metres beyond which a robot ahead coming the other way is followed too
        (default :data:`ONCOMING_NEAR`; ``inf``: only those going its way).
    heard : ndarray of bool, shape (N,), optional
        The robots robot i hears of (default: all).

    Returns
    -------
    list of ndarray of int, shape (K_j, 2)
        One array of (row, column) pairs per robot closed, in robot order.
    """
    n = len(team)
    ahead = _followed(team, i, near) if following else np.zeros(n, dtype=np.bool_)
    others = np.ones(n, dtype=np.bool_) if heard is None else heard
    mine = (int(cells[i, 0]), int(cells[i, 1]))
    out: list[npt.NDArray[np.intp]] = []
    for j in np.flatnonzero(others & ~ahead).tolist():
        if j == i:
            continue
        # With ``halve``, the disc's cells nearer the other robot than robot i: an
        # artificial obstacle that never shuts the cells about the robot planning, so
        # two robots closer than twice its radius can still part.
        side = disc_side(disc, int(cells[j, 0]), int(cells[j, 1]), shape, mine if halve else None)
        out.append(side.astype(np.intp, copy=False))
    return out
