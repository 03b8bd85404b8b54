"""Expectation maximisation with Thrun's forward sonar model (after Thrun 2003): ``em``.

sonarmap's own *relaxed* variant: each cell holds a continuous m_i in [0, 1] and
reflects with probability p_hit * m_i. Thrun 2003's EM over a *binary* map, where
every occupied cell reflects with probability p_hit, is ``em-thrun``
(:mod:`.em_thrun`); the two share the sonar model's code (:mod:`._thrun`).

The reference peer of the forward-model methods: the same probabilistic sonar model
as ``stochastic`` (methods.md sections 3-4), the map found by EM over the
correspondence variables -- which cell, if any, caused each reading -- then a per-cell
uncertainty.

Our derivation (the paper's full text was not available to us; its abstract and the
model of methods.md are what this follows): let cell i reflect with probability
p_hit * m_i, m_i in [0, 1] (for a binary map this is methods.md's model exactly). For a
reading z, the correspondence c is "random" (probability p_rand, density 1 / r_max),
"the n-th cell of the beam in distance order" (probability
(1 - p_rand) p_hit m_n prod_{k<n} (1 - p_hit m_k), density N(z; d_n, sigma)) or
"max range" (probability (1 - p_rand) prod_k (1 - p_hit m_k), density N(z; r_max, sigma)).

- E-step: the posterior e_t(c) of each reading's correspondence under the current map;
  for each cell, a_i = expected readings it caused, b_i = expected readings that passed
  it (caused by something farther, or max range).
- M-step: each cell maximises a_i log m_i + b_i log(1 - p_hit m_i), so
  m_i = min(1, a_i / (p_hit (a_i + b_i))).

EM never decreases the likelihood; it starts by default from every touched cell at
0.5 (the papers' neutral start), or from the inverse mapper's map (see ``init``). At
convergence the map is binarised at 0.5 and each
cell's uncertainty is its posterior with every other cell held at that map:
p(m_i = 1 | Z, m_-i) from the change of sum_t log p(z_t | m) when cell i flips.
``occupancy_`` holds this posterior; ``em_map_`` the EM estimate.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt

from ..readings import Readings
from ._base import Mapper, Progress, register
from ._checks import choice, integer, number
from ._thrun import BeamIndex
from ._thrun_common import held_posterior, model_inputs, scatter

__all__ = ["EMMapper"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@nb.njit(cache=True)
def _e_step(
    m: F64,
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
) -> tuple[F64, F64, float, F64]:
    """Expected hits a and passes b per cell, the log-likelihood of the data, and each
    reading's posterior probability of being an outlier.

    With ``weight`` (one per reading) each reading's share of a, b and the
    log-likelihood is its weight times what it would be; None compiles to weight 1."""
    n_cells = m.shape[0]
    hit = np.zeros(n_cells)
    pas = np.zeros(n_cells)
    log_norm = -math.log(sigma * math.sqrt(2.0 * math.pi))
    log_rand = math.log(p_rand / r_max) if p_rand > 0 else -np.inf
    log_keep = math.log(1.0 - p_rand)
    max_band = 1
    for i in range(z.shape[0]):
        max_band = max(max_band, band_off[i + 1] - band_off[i])
    loge = np.empty(max_band)
    outlier = np.empty(z.shape[0])
    total_ll = 0.0
    for i in range(z.shape[0]):
        wi = 1.0
        if weight is not None:
            wi = weight[i]
        log_t = 0.0
        for j in range(free_off[i], free_off[i + 1]):
            log_t += math.log1p(-p_hit * m[free_cell[j]])
        nb_ = band_off[i + 1] - band_off[i]
        run = log_t
        for q in range(nb_):
            j = band_off[i] + q
            mc = m[band_cell[j]]
            u = (z[i] - band_dist[j]) / sigma
            if mc > 0.0:
                loge[q] = log_keep + log_norm - 0.5 * u * u + math.log(p_hit * mc) + run
            else:
                loge[q] = -np.inf
            run += math.log1p(-p_hit * mc)
        u = (z[i] - r_max) / sigma
        log_max = log_keep + log_norm - 0.5 * u * u + run
        top = max(log_rand, log_max)
        for q in range(nb_):
            top = max(top, loge[q])
        s = math.exp(log_rand - top) + math.exp(log_max - top)
        for q in range(nb_):
            s += math.exp(loge[q] - top)
        log_z = top + math.log(s)
        total_ll += wi * log_z
        e_rand = math.exp(log_rand - log_z)
        outlier[i] = e_rand
        e_max = math.exp(log_max - log_z)
        beyond = e_max
        for q in range(nb_ - 1, -1, -1):
            j = band_off[i] + q
            e = math.exp(loge[q] - log_z)
            pas[band_cell[j]] += wi * beyond
            hit[band_cell[j]] += wi * e
            beyond += e
        # ``beyond`` now holds the posterior of every non-random cause, summed from its
        # terms: ``1 - e_rand`` would round to 0 when chance explains the reading almost
        # surely, and the free part would never learn it is free (a false fixed point).
        for j in range(free_off[i], free_off[i + 1]):
            pas[free_cell[j]] += wi * beyond
    return hit, pas, total_ll, outlier


@register
class EMMapper(Mapper):
    """Maximum-likelihood map by EM over the correspondences of Thrun's sonar model,
    relaxed to a continuous map (``em``); Thrun 2003's binary map is ``em-thrun``.

    Defaults (p_rand 0.1, p_hit 0.75, sigma 0.03, the neutral start) had the highest
    mean quality (wall F1 and passage F1 together) in ``sonarmap sweep
    sweeps/tune.yaml``: its defaults and 60 settings of p_rand, p_hit, sigma, start and
    prior, on the ten training scenes every method was tuned on (0.445; the runner-up,
    which starts from the inverse map, 0.438). With the band a quarter of a cell behind
    the echo it had the highest in ``sonarmap sweep sweeps/band.yaml`` (offsets 0-1
    cell, sigma and p_hit): 0.494 against 0.464 unmoved (after the E-step fix). p_hit
    0.3 had the highest quality (the geometric mean of wall F1, passage F1 and
    observed-wall recall) in ``sonarmap sweep sweeps/rigs.yaml`` (issue 39: p_hit 0.3,
    0.5 and 0.75 on training scenes mapped by six MaxSonar EZ1s, six HC-SR04s and a
    ring of 16 Polaroid sonars): 0.282 against 0.247 for both others. An acoustic
    sonar's beam passing a smooth wall at a slant is mostly mirrored away, so a wall
    reflects far less often than 0.75.

    Parameters
    ----------
    p_rand : float
        Outlier probability, in [0, 1) (0.1; thesis 000 used 0.05).
    p_hit : float
        Reflection probability of an occupied cell, in (0, 1) (0.3; thesis 000 used 0.75).
    sigma : float or None
        Range noise of the model, metres (0.03); None: half a cell or the sensor's range
        resolution, whichever is larger.
    band_offset : float or None
        How far behind the echo the surface's cells lie, metres (>= 0): a cell at
        distance d explains a range of d - offset; None (default): a quarter of a cell.
        See :mod:`sonarmap.raster` for why.
    init : {"inverse", "uniform"}
        Starting map: every touched cell at ``init_value`` (the neutral start, default)
        or the inverse mapper's map binarised (occupied cells at 0.9, the rest at 0.01).
    init_value : float
        Starting occupancy for ``init="uniform"``, in (0, 1].
    max_iter : int
        EM iterations at most.
    tol : float
        Stop when no cell's occupancy changes by more than this.
    prior : float
        Prior occupancy probability used for the final per-cell posterior, in (0, 1).
    correlated : float
        Down-weighting of correlated readings (Konolige 1997), metres; 0 (default) is off.
        With c > 0 the n readings of one sonar from poses in the same c-metre bin (and
        10-degree heading bin) with ranges in the same c-metre bin each weigh 1 / n (see
        :func:`~sonarmap.mappers._correlated.correlation_weights`), scaled to mean 1, and EM
        maximises the weighted log-likelihood ``sum_t w_t log p(z_t | m)``: each reading's
        expected hits and passes in the E-step count w_t times, and so does its
        log-likelihood in the final posterior. Off by default: in ``sonarmap sweep
        sweeps/correlated.yaml`` (bins of 2, 5, 10 and 20 cm, the ten training scenes) off
        scored 0.494 and 5 cm 0.499, a tie (one noisy doorways scene made the difference),
        2 cm 0.494 and 10 to 20 cm 0.46-0.48.

    Attributes
    ----------
    em_map_ : ndarray of float32, shape ``grid.shape``
        The EM estimate m, NaN where untouched (NaN everywhere before a fit).
    loglik_ : list of float
        Log-likelihood of the data at each iteration (non-decreasing); with
        ``correlated``, the weighted log-likelihood EM maximises.
    outlier_prob_ : ndarray
        Per reading, the posterior probability that the random component caused it.
    n_iter_ : int
    """

    name = "em"
    offset_cells = 0.25

    def __init__(
        self,
        *,
        p_rand: float = 0.1,
        p_hit: float = 0.3,
        sigma: float | None = 0.03,
        band_offset: float | None = None,
        init: str = "uniform",
        init_value: float = 0.5,
        max_iter: int = 100,
        tol: float = 1e-3,
        prior: float = 0.5,
        correlated: float = 0.0,
    ) -> None:
        self.p_rand = p_rand
        self.p_hit = p_hit
        self.sigma = sigma
        self.band_offset = band_offset
        self.init = init
        self.init_value = init_value
        self.max_iter = max_iter
        self.tol = tol
        self.prior = prior
        self.correlated = correlated
        number("p_rand", p_rand, 0.0, 1.0, hi_open=True)
        number("p_hit", p_hit, 0.0, 1.0, lo_open=True, hi_open=True)
        if sigma is not None:
            number("sigma", sigma, 0.0, None, lo_open=True)
        if band_offset is not None:
            number("band_offset", band_offset, 0.0, None)
        choice("init", init, ("inverse", "uniform"))
        number("init_value", init_value, 0.0, 1.0, lo_open=True)
        integer("max_iter", max_iter, 1)
        number("tol", tol, 0.0, None)
        number("prior", prior, 0.0, 1.0, lo_open=True, hi_open=True)
        number("correlated", correlated, 0.0, None)

    def _reset(self) -> None:
        self._index: BeamIndex | None = None
        self._m: F64 | None = None
        self._post: F64 | None = None
        self.loglik_: list[float] = []
        self.n_iter_ = 0
        self.outlier_prob_: F64 = np.empty(0)

    def _add(self, readings: Readings, progress: Progress | None) -> None:
        everything = self._accumulate(readings)
        # The weights' mean 1: the M-step's ratio a / (a + b) does not see a common
        # scale, but the final posterior's log-odds grow with it against the prior's;
        # mean 1 gives the data the weight of as many readings as there are.
        sigma, ix, weight = model_inputs(self, everything, self.sigma, self.correlated)
        r_max = self.sensor.r_max
        m = self._initial_map(everything, ix)
        self.loglik_ = []
        k = 0
        for k in range(1, self.max_iter + 1):
            hit, pas, ll, outlier = _e_step(
                m,
                ix.free_off,
                ix.free_cell,
                ix.band_off,
                ix.band_cell,
                ix.band_dist,
                ix.z,
                self.p_rand,
                self.p_hit,
                sigma,
                r_max,
                weight,
            )
            self.loglik_.append(ll)
            seen = hit + pas > 0
            new = m.copy()
            new[seen] = np.minimum(hit[seen] / (self.p_hit * (hit[seen] + pas[seen])), 1.0)
            change = float(np.max(np.abs(new - m))) if len(m) else 0.0
            m = new
            if progress is not None:
                progress(k, self.max_iter)
            if change <= self.tol:
                break
        self.n_iter_ = k
        self.outlier_prob_ = outlier
        model = (self.p_rand, self.p_hit, sigma, r_max)
        self._post = held_posterior(m >= 0.5, ix, model, weight, self.prior)
        self._m = m
        self._index = ix

    def _initial_map(self, readings: Readings, ix: BeamIndex) -> F64:
        """The starting map.

        ``uniform`` (the default, chosen by the sweep on training scenes): every touched
        cell at ``init_value``. In the relaxed model a touched cell at m reflects with
        probability p_hit * m, so a long beam through many cells at 0.5 is unlikely and
        the first E-step blames it on the random component almost surely; the tiny rest
        still tells the M-step which cells the beam crossed, and they clear.
        ``inverse`` starts from the inverse mapper's map, pushed to nearly free (0.01)
        and nearly occupied (0.9); experiments report both starts.
        """
        if self.init == "uniform":
            return np.full(ix.n_cells, self.init_value)
        from .inverse import InverseMapper

        inv = InverseMapper().fit(readings, self.grid, self.sensor).occupancy_.ravel()
        start = inv[ix.cells]
        return np.where(np.nan_to_num(start, nan=0.0) >= 0.5, 0.9, 0.01)

    @property
    def em_map_(self) -> npt.NDArray[np.float32]:
        return scatter(self._index, self._m, self.grid.size).reshape(self.grid.shape)

    def _occupancy(self) -> npt.NDArray[np.float32]:
        return scatter(self._index, self._post, self.grid.size)
