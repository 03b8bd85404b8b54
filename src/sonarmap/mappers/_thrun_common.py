"""What the mappers of Thrun's model (``em``, ``em-thrun``, ``stochastic``) share: their
inputs (range noise, beam index, reading weights), the sweep over cells that gives each
its log odds with the rest of the map held and flips it where that pays, the held
posterior, and the scatter of local cells onto the grid."""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt

from ..readings import Readings
from ._base import Mapper
from ._correlated import reading_weights
from ._thrun import BeamIndex, IndexArrays, apply_flip, build_index, flip_delta, init_state

__all__ = [
    "held_posterior",
    "index_readings",
    "model_inputs",
    "model_sigma",
    "posterior",
    "probability",
    "scatter",
    "sweep",
]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def model_sigma(mapper: Mapper, sigma: float | None) -> float:
    """The model's range noise: given, or half a cell or the sensor's range resolution,
    whichever is larger (a Gaussian narrower than a cell cannot be told apart on the
    grid). Never the noise a simulation used: that is not the mapper's to know."""
    if sigma is not None:
        return sigma
    return max(mapper.grid.resolution / 2, mapper.sensor.range_resolution)


def index_readings(mapper: Mapper, readings: Readings, sigma: float) -> BeamIndex:
    """Rasterise with a band of 3 sigma about the range moved by the mapper's
    ``band_offset``, and index the result (a cell at distance d then stands for a
    surface at d - offset)."""
    offset = mapper.band_offset_for(mapper.grid)
    fps = mapper.kept_footprints(readings, dr=3.0 * sigma, offset=offset)
    r = np.minimum(readings.range, mapper.sensor.r_max)
    return build_index(fps, np.asarray(r, dtype=np.float64), offset)


def model_inputs(
    mapper: Mapper, readings: Readings, sigma: float | None, correlated: float
) -> tuple[float, BeamIndex, F64 | None]:
    """What a mapper of the model fits ``readings`` with: the range noise
    (:func:`model_sigma` of ``sigma``), the index of the readings
    (:func:`index_readings`), and each reading's weight
    (:func:`~._correlated.reading_weights` with ``correlated``-metre bins, mean 1), or
    None when ``correlated`` is 0 (every reading counts once)."""
    sigma_m = model_sigma(mapper, sigma)
    index = index_readings(mapper, readings, sigma_m)
    weight = None
    if correlated > 0:
        weight = reading_weights(readings, correlated, mapper.sensor.r_max)
    return sigma_m, index, weight


def probability(log_odds: F64, prior: float) -> F64:
    """Occupancy probability from a log-likelihood ratio (occupied to free) and the
    prior occupancy probability ``prior``, in (0, 1)."""
    return np.asarray(
        0.5 * (1.0 + np.tanh(0.5 * (log_odds + math.log(prior / (1.0 - prior))))),
        dtype=np.float64,
    )


def held_posterior(
    occ: npt.NDArray[np.bool_],
    index: BeamIndex,
    model: tuple[float, float, float, float],
    weight: F64 | None,
    prior: float,
) -> F64:
    """Each local cell's occupancy probability with every other cell held at ``occ``:
    :func:`posterior` under ``model`` (p_rand, p_hit, sigma and r_max, as it takes
    them) and ``weight``, with the prior ``prior`` (see :func:`probability`)."""
    return probability(posterior(occ, index.posterior_arrays(), *model, weight), prior)


def scatter(
    index: BeamIndex | None, values: npt.NDArray[np.float64] | None, size: int
) -> npt.NDArray[np.float32]:
    """Local cell values onto a flat grid of ``size`` cells, NaN elsewhere; NaN
    everywhere when ``index`` or ``values`` is None (nothing fitted yet)."""
    out = np.full(size, np.nan, dtype=np.float32)
    if index is not None and values is not None:
        out[index.cells] = values
    return out


