"""A simulated team mission, standing in for the stereo logs thesis 002 did not keep.

A :class:`World` is a prior map (:class:`~sonarmap.io.rosmap.OccupancyMap`) with
visual landmarks on its obstacle surfaces (:func:`make_world`), some of them sharing
one texture, some vanishing, appearing or moving during the mission. A robot drives a
route (:func:`route_from_waypoints`, :func:`patrol_route`), dead-reckons with drifting
odometry (:func:`odometry`), sees landmarks with a stereo camera (:func:`observe`) and
ranges with a ring of sonars (:func:`sonar_readings`). A world and a route are saved to
and loaded from a folder (:func:`save_world`, :func:`load_world`); a route alone is a
CSV (:func:`read_route`).

Conventions: world frame of the plan (metres, radians); a route is an array (T, 4) of
``t, x, y, theta`` true poses; observations are in the robot's frame (x forward, y left,
z up, origin on the floor below the left camera), as :mod:`.records` wants.

Folder format (:func:`save_world`)::

    world.yaml      format, version, plan (path of a map_server YAML, relative to the
                    folder or absolute), params (make_world's), descriptor_dim,
                    landmarks: landmarks.csv, route: route.csv or null
    landmarks.csv   id,x,y,z,born,died,moved_at,moved_x,moved_y,group,descriptor_hex
                    (id = 0, 1, ... in order; died "inf" if never; moved_* empty if the
                    landmark never moves; group -1 if none; descriptor as hex bytes)
    route.csv       t,x,y,theta (t strictly increasing)
    plan.yaml/.pgm  the plan itself, when the world was not made from a map file
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import ConfigError, InputError, quote
from ..files import atomic_folder, dump_yaml, need_file, read_text, read_yaml
from ..floorplan import random_building
from ..grid import Grid
from ..io.rosmap import FREE, OCCUPIED, OccupancyMap, read_map, write_map
from ..patrol.paths import Wave, path_to
from ..patrol.reach import reach
from ..patrol.territory import Territory, segment_clear
from ..patrol.tour import plan_tour
from ..readings import Readings, Trajectory
from ..rig import Rig, get_rig
from ..scenarios import office
from ..sensors import Noise
from ..simulate import SonarModel, simulate
from .config import MAX_DURATION
from .records import Landmarks
from .territory import ROBOT_RADIUS, mask_on

__all__ = [
    "BUILTIN_PLANS",
    "FACES",
    "LANDMARK_COLUMNS",
    "ODOMETRY_MODEL",
    "ODOMETRY_NOISE",
    "ROUTE_COLUMNS",
    "ROUTE_SEED_STEP",
    "ROUTE_STYLES",
    "World",
    "builtin_plan",
    "facing_cells",
    "load_world",
    "make_world",
    "observe",
    "odometry",
    "odometry_covariance",
    "patrol_route",
    "read_route",
    "route_from_waypoints",
    "save_world",
    "sonar_readings",
    "speckle_mask",
    "territory_faces",
    "wall_faces",
    "world_territory",
]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]

LANDMARK_COLUMNS = (
    "id",
    "x",
    "y",
    "z",
    "born",
    "died",
    "moved_at",
    "moved_x",
    "moved_y",
    "group",
    "descriptor_hex",
)
ROUTE_COLUMNS = ("t", "x", "y", "theta")
FORMAT = "sonarmap-team-world"
VERSION = 1


@dataclass
class World:
    """The simulated territory: a plan and its landmarks, one row each.

    Attributes
    ----------
    plan : OccupancyMap
        The prior map; occupied cells block sight.
    points : ndarray (n, 3) float64
        World position (x, y, z metres) where each landmark first is.
    descriptors : ndarray (n, d) uint8
        Each landmark's true appearance.
    born, died : ndarray (n,) float64
        Mission time (s) it appears and vanishes: alive when ``born <= t < died``
        (``died`` is inf for one that stays).
    moved_at : ndarray (n,) float64
        Time it jumps to ``moved_to``; NaN if never.
    moved_to : ndarray (n, 2) float64
        World (x, y) after the jump (z kept); NaN if never.
    group : ndarray (n,) int64
        Repeated-texture group, -1 for a unique texture.
    params : dict
        The parameters the world was made with.
    plan_path : str or None
        The map file the plan was read from, if any.
    """

    plan: OccupancyMap
    points: F64
    descriptors: U8
    born: F64
    died: F64
    moved_at: F64
    moved_to: F64
    group: I64
    params: dict[str, Any] = field(default_factory=dict)
    plan_path: str | None = None

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        n = len(self.points)
        self.descriptors = np.asarray(self.descriptors, dtype=np.uint8).reshape(n, -1)
        self.born = np.asarray(self.born, dtype=np.float64).reshape(n)
        self.died = np.asarray(self.died, dtype=np.float64).reshape(n)
        self.moved_at = np.asarray(self.moved_at, dtype=np.float64).reshape(n)
        self.moved_to = np.asarray(self.moved_to, dtype=np.float64).reshape(n, 2)
        self.group = np.asarray(self.group, dtype=np.int64).reshape(n)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def descriptor_dim(self) -> int:
        return int(self.descriptors.shape[1])

    def alive(self, t: float) -> npt.NDArray[np.bool_]:
        """Landmarks present at time ``t``."""
        return (self.born <= t) & (t < self.died)

    def positions(self, t: float) -> F64:
        """World positions (n, 3) at time ``t`` (moved landmarks at their new place)."""
        pos = self.points.copy()
        moved = self.moved_at <= t
        pos[moved, :2] = self.moved_to[moved]
        return pos


# --- landmarks --------------------------------------------------------------------------


#: The floor plans known by name (:func:`builtin_plan`).
BUILTIN_PLANS = ("office", "building:SEED")


def builtin_plan(name: str) -> OccupancyMap:
    """A built-in floor plan at 10 cm: ``"office"`` (20 m x 20 m, eight rooms off a
    corridor, :func:`~sonarmap.scenarios.office`) or ``"building:SEED"`` (a random
    building, :func:`~sonarmap.floorplan.random_building` of that seed).

    Raises
    ------
    ConfigError
        Any other name.
    """
    if name == "office":
        return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    kind, _, seed = name.partition(":")
    if kind != "building" or not seed.isdigit():
        raise ConfigError(f"no built-in plan {name!r}: {' or '.join(BUILTIN_PLANS)}")
    fp = random_building(seed=int(seed))
    return fp.render(fp.grid(0.1))


def wall_faces(plan: OccupancyMap) -> tuple[F64, F64, F64]:
    """Cell sides where an occupied cell meets a free one (4-neighbours).

    Returns
    -------
    starts : ndarray (m, 2)
        Each side's start corner, world metres.
    dirs : ndarray (m, 2)
        Unit direction along the side (the side is one cell long).
    normals : ndarray (m, 2)
        Unit normal out of the occupied cell, into the free one.
    """
    classes = plan.classes()
    occ = classes == OCCUPIED
    free = np.pad(classes == FREE, 1, constant_values=False)
    grid = plan.grid
    h = grid.resolution
    rr, cc = np.nonzero(occ)
    x0, y0 = grid.cell_centres(rr, cc)
    x0, y0 = x0 - h / 2, y0 - h / 2  # lower-left corner of each occupied cell
    starts, dirs, normals = [], [], []
    # (row step, col step) to the neighbour, then the side's start offset, direction and
    # normal in world axes (rows grow downwards: row - 1 is +y).
    sides = (
        ((-1, 0), (0.0, h), (1.0, 0.0), (0.0, 1.0)),
        ((1, 0), (0.0, 0.0), (1.0, 0.0), (0.0, -1.0)),
        ((0, 1), (h, 0.0), (0.0, 1.0), (1.0, 0.0)),
        ((0, -1), (0.0, 0.0), (0.0, 1.0), (-1.0, 0.0)),
    )
    for (dr, dc), (ox, oy), d, nrm in sides:
        k = free[rr + 1 + dr, cc + 1 + dc]
        m = int(k.sum())
        starts.append(np.stack([x0[k] + ox, y0[k] + oy], axis=1))
        dirs.append(np.tile(d, (m, 1)))
        normals.append(np.tile(nrm, (m, 1)))
    return np.concatenate(starts), np.concatenate(dirs), np.concatenate(normals)


def speckle_mask(plan: OccupancyMap, area: float = 0.01) -> npt.NDArray[np.bool_]:
    """Occupied cells in 8-connected pieces smaller than ``area`` m^2 (0.01: a speck
    under 10 x 10 cm, a SLAM map's noise rather than a wall or a post)."""
    occ = plan.classes() == OCCUPIED
    labels, n = ndimage.label(occ, structure=np.ones((3, 3), dtype=bool))
    cells = np.bincount(labels.ravel(), minlength=n + 1)
    small = cells * plan.grid.resolution**2 < area
    small[0] = False
    return np.asarray(small[labels], dtype=bool)


#: Which wall faces carry landmarks (:func:`make_world`'s ``faces``).
FACES = ("territory", "all")


def facing_cells(
    plan: OccupancyMap,
    radius: float = ROBOT_RADIUS,
    margin: float = 0.5,
    starts: npt.NDArray[np.intp] | None = None,
    region: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.bool_]:
    """Free cells a robot of ``radius`` metres sees a wall across: those within
    ``radius + margin`` metres (0.3 + 0.5) of where its centre can get to, by steps over
    free cells (a wall, however thin, is not crossed).

    Where its centre can get to is :func:`~sonarmap.patrol.reach.reach`'s: the pieces
    of the map holding ``starts`` (rows, cols), or the largest piece; unknown cells
    are never free; with a ``region`` (a user's territory mask on the plan's cells,
    :mod:`.territory`) only its inside. Left out: a real map's outside behind its outer
    wall, the inside of a shelf drawn as an outline, a room behind a door narrower than
    the robot.
    """
    terr = Territory.from_map(plan)
    passable = reach(terr, radius, starts=starts, region=region).passable
    steps = max(1, math.ceil((radius + margin) / plan.grid.resolution))
    grown = ndimage.binary_dilation(
        passable, structure=np.ones((3, 3), dtype=bool), iterations=steps, mask=terr.free
    )
    return np.asarray(grown, dtype=bool)


def territory_faces(
    plan: OccupancyMap,
    radius: float = ROBOT_RADIUS,
    speckle_area: float = 0.01,
    region: npt.NDArray[np.bool_] | None = None,
) -> tuple[F64, F64, F64]:
    """The :func:`wall_faces` a robot of ``radius`` metres can see: those whose free
    cell is one of :func:`facing_cells` (of the largest piece where it fits, inside
    ``region`` when one is given), on an obstacle that is not a speck
    (:func:`speckle_mask` of ``speckle_area`` m^2). Same arrays as :func:`wall_faces`.
    """
    starts, dirs, normals = wall_faces(plan)
    if len(starts) == 0:
        return starts, dirs, normals
    seen = facing_cells(plan, radius, region=region)
    fr, fc = _side_cells(plan.grid, (starts, dirs, normals), 1.0)
    orow, ocol = _side_cells(plan.grid, (starts, dirs, normals), -1.0)
    keep = seen[fr, fc] & ~speckle_mask(plan, speckle_area)[orow, ocol]
    return starts[keep], dirs[keep], normals[keep]


def _side_cells(
    grid: Grid, sides: tuple[F64, F64, F64], side: float
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Rows and columns of the cell beside each face's midpoint: its free cell for
    ``side`` +1, the obstacle's for -1 (half a cell along the normal)."""
    starts, dirs, normals = sides
    h = grid.resolution
    centre = starts + 0.5 * h * dirs
    r, c = grid.world_to_cell(*(centre + side * 0.5 * h * normals).T)
    return r, c


def _faces_inside(
    plan: OccupancyMap, sides: tuple[F64, F64, F64], region: npt.NDArray[np.bool_]
) -> tuple[F64, F64, F64]:
    """The faces of ``sides`` whose free cell lies inside ``region``."""
    fr, fc = _side_cells(plan.grid, sides, 1.0)
    keep = region[fr, fc]
    starts, dirs, normals = sides
    return starts[keep], dirs[keep], normals[keep]


def _on_faces(
    rng: np.random.Generator, starts: F64, dirs: F64, pick: npt.NDArray[np.intp], h: float
) -> F64:
    """Uniform points (k, 2) on the chosen faces."""
    s = rng.uniform(0.0, h, len(pick))
    return starts[pick] + s[:, None] * dirs[pick]


def _moves(
    rng: np.random.Generator,
    faces: tuple[F64, F64, F64],
    h: float,
    origin: F64,
    face: npt.NDArray[np.intp],
    lo: float,
    hi: float,
) -> F64:
    """A new place (k, 2) for each landmark, on a face of the same orientation
    ``lo``..``hi`` metres away (along its wall); NaN where there is none."""
    starts, dirs, normals = faces
    centres = starts + 0.5 * h * dirs
    out = np.full((len(face), 2), np.nan)
    for i, (p, f) in enumerate(zip(origin, face, strict=True)):
        d = np.hypot(centres[:, 0] - p[0], centres[:, 1] - p[1])
        same = (normals == normals[f]).all(axis=1)
        cand = np.flatnonzero(same & (d >= lo) & (d <= hi))
        if len(cand):
            j = cand[rng.integers(len(cand))]
            out[i] = _on_faces(rng, starts, dirs, np.array([j]), h)[0]
    return out


def _check_share(**values: float) -> None:
    for k, v in values.items():
        if not (0.0 <= v <= 1.0):
            raise ConfigError(f"world parameter '{k}' must be in [0, 1], got {v}")


def _check_positive(**values: float) -> None:
    for k, v in values.items():
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"parameter '{k}' must be > 0, got {v}")


def _check_duration(duration: float) -> None:
    # Routes and changes are drawn for the whole mission at once: refuse before drawing.
    if duration > MAX_DURATION:
        raise ConfigError(
            f"duration {duration:g} s: at most {MAX_DURATION:g} s (a day)", field="duration"
        )


def make_world(
    plan: OccupancyMap,
    *,
    seed: int = 0,
    landmark_spacing: float = 0.5,
    z_min: float = 0.2,
    z_max: float = 2.0,
    descriptor_dim: int = 128,
    texture_share: float = 0.2,
    texture_groups: int = 5,
    texture_noise: float = 3.0,
    change_share: float = 0.1,
    move_share: float = 0.05,
    move_min: float = 0.5,
    move_max: float = 2.0,
    duration: float = 600.0,
    plan_path: str | Path | None = None,
    faces: str = "territory",
    radius: float = ROBOT_RADIUS,
    speckle_area: float = 0.01,
    region: npt.NDArray[np.bool_] | None = None,
) -> World:
    """Landmarks on the obstacle surfaces of ``plan``, with repeated textures and changes.

    Parameters
    ----------
    plan : OccupancyMap
        The territory; landmarks lie on the sides of occupied cells that face free cells
        (which of them: ``faces``).
    seed : int
        Everything random is drawn from it (0).
    landmark_spacing : float
        Mean distance between landmarks along the walls, metres (0.5); their places
        along the walls are uniform at random.
    z_min, z_max : float
        Landmark heights, uniform, metres (0.2, 2.0).
    descriptor_dim : int
        Bytes per descriptor (128, as SIFT).
    texture_share : float
        Share of the landmarks with a repeated texture (0.2), shared out in turn among
        ``texture_groups`` groups (5) placed at random over the map: a group's members
        carry its base descriptor plus Gaussian noise of ``texture_noise`` (3) uint8
        units (the thesis only says textures repeat; the values are ours).
    change_share : float
        Share of the initial landmarks that vanish at a uniform time in [0, duration],
        and, as many again, new landmarks that appear at such a time (0.1).
    move_share : float
        Share of the initial landmarks (not among those vanishing) that jump at a uniform
        time to another place of their wall orientation ``move_min``..``move_max`` m away
        (0.05; 0.5-2 m); one with no such place stays.
    duration : float
        The mission's length, seconds (600): changes happen within it.
    plan_path : str or Path, optional
        The map file ``plan`` came from, recorded by :func:`save_world`.
    faces : {"territory", "all"}
        ``territory`` (default): only the faces a robot of ``radius`` metres (0.3) can
        see, :func:`territory_faces` (none on specks under ``speckle_area`` m^2, 0.01,
        none facing free space it cannot reach: a real map's outside, the inside of a
        shelf, a room behind a door narrower than the robot); ``all``: every face of an
        occupied cell on a free one.
    region : ndarray of bool, optional
        A user's territory mask on the plan's cells (:mod:`.territory`): ``territory``
        faces are then those of the largest piece a robot fits in inside it, ``all``
        faces those whose free cell lies inside it. None (default): the whole plan.

    Returns
    -------
    World
        Initial landmarks first (born at 0), then the appearing ones.

    Raises
    ------
    InputError
        When no face is left to put a landmark on.
    """
    _check_positive(
        landmark_spacing=landmark_spacing,
        duration=duration,
        descriptor_dim=descriptor_dim,
        texture_groups=texture_groups,
        move_max=move_max,
    )
    _check_duration(duration)
    _check_share(texture_share=texture_share, change_share=change_share, move_share=move_share)
    if not (0 <= z_min <= z_max) or not (0 <= move_min <= move_max) or texture_noise < 0:
        raise ConfigError(
            f"need 0 <= z_min <= z_max ({z_min}, {z_max}), 0 <= move_min <= move_max "
            f"({move_min}, {move_max}) and texture_noise >= 0 ({texture_noise})"
        )
    if faces not in FACES:
        raise ConfigError(f"faces must be one of {', '.join(FACES)}, got {quote(faces)}")
    _check_positive(radius=radius, speckle_area=speckle_area)
    rng = np.random.default_rng(seed)
    if faces == "all":
        sides = wall_faces(plan)
        if region is not None:
            sides = _faces_inside(plan, sides, region)
    else:
        sides = territory_faces(plan, radius, speckle_area, region)
    starts, dirs, _ = sides
    h = plan.grid.resolution
    if len(starts) == 0:
        where = "" if faces == "all" else f" that a robot of radius {radius:g} m can reach"
        where += "" if region is None else " inside the territory mask"
        raise InputError(f"the plan has no obstacle facing free space{where} to put landmarks on")
    n_base = max(1, round(len(starts) * h / landmark_spacing))
    n_new = round(change_share * n_base)
    n = n_base + n_new
    face = rng.choice(len(starts), size=n, replace=n > len(starts))
    xy = _on_faces(rng, starts, dirs, face, h)
    z = rng.uniform(z_min, z_max, n)
    desc = rng.integers(0, 256, size=(n, descriptor_dim), dtype=np.uint8)
    group = np.full(n, -1, dtype=np.int64)
    members = rng.permutation(n)[: round(texture_share * n)]
    if len(members):
        bases = rng.integers(0, 256, size=(texture_groups, descriptor_dim)).astype(np.float64)
        group[members] = np.arange(len(members)) % texture_groups
        noisy = bases[group[members]] + rng.normal(
            0.0, texture_noise, (len(members), descriptor_dim)
        )
        desc[members] = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    born = np.zeros(n)
    born[n_base:] = rng.uniform(0.0, duration, n_new)
    died = np.full(n, np.inf)
    order = rng.permutation(n_base)
    n_gone = round(change_share * n_base)
    n_move = min(round(move_share * n_base), n_base - n_gone)
    gone, moving = order[:n_gone], order[n_gone : n_gone + n_move]
    died[gone] = rng.uniform(0.0, duration, n_gone)
    moved_at = np.full(n, np.nan)
    moved_to = np.full((n, 2), np.nan)
    moved_to[moving] = _moves(rng, sides, h, xy[moving], face[moving], move_min, move_max)
    ok = moving[np.isfinite(moved_to[moving, 0])]
    moved_at[ok] = rng.uniform(0.0, duration, len(ok))
    params = {
        "seed": seed,
        "landmark_spacing": landmark_spacing,
        "z_min": z_min,
        "z_max": z_max,
        "descriptor_dim": descriptor_dim,
        "texture_share": texture_share,
        "texture_groups": texture_groups,
        "texture_noise": texture_noise,
        "change_share": change_share,
        "move_share": move_share,
        "move_min": move_min,
        "move_max": move_max,
        "duration": duration,
        "faces": faces,
        "radius": radius,
        "speckle_area": speckle_area,
    }
    if region is not None:
        # Only when given: worlds made without a mask keep the parameters they had.
        params["territory_cells"] = int(region.sum())
    return World(
        plan,
        np.column_stack([xy, z]),
        desc,
        born,
        died,
        moved_at,
        moved_to,
        group,
        params,
        None if plan_path is None else str(plan_path),
    )


# --- routes -----------------------------------------------------------------------------


def _passable(plan: OccupancyMap, radius: float) -> tuple[Grid, npt.NDArray[np.bool_]]:
    if not (math.isfinite(radius) and radius >= 0):
        raise ConfigError(f"robot radius must be >= 0 metres, got {radius}")
    terr = Territory.from_map(plan)
    ok = terr.passable(radius)
    if not ok.any():
        raise ConfigError(f"no cell of the plan lets a robot of radius {radius} m pass")
    return terr.grid, ok


def _snap(grid: Grid, ok: npt.NDArray[np.bool_], x: float, y: float) -> tuple[int, int]:
    """The passable cell nearest a world point (first in row-major order among equals)."""
    r, c = (int(v) for v in grid.world_to_cell(x, y))
    if grid.contains(r, c) and ok[r, c]:
        return r, c
    rows, cols = np.nonzero(ok)
    k = int(np.argmin((rows - r) ** 2 + (cols - c) ** 2))
    return int(rows[k]), int(cols[k])


def _clear(a: F64, b: F64, ok: npt.NDArray[np.bool_], grid: Grid) -> bool:
    return segment_clear(float(a[0]), float(a[1]), float(b[0]), float(b[1]), ok, grid)


def _pull(points: F64, ok: npt.NDArray[np.bool_], grid: Grid) -> F64:
    """String pulling: keep only the corners a straight line over passable cells needs."""
    out = [points[0]]
    i = 0
    n = len(points)
    while i < n - 1:
        j = i + 1
        while j + 1 < n and _clear(points[i], points[j + 1], ok, grid):
            j += 1
        out.append(points[j])
        i = j
    return np.array(out)


def _drive(polyline: F64, speed: float, rate: float, smooth: float) -> F64:
    """Drive a polyline at ``speed``, poses at ``rate`` Hz: positions smoothed by a moving
    average over ``smooth`` metres of path, headings along the smoothed motion."""
    seg = np.hypot(*np.diff(polyline, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = float(s[-1])
    # The last pose is the end itself: the final step may be shorter.
    t = np.arange(math.ceil(total / speed * rate - 1e-9) + 1) / rate
    along = np.minimum(speed * t, total)
    x = np.interp(along, s, polyline[:, 0])
    y = np.interp(along, s, polyline[:, 1])
    k = round(smooth / (speed / rate)) // 2
    if k > 0 and len(t) > 1:
        kernel = np.ones(2 * k + 1) / (2 * k + 1)
        x = np.convolve(np.pad(x, k, mode="edge"), kernel, mode="valid")
        y = np.convolve(np.pad(y, k, mode="edge"), kernel, mode="valid")
    if len(t) < 2:
        d = np.diff(polyline[:2], axis=0).reshape(-1, 2)
        theta = np.full(len(t), math.atan2(d[0, 1], d[0, 0]) if len(d) else 0.0)
        return np.column_stack([t, x, y, theta])
    dx, dy = np.gradient(x), np.gradient(y)
    theta = np.arctan2(dy, dx)
    # Where the robot stands still (the edge padding), keep the last heading it had.
    still = np.hypot(dx, dy) < 1e-9
    idx = np.where(~still, np.arange(len(theta)), 0)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(~still)) if (~still).any() else 0
    idx[: first + 1] = first
    theta = theta[idx]
    return np.column_stack([t, x, y, theta])


def _legs(
    grid: Grid, ok: npt.NDArray[np.bool_], cells: Sequence[tuple[int, int]], wave: Wave
) -> F64:
    """The pulled polyline through shortest grid paths between successive cells."""
    pieces: list[F64] = []
    for a, b in itertools.pairwise(cells):
        dist, _ = wave(ok, a, grid.resolution)
        if not np.isfinite(dist[b]):
            raise ConfigError(f"waypoint at cell {b} cannot be reached from cell {a}")
        path = path_to(dist, b, grid.resolution)
        px, py = grid.cell_centres(path[:, 0], path[:, 1])
        leg = _pull(np.column_stack([px, py]), ok, grid)
        pieces.append(leg if not pieces else leg[1:])
    if not pieces:
        x, y = grid.cell_centres(*cells[0])
        return np.array([[float(x), float(y)]])
    return np.concatenate(pieces)


def route_from_waypoints(
    plan: OccupancyMap,
    waypoints: npt.ArrayLike,
    *,
    speed: float = 0.5,
    rate: float = 2.0,
    radius: float = ROBOT_RADIUS,
    smooth: float = 0.5,
) -> F64:
    """A route through ``waypoints`` along shortest paths.

    Each waypoint snaps to the nearest cell where a robot of ``radius`` metres (0.3) fits;
    legs are shortest 8-connected grid paths over such cells
    (:func:`~sonarmap.patrol.paths.wave`), straightened by string pulling, driven at
    ``speed`` m/s (0.5) with poses at ``rate`` Hz (2), the positions smoothed by a moving
    average over ``smooth`` metres (0.5; it rounds the corners by a few centimetres).

    Returns
    -------
    ndarray (T, 4)
        ``t, x, y, theta``, t from 0; the heading follows the motion.
    """
    _check_positive(speed=speed, rate=rate)
    pts = np.asarray(waypoints, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0 or not np.isfinite(pts).all():
        raise ConfigError(f"waypoints must be finite (x, y) pairs, got shape {pts.shape}")
    grid, ok = _passable(plan, radius)
    cells = [_snap(grid, ok, float(x), float(y)) for x, y in pts]
    return _drive(_legs(grid, ok, cells, Wave(grid.shape)), speed, rate, max(smooth, 0.0))


#: How :func:`patrol_route` draws its route.
ROUTE_STYLES = ("tour", "waypoints")

#: Robot ``i``'s route and sensor seeds start at the mission's seed +
#: ``ROUTE_SEED_STEP`` x ``i``: every place that draws a robot's route by itself
#: (:class:`~.sensing.RobotSensing`, :func:`~.inputs.mission_routes`, the nodes) uses it,
#: so a route drawn up front is the one the mission would draw.
ROUTE_SEED_STEP = 7919


def _largest_area(ok: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    comps, _ = ndimage.label(ok, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(comps.ravel())
    sizes[0] = 0
    return np.asarray(comps == int(np.argmax(sizes)))


def _tour_points(
    plan: OccupancyMap,
    radius: float,
    budget: float,
    spacing: float,
    region: npt.NDArray[np.bool_] | None = None,
) -> F64:
    """World points (K, 2) of a cyclic tour over the largest area a robot of ``radius``
    fits in (inside ``region``, a mask on the plan's cells, when given), in tour order,
    its lattice as fine as ``spacing`` metres allows while the tour stays within
    ``budget`` metres (coarser until it does)."""
    # On cells of about 0.1 m: a wave per waypoint, so the map's own 3-5 cm cells would
    # cost ten times the time for the same tour.
    terr = Territory.from_map(plan, cell=max(0.1, plan.grid.resolution))
    ok = terr.passable(radius)
    if region is not None:
        ok = ok & mask_on(region, plan.grid, terr.grid)
    if not ok.any():
        raise ConfigError(f"no cell of the plan lets a robot of radius {radius} m pass")
    area = _largest_area(ok)
    h = terr.grid.resolution
    first = np.argwhere(area)[0]
    # A lattice tour is about (area / spacing) long: start near the budget's spacing.
    step = max(spacing, float(area.sum()) * h * h / budget)
    for _ in range(20):
        cells, length = plan_tour(terr, area, step / math.sqrt(2), (int(first[0]), int(first[1])))
        if length <= budget or len(cells) <= 3:
            break
        step *= 1.25
    x, y = terr.grid.cell_centres(cells[:, 0], cells[:, 1])
    return np.column_stack([x, y]).astype(np.float64)


def patrol_route(
    plan: OccupancyMap,
    duration: float = 600.0,
    *,
    seed: int = 0,
    speed: float = 0.5,
    rate: float = 2.0,
    radius: float = ROBOT_RADIUS,
    min_leg: float = 3.0,
    smooth: float = 0.5,
    style: str = "waypoints",
    laps: float = 3.0,
    spacing: float = 2.0,
    region: npt.NDArray[np.bool_] | None = None,
) -> F64:
    """A stand-in for the patroller: random waypoints, or a tour driven lap after lap.

    The robot starts on a random cell of the largest connected area where it fits
    (unknown cells are never free; with a ``region``, a user's territory mask on the
    plan's cells (:mod:`.territory`), the largest such area inside it, and every leg
    stays inside it). With ``style="waypoints"`` (default) it then heads
    for random cells of that area at least ``min_leg`` metres (3) away, one after the
    other; it rarely passes a place the same way twice. With ``style="tour"`` it drives
    one cyclic tour of that area again and again, the same way round, so that it passes
    every place of the tour with the same heading once a lap: the tour's waypoints lie
    on a square lattice ``spacing`` metres apart (2), or coarser so that one lap takes
    at most ``duration / laps`` seconds (``laps`` 3), ordered by nearest neighbour and
    2-opt on path lengths (:func:`~sonarmap.patrol.tour.plan_tour`; the tour is the same
    for every seed, the start is not: the robot joins the tour at its waypoint nearest
    the start). The tour is not the default: on the training maps it did not lower a
    mission's trajectory error (docs/results/2026-12-06-team-real-maps-world.md). Legs
    are driven as :func:`route_from_waypoints` drives them, until ``duration`` seconds
    (600) have passed. Drawn from ``seed``.

    Returns
    -------
    ndarray (T, 4)
        ``t, x, y, theta``; T = ``round(duration * rate)``.

    Raises
    ------
    ConfigError
        An unknown ``style``, ``laps`` or ``spacing`` not > 0, or an area too small to
        drive in (inside the mask too).
    """
    _check_positive(duration=duration, speed=speed, rate=rate, laps=laps, spacing=spacing)
    _check_duration(duration)
    if style not in ROUTE_STYLES:
        raise ConfigError(
            f"route style must be one of {', '.join(ROUTE_STYLES)}, got {quote(style)}"
        )
    grid, ok = _passable(plan, radius)
    if region is not None:
        if region.shape != grid.shape:
            raise ValueError(f"a territory mask of {region.shape} for a plan of {grid.shape}")
        ok = ok & region
        if not ok.any():
            raise ConfigError(
                f"no cell inside the territory mask lets a robot of radius {radius} m pass"
            )
    area = _largest_area(ok)
    rows, cols = np.nonzero(area)
    rng = np.random.default_rng(seed)
    wave = Wave(grid.shape)
    k = int(rng.integers(len(rows)))
    cells = [(int(rows[k]), int(cols[k]))]
    need = speed * duration
    if style == "tour":
        pts = _tour_points(plan, radius, need / laps, spacing, region)
        loop = [_snap(grid, area, float(x), float(y)) for x, y in pts]
        loop = [c for i, c in enumerate(loop) if c != loop[i - 1]] or loop[:1]
        near = int(np.argmin([math.hypot(r - cells[0][0], c - cells[0][1]) for r, c in loop]))
        loop = loop[near:] + loop[:near]
        lap = _legs(grid, area, [*loop, loop[0]], wave)
        lap_m = float(np.hypot(*np.diff(lap, axis=0).T).sum())
        if lap_m >= min_leg:
            lead = _legs(grid, area, [cells[0], loop[0]], wave)
            lead_m = float(np.hypot(*np.diff(lead, axis=0).T).sum())
            n = max(1, math.ceil((need - lead_m) / lap_m) + 1)
            poly = np.concatenate([lead, *([lap[1:]] * n)])
            route = _drive(poly, speed, rate, max(smooth, 0.0))
            return route[: round(duration * rate)]
        # A territory too small for a tour of min_leg: random waypoints, or their error.
    length = 0.0
    tries = stuck = 0
    while length < need:
        k = int(rng.integers(len(rows)))
        r, c = cells[-1]
        far = math.hypot(rows[k] - r, cols[k] - c) * grid.resolution >= min_leg
        tries += 1
        if not far and tries < 100:
            continue
        tries = 0
        leg = _legs(grid, area, [cells[-1], (int(rows[k]), int(cols[k]))], wave)
        step = float(np.hypot(*np.diff(leg, axis=0).T).sum())
        stuck = stuck + 1 if step == 0 else 0
        if stuck > 100:
            raise ConfigError(f"the area a robot of radius {radius} m fits in is too small")
        length += step
        cells.append((int(rows[k]), int(cols[k])))
    route = _drive(_legs(grid, area, cells, wave), speed, rate, max(smooth, 0.0))
    return route[: round(duration * rate)]


# --- odometry ---------------------------------------------------------------------------


def _increments(route: F64) -> F64:
    """Body-frame steps (T-1, 3): dx, dy, dtheta from each pose to the next."""
    th = route[:-1, 3]
    d = np.diff(route[:, 1:3], axis=0)
    c, s = np.cos(th), np.sin(th)
    dth = np.remainder(np.diff(route[:, 3]) + np.pi, 2 * np.pi) - np.pi
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], dth])


def _dead_reckon(start: F64, steps: F64) -> F64:
    """Poses (T, 3) from a start pose and body-frame steps, composed in turn."""
    th = start[2] + np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    dx = c * steps[:, 0] - s * steps[:, 1]
    dy = s * steps[:, 0] + c * steps[:, 1]
    x = start[0] + np.concatenate([[0.0], np.cumsum(dx)])
    y = start[1] + np.concatenate([[0.0], np.cumsum(dy)])
    return np.column_stack([x, y, np.remainder(th + np.pi, 2 * np.pi) - np.pi])


def odometry(
    route: npt.ArrayLike,
    *,
    sigma_xy: float = 0.02,
    sigma_theta: float = 0.01,
    sigma_theta_dist: float = 0.002,
    bias_theta: float = 0.003,
    seed: int = 0,
) -> tuple[F64, F64]:
    """Wheel odometry along a true route: noisy steps, dead-reckoned.

    Per step of length ``s`` metres turning ``a`` radians, the body-frame step gets
    Gaussian noise of standard deviation ``sigma_xy * sqrt(s)`` on x and on y (0.02: 2 cm
    after one metre; variances add up with distance, so the drift does not depend on the
    rate), and the turn ``sqrt(sigma_theta**2 * a + sigma_theta_dist**2 * s)`` (0.01 rad
    per radian turned, 0.002 rad per metre) plus a systematic ``bias_theta * s`` (0.003
    rad per metre: wheels of unequal diameter, which make the drift grow along the
    route; an error of the wheel base would instead turn in proportion to the angle
    turned, and is not simulated). The thesis gives no odometry model; these are
    typical of a small wheeled robot. The first pose is the true one.

    Returns
    -------
    poses : ndarray (T, 4)
        ``t, x, y, theta`` as dead-reckoned.
    steps : ndarray (T-1, 3)
        The noisy body-frame steps ``dx, dy, dtheta`` from each pose to the next.
    """
    r = np.asarray(route, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 4 or len(r) == 0:
        raise ConfigError(f"a route is an array (T, 4) of t, x, y, theta; got {r.shape}")
    for k, v in {"sigma_xy": sigma_xy, "sigma_theta": sigma_theta}.items():
        if not (math.isfinite(v) and v >= 0):
            raise ConfigError(f"odometry parameter '{k}' must be >= 0, got {v}")
    rng = np.random.default_rng(seed)
    true = _increments(r)
    dist = np.hypot(true[:, 0], true[:, 1])
    noise_xy = rng.standard_normal((len(true), 2)) * (sigma_xy * np.sqrt(dist))[:, None]
    sd_th = np.sqrt(sigma_theta**2 * np.abs(true[:, 2]) + sigma_theta_dist**2 * dist)
    noise_th = rng.standard_normal(len(true)) * sd_th + bias_theta * dist
    steps = true + np.column_stack([noise_xy, noise_th])
    poses = _dead_reckon(r[0, 1:4], steps)
    return np.column_stack([r[:, 0], poses]), steps


# --- sensors ----------------------------------------------------------------------------


def _lines_clear(
    plan: OccupancyMap, x0: float, y0: float, px: F64, py: F64, step: float = 0.25
) -> npt.NDArray[np.bool_]:
    """Whether each segment from (x0, y0) to (px, py) stays on the map and off occupied
    cells (sampled every ``step`` cells, as :func:`segment_clear`), stopping half a cell
    short of the end: a landmark lies on its obstacle's face, and from behind, the
    segment's last half cell lies in that obstacle."""
    if len(px) == 0:
        return np.zeros(0, dtype=bool)
    grid = plan.grid
    h = grid.resolution
    length = np.hypot(px - x0, py - y0)
    n = max(2, math.ceil(float(length.max()) / (h * step)) + 1)
    stop = np.clip((length - 0.5 * h) / np.maximum(length, 1e-12), 0.0, 1.0)
    f = np.linspace(0.0, 1.0, n)[None, :] * stop[:, None]
    r, c = grid.world_to_cell(x0 + f * (px - x0)[:, None], y0 + f * (py - y0)[:, None])
    inside = grid.contains(r, c)
    blocked = plan.classes() == OCCUPIED
    hit = blocked[np.clip(r, 0, grid.rows - 1), np.clip(c, 0, grid.cols - 1)]
    return np.asarray((inside & ~hit).all(axis=1))


def observe(
    world: World,
    pose: npt.ArrayLike,
    t: float,
    *,
    fov_deg: float = 90.0,
    max_range: float = 8.0,
    min_range: float = 0.5,
    focal: float = 500.0,
    baseline: float = 0.12,
    sigma_pixel: float = 0.3,
    camera_height: float = 0.5,
    descriptor_noise: float = 8.0,
    reliability: float = 0.5,
    seed: int = 0,
) -> Landmarks:
    """What the stereo camera sees from true pose ``(x, y, theta)`` at time ``t``.

    Visible: landmarks alive at ``t``, whose horizontal distance from the left camera is
    in [``min_range``, ``max_range``] (0.5, 8 m) and bearing within ``fov_deg`` (90) of
    the heading, with no occupied cell of the plan on the line of sight. The vertical
    field is not limited.

    Stereo model (the thesis's, l.1264-1328): a rectified pair, focal length ``focal``
    pixels (500: a 1000-pixel-wide image spans 90 degrees), baseline ``baseline`` m
    (0.12) to the right of the left camera, which sits ``camera_height`` m (0.5) above
    the robot's origin looking along x. A point (X forward, Y left, Z up) projects to
    ``u_l = -f Y / X``, ``u_r = -f (Y + B) / X``, ``v = -f (Z - h) / X``; each pixel
    coordinate gets Gaussian noise ``sigma_pixel`` (0.3 px, typical sub-pixel matching)
    and the point is triangulated back: ``X = f B / (u_l - u_r)``,
    ``Y = -X u_l / f``, ``Z = h - X v / f``. The depth error so grows as
    ``X**2 sigma_d / (f B)`` with ``sigma_d = sqrt(2) sigma_pixel``: 2.8 cm at 2 m, 45 cm
    at 8 m. A disparity that noise makes below 0.5 px is dropped (a failed match).

    Descriptors are the true ones plus Gaussian noise of ``descriptor_noise`` (8) uint8
    units, rounded and clipped. Noise is drawn from ``(seed, t in milliseconds)``: give
    each robot its own seed.

    Returns
    -------
    Landmarks
        In the robot's frame (x forward, y left, z up); reliability ``reliability``
        (0.5), stamp ``t``, ``ids`` the true landmark indices.
    """
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(-1)[:3])
    _check_positive(focal=focal, baseline=baseline, fov_deg=fov_deg, max_range=max_range)
    idx = np.flatnonzero(world.alive(t))
    pos = world.positions(t)[idx]
    dx, dy = pos[:, 0] - x, pos[:, 1] - y
    c, s = math.cos(th), math.sin(th)
    bx, by = c * dx + s * dy, -s * dx + c * dy
    rng_ = np.hypot(bx, by)
    bearing = np.abs(np.arctan2(by, bx))
    near = (rng_ >= min_range) & (rng_ <= max_range) & (bearing <= math.radians(fov_deg) / 2)
    near[near] = _lines_clear(world.plan, x, y, pos[near, 0], pos[near, 1])
    idx, bx, by, z = idx[near], bx[near], by[near], pos[near, 2]
    rng = np.random.default_rng([seed, abs(round(t * 1000))])
    noise = rng.normal(0.0, sigma_pixel, (len(idx), 3))
    ul = -focal * by / bx + noise[:, 0]
    ur = -focal * (by + baseline) / bx + noise[:, 1]
    v = -focal * (z - camera_height) / bx + noise[:, 2]
    disparity = ul - ur
    ok = disparity >= 0.5
    X = focal * baseline / disparity[ok]
    pts = np.column_stack([X, -X * ul[ok] / focal, camera_height - X * v[ok] / focal])
    idx = idx[ok]
    desc = world.descriptors[idx].astype(np.float64)
    desc += rng.normal(0.0, descriptor_noise, desc.shape)
    n = len(idx)
    return Landmarks(
        pts.astype(np.float32),
        np.clip(np.rint(desc), 0, 255).astype(np.uint8),
        np.full(n, reliability, dtype=np.float32),
        np.full(n, float(t)),
        idx.astype(np.int64),
    )


def sonar_readings(
    plan: OccupancyMap,
    route: npt.ArrayLike,
    *,
    rig: Rig | None = None,
    model: SonarModel | None = None,
    seed: int = 0,
) -> Readings:
    """Sonar readings along a true route, by :func:`sonarmap.simulate.simulate`.

    Default rig: ``ring16`` (16 Polaroid sonars every 22.5 degrees, as the ``office``
    scenario), a stand-in for the thesis robot's six LV-MaxSonar-EZ1 (``paper-synthetic``
    is that one). Default model: the acoustic model on the plan's own cells (give a finer
    plan for finer echoes).
    """
    r = np.asarray(route, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 4:
        raise ConfigError(f"a route is an array (T, 4) of t, x, y, theta; got {r.shape}")
    traj = Trajectory(r[:, 0].copy(), r[:, 1].copy(), r[:, 2].copy(), r[:, 3].copy())
    return simulate(plan, get_rig("ring16") if rig is None else rig, traj, model=model, seed=seed)


# --- files ------------------------------------------------------------------------------


def _num(v: float) -> str:
    return "" if math.isnan(v) else repr(float(v))


def _landmarks_csv(world: World) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(LANDMARK_COLUMNS)
    for i in range(len(world)):
        x, y, z = world.points[i]
        mx, my = world.moved_to[i]
        w.writerow(
            [
                i,
                _num(x),
                _num(y),
                _num(z),
                _num(world.born[i]),
                _num(world.died[i]),
                _num(world.moved_at[i]),
                _num(mx),
                _num(my),
                int(world.group[i]),
                world.descriptors[i].tobytes().hex(),
            ]
        )
    return buf.getvalue()


def _route_csv(route: F64) -> str:
    lines = [",".join(ROUTE_COLUMNS)]
    lines += [",".join(repr(float(v)) for v in row) for row in route]
    return "\n".join(lines) + "\n"


def save_world(
    world: World,
    route: npt.ArrayLike | None,
    folder: str | Path,
    region: npt.NDArray[np.bool_] | None = None,
    territory: str | None = None,
) -> Path:
    """Write a world (and a route) into ``folder``, all files or none.

    The plan is referred to by its path when the world has one, else written into the
    folder as ``plan.yaml`` (+ ``.pgm``, ``.npy``). ``region`` (a territory mask on the
    plan's cells the world was made inside; default None, the whole plan) is written as
    a map_server mask ``territory.yaml`` (its free cells inside, a ``--territory`` file)
    and named in ``world.yaml`` with ``territory`` (where the mask came from: the
    default's name or the user's file). Returns the ``world.yaml`` path.
    """
    out = Path(folder)
    r = None if route is None else np.asarray(route, dtype=np.float64)
    if r is not None and (r.ndim != 2 or r.shape[1] != 4):
        raise ConfigError(f"a route is an array (T, 4) of t, x, y, theta; got {r.shape}")
    plan_ref = "plan.yaml" if world.plan_path is None else str(Path(world.plan_path).absolute())
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "plan": plan_ref,
        "descriptor_dim": world.descriptor_dim,
        "landmarks": "landmarks.csv",
        "route": None if r is None else "route.csv",
        "params": dict(world.params),
    }
    if region is not None:
        if region.shape != world.plan.grid.shape:
            raise ValueError(
                f"a territory mask of {region.shape} for a plan of {world.plan.grid.shape}"
            )
        meta["territory"] = {"mask": "territory.yaml", "from": territory}
    with atomic_folder(out) as tmp:
        if region is not None:
            mask = np.where(region, 0.0, 1.0).astype(np.float32)
            write_map(OccupancyMap(world.plan.grid, mask), tmp / "territory")
        if world.plan_path is None:
            write_map(world.plan, tmp / "plan")
        (tmp / "landmarks.csv").write_text(_landmarks_csv(world))
        if r is not None:
            (tmp / "route.csv").write_text(_route_csv(r))
        (tmp / "world.yaml").write_text(dump_yaml(meta))
    return out / "world.yaml"


def _rows(path: Path, columns: Sequence[str], what: str) -> list[tuple[int, list[str]]]:
    """The data rows of a CSV with exactly ``columns`` as its header, with line numbers."""
    p = need_file(path, what)
    lines = read_text(p, what).splitlines()
    if not lines or [h.strip() for h in lines[0].split(",")] != list(columns):
        raise InputError(f"header must be '{','.join(columns)}'", path=p, line=1)
    out: list[tuple[int, list[str]]] = []
    for k, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = next(csv.reader([line]))
        if len(cells) != len(columns):
            raise InputError(f"{len(cells)} fields, expected {len(columns)}", path=p, line=k)
        out.append((k, cells))
    return out


def _float(
    text: str, path: Path, line: int, name: str, *, finite: bool = True, empty: bool = False
) -> float:
    if empty and not text.strip():
        return math.nan
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"not a number: {quote(text)}", path=path, line=line, field=name) from None
    if math.isnan(v) or (finite and not math.isfinite(v)):
        raise InputError(f"not a finite number: {quote(text)}", path=path, line=line, field=name)
    return v


def read_route(path: str | Path) -> F64:
    """A route from a CSV with the header ``t,x,y,theta`` (seconds, metres, radians).

    Returns
    -------
    ndarray (T, 4)

    Raises
    ------
    InputError
        Naming the file, the line and the field of a bad value, or times that do not
        increase.
    """
    p = Path(path)
    rows = _rows(p, ROUTE_COLUMNS, "route")
    if not rows:
        raise InputError("the route has no pose", path=p)
    out = np.empty((len(rows), 4))
    for i, (line, cells) in enumerate(rows):
        for j, name in enumerate(ROUTE_COLUMNS):
            out[i, j] = _float(cells[j], p, line, name)
        if i and out[i, 0] <= out[i - 1, 0]:
            raise InputError(
                f"time {out[i, 0]} does not follow {out[i - 1, 0]}", path=p, line=line, field="t"
            )
    return out


def _read_landmarks(path: Path, dim: int) -> dict[str, Any]:
    rows = _rows(path, LANDMARK_COLUMNS, "landmarks")
    n = len(rows)
    num = np.empty((n, 8))
    group = np.empty(n, dtype=np.int64)
    desc = np.empty((n, dim), dtype=np.uint8)
    for i, (line, cells) in enumerate(rows):
        if cells[0].strip() != str(i):
            raise InputError(
                f"ids must run 0, 1, ... in order; expected {i}", path=path, line=line, field="id"
            )
        for j, name in enumerate(LANDMARK_COLUMNS[1:9], start=1):
            num[i, j - 1] = _float(
                cells[j], path, line, name, finite=name != "died", empty=name.startswith("moved")
            )
        if num[i, 4] < num[i, 3]:
            raise InputError("dies before it is born", path=path, line=line, field="died")
        if np.isnan(num[i, 5:8]).any() and not np.isnan(num[i, 5:8]).all():
            raise InputError(
                "moved_at, moved_x, moved_y: all or none", path=path, line=line, field="moved_at"
            )
        try:
            group[i] = int(cells[9])
            raw = bytes.fromhex(cells[10].strip())
        except ValueError:
            bad = "group" if not cells[9].strip().lstrip("-").isdigit() else "descriptor_hex"
            raise InputError(
                f"bad {bad}: {cells[LANDMARK_COLUMNS.index(bad)]!r}",
                path=path,
                line=line,
                field=bad,
            ) from None
        if group[i] < -1:
            raise InputError("group must be >= -1", path=path, line=line, field="group")
        if len(raw) != dim:
            raise InputError(
                f"{len(raw)} descriptor bytes, expected {dim}",
                path=path,
                line=line,
                field="descriptor_hex",
            )
        desc[i] = np.frombuffer(raw, dtype=np.uint8)
    return {
        "points": num[:, 0:3],
        "born": num[:, 3],
        "died": num[:, 4],
        "moved_at": num[:, 5],
        "moved_to": num[:, 6:8],
        "group": group,
        "descriptors": desc,
    }


def _meta_key(meta: Mapping[str, Any], key: str, kind: type | tuple[type, ...], p: Path) -> Any:
    if key not in meta:
        raise InputError(f"missing key '{key}'", path=p, field=key)
    v = meta[key]
    if isinstance(v, bool) or not isinstance(v, kind):
        raise InputError(f"unexpected value {quote(v)}", path=p, field=key)
    return v


def world_territory(folder: str | Path) -> tuple[Path, str | None] | None:
    """The territory mask :func:`save_world` wrote into ``folder`` (its ``territory.yaml``
    path and where the mask came from), None for a world made on the whole plan; a bad
    ``world.yaml`` raises InputError naming it."""
    p = need_file(Path(folder) / "world.yaml", "world file")
    meta = read_yaml(p, "world file")
    if not isinstance(meta, Mapping):
        raise InputError("expected a YAML mapping", path=p)
    t = meta.get("territory")
    if t is None:
        return None
    if not (isinstance(t, Mapping) and isinstance(t.get("mask"), str)):
        raise InputError(f"unexpected value {t!r}", path=p, field="territory")
    source = t.get("from")
    return Path(folder) / t["mask"], None if source is None else str(source)


def load_world(folder: str | Path) -> tuple[World, F64 | None]:
    """A world and its route (None if it was saved without one) from :func:`save_world`'s
    folder; a bad file raises InputError naming it (and the line and field)."""
    base = Path(folder)
    p = need_file(base / "world.yaml", "world file")
    meta = read_yaml(p, "world file")
    if not isinstance(meta, Mapping):
        raise InputError("expected a YAML mapping", path=p)
    if meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise InputError(f"not a {FORMAT} version {VERSION} file", path=p, field="format")
    dim = _meta_key(meta, "descriptor_dim", int, p)
    if dim < 1:
        raise InputError("must be >= 1", path=p, field="descriptor_dim")
    params = meta.get("params", {})
    if not isinstance(params, Mapping):
        raise InputError("expected a mapping", path=p, field="params")
    plan_file = Path(_meta_key(meta, "plan", str, p))
    plan_file = plan_file if plan_file.is_absolute() else base / plan_file
    plan = read_map(need_file(plan_file, "plan"))
    cols = _read_landmarks(base / _meta_key(meta, "landmarks", str, p), dim)
    route_name = meta.get("route")
    if route_name is not None and not isinstance(route_name, str):
        raise InputError(f"unexpected value {route_name!r}", path=p, field="route")
    route = None if route_name is None else read_route(base / route_name)
    own = meta["plan"] == "plan.yaml"
    world = World(plan=plan, params=dict(params), plan_path=None if own else str(plan_file), **cols)
    return world, route


def odometry_covariance(
    odo: F64, j: int, k: int, model: Mapping[str, float], bias_sd: float
) -> F64:
    """Covariance of the odometry between route steps j and k, from the robot's model of
    its odometry.

    Parameters
    ----------
    odo : ndarray (T, 4)
        ``t, x, y, theta`` as dead-reckoned.
    j, k : int
        The route steps, ``j <= k``.
    model : mapping of str to float
        The random noise's sizes ``sigma_xy``, ``sigma_theta``, ``sigma_theta_dist``
        (:func:`odometry`'s keywords; :data:`ODOMETRY_MODEL`); other keys are ignored.
    bias_sd : float
        Radians per metre: the robot's uncertainty about the heading bias left in the
        step (its prior :data:`~sonarmap.team.calibration.HEADING_BIAS_PRIOR`, or what
        a calibration leaves), counted as noise ``(bias_sd * s)^2`` on the heading.

    Returns
    -------
    ndarray (3, 3)
        Diagonal: x and y variance ``sigma_xy^2 s`` (m^2), heading ``sigma_theta^2 a +
        sigma_theta_dist^2 s + (bias_sd s)^2`` (rad^2), for ``s`` metres driven and ``a``
        radians turned, plus small floors.
    """
    d = np.diff(odo[j : k + 1, 1:3], axis=0)
    s = float(np.hypot(d[:, 0], d[:, 1]).sum())
    turn = float(np.abs(np.diff(np.unwrap(odo[j : k + 1, 3]))).sum())
    var_xy = model["sigma_xy"] ** 2 * s + 1e-6
    var_t = (
        model["sigma_theta"] ** 2 * turn
        + model["sigma_theta_dist"] ** 2 * s
        + (bias_sd * s) ** 2
        + 1e-8
    )
    return np.diag([var_xy, var_xy, var_t])


#: The robot's model of its odometry's random noise, for its edges' covariance
#: (:func:`odometry_covariance`): sizes a robot's maker states, here the simulator's
#: defaults. Its heading bias is not in it: a robot does not know that in advance (see
#: :mod:`~sonarmap.team.calibration`).
ODOMETRY_MODEL = {"sigma_xy": 0.02, "sigma_theta": 0.01, "sigma_theta_dist": 0.002}

#: The simulator's odometry noise (:func:`~sonarmap.team.world.odometry`'s defaults).
ODOMETRY_NOISE = {
    "sigma_xy": 0.02,
    "sigma_theta": 0.01,
    "sigma_theta_dist": 0.002,
    "bias_theta": 0.003,
}
