"""The deterministic forward model's objective (methods.md section 2), shared by its solvers.

Readings become rows of one sparse matrix ``W`` over the touched cells: a row per
non-empty Omega_free (a "free" term) and per non-empty Omega_occ (an "occ" term), with
weights ``w = w0 / sum(w0)`` and threshold ``X0 = 1 / sum(w0)``. With ``X = W x``:

    S(x) = sum_free P_free(X) + sum_occ P_occ(X) + sum_cells R1(x) + R2(x)

R2 is the tent ``c2 (0.5 - |x - 0.5|)`` on [0, 1] (thesis 000), or, for reproducing
paper 001 and thesis 002 as printed, ``c2 |x - 0.5|`` on [0, 1] (``r2="abs"``), which
pulls towards 0.5 instead of away from it. Derivatives at the kinks (X0, 0, 0.5, 1) are
0 by convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ..raster import CellSet, Footprint

F64 = npt.NDArray[np.float64]


#: Forms of R2: the tent (the default) and the printed absolute value.
R2_FORMS = ("tent", "abs")


@dataclass(frozen=True)
class Penalties:
    """The model's constants: P slopes ``a1``, ``a2``, regulariser weights ``c1``, ``c2``
    and the form of R2 (one of :data:`R2_FORMS`)."""

    a1: float
    a2: float
    c1: float
    c2: float
    r2: str = "tent"


@dataclass(frozen=True, eq=False)
class ForwardProblem:
    """The objective over the touched cells.

    Attributes
    ----------
    W : csr_matrix, shape (terms, cells)
        Normalised weights, free terms first.
    WT : csr_matrix
        ``W.T`` in CSR form, for the transposed product.
    X0 : ndarray, shape (terms,)
        Per-term threshold.
    is_occ : ndarray of bool, shape (terms,)
        Which terms are Omega_occ terms.
    cells : ndarray of int64
        Flat grid index of each column.
    """

    W: sp.csr_matrix
    WT: sp.csr_matrix
    X0: F64
    is_occ: npt.NDArray[np.bool_]
    cells: npt.NDArray[np.int64]
    pen: Penalties

    @property
    def n_terms(self) -> int:
        return int(self.W.shape[0])

    @property
    def n_cells(self) -> int:
        return int(self.W.shape[1])

    def slopes(self) -> tuple[F64, F64]:
        """Per-term slope below and above X0 (computed once)."""
        cached: tuple[F64, F64] | None = self.__dict__.get("_slopes")
        if cached is None:
            cached = self._compute_slopes()
            object.__setattr__(self, "_slopes", cached)
        return cached

    def _compute_slopes(self) -> tuple[F64, F64]:
        a1, a2 = self.pen.a1, self.pen.a2
        x0 = self.X0
        # X0 >= 1 (less than one detectable obstacle's worth of sensitivity in the region):
        # X never exceeds X0 in the box, so the upper piece is never used; keep it finite.
        denom = 1.0 - x0
        b1 = np.divide(1.0 - a1 * x0, denom, out=np.full_like(x0, a1), where=denom > 0)
        b2 = (1.0 - a2 + a2 * x0) / x0
        below = np.where(self.is_occ, -b2, a1)
        above = np.where(self.is_occ, -a2, b1)
        return below, above

    def term_values(self, X: F64) -> F64:
        """P_free or P_occ of each term."""
        below, above = self.slopes()
        x0 = self.X0
        base = np.where(self.is_occ, 1.0, 0.0)
        at_x0 = base + below * x0
        return np.where(x0 > X, base + below * X, at_x0 + above * (X - x0))

    def value(self, x: F64, X: F64 | None = None) -> float:
        """The objective S(x); ``X = W x`` when the caller has it already."""
        if X is None:
            X = self.W @ x
        p = float(np.sum(self.term_values(X)))
        c1, c2 = self.pen.c1, self.pen.c2
        r1 = c1 * np.where(x > 1, x - 1, np.where(x < 0, -x, 0.0))
        dev = np.abs(x - 0.5)
        shape = dev if self.pen.r2 == "abs" else 0.5 - dev
        r2 = c2 * np.where((x >= 0) & (x <= 1), shape, 0.0)
        return p + float(np.sum(r1) + np.sum(r2))

    def term_slopes(self, X: F64) -> F64:
        """P'(X) of each term, 0 at X0."""
        below, above = self.slopes()
        return np.where(X < self.X0, below, np.where(X > self.X0, above, 0.0))

    def reg_grad(self, x: F64, *, box: bool = True) -> F64:
        """R1'(x) + R2'(x), 0 at the kinks; without R1 when ``box`` is False."""
        c1, c2 = self.pen.c1, self.pen.c2
        # The tent rises towards 0.5, the absolute value falls towards it.
        up = -c2 if self.pen.r2 == "abs" else c2
        g = np.where((x > 0) & (x < 0.5), up, np.where((x > 0.5) & (x < 1), -up, 0.0))
        if box:
            g = g + np.where(x > 1, c1, np.where(x < 0, -c1, 0.0))
        return g

    def grad(self, x: F64, X: F64 | None = None, *, box: bool = True) -> F64:
        """A subgradient of S: ``W^T P'(W x)`` plus the regulariser; ``X = W x`` when the
        caller has it already."""
        if X is None:
            X = self.W @ x
        return np.asarray(self.WT @ self.term_slopes(X)) + self.reg_grad(x, box=box)


