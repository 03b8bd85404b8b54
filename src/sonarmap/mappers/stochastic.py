"""Thrun's probabilistic forward model solved by random bit flips (Shepelev 2016).

The map is binary. Its score (to maximise) is

    Phi = sum_t log p(z_t | m) + w_occ * (occupied cells) + w_border * sum_i n_i^2,

n_i the number of 4- (or 8-) neighbours whose state differs from cell i (methods.md
section 3). A random cell among those some beam holds is flipped; the flip is kept if
Phi grew, otherwise with probability ``p_randomfactor`` (``schedule="greedy"``, the
thesis' rule) or ``exp(dPhi / T)`` with T falling geometrically from ``t0`` to ``t_end``
(``schedule="anneal"``). Each flip recomputes only the terms it changes. The search is
deterministic for a given ``seed``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..readings import Readings
from ..sensors import SensorModel
from ._base import Mapper, Progress, register
from ._checks import choice, integer, number
from ._stream import StreamEngine
from ._thrun import BeamIndex, apply_flip, flip_delta, index_arrays, init_state
from ._thrun_common import model_inputs, model_sigma, scatter

__all__ = ["StochasticMapper"]

#: Parameter sets: ``tuned`` (with ``sigma=0.08`` and 8 neighbours, the defaults) had the
#: highest mean quality (wall F1 and passage F1 together) in ``sonarmap sweep
#: sweeps/tune.yaml``: its defaults and 60 settings of p_rand, p_hit, w_occ, w_border,
#: sigma and neighbourhood, on the ten training scenes every method was tuned on: 0.352
#: (runner-up 0.338). It costs about 18 s a map there; ``sigma=0.05`` scored 0.337 in
#: 7 s. With the band 0.75 of a cell behind the echo (the default ``band_offset``) it
#: scored 0.371 in ``sonarmap sweep sweeps/band.yaml`` (0, 0.5 and 0.75 of a cell).
#: The documents' sets: thesis 000, and thesis 002 section 4.5.
PRESETS: dict[str, dict[str, float]] = {
    "tuned": {"p_rand": 0.05, "p_hit": 0.3, "w_occ": 0.0, "w_border": -0.005},
    "thesis000": {"p_rand": 0.05, "p_hit": 0.75, "w_occ": -0.05, "w_border": -0.005},
    "thesis002": {"p_rand": 0.001, "p_hit": 0.35, "w_occ": -0.25, "w_border": -0.05},
}

#: The method's named parameter sets (``--preset``), as printed: thesis 000's weights
#: with its rule of never keeping a worse flip (p_randomfactor 0); thesis 002's weights
#: (section 4.4.2, set (4.5)) with its range limit R_max = 3.5 m and its border count
#: over cell edges (4 neighbours); both with the band on the echo, as the documents have
#: it. What they leave unset stays sonarmap's.
METHOD_PRESETS: dict[str, dict[str, Any]] = {
    "thesis000": {
        **PRESETS["thesis000"],
        "schedule": "greedy",
        "p_randomfactor": 0.0,
        "band_offset": 0.0,
    },
    "thesis002": {**PRESETS["thesis002"], "r_max": 3.5, "neighbours": 4, "band_offset": 0.0},
}


@nb.njit(cache=True)
def _border_delta(g: int, full: npt.NDArray[np.bool_], rows: int, cols: int, eight: bool) -> int:
    """Change of sum n_i^2 over g and its neighbours if grid cell g flips."""
    r0 = g // cols
    c0 = g % cols
    delta = 0
    for dr in range(-1, 2):
        for dc in range(-1, 2):
            r = r0 + dr
            c = c0 + dc
            if r < 0 or r >= rows or c < 0 or c >= cols:
                continue
            if not eight and dr != 0 and dc != 0:
                continue
            h = r * cols + c
            # n before and after the flip, for cell h (g itself or a neighbour).
            before = 0
            after = 0
            for er in range(-1, 2):
                for ec in range(-1, 2):
                    if er == 0 and ec == 0:
                        continue
                    if not eight and er != 0 and ec != 0:
                        continue
                    rr = r + er
                    cc = c + ec
                    if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                        continue
                    k = rr * cols + cc
                    sh = full[h]
                    sk = full[k]
                    if sh != sk:
                        before += 1
                    sh2 = (not sh) if h == g else sh
                    sk2 = (not sk) if k == g else sk
                    if sh2 != sk2:
                        after += 1
            delta += after * after - before * before
    return delta


@nb.njit(cache=True)
def _search(
    occ: npt.NDArray[np.bool_],
    full: npt.NDArray[np.bool_],
    cells: npt.NDArray[np.int64],
    cand: npt.NDArray[np.int64],
    rows: int,
    cols: int,
    eight: bool,
    free_off: npt.NDArray[np.int64],
    free_cell: npt.NDArray[np.int64],
    band_off: npt.NDArray[np.int64],
    band_cell: npt.NDArray[np.int64],
    band_dist: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64],
    cell_off: npt.NDArray[np.int64],
    cell_reading: npt.NDArray[np.int64],
    cell_kind: npt.NDArray[np.int8],
    p_rand: float,
    p_hit: float,
    sigma: float,
    r_max: float,
    w_occ: float,
    w_border: float,
    n_flips: int,
    anneal: bool,
    p_random: float,
    t0: float,
    t_end: float,
    seed: int,
    weight: npt.NDArray[np.float64] | None = None,
) -> tuple[int, float]:
    # numba keeps its own generator per thread; seeding it here makes the search
    # deterministic. NumPy's Generator objects are not what runs inside the kernel.
    np.random.seed(seed)  # noqa: NPY002
    n_before, bsum, loglik = init_state(
        occ, free_off, free_cell, band_off, band_cell, band_dist, z, p_rand, p_hit, sigma, r_max
    )
    max_deg = 0
    for c in range(cells.shape[0]):
        max_deg = max(max_deg, cell_off[c + 1] - cell_off[c])
    new_ll = np.empty(max(max_deg, 1))
    new_bsum = np.empty(max(max_deg, 1))
    accepted = 0
    n = cand.shape[0]
    for k in range(n_flips):
        c = cand[np.random.randint(0, n)]  # noqa: NPY002
        d = flip_delta(
            c,
            occ,
            n_before,
            bsum,
            loglik,
            new_ll,
            new_bsum,
            cell_off,
            cell_reading,
            cell_kind,
            band_off,
            band_cell,
            band_dist,
            z,
            p_rand,
            p_hit,
            sigma,
            r_max,
            weight,
        )
        d += w_occ * (-1.0 if occ[c] else 1.0)
        if w_border != 0.0:
            d += w_border * _border_delta(cells[c], full, rows, cols, eight)
        keep = d > 0.0
        if not keep:
            u = np.random.random()  # noqa: NPY002
            if anneal:
                t = t0 * (t_end / t0) ** (k / n_flips)
                keep = u < math.exp(d / t)
            else:
                keep = u < p_random
        if keep:
            apply_flip(
                c, occ, n_before, bsum, loglik, new_ll, new_bsum, cell_off, cell_reading, cell_kind
            )
            full[cells[c]] = occ[c]
            accepted += 1
    if weight is not None:
        return accepted, (weight * loglik).sum()
    return accepted, loglik.sum()


@register
class StochasticMapper(Mapper):
    """Binary map maximising Thrun's likelihood with shape priors, by random flips.

    Parameters
    ----------
    preset : {"tuned", "thesis000", "thesis002"}
        Parameter set the unset parameters come from: ``tuned`` (p_rand 0.05, p_hit 0.3,
        w_occ 0, w_border -0.005; see :data:`PRESETS`), thesis 000 (0.05, 0.75, -0.05,
        -0.005) or thesis 002 (0.001, 0.35, -0.25, -0.05). The method's presets
        (:data:`METHOD_PRESETS`, ``--preset`` on the command line) set these weights and
        the rest of each document's set (thesis 002: ``r_max`` 3.5, 4 neighbours).
    p_rand, p_hit : float or None
        Outlier probability in [0, 1) and per-cell reflection probability in (0, 1).
    w_occ, w_border : float or None
        Weights of the occupied-cell count and of the border term (<= 0 favours free
        space and compact obstacles).
    sigma : float or None
        Range noise of the model, metres (0.08); None: half a cell or the sensor's range
        resolution, whichever is larger.
    band_offset : float or None
        How far behind the echo the surface's cells lie, metres (>= 0): a cell at
        distance d explains a range of d - offset; None (default): 0.75 of a cell.
        See :mod:`sonarmap.raster` for why.
    r_max : float or None
        Range limit of the model, metres: readings at or beyond it count as no echo
        (their beam free up to it); None (default): the sensor's. Thesis 002 used 3.5.
    neighbours : {4, 8}
        Neighbourhood of the border term (8).
    sweeps : float
        Flips proposed, in multiples of the number of candidate cells (30).
    schedule : {"anneal", "greedy"}
        Acceptance of flips that do not increase Phi: by a falling temperature (default),
        or with ``p_randomfactor`` as in the thesis. Over three seeds of the noisy
        ``passages`` and the ``room-turn`` scenes, annealing ended with a higher
        log-likelihood and a higher F1 in all six runs, for about 20 % more time.
    p_randomfactor : float
        Probability of keeping a flip that does not increase Phi (greedy), in [0, 1].
    t0, t_end : float
        Start and end temperature of ``anneal``.
    init : {"free", "occupied"}
        Starting map.
    seed : int
        Random seed.
    correlated : float
        Down-weighting of correlated readings (Konolige 1997), metres; 0 (default) is off.
        With c > 0 the n readings of one sonar from poses in the same c-metre bin (and
        10-degree heading bin) with ranges in the same c-metre bin each weigh 1 / n (see
        :func:`~sonarmap.mappers._correlated.correlation_weights`), scaled to mean 1, and
        Phi's log-likelihood is ``sum_t w_t log p(z_t | m)`` (``loglik_`` too). Offline
        only: streaming refuses it (see :mod:`sonarmap.mappers._stream`). Off by default: in
        ``sonarmap sweep sweeps/correlated.yaml`` (bins of 2, 5, 10 and 20 cm, the ten
        training scenes) off scored 0.371 and 5 cm 0.376, a tie for a random search; 2, 10
        and 20 cm 0.361-0.364.
    """

    name = "stochastic"
    offset_cells = 0.75
    presets = METHOD_PRESETS

    def __init__(
        self,
        *,
        preset: str = "tuned",
        p_rand: float | None = None,
        p_hit: float | None = None,
        w_occ: float | None = None,
        w_border: float | None = None,
        sigma: float | None = 0.08,
        band_offset: float | None = None,
        r_max: float | None = None,
        neighbours: int = 8,
        sweeps: float = 30.0,
        schedule: str = "anneal",
        p_randomfactor: float = 0.0,
        t0: float = 2.0,
        t_end: float = 0.01,
        init: str = "free",
        seed: int = 0,
        correlated: float = 0.0,
    ) -> None:
        self.preset = preset
        self.p_rand = p_rand
        self.p_hit = p_hit
        self.w_occ = w_occ
        self.w_border = w_border
        self.sigma = sigma
        self.band_offset = band_offset
        self.r_max = r_max
        self.neighbours = neighbours
        self.sweeps = sweeps
        self.schedule = schedule
        self.p_randomfactor = p_randomfactor
        self.t0 = t0
        self.t_end = t_end
        self.init = init
        self.seed = seed
        self.correlated = correlated
        choice("preset", preset, tuple(PRESETS))
        v = self.values()
        number("p_rand", v["p_rand"], 0.0, 1.0, hi_open=True)
        number("p_hit", v["p_hit"], 0.0, 1.0, lo_open=True, hi_open=True)
        number("w_occ", v["w_occ"])
        number("w_border", v["w_border"])
        if sigma is not None:
            number("sigma", sigma, 0.0, None, lo_open=True)
        if band_offset is not None:
            number("band_offset", band_offset, 0.0, None)
        if r_max is not None:
            number("r_max", r_max, 0.0, None, lo_open=True)
        if neighbours not in (4, 8):
            raise ConfigError(f"parameter 'neighbours' must be 4 or 8, got {neighbours!r}")
        number("sweeps", sweeps, 0.0, None)
        choice("schedule", schedule, ("greedy", "anneal"))
        number("p_randomfactor", p_randomfactor, 0.0, 1.0)
        number("t0", t0, 0.0, None, lo_open=True)
        number("t_end", t_end, 0.0, t0, lo_open=True)
        choice("init", init, ("free", "occupied"))
        integer("seed", seed, 0)
        number("correlated", correlated, 0.0, None)

    def _model(self, sensor: SensorModel) -> SensorModel:
        if self.r_max is None or self.r_max >= sensor.r_max:
            return sensor
        if self.r_max <= sensor.r_min:
            raise ConfigError(
                f"parameter 'r_max' ({self.r_max} m) must exceed the sensor's r_min "
                f"({sensor.r_min} m)"
            )
        return dataclasses.replace(sensor, r_max=self.r_max)

    def values(self) -> dict[str, float]:
        """The model weights in force: the preset's, overridden by those given."""
        out = dict(PRESETS[self.preset])
        for key in out:
            given = getattr(self, key)
            if given is not None:
                out[key] = given
        return out

    def _reset(self) -> None:
        self._occ: npt.NDArray[np.float64] | None = None
        self._index: BeamIndex | None = None
        self.accepted_ = 0
        self.loglik_ = float("nan")

    def _add(self, readings: Readings, progress: Progress | None) -> None:
        # The score couples every reading; batches accumulate and the search restarts
        # from the current map.
        everything = self._accumulate(readings)
        # The weights' mean 1: the log-likelihood is weighed against w_occ, w_border and
        # the annealing temperatures, all tuned with each reading counting once.
        sigma, index, weight = model_inputs(self, everything, self.sigma, self.correlated)
        full = np.zeros(self.grid.size, dtype=np.bool_)
        if self._occ is not None and self._index is not None:
            full[self._index.cells] = self._occ >= 0.5
        elif self.init == "occupied":
            full[index.cells] = True
        occ = full[index.cells].copy()
        n_flips = round(self.sweeps * index.n_cells)
        self.accepted_, self.loglik_ = self.search(
            index,
            occ,
            full,
            np.arange(index.n_cells, dtype=np.int64),
            sigma,
            n_flips,
            anneal=self.schedule == "anneal",
            seed=self.seed,
            weight=weight,
        )
        if progress is not None:
            progress(len(everything), len(everything))
        self._occ = occ.astype(np.float64)
        self._index = index

    def search(
        self,
        index: BeamIndex,
        occ: npt.NDArray[np.bool_],
        full: npt.NDArray[np.bool_],
        cand: npt.NDArray[np.int64],
        sigma: float,
        n_flips: int,
        *,
        anneal: bool,
        seed: int,
        weight: npt.NDArray[np.float64] | None = None,
    ) -> tuple[int, float]:
        """Propose ``n_flips`` flips of the ``cand`` cells (local indices) of ``index``.

        ``occ`` (per local cell) and ``full`` (the whole grid) hold the map and are
        updated in place; returns the flips accepted and the final log-likelihood
        (each reading's times its ``weight``, one per reading of ``index``, if given).
        """
        v = self.values()
        accepted, loglik = _search(
            occ,
            full,
            index.cells,
            cand,
            self.grid.rows,
            self.grid.cols,
            self.neighbours == 8,
            index.free_off,
            index.free_cell,
            index.band_off,
            index.band_cell,
            index.band_dist,
            index.z,
            index.cell_off,
            index.cell_reading,
            index.cell_kind,
            v["p_rand"],
            v["p_hit"],
            sigma,
            self.sensor.r_max,
            v["w_occ"],
            v["w_border"],
            n_flips,
            anneal,
            self.p_randomfactor,
            self.t0,
            self.t_end,
            seed,
            weight,
        )
        return int(accepted), float(loglik)

    @property
    def index_(self) -> BeamIndex | None:
        """The beam index of the readings last searched over; None before a fit."""
        return self._index

    @property
    def local_occupancy_(self) -> npt.NDArray[np.float64] | None:
        """The searched map (0 or 1) on the cells of :attr:`index_`, in its order; None
        before a fit."""
        return self._occ

    def _occupancy(self) -> npt.NDArray[np.float32]:
        return scatter(self._index, self._occ, self.grid.size)


