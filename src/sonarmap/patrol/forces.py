"""The pull of every place on a robot, and the direction the robot chooses.

Place T pulls robot R with F = f(TB_n(T)) * g(L(R, T)) along the first direction of
the shortest path from R to T; TB_n = TB / MTB in [0, 1]; L in decimetres, as in the
thesis. The candidate families (docs/patrol.md):

- f1 TB_n, f2 TB_n^2, f3 e^(a TB_n), f4 e^(a TB_n^2), f5 e^(a TB_n^4);
- g1 1/L, g2 1/L^2, g3 e^(-L/b), g4 e^(-L^2/b^2), g5 e^(-L^4/b^4);

adopted f3 g4 with a = 40, b = 65 dm. Forces are summed in the log domain (the common
scale of all forces does not change a direction, and e^40 or e^-236 stay finite there).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from .paths import STEP_UNITS, Shadows, Wave

__all__ = [
    "FORCE_F",
    "FORCE_G",
    "Force",
    "choose_direction",
    "parse_force",
    "sector_pulls",
    "step_direction",
]

F64 = npt.NDArray[np.float64]

#: The families of f (of TB_n, scale a) and g (of L in decimetres, scale b).
FORCE_F = ("f1", "f2", "f3", "f4", "f5")
FORCE_G = ("g1", "g2", "g3", "g4", "g5")


@nb.njit(cache=True)
def _log_f(code: int, t: float, a: float) -> float:
    """log f_code(TB_n = t); -inf where f is 0."""
    if code <= 2:
        return code * math.log(t) if t > 0 else -np.inf
    if code == 3:
        return a * t
    t2 = t * t
    return a * t2 if code == 4 else a * (t2 * t2)


@nb.njit(cache=True)
def _log_g(code: int, dm: float, b: float) -> float:
    """log g_code(L = dm decimetres)."""
    if code <= 2:
        return -code * math.log(dm)
    x = dm / b
    if code == 3:
        return -x
    x2 = x * x
    return -x2 if code == 4 else -(x2 * x2)


@nb.njit(cache=True)
def _log_pull_array(fcode: int, gcode: int, a: float, b: float, tb_n: F64, length_m: F64) -> F64:
    out = np.empty(tb_n.shape[0])
    for i in range(tb_n.shape[0]):
        dm = length_m[i] * 10.0
        v = _log_f(fcode, tb_n[i], a) + _log_g(gcode, dm, b) if dm > 0 else -np.inf
        out[i] = v if v == v else -np.inf
    return out


#: log of the share of the strongest pull below which the pulls of far places are
#: dropped (about 1e-18: beneath the resolution of a float64 sum).
NEGLIGIBLE = -41.5
#: Relative difference below which two sectors' pulls count as equal.
TIE = 1e-9


@nb.njit(cache=True)
def _pull_limit(
    fcode: int,
    gcode: int,
    a: float,
    b: float,
    best: float,
    count: float,
    share: float = NEGLIGIBLE,
) -> float:
    """See :meth:`Force.pull_limit`; ``share`` the log of the remaining places' allowed
    total pull relative to ``best``."""
    if not (best > -np.inf and best < np.inf):
        return np.inf
    f_max = _log_f(fcode, 1.0, a)
    x = best - f_max - math.log(max(count, 1.0)) + share  # we need log g(L) < x
    if gcode <= 2:
        dm = math.exp(min(-x / gcode, 700.0))
    elif x >= 0:
        dm = 0.0
    elif gcode == 3:
        dm = b * -x
    elif gcode == 4:
        dm = b * math.sqrt(-x)
    else:
        dm = b * math.sqrt(math.sqrt(-x))
    return dm / 10.0


#: What :func:`sector_pulls` gathers: [0] the strongest log pull so far, [1:9] each
#: wave step's summed pull relative to it, [9] the watched cells taken, [10:18] each
#: step's strongest single log pull, [18:26] and [26:34] that place's row and column.
_BEST, _SUMS, _TAKEN, _STEP_BEST, _STEP_ROW, _STEP_COL = 0, 1, 9, 10, 18, 26
#: The visitor's numbers: TB = [0] + [1] x source, f and g codes, a, b, MTB, watched
#: cells, prune (0/1), certify the mode's choice (0: no, 1: the step, 2: the step and
#: its strongest place), the 8 steps' weights.
_ALPHA, _BETA, _F, _G, _A, _B, _TOP, _COUNT, _PRUNE, _CERTIFY, _WEIGHTS = range(11)
#: After the weights: whether shadows (:class:`~sonarmap.patrol.paths.Shadows`) pull,
#: and the side of the fog's blocks a place stands for, in fog cells (1: one cell).
_SHADE = _WEIGHTS + 8
_BLOCK = _SHADE + 1


@nb.njit(cache=True)
def _block_log_f(
    src: F64,
    watched: npt.NDArray[np.bool_],
    r: int,
    c: int,
    block: int,
    alpha: float,
    beta: float,
    inv_top: float,
    fcode: int,
    a: float,
) -> float:
    """log of the sum of f(TB_n) over the watched fog cells of block (r, c), ``block`` x
    ``block`` fog cells (TB = alpha + beta x src, TB_n = TB x inv_top); -inf when it has
    none or none pulls."""
    rows, cols = src.shape
    r1 = min((r + 1) * block, rows)
    c1 = min((c + 1) * block, cols)
    # Summed relative to the strongest, as the steps' sums are.
    most = -np.inf
    for fr in range(r * block, r1):
        for fc in range(c * block, c1):
            if watched[fr, fc]:
                most = max(most, _log_f(fcode, (alpha + beta * src[fr, fc]) * inv_top, a))
    if not most > -np.inf:
        return most
    total = 0.0
    # Cells seen by one look share their time: their terms are one exp.
    prev = np.nan
    term = 0.0
    for fr in range(r * block, r1):
        for fc in range(c * block, c1):
            if watched[fr, fc]:
                lf = _log_f(fcode, (alpha + beta * src[fr, fc]) * inv_top, a)
                if lf != prev:
                    prev = lf
                    term = math.exp(lf - most)
                total += term
    return most + math.log(total)


@nb.njit(cache=True)
def _top_two(sums: F64, weights: F64) -> tuple[int, float, float]:
    """Of the weighted sums ``sums * weights``: the index of the largest (the first
    among equals, as ``np.argmax``), its value and the largest of the others, without
    an array for the products (NaN, as ``np.argmax`` and ``max`` take it, wins)."""
    k = 0
    top = sums[0] * weights[0]
    for j in range(1, len(sums)):
        v = sums[j] * weights[j]
        if v > top or (v != v and top == top):
            k = j
            top = v
    rest = -np.inf
    for j in range(len(sums)):
        if j != k:
            v = sums[j] * weights[j]
            if v > rest or v != v:
                rest = v
    return k, top, rest


@nb.njit(cache=True)
def _pull_visit(
    order: npt.NDArray[np.int32],
    lo: int,
    hi: int,
    dist: F64,
    first: npt.NDArray[np.uint8],
    width: int,
    ctx: Any,
) -> float:
    """The wave's visitor summing pulls by first step (see :func:`sector_pulls`)."""
    tb_src, watched, fog_watched, p, acc, ptr, s_rows, s_cols, s_extra = ctx
    shade = p[_SHADE] != 0.0
    block = int(p[_BLOCK])
    # A block pulls as its cells together: at most this many times a cell's most.
    cells = float(block * block)
    cols = width - 2
    alpha, beta, top = p[_ALPHA], p[_BETA], p[_TOP]
    fcode, gcode, a, b = int(p[_F]), int(p[_G]), p[_A], p[_B]
    inv_top = 1.0 / top if top > 0 else 0.0
    best = acc[_BEST]
    taken = acc[_TAKEN]
    # Views into ``acc``, written in place: the visitor runs once per bucket of the
    # wave (hundreds per wave), where a copy would be an allocation each time.
    sums = acc[_SUMS : _SUMS + 8]
    step_best = acc[_STEP_BEST : _STEP_BEST + 8]
    inv_width = 1.0 / width
    for i in range(lo, hi):
        u = order[i]
        step = first[u]
        if step > 7:
            continue  # the start
        # Row by a float product, as in the wave (exact for these sizes).
        r = int((u + 0.5) * inv_width)
        c = u - r * width - 1
        r -= 1
        # The place itself, then the shadows tied to it (they pull as if there, a little
        # farther, and a robot goes for the place to see them).
        s_lo = s_hi = 0
        if shade:
            g = r * cols + c
            s_lo, s_hi = ptr[g], ptr[g + 1]
        for k in range(s_lo - 1, s_hi):
            if k < s_lo:
                if not watched[r, c]:
                    continue
                if block == 1:
                    lf = _log_f(fcode, (alpha + beta * tb_src[r, c]) * inv_top, a)
                else:
                    lf = _block_log_f(
                        tb_src, fog_watched, r, c, block, alpha, beta, inv_top, fcode, a
                    )
                length = dist[u]
            else:
                sr, sc = s_rows[k], s_cols[k]
                if block == 1:
                    lf = _log_f(fcode, (alpha + beta * tb_src[sr, sc]) * inv_top, a)
                else:
                    lf = _block_log_f(
                        tb_src, fog_watched, sr, sc, block, alpha, beta, inv_top, fcode, a
                    )
                length = dist[u] + s_extra[k]
            taken += 1.0
            lp = lf + _log_g(gcode, length * 10.0, b)
            if not lp > -np.inf:
                continue
            if lp > best:
                # A new strongest pull: every sum so far relative to it instead.
                if best > -np.inf:
                    scale = math.exp(best - lp)
                    for j in range(8):
                        sums[j] *= scale
                best = lp
            sums[step] += math.exp(lp - best)
            if lp > step_best[step]:
                step_best[step] = lp
                acc[_STEP_ROW + step] = r
                acc[_STEP_COL + step] = c
    acc[_BEST] = best
    acc[_TAKEN] = taken
    if p[_PRUNE] == 0.0:
        return np.inf
    share = NEGLIGIBLE
    if p[_CERTIFY] != 0.0:
        # The mode's choice cannot change once the places left could not lift any other
        # step's weighted sum to within TIE of the chosen one's, even all together (a
        # weight is at most 1).
        k, top_w, rest = _top_two(sums, p[_WEIGHTS : _WEIGHTS + 8])
        top_w *= 1.0 - TIE
        gap = top_w - rest
        if gap > 0.0:
            share = max(share, math.log(gap))
        if p[_CERTIFY] == 2.0 and gap > 0.0:
            # And no place left could outpull the chosen step's strongest (a place
            # pulls at most f(1) g(L)): that place is the whole map's too.
            alone = _pull_limit(fcode, gcode, a, b, best, cells, step_best[k] - best)
            limit = _pull_limit(fcode, gcode, a, b, best, (p[_COUNT] - taken) * cells, share)
            return max(limit, alone)
    return _pull_limit(fcode, gcode, a, b, best, (p[_COUNT] - taken) * cells, share)


