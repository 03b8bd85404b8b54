"""Thrun 2003's EM over a binary map (methods.md section 4): ``em-thrun``.

Not to be confused with ``em`` (:mod:`.em`), sonarmap's own *relaxed* model, in which
cell i reflects with probability p_hit * m_i for a continuous m_i in [0, 1]. Here, as
in S. Thrun, "Learning occupancy grid maps with forward sensor models" (Autonomous
Robots 15(2), 2003), the map is binary and every occupied cell reflects with
probability p_hit: the sonar model of methods.md section 3, shared with ``stochastic``
through :mod:`._thrun`.

The latent variable of reading z_t is its cause c_t: "random" (probability p_rand,
density 1 / r_max), "occupied cell j of the band" (probability
(1 - p_rand) p_hit (1 - p_hit)^(occupied cells nearer than j), density N(z_t; d_j,
sigma)) or "max range" (probability (1 - p_rand) (1 - p_hit)^(occupied cells in the
beam), density N(z_t; r_max, sigma)).

- E-step: the posterior e_t(c) of every reading's cause under the current map. From it,
  the expected complete-data log-likelihood Q(m) = sum_t sum_c e_t(c) log p(z_t, c | m)
  and the data log-likelihood L(m) = sum_t log p(z_t | m) = Q(m) + H(e), H the
  entropy of the posteriors (``expected_loglik_`` and ``loglik_``).
- M-step: hill climbing over the binary map, one cell at a time in a fixed order. A
  cell flips when that raises the expected log-likelihood plus the posteriors' entropy
  with the causes of the readings whose beam holds it re-estimated for the flipped map
  -- which is L itself. Those are the only readings a flip changes, so each flip is an
  exact partial E-step followed by a partial M-step (the incremental EM of Neal and
  Hinton, 1998), and L never falls. Held fixed instead, the causes would forbid every
  useful flip: a free cell is nobody's cause, so occupying it only adds the pass-through
  cost log(1 - p_hit) of the readings whose beam it lies in, and freeing a cell that a
  reading is credited to makes that reading impossible (log 0): the binary map would
  never leave its start. (Only the opening of the paper's text could be read when this
  was written; the model, the E-step, the flipping M-step and the final per-cell
  posterior follow the paper's description, the incremental form is our reading.)
- A sweep that flips no cell ends the search (or ``max_iter`` sweeps). Then, as in the
  paper, each cell's uncertainty: its posterior with every other cell held at the
  final map, p(m_i = 1 | Z, m_-i), from the change of L when cell i flips and the
  prior odds ``prior``. ``occupancy_`` holds it; ``binary_map_`` the EM map itself.

The search is deterministic: the same readings give the same map. ``partial_fit``
re-solves over every reading given so far, from the start.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..readings import Readings
from ._base import Mapper, Progress, register
from ._checks import choice, integer, number
from ._stream import StreamEngine
from ._thrun import BeamIndex, IndexArrays, init_state, loglik_of
from ._thrun_common import held_posterior, model_inputs, model_sigma, probability, scatter, sweep

__all__ = ["ThrunEMMapper"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

#: Smallest gain of L (nats) for which a cell flips: float round-off in the incremental
#: bookkeeping must not make two states of a cell trade places forever.
MIN_GAIN = 1e-9


@nb.njit(cache=True)
def _e_step(
    occ: B,
    free_off: I64,
    free_cell: I64,
    band_off: I64,
    band_cell: I64,
    band_dist: F64,
    z: F64,
    p_rand: float,
    p_hit: float,
    sigma: float,
    r_max: float,
    weight: F64 | None = None,
) -> tuple[float, float, F64]:
    """Expected complete-data log-likelihood Q, data log-likelihood L, and each
    reading's posterior probability of being random, under the binary map ``occ``.

    With ``weight`` (one per reading) each reading's terms of Q and L count its weight
    times; None compiles to weight 1."""
    log_norm = -math.log(sigma * math.sqrt(2.0 * math.pi))
    log_rand = math.log(p_rand / r_max)
    log_keep = math.log(1.0 - p_rand)
    log_hit = math.log(p_hit)
    log_miss = math.log(1.0 - p_hit)
    n = z.shape[0]
    max_band = 1
    for i in range(n):
        max_band = max(max_band, band_off[i + 1] - band_off[i])
    # Log joint p(z_t, c | m) of each cause: random, the band's cells, max range.
    lj = np.empty(max_band + 2)
    outlier = np.empty(n)
    q_total = 0.0
    l_total = 0.0
    for i in range(n):
        wi = 1.0
        if weight is not None:
            wi = weight[i]
        passed = 0
        for j in range(free_off[i], free_off[i + 1]):
            if occ[free_cell[j]]:
                passed += 1
        k = 0
        lj[k] = log_rand
        k += 1
        for j in range(band_off[i], band_off[i + 1]):
            if occ[band_cell[j]]:
                u = (z[i] - band_dist[j]) / sigma
                lj[k] = log_keep + passed * log_miss + log_hit + log_norm - 0.5 * u * u
                k += 1
                passed += 1
        u = (z[i] - r_max) / sigma
        lj[k] = log_keep + passed * log_miss + log_norm - 0.5 * u * u
        k += 1
        top = lj[0]
        for q in range(1, k):
            top = max(top, lj[q])
        s = 0.0
        for q in range(k):
            s += math.exp(lj[q] - top)
        log_z = top + math.log(s)
        l_total += wi * log_z
        for q in range(k):
            e = math.exp(lj[q] - log_z)
            # A cause with posterior 0 adds nothing, even where its log joint is -inf.
            if e > 0.0:
                q_total += wi * (e * lj[q])
        outlier[i] = math.exp(lj[0] - log_z)
    return q_total, l_total, outlier


@register
class ThrunEMMapper(Mapper):
    """Thrun 2003's EM over a binary map (``em-thrun``); ``em`` is the relaxed variant.

    Each occupied cell reflects with probability ``p_hit``; EM alternates the posterior
    of every reading's cause (E-step) with hill climbing over the binary map (M-step),
    then gives each cell its posterior with the rest of the map held fixed. See the
    module docstring for the derivation.

    The defaults are ``em``'s tuned model parameters but sigma, 0.05, and the band a
    quarter of a cell behind the echo: the highest mean quality in ``sonarmap sweep
    sweeps/band.yaml`` (offsets 0-1 cell and sigma): 0.483, against 0.478 with em's
    sigma 0.03 and 0.445 before (em's parameters, band unmoved). The start from an
    empty map is the one the literature's MAP hill climbing uses.

    Parameters
    ----------
    p_rand : float
        Outlier probability, in (0, 1) (0.1). Zero is refused: a binary map must be
        able to call an unexplainable reading random.
    p_hit : float
        Reflection probability of an occupied cell, in (0, 1) (0.75, thesis 000).
    sigma : float or None
        Range noise of the model, metres (0.05); None: half a cell or the sensor's range
        resolution, whichever is larger.
    band_offset : float or None
        How far behind the echo the surface's cells lie, metres (>= 0): a cell at
        distance d explains a range of d - offset; None (default): a quarter of a cell.
        See :mod:`sonarmap.raster` for why.
    init : {"free", "inverse"}
        Starting map: every cell free (default), or the inverse mapper's map binarised
        at 0.5.
    max_iter : int
        EM iterations (E-step plus one M-step sweep) at most (50).
    prior : float
        Prior occupancy probability used for the final per-cell posterior, in (0, 1)
        (0.5).
    correlated : float
        Down-weighting of correlated readings (Konolige 1997), metres; 0 (default) is off.
        With c > 0 the n readings of one sonar from poses in the same c-metre bin (and
        10-degree heading bin) with ranges in the same c-metre bin each weigh 1 / n (see
        :func:`~sonarmap.mappers._correlated.correlation_weights`), scaled to mean 1, and
        every sum over readings (L, Q, a flip's gain in the M-step and the final posterior)
        counts reading t's term w_t times. Off by default: in ``sonarmap sweep
        sweeps/correlated.yaml`` (bins of 2, 5, 10 and 20 cm, the ten training scenes) every
        setting scored 0.481-0.484, off 0.483: a tie.

    Attributes
    ----------
    binary_map_ : ndarray of float32, shape ``grid.shape``
        The EM map: 1 occupied, 0 free, NaN where no beam reached.
    loglik_ : list of float
        Data log-likelihood L at each E-step, the last after the final M-step
        (non-decreasing); with ``correlated``, the weighted L.
    expected_loglik_ : list of float
        Expected complete-data log-likelihood Q at each E-step (weighted likewise).
    flips_ : list of int
        Cells flipped by each M-step sweep.
    outlier_prob_ : ndarray of float64, shape (n_readings,)
        Per reading, the posterior probability that the random component caused it.
    n_iter_ : int
        M-step sweeps run.

    Examples
    --------
    >>> from sonarmap.grid import Grid
    >>> from sonarmap.readings import Readings
    >>> from sonarmap.rig import get_rig
    >>> import numpy as np
    >>> z = np.zeros(4)
    >>> r = Readings(np.arange(4.0), np.zeros(4, np.int32), z, z, z, np.full(4, 1.0), ("s",))
    >>> grid = Grid(resolution=0.1, origin=(-0.5, -1.0), shape=(20, 20))
    >>> m = ThrunEMMapper().fit(r, grid, get_rig("paper-synthetic").sensor)
    >>> bool(np.nanmax(m.binary_map_) == 1.0), m.loglik_[-1] >= m.loglik_[0]
    (True, True)
    """

    name = "em-thrun"
    offset_cells = 0.25

    def __init__(
        self,
        *,
        p_rand: float = 0.1,
        p_hit: float = 0.75,
        sigma: float | None = 0.05,
        band_offset: float | None = None,
        init: str = "free",
        max_iter: int = 50,
        prior: float = 0.5,
        correlated: float = 0.0,
    ) -> None:
        self.p_rand = p_rand
        self.p_hit = p_hit
        self.sigma = sigma
        self.band_offset = band_offset
        self.init = init
        self.max_iter = max_iter
        self.prior = prior
        self.correlated = correlated
        number("p_rand", p_rand, 0.0, 1.0, lo_open=True, hi_open=True)
        number("p_hit", p_hit, 0.0, 1.0, lo_open=True, hi_open=True)
        if sigma is not None:
            number("sigma", sigma, 0.0, None, lo_open=True)
        if band_offset is not None:
            number("band_offset", band_offset, 0.0, None)
        choice("init", init, ("free", "inverse"))
        integer("max_iter", max_iter, 1)
        number("prior", prior, 0.0, 1.0, lo_open=True, hi_open=True)
        number("correlated", correlated, 0.0, None)

    def _reset(self) -> None:
        self._index: BeamIndex | None = None
        self._occ: B | None = None
        self._post: F64 | None = None
        self.loglik_: list[float] = []
        self.expected_loglik_: list[float] = []
        self.flips_: list[int] = []
        self.n_iter_ = 0
        self.outlier_prob_: F64 = np.empty(0)

    def _add(self, readings: Readings, progress: Progress | None) -> None:
        everything = self._accumulate(readings)
        # The weights' mean 1: a flip's sign does not see a common scale, but the final
        # posterior's log-odds grow with it against the prior's (and the gains against
        # MIN_GAIN); mean 1 gives the data the weight of as many readings as there are.
        sigma, ix, weight = model_inputs(self, everything, self.sigma, self.correlated)
        r_max = self.sensor.r_max
        occ = self._initial_map(everything, ix)
        model = (self.p_rand, self.p_hit, sigma, r_max)
        beams = (ix.free_off, ix.free_cell, ix.band_off, ix.band_cell, ix.band_dist, ix.z)
        state = init_state(occ, *beams, *model)
        # The M-step: one hill-climbing sweep over every cell in index order.
        cells = np.arange(ix.n_cells, dtype=np.int64)
        arrays = ix.posterior_arrays()
        # The sweep's out array for each cell's odds, not read here (the posterior is
        # taken once after the last sweep, with every cell held at the final map):
        # allocated once, each sweep overwrites it.
        odds = np.empty(ix.n_cells)
        self.loglik_, self.expected_loglik_, self.flips_ = [], [], []
        k = 0
        for k in range(1, self.max_iter + 1):
            q, ll, _ = _e_step(occ, *beams, *model, weight)
            self.expected_loglik_.append(q)
            self.loglik_.append(ll)
            flips = sweep(cells, occ, state, arrays, model, weight, None, odds, MIN_GAIN)
            self.flips_.append(flips)
            if progress is not None:
                progress(k, self.max_iter)
            if flips == 0:
                break
        q, ll, outlier = _e_step(occ, *beams, *model, weight)
        self.expected_loglik_.append(q)
        self.loglik_.append(ll)
        self.n_iter_ = k
        self.outlier_prob_ = outlier
        self._post = held_posterior(occ, ix, model, weight, self.prior)
        self._occ = occ
        self._index = ix

    def _initial_map(self, readings: Readings, ix: BeamIndex) -> B:
        """Every touched cell free, or the inverse mapper's map binarised at 0.5."""
        if self.init == "free":
            return np.zeros(ix.n_cells, dtype=np.bool_)
        from .inverse import InverseMapper

        inv = InverseMapper().fit(readings, self.grid, self.sensor).occupancy_.ravel()
        return np.asarray(np.nan_to_num(inv[ix.cells], nan=0.0) > 0.5, dtype=np.bool_)

    @property
    def binary_map_(self) -> npt.NDArray[np.float32]:
        values = None if self._occ is None else self._occ.astype(np.float64)
        return scatter(self._index, values, self.grid.size).reshape(self.grid.shape)

    def _occupancy(self) -> npt.NDArray[np.float32]:
        return scatter(self._index, self._post, self.grid.size)


@nb.njit(cache=True)
def _climb(
    cand: I64,
    occ: B,
    state: tuple[I64, F64, F64],
    index_arrays: IndexArrays,
    model: tuple[float, float, float, float],
    max_sweeps: int,
    bias: F64,
    log_odds: F64,
) -> int:
    """Hill-climbing sweeps of the M-step over the local cells ``cand`` only, in their
    order, until a sweep flips none or ``max_sweeps`` have run. ``bias`` (per local
    cell) is a fixed log-likelihood ratio of occupied to free added to each cell's: the
    readings that have left the stream. Returns the flips made.

    Each candidate's log posterior odds with the other cells held go to ``log_odds``
    (aligned with ``cand``) as the last sweep found them: a cell's odds do not depend
    on its own state, only on the other cells', which that sweep may still have
    changed after it; a second pass for the exact odds would double the work.
    """
    flips = 0
    for _ in range(max_sweeps):
        made = sweep(cand, occ, state, index_arrays, model, None, bias, log_odds, MIN_GAIN)
        flips += made
        if made == 0:
            break
    return flips


@nb.njit(cache=True)
def _band_sum_at(
    a: int,
    n: int,
    cell: npt.NDArray[np.int32],
    dist: npt.NDArray[np.float32],
    offset: float,
    occ: B,
    flip: int,
    zi: float,
    p_hit: float,
    sigma: float,
    r_max: float,
) -> float:
    """:func:`~._thrun.band_sum` of one reading read straight from a store's arena (its
    band entries ``a .. a + n``, sorted by distance) against the whole grid's ``occ``,
    the grid cell ``flip`` (or -1) read inverted."""
    norm = 1.0 / (sigma * math.sqrt(2.0 * math.pi))
    miss = 1.0 - p_hit
    k = 0
    total = 0.0
    for j in range(a, a + n):
        c = cell[j]
        state = occ[c]
        if c == flip:
            state = not state
        if state:
            u = (zi - (float(dist[j]) - offset)) / sigma
            total += norm * math.exp(-0.5 * u * u) * p_hit * miss**k
            k += 1
    u = (zi - r_max) / sigma
    return total + norm * math.exp(-0.5 * u * u) * miss**k


@nb.njit(cache=True)
def _fold_readings(
    gone: I64,
    f_start: I64,
    f_len: I64,
    o_start: I64,
    o_len: I64,
    cell: npt.NDArray[np.int32],
    dist: npt.NDArray[np.float32],
    z: F64,
    offset: float,
    occ: B,
    p_rand: float,
    p_hit: float,
    sigma: float,
    r_max: float,
    bias: F64,
) -> None:
    """Add to ``bias`` each reading of ``gone``'s log-likelihood ratio of occupied to
    free for every cell of its beam, the rest of the map held at ``occ`` (the grid's).
    Read straight from the store, a reading at a time: the sum over the readings is
    what :func:`~._thrun_common.posterior` gives over an index of them."""
    for s in gone:
        zi = z[s]
        n_before = 0
        for j in range(f_start[s], f_start[s] + f_len[s]):
            if occ[cell[j]]:
                n_before += 1
        a, n = o_start[s], o_len[s]
        bs = _band_sum_at(a, n, cell, dist, offset, occ, -1, zi, p_hit, sigma, r_max)
        ll = loglik_of(n_before, bs, p_rand, p_hit, r_max)
        for j in range(f_start[s], f_start[s] + f_len[s]):
            c = cell[j]
            if occ[c]:
                bias[c] += ll - loglik_of(n_before - 1, bs, p_rand, p_hit, r_max)
            else:
                bias[c] += loglik_of(n_before + 1, bs, p_rand, p_hit, r_max) - ll
        # A flip at band position j scales the terms after it by (1 - p_hit)^-+1: with
        # the sum of the occupied cells' terms before j and the total, each flip's band
        # sum costs O(1), not a pass over the band.
        norm = 1.0 / (sigma * math.sqrt(2.0 * math.pi))
        miss = 1.0 - p_hit
        u = (zi - r_max) / sigma
        tail = norm * math.exp(-0.5 * u * u)
        occupied = 0.0
        k = 0
        for j in range(a, a + n):
            if occ[cell[j]]:
                v = (zi - (float(dist[j]) - offset)) / sigma
                occupied += norm * math.exp(-0.5 * v * v) * p_hit * miss**k
                k += 1
        tail *= miss**k
        before = 0.0
        k = 0
        for j in range(a, a + n):
            c = cell[j]
            v = (zi - (float(dist[j]) - offset)) / sigma
            t = norm * math.exp(-0.5 * v * v) * p_hit * miss**k
            if occ[c]:
                flipped = before + (occupied - before - t + tail) / miss
                before += t
                k += 1
            else:
                flipped = before + t + miss * (occupied - before + tail)
            d = loglik_of(n_before, flipped, p_rand, p_hit, r_max) - ll
            bias[c] += -d if occ[c] else d


@nb.njit(cache=True)
def _store_index(
    sel: I64,
    f_start: I64,
    f_len: I64,
    o_start: I64,
    o_len: I64,
    cell: npt.NDArray[np.int32],
    dist: npt.NDArray[np.float32],
    offset: float,
    local: I64,
) -> tuple[I64, I64, I64, I64, F64, I64, I64, npt.NDArray[np.int8], I64, I64]:
    """The arrays of :func:`~._thrun.index_arrays` for the store's slots ``sel``, read
    straight from its arena (whose bands are kept sorted by distance): free offsets and
    cells, band offsets, cells and distances, then per cell its readings, their kinds
    and band positions, and the touched grid cells, sorted. ``local`` is a grid-sized
    scratch array of -1, left so."""
    n = sel.shape[0]
    free_off = np.zeros(n + 1, np.int64)
    band_off = np.zeros(n + 1, np.int64)
    for i in range(n):
        free_off[i + 1] = free_off[i] + f_len[sel[i]]
        band_off[i + 1] = band_off[i] + o_len[sel[i]]
    n_free, n_band = free_off[n], band_off[n]
    touched = np.empty(n_free + n_band, np.int64)
    k = 0
    for i in range(n):
        s = sel[i]
        for a, m in ((f_start[s], f_len[s]), (o_start[s], o_len[s])):
            for j in range(a, a + m):
                c = cell[j]
                if local[c] == -1:
                    local[c] = -2
                    touched[k] = c
                    k += 1
    cells = np.sort(touched[:k])
    for q in range(k):
        local[cells[q]] = q
    free_cell = np.empty(n_free, np.int64)
    band_cell = np.empty(n_band, np.int64)
    band_dist = np.empty(n_band)
    counts = np.zeros(k + 1, np.int64)
    for i in range(n):
        s = sel[i]
        for j in range(f_len[s]):
            c = local[cell[f_start[s] + j]]
            free_cell[free_off[i] + j] = c
            counts[c + 1] += 1
    for i in range(n):
        s = sel[i]
        for j in range(o_len[s]):
            e = o_start[s] + j
            c = local[cell[e]]
            band_cell[band_off[i] + j] = c
            band_dist[band_off[i] + j] = np.float64(dist[e]) - offset
            counts[c + 1] += 1
    cell_off = np.cumsum(counts)
    fill = cell_off[:-1].copy()
    cell_reading = np.empty(n_free + n_band, np.int64)
    cell_kind = np.empty(n_free + n_band, np.int8)
    cell_slot = np.empty(n_free + n_band, np.int64)
    for i in range(n):
        for j in range(free_off[i], free_off[i + 1]):
            c = free_cell[j]
            cell_reading[fill[c]] = i
            cell_kind[fill[c]] = 0
            cell_slot[fill[c]] = -1
            fill[c] += 1
    for i in range(n):
        for j in range(band_off[i], band_off[i + 1]):
            c = band_cell[j]
            cell_reading[fill[c]] = i
            cell_kind[fill[c]] = 1
            cell_slot[fill[c]] = j - band_off[i]
            fill[c] += 1
    for q in range(k):
        local[cells[q]] = -1
    return (
        free_off,
        free_cell,
        band_off,
        band_cell,
        band_dist,
        cell_off,
        cell_reading,
        cell_kind,
        cell_slot,
        cells,
    )


class ThrunEMStream(StreamEngine):
    """Thrun's EM over a bounded set of readings, the M-step on the touched cells.

    Each update indexes the readings in play that touch the cells the entering or
    leaving readings touch (their footprints are kept, so nothing is rasterised twice),
    computes those readings' causes under the current binary map (the E-step, exact for
    them, as every reading through a touched cell is indexed) and runs the offline
    M-step's hill-climbing sweeps over the touched cells only -- up to ``effort`` sweeps,
    fewer once a sweep flips nothing -- then gives each touched cell its posterior with
    the rest of the map held, as the offline fit does at its end. A cell no reading in
    play touches keeps its last state and posterior. New cells start free, as the
    offline ``init="free"`` does (``init="inverse"`` is refused: it needs every reading).
    """

    sort_band = True
    can_fold = True

    def _setup(self) -> None:
        m = self.mapper
        assert isinstance(m, ThrunEMMapper)
        if m.init != "free":
            raise ConfigError(
                "streaming 'em-thrun' starts every new cell free; set init=free "
                "(init=inverse needs every reading at once)"
            )
        m.attach(self.grid, self.sensor)
        self.sigma = model_sigma(m, m.sigma)
        self.dr = 3.0 * self.sigma
        self.occ = np.zeros(self.grid.size, np.bool_)
        self.post = np.full(self.grid.size, m.prior)
        #: Per cell, the log-likelihood ratio (occupied to free) of the readings that
        #: have left, each taken with the rest of the map as it was when it left.
        self.bias = np.zeros(self.grid.size)
        self._local = np.full(self.grid.size, -1, np.int64)
        self.flips_ = 0

    def _leave(self, gone: I64) -> None:
        # A reading that leaves keeps voting on the cells of its beam, but no longer
        # jointly: its vote on each cell is fixed at the map of the moment it leaves
        # (each cell's flip with the others held, as in the final posterior). Without
        # it a wall's cells lose their echoes when those leave, and the long no-echo
        # beams still in play clear them.
        if len(gone) == 0 or not self.fold:
            return
        m = self.mapper
        assert isinstance(m, ThrunEMMapper)
        p = self.pool
        _fold_readings(
            gone,
            p.f_start,
            p.f_len,
            p.o_start,
            p.o_len,
            p.cell,
            p.dist,
            p.z,
            self.offset,
            self.occ,
            m.p_rand,
            m.p_hit,
            self.sigma,
            self.sensor.r_max,
            self.bias,
        )

    def index(self, sel: I64) -> BeamIndex:
        """The beam index of the slots ``sel`` of the store (local cells in grid order),
        as :func:`~._thrun.index_arrays` builds it from their gathered entries."""
        p = self.pool
        a = _store_index(
            sel, p.f_start, p.f_len, p.o_start, p.o_len, p.cell, p.dist, self.offset, self._local
        )
        return BeamIndex(*a[:9], z=p.z[sel].astype(np.float64), cells=a[9])

    def _optimise(self, dirty: I64, box: tuple[int, int, int, int]) -> None:
        live = dirty[self.cov[dirty] > 0]
        if len(live) == 0:
            return
        self._climb(self.touching_dirty(box), live, self.effort)

    def _climb(self, sel: I64, cells: I64, sweeps: int) -> None:
        """Sweep ``cells`` (grid indices, each touched by a reading of ``sel``) against
        the readings ``sel``, which must hold every reading in play through them."""
        m = self.mapper
        assert isinstance(m, ThrunEMMapper)
        ix = self.index(sel)
        cand = np.searchsorted(ix.cells, cells).astype(np.int64)
        occ = self.occ[ix.cells]
        model = (m.p_rand, m.p_hit, self.sigma, self.sensor.r_max)
        beams = (ix.free_off, ix.free_cell, ix.band_off, ix.band_cell, ix.band_dist, ix.z)
        state = init_state(occ, *beams, *model)
        log_odds = np.empty(len(cand))
        arrays = ix.posterior_arrays()
        self.flips_ += _climb(
            cand, occ, state, arrays, model, sweeps, self.bias[ix.cells], log_odds
        )
        self.occ[cells] = occ[cand]
        self.post[cells] = probability(log_odds, m.prior)

    def improve(self, budget: float) -> int:
        """One M-step sweep at a time over every cell in play, for up to ``budget`` s."""
        return self._improve_with(budget, lambda sel, cells: self._climb(sel, cells, 1))

    def occupancy(self) -> npt.NDArray[np.float32]:
        return self._seen_only(self.post)

    def nbytes(self) -> int:
        own = (self.occ, self.post, self.bias, self._local)
        return super().nbytes() + sum(int(a.nbytes) for a in own)


ThrunEMMapper.streamer = ThrunEMStream
