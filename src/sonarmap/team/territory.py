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

Without a mask a mission's territory is the default (:func:`default_territory`): on a
drawn plan whose outside is free (:func:`footprint`: no unknown cell, a free margin all
round, one building, and a footprint that a much wider disc confirms), the building's
footprint, its walls grown by a disc a door wide before their holes are filled, so that
an open entrance does not join the inside to the outside; elsewhere (a SLAM map, the
built-in maps, a plan whose entrance is wider than a door) the whole map.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import ConfigError, InputError
from ..grid import Grid
from ..io.rosmap import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from ..patrol.reach import Reach, reach
from ..patrol.region import read_region
from ..patrol.territory import Territory

__all__ = [
    "DOOR_WIDTH",
    "NO_TERRITORY",
    "ROBOT_RADIUS",
    "Footprint",
    "MissionTerritory",
    "building_footprint",
    "check_route_inside",
    "default_territory",
    "footprint",
    "is_no_territory",
    "load_territory",
    "mask_file",
    "mask_on",
    "read_territory",
    "territory_of",
    "territory_option",
    "territory_reach",
    "territory_record",
]

#: The mission robots' radius, metres: the one :func:`~.world.patrol_route`,
#: :func:`~.world.route_from_waypoints`, :func:`~.world.make_world` (and its
#: :func:`~.world.facing_cells`, :func:`~.world.territory_faces`) and
#: :func:`~.patrolling.patrol_config` default to.
ROBOT_RADIUS = 0.3

#: Metres: the widest opening in a drawn plan's outer wall (an entrance) that
#: :func:`building_footprint` bridges, the diameter of its disc.
DOOR_WIDTH = 1.5

#: What ``--territory`` takes for "no mask, not even the default": the whole map.
NO_TERRITORY = "none"


def is_no_territory(path: str | Path | None) -> bool:
    """Whether a ``--territory`` value is :data:`NO_TERRITORY` (the whole map); False
    for None (the default) and for a mask file."""
    return path is not None and str(path) == NO_TERRITORY


#: A drawn plan (:func:`footprint`): at most this share of its cells unknown ...
_UNKNOWN_SHARE = 0.01
#: ... at least this share of its border cells free and off the footprint ...
_MARGIN_SHARE = 0.99
#: ... at least this share of its occupied cells in the footprint's largest piece ...
_BUILDING_SHARE = 0.9
#: ... and the free cells its footprint leaves out the same, within this share of the
#: free cells inside either footprint, as those left out by the footprint of a disc this
#: many metres across: an entrance wider than :data:`DOOR_WIDTH` joins the inside to the outside
#: for the door-wide disc but not for the wide one, and the two then disagree by the
#: inside's free area.
_AGREE_SHARE = 0.01
_CHECK_WIDTH = 4.0


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
    path: str | Path | None,
    plan: OccupancyMap,
    region: npt.NDArray[np.bool_],
    where: Reach | None = None,
) -> dict[str, Any]:
    """What ``summary.json`` records of the mask a mission used: its file (None for the
    default footprint), the free area inside it, the area the robots' largest piece
    covers there (m^2), and the patrol's shares of what was left out
    (:meth:`~sonarmap.patrol.reach.Reach.summary`).
    ``where`` is :func:`territory_reach` of ``region`` when already worked out (default:
    worked out here)."""
    if where is None:
        where = territory_reach(plan, region)
    cell = plan.grid.resolution**2
    free = Territory.from_map(plan).free
    return {
        "file": None if path is None else str(path),
        "free_area_inside_m2": round(float((free & region).sum()) * cell, 3),
        "reached_area_m2": round(float(where.watched.sum()) * cell, 3),
        **where.summary(),
    }


@dataclass(frozen=True)
class Footprint:
    """A plan's building footprint and whether the plan is a drawn one whose outside is
    free (:func:`footprint`).

    Attributes
    ----------
    region : ndarray of bool
        The footprint on the plan's cells (:func:`building_footprint`; all False when
        the plan's checks stopped before it was worked out).
    drawn : bool
        The plan is a drawn plan with a free outside: the footprint is its default
        territory.
    why : str
        Why (or why not), one phrase naming the check that decided.
    unknown_share, margin_share, building_share : float
        The plan's unknown share of cells, the share of its border cells free and off the
        footprint, and the share of its occupied cells in the footprint's largest piece
        (NaN when not worked out).
    disagreement : float
        The free cells left out by this footprint or by the 4 m disc's but not by both,
        as a share of the free cells inside either (NaN when not worked out).
    reach : Reach or None
        What a robot reaches inside the footprint (:func:`territory_reach`), when the
        plan is drawn; None otherwise.
    """

    region: npt.NDArray[np.bool_]
    drawn: bool
    why: str
    unknown_share: float
    margin_share: float
    building_share: float
    disagreement: float = float("nan")
    reach: Reach | None = None

    def figures(self) -> dict[str, Any]:
        """The checks' figures, rounded for ``summary.json`` (the unknown share as
        ``plan_unknown_share``: :meth:`~sonarmap.patrol.reach.Reach.summary` has an
        ``unknown_share`` of its own in the same record)."""
        return {
            "why": self.why,
            "plan_unknown_share": _rounded(self.unknown_share),
            "margin_share": _rounded(self.margin_share),
            "building_share": _rounded(self.building_share),
            "wide_disc_disagreement": _rounded(self.disagreement),
            "wide_disc_width_m": _CHECK_WIDTH,
        }


