"""A prior map that is not the truth: the floor plan a robot is given, with the errors a
real plan has (thesis 002, chapter 2: the prior "may be imprecise but its large features
persist").

The simulator drives, senses and scores on the true plan; the robot aligns its global map
to, and cuts its regions from, the prior. :func:`degrade_plan` makes a prior from the
truth with four kinds of error, each drawn from a seed:

- **Doors closed**: a doorway of the truth drawn as wall. A doorway is found on the
  occupancy map as a gap in a thin wall: a run of free cells, between ``door_min`` and
  ``door_max`` metres long, with a cell of a wall at each end (the jambs: an obstacle
  spanning at least ``jamb_min`` metres, not a speck or a pillar), repeated over
  at most ``wall_max`` metres of consecutive rows (the wall's thickness), and with the
  free space wider than the gap on both sides of the wall (so a narrow corridor, which
  stays narrow, is not a door). Rows and columns are searched alike.
- **Doors opened**: a doorway the truth does not have, ``door_width`` metres wide, cut
  through a thin wall (occupied over at most ``wall_max`` metres across it, free cells on
  both sides) where the wall goes on for at least one cell beyond each jamb.
- **Furniture missing**: a small obstacle of the truth drawn free. Furniture is either a
  connected blob of occupied cells (8-neighbours; an unknown inside included) whose outer
  ring of cells is all free, or a block thicker than any wall (it survives a
  morphological opening by a square ``wall_max`` + 2 cells wide) standing against a wall
  with more than half its outline free, the wall itself (straight runs longer than
  ``furniture_max``) left standing; either spans ``furniture_min`` to
  ``furniture_max`` metres (smaller blobs are speckle, larger ones walls), and a blob
  alone keeps off the map's edge.
- **Scale error**: the plan drawn ``1 + scale`` times too large (a wrong resolution on a
  scanned drawing): resampled about the map's origin at the truth's resolution, a cell of
  the prior taking the most occupied class of the true cells it covers (occupied over
  unknown over free), so that one-cell walls survive a shrinking plan.

:func:`check_prior` refuses a prior file that cannot be matched to the truth: a
resolution more than ``MAX_RESOLUTION_RATIO`` times off, or an extent that covers less
than ``MIN_OVERLAP`` of the truth's (or the truth less than that of the prior's).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import ConfigError, InputError
from ..grid import Grid
from ..io.rosmap import FREE, OCCUPIED, UNKNOWN, OccupancyMap, read_plan
from .territory import mask_on

__all__ = [
    "MAX_RESOLUTION_RATIO",
    "MIN_OVERLAP",
    "Door",
    "PriorError",
    "PriorReport",
    "check_prior",
    "check_prior_inside",
    "degrade_plan",
    "find_doors",
    "find_furniture",
    "find_walls_to_open",
    "make_prior",
    "parse_prior_error",
    "scale_plan",
]

Mask = npt.NDArray[np.bool_]
I8 = npt.NDArray[np.int8]

#: A prior whose resolution is more than this many times finer or coarser than the
#: truth's cannot be matched to it (a resolution in the wrong unit).
MAX_RESOLUTION_RATIO = 4.0
#: Share of the truth's extent a prior's extent must cover, and of the prior's the
#: truth's must (an origin or a resolution that puts the plan elsewhere).
MIN_OVERLAP = 0.5

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class PriorError:
    """How a prior differs from the truth (:func:`degrade_plan`).

    Parameters
    ----------
    close_doors : int
        Doorways of the truth drawn as wall (0).
    open_doors : int
        Doorways the truth lacks cut through thin walls (0).
    drop_furniture : int
        Furniture blobs of the truth drawn free (0).
    scale : float
        The prior drawn ``1 + scale`` times the truth's size about the map's origin
        (0; in (-0.5, 0.5)).
    seed : int
        Which doors, walls and blobs are drawn (0).
    door_min, door_max : float
        Metres: the widths a doorway of the truth may have (0.5, 1.6).
    door_width : float
        Metres: the width of an opened doorway (0.9).
    wall_max : float
        Metres: the thickest wall a doorway is found in or cut through (0.4).
    jamb_min : float
        Metres: the shortest obstacle (bounding box) a doorway's jamb may belong to (1.0):
        a gap between specks or pillars is no doorway.
    furniture_min, furniture_max : float
        Metres: the bounding-box sizes a furniture blob may span (0.2, 2.5).
    """

    close_doors: int = 0
    open_doors: int = 0
    drop_furniture: int = 0
    scale: float = 0.0
    seed: int = 0
    door_min: float = 0.5
    door_max: float = 1.6
    door_width: float = 0.9
    wall_max: float = 0.4
    jamb_min: float = 1.0
    furniture_min: float = 0.2
    furniture_max: float = 2.5

    def __post_init__(self) -> None:
        for name in ("close_doors", "open_doors", "drop_furniture", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ConfigError(f"prior error '{name}' must be an integer >= 0, got {v!r}")
        if not (math.isfinite(self.scale) and -0.5 < self.scale < 0.5):
            raise ConfigError(f"prior error 'scale' must be in (-0.5, 0.5), got {self.scale}")
        for name in ("door_min", "door_max", "door_width", "wall_max", "jamb_min"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"prior error '{name}' must be > 0 metres, got {v}")
        if self.door_min > self.door_max or self.furniture_min > self.furniture_max:
            raise ConfigError(
                "prior error: door_min <= door_max and furniture_min <= furniture_max"
            )

    @property
    def none(self) -> bool:
        """Whether the prior is the truth itself."""
        return not (self.close_doors or self.open_doors or self.drop_furniture or self.scale)


#: ``--prior-error`` keys and the :class:`PriorError` fields they set.
ERROR_KEYS = {
    "close-doors": "close_doors",
    "open-doors": "open_doors",
    "furniture": "drop_furniture",
    "scale": "scale",
    "seed": "seed",
}


def parse_prior_error(text: str, *, seed: int = 0, option: str = "--prior-error") -> PriorError:
    """``close-doors=N,open-doors=N,furniture=N,scale=S,seed=K`` (any of them,
    comma-separated) as a :class:`PriorError` drawn from ``seed`` unless the spec gives
    its own (to vary the prior alone while the mission keeps its seed); a bad item raises
    :class:`ConfigError` naming ``option`` and the item."""
    values: dict[str, Any] = {}
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or key not in ERROR_KEYS:
            raise ConfigError(
                f"{option}: expected KEY=VALUE with KEY one of {', '.join(ERROR_KEYS)}, "
                f"got {item!r}"
            )
        name = ERROR_KEYS[key]
        try:
            values[name] = float(value) if name == "scale" else int(value)
        except ValueError:
            kind = "a number" if name == "scale" else "an integer"
            raise ConfigError(f"{option} {key}: {kind} expected, got {value!r}") from None
    values.setdefault("seed", seed)
    try:
        return PriorError(**values)
    except ConfigError as err:
        raise ConfigError(f"{option}: {err}") from None


@dataclass(frozen=True)
class Door:
    """A doorway: the cells ``rows x cols`` (half-open ranges) that close it."""

    rows: tuple[int, int]
    cols: tuple[int, int]

    @property
    def corners(self) -> tuple[list[int], list[int]]:
        """Rows and columns of its first and last cells."""
        return [self.rows[0], self.rows[1] - 1], [self.cols[0], self.cols[1] - 1]

    def width(self, resolution: float) -> float:
        """Metres along the wall (the longer side)."""
        return max(self.rows[1] - self.rows[0], self.cols[1] - self.cols[0]) * resolution


def _runs(line: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open ``(start, end)`` of each run of True in a 1-D mask."""
    d = np.diff(np.concatenate(([0], line.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _run_at(line: npt.NDArray[np.bool_], c: int) -> tuple[int, int]:
    """The run of True in ``line`` containing index ``c`` (empty if ``line[c]`` is False)."""
    if not line[c]:
        return (c, c)
    lo = c
    while lo > 0 and line[lo - 1]:
        lo -= 1
    hi = c + 1
    while hi < len(line) and line[hi]:
        hi += 1
    return (lo, hi)


def _walls(cls: I8, h: float, err: PriorError) -> Mask:
    """Occupied cells of blobs spanning at least ``jamb_min`` metres (walls, not specks
    or pillars)."""
    labels, n = ndimage.label(cls == OCCUPIED, structure=_EIGHT)
    long = np.zeros(n + 1, dtype=bool)
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        long[k] = sl is not None and _span(sl, h) >= err.jamb_min
    return np.asarray(long[labels], dtype=bool)


def _doors_along_rows(cls: I8, h: float, err: PriorError) -> list[Door]:
    """Doorways in walls that run along the rows (gaps seen as short free runs in a row)."""
    free = cls == FREE
    occ = _walls(cls, h, err)
    lo_w, hi_w = math.ceil(err.door_min / h - 1e-9), math.floor(err.door_max / h + 1e-9)
    thick = max(1, round(err.wall_max / h))
    gaps: dict[tuple[int, int], list[int]] = {}
    for r in range(cls.shape[0]):
        for a, b in _runs(free[r]):
            if lo_w <= b - a <= hi_w and a > 0 and b < cls.shape[1] and occ[r, a - 1] and occ[r, b]:
                gaps.setdefault((a, b), []).append(r)
    doors = []
    for (a, b), rows in gaps.items():
        for r0, r1 in _runs(np.isin(np.arange(cls.shape[0]), rows)):
            if r1 - r0 > thick or r0 == 0 or r1 == cls.shape[0]:
                continue
            mid = (a + b) // 2
            before, after = _run_at(free[r0 - 1], mid), _run_at(free[r1], mid)
            # The space on each side of the wall is wider than the gap, past both jambs.
            if before[0] < a and before[1] > b and after[0] < a and after[1] > b:
                doors.append(Door((r0, r1), (a, b)))
    return doors


def find_doors(plan: OccupancyMap, err: PriorError | None = None) -> list[Door]:
    """The doorways of ``plan`` (see the module's notes), in row-major order of their
    first cell. ``err`` gives the widths and wall thickness (:class:`PriorError`'s
    defaults unless given)."""
    err = PriorError() if err is None else err
    cls, h = plan.classes(), plan.grid.resolution
    doors = _doors_along_rows(cls, h, err)
    doors += [Door(d.cols, d.rows) for d in _doors_along_rows(cls.T.copy(), h, err)]
    return sorted(doors, key=lambda d: (d.rows[0], d.cols[0], d.rows[1], d.cols[1]))


def _walls_along_rows(cls: I8, h: float, err: PriorError) -> list[Door]:
    """Places to cut a doorway through a wall that runs along the rows."""
    free, occ = cls == FREE, cls == OCCUPIED
    thick = max(1, round(err.wall_max / h))
    width = max(1, round(err.door_width / h))
    rows_n, cols_n = cls.shape
    # Per column, the thin occupied spans (r0, r1) with free cells above and below.
    by_span: dict[tuple[int, int], list[int]] = {}
    for c in range(cols_n):
        for r0, r1 in _runs(occ[:, c]):
            if r1 - r0 <= thick and r0 > 0 and r1 < rows_n and free[r0 - 1, c] and free[r1, c]:
                by_span.setdefault((r0, r1), []).append(c)
    out = []
    for (r0, r1), cols in by_span.items():
        for c0, c1 in _runs(np.isin(np.arange(cols_n), cols)):
            # A jamb of wall at least one cell wide is left on each side of the cut.
            for start in range(c0 + 1, c1 - width, width):
                out.append(Door((r0, r1), (start, start + width)))
    return out


def find_walls_to_open(plan: OccupancyMap, err: PriorError | None = None) -> list[Door]:
    """Where a doorway ``err.door_width`` wide can be cut through a thin wall of
    ``plan`` (see the module's notes): candidate cuts, side by side along each wall, in
    row-major order."""
    err = PriorError() if err is None else err
    cls, h = plan.classes(), plan.grid.resolution
    walls = _walls_along_rows(cls, h, err)
    walls += [Door(d.cols, d.rows) for d in _walls_along_rows(cls.T.copy(), h, err)]
    return sorted(walls, key=lambda d: (d.rows[0], d.cols[0], d.rows[1], d.cols[1]))


def _span(sl: tuple[slice, ...], h: float) -> float:
    """Metres of the longer side of a bounding box."""
    return float(max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) * h)


def _inside(sl: tuple[slice, ...], shape: tuple[int, ...]) -> bool:
    """Whether a bounding box keeps off the map's edge."""
    r, c = sl[0], sl[1]
    return bool(r.start > 0 and c.start > 0 and r.stop < shape[0] and c.stop < shape[1])


def _free_blobs(cls: I8, h: float, err: PriorError) -> list[Mask]:
    """Occupied blobs standing alone in free space, holes (unknown insides) included."""
    free = cls == FREE
    labels, _ = ndimage.label(cls == OCCUPIED, structure=_EIGHT)
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None or not (err.furniture_min <= _span(sl, h) <= err.furniture_max):
            continue
        if not _inside(sl, cls.shape):
            continue
        win = (slice(sl[0].start - 1, sl[0].stop + 1), slice(sl[1].start - 1, sl[1].stop + 1))
        blob = ndimage.binary_fill_holes(labels[win] == k)
        ring = ndimage.binary_dilation(blob, structure=_EIGHT) & ~blob
        if free[win][ring].all():
            mask = np.zeros(cls.shape, dtype=bool)
            mask[win] = blob & ~free[win]
            out.append(mask)
    return out


def _thick_blobs(cls: I8, h: float, err: PriorError, taken: Mask) -> list[Mask]:
    """Blocks thicker than any wall (they survive an opening wider than ``wall_max``),
    standing against a wall with most of their outline in free space; the wall they
    stand against (cells on a straight run longer than ``furniture_max``) stays."""
    solid = cls != FREE
    k = max(3, round(err.wall_max / h) + 2)
    thick = ndimage.binary_opening(solid, structure=np.ones((k, k), dtype=bool))
    run = round(err.furniture_max / h) + 2
    wall = ndimage.binary_opening(solid, structure=np.ones((1, run), dtype=bool))
    wall |= ndimage.binary_opening(solid, structure=np.ones((run, 1), dtype=bool))
    labels, _ = ndimage.label(thick, structure=_EIGHT)
    out = []
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None or not (err.furniture_min <= _span(sl, h) <= err.furniture_max):
            continue
        mask = labels == i
        if (mask & taken).any():
            continue
        ring = ndimage.binary_dilation(mask, structure=_EIGHT) & ~mask
        if (cls[ring] == FREE).mean() > 0.5:
            out.append(mask & ~wall)
    return out


def find_furniture(plan: OccupancyMap, err: PriorError | None = None) -> list[Mask]:
    """The furniture blobs of ``plan`` (see the module's notes), each a mask of the
    cells that are not free: blobs alone in free space first, then blocks thicker than
    a wall standing against one, each in row-major order of its first cell."""
    err = PriorError() if err is None else err
    cls, h = plan.classes(), plan.grid.resolution
    alone = _free_blobs(cls, h, err)
    taken = np.zeros(cls.shape, dtype=bool)
    for m in alone:
        taken |= m
    return alone + _thick_blobs(cls, h, err, taken)


def scale_plan(plan: OccupancyMap, scale: float) -> OccupancyMap:
    """``plan`` drawn ``1 + scale`` times too large about its origin, at its resolution
    (see the module's notes); a cell takes 0 (free), NaN (unknown) or 1 (occupied)."""
    f = 1.0 + scale
    if not (math.isfinite(f) and f > 0):
        raise ConfigError(f"scale must be > -1, got {scale}")
    g = plan.grid
    # Rank classes so that a max keeps the most occupied: free < unknown < occupied.
    rank = np.select([plan.classes() == OCCUPIED, plan.classes() == UNKNOWN], [2, 1], 0)
    # Scaling is about the origin (lower-left): work bottom-up, then flip back.
    up = rank[::-1]
    rows, cols = max(1, round(g.rows * f)), max(1, round(g.cols * f))
    # The tolerance keeps 55 / 1.1 from flooring to 49.
    r_start = np.minimum(np.floor(np.arange(rows) / f + 1e-9).astype(np.int64), g.rows - 1)
    c_start = np.minimum(np.floor(np.arange(cols) / f + 1e-9).astype(np.int64), g.cols - 1)
    # reduceat: [start_i, start_{i+1}) blocks when shrinking, one cell when growing.
    out = np.maximum.reduceat(np.maximum.reduceat(up, r_start, axis=0), c_start, axis=1)
    occ = np.choose(out[::-1], [np.float32(0.0), np.float32(np.nan), np.float32(1.0)])
    return OccupancyMap(Grid(g.resolution, g.origin, (rows, cols)), occ.astype(np.float32))


@dataclass
class PriorReport:
    """What :func:`degrade_plan` changed, for ``summary.json``.

    Attributes
    ----------
    error : PriorError
        What was asked.
    doors_found, walls_found, furniture_found : int
        Candidates the truth offered for each change.
    doors_closed, doors_opened, furniture_dropped : list of list of float
        Where each change was made: ``[x, y]`` of its centre, metres in the truth's frame.
    cells_changed : int
        Cells of the truth's grid whose class the changes (before scaling) altered.
    scale_shift_max_m : float
        How far the scale moves the truth's farthest corner from the origin, metres.
    """

    error: PriorError
    doors_found: int = 0
    walls_found: int = 0
    furniture_found: int = 0
    doors_closed: list[list[float]] = field(default_factory=list)
    doors_opened: list[list[float]] = field(default_factory=list)
    furniture_dropped: list[list[float]] = field(default_factory=list)
    cells_changed: int = 0
    scale_shift_max_m: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON values."""
        d = asdict(self)
        d["error"] = {k: v for k, v in asdict(self.error).items()}
        return d


def _centre(grid: Grid, rows: npt.ArrayLike, cols: npt.ArrayLike) -> list[float]:
    """``[x, y]``, metres: the mean of the cells' centres."""
    x, y = grid.cell_centres(rows, cols)
    return [round(float(np.mean(x)), 3), round(float(np.mean(y)), 3)]


def _pick(rng: np.random.Generator, n: int, k: int) -> list[int]:
    """``min(k, n)`` distinct indices of ``n``, sorted."""
    return sorted(rng.choice(n, size=min(k, n), replace=False).tolist()) if n and k else []


def degrade_plan(plan: OccupancyMap, err: PriorError) -> tuple[OccupancyMap, PriorReport]:
    """A prior made from the true ``plan`` with the errors ``err`` (see the module's
    notes): doors closed, doors opened, furniture dropped, then the scale.

    Asked for more changes of a kind than the truth offers, it makes as many as there
    are; the report says how many were found and where each change went.

    Returns
    -------
    prior : OccupancyMap
        On the truth's grid, or (with a scale error) on a grid ``1 + scale`` times its
        size, same resolution and origin.
    report : PriorReport
    """
    rng = np.random.default_rng(err.seed)
    g = plan.grid
    occ = plan.occupancy.copy()
    report = PriorReport(err)
    doors = find_doors(plan, err)
    walls = find_walls_to_open(plan, err)
    blobs = find_furniture(plan, err)
    report.doors_found, report.walls_found, report.furniture_found = (
        len(doors),
        len(walls),
        len(blobs),
    )
    for i in _pick(rng, len(doors), err.close_doors):
        d = doors[i]
        occ[d.rows[0] : d.rows[1], d.cols[0] : d.cols[1]] = 1.0
        report.doors_closed.append(_centre(g, *d.corners))
    opened: list[Door] = []
    for i in _pick(rng, len(walls), err.open_doors * 4):
        # Two cuts side by side would make one wide gap: keep them a door apart.
        d = walls[i]
        if len(opened) == err.open_doors or any(_near(d, o) for o in opened):
            continue
        opened.append(d)
        occ[d.rows[0] : d.rows[1], d.cols[0] : d.cols[1]] = 0.0
        report.doors_opened.append(_centre(g, *d.corners))
    for i in _pick(rng, len(blobs), err.drop_furniture):
        occ[blobs[i]] = 0.0
        rr, cc = np.nonzero(blobs[i])
        report.furniture_dropped.append(_centre(g, rr, cc))
    prior = OccupancyMap(g, occ)
    report.cells_changed = int(np.count_nonzero(prior.classes() != plan.classes()))
    if err.scale:
        prior = scale_plan(prior, err.scale)
        report.scale_shift_max_m = round(
            abs(err.scale) * math.hypot(g.cols * g.resolution, g.rows * g.resolution), 3
        )
    return prior, report


def _near(a: Door, b: Door) -> bool:
    """Whether two cuts overlap or touch (within one door's width)."""
    w = max(a.rows[1] - a.rows[0], a.cols[1] - a.cols[0])
    return (
        a.rows[0] < b.rows[1] + w
        and b.rows[0] < a.rows[1] + w
        and a.cols[0] < b.cols[1] + w
        and b.cols[0] < a.cols[1] + w
    )


def _overlap(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> float:
    w = min(a[1], b[1]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[2], b[2])
    return max(w, 0.0) * max(h, 0.0)


def check_prior(truth: OccupancyMap, prior: OccupancyMap, where: str) -> None:
    """Refuse a prior that cannot be matched to the truth, in one line naming ``where``
    (the option and file it came from): no free cell, a resolution more than
    :data:`MAX_RESOLUTION_RATIO` times off the truth's, or extents that overlap on less
    than :data:`MIN_OVERLAP` of either (an origin or a resolution that puts the plan
    elsewhere). Raises :class:`InputError`."""
    ratio = prior.grid.resolution / truth.grid.resolution
    if not (1 / MAX_RESOLUTION_RATIO <= ratio <= MAX_RESOLUTION_RATIO):
        raise InputError(
            f"resolution {prior.grid.resolution:g} m is {ratio:.3g} times the map's "
            f"{truth.grid.resolution:g} m (at most {MAX_RESOLUTION_RATIO:g}x either way)",
            path=where,
            field="resolution",
        )
    te, pe = truth.grid.extent, prior.grid.extent
    common = _overlap(te, pe)
    t_area = (te[1] - te[0]) * (te[3] - te[2])
    p_area = (pe[1] - pe[0]) * (pe[3] - pe[2])
    share = min(common / t_area, common / p_area)
    if share < MIN_OVERLAP:
        raise InputError(
            f"its extent x {pe[0]:g}..{pe[1]:g}, y {pe[2]:g}..{pe[3]:g} m overlaps the map's "
            f"x {te[0]:g}..{te[1]:g}, y {te[2]:g}..{te[3]:g} m on {100 * share:.0f} % "
            f"(at least {100 * MIN_OVERLAP:.0f} %): check its origin and resolution",
            path=where,
            field="origin",
        )
    if not (prior.classes() == FREE).any():
        raise InputError("the prior has no free cell", path=where)


def make_prior(
    plan: OccupancyMap,
    path: str | Path | None = None,
    error: str | None = None,
    *,
    seed: int = 0,
    resolution: float | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
    option: str = "--prior",
    error_option: str = "--prior-error",
) -> tuple[OccupancyMap | None, dict[str, Any] | None]:
    """The robots' prior map, as ``team run --prior PATH --prior-error SPEC`` makes it.

    Parameters
    ----------
    plan : OccupancyMap
        The truth the robots drive, sense and are scored on.
    path : str or Path, optional
        A prior map file (:func:`~sonarmap.io.rosmap.read_plan`: a map_server YAML, or
        an image with ``resolution`` and ``origin``), checked against ``plan``
        (:func:`check_prior`). Default: ``plan`` itself.
    error : str, optional
        Errors to put into the prior (:func:`parse_prior_error`'s spec, drawn from
        ``seed`` unless it gives its own); the result must still match ``plan``.
    seed : int
        The mission's seed. Default 0.
    resolution : float, optional
        Metres per pixel of a bare image ``path``.
    origin : (float, float)
        Metres: the world position of a bare image's lower-left corner.
    option, error_option : str
        What ``path`` and ``error`` were given as, for the messages (default
        ``"--prior"`` and ``"--prior-error"``).

    Returns
    -------
    (OccupancyMap or None, dict or None)
        The prior (None with neither ``path`` nor ``error``: the plan itself) and what
        ``summary.json`` records of it: its ``source`` and :meth:`PriorReport.to_dict`.

    Raises
    ------
    ConfigError
        No such file, a bad spec, or a spec whose prior no longer matches ``plan``, in
        one line naming ``option`` or ``error_option``.
    InputError
        A file that cannot be read or matched to ``plan``, naming ``option PATH``.
    """
    if path is None and error is None:
        return None, None
    base, source = plan, "the map"
    if path is not None:
        if not Path(path).is_file():
            raise ConfigError(f"{option} {path}: no such file")
        base, source = read_plan(path, resolution, origin), str(path)
        check_prior(plan, base, f"{option} {path}")
    desc: dict[str, Any] = {"source": source}
    if error is None:
        return base, desc
    prior, report = degrade_plan(base, parse_prior_error(error, seed=seed, option=error_option))
    # The same rule as for a user's file, so that both transports take the same priors
    # (a node checks the prior it is handed).
    try:
        check_prior(plan, prior, "prior")
    except InputError as err:
        raise ConfigError(
            f"{error_option} {error}: the prior it makes no longer matches the map "
            f"({err.reason}; a smaller scale?)"
        ) from None
    desc.update(report.to_dict())
    return prior, desc


def check_prior_inside(
    plan: OccupancyMap,
    prior: OccupancyMap | None,
    region: npt.NDArray[np.bool_] | None,
    where: str,
) -> None:
    """Refuse a prior none of whose free cells lies inside the territory: its regions
    could not be cut inside it (a prior that does not match the plan).

    Parameters
    ----------
    plan : OccupancyMap
        The plan ``region`` is on.
    prior : OccupancyMap or None
        The prior (None: the plan itself, nothing to check).
    region : ndarray of bool or None
        The territory mask on the plan's cells (None: the whole plan, nothing to check).
    where : str
        The prior's name in the message (``"--prior FILE"``).

    Raises
    ------
    ConfigError
        In one line naming ``where``.
    """
    if prior is None or region is None:
        return
    if not ((prior.classes() == FREE) & mask_on(region, plan.grid, prior.grid)).any():
        raise ConfigError(
            f"{where}: no free cell of the prior lies inside the territory, so its "
            "regions cannot be cut inside it (does the prior match the map?)"
        )
