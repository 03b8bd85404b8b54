"""A car-like robot's planner: pure pursuit along the wave's path, and hybrid-A*
manoeuvres out of dead ends.

The thesis's car turns towards the chosen direction (the first step of the wave's path)
as fast as its turning radius allows and, when forward motion is impossible, reverses
while steering towards that direction. On streets only a little wider than a car's
turning circle that takes it into dead ends again and again. A car-like planner does
two things instead:

- it follows the wave's path to the place it goes for with *pure pursuit*: the arc
  through a point ``lookahead`` metres along the path (:func:`carrot`), so it turns
  where the path turns and not where the path's first step points;
- when no forward arc is clear, or the path lies behind it, it plans a *manoeuvre*
  (:func:`plan_manoeuvre`): a hybrid-A* search over (x, y, heading) with forward and
  reverse arcs of the car's turning radius, to a pose on the path a few metres ahead,
  every point of it checked against the map (the cells the car's disc may have its
  centre on) and against the other robots. A manoeuvre that reverses is the dead-end
  escape the DVT counts.

Nothing here is random: the search breaks ties by insertion order.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numba as nb
import numpy as np
import numpy.typing as npt

from ..grid import Grid
from .fog import Fog
from .paths import STEP_UNITS

__all__ = [
    "DeadEnds",
    "FreshAhead",
    "Manoeuvre",
    "behind_cells",
    "carrot",
    "clear_goals",
    "drop_fresh_behind",
    "fresh_behind",
    "leads_on",
    "plan_manoeuvre",
    "route_goals",
    "turn_weights",
]

F64 = npt.NDArray[np.float64]

#: Heading bins of the search: a turning arc of one primitive turns by one bin.
HEADINGS = 16
#: Points checked per metre of a primitive (the map's cells are 0.5 m): a corner of a
#: cell the arc passes closer than 1/64 m may go unseen (at 16 a metre, a manoeuvre on
#: training street site 0 cut 1.5 cm through one).
SAMPLES_PER_M = 64
#: Side of the search's position bins, metres.
BIN = 0.5
#: Extra cost of a metre driven in reverse, and of a change of gear, in metres.
REVERSE_COST = 1.5
GEAR_COST = 2.0


@dataclass
class Manoeuvre:
    """A planned manoeuvre: arcs (signed length in metres, negative in reverse, and
    curvature in 1/m) driven in order; ``reverses`` when any of them is in reverse."""

    arcs: list[tuple[float, float]]

    @property
    def reverses(self) -> bool:
        return any(length < 0 for length, _ in self.arcs)


def carrot(route: F64, x: float, y: float, lookahead: float) -> tuple[float, float]:
    """The point ``lookahead`` metres along ``route`` (K, 2 world points, starting near
    the car) from its point nearest (x, y); the route's end when it is shorter."""
    d = np.hypot(route[:, 0] - x, route[:, 1] - y)
    k = int(np.argmin(d))
    left = lookahead
    px, py = x, y
    for qx, qy in route[k:].tolist():
        step = math.hypot(qx - px, qy - py)
        if step >= left and step > 0:
            f = left / step
            return px + (qx - px) * f, py + (qy - py) * f
        left -= step
        px, py = qx, qy
    return float(route[-1, 0]), float(route[-1, 1])


def behind_cells(
    x: float, y: float, heading: float, grid: Grid, radius: float = 4.0, gap: float = 0.5
) -> npt.NDArray[np.intp]:
    """(row, column) pairs, shape (K, 2), of the cells inside the grid whose centres lie
    within ``radius`` metres of a car at (x, y) and more than ``gap`` metres behind it
    along its ``heading``: closed on the car's wave, its paths leave forwards, and a
    place behind it is reached around the block rather than by turning on the spot
    (a turn a car can only make by reversing on streets narrower than its turning
    circle). The car's own cell is never among them. Rows in row-major order of the
    square of cells round the car's."""
    ox, oy = grid.origin
    return _behind_cells(
        float(x),
        float(y),
        math.cos(heading),
        math.sin(heading),
        grid.rows,
        grid.cols,
        float(ox),
        float(oy),
        grid.resolution,
        radius,
        gap,
    )


@nb.njit(cache=True)
def _behind_cells(
    x: float,
    y: float,
    hx: float,
    hy: float,
    rows: int,
    cols: int,
    ox: float,
    oy: float,
    res: float,
    radius: float,
    gap: float,
) -> npt.NDArray[np.intp]:
    # behind_cells' test cell by cell, with the same floating-point operations as its
    # numpy form (the car's cell as Grid.world_to_cell, cell centres as
    # Grid.cell_centres, libm's hypot as np.hypot), so the same cells.
    r0 = rows - 1 - math.floor((y - oy) / res)
    c0 = math.floor((x - ox) / res)
    k = math.ceil(radius / res)
    out = np.empty(((2 * k + 1) ** 2, 2), dtype=np.intp)
    n = 0
    for dr in range(-k, k + 1):
        r = r0 + dr
        if r < 0 or r >= rows:
            continue
        dy = oy + (float(rows - 1 - r) + 0.5) * res - y
        for dc in range(-k, k + 1):
            c = c0 + dc
            if c < 0 or c >= cols or (dr == 0 and dc == 0):
                continue
            dx = ox + (float(c) + 0.5) * res - x
            if dx * hx + dy * hy < -gap and math.hypot(dx, dy) <= radius:
                out[n, 0] = r
                out[n, 1] = c
                n += 1
    return out[:n].copy()


