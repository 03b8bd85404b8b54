"""The fog of war: time since each place was last seen, and the metrics on it.

TB(x) is the time in seconds since any robot last had cell x within its vision radius
(a disc, as the thesis draws it). The watched domain is the territory's free cells.
MTB(t) = max of TB over the free cells; the thesis's criterion is its time average.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..grid import Grid

__all__ = ["Fog", "Vision", "dilate", "disc_cells", "disc_offsets", "disc_side"]


def disc_offsets(radius: float, resolution: float) -> npt.NDArray[np.int64]:
    """(row, column) offsets of the cells whose centres lie within ``radius`` metres of
    a cell's centre."""
    k = int(np.floor(radius / resolution))
    dr, dc = np.mgrid[-k : k + 1, -k : k + 1]
    inside = (dr * resolution) ** 2 + (dc * resolution) ** 2 <= radius**2 + 1e-12
    return np.column_stack([dr[inside], dc[inside]]).astype(np.int64)


def disc_cells(
    disc: npt.NDArray[np.int64], r: int, c: int, shape: tuple[int, int]
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Rows and columns of the ``disc`` offsets around cell (r, c) that lie inside a grid
    of ``shape``."""
    rows = disc[:, 0] + r
    cols = disc[:, 1] + c
    ok = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
    return rows[ok], cols[ok]


@nb.njit(cache=True)
def _disc_side(
    disc: npt.NDArray[np.int64],
    r: int,
    c: int,
    rows: int,
    cols: int,
    mine_r: int,
    mine_c: int,
    halve: bool,
) -> npt.NDArray[np.int64]:
    out = np.empty((disc.shape[0], 2), dtype=np.int64)
    n = 0
    for k in range(disc.shape[0]):
        rr = disc[k, 0] + r
        cc = disc[k, 1] + c
        if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
            continue
        if halve:
            # Squared offsets are exact integers. Where they differ and lie below
            # 2**40, their square roots differ by more than 2**-22, and libm's hypot
            # (as numpy's np.hypot) is within an ulp of them, at most 2**-32 there: the
            # same order. Otherwise the two hypots are compared as numpy does. The
            # squares are only formed for offsets below 2**20, as int64 squares of
            # offsets past about 3e9 cells wrap (2**32 squares to 0).
            a, b = rr - r, cc - c
            e, f = rr - mine_r, cc - mine_c
            small = max(abs(a), abs(b), abs(e), abs(f)) < 2**20
            s_them = a * a + b * b if small else 0
            s_mine = e * e + f * f if small else 0
            if small and s_them != s_mine and max(s_them, s_mine) < 2**40:
                if s_them > s_mine:
                    continue
            elif not math.hypot(float(a), float(b)) < math.hypot(float(e), float(f)):
                continue
        out[n, 0] = rr
        out[n, 1] = cc
        n += 1
    return out[:n].copy()


def disc_side(
    disc: npt.NDArray[np.int64],
    r: int,
    c: int,
    shape: tuple[int, int],
    mine: tuple[int, int] | None = None,
) -> npt.NDArray[np.int64]:
    """The cells of a disc around a cell that lie inside the grid, optionally only
    those nearer it than another cell.

    Parameters
    ----------
    disc : ndarray of int64, shape (M, 2)
        (row, column) offsets of the disc's cells, as :func:`disc_offsets` gives them.
    r, c : int
        Row and column of the disc's centre cell.
    shape : tuple of int
        (rows, columns) of the grid; offsets landing outside it are left out.
    mine : tuple of int, optional
        A cell (row, column): when given, only the cells whose centres lie strictly
        nearer (r, c) than ``mine`` are kept (by ``np.hypot`` of the cell offsets).
        Default None: every cell inside the grid.

    Returns
    -------
    ndarray of int64, shape (K, 2)
        (row, column) of the cells kept, in the disc's order. Without ``mine``:
        ``np.column_stack(disc_cells(disc, r, c, shape))``.
    """
    mr, mc = (0, 0) if mine is None else (int(mine[0]), int(mine[1]))
    return _disc_side(disc, int(r), int(c), int(shape[0]), int(shape[1]), mr, mc, mine is not None)


class Vision:
    """What a robot at a cell sees: every cell of the disc of ``radius`` metres, or with
    ``line_of_sight`` only those whose centre the straight line from the robot's cell
    reaches without crossing a cell that is not ``clear`` (sampled every half cell;
    the seen obstacle's own face is seen)."""

    def __init__(
        self,
        radius: float,
        resolution: float,
        clear: npt.NDArray[np.bool_] | None = None,
    ) -> None:
        self.disc = disc_offsets(radius, resolution)
        self.clear = clear
        if clear is not None:
            # Sample points strictly between the robot's cell and each disc cell.
            length = np.hypot(self.disc[:, 0], self.disc[:, 1])
            n = max(1, int(np.ceil(length.max() * 2)))
            f = (np.arange(1, n) / n)[None, :]
            self.ray_r = np.rint(self.disc[:, :1] * f).astype(np.int64)
            self.ray_c = np.rint(self.disc[:, 1:] * f).astype(np.int64)

    def seen(
        self, r: int, c: int, shape: tuple[int, int]
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """Rows and columns (inside a grid of ``shape``) seen from cell (r, c)."""
        if self.clear is None:
            return disc_cells(self.disc, r, c, shape)
        nr, nc = self.clear.shape
        rr = np.clip(self.ray_r + r, 0, nr - 1)
        cc = np.clip(self.ray_c + c, 0, nc - 1)
        inside_ray = (self.ray_r + r >= 0) & (self.ray_r + r < nr)
        inside_ray &= (self.ray_c + c >= 0) & (self.ray_c + c < nc)
        # A sample on the robot's own cell or the target's own cell does not block.
        own = ((self.ray_r == 0) & (self.ray_c == 0)) | (
            (self.ray_r == self.disc[:, :1]) & (self.ray_c == self.disc[:, 1:])
        )
        blocked = inside_ray & ~own & ~self.clear[rr, cc]
        rows = self.disc[:, 0] + r
        cols = self.disc[:, 1] + c
        ok = ~blocked.any(axis=1) & (rows >= 0) & (rows < shape[0]) & (cols >= 0)
        ok &= cols < shape[1]
        return rows[ok], cols[ok]


def dilate(tb: npt.NDArray[np.float64], wing: int) -> npt.NDArray[np.float64]:
    """TB(x) <- max of TB over the square of half-side ``wing`` cells around x (the
    thesis's fog dilation, so small long-unseen places are not ignored)."""
    if wing <= 0:
        return tb
    out: npt.NDArray[np.float64] = ndimage.grey_dilation(
        tb, size=(2 * wing + 1, 2 * wing + 1), mode="nearest"
    )
    return out


class Fog:
    """TB over a grid; cells outside ``watched`` stay at 0 and never count.

    Kept as the time each cell was last seen, so that time passing costs nothing, with
    the earliest and the latest of those times per block of :attr:`BLOCK` x
    :attr:`BLOCK` cells, so that MTB costs one pass over the blocks, the cells seen
    lately are found among the blocks seen lately (:meth:`latest_blocks`), and a
    robot's look renews only the blocks its vision touches (unwatched cells are "last
    seen" at +inf and count in neither).

    Parameters
    ----------
    grid : Grid
    watched : ndarray of bool
        The cells whose TB is kept (the territory's free cells).
    start : float
        TB of every watched cell at time 0 (the thesis's START_FOG, not given; 0 means
        the patrol starts from a territory just seen).

    Attributes
    ----------
    t : float
        The fog's time, seconds (:meth:`advance`).
    last : ndarray of float64, shape grid
        The time each cell was last seen, seconds. Read freely; written only through
        :meth:`observe` or :meth:`restore`, which keep the per-block times and the
        running sums with it (a direct write leaves them stale).
    """

    #: Side of the blocks whose earliest last-seen time is kept, in cells.
    BLOCK = 32

    def __init__(self, grid: Grid, watched: npt.NDArray[np.bool_], start: float = 0.0) -> None:
        self.grid = grid
        self.watched = watched
        self.t = 0.0
        self.start = float(start)
        # -start for a watched cell never seen, +inf off the watched cells; written
        # only by observe() and restore() (see the class's Attributes).
        self.last = np.where(watched, -float(start), np.inf)
        self._n = int(watched.sum())
        # Sum of ``last`` over the watched cells, kept as cells are seen.
        self._sum = -float(start) * self._n
        self._rebuild()
        # The ages of the cells one look sees, before it (a buffer for the kernel).
        self._ages = np.empty(0)

    def _rebuild(self) -> None:
        """Derive from :attr:`last` the earliest and latest time of each block and the
        count of the watched cells never seen (the running sum is not derived: its
        rounding follows the looks)."""
        b = self.BLOCK
        rows, cols = self.last.shape
        padded = np.full((-(-rows // b) * b, -(-cols // b) * b), np.inf)
        padded[:rows, :cols] = self.last
        self._block_min = padded.reshape(padded.shape[0] // b, b, -1, b).min(axis=(1, 3))
        padded[~np.isfinite(padded)] = -np.inf
        self._block_max = padded.reshape(padded.shape[0] // b, b, -1, b).max(axis=(1, 3))
        # Watched cells whose ``last`` is still -start (never seen), kept as cells are.
        self._n_never = int(np.count_nonzero(self.watched & (self.last == -self.start)))

    def state(self) -> dict[str, Any]:
        """What a checkpoint keeps (:meth:`restore` reads it): the time ``t``, the
        ``start`` TB, a copy of :attr:`last` and the running sum of its watched
        cells (kept, not recomputed, so that :meth:`mean_tb` and
        :meth:`mean_seen_tb` answer to the last bit as before)."""
        return {"t": self.t, "start": self.start, "last": self.last.copy(), "sum": self._sum}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state` of a fog on the same grid and watched cells; the
        per-block times and the never-seen count are rebuilt from ``last``.

        Raises
        ------
        ValueError
            If the state's ``last`` is not of the grid's shape.
        """
        last = np.array(state["last"], dtype=np.float64)
        if last.shape != self.last.shape:
            raise ValueError(f"fog state: last has shape {last.shape}, the grid {self.last.shape}")
        self.t = float(state["t"])
        self.start = float(state["start"])
        self.last = last
        self._sum = float(state["sum"])
        self._rebuild()

    def never_seen(self) -> npt.NDArray[np.bool_]:
        """Watched cells not seen since time 0: a new array."""
        out: npt.NDArray[np.bool_] = self.watched & (self.last == -self.start)
        return out

    @property
    def tb(self) -> npt.NDArray[np.float64]:
        """TB of every cell (0 outside the watched cells): a new array."""
        return np.where(self.watched, self.t - self.last, 0.0)

    def tb_at(
        self, rows: npt.NDArray[np.intp], cols: npt.NDArray[np.intp]
    ) -> npt.NDArray[np.float64]:
        """TB of watched cells (rows, cols)."""
        return np.asarray(self.t - self.last[rows, cols], dtype=np.float64)

    def mean_seen_tb(self) -> float:
        """Mean TB over the watched cells seen at least once (:meth:`never_seen` not),
        inf when none has been; from the running sum of the cells' last-seen times, so
        it may differ from the mean of those cells' TB in the last bits."""
        seen = self._n - self._n_never
        if seen <= 0:
            return float(np.inf)
        return self.t - (self._sum + self.start * self._n_never) / seen

    def latest_blocks(self) -> npt.NDArray[np.float64]:
        """The latest last-seen time of each :attr:`BLOCK` x :attr:`BLOCK` block's
        watched cells (-inf for a block with none; block (i, j) holds cells from row
        i x BLOCK and column j x BLOCK): a view, not to be written. No cell of a block
        whose entry is t0 was seen after t0."""
        out: npt.NDArray[np.float64] = self._block_max.view()
        out.flags.writeable = False
        return out

    def clear_just_seen(self, mask: npt.NDArray[np.bool_]) -> int:
        """Set to False, in ``mask`` (of the grid's shape, written in place), the
        watched cells seen at time :attr:`t` (by the last look: ``last`` not below
        ``t``), looking only in the blocks seen then; returns how many cells of
        ``mask`` it set to False (those that were True)."""
        return int(_clear_recent(mask, self.last, self._block_max, self.BLOCK, self.t))

    def advance(self, dt: float) -> None:
        """Time passes: every watched cell's TB grows by ``dt``."""
        self.t += dt

    def observe(
        self, rows: npt.ArrayLike, cols: npt.ArrayLike, vision: Vision | npt.NDArray[np.int64]
    ) -> None:
        """Robots at cells (rows, cols) see around them: a :class:`Vision`, or a plain
        disc of cell offsets."""
        shape = (self.last.shape[0], self.last.shape[1])
        disc = vision if not isinstance(vision, Vision) else None
        if isinstance(vision, Vision) and vision.clear is None:
            disc = vision.disc
        if disc is not None and len(self._ages) < len(disc):
            self._ages = np.empty(len(disc))
        for r, c in zip(np.atleast_1d(rows).tolist(), np.atleast_1d(cols).tolist(), strict=True):
            if disc is not None:
                # A plain disc: one pass in a kernel. The ages are summed by numpy, as
                # before, so that the mean TB keeps its rounding.
                n, first = _see_disc(
                    self.last,
                    self.watched,
                    disc,
                    r,
                    c,
                    self.t,
                    self._ages,
                    self._block_min,
                    self._block_max,
                    self.BLOCK,
                    -self.start,
                )
                if n:
                    self._sum += float(np.sum(self._ages[:n]))
                    self._n_never -= first
                continue
            assert isinstance(vision, Vision)
            rr, cc = vision.seen(r, c, shape)
            keep = self.watched[rr, cc]
            rr, cc = rr[keep], cc[keep]
            if not len(rr):
                continue
            self._sum += float(np.sum(self.t - self.last[rr, cc]))
            if self.t != -self.start:
                self._n_never -= int(np.count_nonzero(self.last[rr, cc] == -self.start))
            self.last[rr, cc] = self.t
            self._block_max[rr // self.BLOCK, cc // self.BLOCK] = self.t
            self._renew_blocks(int(rr.min()), int(rr.max()), int(cc.min()), int(cc.max()))

    def _renew_blocks(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Recompute the earliest last-seen time of the blocks over rows r0..r1 and
        columns c0..c1 (inclusive)."""
        _renew(self.last, self._block_min, self.BLOCK, r0, r1, c0, c1)

    def mtb(self) -> float:
        """Max of TB over the watched cells."""
        return self.t - float(self._block_min.min())

    def mean_tb(self) -> float:
        """Mean of TB over the watched cells."""
        return self.t - self._sum / self._n


@nb.njit(cache=True)
def _renew(
    last: npt.NDArray[np.float64],
    block_min: npt.NDArray[np.float64],
    b: int,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
) -> None:
    """The earliest of ``last`` over each ``b`` x ``b`` block touching rows r0..r1 and
    columns c0..c1 (inclusive) into ``block_min`` (blocks cut short by the grid's edge
    over their cells inside)."""
    rows, cols = last.shape
    for br in range(r0 // b, r1 // b + 1):
        for bc in range(c0 // b, c1 // b + 1):
            m = np.inf
            for r in range(br * b, min((br + 1) * b, rows)):
                for c in range(bc * b, min((bc + 1) * b, cols)):
                    v = last[r, c]
                    if v < m:
                        m = v
            block_min[br, bc] = m


@nb.njit(cache=True)
def _see_disc(
    last: npt.NDArray[np.float64],
    watched: npt.NDArray[np.bool_],
    disc: npt.NDArray[np.int64],
    r: int,
    c: int,
    t: float,
    ages: npt.NDArray[np.float64],
    block_min: npt.NDArray[np.float64],
    block_max: npt.NDArray[np.float64],
    b: int,
    never: float,
) -> tuple[int, int]:
    """A robot at cell (r, c) sees the watched cells of ``disc`` (offsets) inside the
    grid: their ages before the look (seconds) into ``ages`` in the disc's order, their
    ``last`` set to ``t``, their blocks renewed. Returns how many it saw, and how many
    of those it saw first (their ``last`` was ``never`` and is no longer)."""
    rows, cols = last.shape
    n = 0
    first = 0
    lo_r, hi_r, lo_c, hi_c = rows, -1, cols, -1
    for k in range(disc.shape[0]):
        rr = disc[k, 0] + r
        cc = disc[k, 1] + c
        if rr < 0 or rr >= rows or cc < 0 or cc >= cols or not watched[rr, cc]:
            continue
        ages[n] = t - last[rr, cc]
        n += 1
        if last[rr, cc] == never and t != never:
            first += 1
        last[rr, cc] = t
        # No cell is seen later than now: the block's latest.
        block_max[rr // b, cc // b] = t
        lo_r = min(lo_r, rr)
        hi_r = max(hi_r, rr)
        lo_c = min(lo_c, cc)
        hi_c = max(hi_c, cc)
    if n:
        _renew(last, block_min, b, lo_r, hi_r, lo_c, hi_c)
    return n, first


@nb.njit(cache=True)
def _clear_recent(
    mask: npt.NDArray[np.bool_],
    last: npt.NDArray[np.float64],
    block_max: npt.NDArray[np.float64],
    b: int,
    t: float,
) -> int:
    """``mask`` False where ``last`` is not below ``t`` (and finite), looking only in
    the blocks whose latest time is not below ``t``; how many were True."""
    rows, cols = last.shape
    n = 0
    for br in range(block_max.shape[0]):
        for bc in range(block_max.shape[1]):
            if block_max[br, bc] < t:
                continue
            for r in range(br * b, min((br + 1) * b, rows)):
                for c in range(bc * b, min((bc + 1) * b, cols)):
                    v = last[r, c]
                    if v >= t and v < np.inf and mask[r, c]:
                        mask[r, c] = False
                        n += 1
    return n