@dataclass(frozen=True)
class Force:
    """A force law f x g with its constants (the thesis's adopted f3 g4, a 40, b 65 dm)."""

    f: str = "f3"
    g: str = "g4"
    a: float = 40.0
    b: float = 65.0

    def __post_init__(self) -> None:
        if self.f not in FORCE_F or self.g not in FORCE_G:
            raise ConfigError(f"unknown force '{self.f}{self.g}'; valid: f1..f5 with g1..g5")
        if not (math.isfinite(self.a) and self.a > 0 and math.isfinite(self.b) and self.b > 0):
            raise ConfigError(f"force constants must be > 0, got a={self.a}, b={self.b}")

    @property
    def name(self) -> str:
        return f"{self.f}{self.g}"

    def pull_limit(self, best: float, count: int) -> float:
        """The path length (metres) beyond which ``count`` places together pull less
        than e^-41.5 (about 1e-18) of the strongest pull found, ``best`` (log): the
        most a place can pull is f(1) g(L), so places farther than this cannot change
        a direction. ``inf`` when nothing pulls yet."""
        return float(_pull_limit(self.codes[0], self.codes[1], self.a, self.b, best, count))

    @property
    def codes(self) -> tuple[int, int]:
        """The numbers of f and g (1..5)."""
        return int(self.f[1]), int(self.g[1])

    def log_pull(self, tb_n: F64, length_m: F64) -> F64:
        """log F for normalised fog and path lengths in metres; -inf where there is no
        pull (TB_n = 0 under f1/f2, or the robot's own cell)."""
        tb_n = np.ascontiguousarray(tb_n, dtype=np.float64)
        length_m = np.ascontiguousarray(length_m, dtype=np.float64)
        return _log_pull_array(*self.codes, self.a, self.b, tb_n, length_m)


