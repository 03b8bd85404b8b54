"""Map quality against a ground-truth floor plan on the same grid.

Maps are binarised at a threshold (0.5 by default, as the research does): a cell is
occupied when ``p >= threshold``, free below, unknown when NaN.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .errors import InputError
from .io.rosmap import OccupancyMap
from .scenarios import Passage, SmallObstacle

__all__ = [
    "MapScore",
    "ObstacleResult",
    "PassageResult",
    "agreement",
    "measure_obstacle",
    "measure_passage",
    "passage_open",
    "score",
]


@dataclass(frozen=True)
class MapScore:
    """Scores of one map against the truth.

    Attributes
    ----------
    accuracy, precision, recall, f1, iou : float
        Over the cells the map observed (not NaN); the last four of the occupied class
        (NaN when undefined).
    accuracy_all, precision_all, recall_all, f1_all, iou_all : float
        Over the whole map, unknown cells counted as free (what a planner that treats
        unknown space as free would see).
    unknown : float
        Fraction of the scored cells (all of a floor plan; the known ones of a reference
        map) left unknown.
    dist_to_truth : float
        Mean distance (metres) from each recovered obstacle cell to the nearest true one.
    dist_from_truth : float
        Mean distance from each true obstacle cell the map observed to the nearest
        recovered obstacle cell.
    passages, passages_open, passages_detected : int
        Truth passages; those left passable (:func:`passage_open`); those whose gap the
        map shows (:func:`measure_passage`).
    width_error : float
        Mean absolute error of the recovered widths of detected passages (metres).
    small_obstacles, small_found : int
        Annotated small obstacles, and those the map marks (:func:`measure_obstacle`).
    size_error : float
        Mean absolute size error of the small obstacles found (metres).
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
    small_obstacles: int
    small_found: int
    size_error: float

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


def _classes(
    t: npt.NDArray[np.bool_], occ: npt.NDArray[np.bool_], mask: npt.NDArray[np.bool_]
) -> tuple[float, float, float, float, float]:
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


def _mean_distance(src: npt.NDArray[np.bool_], dst: npt.NDArray[np.bool_], h: float) -> float:
    """Mean distance (metres) from the cells of ``src`` to the nearest cell of ``dst``."""
    if not src.any() or not dst.any():
        return math.nan
    dist = ndimage.distance_transform_edt(~dst) * h
    return float(np.mean(dist[src]))


def score(
    truth: OccupancyMap,
    m: OccupancyMap,
    passages: Sequence[Passage] = (),
    obstacles: Sequence[SmallObstacle] = (),
    *,
    threshold: float = 0.5,
) -> MapScore:
    """Compare a map with the truth (same grid).

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
    t = np.nan_to_num(truth.occupancy, nan=0.0) >= 0.5
    # A reference map (e.g. built from a laser) may leave cells unknown: they are not
    # scored at all. A floor plan knows every cell.
    scored = np.isfinite(truth.occupancy)
    known = np.isfinite(m.occupancy) & scored
    occ = np.zeros_like(known)
    occ[known] = m.occupancy[known] >= threshold
    observed = _classes(t, occ, known)
    whole = _classes(t, occ, scored)
    h = m.grid.resolution
    found = [measure_passage(m, p, threshold=threshold) for p in passages]
    detected = [r for r in found if r.detected]
    posts = [measure_obstacle(m, o, threshold=threshold) for o in obstacles]
    seen = [r for r in posts if r.found]
    return MapScore(
        *observed,
        *whole,
        unknown=float(1.0 - known.sum() / max(int(scored.sum()), 1)),
        dist_to_truth=_mean_distance(occ, t, h),
        dist_from_truth=_mean_distance(t & known, occ, h),
        passages=len(found),
        passages_open=sum(r.open for r in found),
        passages_detected=len(detected),
        width_error=float(np.mean([abs(r.width - r.true_width) for r in detected]))
        if detected
        else math.nan,
        small_obstacles=len(posts),
        small_found=len(seen),
        size_error=float(np.mean([abs(r.size - r.true_size) for r in seen])) if seen else math.nan,
    )


def agreement(a: OccupancyMap, b: OccupancyMap, *, threshold: float = 0.5) -> tuple[float, int]:
    """How often two maps of one grid agree: the fraction of the cells both know (not
    NaN) that both call occupied (>= ``threshold``) or both free, and the number of
    those cells.

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
    both = ~np.isnan(a.occupancy) & ~np.isnan(b.occupancy)
    n = int(both.sum())
    if n == 0:
        return float("nan"), 0
    same = (a.occupancy[both] >= threshold) == (b.occupancy[both] >= threshold)
    return float(same.mean()), n


def _axes(p: Passage) -> tuple[float, float, float, float]:
    """Middle of the opening and the unit vector from jamb ``a`` to jamb ``b``."""
    ax, ay = p.a
    bx, by = p.b
    return (ax + bx) / 2, (ay + by) / 2, (bx - ax) / p.width, (by - ay) / p.width


