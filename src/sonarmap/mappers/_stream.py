"""Streaming engines: a method's map kept up to date over a bounded set of readings.

An engine owns the map over the whole grid, the store of the readings in play
(:class:`ReadingPool`) and a selection :class:`~sonarmap.selection.Strategy`. Each
:meth:`StreamEngine.add` rasterises the new readings once, lets the strategy name the
readings that leave, and re-optimises the map locally: only cells the entering or leaving
readings touch change, against every reading in play that touches them. A cell that no
reading in play touches any more keeps its last estimate, so the map remembers what it
has seen while the objective stays bounded.

No engine down-weights correlated readings (the mappers' ``correlated``): a reading's
weight depends on every reading that repeats it, including readings not yet come and
readings that have left the window, so each update would re-weight, and re-fold, readings
throughout the pool. Engines refuse ``correlated > 0`` rather than ignore it, and
likewise the gradient's offline-only ``sparsity``, ``polish`` and ``free_shell``.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import TYPE_CHECKING, ClassVar

import numba as nb
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..grid import Grid
from ..raster import rasterise
from ..readings import Readings
from ..selection import Strategy
from ..sensors import SensorModel
from ._pool import ReadingPool

if TYPE_CHECKING:
    from ._base import Mapper

I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
F64 = npt.NDArray[np.float64]


@nb.njit(cache=True)
def touch(
    slots: I64,
    sign: int,
    f_start: I64,
    f_len: I64,
    o_len: I64,
    cell: I32,
    cov: I32,
    mark: npt.NDArray[np.bool_],
    dirty: I64,
    n_dirty: int,
) -> int:
    """Add ``sign`` to the coverage of every cell of ``slots`` and mark the cells dirty
    (appended to ``dirty`` once each); returns the new number of dirty cells."""
    for s in slots:
        a = f_start[s]
        for j in range(a, a + f_len[s] + o_len[s]):
            c = cell[j]
            cov[c] += sign
            if not mark[c]:
                mark[c] = True
                dirty[n_dirty] = c
                n_dirty += 1
    return n_dirty


@nb.njit(cache=True)
def cover_spans(
    slots: I64,
    sign: int,
    fs_start: I64,
    fs_len: I64,
    os_len: I64,
    sp_cell: I32,
    sp_len: I32,
    cov: I32,
    mark: npt.NDArray[np.bool_],
) -> None:
    """Add ``sign`` to the coverage of every cell of ``slots`` and mark the cells, a
    span (one vectorised slice) at a time; unlike :func:`touch`, the marked cells are
    not listed (the caller reads them off the marks, in grid order)."""
    for s in slots:
        a = fs_start[s]
        for q in range(a, a + fs_len[s] + os_len[s]):
            c0 = sp_cell[q]
            n = sp_len[q]
            cs = cov[c0 : c0 + n]
            ms = mark[c0 : c0 + n]
            for i in range(n):
                cs[i] += sign
                ms[i] = True


@nb.njit(cache=True)
def touching(
    alive: npt.NDArray[np.bool_],
    box: I32,
    f_start: I64,
    f_len: I64,
    o_len: I64,
    cell: I32,
    mark: npt.NDArray[np.bool_],
    r0: int,
    r1: int,
    c0: int,
    c1: int,
) -> I64:
    """Slots in play with a cell marked dirty (bounding boxes first, then the cells)."""
    out = np.empty(alive.shape[0], np.int64)
    k = 0
    for s in range(alive.shape[0]):
        if not alive[s]:
            continue
        if box[s, 1] < r0 or box[s, 0] > r1 or box[s, 3] < c0 or box[s, 2] > c1:
            continue
        a = f_start[s]
        for j in range(a, a + f_len[s] + o_len[s]):
            if mark[cell[j]]:
                out[k] = s
                k += 1
                break
    return out[:k]


class StreamEngine(ABC):
    """A method's streaming map; see the module notes.

    Parameters
    ----------
    mapper : Mapper
        The method and its parameters.
    grid : Grid
        The map grid (fixed for the whole stream).
    sensor : SensorModel
        The sonars' model.
    strategy : Strategy
        Which readings stay in play.
    effort : int
        Work per update, in the method's unit (gradient steps, flip sweeps).
    """

    #: Whether the engine keeps readings (and so needs a bounded strategy).
    keeps_readings: ClassVar[bool] = True
    sort_band: ClassVar[bool] = False
    #: Whether the pool keeps the footprints as spans too (see :class:`ReadingPool`).
    spans: ClassVar[bool] = False
    #: Whether the engine can fold a reading that leaves into fixed per-cell evidence
    #: (its pull on each cell frozen as it stands when it leaves) rather than forget it:
    #: ``gradient`` and ``em-thrun``.
    can_fold: ClassVar[bool] = False

    def __init__(
        self,
        mapper: Mapper,
        grid: Grid,
        sensor: SensorModel,
        strategy: Strategy,
        effort: int,
        *,
        fold: bool | None = None,
    ) -> None:
        if getattr(mapper, "correlated", 0.0) > 0:
            raise ConfigError(
                f"streaming '{mapper.name}' cannot down-weight correlated readings (a "
                "reading's weight depends on readings still to come); set correlated=0"
            )
        if getattr(mapper, "specular_deg", 0.0) > 0:
            raise ConfigError(
                f"streaming '{mapper.name}' cannot weigh free evidence by incidence (the "
                "surfaces' normals depend on echoes still to come); set specular_deg=0"
            )
        for option in ("sparsity", "polish", "free_shell"):
            if getattr(mapper, option, 0.0) > 0:
                raise ConfigError(
                    f"streaming '{mapper.name}' does not implement {option} (offline "
                    f"only); set {option}=0"
                )
        for option in ("no_echo_share", "no_echo_weight"):
            if getattr(mapper, option, 1.0) < 1.0:
                raise ConfigError(
                    f"streaming '{mapper.name}' does not implement {option} (offline "
                    f"only); set {option}=1"
                )
        if self.keeps_readings and not strategy.bounded:
            raise ConfigError(
                f"streaming '{mapper.name}' keeps readings in play; give a bounded strategy "
                "(last:N, cell:N or pose:N), not 'all'"
            )
        if effort < 1:
            raise ConfigError(f"streaming effort must be >= 1, got {effort}")
        if fold is not None and not self.can_fold:
            raise ConfigError(
                f"streaming '{mapper.name}' cannot fold the readings that leave; give fold "
                "only for gradient or em-thrun"
            )
        self._fold = self.default_fold(mapper) if fold is None else bool(fold)
        self.mapper = mapper
        self.grid = grid
        self.sensor = sensor
        self.strategy = strategy
        self.effort = effort
        #: Band half-width to rasterise with: the mapper's ``dr`` (None for the
        #: rasteriser's default); engines of other models set their own in ``_setup``.
        self.dr: float | None = getattr(mapper, "dr", None)
        #: Growth of the band's half-width with the range, metres per metre (the
        #: mapper's ``band_growth``; 0 for methods without one).
        self.band_growth: float = float(getattr(mapper, "band_growth", 0.0))
        self.offset = mapper.band_offset_for(grid)
        self.pool = ReadingPool(grid.cols, sort_band=self.sort_band, spans=self.spans)
        self.cov = np.zeros(grid.size, np.int32)
        self.seen = np.zeros(grid.size, np.bool_)
        self._mark = np.zeros(grid.size, np.bool_)
        self._dirty = np.empty(grid.size, np.int64)
        self.n_updates = 0
        strategy.start(grid.size)
        self._setup()

    @property
    def fold(self) -> bool:
        """Whether readings that leave are folded into fixed per-cell evidence rather
        than forgotten; set once, at construction (False for engines that cannot fold)."""
        return self._fold

    # -- for subclasses ------------------------------------------------------------

    def default_fold(self, mapper: Mapper) -> bool:
        """Whether the engine folds when not told: as :attr:`can_fold` unless the
        method decides by its parameters."""
        return self.can_fold

    def _setup(self) -> None:  # noqa: B027 -- optional
        """Allocate the method's map."""

    def _enter(self, new: I64) -> None:  # noqa: B027 -- optional
        """Readings ``new`` have entered the pool."""

    def _leave(self, gone: I64) -> None:  # noqa: B027 -- optional
        """Readings ``gone`` are about to leave the pool (their entries still readable)."""

    @abstractmethod
    def _optimise(self, dirty: I64, box: tuple[int, int, int, int]) -> None:
        """Re-optimise the ``dirty`` cells (marked, coverage updated, inside ``box``)
        against the readings in play that touch them."""

    @abstractmethod
    def occupancy(self) -> npt.NDArray[np.float32]:
        """Flat occupancy in [0, 1], NaN where no reading has been."""

    def improve(self, budget: float) -> int:
        """Spend up to ``budget`` seconds improving the map over every reading in play;
        returns the units of work done (0 for methods with nothing to improve)."""
        return 0

    def finish(self, passes: int, stop: Callable[[], bool] | None = None) -> int:
        """Bring the map over the readings in play to rest at the end of a log.

        Only ``gradient`` has work to finish (its cells step only in the updates whose
        readings touch them); the other engines return 0 at once.

        Parameters
        ----------
        passes : int
            Passes of the method's work over every reading in play, at most; >= 0.
        stop : callable, optional
            Asked before each pass; when it returns True the finish ends there.

        Returns
        -------
        int
            The passes done (fewer than ``passes`` when ``stop`` said so).
        """
        return 0

    def _finish_with(
        self, passes: int, stop: Callable[[], bool] | None, one_pass: Callable[[I64, I64], object]
    ) -> int:
        """:meth:`finish` for a method whose unit of work is ``one_pass(slots, cells)``
        over the readings in play and every cell a reading has covered."""
        cells = np.flatnonzero(self.cov > 0).astype(np.int64)
        if len(cells) == 0:
            return 0
        sel = self.pool.alive_slots()
        for n in range(passes):
            if stop is not None and stop():
                return n
            one_pass(sel, cells)
        return passes

    def _improve_with(self, budget: float, one_pass: Callable[[I64, I64], object]) -> int:
        """:meth:`improve` for a method whose unit of work is ``one_pass(slots, cells)``
        over the readings in play and every cell a reading has covered: passes until
        ``budget`` seconds are spent (the last may overrun it); returns their count."""
        cells = np.flatnonzero(self.cov > 0).astype(np.int64)
        if len(cells) == 0 or budget <= 0:
            return 0
        sel = self.pool.alive_slots()
        end = time.perf_counter() + budget
        n = 0
        while time.perf_counter() < end:
            one_pass(sel, cells)
            n += 1
        return n

    def _seen_only(self, values: npt.NDArray[np.generic]) -> npt.NDArray[np.float32]:
        """Flat ``values`` (occupancies or a binary map) as float32 with NaN where no
        reading has been (a copy)."""
        out = values.astype(np.float32)
        out[~self.seen] = np.nan
        return out

    # -- the update ---------------------------------------------------------------

    def _prepare(self, readings: Readings) -> Readings:
        """The readings the method uses: without no-echo readings when the mapper is
        told to ignore them (``no_echo="ignore"``), as its offline fit does."""
        if getattr(self.mapper, "no_echo", "free") == "ignore":
            return readings.take(readings.range < self.sensor.r_max)
        return readings

    def add(self, readings: Readings) -> None:
        """Take new readings and update the map around them."""
        readings = self._prepare(readings)
        if len(readings) == 0:
            return
        fp = rasterise(
            self.grid,
            self.sensor,
            readings.x,
            readings.y,
            readings.theta,
            readings.range,
            dr=self.dr,
            offset=self.offset,
            band_growth=self.band_growth,
        )
        z = np.minimum(readings.range, self.sensor.r_max)
        p = self.pool
        new = p.add(fp, z, readings.range < self.sensor.r_max)
        gone = self.strategy.admit(new, readings, p.f_start, p.f_len + p.o_len, p.cell)
        b = p.box[np.concatenate([new, gone])]
        box = (int(b[:, 0].min()), int(b[:, 1].max()), int(b[:, 2].min()), int(b[:, 3].max()))
        dirty = self._touch(new, gone, box)
        self._enter(new)
        self._leave(gone)
        p.remove(gone)
        self._optimise(dirty, box)
        self._mark[dirty] = False
        self.n_updates += 1

    def _touch(self, new: I64, gone: I64, box: tuple[int, int, int, int]) -> I64:
        """Count the readings ``new`` in the coverage and ``gone`` out of it, mark the
        cells they touch (all inside ``box``) dirty and seen; the dirty cells."""
        p = self.pool
        if p.spans:
            for slots, sign in ((new, 1), (gone, -1)):
                cover_spans(
                    slots,
                    sign,
                    p.fs_start,
                    p.fs_len,
                    p.os_len,
                    p.sp_cell,
                    p.sp_len,
                    self.cov,
                    self._mark,
                )
            # The rows of the box hold every marked cell: listed in grid order, which
            # is as good as any to the engines that keep spans (their cells' steps do
            # not depend on each other) and reads the marks off in one vectorised pass.
            lo, hi = max(box[0], 0) * self.grid.cols, (box[1] + 1) * self.grid.cols
            window = self._mark[lo:hi]
            self.seen[lo:hi] |= window
            return np.flatnonzero(window).astype(np.int64) + lo
        n = touch(new, 1, p.f_start, p.f_len, p.o_len, p.cell, self.cov, self._mark, self._dirty, 0)
        n = touch(
            gone, -1, p.f_start, p.f_len, p.o_len, p.cell, self.cov, self._mark, self._dirty, n
        )
        dirty = self._dirty[:n].copy()
        self.seen[dirty] = True
        return dirty

    def touching_dirty(self, box: tuple[int, int, int, int]) -> I64:
        """Readings in play that touch a dirty cell (call while cells are marked)."""
        p = self.pool
        return touching(p.alive, p.box, p.f_start, p.f_len, p.o_len, p.cell, self._mark, *box)

    # -- figures ------------------------------------------------------------------

    @property
    def n_in_play(self) -> int:
        return self.pool.n_alive

    def nbytes(self) -> int:
        """Memory of the engine's state: map, coverage and the readings in play."""
        return int(self.cov.nbytes + self.seen.nbytes * 2 + self._dirty.nbytes) + self.pool.nbytes()