def parse_force(text: str, a: float = 40.0, b: float = 65.0) -> Force:
    """``f3g4`` -> Force("f3", "g4", a, b)."""
    m = re.fullmatch(r"\s*(f[1-5])\s*(g[1-5])\s*", text)
    if m is None:
        raise ConfigError(f"unknown force {text!r}; expected f1..f5 followed by g1..g5, e.g. f3g4")
    return Force(m.group(1), m.group(2), a, b)


def choose_direction(
    log_pull: F64,
    ux: F64,
    uy: F64,
    method: str = "mode",
    sectors: int = 8,
    weights: F64 | None = None,
    steps: npt.NDArray[np.integer[Any]] | None = None,
) -> tuple[float, float] | None:
    """The direction a robot goes: unit (x, y), or None when nothing pulls.

    ``vector``: the sum of all forces. ``mode``: forces are summed per direction sector
    (``sectors`` equal sectors, the first centred on +x) and the robot goes along the
    strongest sector, in the direction of the forces' sum within it (with the wave's
    8 first steps and 8 sectors, exactly that step). ``weights`` (mode only) scale each
    sector's sum (direction weakening). ``steps``: the wave's first-step indices
    (:data:`~sonarmap.patrol.paths.STEPS`) behind ``ux``, ``uy`` (which must then be
    the steps' unit vectors): the pulls are summed per step at once
    (:func:`step_direction`).
    """
    if method not in ("mode", "vector"):
        raise ConfigError(f"unknown direction method {method!r}; valid: mode, vector")
    ok = np.isfinite(log_pull)
    if not ok.any():
        return None
    lp = log_pull[ok]
    w = np.exp(lp - lp.max())
    if steps is not None and (sectors == 8 or method == "vector"):
        sums = np.bincount(steps[ok], weights=w, minlength=8).astype(np.float64)
        return step_direction(sums, method, weights)
    x, y = ux[ok], uy[ok]
    if method == "vector":
        sx, sy = float(np.dot(w, x)), float(np.dot(w, y))
    else:
        angle = np.arctan2(y, x)
        width = 2 * math.pi / sectors
        sector = np.floor((angle + width / 2) / width).astype(np.int64) % sectors
        sums = np.bincount(sector, weights=w, minlength=sectors).astype(np.float64)
        strength = _weaken(sums, weights)
        pick = sector == _strongest(strength)
        sx, sy = float(np.dot(w[pick], x[pick])), float(np.dot(w[pick], y[pick]))
    return _unit(sx, sy)


