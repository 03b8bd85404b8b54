"""Map quality against a ground-truth floor plan on the same grid.

Every cell of a map is occupied, free or unknown (:func:`sonarmap.io.rosmap.classify`:
above 0.5, below 0.5, NaN or exactly 0.5); the written ``.pgm`` and the pictures use the
same classes. A truth map is scored where it is known (a floor plan everywhere, a laser
reference where the laser saw).

What a map must show to be credited with a passage (:func:`measure_passage`):

- *open*: the walls on both sides are there -- at least ``WALL_SHARE`` (75 %) of the
  first ``JAMB_LENGTH`` (0.3 m, or less where the truth's wall is shorter) of wall next
  to each jamb, in slices one cell wide across the wall, holds an occupied cell within
  the wall's thickness plus one cell -- **and** a 4-connected path of non-occupied cells
  crosses the opening between the jambs, through at least one free cell inside the
  wall's thickness (the map must have seen the gap, not merely left it unknown);
- *detected*: open, and the recovered width (the narrowest gap bounded by occupied
  cells on lines along the opening) within ``max(2 cells, 25 %)`` of the true width.

A *false opening* is a see-through gap in a wall where the truth has wall
(:func:`false_openings`). The passage score pays for them: passage F1 is
``2 D / (2 D + M + F)`` with D passages detected, M missed and F false openings.

The *observed walls* of a run are the truth's obstacle cells that some echo put its
range on (:func:`observed_walls`): the walls the readings saw, whatever the map made of
them. Their share the map marks occupied is the *observed-wall recall*; a map that
clears walls the sonar heard loses it however open its doors are.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ._walls_kernel import STEPS, crossings
from .annotations import Passage, SmallObstacle
from .errors import InputError
from .io.rosmap import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from .raster import rasterise
from .readings import Readings
from .rig import Rig

__all__ = [
    "JAMB_LENGTH",
    "MAX_WALL_THICKNESS",
    "WALL_SHARE",
    "FalseOpening",
    "MapScore",
    "ObstacleResult",
    "PassageResult",
    "agreement",
    "false_openings",
    "measure_obstacle",
    "measure_passage",
    "observed_walls",
    "passage_open",
    "quality",
    "score",
    "width_tolerance",
]

B = npt.NDArray[np.bool_]
F = npt.NDArray[np.float64]

#: Length of wall next to each jamb that must be present (metres).
JAMB_LENGTH = 0.3
#: Share of that wall, in slices across it, that must hold an occupied cell.
WALL_SHARE = 0.75
#: Thickest obstacle a straight crossing of a wall may pass through (metres).
MAX_WALL_THICKNESS = 1.0
#: See-through gaps lying wholly within this many cells of an annotated opening widen
#: that opening (its width error), rather than open a new one.
JAMB_CELLS = 2


def width_tolerance(true_width: float, resolution: float) -> float:
    """How far a recovered width may be from the truth for a detection (metres):
    two cells or 25 % of the true width, whichever is larger.

    Examples
    --------
    >>> width_tolerance(0.2, 0.05), width_tolerance(1.2, 0.05)
    (0.1, 0.3)
    """
    return max(2.0 * resolution, 0.25 * true_width)


@dataclass(frozen=True)
class MapScore:
    """Scores of one map against the truth.

    Attributes
    ----------
    accuracy, precision, recall, f1, iou : float
        Over the cells the map knows (not unknown); the last four of the occupied class
        (NaN when undefined).
    accuracy_all, precision_all, recall_all, f1_all, iou_all : float
        Over every scored cell, unknown counted as not occupied: a wall the map leaves
        unknown is missed. ``f1_all`` is the *wall F1* of the tables.
    unknown : float
        Fraction of the scored cells the map leaves unknown.
    dist_to_truth : float
        Mean distance (metres) from each recovered obstacle cell to the nearest true one.
    dist_from_truth : float
        Mean distance from each true obstacle cell the map knows to the nearest
        recovered obstacle cell.
    passages, passages_open, passages_detected : int
        Annotated passages; those open; those detected (see the module notes).
    width_error : float
        Mean absolute error of the recovered widths of the detected passages (metres).
    false_openings : int
        See-through gaps in walls where the truth has wall (:func:`false_openings`).
    false_opening_width : float
        Their total width along the walls (metres).
    passage_f1 : float
        ``2 D / (2 D + M + F)``: detected passages against missed ones and false
        openings (NaN with neither passages nor false openings).
    small_obstacles, small_found : int
        Annotated small obstacles, and those the map marks (:func:`measure_obstacle`).
    size_error : float
        Mean absolute size error of the small obstacles found (metres).
    observed_wall_recall : float
        Share of the observed walls (:func:`observed_walls`) the map marks occupied; NaN
        when the score was not given them, or there are none.
    quality : float
        What sweeps rank parameters by (:func:`quality`): the geometric mean of wall F1,
        passage F1 and observed-wall recall, each part that is scored. Erasing walls
        lowers all three, closing every door the second, marking everything occupied
        the first two.
    """

    accuracy: float
    precision: float
    recall: float
    f1: float
    iou: float
    accuracy_all: float
    precision_all: float
    recall_all: float
    f1_all: float
    iou_all: float
    unknown: float
    dist_to_truth: float
    dist_from_truth: float
    passages: int
    passages_open: int
    passages_detected: int
    width_error: float
    false_openings: int
    false_opening_width: float
    passage_f1: float
    small_obstacles: int
    small_found: int
    size_error: float
    observed_wall_recall: float
    quality: float

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def _ratio(a: int, b: int) -> float:
    return a / b if b else math.nan


def _check_same_grid(truth: OccupancyMap, m: OccupancyMap) -> None:
    if truth.grid != m.grid:
        raise InputError(
            f"map grid {m.grid} differs from the truth grid {truth.grid}; "
            "build the map with the truth's grid (e.g. --like TRUTH.yaml)"
        )


def _classes(t: B, occ: B, mask: B) -> tuple[float, float, float, float, float]:
    tp = int(np.sum(occ & t & mask))
    fp = int(np.sum(occ & ~t & mask))
    fn = int(np.sum(~occ & t & mask))
    tn = int(np.sum(~occ & ~t & mask))
    return (
        _ratio(tp + tn, tp + tn + fp + fn),
        _ratio(tp, tp + fp),
        _ratio(tp, tp + fn),
        _ratio(2 * tp, 2 * tp + fp + fn),
        _ratio(tp, tp + fp + fn),
    )


def _mean_distance(src: B, dst: B, h: float) -> float:
    """Mean distance (metres) from the cells of ``src`` to the nearest cell of ``dst``."""
    if not src.any() or not dst.any():
        return math.nan
    dist = ndimage.distance_transform_edt(~dst) * h
    return float(np.mean(dist[src]))


def quality(wall_f1: float, pf1: float, observed_recall: float = math.nan) -> float:
    """The tuning objective: the geometric mean of wall F1, passage F1 and observed-wall
    recall.

    A part that is not scored (NaN: no passages nor false openings, no observed walls
    given) is left out; an undefined wall F1 (no walls marked nor true) counts 0. The
    parts multiply, so none can be traded away for another: a map that clears the walls
    the sonar heard to open its doors (issue 39), or closes every door to keep its
    walls, scores near 0. (The arithmetic mean, tried first on the training scenes,
    picked an inverse setting that detected no passage at all.)

    Examples
    --------
    >>> quality(0.4, 0.9), quality(0.4, float("nan")), quality(0.5, 0.8, 0.0)
    (0.6, 0.4, 0.0)
    """
    parts = [0.0 if math.isnan(wall_f1) else wall_f1]
    parts += [v for v in (pf1, observed_recall) if not math.isnan(v)]
    return float(round(math.prod(parts) ** (1.0 / len(parts)), 12))


def observed_walls(truth: OccupancyMap, rig: Rig, readings: Readings) -> B:
    """The truth's obstacle cells that an echo of ``readings`` put its range on.

    A cell is observed when its centre lies in some echo's beam between the measured
    range ``r`` and ``r + h`` (h the cell size): the first cell behind the surface the
    echo came from, where a map must mark it (:mod:`sonarmap.raster`), and not the far
    side of a thin wall. Readings without an echo observe nothing.

    Returns
    -------
    ndarray of bool, shape of the grid
        True on the observed wall cells (a subset of the truth's occupied cells).
    """
    h = truth.grid.resolution
    echo = readings.range < rig.sensor.r_max
    fp = rasterise(
        truth.grid,
        rig.sensor,
        readings.x[echo],
        readings.y[echo],
        readings.theta[echo],
        readings.range[echo],
        dr=h / 2,
        offset=h / 2,
    )
    hit = np.zeros(truth.grid.size, dtype=np.bool_)
    hit[fp.occ.cells] = True
    walls: B = hit.reshape(truth.grid.shape) & (truth.classes() == OCCUPIED)
    return walls


def passage_f1(detected: int, passages: int, false_openings: int) -> float:
    """Passage F1: ``2 D / (2 D + M + F)`` (NaN with nothing to score).

    Examples
    --------
    >>> passage_f1(3, 4, 0), passage_f1(3, 4, 2), passage_f1(0, 0, 0)
    (0.8571428571428571, 0.6666666666666666, nan)
    """
    missed = passages - detected
    return _ratio(2 * detected, 2 * detected + missed + false_openings)


def score(
    truth: OccupancyMap,
    m: OccupancyMap,
    passages: Sequence[Passage] = (),
    obstacles: Sequence[SmallObstacle] = (),
    observed: B | None = None,
) -> MapScore:
    """Compare a map with the truth (same grid).

    ``observed`` is the run's observed walls (:func:`observed_walls`), for the
    observed-wall recall and the quality; without it both leave the recall out.

    Examples
    --------
    >>> from sonarmap.grid import Grid
    >>> g = Grid(1.0, (0.0, 0.0), (1, 4))
    >>> t = OccupancyMap(g, np.array([[1, 0, 0, 1]], dtype=np.float32))
    >>> m = OccupancyMap(g, np.array([[0.9, 0.2, 0.7, np.nan]], dtype=np.float32))
    >>> s = score(t, m)
    >>> round(s.accuracy, 3), s.precision, s.recall, s.unknown, s.recall_all
    (0.667, 0.5, 1.0, 0.25, 0.5)
    """
    _check_same_grid(truth, m)
    tcls = truth.classes()
    mcls = m.classes()
    t = tcls == OCCUPIED
    scored = tcls != UNKNOWN
    known = (mcls != UNKNOWN) & scored
    occ = mcls == OCCUPIED
    on_known = _classes(t, occ, known)
    whole = _classes(t, occ, scored)
    h = m.grid.resolution
    found = [measure_passage(truth, m, p) for p in passages]
    detected = [r for r in found if r.detected]
    holes = false_openings(truth, m, passages)
    posts = [measure_obstacle(m, o) for o in obstacles]
    seen = [r for r in posts if r.found]
    pf1 = passage_f1(len(detected), len(found), len(holes))
    seen_walls = math.nan
    if observed is not None:
        if observed.shape != truth.grid.shape:
            raise InputError(
                f"observed walls of shape {observed.shape} differ from the grid {truth.grid.shape}"
            )
        seen_walls = _ratio(int(np.sum(observed & occ)), int(np.sum(observed)))
    return MapScore(
        *on_known,
        *whole,
        unknown=float(1.0 - known.sum() / max(int(scored.sum()), 1)),
        dist_to_truth=_mean_distance(occ & scored, t, h),
        dist_from_truth=_mean_distance(t & known, occ, h),
        passages=len(found),
        passages_open=sum(r.open for r in found),
        passages_detected=len(detected),
        width_error=float(np.mean([abs(r.width - r.true_width) for r in detected]))
        if detected
        else math.nan,
        false_openings=len(holes),
        false_opening_width=float(sum(o.width for o in holes)),
        passage_f1=pf1,
        small_obstacles=len(posts),
        small_found=len(seen),
        size_error=float(np.mean([abs(r.size - r.true_size) for r in seen])) if seen else math.nan,
        observed_wall_recall=seen_walls,
        quality=quality(whole[3], pf1, seen_walls),
    )


def agreement(a: OccupancyMap, b: OccupancyMap) -> tuple[float, int]:
    """How often two maps of one grid agree: the fraction of the cells both know that
    both call occupied or both free, and the number of those cells.

    Examples
    --------
    >>> from sonarmap.grid import Grid
    >>> g = Grid(1.0, (0.0, 0.0), (1, 4))
    >>> a = OccupancyMap(g, np.array([[1, 0, 0, np.nan]], dtype=np.float32))
    >>> b = OccupancyMap(g, np.array([[0.9, 0.2, 0.7, 1.0]], dtype=np.float32))
    >>> agreement(a, b)
    (0.6666666666666666, 3)
    """
    _check_same_grid(a, b)
    ca, cb = a.classes(), b.classes()
    both = (ca != UNKNOWN) & (cb != UNKNOWN)
    n = int(both.sum())
    if n == 0:
        return float("nan"), 0
    return float((ca[both] == cb[both]).mean()), n


# -- passages ------------------------------------------------------------------------


def _axes(p: Passage) -> tuple[float, float, float, float]:
    """Middle of the opening and the unit vector from jamb ``a`` to jamb ``b``."""
    ax, ay = p.a
    bx, by = p.b
    return (ax + bx) / 2, (ay + by) / 2, (bx - ax) / p.width, (by - ay) / p.width


def _passage_frame(m: OccupancyMap, p: Passage) -> tuple[F, F]:
    """Each cell centre's coordinate along the opening and across it, from its middle."""
    xc, yc = m.grid.all_centres()
    mx, my, ux, uy = _axes(p)
    along = (xc - mx) * ux + (yc - my) * uy
    across = -(xc - mx) * uy + (yc - my) * ux
    return along, across


@dataclass(frozen=True)
class PassageResult:
    """What a map shows of one passage.

    Attributes
    ----------
    width : float
        Recovered width in metres (the narrowest gap bounded by occupied cells on lines
        along the opening); NaN when no such line is bounded on both sides.
    walls : tuple of float
        Share of the wall next to jamb ``a`` and jamb ``b`` that the map closes.
    crossed : bool
        A non-occupied 4-connected path crosses the opening through a free cell.
    open : bool
        Both walls present (share >= :data:`WALL_SHARE`) and ``crossed``.
    detected : bool
        Open, and ``width`` within :func:`width_tolerance` of ``true_width``.
    """

    name: str
    true_width: float
    width: float
    walls: tuple[float, float]
    crossed: bool
    open: bool
    detected: bool


def measure_passage(truth: OccupancyMap, m: OccupancyMap, p: Passage) -> PassageResult:
    """Whether a map shows a passage open, detected, and how wide (see the module notes).

    Raises
    ------
    InputError
        When the truth has no wall next to a jamb (the annotation does not match it).
    """
    _check_same_grid(truth, m)
    h = m.grid.resolution
    along, across = _passage_frame(m, p)
    mcls = m.classes()
    walls = (
        _wall_share(truth, mcls, p, along, across, -1.0),
        _wall_share(truth, mcls, p, along, across, 1.0),
    )
    crossed = _crossed(mcls, p, along, across, h)
    walled = min(walls) >= WALL_SHARE
    width = _recovered_width(m, mcls, p)
    is_open = walled and crossed
    detected = is_open and abs(width - p.width) <= width_tolerance(p.width, h) + 1e-9
    return PassageResult(p.name, p.width, width, walls, crossed, is_open, bool(detected))


def passage_open(truth: OccupancyMap, m: OccupancyMap, p: Passage) -> bool:
    """Whether a map shows a passage open (:func:`measure_passage`)."""
    return measure_passage(truth, m, p).open


def _wall_share(
    truth: OccupancyMap,
    mcls: npt.NDArray[np.int8],
    p: Passage,
    along: F,
    across: F,
    side: float,
) -> float:
    """Share of the truth's wall beside one jamb (``side`` -1: jamb a, +1: jamb b) that
    the map closes, in slices one cell wide along the wall."""
    h = truth.grid.resolution
    length = max(JAMB_LENGTH, 3 * h)
    beyond = side * along - p.width / 2  # distance past the jamb, along the wall
    slices = np.floor(beyond / h).astype(np.int64)
    n = math.ceil(length / h)
    near = (slices >= 0) & (slices < n)
    in_wall = near & (np.abs(across) <= p.depth / 2 + h / 2)
    band = near & (np.abs(across) <= p.depth / 2 + h)
    tcls = truth.classes()
    has_wall = np.bincount(slices[in_wall & (tcls == OCCUPIED)], minlength=n)[:n] > 0
    if not has_wall[0]:
        raise InputError(
            f"passage '{p.name}': the truth has no wall next to jamb {'a' if side < 0 else 'b'}"
        )
    # The wall runs from the jamb to its first break; beyond it is another opening.
    run = int(np.argmin(has_wall)) if not has_wall.all() else n
    closed = np.bincount(slices[band & (mcls == OCCUPIED)], minlength=n)[:run] > 0
    return float(closed.mean())


def _crossed(mcls: npt.NDArray[np.int8], p: Passage, along: F, across: F, h: float) -> bool:
    """A 4-connected path of non-occupied cells runs through the opening, from two cells
    before the obstacle to two cells past it, through a free cell within the obstacle."""
    reach = p.depth / 2 + 2 * h
    band = (np.abs(along) < p.width / 2) & (np.abs(across) <= reach)
    passable = band & (mcls != OCCUPIED)
    labels, n = ndimage.label(passable)
    if n == 0:
        return False
    near = set(np.unique(labels[passable & (across <= -reach + h)]).tolist())
    far = set(np.unique(labels[passable & (across >= reach - h)]).tolist())
    throat = passable & (mcls == FREE) & (np.abs(across) <= p.depth / 2)
    seen = set(np.unique(labels[throat]).tolist())
    return bool((near & far & seen) - {0})


def _recovered_width(m: OccupancyMap, mcls: npt.NDArray[np.int8], p: Passage) -> float:
    """The width of the gap in the map's wall (thesis 002, fig. 4.10).

    Lines parallel to the opening are laid through the obstacle, one per cell across
    its depth plus one cell either side. A line *holds the wall* when it has at least
    half as many occupied cells within :data:`JAMB_LENGTH` beyond both jambs (the weaker
    side counts) as the line that has most; a line in front of the wall, in the free
    space, does not, so a stray cell there does not narrow the gap. On each line that
    holds the wall, runs of non-occupied cells bounded by occupied cells on both sides,
    within 2 m of the opening, are gaps, and the one overlapping the true opening most
    is the line's (0 when none does). The recovered width is the narrowest of those:
    where the wall is several cells thick, the passage is as wide as its narrowest
    section. NaN when no line holds a wall on both sides. Unknown cells do not bound a
    gap: a sonar that sees an opening from one side only leaves the space behind it
    unknown.
    """
    h = m.grid.resolution
    mx, my, ux, uy = _axes(p)
    nx, ny = -uy, ux
    reach = p.width / 2 + 2.0
    steps = math.ceil(reach / h)
    # A quarter-cell shift keeps samples off cell boundaries (where the gap's centre or
    # the obstacle's mid-line may lie), where rounding would pick either side.
    offsets = np.arange(-steps, steps + 1, dtype=np.float64) * h + h / 4
    beyond = np.abs(offsets) - p.width / 2
    jamb = (beyond > 0) & (beyond <= max(JAMB_LENGTH, 3 * h))
    n_across = math.ceil((p.depth / 2) / h) + 1
    lines: list[tuple[int, npt.NDArray[np.bool_]]] = []
    for k in range(-n_across - 1, n_across + 1):
        shift = (k + 0.25) * h
        rows, cols = m.grid.world_to_cell(
            mx + shift * nx + offsets * ux, my + shift * ny + offsets * uy
        )
        inside = m.grid.contains(rows, cols)
        is_occ = np.zeros(len(offsets), dtype=np.bool_)
        is_occ[inside] = mcls[rows[inside], cols[inside]] == OCCUPIED
        left = int(np.sum(is_occ & jamb & (offsets < 0)))
        right = int(np.sum(is_occ & jamb & (offsets > 0)))
        lines.append((min(left, right), is_occ))
    most = max(held for held, _ in lines)
    if most == 0:
        return math.nan
    widths = [
        _gap_on_line(is_occ, offsets, p.width, h) for held, is_occ in lines if 2 * held >= most
    ]
    return min(widths)


def _gap_on_line(is_occ: npt.NDArray[np.bool_], offsets: F, width: float, h: float) -> float:
    """Length of the bounded non-occupied run overlapping [-width/2, width/2] most."""
    walls = np.flatnonzero(is_occ)
    best, overlap = 0.0, 0.0
    for a, b in itertools.pairwise(walls):
        if b - a < 2:
            continue
        o = min(offsets[b - 1] + h / 2, width / 2) - max(offsets[a + 1] - h / 2, -width / 2)
        if o > overlap:
            overlap, best = o, float(b - a - 1) * h
    return best


# -- false openings ---------------------------------------------------------------------


@dataclass(frozen=True)
class FalseOpening:
    """A see-through gap in a wall where the truth has wall.

    Attributes
    ----------
    centre : tuple of float
        World position (metres) of the gap's middle.
    width : float
        Its width along the wall (metres).
    cells : int
        Wall cells the map sees through there.
    """

    centre: tuple[float, float]
    width: float
    cells: int


def _closure(truth: OccupancyMap, passages: Sequence[Passage]) -> B:
    """The cells that close every annotated opening, wall to wall."""
    h = truth.grid.resolution
    out = np.zeros(truth.grid.shape, dtype=np.bool_)
    for p in passages:
        along, across = _passage_frame(truth, p)
        out |= (np.abs(along) <= p.width / 2 + h) & (np.abs(across) <= p.depth / 2 + h / 2)
    return out


def false_openings(
    truth: OccupancyMap, m: OccupancyMap, passages: Sequence[Passage] = ()
) -> list[FalseOpening]:
    """See-through gaps in walls where the truth has wall.

    The truth's walls are its obstacles between two separate free regions once every
    annotated opening is closed: a straight line (along a row, a column or a diagonal)
    from a free cell of one region through at most :data:`MAX_WALL_THICKNESS` of
    obstacle to a free cell of another *crosses a wall*. (Obstacles that free space goes
    round, such as posts and cabinets, are not walls; annotate every opening so that the
    walls beside it are checked.) The map sees through a crossing when it has no
    occupied cell on it -- nor at the free cells at its two ends, so a wall recovered
    one cell off is still a wall -- and a free cell among its wall cells (a wall the
    map left unknown is unseen, not open).

    The wall cells of see-through crossings, 8-connected, form the false openings;
    one lying wholly within two cells of an annotated opening widens that opening
    instead (its recovered width shows it). A gap's width is the number of crossing
    positions it spans: the sum over its cells of one over the wall's thickness there.
    """
    _check_same_grid(truth, m)
    h = truth.grid.resolution
    tcls = truth.classes()
    closure = _closure(truth, passages)
    wall = (tcls == OCCUPIED) & ~closure
    free = (tcls == FREE) & ~closure
    region, _ = ndimage.label(free)
    max_cells = max(1, math.floor(MAX_WALL_THICKNESS / h + 1e-9))
    _, seen, thickness = crossings(wall, region.astype(np.int32), m.classes(), max_cells, STEPS)
    labels, n = ndimage.label(seen, structure=np.ones((3, 3)))
    if n == 0:
        return []
    jamb = ndimage.binary_dilation(closure, np.ones((3, 3)), iterations=JAMB_CELLS)
    xc, yc = truth.grid.all_centres()
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        part = labels[sl] == k
        if np.all(jamb[sl][part]):
            continue
        out.append(
            FalseOpening(
                (float(xc[sl][part].mean()), float(yc[sl][part].mean())),
                float(np.sum(1.0 / thickness[sl][part]) * h),
                int(part.sum()),
            )
        )
    return out


# -- small obstacles -------------------------------------------------------------------


@dataclass(frozen=True)
class ObstacleResult:
    """What a map shows of one small obstacle.

    Attributes
    ----------
    size : float
        Side of the bounding box of the occupied cells found there (metres), NaN if none.
    found : bool
        Some occupied cell lies within half the obstacle's size plus one cell of its centre.
    """

    name: str
    true_size: float
    size: float
    found: bool


def measure_obstacle(m: OccupancyMap, o: SmallObstacle, *, reach: float = 0.3) -> ObstacleResult:
    """Recovered size of a small obstacle.

    The occupied cells within ``reach`` metres of the obstacle's edge, 8-connected to a
    cell within half its size plus one cell of its centre, form the recovered obstacle;
    its size is the longer side of their bounding box (a wide beam grows small obstacles
    along the arc, which this measures).
    """
    h = m.grid.resolution
    xc, yc = m.grid.all_centres()
    d = np.maximum(np.abs(xc - o.centre[0]), np.abs(yc - o.centre[1]))
    occ = m.classes() == OCCUPIED
    window = occ & (d <= o.size / 2 + reach)
    labels, _ = ndimage.label(window, structure=np.ones((3, 3)))
    core = window & (d <= o.size / 2 + h)
    keep = set(np.unique(labels[core]).tolist()) - {0}
    if not keep:
        return ObstacleResult(o.name, o.size, math.nan, False)
    cells = np.isin(labels, list(keep))
    xs, ys = xc[cells], yc[cells]
    size = max(xs.max() - xs.min(), ys.max() - ys.min()) + h
    return ObstacleResult(o.name, o.size, float(size), True)