def _rounded(x: float) -> float | None:
    return None if np.isnan(x) else round(float(x), 4)


def _border(shape: tuple[int, ...]) -> npt.NDArray[np.bool_]:
    edge = np.zeros(shape, dtype=bool)
    edge[0, :] = edge[-1, :] = edge[:, 0] = edge[:, -1] = True
    return edge


def building_footprint(plan: OccupancyMap, door_width: float = DOOR_WIDTH) -> npt.NDArray[np.bool_]:
    """The plan's building footprint: its occupied cells grown by a disc ``door_width``
    metres across (radius ``ceil(door_width / 2 / resolution)`` cells), which bridges any
    opening in a wall up to a door wide, thin walls' included; the holes of that filled;
    and the whole shrunk back by the same disc, so that its outer edge returns to the
    outer wall (an opening keeps a notch a few cells deep). A closing with the holes
    filled between its halves; a plain closing would leave an opening in a one-cell
    wall open. Distance transforms on the map padded by the radius, so that the image's
    edge does not cut the disc."""
    r = int(np.ceil(0.5 * door_width / plan.grid.resolution - 1e-9))
    walls = np.pad(plan.classes() == OCCUPIED, r + 1)
    grown = ndimage.distance_transform_edt(~walls) <= r
    filled = ndimage.binary_fill_holes(grown)
    shrunk = (ndimage.distance_transform_edt(filled) > r) | walls
    return np.asarray(shrunk[r + 1 : -r - 1, r + 1 : -r - 1], dtype=bool)


def footprint(
    plan: OccupancyMap, door_width: float = DOOR_WIDTH, radius: float = ROBOT_RADIUS
) -> Footprint:
    """The plan's building footprint (:func:`building_footprint`) and whether the
    plan is a drawn plan with a free outside: at most 1 % of its cells unknown, at
    least 99 % of its border cells free and off the footprint (a drawing's margin), at
    least 90 % of its occupied cells in the footprint's largest 8-connected piece (one
    building), the free cells it leaves out the same, within 1 % of the free cells
    inside either footprint, as those a 4 m disc's footprint leaves out (an entrance
    wider than a door: the narrow disc would leave the rooms behind it out, the wide one
    would not), and room inside the footprint for a robot of ``radius`` metres. The
    cheap checks come first, so a SLAM map with unknown cells or a walled border costs
    no footprint."""
    cls = plan.classes()
    nan = float("nan")
    none = np.zeros(cls.shape, dtype=bool)
    unknown = float((cls == UNKNOWN).mean())
    if unknown > _UNKNOWN_SHARE:
        return Footprint(none, False, "unknown cells: not a drawn plan", unknown, nan, nan)
    edge = _border(cls.shape)
    if float((cls[edge] == FREE).mean()) < _MARGIN_SHARE:
        why = "border not free all round: not a drawn plan with a free outside"
        return Footprint(none, False, why, unknown, float((cls[edge] == FREE).mean()), nan)
    region = building_footprint(plan, door_width)
    margin = float(((cls == FREE) & ~region)[edge].mean())
    walls = cls == OCCUPIED
    labels, n = ndimage.label(region, structure=np.ones((3, 3), dtype=bool))
    per = np.bincount(labels[walls], minlength=n + 1)[1:] if n else np.zeros(1)
    building = float(per.max() / max(1, walls.sum()))
    if margin < _MARGIN_SHARE:
        why = "the footprint reaches the border: not a drawn plan with a free outside"
        return Footprint(region, False, why, unknown, margin, building)
    if building < _BUILDING_SHARE:
        why = "walls in pieces, not one building"
        return Footprint(region, False, why, unknown, margin, building)
    free = cls == FREE
    wide = building_footprint(plan, max(door_width, _CHECK_WIDTH))
    # Of the free cells inside either footprint, not of the plan's: a wide margin
    # round a small building must not dilute a lost room.
    differ = float((free & (region != wide)).sum() / max(1, (free & (region | wide)).sum()))
    if differ >= _AGREE_SHARE:
        why = (
            f"the footprint of a {_CHECK_WIDTH:g} m disc differs by {100 * differ:.1f} % of "
            f"its free cells: an opening wider than {door_width:g} m joins inside and outside"
        )
        return Footprint(region, False, why, unknown, margin, building, differ)
    try:
        where = territory_reach(plan, region, radius)
    except InputError:
        why = "no room for a robot inside the footprint"
        return Footprint(region, False, why, unknown, margin, building, differ)
    why = "a drawn plan: no unknown cells, a free margin all round, one building"
    return Footprint(region, True, why, unknown, margin, building, differ, where)