def turn_weights(heading: float, behind: float, penalty: float) -> F64:
    """Weights (8,) of the wave's first steps (:data:`~sonarmap.patrol.paths.STEPS`)
    for a car heading ``heading`` radians: ``exp(-penalty)`` for the steps more than
    ``behind`` radians off the heading, 1 for the others.

    The potential field's pulls are logarithmic in TB (e^(a TB_n), a = 40), so a weight
    must be that small to count: ``penalty`` is the lead, in units of log pull, a
    place reached by turning round needs over one reached forwards (10 is a lead of a
    quarter of the MTB in TB_n). On streets narrower than its turning circle a car can
    only turn round by reversing, so a place behind it is chosen only when it pulls that
    much harder; a car whose every path leaves backwards (at the end of a dead end) is
    unaffected.
    """
    angle = np.arctan2(STEP_UNITS[:, 1], STEP_UNITS[:, 0])
    off = np.abs((angle - heading + math.pi) % (2 * math.pi) - math.pi)
    return np.where(off > behind, math.exp(-penalty), 1.0).astype(np.float64)


def fresh_behind(
    last: F64,
    now: float,
    x: float,
    y: float,
    heading: float,
    grid: Grid,
    behind: float,
    turn_time: float,
    never_seen: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.bool_]:
    """The cells (a mask of ``last``'s shape) seen less than ``turn_time`` seconds
    before ``now`` whose centres lie more than ``behind`` radians off the ``heading``
    of a car at (x, y), metres; the cells of ``never_seen`` (a mask of ``last``'s
    shape, e.g. :meth:`~sonarmap.patrol.fog.Fog.never_seen`; None: none) are never
    among them, whatever ``last`` says of them.

    A car goes for such a place only by turning round, which on a street narrower
    than its turning circle is a reversing manoeuvre taking some seconds: going there
    sees the place about that much later than it was last seen, so it gains nothing
    (:attr:`~sonarmap.patrol.simulation.PatrolConfig.turn_time`). ``last`` holds the
    time each cell was last seen (seconds; ``inf`` for cells never watched).
    """
    age = now - last
    out = np.zeros(last.shape, dtype=np.bool_)
    fresh = (age < turn_time) & np.isfinite(last)
    if never_seen is not None:
        fresh &= ~never_seen
    rr, cc = np.nonzero(fresh)
    if not len(rr):
        return out
    keep = _off_heading(rr, cc, x, y, heading, grid, behind)
    out[rr[keep], cc[keep]] = True
    return out


def _off_heading(
    rr: npt.NDArray[np.intp],
    cc: npt.NDArray[np.intp],
    x: float,
    y: float,
    heading: float,
    grid: Grid,
    behind: float,
) -> npt.NDArray[np.bool_]:
    """Whether the centres of cells (rr, cc) lie more than ``behind`` radians off the
    ``heading`` of a car at (x, y), metres (the car's own point never)."""
    px, py = grid.cell_centres(rr, cc)
    dx, dy = np.asarray(px) - x, np.asarray(py) - y
    off = np.abs((np.arctan2(dy, dx) - heading + math.pi) % (2 * math.pi) - math.pi)
    keep: npt.NDArray[np.bool_] = (off > behind) & (np.hypot(dx, dy) > 1e-9)
    return keep


#: Cells whose side of :func:`fresh_behind`'s angle the kernel of
#: :func:`drop_fresh_behind` leaves to numpy (as many as it may note at once).
UNSURE_CELLS = 4096


#: How far, in cosine of the angle off the heading, every cell of a block must lie
#: from ``behind`` for :func:`drop_fresh_behind` to pass the block over unread: a
#: thousand times the band whose cells it leaves to numpy's ``arctan2``.
OFF_CONE_MARGIN = 1e-6


def _cone_sides(heading: float, behind: float) -> npt.NDArray[np.float64]:
    """The two sides of the cone of directions more than ``behind`` radians (between a
    right angle and pi) off ``heading``, for :func:`_off_cone`: rows 0 and 1 the inward
    unit normals (x, y) of its two edges, and [2, 0] the factor min(sin(behind), 0.7)
    (see :func:`_off_cone`)."""
    back = heading + math.pi
    edge = math.pi - behind
    out = np.zeros((3, 2), dtype=np.float64)
    # Edge 1 at back + edge (the cone lies clockwise of it), edge 2 at back - edge.
    out[0] = math.sin(back + edge), -math.cos(back + edge)
    out[1] = -math.sin(back - edge), math.cos(back - edge)
    out[2, 0] = min(math.sin(behind), 0.7)
    return out


@nb.njit(cache=True)
def _off_cone(
    sides: npt.NDArray[np.float64],
    ox: float,
    oy: float,
    res: float,
    rows: int,
    x: float,
    y: float,
    r_lo: int,
    r_hi: int,
    c_lo: int,
    c_hi: int,
) -> bool:
    # Whether every cell centre of the block (rows r_lo..r_hi, columns c_lo..c_hi) lies
    # outside one edge's half-plane of the cone behind (``sides``, _cone_sides) far
    # enough that its angle test is not near ``behind``: a cell at distance s outside
    # an edge's line and at most D from the car is at least asin(s / D) (or a right
    # angle) short of ``behind`` off the heading, so its cosine test exceeds
    # cos(behind) by at least 2 min(sin(behind), 0.7) (s / D) / pi. The half-plane
    # being convex, the block's corner cells bound its other cells.
    far = 0.0
    short = np.full(2, np.inf)
    for r in (r_lo, r_hi):
        for c in (c_lo, c_hi):
            dx = ox + (c + 0.5) * res - x
            dy = oy + (rows - 1 - r + 0.5) * res - y
            far = max(far, math.sqrt(dx * dx + dy * dy))
            for e in range(2):
                short[e] = min(short[e], -(dx * sides[e, 0] + dy * sides[e, 1]))
    for e in range(2):
        if short[e] > 0.0 and 2.0 * sides[2, 0] * (short[e] / far) / math.pi > OFF_CONE_MARGIN:
            return True
    return False