class StochasticStream(StreamEngine):
    """Thrun's model by random flips, over a bounded set of readings.

    Each update indexes the readings in play that touch the cells the entering or
    leaving readings touch (their footprints are kept, so nothing is rasterised twice)
    and proposes ``effort`` sweeps of flips over those cells, every reading's
    likelihood computed over its whole beam from the current map. Flips are kept when
    the score grows, or with ``p_randomfactor`` (the thesis' rule): annealing from a
    high temperature would undo the map already built. New cells start free.
    """

    sort_band = True

    def _setup(self) -> None:
        m = self.mapper
        assert isinstance(m, StochasticMapper)
        m.attach(self.grid, self.sensor)
        self.sigma = model_sigma(m, m.sigma)
        self.dr = 3.0 * self.sigma
        self.full = np.zeros(self.grid.size, np.bool_)
        self.flips_ = 0
        self._searches = 0

    def _optimise(self, dirty: npt.NDArray[np.int64], box: tuple[int, int, int, int]) -> None:
        live = dirty[self.cov[dirty] > 0]
        if len(live) == 0:
            return
        sel = self.touching_dirty(box)
        self._search(sel, live)

    def _search(self, sel: npt.NDArray[np.int64], cells: npt.NDArray[np.int64]) -> None:
        m = self.mapper
        assert isinstance(m, StochasticMapper)
        p = self.pool
        f_cells, f_off, b_cells, b_dist, b_off = p.gather(sel)
        index = index_arrays(f_cells, f_off, b_cells, b_dist, b_off, p.z[sel], self.offset)
        cand = np.searchsorted(index.cells, cells).astype(np.int64)
        occ = self.full[index.cells].copy()
        n_flips = self.effort * len(cand)
        # A new stream of random numbers per search, the same for a given seed.
        m.search(
            index,
            occ,
            self.full,
            cand,
            self.sigma,
            n_flips,
            anneal=False,
            seed=m.seed + self._searches,
        )
        self._searches += 1
        self.flips_ += n_flips

    def improve(self, budget: float) -> int:
        return self._improve_with(budget, self._search)

    def occupancy(self) -> npt.NDArray[np.float32]:
        return self._seen_only(self.full)


StochasticMapper.streamer = StochasticStream
