"""Thrun's probabilistic sonar model on a grid (methods.md section 3), shared by the
stochastic search and EM.

For a reading z with the occupied cells of its beam sorted by distance d_1 < ... < d_K:

    p(z | m) = p_rand / r_max
             + (1 - p_rand) [ sum_k N(z; d_k, sigma) (1 - p_hit)^(k-1) p_hit
                              + N(z; r_max, sigma) (1 - p_hit)^K ]

N(z; d, sigma) is negligible for |z - d| > 3 sigma, so a reading only needs the number
of occupied cells nearer than z - 3 sigma (its Omega_free, with dr = 3 sigma) and the
states of the cells of its band [z - 3 sigma, z + 3 sigma] (its Omega_occ), kept sorted
by distance. Cells beyond the band only enter through the r_max term, which is
negligible for a reading with an echo; for a no-echo reading the whole beam is its
Omega_free. A flip of one cell therefore updates only the readings whose beam holds it,
found through a per-cell index.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
import numpy.typing as npt

from ..raster import Footprint

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]

#: A beam index's arrays in the order the kernels take them
#: (:meth:`BeamIndex.posterior_arrays`).
IndexArrays = tuple[I64, I64, I64, I64, F64, I64, I64, npt.NDArray[np.int8], F64]

KIND_FREE = 0
KIND_BAND = 1


@dataclass(frozen=True, eq=False)
class BeamIndex:
    """Readings and cells in both directions, over the touched cells (local indices).

    Attributes
    ----------
    free_off, free_cell : per reading, its Omega_free cells.
    band_off, band_cell, band_dist : per reading, its band cells sorted by distance.
    cell_off, cell_reading, cell_kind, cell_slot : per cell, the readings whose beam holds
        it, whether it is in their free part or band, and its position in their band.
    z : ranges; cells : flat grid index of each local cell.
    """

    free_off: I64
    free_cell: I64
    band_off: I64
    band_cell: I64
    band_dist: F64
    cell_off: I64
    cell_reading: I64
    cell_kind: npt.NDArray[np.int8]
    cell_slot: I64
    z: F64
    cells: I64

    @property
    def n_readings(self) -> int:
        return len(self.z)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    def posterior_arrays(self) -> IndexArrays:
        """The arrays :func:`._thrun_common.posterior` and :func:`._thrun_common.sweep`
        take, in their order: both directions of the index and ``z``."""
        return (
            self.free_off,
            self.free_cell,
            self.band_off,
            self.band_cell,
            self.band_dist,
            self.cell_off,
            self.cell_reading,
            self.cell_kind,
            self.z,
        )


def build_index(footprints: list[Footprint], ranges: F64, offset: float = 0.0) -> BeamIndex:
    """Index footprints rasterised with ``dr = 3 sigma`` (and ``offset``: each band
    cell's distance is taken ``offset`` nearer, where the surface it stands for is)."""
    f_cells = [fp.free.cells.astype(np.int64) for fp in footprints]
    f_off = _join_offsets([fp.free.offsets for fp in footprints])
    b_cells = [fp.occ.cells.astype(np.int64) for fp in footprints]
    b_dist = [fp.occ.distance.astype(np.float64) for fp in footprints]
    b_off = _join_offsets([fp.occ.offsets for fp in footprints])
    free_flat = np.concatenate(f_cells) if f_cells else np.empty(0, np.int64)
    band_flat = np.concatenate(b_cells) if b_cells else np.empty(0, np.int64)
    band_dist = np.concatenate(b_dist) if b_dist else np.empty(0)
    return index_arrays(free_flat, f_off, band_flat, band_dist, b_off, ranges, offset)


def index_arrays(
    free_flat: I64,
    f_off: I64,
    band_flat: I64,
    band_dist: F64,
    b_off: I64,
    ranges: F64,
    offset: float = 0.0,
) -> BeamIndex:
    """Index readings given as flat grid cells with CSR offsets (free part, then band).

    ``band_dist`` are the rasteriser's distances of the band cells; a band rasterised
    ``offset`` behind the echo has each cell stand for a surface ``offset`` nearer, and
    the index keeps that surface distance.
    """
    band_dist = band_dist - offset
    touched, local = np.unique(np.concatenate([free_flat, band_flat]), return_inverse=True)
    free_local = local[: len(free_flat)].astype(np.int64)
    band_local = local[len(free_flat) :].astype(np.int64)
    n = len(ranges)
    # Sort each reading's band by distance.
    band_reading = np.repeat(np.arange(n), np.diff(b_off))
    order = np.lexsort((band_dist, band_reading))
    band_local = band_local[order]
    band_dist = band_dist[order]
    # The transposed index: for each cell, (reading, kind, slot in the band).
    free_reading = np.repeat(np.arange(n), np.diff(f_off))
    slots = np.arange(len(band_local)) - np.repeat(b_off[:-1], np.diff(b_off))
    all_cell = np.concatenate([free_local, band_local])
    all_reading = np.concatenate([free_reading, band_reading])
    all_kind = np.concatenate(
        [np.full(len(free_local), KIND_FREE, np.int8), np.full(len(band_local), KIND_BAND, np.int8)]
    )
    all_slot = np.concatenate([np.full(len(free_local), -1, np.int64), slots])
    by_cell = np.argsort(all_cell, kind="stable")
    counts = np.bincount(all_cell, minlength=len(touched))
    cell_off = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return BeamIndex(
        free_off=f_off,
        free_cell=free_local,
        band_off=b_off,
        band_cell=band_local,
        band_dist=band_dist,
        cell_off=cell_off,
        cell_reading=all_reading[by_cell],
        cell_kind=all_kind[by_cell],
        cell_slot=all_slot[by_cell],
        z=np.asarray(ranges, dtype=np.float64),
        cells=touched.astype(np.int64),
    )


def _join_offsets(parts: list[I64]) -> I64:
    out = [np.zeros(1, np.int64)]
    base = 0
    for o in parts:
        out.append(o[1:].astype(np.int64) + base)
        base += int(o[-1])
    return np.concatenate(out)


@nb.njit(cache=True)
def band_sum(
    i: int,
    occ: npt.NDArray[np.bool_],
    flip: int,
    band_off: I64,
    band_cell: I64,
    band_dist: F64,
    z: F64,
    p_hit: float,
    sigma: float,
    r_max: float,
) -> float:
    """The bracket of p(z_i | m) for a reading with no occupied cell before its band,
    ``flip`` (a local cell index, or -1) read with its state inverted.

    With n occupied cells before the band the bracket is ``(1 - p_hit)**n`` times this,
    so a flip in a reading's free part costs O(1).
    """
    zi = z[i]
    norm = 1.0 / (sigma * math.sqrt(2.0 * math.pi))
    miss = 1.0 - p_hit
    k = 0
    total = 0.0
    for j in range(band_off[i], band_off[i + 1]):
        c = band_cell[j]
        state = occ[c]
        if c == flip:
            state = not state
        if state:
            u = (zi - band_dist[j]) / sigma
            total += norm * math.exp(-0.5 * u * u) * p_hit * miss**k
            k += 1
    u = (zi - r_max) / sigma
    total += norm * math.exp(-0.5 * u * u) * miss**k
    return total


@nb.njit(cache=True, inline="always")
def loglik_of(n_before: int, bsum: float, p_rand: float, p_hit: float, r_max: float) -> float:
    """log p(z | m) from the occupied count before the band and the band sum."""
    return math.log(p_rand / r_max + (1.0 - p_rand) * (1.0 - p_hit) ** n_before * bsum)


@nb.njit(cache=True)
def init_state(
    occ: npt.NDArray[np.bool_],
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
) -> tuple[I64, F64, F64]:
    """Per reading: occupied cells in the free part, band sum, log-likelihood."""
    n = z.shape[0]
    n_before = np.zeros(n, dtype=np.int64)
    bsum = np.empty(n)
    loglik = np.empty(n)
    for i in range(n):
        cnt = 0
        for j in range(free_off[i], free_off[i + 1]):
            if occ[free_cell[j]]:
                cnt += 1
        n_before[i] = cnt
        bsum[i] = band_sum(i, occ, -1, band_off, band_cell, band_dist, z, p_hit, sigma, r_max)
        loglik[i] = loglik_of(cnt, bsum[i], p_rand, p_hit, r_max)
    return n_before, bsum, loglik


@nb.njit(cache=True)
def flip_delta(
    c: int,
    occ: npt.NDArray[np.bool_],
    n_before: I64,
    bsum: F64,
    loglik: F64,
    new_ll: F64,
    new_bsum: F64,
    cell_off: I64,
    cell_reading: I64,
    cell_kind: npt.NDArray[np.int8],
    band_off: I64,
    band_cell: I64,
    band_dist: F64,
    z: F64,
    p_rand: float,
    p_hit: float,
    sigma: float,
    r_max: float,
    weight: F64 | None = None,
) -> float:
    """Change of sum_t log p(z_t | m) if cell ``c`` flips; the readings' new values go to
    ``new_ll`` and ``new_bsum`` (aligned with the cell's index entries).

    With ``weight`` (one per reading) the change of ``sum_t weight_t log p(z_t | m)``;
    None compiles to the unweighted sum."""
    delta = 0.0
    step = -1 if occ[c] else 1
    for e in range(cell_off[c], cell_off[c + 1]):
        i = cell_reading[e]
        k = e - cell_off[c]
        if cell_kind[e] == 0:
            new_bsum[k] = bsum[i]
            ll = loglik_of(n_before[i] + step, bsum[i], p_rand, p_hit, r_max)
        else:
            new_bsum[k] = band_sum(
                i, occ, c, band_off, band_cell, band_dist, z, p_hit, sigma, r_max
            )
            ll = loglik_of(n_before[i], new_bsum[k], p_rand, p_hit, r_max)
        new_ll[k] = ll
        d = ll - loglik[i]
        if weight is not None:
            d *= weight[i]
        delta += d
    return delta


@nb.njit(cache=True)
def apply_flip(
    c: int,
    occ: npt.NDArray[np.bool_],
    n_before: I64,
    bsum: F64,
    loglik: F64,
    new_ll: F64,
    new_bsum: F64,
    cell_off: I64,
    cell_reading: I64,
    cell_kind: npt.NDArray[np.int8],
) -> None:
    """Commit a flip whose new values ``flip_delta`` left in ``new_ll`` and ``new_bsum``."""
    step = -1 if occ[c] else 1
    for e in range(cell_off[c], cell_off[c + 1]):
        i = cell_reading[e]
        k = e - cell_off[c]
        if cell_kind[e] == 0:
            n_before[i] += step
        bsum[i] = new_bsum[k]
        loglik[i] = new_ll[k]
    occ[c] = not occ[c]