@nb.njit(cache=True)
def _drop_fresh_behind(
    mask: npt.NDArray[np.bool_],
    last: npt.NDArray[np.float64],
    latest: npt.NDArray[np.float64],
    b: int,
    now: float,
    turn_time: float,
    never: float,
    x: float,
    y: float,
    hx: float,
    hy: float,
    cos_behind: float,
    sides: npt.NDArray[np.float64],
    ox: float,
    oy: float,
    res: float,
    unsure: npt.NDArray[np.int64],
    dropped: npt.NDArray[np.int64],
) -> tuple[int, int]:
    # fresh_behind's cells set False in ``mask``, looking only in the blocks seen less
    # than ``turn_time`` before ``now``; the first of them (as many as ``dropped``
    # holds) listed there by flat index. The angle off the heading is compared by its
    # cosine, (d . h) / |d| against cos(behind); a cell within 1e-9 of that (or at the
    # car) is noted in ``unsure`` for numpy's arctan2 to decide, so that every answer
    # is fresh_behind's. Returns the cells set False and the unsure ones.
    rows, cols = last.shape
    n = 0
    k = 0
    # With ``behind`` past a right angle, a cell ahead of the car's side line (d . h
    # > 0) is never behind: (d . h) / |d| - cos(behind) >= -cos(behind) > 1e-9. Whole
    # blocks ahead of it are passed over (the extremes of d . h over a block lie at
    # its corner cells; a hair of slack for their rounding), and such cells.
    ahead_is_out = cos_behind < -1e-6
    for br in range(latest.shape[0]):
        for bc in range(latest.shape[1]):
            if not now - latest[br, bc] < turn_time:
                continue
            r_lo, r_hi = br * b, min((br + 1) * b, rows) - 1
            c_lo, c_hi = bc * b, min((bc + 1) * b, cols) - 1
            lowest = np.inf
            # Whether every corner cell lies behind by a margin: the points whose
            # (d . h) / |d| - cos(behind) is at most -1e-6 form a convex cone when
            # cos(behind) < 0, so every cell centre of the block (inside its corner
            # centres' rectangle) lies in it too, and at least -cos(behind) times the
            # nearest corner's distance from the car (|d| >= -d . h): behind, clear of
            # the unsure cells, with no angle to work out.
            inside = cos_behind < -1e-6
            for r in (r_lo, r_hi):
                for c in (c_lo, c_hi):
                    dx = ox + (c + 0.5) * res - x
                    dy = oy + (rows - 1 - r + 0.5) * res - y
                    dot = dx * hx + dy * hy
                    lowest = min(lowest, dot)
                    d = math.sqrt(dx * dx + dy * dy)
                    if not (d * -cos_behind > 2e-6 and dot / d - cos_behind < -1e-6):
                        inside = False
            if ahead_is_out and lowest > 1e-6:
                continue
            if ahead_is_out and _off_cone(sides, ox, oy, res, rows, x, y, r_lo, r_hi, c_lo, c_hi):
                continue
            if inside:
                for r in range(r_lo, r_hi + 1):
                    for c in range(c_lo, c_hi + 1):
                        if mask[r, c]:
                            v = last[r, c]
                            if now - v < turn_time and np.isfinite(v) and v != never:
                                mask[r, c] = False
                                if n < dropped.shape[0]:
                                    dropped[n] = r * cols + c
                                n += 1
                continue
            for r in range(r_lo, r_hi + 1):
                py = oy + (rows - 1 - r + 0.5) * res
                for c in range(c_lo, c_hi + 1):
                    if not mask[r, c]:
                        continue
                    v = last[r, c]
                    if not (now - v < turn_time) or not np.isfinite(v) or v == never:
                        continue
                    dx = ox + (c + 0.5) * res - x
                    dy = py - y
                    if ahead_is_out and dx * hx + dy * hy > 1e-6:
                        continue
                    d = math.sqrt(dx * dx + dy * dy)
                    diff = 0.0 if d < 1e-6 else (dx * hx + dy * hy) / d - cos_behind
                    if abs(diff) < 1e-9:
                        if k < unsure.shape[0]:
                            unsure[k] = r * cols + c
                        k += 1
                    elif diff < 0.0:
                        mask[r, c] = False
                        if n < dropped.shape[0]:
                            dropped[n] = r * cols + c
                        n += 1
    return n, k


def drop_fresh_behind(
    mask: npt.NDArray[np.bool_],
    fog: Fog,
    x: float,
    y: float,
    heading: float,
    grid: Grid,
    behind: float,
    turn_time: float,
    dropped: npt.NDArray[np.int64] | None = None,
) -> int:
    """Set to False, in ``mask`` (written in place), the cells of
    :func:`fresh_behind` for ``fog``'s last-seen times at its time, never-seen cells
    excluded; returns how many of ``mask``'s True cells that were.

    The same cells as ``mask & fresh_behind(fog.last, fog.t, x, y, heading, grid,
    behind, turn_time, fog.never_seen())``, found in the fog's blocks seen less than
    ``turn_time`` seconds ago (:meth:`~sonarmap.patrol.fog.Fog.latest_blocks`), without
    a pass over the whole map. ``dropped`` (optional, int64): when the count returned
    is at most its length, its first that many entries are the flat (row-major)
    indices of the cells set False, in no particular order; otherwise its contents are
    undefined."""
    unsure = np.empty(UNSURE_CELLS, dtype=np.int64)
    out = dropped if dropped is not None else np.empty(0, dtype=np.int64)
    ox, oy = grid.origin
    n, k = _drop_fresh_behind(
        mask,
        fog.last,
        np.ascontiguousarray(fog.latest_blocks()),
        fog.BLOCK,
        fog.t,
        turn_time,
        -fog.start,
        x,
        y,
        math.cos(heading),
        math.sin(heading),
        math.cos(behind),
        _cone_sides(heading, behind),
        float(ox),
        float(oy),
        grid.resolution,
        unsure,
        out,
    )
    if k > len(unsure):
        # Too many to note: fresh_behind decides every cell.
        fresh = mask & fresh_behind(
            fog.last, fog.t, x, y, heading, grid, behind, turn_time, fog.never_seen()
        )
        mask &= ~fresh
        more = np.flatnonzero(fresh)
    elif k:
        rr, cc = np.divmod(unsure[:k], mask.shape[1])
        keep = _off_heading(rr, cc, x, y, heading, grid, behind)
        mask[rr[keep], cc[keep]] = False
        more = unsure[:k][keep]
    else:
        return int(n)
    if n + len(more) <= len(out):
        out[n : n + len(more)] = more
    return int(n + len(more))


