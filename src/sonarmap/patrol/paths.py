"""Path lengths and first steps from a robot to every place.

- :func:`wave` (and :class:`Wave`, which keeps its buffers from one call to the next):
  the thesis's wave (Lee's algorithm with weights): Dijkstra on the grid's passable
  cells, 8-connected, steps of one cell and sqrt(2) cells. One wave from the robot gives
  the length L of the shortest path to every cell and the first step of that path (one
  of 8 directions). It follows map edits for free: it is recomputed on the current
  passable mask every step.
- :func:`straight_paths`: straight lines (open space, the thesis's Tables 2-3).

An 8-connected wave overestimates the Euclidean geodesic by up to about 8 %.

The wave is exact Dijkstra with a bucket queue (Dial's algorithm) instead of a heap:
bucket k holds the cells whose distance lies in [k, k + 1) cells. Every step weighs at
least one cell, so a cell taken from bucket k only lowers cells into buckets k + 1 and
k + 2 (a step weighs less than 2 cells): three buckets used as a ring suffice, and when
bucket k is reached every cell in it already has its final distance, so the order within
a bucket does not matter. Taking a cell costs O(1) instead of O(log n).

Ties matter: in open space almost every cell has shortest paths starting with either of
two steps. They are broken by a fixed rule, independent of the order in which cells are
taken. Each cell gets the set of the first steps of all its shortest paths (the union of
the sets of its neighbours on a shortest path to it, the start's neighbours having the
step itself), and its first step is the step of that set closest in direction to the
straight line from the start to the cell (largest dot product with the bearing; the
smallest index among equals). In open space that is the nearest of the 8 directions to
the straight line, as with straight paths. (The former heap kernel kept whichever
neighbour lowered a cell first, the one nearest the start, so its paths ended with their
diagonal steps: away from the exact diagonals every first step was east, north, west or
south.) "On a shortest path" allows a tolerance of :data:`TIE` cells for rounding: a
length is a + b sqrt(2) with whole a, b, two different such lengths with fewer than
20,000 diagonal steps differ by more than 2.5e-5 cells, and rounding stays far below
1e-6 cells, so the tolerance merges true ties only.

With a ``limit``, the wave stops taking cells beyond that length: the cells within get
exactly the lengths and first steps of the full wave (every shortest path to them runs
through cells within), the others are left unreached.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt

__all__ = [
    "STEPS",
    "TIE",
    "Shadows",
    "Wave",
    "nearest_step",
    "no_visit",
    "path_to",
    "shadows",
    "straight_paths",
    "until_reached",
    "wave",
]

#: The 8 steps as (row, column) offsets, counter-clockwise from east (+x); rows grow
#: downwards, so north (+y) is row - 1.
STEPS = np.array(
    [(0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1)], dtype=np.int64
)
#: Unit world vectors (x, y) of the 8 steps.
STEP_UNITS = np.array(
    [(math.cos(k * math.pi / 4), math.sin(k * math.pi / 4)) for k in range(8)], dtype=np.float64
)
#: Two path lengths closer than this (in cells) are equal: see the module's notes.
TIE = 1e-6


def nearest_step(dx: float, dy: float) -> int:
    """Index into :data:`STEPS` of the step nearest the world direction (dx, dy)."""
    return round(math.atan2(dy, dx) / (math.pi / 4)) % 8


# Cell codes of the wave's padded map: 2 passable, 1 target only (a closed passable
# cell), 0 neither, and _RIM for a cell off the passable mask next to a passable one,
# whose code (1 or 0) the wave reads from the call's targets when it gets there.
_CLOSED = 0
_RIM = 3
#: A marker no target array is: the kept target codes are stale.
_CHANGED = object()


@nb.njit(cache=True)
def _fill_codes(passable: npt.NDArray[np.bool_], code: npt.NDArray[np.uint8]) -> None:
    """Padded codes of ``passable``: 2 passable, :data:`_RIM` off it with a passable
    cell among the 8 neighbours, 0 elsewhere (and the one-cell border)."""
    rows, cols = passable.shape
    width = cols + 2
    for r in range(rows):
        base = (r + 1) * width + 1
        for c in range(cols):
            if passable[r, c]:
                code[base + c] = 2
                continue
            near = False
            for dr in range(-1, 2):
                rr = r + dr
                if 0 <= rr < rows:
                    for dc in range(-1, 2):
                        cc = c + dc
                        if 0 <= cc < cols and passable[rr, cc]:
                            near = True
            code[base + c] = _RIM if near else 0


@nb.njit(cache=True)
def _rim_code(target: npt.NDArray[np.bool_], v: int, width: int, inv_width: float) -> int:
    """The code of rim cell ``v`` (padded flat index) for the targets ``target`` (the
    grid's own cells, flat): 1 target, 0 not."""
    r = int((v + 0.5) * inv_width)
    return 1 if target[(r - 1) * (width - 2) + v - r * width - 1] else 0


@nb.njit(cache=True)
def _resolve(
    code: npt.NDArray[np.uint8],
    target: npt.NDArray[np.bool_],
    v: int,
    width: int,
    inv_width: float,
    done: npt.NDArray[np.int32],
    n_done: npt.NDArray[np.int64],
) -> int:
    """The code of rim cell ``v`` (as :func:`_rim_code`), written into ``code`` so that
    later reads (this wave's and the next ones' for the same targets) skip the targets;
    ``v`` is appended to ``done`` (its count in ``n_done[0]``) to be reset to
    :data:`_RIM` when the targets change."""
    c = _rim_code(target, v, width, inv_width)
    code[v] = c
    done[n_done[0]] = v
    n_done[0] += 1
    return c


@nb.njit(cache=True)
def _corner(
    code: npt.NDArray[np.uint8],
    target: npt.NDArray[np.bool_],
    w: int,
    cv: int,
    width: int,
    inv_width: float,
    done: npt.NDArray[np.int32],
    n_done: npt.NDArray[np.int64],
) -> int:
    """The code of cell ``w``, a corner a diagonal step onto a cell of code ``cv`` passes:
    a rim cell (1 or 0) stops a step onto a passable cell (2) without its target bit
    being read, and is read (:func:`_resolve`) for a step onto a target."""
    c = int(code[w])
    if c != _RIM:
        return c
    return 0 if cv == 2 else _resolve(code, target, w, width, inv_width, done, n_done)


@nb.njit(cache=True)
def _unresolve(
    code: npt.NDArray[np.uint8], done: npt.NDArray[np.int32], n_done: npt.NDArray[np.int64]
) -> None:
    """Reset the rim cells :func:`_resolve` wrote back to :data:`_RIM`."""
    for i in range(n_done[0]):
        code[done[i]] = _RIM
    n_done[0] = 0


#: Lowest set bit of a byte (0 for 0).
_LOWEST = np.array([((i & -i).bit_length() - 1) if i else 0 for i in range(256)], dtype=np.int64)
_S = math.sqrt(0.5)
#: The 8 steps as world vectors (x, y), diagonals with the same two components exactly,
#: so that a direction halfway between two steps scores both the same.
_UNITS = np.array(
    [(1.0, 0.0), (_S, _S), (0.0, 1.0), (-_S, _S), (-1.0, 0.0), (-_S, -_S), (0.0, -1.0), (_S, -_S)]
)


# Not cached: its visitor argument is a jitted function, whose type never matches the
# one an earlier process pickled, so every process appended an entry to the on-disk
# index and, once one was there, saving it failed ("underlying object has vanished"):
# every fresh process calling the wave crashed (team nodes, a second CLI run).
@nb.njit
def _dial(
    code: npt.NDArray[np.uint8],
    target: npt.NDArray[np.bool_],
    allow: npt.NDArray[np.uint8],
    width: int,
    start: int,
    resolution: float,
    limit: float,
    dist: npt.NDArray[np.float64],
    first: npt.NDArray[np.uint8],
    order: npt.NDArray[np.int32],
    ring: npt.NDArray[np.int32],
    done: npt.NDArray[np.int32],
    n_done: npt.NDArray[np.int64],
    visit: Any,
    ctx: Any,
) -> tuple[int, npt.NDArray[np.int32]]:
    """The wave on padded flat arrays (``dist`` all inf and ``first`` all 255 on entry);
    ``target`` (the grid's own cells, flat) gives the rim cells' codes, each read once
    and then kept in ``code`` (listed in ``done``, see :func:`_resolve`); ``allow``
    holds per cell the steps out of it the wave may take (bit j for step j).

    Fills ``dist`` (metres) and ``first`` for the cells within ``limit`` metres, lists
    them in ``order`` (in the order taken) and returns their count and the bucket ring
    (grown if it had to be). Cells beyond ``limit`` are left inf / 255.

    After each bucket, ``visit(order, lo, hi, dist, first, width, ctx)`` (a jitted
    function) sees the cells just taken, ``order[lo:hi]``, with their final lengths and
    first steps, and returns a length (metres): the wave stops before the next bucket
    if every cell left is farther than that. A visitor can so stop the wave as soon as
    what it gathers shows that farther cells no longer matter.

    Until a cell is taken, ``first`` holds the set (bit mask) of the first steps of all
    shortest paths found to it so far; when it is taken the set is final (all its
    neighbours on shortest paths to it were taken before) and is replaced by the step
    of the set closest in direction to the cell.
    """
    inv = 1.0 / resolution
    w1 = resolution
    w2 = resolution * math.sqrt(2.0)
    tol = TIE * resolution
    # Flat offsets of the 8 steps and, for the diagonals, of the two cells beside them.
    step = np.empty(8, dtype=np.int64)
    side_a = np.zeros(8, dtype=np.int64)
    side_b = np.zeros(8, dtype=np.int64)
    for j in range(8):
        dr = STEPS[j, 0]
        dc = STEPS[j, 1]
        step[j] = dr * width + dc
        side_a[j] = dc
        side_b[j] = dr * width
    # Row of a flat index u by a float product instead of a division: (u + 0.5) / width
    # is at least 0.5 / width away from a whole number, far more than the product's
    # rounding error (about u * 1e-16 / width).
    inv_width = 1.0 / width
    r0 = start // width
    c0 = start - r0 * width
    count = np.zeros(3, dtype=np.int64)
    dist[start] = 0.0
    ring[0, 0] = start
    count[0] = 1
    n = 0
    k = 0
    # Bucket of a length x metres: floor(x / resolution), nudged up by TIE so that a
    # whole number of cells rounded down a little still lands in its own bucket.
    last = limit * inv + 1.0
    # The visitor's latest limit. It may rise as well as fall, so it stops the wave only
    # between buckets, when every cell left is farther: a later, higher limit must not
    # find cells dropped for an earlier, lower one.
    told = np.inf
    while count[0] + count[1] + count[2] > 0 and k <= last:
        if (k - TIE) * resolution > told:
            break
        slot = k % 3
        size = count[slot]
        # Room in the ring for every cell of this bucket lowering all 8 neighbours.
        need = count[0] + count[1] + count[2] + 8 * size
        if need > ring.shape[1]:
            grown = np.empty((3, 2 * need), dtype=np.int32)
            grown[:, : ring.shape[1]] = ring
            ring = grown
        lo = n
        for i in range(size):
            u = ring[slot, i]
            d = dist[u]
            if d > limit:
                dist[u] = np.inf
                first[u] = 255
                continue
            if int(d * inv + TIE) != k:
                continue  # lowered into an earlier bucket since, and taken there
            order[n] = u
            n += 1
            mu = first[u]
            if u == start:
                mu = 0
            elif mu & (mu - 1) == 0:
                first[u] = _LOWEST[mu]
            else:
                # Several first steps: the one closest to the bearing of the cell, the
                # smallest index among equals.
                r = int((u + 0.5) * inv_width)
                dx = float(u - r * width - c0)
                dy = float(r0 - r)
                m = mu
                best = -np.inf
                pick = 0
                while m:
                    j = _LOWEST[m]
                    m &= m - 1
                    score = dx * _UNITS[j, 0] + dy * _UNITS[j, 1]
                    if score > best:
                        best = score
                        pick = j
                first[u] = pick
            cu = code[u]
            if cu != 2:
                # A place off the passable cells is reached in one step from a cell the
                # centre may be on, never through others like it: a strip of such
                # places along a wall or through a gap narrower than the robot would
                # otherwise pull the robot towards places it cannot get to that way.
                continue
            au = allow[u]
            for j in range(8):
                if not (au >> j) & 1:
                    continue
                v = u + step[j]
                # The length first: about half the neighbours were taken before (or
                # are as near), and a step that cannot lower a length or tie with it
                # needs no codes read. A code read is only kept (``_resolve``), never
                # an answer, so reading fewer changes no length or first step.
                nd = d + (w2 if j & 1 else w1)
                od = dist[v]
                if not nd < od + tol:
                    continue
                cv = code[v]
                if cv == _RIM:
                    cv = _resolve(code, target, v, width, inv_width, done, n_done)
                # Once a path leaves the cells the robot's centre may cross (to reach a
                # place near a wall), it does not come back: paths between passable
                # cells stay passable (the cell taken is passable, 2: none is higher).
                if cv == _CLOSED:
                    continue
                if j & 1:
                    # A diagonal step may not cut the corner of a cell it could not
                    # enter itself.
                    ca = _corner(code, target, u + side_a[j], cv, width, inv_width, done, n_done)
                    cb = _corner(code, target, u + side_b[j], cv, width, inv_width, done, n_done)
                    if ca < cv or cb < cv:
                        continue
                f = mu if mu else (1 << j)
                if nd <= od - tol:
                    # Shorter: into its bucket, unless already there.
                    first[v] = f
                    dist[v] = nd
                    b = int(nd * inv + TIE)
                    if od == np.inf or int(od * inv + TIE) != b:
                        s = b % 3
                        ring[s, count[s]] = v
                        count[s] += 1
                else:
                    # As short (rounding aside): more first steps.
                    first[v] |= f
                    if nd < od:
                        dist[v] = nd
        count[slot] = 0
        k += 1
        if n > lo:
            told = visit(order, lo, n, dist, first, width, ctx)
    # Stopped: clear what is left in the ring untaken (beyond the limit, or in bucket k
    # or later; entries of cells since taken in an earlier bucket stay).
    for s in range(3):
        for i in range(count[s]):
            v = ring[s, i]
            d = dist[v]
            if d < np.inf and (d > limit or int(d * inv + TIE) >= k):
                dist[v] = np.inf
                first[v] = 255
    return n, ring


@nb.njit(cache=True)
def no_visit(
    order: npt.NDArray[np.int32],
    lo: int,
    hi: int,
    dist: npt.NDArray[np.float64],
    first: npt.NDArray[np.uint8],
    width: int,
    ctx: Any,
) -> float:
    """The plain wave's visitor: sees nothing, sets no limit."""
    return np.inf


@nb.njit(cache=True)
def until_reached(
    order: npt.NDArray[np.int32],
    lo: int,
    hi: int,
    dist: npt.NDArray[np.float64],
    first: npt.NDArray[np.uint8],
    width: int,
    ctx: Any,
) -> float:
    """A visitor stopping the wave once the cell ``ctx[0]`` (a padded flat index) is
    taken: its length so far, a bound that only falls, so the wave ends with every
    cell up to it exact (as in the full wave) and nothing farther."""
    return float(dist[ctx[0]])


@nb.njit(cache=True)
def _reset(
    dist: npt.NDArray[np.float64],
    first: npt.NDArray[np.uint8],
    order: npt.NDArray[np.int32],
    n: int,
) -> None:
    for i in range(n):
        dist[order[i]] = np.inf
        first[order[i]] = 255


@nb.njit(cache=True)
def _close(
    code: npt.NDArray[np.uint8],
    rc: npt.NDArray[np.int64],
    width: int,
    start: int,
    shut: npt.NDArray[np.int64],
) -> int:
    """Take the cells ``rc`` (row, column pairs) off the passable cells in the padded
    ``code`` (2 -> 1: they stay targets), all but ``start``: their padded flat indices
    (as numpy would index them) go into ``shut``; returns how many, or -1 - k with
    nothing changed when pair k lies off the padded codes."""
    size = code.shape[0]
    for k in range(rc.shape[0]):
        u = (rc[k, 0] + 1) * width + rc[k, 1] + 1
        if u < -size or u >= size:
            return -1 - k
    n = 0
    for k in range(rc.shape[0]):
        u = (rc[k, 0] + 1) * width + rc[k, 1] + 1
        if u == start:
            continue
        if u < 0:
            u += size
        if code[u] == 2:
            code[u] = 1
            shut[n] = u
            n += 1
    return n


@nb.njit(cache=True)
def _reached_in(
    order: npt.NDArray[np.int32],
    n: int,
    first: npt.NDArray[np.uint8],
    dist: npt.NDArray[np.float64],
    mask: npt.NDArray[np.bool_],
    width: int,
) -> tuple[
    npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.int8], npt.NDArray[np.float64]
]:
    """The cells ``order[:n]`` (padded flat indices, ``width`` columns) that ``mask``
    (the grid's own cells, 2-D) holds and that have a first step (0-7 in ``first``;
    the start's 255 is left out), in that order: their rows and columns in the grid,
    first steps and lengths from ``dist`` (metres). See :meth:`Wave.reached_in`."""
    rows = np.empty(n, dtype=np.intp)
    cols = np.empty(n, dtype=np.intp)
    steps = np.empty(n, dtype=np.int8)
    lengths = np.empty(n, dtype=np.float64)
    # Row by a float product, as in the wave (exact for these sizes), not a division
    # per cell.
    inv_width = 1.0 / width
    k = 0
    for i in range(n):
        u = order[i]
        f = first[u]
        if f > 7:
            continue  # the start (-1)
        r = int((u + 0.5) * inv_width)
        c = u - r * width - 1
        r -= 1
        if not mask[r, c]:
            continue
        rows[k] = r
        cols[k] = c
        steps[k] = f
        lengths[k] = dist[u]
        k += 1
    return rows[:k].copy(), cols[:k].copy(), steps[:k].copy(), lengths[:k].copy()


