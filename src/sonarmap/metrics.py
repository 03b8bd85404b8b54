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
from .scenarios import Passage

__all__ = ["MapScore", "PassageResult", "measure_passage", "passage_open", "score"]


@dataclass(frozen=True)
class MapScore:
    """Scores of one map against the truth, over the cells the map observed.

    Attributes
    ----------
    accuracy : float
        Fraction of observed cells classified right.
    precision, recall, f1, iou : float
        Of the occupied class (NaN when undefined).
    unknown : float
        Fraction of all cells left unknown.
    passages_open : int
        Truth passages left passable (see :func:`passage_open`).
    passages : int
        Number of truth passages scored.
    passages_detected : int
        Truth passages whose gap the map shows (see :func:`measure_passage`).
    """

    accuracy: float
    precision: float
    recall: float
    f1: float
    iou: float
    unknown: float
    passages_open: int
    passages: int
    passages_detected: int

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


def score(
    truth: OccupancyMap,
    m: OccupancyMap,
    passages: Sequence[Passage] = (),
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
    >>> round(s.accuracy, 3), s.precision, s.recall, s.unknown
    (0.667, 0.5, 1.0, 0.25)
    """
    _check_same_grid(truth, m)
    t = np.nan_to_num(truth.occupancy, nan=0.0) >= 0.5
    known = np.isfinite(m.occupancy)
    occ = np.zeros_like(known)
    occ[known] = m.occupancy[known] >= threshold
    tp = int(np.sum(occ & t & known))
    fp = int(np.sum(occ & ~t & known))
    fn = int(np.sum(~occ & t & known))
    tn = int(np.sum(~occ & ~t & known))
    precision = _ratio(tp, tp + fp)
    recall = _ratio(tp, tp + fn)
    f1 = _ratio(2 * tp, 2 * tp + fp + fn)
    iou = _ratio(tp, tp + fp + fn)
    n_open = sum(passage_open(m, p, threshold=threshold) for p in passages)
    n_detected = sum(measure_passage(m, p, threshold=threshold).detected for p in passages)
    return MapScore(
        accuracy=_ratio(tp + tn, tp + tn + fp + fn),
        precision=precision,
        recall=recall,
        f1=f1,
        iou=iou,
        unknown=float(1.0 - known.mean()),
        passages_open=n_open,
        passages=len(passages),
        passages_detected=n_detected,
    )


def _passage_frame(
    m: OccupancyMap, p: Passage
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Each cell centre's coordinate along the opening and across it, from its middle."""
    xc, yc = m.grid.all_centres()
    ax, ay = p.a
    bx, by = p.b
    w = p.width
    ux, uy = (bx - ax) / w, (by - ay) / w
    mx, my = (ax + bx) / 2, (ay + by) / 2
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
    ax, ay = p.a
    bx, by = p.b
    ux, uy = (bx - ax) / p.width, (by - ay) / p.width
    nx, ny = -uy, ux
    mx, my = (ax + bx) / 2, (ay + by) / 2
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