def _weaken(strength: F64, weights: F64 | None) -> F64:
    out = np.asarray(strength, dtype=np.float64)
    return out if weights is None else out * np.asarray(weights, dtype=np.float64)


def _strongest(strength: F64) -> int:
    # Sectors within a relative TIE of the strongest are tied, and the first wins: on a
    # symmetric map with an even fog, two sectors pull exactly alike and only rounding
    # would otherwise choose (and choose differently as the sum's order changes).
    return int(np.flatnonzero(strength >= strength.max() * (1.0 - TIE))[0])


def _unit(sx: float, sy: float) -> tuple[float, float] | None:
    norm = math.hypot(sx, sy)
    if norm < 1e-12:
        return None
    return sx / norm, sy / norm


def step_direction(
    strength: F64, method: str = "mode", weights: F64 | None = None
) -> tuple[float, float] | None:
    """The direction from the pulls summed per wave step (``strength``, 8 values in the
    order of :data:`~sonarmap.patrol.paths.STEPS`): ``mode`` goes exactly along the
    strongest step (after ``weights``), ``vector`` along the sum of all; None when
    nothing pulls."""
    if not strength.max() > 0:
        return None
    if method == "mode":
        k = _strongest(_weaken(strength, weights))
        return float(STEP_UNITS[k, 0]), float(STEP_UNITS[k, 1])
    return _unit(float(strength @ STEP_UNITS[:, 0]), float(strength @ STEP_UNITS[:, 1]))