class Wave:
    """The wave on grids of one shape, keeping its buffers between calls.

    ``allowed`` (uint8, the grid's shape; default every step everywhere): the steps out
    of each cell the wave may take, bit j for :data:`STEPS` [j] (one-way streets,
    :mod:`.oneway`). :func:`path_to` then needs the same mask.

    A call returns views of those buffers: they hold until the next call (copy them to
    keep them longer). Only the cells the last wave reached are cleared before the next,
    so a wave cut short by ``limit`` costs about the cells it reaches (and a pass over
    the grid when the passable mask is another array than the last call's).
    """

    def __init__(
        self, shape: tuple[int, int], allowed: npt.NDArray[np.uint8] | None = None
    ) -> None:
        rows, cols = shape
        self.shape = (int(rows), int(cols))
        self._width = cols + 2
        size = (rows + 2) * (cols + 2)
        if size >= 2**31:
            raise ValueError(f"grid too large for the wave: {shape}")
        self._code = np.zeros(size, dtype=np.uint8)
        self._allow = np.full(size, 255, dtype=np.uint8)
        if allowed is not None:
            if allowed.shape != self.shape:
                raise ValueError(f"a wave for {self.shape} given allowed steps of {allowed.shape}")
            if allowed.dtype != np.uint8:
                # Any other type would be cast silently, wrapping a mask like 256 to 0.
                raise ValueError(f"allowed steps must be uint8 bit masks, got {allowed.dtype}")
            self._inner(self._allow)[...] = allowed
        self._dist = np.full(size, np.inf)
        self._first = np.full(size, -1, dtype=np.int8)
        self._order = np.empty(size, dtype=np.int32)
        self._ring = np.empty((3, max(64, 4 * (rows + cols))), dtype=np.int32)
        self._n = 0
        # The passable array whose codes _code holds, and its cells (flat).
        self._held: object | None = None
        self._passable = np.zeros(rows * cols, dtype=np.bool_)
        # The targets whose rim codes _code holds once read (None: the passable cells),
        # the padded indices of those read (to reset them) and their count.
        self._held_target: object | None = None
        self._done = np.empty(size, dtype=np.int32)
        self._n_done = np.zeros(1, dtype=np.int64)

    def __call__(
        self,
        passable: npt.NDArray[np.bool_],
        start: tuple[int, int],
        resolution: float,
        target: npt.NDArray[np.bool_] | None = None,
        limit: float | None = None,
        closed: npt.NDArray[np.intp] | None = None,
        visit: tuple[Any, Any] | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
        """As :func:`wave`, into this object's buffers.

        ``visit`` (a jitted function and its context, see :func:`no_visit`) sees the
        cells bucket by bucket as they are taken and may stop the wave early (e.g.
        :func:`~sonarmap.patrol.forces.sector_pulls`). Cells are given as indices into
        the padded grid, one cell wider on every side: row ``u // width - 1``.

        ``closed`` (row, column pairs, shape (K, 2)) edits the map for this call only:
        those cells are taken off ``passable`` (they stay targets), as if ``passable``
        had them False; the start stays open. The codes of ``passable``, and those of
        the ``target`` cells the wave has read, are kept between calls given the same
        arrays (by identity): do not change either in place between calls (pass a new
        array instead).
        """
        if passable.shape != self.shape:
            raise ValueError(f"a wave for {self.shape} given a map of {passable.shape}")
        r0, c0 = int(start[0]), int(start[1])
        if not (0 <= r0 < self.shape[0] and 0 <= c0 < self.shape[1] and passable[r0, c0]):
            raise ValueError(f"the wave starts in an impassable cell {start}")
        if limit is not None and not limit >= 0:
            raise ValueError(f"the wave's limit must be >= 0 metres, got {limit}")
        if self._n > self._dist.size // 16:
            self._dist.fill(np.inf)
            self._first.fill(-1)
        else:
            _reset(self._dist, self._first.view(np.uint8), self._order, self._n)
        self._n = 0
        if target is not None and target.shape != self.shape:
            raise ValueError(f"a wave for {self.shape} given targets of {target.shape}")
        if self._held is not passable:
            ok = np.ascontiguousarray(passable, dtype=np.bool_)
            _fill_codes(ok, self._code)
            self._held, self._passable = passable, ok.reshape(-1)
            self._n_done[0] = 0
            self._held_target = target
        elif self._held_target is not target:
            # Only the rim cells read for the last targets differ from fresh codes.
            _unresolve(self._code, self._done, self._n_done)
            self._held_target = target
        # The wave reads codes only on the passable cells (2 whatever the targets) and
        # their neighbours, so of the targets only the rim's count, and only those the
        # wave gets to: it reads them from the targets themselves as it goes.
        tg = (
            self._passable
            if target is None
            else np.ascontiguousarray(target, dtype=np.bool_).reshape(-1)
        )
        start_flat = (r0 + 1) * self._width + c0 + 1
        shut = np.empty(0, dtype=np.int64)
        if closed is not None and len(closed):
            rc = np.asarray(closed, dtype=np.int64).reshape(-1, 2)
            shut = np.empty(len(rc), dtype=np.int64)
            n_shut = _close(self._code, rc, self._width, start_flat, shut)
            if n_shut < 0:
                raise IndexError(f"closed cell {tuple(rc[-1 - n_shut].tolist())} is off the map")
            shut = shut[:n_shut]
        try:
            self._n, self._ring = _dial(
                self._code,
                tg,
                self._allow,
                self._width,
                start_flat,
                float(resolution),
                np.inf if limit is None else float(limit),
                self._dist,
                self._first.view(np.uint8),
                self._order,
                self._ring,
                self._done,
                self._n_done,
                *(visit if visit is not None else (no_visit, ())),
            )
        finally:
            self._code[shut] = 2
        return self.dist, self.first

    def forget_targets(self) -> None:
        """Drop the target codes kept from earlier calls: call it after changing in
        place an array given as ``target``, before the next call with it."""
        self._held_target = _CHANGED

    def to(
        self,
        passable: npt.NDArray[np.bool_],
        start: tuple[int, int],
        goal: tuple[int, int],
        resolution: float,
        target: npt.NDArray[np.bool_] | None = None,
        closed: npt.NDArray[np.intp] | None = None,
        limit: float | None = None,
    ) -> float:
        """The wave from ``start`` only as far as ``goal``: every cell up to the goal's
        path length gets the full wave's length and first step (so :func:`path_to` the
        goal reads back the full wave's path); the wave stops between buckets, so cells
        up to about a cell's length farther may be reached too, none beyond. Returns the
        goal's path length (metres; inf when it cannot be reached, or lies beyond
        ``limit`` metres). Arguments as in a call."""
        r, c = int(goal[0]), int(goal[1])
        if not (0 <= r < self.shape[0] and 0 <= c < self.shape[1]):
            raise ValueError(f"the wave's goal {goal} is off the grid {self.shape}")
        flat = np.array([(r + 1) * self._width + c + 1], dtype=np.int64)
        self(passable, start, resolution, target, limit, closed, visit=(until_reached, flat))
        return float(self.dist[r, c])

    def _inner(self, flat: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
        return flat.reshape(self.shape[0] + 2, self._width)[1:-1, 1:-1]

    @property
    def dist(self) -> npt.NDArray[np.float64]:
        """Path length (metres) to every cell of the last wave; inf where none."""
        return self._inner(self._dist)  # type: ignore[return-value]

    @property
    def allowed(self) -> npt.NDArray[np.uint8]:
        """The steps the wave may take out of each cell (see the class notes)."""
        return self._inner(self._allow)  # type: ignore[return-value]

    @property
    def first(self) -> npt.NDArray[np.int8]:
        """First step of the last wave to every cell; -1 at the start and where none."""
        return self._inner(self._first)  # type: ignore[return-value]

    def reached(self) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Rows and columns of the cells the last wave reached (the start first), in
        order of path length (within one cell)."""
        flat = self._order[: self._n].astype(np.intp)
        return flat // self._width - 1, flat % self._width - 1

    def reached_in(
        self, mask: npt.NDArray[np.bool_]
    ) -> tuple[
        npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.int8], npt.NDArray[np.float64]
    ]:
        """The cells the last wave reached that ``mask`` holds, the start left out.

        In one pass: the same as ``rr, cc = reached()``, ``keep = mask[rr, cc] &
        (first[rr, cc] >= 0)`` and those cells' :attr:`first` and :attr:`dist`.

        Parameters
        ----------
        mask : ndarray of bool, the grid's shape
            The cells wanted.

        Returns
        -------
        rows, cols : ndarray of intp, shape (K,)
            The cells, in the order of :meth:`reached` (path length, within one cell).
        steps : ndarray of int8, shape (K,)
            Each cell's first step (an index into :data:`STEPS`).
        lengths : ndarray of float64, shape (K,)
            Each cell's path length (metres).

        Raises
        ------
        ValueError
            When ``mask`` is not of the grid's shape.
        """
        if mask.shape != self.shape:
            raise ValueError(f"a wave for {self.shape} given a mask of {mask.shape}")
        return _reached_in(
            self._order,
            self._n,
            self._first.view(np.uint8),
            self._dist,
            np.asarray(mask, dtype=np.bool_),
            self._width,
        )


def wave(
    passable: npt.NDArray[np.bool_],
    start: tuple[int, int],
    resolution: float,
    target: npt.NDArray[np.bool_] | None = None,
    limit: float | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
    """Shortest 8-connected path lengths (metres) and first steps from ``start``.

    Paths run over ``passable`` cells (where the robot's centre may be). With
    ``target`` (the free cells; passable cells count as target cells anyway), a cell the
    centre cannot reach -- beside a wall, at the mouth of a gap narrower than the robot --
    is reached by a passable path and one last step onto it, so it still pulls the robot
    towards the nearest place from which it can be seen; target cells are never crossed
    on the way to others. With ``limit`` (metres), the
    wave stops there: cells farther away are left as if unreachable (the cells within
    get exactly the lengths and first steps of the full wave).

    Among several shortest paths, the first step is the one nearest the straight line to
    the cell (see the module's notes). To run many waves on one grid, a :class:`Wave`
    reuses its buffers.

    Returns
    -------
    dist : ndarray of float64
        Path length to every cell; ``inf`` where no path exists (or beyond ``limit``).
    first : ndarray of int8
        Index into :data:`STEPS` of the path's first step; -1 at the start and where
        no path exists.

    Both are views of arrays one cell larger on every side (not C-contiguous).
    """
    return Wave(passable.shape)(passable, start, resolution, target, limit)


def straight_paths(
    x: float, y: float, cx: npt.NDArray[np.float64], cy: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Straight-line lengths and unit directions from (x, y) to points (cx, cy)."""
    dx = cx - x
    dy = cy - y
    dist = np.hypot(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(dist > 0, dx / dist, 0.0)
        uy = np.where(dist > 0, dy / dist, 0.0)
    return dist, ux, uy


@nb.njit(cache=True)
def _back(
    dist: npt.NDArray[np.float64],
    r: int,
    c: int,
    steps: npt.NDArray[np.int64],
    resolution: float,
    through: npt.NDArray[np.bool_],
    allowed: npt.NDArray[np.uint8],
) -> npt.NDArray[np.int64]:
    rows, cols = dist.shape
    # Every step is at least one cell long: the path has at most L / cell + 1 cells.
    out = np.empty((int(dist[r, c] / resolution) + 2, 2), dtype=np.int64)
    n = 0
    out[n, 0] = r
    out[n, 1] = c
    n += 1
    diag = math.sqrt(2.0) * resolution
    while dist[r, c] > 0.0:
        best = -1
        best_d = dist[r, c]
        for k in range(8):
            rr = r + steps[k, 0]
            cc = c + steps[k, 1]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                continue
            if not through[rr, cc]:
                continue
            # The step from the predecessor here is step k reversed.
            if not (allowed[rr, cc] >> ((k + 4) % 8)) & 1:
                continue
            cost = diag if k % 2 == 1 else resolution
            # A predecessor on a shortest path: its length plus the step is this one's.
            if abs(dist[rr, cc] + cost - dist[r, c]) < 1e-6 * resolution and dist[rr, cc] < best_d:
                best = k
                best_d = dist[rr, cc]
        if best < 0:
            break
        r += steps[best, 0]
        c += steps[best, 1]
        out[n, 0] = r
        out[n, 1] = c
        n += 1
    return out[:n][::-1].copy()


def path_to(
    dist: npt.NDArray[np.float64],
    target: tuple[int, int],
    resolution: float,
    passable: npt.NDArray[np.bool_] | None = None,
    allowed: npt.NDArray[np.uint8] | None = None,
) -> npt.NDArray[np.int64]:
    """The cells (K, 2) of a shortest path from the wave's start to ``target``, start
    first, read back from the wave's lengths ``dist`` (metres).

    ``allowed``: the wave's allowed steps (:class:`Wave`), if it had any.

    ``passable`` (the map the wave ran on) keeps the path to cells the wave went
    through: the wave also reaches, in one last step, target cells it may not cross,
    and one of those can tie with a passable cell as the way back. Only ``target``
    itself may then be impassable. Default: any cell the wave reached.
    """
    r, c = target
    if not np.isfinite(dist[r, c]):
        raise ValueError(f"no path to {target}")
    if passable is not None and passable.shape != dist.shape:
        raise ValueError(f"passable cells of {passable.shape} for a wave of {dist.shape}")
    # Without a map, any reached cell: the only ones a shortest path can come from.
    through = np.isfinite(dist) if passable is None else passable
    # No copies: a wave's lengths are a strided view of a whole-map buffer, and copying
    # it for every path read back would cost more than the wave.
    through = np.asarray(through, dtype=np.bool_)
    if allowed is None:
        steps = np.full(dist.shape, 255, dtype=np.uint8)
    else:
        steps = np.asarray(allowed, dtype=np.uint8)
        if steps.shape != dist.shape:
            raise ValueError(f"allowed steps of {steps.shape} for a wave of {dist.shape}")
    return _back(dist, int(r), int(c), STEPS, float(resolution), through, steps)


@dataclass(frozen=True)
class Shadows:
    """Watched cells no wave reaches, each tied to the nearest cell a wave does reach.

    A wave reaches a place off the passable cells in one last step from a passable
    cell, never through other such places (see :func:`wave`), so the cells of a
    wall-side strip two or more cells deep get no path: they would pull no robot and
    could stay unseen. Each is tied to its *anchor*, the nearest cell the wave reaches,
    and pulls as if it lay there, ``extra`` metres farther.

    Attributes
    ----------
    ptr : ndarray of int64, shape (rows * cols + 1,)
        The shadows of the cell with flat index ``k`` (row-major) are entries
        ``ptr[k]:ptr[k + 1]`` of ``rows``, ``cols`` and ``extra``.
    rows, cols : ndarray of int64
        The shadow cells, grouped by anchor.
    extra : ndarray of float64
        Straight distance from each shadow cell to its anchor, metres.
    """

    ptr: npt.NDArray[np.int64]
    rows: npt.NDArray[np.int64]
    cols: npt.NDArray[np.int64]
    extra: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.rows)


def shadows(
    passable: npt.NDArray[np.bool_], watched: npt.NDArray[np.bool_], resolution: float
) -> Shadows:
    """The watched cells that no wave over ``passable`` with ``watched`` as its targets
    reaches, tied to their anchors (see :class:`Shadows`)."""
    from scipy import ndimage

    if passable.shape != watched.shape:
        raise ValueError(f"passable cells of {passable.shape}, watched of {watched.shape}")
    reached = np.zeros(passable.shape, dtype=bool)
    waver = Wave(passable.shape)
    # One wave per passable component: paths never leave one.
    labels, n = ndimage.label(passable, structure=np.ones((3, 3), dtype=bool))
    for k in range(1, n + 1):
        r, c = np.argwhere(labels == k)[0]
        dist, _ = waver(passable, (int(r), int(c)), resolution, watched)
        reached |= np.isfinite(dist)
    lost = watched & ~reached
    rows, cols = passable.shape
    ptr = np.zeros(rows * cols + 1, dtype=np.int64)
    if not lost.any() or not reached.any():
        empty = np.empty(0, dtype=np.int64)
        return Shadows(ptr, empty, empty.copy(), np.empty(0))
    gap, (ar, ac) = ndimage.distance_transform_edt(~reached, return_indices=True)
    sr, sc = np.nonzero(lost)
    anchor = ar[sr, sc] * cols + ac[sr, sc]
    order = np.argsort(anchor, kind="stable")
    np.add.at(ptr, anchor + 1, 1)
    np.cumsum(ptr, out=ptr)
    return Shadows(
        ptr,
        sr[order].astype(np.int64),
        sc[order].astype(np.int64),
        (gap[sr, sc] * resolution)[order].astype(np.float64),
    )
