"""A user's territory mask for a team mission: only the inside of a building, say.

A scanned building drawing is often drawn with its outside free; the largest area a
robot fits in may then be that outside, and the mission's route, its landmarks and a
patrolling team's starts go round the building instead of through it. The patrol's
``--territory`` mask (:mod:`sonarmap.patrol.region`: a map_server YAML whose free cells
are inside, or a polygon file, ``x y`` metres a line) bounds them here as it bounds a
patrol: :func:`read_territory` reads it onto the plan's cells and refuses a mask that
leaves no place a robot fits in; :func:`mask_on` carries it onto another grid of the
same frame (the tour's and the patroller's coarser cells); :func:`territory_record`
is what ``summary.json`` says of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..grid import Grid
from ..io.rosmap import OccupancyMap
from ..patrol.reach import Reach, reach
from ..patrol.region import read_region
from ..patrol.territory import Territory

__all__ = [
    "ROBOT_RADIUS",
    "MissionTerritory",
    "load_territory",
    "mask_on",
    "read_territory",
    "territory_reach",
    "territory_record",
]

#: The mission robots' radius, metres: the one :func:`~.world.patrol_route`,
#: :func:`~.world.route_from_waypoints`, :func:`~.world.make_world` (and its
#: :func:`~.world.facing_cells`, :func:`~.world.territory_faces`) and
#: :func:`~.patrolling.patrol_config` default to.
ROBOT_RADIUS = 0.3


@dataclass(frozen=True)
class MissionTerritory:
    """A mission's territory mask as read once (:func:`load_territory`).

    Attributes
    ----------
    region : ndarray of bool
        The mask on the plan's cells.
    reach : Reach
        What a robot of :data:`ROBOT_RADIUS` reaches inside it (:func:`territory_reach`).
    record : dict
        What ``summary.json`` records of it (:func:`territory_record`).
    """

    region: npt.NDArray[np.bool_]
    reach: Reach
    record: dict[str, Any]

    def first_outside(self, plan: OccupancyMap, x: npt.ArrayLike, y: npt.ArrayLike) -> int:
        """Index of the first position (``x``, ``y`` metres, arrays of the same length)
        off the reached area (:attr:`Reach.watched`: where the robot's body can be once
        its centre is on the largest piece inside the mask), or -1 when none is."""
        xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        r, c = plan.grid.world_to_cell(xs, ys)
        ok = plan.grid.contains(r, c)
        ok[ok] = self.reach.watched[r[ok], c[ok]]
        bad = np.flatnonzero(~ok)
        return int(bad[0]) if len(bad) else -1


def mask_on(region: npt.NDArray[np.bool_], src: Grid, dst: Grid) -> npt.NDArray[np.bool_]:
    """``region`` (a mask on ``src``) on the cells of ``dst``, a grid of the same frame:
    a ``dst`` cell is inside when the ``src`` cell under its centre is (cells beyond
    ``src`` are outside), as :func:`~sonarmap.patrol.region.read_region` reads a mask
    map. ``region`` itself when the grids are the same."""
    if region.shape != src.shape:
        raise ValueError(f"a mask of {region.shape} for a grid of {src.shape}")
    if src == dst:
        return region
    r, c = src.world_to_cell(*dst.all_centres())
    ok = src.contains(r, c)
    out = np.zeros(dst.shape, dtype=bool)
    out[ok] = region[r[ok], c[ok]]
    return out


def territory_reach(
    plan: OccupancyMap, region: npt.NDArray[np.bool_] | None, radius: float = ROBOT_RADIUS
) -> Reach:
    """What a robot of ``radius`` metres reaches of ``plan`` inside ``region`` (a mask on
    the plan's cells; None: the whole plan): :func:`~sonarmap.patrol.reach.reach` with no
    start, so the largest piece it fits in.

    Raises
    ------
    InputError
        No place inside the mask has room for the robot.
    """
    return reach(Territory.from_map(plan), radius, region=region)


def read_territory(
    path: str | Path, plan: OccupancyMap, radius: float = ROBOT_RADIUS
) -> npt.NDArray[np.bool_]:
    """The territory mask of a file (the patrol's formats, :mod:`sonarmap.patrol.region`)
    on the plan's cells.

    Raises
    ------
    InputError
        Naming the file: unreadable or malformed, a mask that covers no cell of the plan,
        or one that leaves no place a robot of ``radius`` metres (0.3) fits in.
    """
    return _read(path, plan, radius)[0]


def load_territory(path: str | Path, plan: OccupancyMap) -> MissionTerritory:
    """:func:`read_territory` and :func:`territory_record` of the file, with the robots'
    reach worked out once.

    Raises
    ------
    InputError
        As :func:`read_territory`.
    """
    region, where = _read(path, plan, ROBOT_RADIUS)
    return MissionTerritory(region, where, territory_record(path, plan, region, where))


def _read(
    path: str | Path, plan: OccupancyMap, radius: float
) -> tuple[npt.NDArray[np.bool_], Reach]:
    region = read_region(path, plan.grid)
    try:
        where = territory_reach(plan, region, radius)
    except InputError as err:
        raise InputError(err.reason, path=path) from None
    return region, where


def territory_record(
    path: str | Path,
    plan: OccupancyMap,
    region: npt.NDArray[np.bool_],
    where: Reach | None = None,
) -> dict[str, Any]:
    """What ``summary.json`` records of the mask a mission used: its file, the free
    area inside it, the area the robots' largest piece covers there (m^2), and the
    patrol's shares of what was left out (:meth:`~sonarmap.patrol.reach.Reach.summary`).
    ``where`` is :func:`territory_reach` of ``region`` when already worked out (default:
    worked out here)."""
    if where is None:
        where = territory_reach(plan, region)
    cell = plan.grid.resolution**2
    free = Territory.from_map(plan).free
    return {
        "file": str(path),
        "free_area_inside_m2": round(float((free & region).sum()) * cell, 3),
        "reached_area_m2": round(float(where.watched.sum()) * cell, 3),
        **where.summary(),
    }
