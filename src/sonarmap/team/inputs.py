"""What a team run is given, chosen and checked as ``team run`` does before any work.

A run's territory (:func:`run_territory`: a mask file, none, the default footprint, or
the mask a saved world was made in) and its world and routes (:func:`draw_world`: the
landmarks and the seeded routes each mission would draw itself, drawn up front so that a
plan with no wall for a landmark or no room for a route fails before the missions
start). The prior map is :func:`~.prior.make_prior`'s.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..io.rosmap import OccupancyMap
from .config import check_team_size
from .territory import (
    NO_TERRITORY,
    MissionTerritory,
    default_territory,
    is_no_territory,
    load_territory,
    mask_file,
    territory_option,
)
from .world import ROUTE_SEED_STEP, World, make_world, patrol_route, world_territory

__all__ = [
    "ROUTE_SEED_STEP",
    "RunTerritory",
    "TerritoryHow",
    "check_world_territory",
    "draw_world",
    "mission_routes",
    "run_territory",
]

F64 = npt.NDArray[np.float64]

#: Where a run's territory came from (:attr:`RunTerritory.how`).
TerritoryHow = Literal["file", "none", "skipped", "world", "default"]


@dataclass(frozen=True)
class RunTerritory:
    """A run's territory (:func:`run_territory`).

    Attributes
    ----------
    mask : MissionTerritory or None
        The mask, None for the whole map.
    record : dict or None
        What ``summary.json`` records of it (None: nothing).
    how : {"file", "none", "skipped", "world", "default"}
        Where it came from: ``"file"`` (a mask file), ``"none"`` (:data:`NO_TERRITORY`),
        ``"skipped"`` (a route of the user's: the whole map), ``"world"`` (the mask a
        saved world was made in) or ``"default"`` (:func:`default_territory`, which may
        be None).
    file : Path or None
        The mask file given, if any.
    """

    mask: MissionTerritory | None
    record: dict[str, Any] | None
    how: TerritoryHow
    file: Path | None = None

    @property
    def region(self) -> npt.NDArray[np.bool_] | None:
        """The mask on the plan's cells, None for the whole map."""
        return None if self.mask is None else self.mask.region

    def node_value(self) -> Path | None:
        """The ``territory`` to hand a ZeroMQ team's nodes
        (:func:`~.launcher.run_zmq_team`) so that each works out this same mask: the
        file, None for the default footprint (each node works it out alike), or
        :data:`NO_TERRITORY` for the whole map."""
        if self.file is not None:
            return self.file
        return None if self.mask is not None else Path(NO_TERRITORY)


def check_world_territory(territory: str | Path | None, world: str | Path | None) -> None:
    """Refuse a mask file together with a saved world, which carries its own landmarks
    and route (made inside the mask it was given, if any).

    Raises
    ------
    ConfigError
        Both given.
    """
    if mask_file(territory) is not None and world is not None:
        raise ConfigError(
            "--world carries its own landmarks and route: give --territory to 'team world' "
            "instead, or drop --world"
        )