@nb.njit(cache=True)
def sweep(
    cand: I64,
    occ: npt.NDArray[np.bool_],
    state: tuple[I64, F64, F64],
    index_arrays: IndexArrays,
    model: tuple[float, float, float, float],
    weight: F64 | None,
    bias: F64 | None,
    log_odds: F64,
    min_gain: float,
) -> int:
    """One pass over the local cells ``cand``, in their order: each cell's log odds
    (occupied to free) with every other cell held, and a flip where it pays.

    Parameters
    ----------
    cand : ndarray of int64
        Local cells of the index to visit.
    occ : ndarray of bool, shape (cells,)
        The map (local cells); a flip changes it in place.
    state : tuple of ndarray
        :func:`~._thrun.init_state`'s per-reading bookkeeping for ``occ``, kept up to
        date by each flip.
    index_arrays : tuple of ndarray
        The beam index's arrays (:meth:`~._thrun.BeamIndex.posterior_arrays`).
    model : tuple of float
        p_rand, p_hit, sigma (metres) and r_max (metres).
    weight : ndarray of float or None
        Each reading's weight on its log-likelihood; None: 1 for all.
    bias : ndarray of float or None
        Per local cell, a fixed log-likelihood ratio (occupied to free) added to its
        odds; None: none.
    log_odds : ndarray of float, shape (len(cand),)
        Out: each candidate's log odds, aligned with ``cand``, as the pass found them.
    min_gain : float
        A cell flips when that raises the log-likelihood (with its bias) by more than
        this; ``inf``: no cell flips.

    Returns
    -------
    int
        The flips made.
    """
    band_off, band_cell, band_dist, cell_off, cell_reading, cell_kind, z = index_arrays[2:]
    n_before, bsum, loglik = state
    p_rand, p_hit, sigma, r_max = model
    max_deg = 1
    for c in cand:
        max_deg = max(max_deg, cell_off[c + 1] - cell_off[c])
    new_ll = np.empty(max_deg)
    new_b = np.empty(max_deg)
    flips = 0
    for k in range(cand.shape[0]):
        c = cand[k]
        d = flip_delta(
            c,
            occ,
            n_before,
            bsum,
            loglik,
            new_ll,
            new_b,
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
        odds = -d if occ[c] else d
        if bias is not None:
            odds += bias[c]
        log_odds[k] = odds
        if (-odds if occ[c] else odds) > min_gain:
            apply_flip(
                c, occ, n_before, bsum, loglik, new_ll, new_b, cell_off, cell_reading, cell_kind
            )
            flips += 1
    return flips


@nb.njit(cache=True)
def posterior(
    occ: npt.NDArray[np.bool_],
    index_arrays: IndexArrays,
    p_rand: float,
    p_hit: float,
    sigma: float,
    r_max: float,
    weight: F64 | None = None,
) -> F64:
    """Each cell's log posterior odds with every other cell held at ``occ``.

    Parameters
    ----------
    occ : ndarray of bool, shape (cells,)
        The map the other cells are held at (local cells of the index).
    index_arrays : tuple of ndarray
        The beam index's arrays: free and band offsets and cells, band distances
        (metres), each cell's readings and their kinds, and the ranges ``z`` (metres).
    p_rand, p_hit : float
        Thrun's model: probability of a random reading, and of a hit on an occupied
        cell.
    sigma : float
        Range noise (metres).
    r_max : float
        The sensor's maximum range (metres).
    weight : ndarray of float, optional
        Each reading's weight on its log-likelihood; default 1 for all.

    Returns
    -------
    ndarray of float, shape (cells,)
        log p(Z | m_i = 1, m_-i) - log p(Z | m_i = 0, m_-i) for every cell i.
    """
    free_off, free_cell, band_off, band_cell, band_dist = index_arrays[:5]
    z = index_arrays[8]
    state = init_state(
        occ, free_off, free_cell, band_off, band_cell, band_dist, z, p_rand, p_hit, sigma, r_max
    )
    n = occ.shape[0]
    out = np.empty(n)
    model = (p_rand, p_hit, sigma, r_max)
    sweep(np.arange(n), occ, state, index_arrays, model, weight, None, out, np.inf)
    return out
