"""Parameter handling and the posterior kernel shared by the two mappers of Thrun's model."""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt

from ..readings import Readings
from ._base import Mapper
from ._correlated import reading_weights
from ._thrun import BeamIndex, build_index, flip_delta, init_state

__all__ = [
    "held_posterior",
    "index_readings",
    "model_inputs",
    "model_sigma",
    "posterior",
    "probability",
    "scatter",
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
    index: BeamIndex, values: npt.NDArray[np.float64], size: int
) -> npt.NDArray[np.float32]:
    """Local cell values onto a flat grid, NaN elsewhere."""
    out = np.full(size, np.nan, dtype=np.float32)
    out[index.cells] = values
    return out


@nb.njit(cache=True)
def posterior(
    occ: npt.NDArray[np.bool_],
    index_arrays: tuple[I64, I64, I64, I64, F64, I64, I64, npt.NDArray[np.int8], F64],
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
    (free_off, free_cell, band_off, band_cell, band_dist, cell_off, cell_reading, cell_kind, z) = (
        index_arrays
    )
    n_before, bsum, loglik = init_state(
        occ, free_off, free_cell, band_off, band_cell, band_dist, z, p_rand, p_hit, sigma, r_max
    )
    max_deg = 1
    for c in range(occ.shape[0]):
        max_deg = max(max_deg, cell_off[c + 1] - cell_off[c])
    new_ll = np.empty(max_deg)
    new_b = np.empty(max_deg)
    out = np.empty(occ.shape[0])
    for c in range(occ.shape[0]):
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
        out[c] = -d if occ[c] else d
    return out
