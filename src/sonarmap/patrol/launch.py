"""A run's robots put on the map: the starts given checked (:func:`check_given_starts`)
or spread over the reachable territory (:func:`place_robots`; cars where they can move,
:func:`car_starts`), and the team built at them (:func:`build_team`).

The start files and the spreading itself are :mod:`.starts`'s; this module applies them
to a run's configuration.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from .reach import Reach, reach
from .robots import Car, Holonomic, Team
from .settings import PatrolConfig
from .starts import CarStarts, StartSource, check_starts, spread_starts
from .territory import Territory

__all__ = ["build_team", "car_starts", "check_given_starts", "place_robots"]

F64 = npt.NDArray[np.float64]


def car_starts(
    territory: Territory, passable: npt.NDArray[np.bool_], config: PatrolConfig
) -> CarStarts:
    """Where ``config``'s cars can start on ``passable`` and facing where
    (:class:`~sonarmap.patrol.starts.CarStarts`: its turning radius, speed rule and
    step)."""
    return CarStarts(territory, passable, config.turn_radius, config.speed_bands, config.dt)


def check_given_starts(
    starts: F64,
    territory: Territory,
    config: PatrolConfig,
    region: npt.NDArray[np.bool_] | None = None,
    source: StartSource | None = None,
) -> Reach:
    """Refuse given starts the run cannot use; the territory reachable from them.

    Every start inside the map (and ``region``), on a free cell the robot's radius fits,
    ``config.min_separation`` from the others; for cars, a pose some step's arc leaves
    (:meth:`~sonarmap.patrol.starts.CarStarts.check`).

    Parameters
    ----------
    starts : ndarray (N, 3)
        World (x, y, heading) per robot.
    territory : Territory
        The map.
    config : PatrolConfig
        The run's configuration (radius, separation, reach, the car's turning).
    region : ndarray of bool, optional
        The user's territory mask on the territory's grid; default None (the whole map).
    source : StartSource, optional
        Where the starts came from, for the message (a start file's path and lines);
        default: world poses.

    Returns
    -------
    Reach
        What the team can patrol from these starts (:func:`~sonarmap.patrol.reach.reach`).

    Raises
    ------
    InputError
        The first start refused, naming the robot and its pose (and file and line).
    """
    inside = territory.passable(config.radius)
    if region is not None:
        inside = inside & region
    check_starts(starts, territory, inside, config.min_separation, source)
    rc = np.column_stack(territory.grid.world_to_cell(starts[:, 0], starts[:, 1]))
    where = reach(
        territory,
        config.radius,
        starts=rc,
        region=region,
        mode=config.reach,
        vision=config.vision,
    )
    if config.model == "car":
        # A car that can never move from its start would waste the run.
        car_starts(territory, where.passable, config).check(starts, source)
    return where


def place_robots(
    territory: Territory,
    config: PatrolConfig,
    starts: F64 | None,
    robots: int | None,
    seed: int,
    *,
    region: npt.NDArray[np.bool_] | None = None,
    start_source: StartSource | None = None,
) -> tuple[F64, Reach]:
    """A run's starts and the territory it patrols from them: the given ``starts``
    checked (:func:`check_given_starts`), else ``robots`` starts spread over the
    reachable territory with ``seed`` (cars by :func:`car_starts`, other robots by
    :func:`~sonarmap.patrol.starts.spread_starts`).

    Parameters
    ----------
    territory : Territory
        The map.
    config : PatrolConfig
        The run's configuration.
    starts : ndarray (N, 3) or None
        World (x, y, heading) per robot, or None to spread ``robots`` of them.
    robots : int or None
        How many robots to spread when ``starts`` is None.
    seed : int
        Seeds the spreading (the first robot's cell).
    region : ndarray of bool, optional
        The user's territory mask on the territory's grid; default None (the whole map).
    start_source : StartSource, optional
        Where ``starts`` came from, named when one is refused; default: world poses.

    Returns
    -------
    starts : ndarray (N, 3)
        The starts, given or spread.
    where : Reach
        What the team can patrol from them (:func:`~sonarmap.patrol.reach.reach`).

    Raises
    ------
    ConfigError
        Neither starts nor a number of robots >= 1.
    InputError
        A start refused (:func:`check_given_starts`); nothing to patrol.
    """
    if starts is not None:
        return starts, check_given_starts(starts, territory, config, region, start_source)
    if robots is None or robots < 1:
        raise ConfigError("give start positions or a number of robots >= 1")
    where = reach(territory, config.radius, region=region, mode=config.reach, vision=config.vision)
    if config.model == "car":
        spread = car_starts(territory, where.passable, config).spread(
            robots, config.min_separation, seed
        )
    else:
        spread = spread_starts(robots, territory, where.passable, config.min_separation, seed)
    return spread, where


def build_team(starts: F64, territory: Territory, config: PatrolConfig) -> Team:
    """The team of ``config``'s robots (:class:`~sonarmap.patrol.robots.Car` or
    :class:`~sonarmap.patrol.robots.Holonomic`) at ``starts``.

    Parameters
    ----------
    starts : ndarray (N, 3)
        World (x, y, heading) per robot; copied, not kept.
    territory : Territory
        The map (a car's speed rule reads its clearance).
    config : PatrolConfig
        The robot model and its numbers (radius, separation, speed, turning, the
        ``give-way`` traffic rule).

    Returns
    -------
    Team
        The robots, standing at their starts.
    """
    if config.model == "car":
        return Car(
            starts[:, 0].copy(),
            starts[:, 1].copy(),
            starts[:, 2].copy(),
            radius=config.radius,
            min_separation=config.min_separation,
            p_random=config.p_random,
            give_way=config.traffic == "give-way",
            clearance=territory.clearance,
            turn_radius=config.turn_radius,
            bands=config.speed_bands,
            planner=config.car_planner,
        )
    return Holonomic(
        starts[:, 0].copy(),
        starts[:, 1].copy(),
        starts[:, 2].copy(),
        radius=config.radius,
        speed=config.speed,
        min_separation=config.min_separation,
        p_random=config.p_random,
        give_way=config.traffic == "give-way",
    )