def _rows(
    cs: CellSet, keep: npt.NDArray[np.bool_]
) -> tuple[F64, npt.NDArray[np.int32], npt.NDArray[np.int64], F64]:
    """Normalised weights of the kept readings' cells: data, columns, row offsets, X0."""
    counts = cs.counts
    # Per-reading sums; bincount is right for readings that touch no cell anywhere in the
    # batch (reduceat is not: it repeats a neighbour's value, or fails at the end).
    sums = np.bincount(
        cs.reading_index(), weights=cs.weight.astype(np.float64), minlength=cs.n_readings
    )
    use = keep & (counts > 0) & (sums > 0)
    entry_use = np.repeat(use, counts)
    data = cs.weight.astype(np.float64) / np.repeat(np.where(sums > 0, sums, 1.0), counts)
    cols = cs.cells[entry_use]
    offsets = np.concatenate([[0], np.cumsum(counts[use])]).astype(np.int64)
    return data[entry_use], cols, offsets, 1.0 / sums[use]


def build_problem(
    footprints: list[Footprint],
    echo: list[npt.NDArray[np.bool_]],
    n_grid_cells: int,
    pen: Penalties,
) -> ForwardProblem:
    """Assemble W over the cells any reading touches.

    Parameters
    ----------
    footprints : list of Footprint
        Rasterised batches of readings.
    echo : list of bool arrays
        Per batch, which readings have an echo (only those get an occ term).
    n_grid_cells : int
        Size of the grid.
    pen : Penalties
        Model constants.
    """
    parts_d: list[F64] = []
    parts_c: list[npt.NDArray[np.int32]] = []
    parts_o: list[npt.NDArray[np.int64]] = []
    x0s: list[F64] = []
    occ_flags: list[npt.NDArray[np.bool_]] = []
    for fp, e in zip(footprints, echo, strict=True):
        for cs, keep, flag in ((fp.free, np.ones_like(e), False), (fp.occ, e, True)):
            d, c, o, x0 = _rows(cs, keep)
            parts_d.append(d)
            parts_c.append(c)
            parts_o.append(o)
            x0s.append(x0)
            occ_flags.append(np.full(len(x0), flag))
    # Free terms first, then occ terms, each in reading order.
    order = [i for i in range(len(parts_d)) if not occ_flags[i].any()] + [
        i for i in range(len(parts_d)) if occ_flags[i].any()
    ]
    data = np.concatenate([parts_d[i] for i in order]) if order else np.empty(0)
    cols = np.concatenate([parts_c[i] for i in order]) if order else np.empty(0, np.int32)
    offs = [np.zeros(1, np.int64)]
    base = 0
    for i in order:
        offs.append(parts_o[i][1:] + base)
        base += int(parts_o[i][-1])
    indptr = np.concatenate(offs)
    X0 = np.concatenate([x0s[i] for i in order]) if order else np.empty(0)
    is_occ = np.concatenate([occ_flags[i] for i in order]) if order else np.empty(0, bool)
    touched, local = np.unique(cols, return_inverse=True)
    W = sp.csr_matrix((data, local.astype(np.int32), indptr), shape=(len(X0), len(touched)))
    W.sum_duplicates()
    return ForwardProblem(
        W=W, WT=W.T.tocsr(), X0=X0, is_occ=is_occ, cells=touched.astype(np.int64), pen=pen
    )
