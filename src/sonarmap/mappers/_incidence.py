"""How detectable an obstacle is to a beam that meets it at a slant (specular walls).

A smooth wall mirrors a sonar pulse: met head-on it echoes, met at a slant the pulse is
reflected away and nothing comes back. So a beam that passed a cell without an echo is
evidence that the cell is empty only in so far as an obstacle there would have faced
the beam. The forward models weigh each cell of a beam by its detectability ``w0``
(the beam's sensitivity there); this module scales that weight by how well a surface
at the cell would face the beam, which needs the surface's orientation.

The orientation is estimated from the echoes themselves (:func:`echo_normals`): every
echo's band of cells is piled up on the grid, and the structure tensor of that pile
(Bigun & Granlund 1987) gives, per cell, the direction across the ridges the bands
make along the walls (the surfaces' normal) and how consistent that direction is over
the neighbourhood (the coherence, in [0, 1]; 0 where there are no echoes or no single
direction). :func:`incidence_factors` turns a beam cell's incidence angle ``alpha``
(between the ray from the sensor and the normal) into a factor

    f = 1 - c (1 - exp(-(alpha / spread)^2)),

``c`` the coherence there: 1 for a surface met head-on or where nothing says which way
a surface would face, towards 0 for a consistent surface met at a slant much wider
than ``spread``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..grid import Grid
from ..raster import CellSet, Footprint

__all__ = ["Normals", "Shield", "echo_normals", "free_factors", "head_on", "shield"]

F64 = npt.NDArray[np.float64]

#: Scales of the structure tensor, in cells: the echo pile is smoothed over ``SMOOTH``
#: before its gradient is taken (one cell: bands are one or two cells thick), and the
#: gradient's outer products over ``INTEGRATE`` (a wall's ridge has both flanks within
#: two cells, so the normal at its crest is averaged from them).
SMOOTH = 1.0
INTEGRATE = 2.0
#: Entries :func:`head_on` computes at once (its temporaries: about 10 float64 each).
SLICE = 1 << 20


class Normals:
    """Per cell of a grid, a unit normal ``(nx, ny)`` (world axes), its coherence and
    the echoes' pile.

    Attributes
    ----------
    nx, ny : ndarray of float64, shape (cells,)
        The normal's components, flat in the grid's row-major order (0 where unknown).
    coherence : ndarray of float64, shape (cells,)
        ``(l1 - l2) / (l1 + l2)`` of the structure tensor's eigenvalues, in [0, 1];
        0 where the tensor vanishes.
    pile : ndarray of float64, shape (cells,)
        The sum of the echoes' band weights ``w0`` on each cell.
    """

    def __init__(self, nx: F64, ny: F64, coherence: F64, pile: F64) -> None:
        self.nx = nx
        self.ny = ny
        self.coherence = coherence
        self.pile = pile


def echo_normals(grid: Grid, bands: list[CellSet]) -> Normals:
    """Surface normals on ``grid`` from the echoes' bands (see the module notes).

    Parameters
    ----------
    grid : Grid
        The map grid.
    bands : list of CellSet
        The Omega_occ of every echo (readings without an echo have none), in any number
        of batches; each entry adds its weight ``w0`` to its cell's pile.

    Returns
    -------
    Normals
        One normal and coherence per grid cell.
    """
    pile = np.zeros(grid.size)
    for cs in bands:
        pile += np.bincount(cs.cells, weights=cs.weight.astype(np.float64), minlength=grid.size)
    img = ndimage.gaussian_filter(pile.reshape(grid.shape), SMOOTH)
    # Rows run down the map (world y up), so world d/dy is minus d/drow.
    d_row, d_col = np.gradient(img)
    gx, gy = d_col, -d_row
    jxx = ndimage.gaussian_filter(gx * gx, INTEGRATE)
    jxy = ndimage.gaussian_filter(gx * gy, INTEGRATE)
    jyy = ndimage.gaussian_filter(gy * gy, INTEGRATE)
    trace = jxx + jyy
    gap = np.sqrt((jxx - jyy) ** 2 + 4.0 * jxy * jxy)
    # The dominant eigenvector of [[jxx, jxy], [jxy, jyy]] is at half the angle of
    # (jxx - jyy, 2 jxy).
    phi = 0.5 * np.arctan2(2.0 * jxy, jxx - jyy)
    coherence = np.divide(gap, trace, out=np.zeros_like(trace), where=trace > 1e-12)
    return Normals(
        np.cos(phi).ravel(), np.sin(phi).ravel(), np.clip(coherence, 0.0, 1.0).ravel(), pile
    )


def head_on(grid: Grid, cs: CellSet, x: F64, y: F64, normals: Normals, spread: float) -> F64:
    """Per entry of ``cs``, ``exp(-(alpha / spread)^2)``: how well a surface at the cell,
    facing along its estimated normal, would return the beam (1 head-on, towards 0 at
    a slant).

    Parameters
    ----------
    grid : Grid
        The grid ``cs`` and ``normals`` are on.
    cs : CellSet
        Cells of N readings.
    x, y : ndarray of float64, shape (N,)
        Each reading's sensor position, metres.
    normals : Normals
        From :func:`echo_normals`.
    spread : float
        Angular width of a surface's echo, radians (> 0).

    Returns
    -------
    ndarray of float64, shape (entries,)
    """
    reading = cs.reading_index()
    out = np.empty(len(cs.cells))
    # In slices of entries: the arithmetic is per entry, so the map is the same, and
    # a batch's temporaries stay bounded by the slice, not by its entries.
    for a in range(0, len(out), SLICE):
        b = min(a + SLICE, len(out))
        out[a:b] = _head_on(grid, cs.cells[a:b], reading[a:b], x, y, normals, spread)
    return out


def _head_on(
    grid: Grid,
    cells: npt.NDArray[np.int32],
    reading: npt.NDArray[np.int64],
    x: F64,
    y: F64,
    normals: Normals,
    spread: float,
) -> F64:
    rows, cols = grid.unravel(cells)
    cx, cy = grid.cell_centres(rows, cols)
    dx, dy = cx - x[reading], cy - y[reading]
    norm = np.hypot(dx, dy)
    cos_a = np.abs(dx * normals.nx[cells] + dy * normals.ny[cells])
    cos_a = np.divide(cos_a, norm, out=np.ones_like(norm), where=norm > 0)
    alpha = np.arccos(np.clip(cos_a, 0.0, 1.0))
    return np.asarray(np.exp(-((alpha / spread) ** 2)), dtype=np.float64)


class Shield:
    """Per grid cell, how much a slanted beam's free evidence there is held back: the
    coherence of the cell's normal times the echoes' share of its evidence (see
    :func:`free_factors`). Grid-sized, so a log's factors can be recomputed batch by
    batch (:meth:`factors`) instead of kept for every entry.

    Attributes
    ----------
    grid : Grid
        The map grid.
    normals : Normals
        From :func:`echo_normals`.
    level : ndarray of float64, shape (cells,)
        ``c g`` per cell, in [0, 1].
    spread : float
        Angular width of a surface's echo, radians (> 0).
    """

    def __init__(self, grid: Grid, normals: Normals, level: F64, spread: float) -> None:
        self.grid = grid
        self.normals = normals
        self.level = level
        self.spread = spread

    def factors(self, cs: CellSet, x: F64, y: F64) -> F64:
        """Per entry of ``cs`` (cells of N readings at sensor positions ``x``, ``y``,
        metres, shape (N,)), the factor in (0, 1] its free weight is scaled by."""
        e = head_on(self.grid, cs, x, y, self.normals, self.spread)
        return np.maximum(1.0 - self.level[cs.cells] * (1.0 - e), 1e-6)


def shield(grid: Grid, fps: list[Footprint], x: F64, y: F64, spread: float) -> Shield:
    """The :class:`Shield` of a log's footprints, one grid-sized pass over them.

    Parameters
    ----------
    grid : Grid
        The map grid.
    fps : list of Footprint
        Consecutive batches of the readings' Omega_free and Omega_occ.
    x, y : ndarray of float64, shape (N,)
        The readings' sensor positions, metres, N the footprints' readings in all.
    spread : float
        Angular width of a surface's echo, radians (> 0).

    Returns
    -------
    Shield
    """
    normals = echo_normals(grid, [fp.occ for fp in fps])
    passed = np.zeros(grid.size)
    a = 0
    for fp in fps:
        b = a + fp.free.n_readings
        e = head_on(grid, fp.free, x[a:b], y[a:b], normals, spread)
        passed += np.bincount(fp.free.cells, weights=fp.free.weight * e, minlength=grid.size)
        a = b
    total = normals.pile + passed
    share = np.divide(normals.pile, total, out=np.zeros_like(total), where=total > 0)
    return Shield(grid, normals, normals.coherence * share, spread)


def free_factors(
    grid: Grid,
    free: list[CellSet],
    bands: list[CellSet],
    xs: list[F64],
    ys: list[F64],
    spread: float,
) -> list[F64]:
    """Per batch, the factor each Omega_free entry's weight is scaled by.

    ``f = 1 - c g (1 - e)``: ``e`` the entry's :func:`head_on`, ``c`` the coherence of
    the cell's normal, and ``g = E / (E + P)`` how much of the cell's evidence is
    echoes: ``E`` its echoes' pile, ``P`` the weight of the beams that passed it
    head-on (``sum w0 e`` over the free entries). A cell that beams have passed
    head-on is one a surface would have echoed from, so it is not shielded from the
    slanted beams either (a doorway in a wall's line); a cell only echoes and slanted
    beams met keeps its echoes' say. Floored at 1e-6.

    Parameters
    ----------
    grid : Grid
        The map grid.
    free, bands : list of CellSet
        Per batch, the readings' Omega_free and Omega_occ.
    xs, ys : list of ndarray
        Per batch, the readings' sensor positions, metres.
    spread : float
        Angular width of a surface's echo, radians (> 0).

    Returns
    -------
    list of ndarray of float64
        Per batch, one factor in (0, 1] per Omega_free entry.
    """
    fps = [Footprint(f, o, 0.0) for f, o in zip(free, bands, strict=True)]
    x, y = np.concatenate(xs), np.concatenate(ys)
    sh = shield(grid, fps, x, y, spread)
    return [sh.factors(cs, xb, yb) for cs, xb, yb in zip(free, xs, ys, strict=True)]