def _passage_frame(
    m: OccupancyMap, p: Passage
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Each cell centre's coordinate along the opening and across it, from its middle."""
    xc, yc = m.grid.all_centres()
    mx, my, ux, uy = _axes(p)
    along = (xc - mx) * ux + (yc - my) * uy
    across = -(xc - mx) * uy + (yc - my) * ux
    return along, across


def passage_open(
    m: OccupancyMap, p: Passage, *, threshold: float = 0.5, margin_cells: int = 2
) -> bool:
    """Whether the binarised map has a free 4-connected path through a passage.

    The path must stay within the opening (cells whose centres lie strictly between the
    jambs) and run from ``margin_cells`` cells before the obstacle to as far beyond it.
    Unknown cells are not free.
    """
    h = m.grid.resolution
    along, across = _passage_frame(m, p)
    reach = p.depth / 2 + margin_cells * h
    band = (np.abs(along) < p.width / 2) & (np.abs(across) <= reach)
    occ = m.occupancy
    free = band & np.isfinite(occ) & (np.nan_to_num(occ, nan=1.0) < threshold)
    labels, n = ndimage.label(free)
    if n == 0:
        return False
    near = band & (across <= -reach + h)
    far = band & (across >= reach - h)
    a = set(np.unique(labels[near & free]).tolist())
    b = set(np.unique(labels[far & free]).tolist())
    return bool((a & b) - {0})


@dataclass(frozen=True)
class PassageResult:
    """What a map shows of one passage.

    Attributes
    ----------
    width : float
        Recovered width in metres (see :func:`measure_passage`); NaN when no line across
        the passage is bounded by occupied cells on both sides.
    detected : bool
        The recovered width is positive and the gap holds at least one observed free cell.
    open : bool
        A free 4-connected path runs through the opening (:func:`passage_open`).
    """

    name: str
    true_width: float
    width: float
    detected: bool
    open: bool


def measure_passage(
    m: OccupancyMap, p: Passage, *, threshold: float = 0.5, search: float = 2.0
) -> PassageResult:
    """Recovered width of a passage, as the research measures it (thesis 002, fig. 4.10).

    Lines parallel to the opening are laid through the obstacle, one per cell across its
    depth plus one cell either side. On each line, starting at the cell nearest the passage
    centre, the run of non-occupied cells is followed both ways up to ``search`` metres
    past the jambs; a line whose run ends at occupied cells on both sides is *bounded* and
    its gap is the run's length. The recovered width is the narrowest bounded gap (0 when
    the centre cell is occupied there). Unknown cells do not bound a gap; a sonar that
    sees an opening from one side only leaves the space behind it unknown.
    """
    h = m.grid.resolution
    mx, my, ux, uy = _axes(p)
    nx, ny = -uy, ux
    occ = m.occupancy
    reach = p.width / 2 + search
    steps = math.ceil(reach / h)
    # A quarter-cell shift keeps samples off cell boundaries when the gap's centre
    # lies on one (an even number of cells), where rounding would pick either side.
    offsets = np.arange(-steps, steps + 1) * h + h / 4
    n_across = math.ceil((p.depth / 2) / h) + 1
    best = math.inf
    best_has_free = False
    for k in range(-n_across, n_across + 1):
        cx, cy = mx + k * h * nx, my + k * h * ny
        rows, cols = m.grid.world_to_cell(cx + offsets * ux, cy + offsets * uy)
        inside = m.grid.contains(rows, cols)
        vals = np.full(len(offsets), np.nan)
        vals[inside] = occ[rows[inside], cols[inside]]
        is_occ = np.nan_to_num(vals, nan=0.0) >= threshold
        is_free = np.isfinite(vals) & ~is_occ
        c = steps
        if is_occ[c]:
            gap, has_free = 0.0, False
        else:
            left = c
            while left - 1 >= 0 and not is_occ[left - 1]:
                left -= 1
            right = c
            while right + 1 < len(offsets) and not is_occ[right + 1]:
                right += 1
            if left == 0 or right == len(offsets) - 1:
                continue  # not bounded on both sides
            gap = (right - left + 1) * h
            has_free = bool(is_free[left : right + 1].any())
        if gap < best:
            best, best_has_free = gap, has_free
    width = best if math.isfinite(best) else math.nan
    detected = bool(math.isfinite(best) and best > 0 and best_has_free)
    return PassageResult(p.name, p.width, width, detected, passage_open(m, p, threshold=threshold))


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


def measure_obstacle(
    m: OccupancyMap, o: SmallObstacle, *, threshold: float = 0.5, reach: float = 0.3
) -> ObstacleResult:
    """Recovered size of a small obstacle.

    The occupied cells within ``reach`` metres of the obstacle's edge, 8-connected to a
    cell within half its size plus one cell of its centre, form the recovered obstacle;
    its size is the longer side of their bounding box (a wide beam grows small obstacles
    along the arc, which this measures).
    """
    h = m.grid.resolution
    xc, yc = m.grid.all_centres()
    d = np.maximum(np.abs(xc - o.centre[0]), np.abs(yc - o.centre[1]))
    occ = np.nan_to_num(m.occupancy, nan=0.0) >= threshold
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
