"""Where a robot heads for the place it goes for: a holonomic robot's step along the
wave's shortest path (:func:`path_goal`), a car's route and pure-pursuit point
(:func:`car_carrot`, driving on round the block with ``round_block``), a kept place's
point from a wave run only as far as it (:func:`held_goal`), and the baselines' steps
along the tour (:func:`follow_tour`) and the patrol graph (:func:`walk_step`).

:mod:`.goals` chooses the place; :func:`~sonarmap.patrol.simulation.run_patrol` moves the
robots towards the points found here.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from ..grid import Grid
from .fog import Fog
from .manoeuvre import behind_cells, carrot
from .paths import STEP_UNITS, Wave, path_to
from .robots import Car, Team
from .settings import PatrolConfig
from .territory import move_clear
from .walkers import GraphWalkers

__all__ = ["car_carrot", "follow_tour", "held_goal", "path_goal", "unit_towards", "walk_step"]

F64 = npt.NDArray[np.float64]


def follow_tour(
    i: int,
    tour: npt.NDArray[np.int64],
    target: npt.NDArray[np.int64],
    dist: F64,
    first: npt.NDArray[np.int8],
    config: PatrolConfig,
) -> tuple[float, float] | None:
    """Robot i's step along the tour (policy ``cycle``): towards its waypoint, the next
    one once within a step of it.

    Parameters
    ----------
    i : int
        The robot.
    tour : ndarray of int, shape (K, 2)
        The tour's waypoints, (row, column) cells (:func:`~sonarmap.patrol.tour.plan_tour`).
    target : ndarray of int, shape (N,)
        Per robot, the index of its waypoint in ``tour``; robot i's advances in place.
    dist, first : ndarray, shape (H, W)
        The robot's wave of this step: path lengths (metres) and first steps (an index
        into :data:`~sonarmap.patrol.paths.STEP_UNITS`, -1 for none).
    config : PatrolConfig
        ``speed`` and ``dt``: how far one step goes.

    Returns
    -------
    (float, float) or None
        The unit step towards the waypoint; None when the wave reaches none.
    """
    for _ in range(len(tour)):
        tr, tc = tour[target[i]]
        # Within one step counts as there: a move of a full step along one of 8
        # directions could otherwise circle the waypoint for ever.
        if first[tr, tc] >= 0 and dist[tr, tc] > config.speed * config.dt:
            k = int(first[tr, tc])
            return float(STEP_UNITS[k, 0]), float(STEP_UNITS[k, 1])
        target[i] = (target[i] + 1) % len(tour)
    return None


def walk_step(
    i: int,
    walkers: GraphWalkers,
    waver: Wave,
    fog: Fog,
    config: PatrolConfig,
    heard: npt.NDArray[np.bool_],
    stuck: bool,
) -> tuple[float, float] | None:
    """Robot i's step towards its graph vertex, the next one once within a step of it,
    another one when it cannot be reached or ``stuck`` (it gave way and was blocked
    again: two walkers head-on on one edge push against each other for good otherwise);
    None (stand) while no neighbour can be reached.

    Parameters
    ----------
    i : int
        The robot.
    walkers : GraphWalkers
        The graph walkers' state (their vertices, updated in place on arriving or
        rerouting).
    waver : Wave
        The robot's wave of this step.
    fog : Fog
        The robot's fog (the vertices' idleness).
    config : PatrolConfig
        ``speed`` and ``dt``: how far one step goes.
    heard : ndarray of bool, shape (N,)
        The robots whose intentions robot i hears.
    stuck : bool
        Whether it gave way and was blocked again.

    Returns
    -------
    (float, float) or None
        The unit step along the wave's first step; None to stand.
    """
    r, c = walkers.goal_cell(i)
    cells = walkers.graph.cells
    if waver.dist[r, c] <= config.speed * config.dt:
        walkers.arrive(i, fog.t, fog.last[cells[:, 0], cells[:, 1]], heard)
        r, c = walkers.goal_cell(i)
    if stuck or not np.isfinite(waver.dist[r, c]):
        reachable = np.isfinite(waver.dist[cells[:, 0], cells[:, 1]])
        walkers.reroute(i, fog.t, fog.last[cells[:, 0], cells[:, 1]], reachable, heard)
        r, c = walkers.goal_cell(i)
    k = int(waver.first[r, c])
    if k < 0:
        return None
    return float(STEP_UNITS[k, 0]), float(STEP_UNITS[k, 1])


def path_goal(
    team: Team,
    i: int,
    cell: tuple[int, int] | None,
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    config: PatrolConfig,
) -> tuple[float, float] | None:
    """Where robot i gets to in one step along the wave's shortest path to ``cell``
    (the path motion).

    Parameters
    ----------
    team : Team
        The robots (world metres).
    i : int
        The robot.
    cell : (int, int) or None
        The (row, column) of the place it goes for.
    waver : Wave
        A wave from the robot's cell that reached ``cell``.
    g : Grid
        The map's grid.
    passable : ndarray of bool, shape (H, W)
        Where a robot's centre may be.
    config : PatrolConfig
        ``speed`` and ``dt``: how far one step goes.

    Returns
    -------
    (float, float) or None
        The world point, the farthest along the path the robot can reach in a straight
        line within one step; None when there is no cell, the wave did not reach it,
        the robot stands on it, or no part of the step is clear.
    """
    if cell is None or not np.isfinite(waver.dist[cell]) or waver.dist[cell] <= 0:
        return None
    cells = path_to(waver.dist, cell, g.resolution, passable, waver.allowed)
    px, py = g.cell_centres(cells[1:, 0], cells[1:, 1])
    x0, y0 = float(team.x[i]), float(team.y[i])
    x, y = x0, y0
    left = config.speed * config.dt
    # The farthest point a step along the path reaches that the robot can go to in a
    # straight line (a corner of the path may hide the rest).
    reach: tuple[float, float] | None = None
    for qx, qy in zip(px.tolist(), py.tolist(), strict=True):
        d = math.hypot(qx - x, qy - y)
        end = (x + (qx - x) * left / d, y + (qy - y) * left / d) if d >= left else (qx, qy)
        if not move_clear(x0, y0, end[0], end[1], passable, g):
            break
        reach = end
        if d >= left:
            break
        x, y, left = qx, qy, left - d
    return reach


def held_goal(
    team: Team,
    i: int,
    start: tuple[int, int],
    held: tuple[int, int],
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    watched: npt.NDArray[np.bool_],
    closed: npt.NDArray[np.intp] | None,
    config: PatrolConfig,
    towards: Callable[..., tuple[float, float] | None],
) -> tuple[float, float] | None:
    """Robot i's point ahead towards the place it keeps going for, from a wave run only
    as far as that place.

    Parameters
    ----------
    team : Team
        The robots.
    i : int
        The robot.
    start : (int, int)
        The robot's cell.
    held : (int, int)
        The cell of the place it keeps going for (or the anchor of a leftover).
    waver : Wave
        The wave, run here from ``start`` until it reaches ``held``.
    g : Grid
        The map's grid.
    passable : ndarray of bool, shape (H, W)
        Where a robot's centre may be.
    watched : ndarray of bool, shape (H, W)
        The wave's targets.
    closed : ndarray of int, shape (K, 2), or None
        Cells closed on the robot's map (its crowding cells).
    config : PatrolConfig
        The run's configuration, passed on to ``towards``.
    towards : callable
        :func:`path_goal` or :func:`car_carrot` (with its keywords bound), called with
        ``(team, i, held, waver, g, passable, config)``.

    Returns
    -------
    (float, float) or None
        ``towards``'s point; None when the place cannot be reached or there is no point
        off the robot.
    """
    if not np.isfinite(waver.to(passable, start, held, g.resolution, watched, closed)):
        return None
    point: tuple[float, float] | None = towards(team, i, held, waver, g, passable, config)
    if (
        point is None
        or math.hypot(point[0] - float(team.x[i]), point[1] - float(team.y[i])) <= 1e-9
    ):
        return None
    return point


def unit_towards(team: Team, i: int, point: tuple[float, float]) -> tuple[float, float]:
    """The unit vector from robot i to ``point``.

    Parameters
    ----------
    team : Team
        The robots (world metres).
    i : int
        The robot.
    point : (float, float)
        A world point, not at the robot.

    Returns
    -------
    (float, float)
        The unit vector.
    """
    dx, dy = point[0] - float(team.x[i]), point[1] - float(team.y[i])
    n = math.hypot(dx, dy)
    return dx / n, dy / n


def car_carrot(
    team: Team,
    i: int,
    cell: tuple[int, int] | None,
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    config: PatrolConfig,
    targets: npt.NDArray[np.bool_] | None = None,
    closed: Callable[[], npt.NDArray[np.intp] | None] | None = None,
    stand: npt.NDArray[np.int64] | None = None,
) -> tuple[float, float] | None:
    """Car i's route (the wave's shortest path to ``cell``, set on the car) and its
    pure-pursuit point ``config.lookahead`` metres along it; None when there is none.

    ``stand`` (:func:`~sonarmap.patrol.stubs.stand_points`): a place in a stub with a
    stand point the wave has reached (not the car's own cell) is gone for by the route
    to that point instead, from which the car sees it.

    With ``config.round_block`` a route whose pursuit point lies behind the car is
    replaced by the shortest one that leaves forwards (:func:`_forward_route`), when
    that is at most ``round_block`` metres longer: ``targets`` are the wave's targets
    and ``closed()`` the cells closed on it (without the discs round the cars ahead
    going the car's way, which it follows). ``waver`` may then hold that wave.

    Parameters
    ----------
    team : Car
        The cars; car i's route (:attr:`~sonarmap.patrol.robots.Car.routes`) is set in
        place (None when there is none).
    i : int
        The car.
    cell : (int, int) or None
        The (row, column) of the place it goes for.
    waver : Wave
        A wave from the car's cell that reached ``cell``.
    g : Grid
        The map's grid.
    passable : ndarray of bool, shape (H, W)
        Where a car's centre may be.
    config : PatrolConfig
        ``lookahead`` and ``round_block``.
    targets : ndarray of bool, shape (H, W), optional
        The wave's targets, for the forward wave (default None).
    closed : callable, optional
        Returns the cells closed on the forward wave (default None: none).
    stand : ndarray of int, shape (H, W), optional
        Per cell the flat index of its stand point, -1 for none (default None).

    Returns
    -------
    (float, float) or None
        The pure-pursuit point, world metres; None when the wave did not reach the
        place or the car stands on it.
    """
    assert isinstance(team, Car)
    team.routes[i] = None
    if stand is not None and cell is not None and stand[cell] >= 0:
        at = (int(stand[cell]) // stand.shape[1], int(stand[cell]) % stand.shape[1])
        if np.isfinite(waver.dist[at]) and waver.dist[at] > 0:
            cell = at
    if cell is None or not np.isfinite(waver.dist[cell]) or waver.dist[cell] <= 0:
        return None
    x, y = float(team.x[i]), float(team.y[i])
    route = _route(team, i, path_to(waver.dist, cell, g.resolution, passable, waver.allowed), g)
    point = carrot(route, x, y, config.lookahead)
    if config.round_block > 0 and team.is_behind(i, point):
        shut = closed() if closed is not None else None
        forward = _forward_route(team, i, cell, waver, g, passable, config, targets, shut)
        if forward is not None:
            route = forward
            point = carrot(route, x, y, config.lookahead)
    team.routes[i] = route
    return point


def _route(team: Team, i: int, cells: npt.NDArray[np.int64], g: Grid) -> F64:
    """World points (K, 2) of a path's ``cells``, the first at robot i itself."""
    px, py = g.cell_centres(cells[:, 0], cells[:, 1])
    route = np.column_stack([px, py]).astype(np.float64)
    route[0] = team.x[i], team.y[i]
    return route


def _forward_route(
    team: Car,
    i: int,
    cell: tuple[int, int],
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    config: PatrolConfig,
    targets: npt.NDArray[np.bool_] | None,
    closed: npt.NDArray[np.intp] | None,
) -> F64 | None:
    """Car i's shortest route to ``cell`` with the cells up to 4 m behind it closed (it
    drives on and round the block), if that is at most ``config.round_block`` metres
    longer than the shortest (``waver.dist`` on entry); None otherwise, or at a dead
    end (no such route). Runs a wave on ``waver``."""
    r, c = (int(v) for v in g.world_to_cell(team.x[i], team.y[i]))
    back = behind_cells(float(team.x[i]), float(team.y[i]), float(team.heading[i]), g)
    shut = back if closed is None else np.concatenate([closed, back])
    limit = float(waver.dist[cell]) + config.round_block
    length = waver.to(passable, (r, c), cell, g.resolution, targets, shut, limit=limit)
    if not np.isfinite(length):
        return None
    return _route(team, i, path_to(waver.dist, cell, g.resolution, passable, waver.allowed), g)