def default_territory(plan: OccupancyMap) -> MissionTerritory | None:
    """A mission's territory when no mask is given: the building's footprint on a drawn
    plan whose outside is free (:func:`footprint`), None (the whole map) elsewhere. Its
    record adds to :func:`territory_record`'s the default's name, the free area left out
    (m^2) and the checks' figures (:meth:`Footprint.figures`)."""
    fp = footprint(plan)
    if not fp.drawn or fp.reach is None:
        return None
    where = fp.reach
    free = plan.classes() == FREE
    record = {
        "default": "footprint",
        **territory_record(None, plan, fp.region, where),
        "left_out_free_area_m2": round(
            float((free & ~fp.region).sum()) * plan.grid.resolution**2, 3
        ),
        "door_width_m": DOOR_WIDTH,
        **fp.figures(),
    }
    return MissionTerritory(fp.region, where, record)


def territory_of(value: str | Path | None, plan: OccupancyMap) -> MissionTerritory | None:
    """A ``--territory`` value's mask on ``plan``, as ``team run``, ``team world`` and
    ``team node`` read it: None (the option not given) is the default
    (:func:`default_territory`), :data:`NO_TERRITORY` the whole map (None), anything
    else a mask file (:func:`load_territory`).

    Raises
    ------
    InputError
        As :func:`load_territory`.
    """
    if value is None:
        return default_territory(plan)
    if is_no_territory(value):
        return None
    return load_territory(value, plan)


def mask_file(value: str | Path | None) -> Path | None:
    """The mask file a ``--territory`` value names: None for the default (None) and for
    :data:`NO_TERRITORY`."""
    return None if value is None or is_no_territory(value) else Path(value)


def territory_option(
    value: str | Path | None, plan: OccupancyMap, option: str = "--territory"
) -> MissionTerritory | None:
    """:func:`territory_of` for a value given as ``option``: a bad mask file fails as a
    configuration error naming the option.

    Parameters
    ----------
    value : str or Path or None
        None (the default), :data:`NO_TERRITORY` or a mask file.
    plan : OccupancyMap
        The plan the mask goes on.
    option : str
        What the value was given as, for the message (default ``"--territory"``).

    Returns
    -------
    MissionTerritory or None
        As :func:`territory_of`.

    Raises
    ------
    ConfigError
        ``"--territory FILE[:LINE]: reason"`` for a file :func:`load_territory` refuses.
    """
    if value is None:
        return territory_of(None, plan)
    try:
        return territory_of(value, plan)
    except InputError as err:
        where = str(err) if err.path is not None else f"{value}: {err.reason}"
        raise ConfigError(f"{option} {where}") from None


def check_route_inside(
    plan: OccupancyMap,
    mask: MissionTerritory,
    route: npt.NDArray[np.float64],
    *,
    where: str,
    inside: str,
) -> None:
    """Refuse a route with a pose off the area a robot reaches inside ``mask``: the
    mission would map a place the mask leaves out while ``summary.json`` records the mask.

    Parameters
    ----------
    plan : OccupancyMap
        The plan the mask is on.
    mask : MissionTerritory
        The territory.
    route : ndarray, shape (T, 4)
        ``t`` (s), ``x``, ``y`` (m), ``theta`` (rad) a row.
    where : str
        The route's name in the message (``"--route FILE"``).
    inside : str
        The mask's name in the message (``"--territory FILE"``).

    Raises
    ------
    ConfigError
        Naming the first pose outside, its time and position.
    """
    i = mask.first_outside(plan, route[:, 1], route[:, 2])
    if i >= 0:
        raise ConfigError(
            f"{where}: pose {i + 1} (t = {route[i, 0]:g} s) at ({route[i, 1]:g}, "
            f"{route[i, 2]:g}) m is off the area a robot reaches inside {inside}"
        )