def sector_pulls(
    waver: Wave,
    passable: npt.NDArray[np.bool_],
    start: tuple[int, int],
    resolution: float,
    watched: npt.NDArray[np.bool_],
    force: Force,
    top: float,
    *,
    tb: F64 | None = None,
    last_seen: F64 | None = None,
    now: float = 0.0,
    closed: npt.NDArray[np.intp] | None = None,
    prune: bool = True,
    n_watched: int | None = None,
    certify: bool = False,
    weights: F64 | None = None,
    goal: bool = False,
    places: npt.NDArray[np.int64] | None = None,
    shadows: Shadows | None = None,
    block: int = 1,
    fog_watched: npt.NDArray[np.bool_] | None = None,
) -> F64:
    """The pulls of the ``watched`` places on a robot at ``start``, summed per first
    step of their waves' paths, in one pass with the wave.

    The places' TB is ``tb`` or ``now - last_seen``, normalised by ``top`` (the robot's
    MTB). With ``prune``, the wave stops at :meth:`Force.pull_limit` of the strongest
    pull found so far and the places not yet taken: the sums are then those of the
    whole map to float64 precision; with ``certify`` too, it stops as soon as the places
    left could not change the ``mode`` choice of :func:`step_direction` (with
    ``weights``): the choice is then that of the whole map, the sums not quite; with
    ``goal`` as well, only once the strongest place whose first step is the chosen one
    is also the whole map's (the place the path motion goes for). ``closed`` edits the
    map as in :class:`Wave`; ``waver`` is left holding the wave. ``n_watched``:
    ``watched.sum()``, when known. ``places``, an (8, 2) array, is filled with the row
    and column of each step's strongest place among those the wave took (-1 where the
    step has none). ``shadows`` (:func:`~sonarmap.patrol.paths.shadows` of ``passable``
    and ``watched``): the watched cells no wave reaches pull too, as if at their
    anchors (which ``places`` then names); without them they do not pull at all.

    With ``block`` > 1 the wave runs on a coarser grid than the fog: ``passable``,
    ``watched``, ``start``, ``shadows`` and ``places`` are on the coarse grid, whose
    cell (r, c) is the block of ``block`` x ``block`` fog cells from (r x block,
    c x block); ``tb`` or ``last_seen`` and ``fog_watched`` (the fog's watched cells)
    are on the fog's grid. A coarse place pulls as its block's watched fog cells
    together, the sum of their f(TB_n), at the coarse wave's length.

    Returns
    -------
    ndarray (8,)
        Summed pull per step, relative to the strongest single pull (all 0 when nothing
        pulls), for :func:`step_direction`.
    """
    if (tb is None) == (last_seen is None):
        raise ValueError("give either tb or last_seen")
    alpha, beta, src = (0.0, 1.0, tb) if tb is not None else (now, -1.0, last_seen)
    assert src is not None
    count = int(watched.sum()) if n_watched is None else n_watched
    w = np.ones(8) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (8,) or not (np.all(w >= 0) and np.all(w <= 1)):
        raise ValueError("weights: 8 values in [0, 1]")
    shaded = shadows is not None and len(shadows) > 0
    head = [alpha, beta, *force.codes, force.a, force.b, top, count, prune]
    if block < 1:
        raise ValueError(f"block: a side of >= 1 fog cells, got {block}")
    fog_mask = watched if fog_watched is None else fog_watched
    if block == 1 and fog_mask.shape != watched.shape:
        raise ValueError(f"fog_watched of {fog_mask.shape} for places of {watched.shape}")
    params = np.array([*head, certify * (1 + goal), *w, shaded, block], dtype=np.float64)
    if shadows is not None and len(shadows.ptr) != watched.size + 1:
        raise ValueError(f"shadows of {len(shadows.ptr) - 1} cells for a map of {watched.size}")
    none = np.zeros(1, dtype=np.int64)
    shade = (
        (shadows.ptr, shadows.rows, shadows.cols, shadows.extra)
        if shadows is not None and shaded
        else (none, none, none, np.zeros(1))
    )
    if places is not None and places.shape != (8, 2):
        raise ValueError(f"places: an (8, 2) array, got {places.shape}")
    acc = np.zeros(_STEP_COL + 8)
    acc[_BEST] = -np.inf
    acc[_STEP_BEST : _STEP_BEST + 8] = -np.inf
    acc[_STEP_ROW:] = -1.0
    ctx = (np.ascontiguousarray(src, dtype=np.float64), watched, fog_mask, params, acc, *shade)
    waver(passable, start, resolution, watched, None, closed, visit=(_pull_visit, ctx))
    if places is not None:
        places[:, 0] = acc[_STEP_ROW : _STEP_ROW + 8]
        places[:, 1] = acc[_STEP_COL : _STEP_COL + 8]
    return acc[_SUMS : _SUMS + 8].copy()