@nb.njit(cache=True)
def _set_back(flat: npt.NDArray[np.bool_], cells: npt.NDArray[np.int64], n: int) -> None:
    # flat[cells[:n]] = True, without numpy's fancy-index set-up.
    for k in range(n):
        flat[cells[k]] = True


class FreshAhead:
    """A map-sized mask kept for a run: a source mask less the fresh cells behind one
    car (:func:`drop_fresh_behind`), made for one car after another.

    While the source stays the same array and the caller's ``version`` of it the same,
    the next car's mask is made by setting back the cells the last car dropped; a new
    source array or version, or a last car that dropped more cells than ``record``
    notes, has the source copied whole. The masks are the same either way.

    Parameters
    ----------
    shape : tuple of int
        The grid's (rows, columns).
    record : int
        How many dropped cells are noted for setting back (default 2**20); when a car
        drops more, the next mask is copied whole.
    """

    def __init__(self, shape: tuple[int, int], record: int = 1 << 20) -> None:
        self._mask = np.zeros(shape, dtype=np.bool_)
        self._dropped = np.empty(record, dtype=np.int64)
        self._n = -1  # cells to set back; -1: the mask is to be copied whole
        self._source: npt.NDArray[np.bool_] | None = None
        self._version: object = None

    def make(
        self,
        source: npt.NDArray[np.bool_],
        version: object,
        fog: Fog,
        x: float,
        y: float,
        heading: float,
        grid: Grid,
        behind: float,
        turn_time: float,
    ) -> tuple[npt.NDArray[np.bool_], int]:
        """``source`` less :func:`drop_fresh_behind`'s cells for a car at (x, y),
        ``heading``, and how many of ``source``'s True cells those were.

        ``version``: anything the caller changes whenever ``source``'s contents may
        have changed since the last call (e.g. the step). The mask returned is this
        object's own, valid until the next call; it must not be written to."""
        if source is self._source and version == self._version and self._n >= 0:
            _set_back(self._mask.reshape(-1), self._dropped, self._n)
        else:
            np.copyto(self._mask, source)
            self._source, self._version = source, version
        n = drop_fresh_behind(
            self._mask, fog, x, y, heading, grid, behind, turn_time, self._dropped
        )
        self._n = n if n <= len(self._dropped) else -1
        return self._mask, n


@nb.njit(cache=True)
def _block_pieces(
    passable: npt.NDArray[np.bool_], shift: int
) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    # The pieces of every b x b block (b = 2**shift: a cell's block by shifts, as in
    # _reaches): the 8-connected components of its passable cells joined inside the
    # block. Returns each cell's piece (-1 off ``passable``), and each piece's block
    # (flat, row-major over the blocks) and cell count.
    rows, cols = passable.shape
    b = 1 << shift
    nbc = (cols + b - 1) >> shift
    piece = np.full((rows, cols), -1, dtype=np.int32)
    block = np.empty(rows * cols, dtype=np.int64)
    size = np.empty(rows * cols, dtype=np.int64)
    stack = np.empty(b * b, dtype=np.int64)
    n = 0
    for r in range(rows):
        for c in range(cols):
            if not passable[r, c] or piece[r, c] >= 0:
                continue
            br, bc = r >> shift, c >> shift
            piece[r, c] = n
            stack[0] = r * cols + c
            top = 1
            count = 0
            while top > 0:
                top -= 1
                rr = stack[top] // cols
                cc = stack[top] - rr * cols
                count += 1
                for dr in range(-1, 2):
                    r2 = rr + dr
                    if r2 < 0 or r2 >= rows or r2 >> shift != br:
                        continue
                    for dc in range(-1, 2):
                        c2 = cc + dc
                        if c2 < 0 or c2 >= cols or c2 >> shift != bc:
                            continue
                        if passable[r2, c2] and piece[r2, c2] < 0:
                            piece[r2, c2] = n
                            stack[top] = r2 * cols + c2
                            top += 1
            block[n] = br * nbc + bc
            size[n] = count
            n += 1
    return piece, block[:n], size[:n]