def run_territory(
    territory: str | Path | None,
    plan: OccupancyMap,
    *,
    route_given: bool = False,
    world: str | Path | None = None,
) -> RunTerritory:
    """A run's territory, by ``team run``'s rule.

    Parameters
    ----------
    territory : str or Path or None
        A mask file (:func:`~.territory.load_territory`), :data:`NO_TERRITORY` (the whole
        map, recorded as ``"default": "none"``) or None for the default.
    plan : OccupancyMap
        The plan.
    route_given : bool
        A route of the user's is followed as given: the default footprint is skipped
        (recorded, with why, when the plan is a drawn one). Default False.
    world : str or Path, optional
        A folder made by :func:`~.world.save_world`: without a mask file, the mask that
        world was made in (none when it was made on the whole map).

    Returns
    -------
    RunTerritory
        By the first rule that applies: ``territory`` :data:`NO_TERRITORY` -> no mask,
        ``how="none"``; a mask file -> that mask, ``how="file"``, ``file`` set;
        ``route_given`` -> no mask, ``how="skipped"`` (recorded only when the default
        would have applied); ``world`` -> the mask it was made in (none if on the whole
        map), ``how="world"``; otherwise the default footprint
        (:func:`~.territory.default_territory`, None on a plan that has none),
        ``how="default"``. ``record`` is what ``summary.json`` records of it.

    Raises
    ------
    ConfigError
        A mask file together with ``world`` (:func:`check_world_territory`), or a mask
        file that cannot be read or leaves no room (naming ``--territory``).
    InputError
        A saved world's mask that cannot be read.
    """
    check_world_territory(territory, world)
    if is_no_territory(territory):
        return RunTerritory(None, {"file": None, "default": NO_TERRITORY}, "none")
    if territory is not None:
        mask = territory_option(territory, plan)
        return RunTerritory(mask, None if mask is None else mask.record, "file", Path(territory))
    if route_given:
        skipped = default_territory(plan)
        if skipped is None:
            return RunTerritory(None, None, "skipped")
        record = {
            "file": None,
            "default": "skipped",
            "why": "a --route of the user's: followed as given, on the whole map",
            "footprint_would_leave_out_free_area_m2": skipped.record["left_out_free_area_m2"],
        }
        return RunTerritory(None, record, "skipped")
    if world is not None:
        saved = world_territory(world)
        if saved is None:
            return RunTerritory(None, None, "world")
        mask = load_territory(saved[0], plan)
        record = {**mask.record, "default": "world", "world_territory_from": saved[1]}
        return RunTerritory(mask, record, "world")
    mask = default_territory(plan)
    return RunTerritory(mask, None if mask is None else mask.record, "default")


def mission_routes(
    plan: OccupancyMap,
    duration: float,
    *,
    seed: int,
    robots: int,
    style: str = "waypoints",
    region: npt.NDArray[np.bool_] | None = None,
    given: Mapping[int, F64 | None] | None = None,
) -> dict[int, F64]:
    """Each robot's route as its mission would draw it itself: robot ``i``'s
    :func:`~.world.patrol_route` from ``seed + ROUTE_SEED_STEP * i``.

    Parameters
    ----------
    plan : OccupancyMap
        The plan.
    duration : float
        The mission's seconds.
    seed : int
        The mission's seed.
    robots : int
        Robots, ids ``0..robots-1``.
    style : str
        :func:`~.world.patrol_route`'s ``style`` (default ``"waypoints"``).
    region : ndarray of bool, optional
        The territory mask on the plan's cells.
    given : mapping, optional
        Robot id -> a route of the caller's (ndarray (T, 4): t, x, y, theta), kept as
        it is; the others are drawn.

    Returns
    -------
    dict
        Robot id -> route, for every robot.

    Raises
    ------
    ConfigError
        ``robots`` not a team size ``team run`` takes (:func:`~.config.check_team_size`).
    """
    check_team_size(robots)
    routes = {i: r for i, r in (given or {}).items() if r is not None}
    for i in range(robots):
        if routes.get(i) is None:
            routes[i] = patrol_route(
                plan, duration, seed=seed + ROUTE_SEED_STEP * i, style=style, region=region
            )
    return routes


def draw_world(
    plan: OccupancyMap,
    duration: float,
    *,
    seed: int,
    robots: int,
    region: npt.NDArray[np.bool_] | None = None,
    routes: Mapping[int, F64 | None] | None = None,
) -> tuple[World, dict[int, F64]]:
    """The world and every robot's route that the missions would draw themselves (the
    same seeds, so the same runs), drawn up front inside ``region``.

    Parameters
    ----------
    plan : OccupancyMap
        The plan.
    duration : float
        The mission's seconds.
    seed : int
        The mission's seed.
    robots : int
        Robots, ids ``0..robots-1``.
    region : ndarray of bool, optional
        The territory mask on the plan's cells (None: the whole plan).
    routes : mapping, optional
        Routes of the caller's by robot id (:func:`mission_routes`' ``given``).

    Returns
    -------
    (World, dict)
        The world (:func:`~.world.make_world`) and robot id -> route.

    Raises
    ------
    InputError, ConfigError
        A plan with no wall for a landmark or no room for a route inside ``region``;
        ``robots`` not a team size ``team run`` takes (:func:`~.config.check_team_size`,
        before any work).
    """
    check_team_size(robots)
    world = make_world(plan, seed=seed, duration=duration, region=region)
    drawn = mission_routes(plan, duration, seed=seed, robots=robots, region=region, given=routes)
    return world, drawn
