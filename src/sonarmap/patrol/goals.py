"""The place a robot goes for: the strongest place along its chosen step
(:func:`goal_index`, :func:`aim`), the one it keeps, a car's leftovers round the place it
chose (:func:`wave_anchors`, :func:`nearest_leftover`; ``leftover``), and when a car's
forward wave is lifted for a stale place (:func:`stale`; ``forward_stale``).

:mod:`.steering` then turns the place into the robot's step or pursuit point.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from .fog import Fog
from .paths import Wave, nearest_step
from .settings import PatrolConfig

__all__ = ["aim", "goal_index", "nearest_leftover", "stale", "wave_anchors"]

F64 = npt.NDArray[np.float64]


def goal_index(
    direction: tuple[float, float] | None, step: npt.NDArray[np.int8], lp: F64
) -> int | None:
    """The place with the strongest pull ``lp`` among those whose first step is the
    one nearest ``direction``.

    Parameters
    ----------
    direction : (float, float) or None
        The robot's chosen direction (a unit vector), or None when it has none.
    step : ndarray of int8, shape (K,)
        Each place's first wave step (an index into
        :data:`~sonarmap.patrol.paths.STEP_UNITS`).
    lp : ndarray of float, shape (K,)
        Each place's pull (any increasing function of it, such as its logarithm).

    Returns
    -------
    int or None
        The index of that place among the K; None when there is no direction, no place
        or no place along that step.
    """
    if direction is None or not len(lp):
        return None
    mine = np.flatnonzero(step == nearest_step(*direction))
    if not len(mine):
        return None
    return int(mine[int(np.argmax(lp[mine]))])


def _mean_seen_tb(fog: Fog) -> float:
    """The mean time since seen over ``fog``'s watched places seen at least once
    (inf when none has been)."""
    seen = fog.watched & ~fog.never_seen()
    if not seen.any():
        return math.inf
    return float(fog.t - fog.last[seen].mean())


def stale(top: float, ratio: float, fog: Fog) -> bool:
    """Whether ``top`` (the fog's MTB) exceeds ``ratio`` times the mean time since seen
    of the places ``fog`` has seen: a car's forward wave is then lifted
    (``config.forward_stale``).

    Decided on the fog's running mean (:meth:`~sonarmap.patrol.fog.Fog.mean_seen_tb`)
    unless that is within a millionth of the line, where its last bits could matter:
    then on the mean of the cells, as the rule is stated.

    Parameters
    ----------
    top : float
        The fog's MTB, seconds (a place never seen counts its time since the start).
    ratio : float
        ``config.forward_stale``.
    fog : Fog
        The fog the car chooses by.

    Returns
    -------
    bool
        True when the stalest place is that much staler than the mean; False while no
        place has been seen (the mean is then infinite).
    """
    mean = fog.mean_seen_tb()
    line = ratio * mean
    if math.isfinite(line) and abs(top - line) <= 1e-6 * max(abs(top), abs(line), 1.0):
        return top > ratio * _mean_seen_tb(fog)
    return top > line


def wave_anchors(
    passable: npt.NDArray[np.bool_], watched: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.bool_]]:
    """Per cell, the row and column of the nearest watched cell a wave over
    ``passable`` with the watched cells as its targets can end at (a passable cell, or
    a watched one a step from one): where a car's wave goes for a place that no wave
    reaches (a stub's far corner beyond the last cell its centre may be on), and the
    watched cells that are no such end (a wave's places pull for them from their
    anchors).

    Parameters
    ----------
    passable : ndarray of bool, shape (H, W)
        Where a robot's centre may be.
    watched : ndarray of bool, shape (H, W)
        The places watched.

    Returns
    -------
    rows, cols : ndarray of intp, shape (H, W)
        Per cell, its anchor's row and column (each cell its own when no watched cell
        is a wave's end).
    shade : ndarray of bool, shape (H, W)
        The watched cells no wave ends at.
    """
    from scipy import ndimage

    ends = watched & ndimage.binary_dilation(passable, structure=np.ones((3, 3), dtype=bool))
    if not ends.any():
        own: npt.NDArray[np.intp] = np.indices(passable.shape, dtype=np.intp)
        return own[0], own[1], np.zeros_like(watched)
    _, (ar, ac) = ndimage.distance_transform_edt(~ends, return_indices=True)
    return ar.astype(np.intp), ac.astype(np.intp), watched & ~ends


def nearest_leftover(
    fog: Fog,
    targets: npt.NDArray[np.bool_],
    place: tuple[int, int],
    before: float,
    radius: float,
    shade: npt.NDArray[np.bool_],
) -> tuple[int, int] | None:
    """The nearest of the ``targets`` in ``shade`` (the places no wave reaches:
    beyond the last cell a car's centre may be on and the step past it) within
    ``radius`` metres of ``place`` last seen
    no later than ``before`` (the time ``place`` had last been seen when a car chose it;
    never-seen places are last seen before every time), by ``fog``: a place the look
    that saw ``place`` missed and as worth the trip as it was (``config.leftover``).

    Parameters
    ----------
    fog : Fog
        The car's fog (its ``last`` times and watched cells).
    targets : ndarray of bool, shape (H, W)
        The places the robots go for (the watched ones but those given up).
    place : (int, int)
        The (row, column) of the place the car chose.
    before : float
        The time, seconds, ``place`` had last been seen when the car chose it.
    radius : float
        Metres round ``place`` looked in (``config.leftover``).
    shade : ndarray of bool, shape (H, W)
        The places no wave reaches (:func:`wave_anchors`' third array).

    Returns
    -------
    (int, int) or None
        The (row, column) of the nearest such place; None when there is none.
    """
    res = fog.grid.resolution
    k = math.floor(radius / res + 1e-9)
    r0, c0 = place
    rows, cols = fog.last.shape
    ra, rb, ca, cb = max(0, r0 - k), min(rows, r0 + k + 1), max(0, c0 - k), min(cols, c0 + k + 1)
    window = (fog.last[ra:rb, ca:cb] <= before) & targets[ra:rb, ca:cb] & fog.watched[ra:rb, ca:cb]
    window &= shade[ra:rb, ca:cb]
    rr, cc = np.nonzero(window)
    if not len(rr):
        return None
    d = np.hypot(rr + ra - r0, cc + ca - c0) * res
    near = d <= radius + 1e-9
    if not near.any():
        return None
    j = int(np.flatnonzero(near)[np.argmin(d[near])])
    return int(rr[j] + ra), int(cc[j] + ca)


def aim(
    i: int,
    way: tuple[float, float] | None,
    places: npt.NDArray[np.int64],
    waver: Wave,
    fog: Fog,
    aims: list[tuple[int, int] | None],
    aimed_at: F64,
    config: PatrolConfig,
) -> tuple[int, int] | None:
    """The place robot i goes for on the path motion: the one it keeps while unseen
    since chosen and reachable, else the strongest place along its step ``way``.

    Parameters
    ----------
    i : int
        The robot.
    way : (float, float) or None
        Its chosen direction, or None when it has none.
    places : ndarray of int, shape (8, 2)
        Per wave step, the (row, column) of its strongest place, -1 for none (as
        :func:`~sonarmap.patrol.forces.sector_pulls` fills them).
    waver : Wave
        The robot's wave of this step (whether the kept place is reached).
    fog : Fog
        The robot's fog (when the kept place was last seen).
    aims : list of (int, int) or None
        Per robot, the place it goes for; robot i's is set in place on a new choice.
    aimed_at : ndarray of float, shape (N,)
        Per robot, when (seconds) it chose that place; robot i's is set with it.
    config : PatrolConfig
        ``keep_goal``: whether a place is kept while unseen.

    Returns
    -------
    (int, int) or None
        The (row, column) of the place; None when there is none.
    """
    held = aims[i]
    if (
        config.keep_goal
        and held is not None
        and np.isfinite(waver.dist[held])
        and fog.last[held] < aimed_at[i]
    ):
        return held
    goal = None
    if way is not None:
        r, c = places[nearest_step(*way)]
        goal = None if r < 0 else (int(r), int(c))
    aims[i], aimed_at[i] = goal, fog.t
    return goal