@nb.njit(cache=True)
def _piece_links(
    piece: npt.NDArray[np.int32], n: int, shift: int
) -> tuple[
    npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]
]:
    # The pieces of neighbouring blocks that touch (8-connected): for each piece u,
    # links[link_ptr[u]:link_ptr[u + 1]] are the pieces it touches, and for each of
    # those links, cells[cell_ptr[k]:cell_ptr[k + 1]] the cells (flat) of the other
    # piece next to a cell of u. Blocks are 2**shift cells a side.
    rows, cols = piece.shape
    # Every (u, cell of another block next to u) pair, once per pair.
    m = 0
    for r in range(rows):
        for c in range(cols):
            if piece[r, c] < 0:
                continue
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    r2, c2 = r + dr, c + dc
                    if r2 < 0 or r2 >= rows or c2 < 0 or c2 >= cols or piece[r2, c2] < 0:
                        continue
                    if r2 >> shift != r >> shift or c2 >> shift != c >> shift:
                        m += 1
    pu = np.empty(m, dtype=np.int64)
    pv = np.empty(m, dtype=np.int64)
    pc = np.empty(m, dtype=np.int64)
    k = 0
    for r in range(rows):
        for c in range(cols):
            if piece[r, c] < 0:
                continue
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    r2, c2 = r + dr, c + dc
                    if r2 < 0 or r2 >= rows or c2 < 0 or c2 >= cols or piece[r2, c2] < 0:
                        continue
                    if r2 >> shift != r >> shift or c2 >> shift != c >> shift:
                        pu[k] = piece[r, c]
                        pv[k] = piece[r2, c2]
                        pc[k] = r2 * cols + c2
                        k += 1
    order = np.argsort(pu * n + pv, kind="mergesort")
    pu, pv, pc = pu[order], pv[order], pc[order]
    # Cells of one (u, v) link may repeat (next to two cells of u): keep each once.
    link_ptr = np.zeros(n + 1, dtype=np.int64)
    links = np.empty(m, dtype=np.int64)
    cell_ptr = np.empty(m + 1, dtype=np.int64)
    cells = np.empty(m, dtype=np.int64)
    n_links = 0
    n_cells = 0
    i = 0
    while i < m:
        j = i
        while j < m and pu[j] == pu[i] and pv[j] == pv[i]:
            j += 1
        links[n_links] = pv[i]
        link_ptr[pu[i] + 1] += 1
        cell_ptr[n_links] = n_cells
        uniq = np.unique(pc[i:j])
        cells[n_cells : n_cells + len(uniq)] = uniq
        n_cells += len(uniq)
        n_links += 1
        i = j
    cell_ptr[n_links] = n_cells
    for u in range(n):
        link_ptr[u + 1] += link_ptr[u]
    return link_ptr, links[:n_links], cell_ptr[: n_links + 1], cells[:n_cells]


@nb.njit(cache=True)
def _reaches(
    passable: npt.NDArray[np.bool_],
    piece: npt.NDArray[np.int32],
    piece_block: npt.NDArray[np.int64],
    piece_size: npt.NDArray[np.int64],
    link_ptr: npt.NDArray[np.int64],
    links: npt.NDArray[np.int64],
    cell_ptr: npt.NDArray[np.int64],
    cells: npt.NDArray[np.int64],
    shift: int,
    mark: npt.NDArray[np.int8],
    seen: npt.NDArray[np.bool_],
    touched: npt.NDArray[np.bool_],
    queue: npt.NDArray[np.int64],
    closed: npt.NDArray[np.int64],
    r0: int,
    c0: int,
    need: float,
) -> int:
    # 1 when the flood reaches ``need`` cells, 0 when not; -1 - k with nothing
    # written when closed cell k lies off the map (as numpy indexes: -rows..rows - 1).
    # A flood from (r0, c0) over the open cells (passable, not closed; the start always
    # open) that stops at ``need`` cells. Cell by cell in the blocks the closed cells
    # (and the start) touch, a block's piece at a time elsewhere: a piece of an
    # untouched block is open and joined through, so reaching one of its cells
    # reaches all. ``mark`` (1 closed, 2 reached), ``seen`` (pieces) and ``touched``
    # (blocks) are all False on entry and left so. ``queue`` holds cells (flat) as
    # k >= 0 and pieces as -1 - u. Blocks are 2**shift cells a side: the block of a
    # row or column (never negative here) is a shift, not a division, on every
    # neighbour of every cell flooded; a cell's row from its flat index is a float
    # product, as in the wave (exact: (q + 0.5) / cols is at least 0.5 / cols away
    # from a whole number, far more than the product's rounding).
    rows, cols = passable.shape
    b = 1 << shift
    nbc = (cols + b - 1) >> shift
    inv_cols = 1.0 / cols
    n_closed = closed.shape[0]
    for k in range(n_closed):
        r, c = closed[k, 0], closed[k, 1]
        if r < -rows or r >= rows or c < -cols or c >= cols:
            return -1 - k
    for k in range(n_closed):
        r, c = closed[k, 0], closed[k, 1]
        if r < 0:  # as numpy indexes
            r += rows
        if c < 0:
            c += cols
        touched[(r >> shift) * nbc + (c >> shift)] = True
        if r != r0 or c != c0:
            mark[r, c] = 1
    touched[(r0 >> shift) * nbc + (c0 >> shift)] = True
    mark[r0, c0] = 2
    # Cells queue from the front of ``queue``, pieces from its back (pieces[i] at
    # queue[last - i]), and pieces go first: the flood's count, and so its answer,
    # is the same in any order, and a way ahead that leads on reaches ``need``
    # through whole pieces mostly, leaving the touched blocks' cells unflooded.
    last = queue.shape[0] - 1
    queue[0] = r0 * cols + c0
    tail = 1
    head = 0
    tail_p = 0
    head_p = 0
    count = 1
    result = count >= need
    while not result and (head_p < tail_p or head < tail):
        if head_p < tail_p:
            q = queue[last - head_p]
            head_p += 1
        else:
            q = queue[head]
            head += 1
        if q >= 0:
            r = int((q + 0.5) * inv_cols)
            c = q - r * cols
            for dr in range(-1, 2):
                r2 = r + dr
                if r2 < 0 or r2 >= rows:
                    continue
                for dc in range(-1, 2):
                    c2 = c + dc
                    if c2 < 0 or c2 >= cols or not passable[r2, c2] or mark[r2, c2]:
                        continue
                    if touched[(r2 >> shift) * nbc + (c2 >> shift)]:
                        mark[r2, c2] = 2
                        queue[tail] = r2 * cols + c2
                        tail += 1
                        count += 1
                    else:
                        v = piece[r2, c2]
                        if seen[v]:
                            continue
                        seen[v] = True
                        queue[last - tail_p] = -1 - v
                        tail_p += 1
                        count += piece_size[v]
        else:
            u = -1 - q
            for k in range(link_ptr[u], link_ptr[u + 1]):
                v = links[k]
                if not touched[piece_block[v]]:
                    if not seen[v]:
                        seen[v] = True
                        queue[last - tail_p] = -1 - v
                        tail_p += 1
                        count += piece_size[v]
                    continue
                for j in range(cell_ptr[k], cell_ptr[k + 1]):
                    r2 = int((cells[j] + 0.5) * inv_cols)
                    c2 = cells[j] - r2 * cols
                    if not mark[r2, c2]:
                        mark[r2, c2] = 2
                        queue[tail] = cells[j]
                        tail += 1
                        count += 1
        result = count >= need
    for k in range(tail):
        q = queue[k]
        r = int((q + 0.5) * inv_cols)
        mark[r, q - r * cols] = 0
    for k in range(tail_p):
        seen[-1 - queue[last - k]] = False
    for k in range(n_closed):
        r, c = closed[k, 0], closed[k, 1]
        r = r + rows if r < 0 else r
        c = c + cols if c < 0 else c
        mark[r, c] = 0
        touched[(r >> shift) * nbc + (c >> shift)] = False
    touched[(r0 >> shift) * nbc + (c0 >> shift)] = False
    return 1 if result else 0


class DeadEnds:
    """The forward wave's dead-end test on one map, asked many times
    (:meth:`leads_on`).

    Built once per map: the map cut into :attr:`BLOCK` x :attr:`BLOCK` blocks, the
    pieces of each block (its passable cells joined inside it, 8-connected) and which
    pieces of neighbouring blocks touch, and scratch arrays that every call leaves as
    it found them (the object holds no state between calls).

    Parameters
    ----------
    passable : ndarray of bool, shape (rows, cols)
        Cells a car's centre may occupy. Kept without a copy when it is already a
        C-contiguous bool array (then it must not change while this object is used);
        any other array (another dtype, a strided view) is copied once, here, and
        later changes to it are not seen.
    """

    #: Side of the blocks, in cells (a power of two).
    BLOCK = 32

    def __init__(self, passable: npt.NDArray[np.bool_]) -> None:
        self.passable = np.ascontiguousarray(passable, dtype=np.bool_)
        b = self.BLOCK
        # The build and the flood find a cell's block by shifts: a power of two.
        self._shift = b.bit_length() - 1
        if b != 1 << self._shift:
            raise ValueError(f"DeadEnds.BLOCK must be a power of two, got {b}")
        self.piece, self.piece_block, self.piece_size = _block_pieces(self.passable, self._shift)
        n = len(self.piece_size)
        self.link_ptr, self.links, self.cell_ptr, self.cells = _piece_links(
            self.piece, n, self._shift
        )
        self.n_passable = int(self.piece_size.sum())
        rows, cols = passable.shape
        self.mark = np.zeros(passable.shape, dtype=np.int8)
        self.seen = np.zeros(max(1, n), dtype=np.bool_)
        self.touched = np.zeros(-(-rows // b) * -(-cols // b), dtype=np.bool_)
        # A flood holds at most every passable cell and piece, and the start.
        self.queue = np.empty(self.n_passable + n + 1, dtype=np.int64)

    def leads_on(
        self, closed: npt.NDArray[np.intp], start: tuple[int, int], share: float = 0.5
    ) -> bool:
        """Whether, with the ``closed`` cells (K, 2; row, column) shut, the passable
        cells still joined to ``start`` are at least ``share`` of all passable cells:
        False when the way ahead is a dead end (the car has to turn round) and the way
        out lay behind.

        Indices as numpy reads them: a negative row or column counts from the map's
        end; one outside ``-rows .. rows - 1`` (or ``-cols .. cols - 1``), in
        ``closed`` or ``start``, raises :class:`IndexError`.

        Cells join 8-connected, as the wave's steps do; ``start`` counts as open (and
        joined) whatever ``passable`` and ``closed`` say of it.

        A flood from ``start`` that stops as soon as it has ``share`` of the cells: cell
        by cell only in the blocks the closed cells or the start touch, elsewhere a
        block's piece at a time (nothing is closed there, so a piece reached is reached
        whole). A way ahead that leads on costs about half the map's pieces, not half
        its cells.

        Raises :class:`ValueError` when ``closed`` is not of shape (K, 2).
        """
        shut = _closed_cells(closed)
        if not len(shut):
            return True
        rows, cols = self.passable.shape
        r0, c0 = int(start[0]), int(start[1])
        if not (-rows <= r0 < rows and -cols <= c0 < cols):
            # A closed cell off the map is named before the start.
            bad = (shut[:, 0] < -rows) | (shut[:, 0] >= rows) | (shut[:, 1] < -cols)
            bad |= shut[:, 1] >= cols
            at = (r0, c0) if not bad.any() else tuple(shut[int(np.argmax(bad))].tolist())
            raise IndexError(f"cell {at} is outside the {rows} x {cols} map")
        # The kernel checks the closed cells (before writing its scratch at them): a
        # numpy pass over thousands of them each call cost more than the kernel's.
        got = int(
            _reaches(
                self.passable,
                self.piece,
                self.piece_block,
                self.piece_size,
                self.link_ptr,
                self.links,
                self.cell_ptr,
                self.cells,
                self._shift,
                self.mark,
                self.seen,
                self.touched,
                self.queue,
                shut,
                r0 + rows if r0 < 0 else r0,
                c0 + cols if c0 < 0 else c0,
                share * self.n_passable,
            )
        )
        if got < 0:
            at = tuple(shut[-1 - got].tolist())
            raise IndexError(f"cell {at} is outside the {rows} x {cols} map")
        return got == 1


def _closed_cells(closed: npt.NDArray[np.intp]) -> npt.NDArray[np.int64]:
    """``closed`` as a contiguous int64 (K, 2) array; ValueError for any other shape
    (the kernel reads two columns)."""
    shut = np.ascontiguousarray(closed, dtype=np.int64)
    if shut.ndim != 2 or shut.shape[1] != 2:
        raise ValueError(f"leads_on: closed must have shape (K, 2) (row, column), got {shut.shape}")
    return shut


def leads_on(
    passable: npt.NDArray[np.bool_],
    closed: npt.NDArray[np.intp],
    start: tuple[int, int],
    share: float = 0.5,
    n_passable: int | None = None,
) -> bool:
    """Whether, with the ``closed`` cells (K, 2) shut, the passable cells still joined to
    ``start`` are at least ``share`` of all passable cells (:meth:`DeadEnds.leads_on`).

    Each call builds a whole :class:`DeadEnds` of ``passable`` (its blocks, pieces and
    links) for one question: a caller asking many questions of one map builds a
    :class:`DeadEnds` once and asks it.

    Parameters
    ----------
    passable : ndarray of bool, shape (rows, cols)
        Cells a car's centre may occupy.
    closed : ndarray of int, shape (K, 2)
        Cells shut (row, column), as :meth:`DeadEnds.leads_on` reads them.
    start : tuple of int
        The car's cell (row, column); counts as open.
    share : float, optional
        Share of the passable cells to reach; default 0.5.
    n_passable : int or None, optional
        Ignored (the count of ``passable`` cells is taken by :class:`DeadEnds`); kept
        so that callers passing it still work. Default None.

    Raises
    ------
    IndexError
        If a cell of ``closed`` or ``start`` lies outside the map.
    ValueError
        If ``closed`` is not of shape (K, 2).
    """
    del n_passable  # accepted for the callers of the former signature, not used
    if not len(_closed_cells(closed)):
        return True
    return DeadEnds(passable).leads_on(closed, start, share)


def route_goals(route: F64, near: float = 3.0, far: float = 10.0) -> F64:
    """Poses (M, 3: x, y, heading) on ``route`` from ``near`` to ``far`` metres along it,
    every half metre, heading along the route; the route's end alone (heading NaN, any
    heading will do) when the route is shorter than ``near``."""
    seg = np.hypot(np.diff(route[:, 0]), np.diff(route[:, 1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if len(route) < 2 or s[-1] < near:
        return np.array([[route[-1, 0], route[-1, 1], math.nan]])
    out = []
    for at in np.arange(near, min(far, s[-1]) + 1e-9, 0.5):
        k = int(np.searchsorted(s, at))
        k = min(max(k, 1), len(route) - 1)
        # The tangent over about a metre either side: single cell steps zigzag.
        a = int(np.searchsorted(s, at - 1.0))
        b = min(int(np.searchsorted(s, at + 1.0)), len(route) - 1)
        a = min(a, b - 1)
        h = math.atan2(route[b, 1] - route[a, 1], route[b, 0] - route[a, 0])
        out.append((route[k, 0], route[k, 1], h))
    return np.array(out, dtype=np.float64)


def clear_goals(
    x: float,
    y: float,
    away: F64,
    passable: npt.NDArray[np.bool_],
    grid: Grid,
    clear: float,
    reach: float = 6.0,
) -> F64:
    """Where a car held up by the robots at ``away`` can back off to, so that they can
    pass.

    Parameters
    ----------
    x, y : float
        The car's position, world metres.
    away : ndarray of float, shape (K, 2)
        The positions of the robots to make way for, world metres.
    passable : ndarray of bool, shape grid
        Cells a car's centre may occupy.
    grid : Grid
        The grid of ``passable``.
    clear : float
        How far from every point of ``away`` a goal must lie, metres.
    reach : float, optional
        How far from (x, y) a goal may lie, metres; default 6.

    Returns
    -------
    ndarray of float, shape (M, 3)
        Goal poses (x, y, heading) at the centres of the qualifying cells, heading NaN
        (any heading will do); (0, 3) when there is no such cell.
    """
    res = grid.resolution
    k = math.ceil(reach / res)
    r0, c0 = (int(v) for v in grid.world_to_cell(x, y))
    dr, dc = np.mgrid[-k : k + 1, -k : k + 1]
    rr, cc = (r0 + dr).ravel(), (c0 + dc).ravel()
    inside = grid.contains(rr, cc)
    rr, cc = rr[inside], cc[inside]
    rr, cc = rr[passable[rr, cc]], cc[passable[rr, cc]]
    px, py = grid.cell_centres(rr, cc)
    keep = np.hypot(px - x, py - y) <= reach
    for ax, ay in away.tolist():
        keep &= np.hypot(px - ax, py - ay) >= clear
    return np.column_stack([px[keep], py[keep], np.full(int(keep.sum()), math.nan)]).astype(
        np.float64
    )


def _primitives(
    turn_radius: float, headings: int = HEADINGS
) -> tuple[F64, F64, F64, list[tuple[float, float]]]:
    """The six arcs (forward and reverse; left, straight, right), each one heading bin
    (of ``headings``) long at the turning radius: their sample points in the car's
    frame (6, S, 2), end poses (6, 3) and costs (6,)."""
    length = turn_radius * 2 * math.pi / headings
    kmax = 1.0 / turn_radius
    arcs = [(g * length, k) for g in (1.0, -1.0) for k in (kmax, 0.0, -kmax)]
    n = max(2, math.ceil(length * SAMPLES_PER_M) + 1)
    pts = np.empty((len(arcs), n, 2))
    ends = np.empty((len(arcs), 3))
    cost = np.empty(len(arcs))
    for j, (ln, k) in enumerate(arcs):
        u = np.linspace(0.0, ln, n)
        if k == 0.0:
            pts[j, :, 0], pts[j, :, 1] = u, 0.0
        else:
            pts[j, :, 0] = np.sin(k * u) / k
            pts[j, :, 1] = (1 - np.cos(k * u)) / k
        ends[j] = (pts[j, -1, 0], pts[j, -1, 1], k * ln)
        cost[j] = abs(ln) * (REVERSE_COST if ln < 0 else 1.0)
    return pts, ends, cost, arcs


def plan_manoeuvre(
    start: tuple[float, float, float],
    goals: F64,
    passable: npt.NDArray[np.bool_],
    grid: Grid,
    turn_radius: float,
    *,
    others: F64 | None = None,
    separation: float = 2.0,
    tolerance: float = 0.75,
    heading_tolerance: float = 0.5,
    budget: int = 3000,
    headings: int = HEADINGS,
    bin_size: float = BIN,
) -> Manoeuvre | None:
    """A shortest manoeuvre (by length, reverse and gear changes costing more) of arcs
    of radius ``turn_radius`` from ``start`` (x, y, heading) to within ``tolerance``
    metres and ``heading_tolerance`` radians of one of ``goals`` (M, 3; a NaN heading
    takes any), keeping every point on ``passable`` cells and ``separation`` metres
    from every robot in ``others`` (K, 2; a robot nearer at the start: no nearer than
    that); None when ``budget`` expansions find none.

    A hybrid A*: states are binned by position (``bin_size`` metres, default
    :data:`BIN`) and heading (``headings`` bins, default :data:`HEADINGS`; each arc of
    the search turns by one bin) but keep their exact poses; the heuristic is, to the nearest
    goal, the larger of the straight-line distance and the arc a turn to the goal's
    heading takes at least (both less the tolerances: it never overestimates).
    """
    pts, ends, cost, arcs = _primitives(turn_radius, headings)
    rows, cols = passable.shape
    bin_w = 2 * math.pi / headings
    gx, gy, gh = goals[:, 0], goals[:, 1], goals[:, 2]
    any_heading = np.isnan(gh)
    ox = others[:, 0] if others is not None and len(others) else None
    oy = others[:, 1] if others is not None and len(others) else None
    near_sep = np.empty(0)
    if ox is not None and oy is not None:
        # A robot already nearer than ``separation`` must only not come nearer: a car
        # held up by another has to be able to back away from it.
        near_sep = np.minimum(separation, np.hypot(ox - start[0], oy - start[1])) - 1e-9

    ox0, oy0 = grid.origin
    res = grid.resolution

    def key(x: float, y: float, h: float) -> tuple[int, int, int]:
        # Grid.world_to_cell's arithmetic on scalars: this runs for every node.
        return (
            math.floor((x - ox0) / bin_size),
            math.floor((y - oy0) / bin_size),
            round(h / bin_w) % headings,
        )

    def done(x: float, y: float, h: float) -> bool:
        close = np.hypot(gx - x, gy - y) <= tolerance
        dh = np.abs((gh - h + math.pi) % (2 * math.pi) - math.pi)
        return bool((close & (any_heading | (dh <= heading_tolerance))).any())

    gh0 = np.where(any_heading, 0.0, gh)

    def guess(x: float, y: float, h: float) -> float:
        # Every turn by dh takes at least turn_radius * dh metres of arc.
        dh = np.abs((gh0 - h + math.pi) % (2 * math.pi) - math.pi)
        turn = np.where(any_heading, 0.0, np.maximum(dh - heading_tolerance, 0.0))
        return float(np.maximum(np.hypot(gx - x, gy - y) - tolerance, turn_radius * turn).min())

    x0, y0, h0 = start
    # Nodes: (x, y, heading, cost so far, gear, parent); via: the arc that led there.
    nodes: list[tuple[float, float, float, float, int, int]] = [(x0, y0, h0, 0.0, 0, -1)]
    via: list[int] = [-1]
    heap: list[tuple[float, int]] = [(guess(x0, y0, h0), 0)]
    best: dict[tuple[int, int, int], float] = {key(x0, y0, h0): 0.0}
    expanded = 0
    while heap and expanded < budget:
        _, u = heapq.heappop(heap)
        x, y, h, g, gear, _parent = nodes[u]
        if g > best.get(key(x, y, h), math.inf) + 1e-9:
            continue
        if u and done(x, y, h):
            out: list[tuple[float, float]] = []
            while u:
                out.append(arcs[via[u]])
                u = nodes[u][5]
            return Manoeuvre(out[::-1])
        expanded += 1
        ch, sh = math.cos(h), math.sin(h)
        wx = x + ch * pts[:, :, 0] - sh * pts[:, :, 1]
        wy = y + sh * pts[:, :, 0] + ch * pts[:, :, 1]
        c = np.floor((wx - ox0) / res).astype(np.int64)
        r = rows - 1 - np.floor((wy - oy0) / res).astype(np.int64)
        inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        ok = inside.all(axis=1)
        clear = np.zeros_like(inside)
        clear[inside] = passable[r[inside], c[inside]]
        ok &= clear.all(axis=1)
        if ox is not None and oy is not None:
            dd = np.hypot(wx[:, :, None] - ox, wy[:, :, None] - oy)
            ok &= (dd >= near_sep).all(axis=(1, 2))
        for j in np.flatnonzero(ok).tolist():
            nx = x + ch * ends[j, 0] - sh * ends[j, 1]
            ny = y + sh * ends[j, 0] + ch * ends[j, 1]
            nh = (h + ends[j, 2] + math.pi) % (2 * math.pi) - math.pi
            ngear = 1 if arcs[j][0] > 0 else -1
            ng = g + float(cost[j]) + (GEAR_COST if gear and ngear != gear else 0.0)
            kk = key(nx, ny, nh)
            if ng >= best.get(kk, math.inf) - 1e-9:
                continue
            best[kk] = ng
            nodes.append((nx, ny, nh, ng, ngear, u))
            via.append(j)
            heapq.heappush(heap, (ng + guess(nx, ny, nh), len(nodes) - 1))
    return None
