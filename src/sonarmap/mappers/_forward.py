"""The deterministic forward model's objective (methods.md section 2), shared by its solvers.

Readings become rows of one sparse matrix ``W`` over the touched cells: a row per
non-empty Omega_free (a "free" term) and per non-empty Omega_occ (an "occ" term), with
weights ``w = w0 / sum(w0)`` and threshold ``X0 = 1 / sum(w0)``. With ``X = W x``:

    S(x) = sum_free P_free(X) + sum_occ P_occ(X) + sum_cells R1(x) + R2(x) + L(x)

R2 is the tent ``c2 (0.5 - |x - 0.5|)`` on [0, 1] (thesis 000), or, for reproducing
paper 001 and thesis 002 as printed, ``c2 |x - 0.5|`` on [0, 1] (``r2="abs"``), which
pulls towards 0.5 instead of away from it. L is the sparsity term ``l1 x`` per cell
(``Penalties.l1``, 0 by default: the documents' model has none): a constant cost per unit
of occupancy, so that among maps the readings explain equally well the one with the
fewest occupied cells is cheaper. Derivatives at the kinks (X0, 0, 0.5, 1) are
0 by convention.

Robust form (``GradientMapper(robust=tau)``): every term t carries a weight v_t (1 in the
plain model), so ``S_v(x) = sum_t v_t P_t(X_t) + R``. The weights are re-estimated from
residuals, as in iteratively reweighted least squares, with the saturating penalty
``rho(r) = tau r / (tau + r)`` (bounded by tau) and its weight ``v = rho'(r) =
tau^2 / (tau + r)^2``; see :func:`robust_weights` for the residuals.
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
    """The model's constants: P slopes ``a1``, ``a2``, regulariser weights ``c1``, ``c2``,
    the form of R2 (one of :data:`R2_FORMS`) and the sparsity weight ``l1`` (>= 0; the
    cost per cell of occupancy 1, linear in x)."""

    a1: float
    a2: float
    c1: float
    c2: float
    r2: str = "tent"
    l1: float = 0.0


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
    #: Per-term weight v_t (None: every term weighs 1, the plain model).
    v: F64 | None = None
    #: Index of each term's reading in the readings the problem was built from.
    reading: npt.NDArray[np.int64] | None = None

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
        if self.v is not None:
            below, above = below * self.v, above * self.v
        return below, above

    def bases(self) -> F64:
        """Each term's value at X = 0: 1 for an occ term, 0 for a free one (times v_t)."""
        base = np.where(self.is_occ, 1.0, 0.0)
        return base if self.v is None else base * self.v

    def term_values(self, X: F64) -> F64:
        """P_free or P_occ of each term (times v_t)."""
        below, above = self.slopes()
        x0 = self.X0
        base = self.bases()
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
        sparse = self.pen.l1 * float(np.sum(x)) if self.pen.l1 else 0.0
        return p + float(np.sum(r1) + np.sum(r2)) + sparse

    def term_slopes(self, X: F64) -> F64:
        """P'(X) of each term, 0 at X0."""
        below, above = self.slopes()
        return np.where(X < self.X0, below, np.where(X > self.X0, above, 0.0))

    def reg_grad(self, x: F64, *, box: bool = True) -> F64:
        """R1'(x) + R2'(x) + L'(x), 0 at the kinks; without R1 when ``box`` is False."""
        c1, c2 = self.pen.c1, self.pen.c2
        # The tent rises towards 0.5, the absolute value falls towards it.
        up = -c2 if self.pen.r2 == "abs" else c2
        g = np.where((x > 0) & (x < 0.5), up, np.where((x > 0.5) & (x < 1), -up, 0.0))
        if box:
            g = g + np.where(x > 1, c1, np.where(x < 0, -c1, 0.0))
        if self.pen.l1:
            g = g + self.pen.l1
        return g

    def grad(self, x: F64, X: F64 | None = None, *, box: bool = True) -> F64:
        """A subgradient of S: ``W^T P'(W x)`` plus the regulariser; ``X = W x`` when the
        caller has it already."""
        if X is None:
            X = self.W @ x
        return np.asarray(self.WT @ self.term_slopes(X)) + self.reg_grad(x, box=box)


#: Which terms the robust form reweights: only Omega_occ terms (a short reading that
#: nothing else supports), or free terms as well (a long reading through a wall).
ROBUST_TERMS = ("occ", "both")


def robust_weights(
    p: ForwardProblem, x: F64, tau: float, terms: str = "occ", support: float = 3.0
) -> F64:
    """Per-term weights ``v_t = tau^2 / (tau + r_t)^2`` from the residuals at ``x``.

    The residual of an occ term is leave-one-out: how unexplained its reading would be
    if it had no say. Its own P cannot flag it: at any minimiser of the plain model an
    occ term is explained (one detectable obstacle in Omega_occ costs each free term
    crossing it only ``a1 X0``). So each cell of its band is judged by the *other*
    readings: a cell is supported when the other occ terms covering it detect it
    enough, ``sum_s v_s w0_si >= support`` (w0 = s / S in [0, 1], so ``support`` is
    about how many other bands see the cell), and keeps its value; a cell not
    supported that some Omega_free covers is seen through, and is taken as 0; a cell
    no other term touches keeps its value. Then
    ``r_t = P_occ(X_t over the kept cells)`` (before weighting), in [0, 1]: a lone
    reading that others see through gets r = 1, a wall reading that neighbouring
    readings' bands share gets r near 0. A free term's residual is its own
    ``P_free(X_t)`` (with ``terms="both"``; otherwise its weight stays 1).

    Parameters
    ----------
    p : ForwardProblem
        The problem with the current weights (``p.v``; None for all ones).
    x : ndarray, shape (cells,)
        The current map over ``p.cells``.
    tau : float
        Scale of the saturating penalty, > 0: a residual of tau halves a term's cost
        relative to the plain model and quarters its pull.
    terms : {"occ", "both"}
        Which terms are reweighted.
    support : float
        Other bands' detectability that makes a cell supported (>= 0).

    Returns
    -------
    ndarray, shape (terms,)
        The new weights, in (0, 1].
    """
    W = p.W
    v = np.ones(p.n_terms) if p.v is None else p.v
    row = np.repeat(np.arange(p.n_terms), np.diff(W.indptr))
    col = W.indices
    occ_entry = p.is_occ[row]
    # Per cell: the weight of the occ terms that cover it (counted once each, a term
    # at full weight counting 1), and whether any Omega_free covers it.
    w0 = W.data / p.X0[row]
    mine = np.where(occ_entry, v[row] * w0, 0.0)
    detect = np.bincount(col, weights=mine, minlength=p.n_cells)
    seen_free = np.bincount(col[~occ_entry], minlength=p.n_cells) > 0
    others = detect[col] - mine
    emptied = occ_entry & (others < support) & seen_free[col]
    X_loo = np.asarray(
        np.bincount(row, weights=W.data * x[col] * ~emptied, minlength=p.n_terms),
        dtype=np.float64,
    )
    plain = ForwardProblem(W=p.W, WT=p.WT, X0=p.X0, is_occ=p.is_occ, cells=p.cells, pen=p.pen)
    r = np.where(p.is_occ, plain.term_values(X_loo), plain.term_values(W @ x))
    r = np.clip(r, 0.0, 1.0)
    out = tau * tau / (tau + r) ** 2
    if terms == "occ":
        out = np.where(p.is_occ, out, 1.0)
    return np.asarray(out, dtype=np.float64)


def robust_cost(r: F64, tau: float) -> F64:
    """``rho(r) = tau r / (tau + r)``: the saturating penalty the weights come from."""
    return np.asarray(tau * r / (tau + r), dtype=np.float64)


def _rows(
    cs: CellSet, keep: npt.NDArray[np.bool_], scale: F64 | None = None
) -> tuple[F64, npt.NDArray[np.int32], npt.NDArray[np.int64], F64, npt.NDArray[np.int64]]:
    """Normalised weights of the kept readings' cells: data, columns, row offsets, X0,
    and which readings (of the batch) the rows are. ``scale`` (per entry) multiplies
    the normalised weights, leaving the sums and X0 as they were."""
    counts = cs.counts
    # Per-reading sums; bincount is right for readings that touch no cell anywhere in the
    # batch (reduceat is not: it repeats a neighbour's value, or fails at the end).
    sums = np.bincount(
        cs.reading_index(), weights=cs.weight.astype(np.float64), minlength=cs.n_readings
    )
    use = keep & (counts > 0) & (sums > 0)
    entry_use = np.repeat(use, counts)
    data = cs.weight.astype(np.float64) / np.repeat(np.where(sums > 0, sums, 1.0), counts)
    if scale is not None:
        data = data * scale
    cols = cs.cells[entry_use]
    offsets = np.concatenate([[0], np.cumsum(counts[use])]).astype(np.int64)
    return data[entry_use], cols, offsets, 1.0 / sums[use], np.flatnonzero(use).astype(np.int64)


def shell_factors(free: CellSet, width: float, gain: float) -> F64:
    """Per Omega_free entry, the factor that adds first-return evidence per range shell.

    The free term weighs a cell by ``w0 / sum(w0)`` over the whole beam, so one
    detectable obstacle in the beam costs each free term only ``a1 X0``, and one cell's
    pull shrinks with the beam's area (about the range squared) while an echo band's
    pull on its cells shrinks with the band's (about the range): far along a beam the
    bands outvote the beams that pass. A detectable obstacle anywhere in Omega_free
    would have returned the echo at its own distance, so each shell of the beam
    ``width`` deep (the echo band's width) is a region that should hold none. The
    factor ``1 + gain * sum(w0) / sum(w0 over the entry's shell)`` adds ``gain`` times
    those shells' own normalised weights to the beam's, in the same term: a cell weighs
    about ``gain`` over the number of cells its shell holds, as a band's cell weighs one
    over the band's. It scales with the beam's width and the range through the shells'
    sizes and with the cell size and the sensor's resolution through ``width``.

    Parameters
    ----------
    free : CellSet
        A batch's Omega_free (with distances).
    width : float
        Depth of a shell, metres (> 0): the echo band's full width ``2 dr``.
    gain : float
        Weight of the shells' evidence against the beam's, >= 0 (0: every factor 1).

    Returns
    -------
    ndarray of float64, shape (entries,)
        One factor >= 1 per entry.
    """
    if gain == 0 or len(free.cells) == 0:
        return np.ones(len(free.cells))
    reading = free.reading_index()
    w = free.weight.astype(np.float64)
    shell = np.floor(free.distance.astype(np.float64) / width).astype(np.int64)
    key = reading * (int(shell.max()) + 1) + shell
    _, inverse = np.unique(key, return_inverse=True)
    shell_sum = np.bincount(inverse, weights=w)[inverse]
    beam_sum = np.bincount(reading, weights=w, minlength=free.n_readings)[reading]
    return np.asarray(1.0 + gain * beam_sum / shell_sum, dtype=np.float64)


def build_problem(
    footprints: list[Footprint],
    echo: list[npt.NDArray[np.bool_]],
    n_grid_cells: int,
    pen: Penalties,
    free_scale: list[F64] | None = None,
    occ_scale: list[F64] | None = None,
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
    free_scale : list of ndarray, optional
        Per batch, a factor for each Omega_free entry's weight, applied after the
        normalisation (so X0 stays one detectable obstacle of the unscaled beam): how
        much less the beam says about a cell than its sensitivity alone would.
    occ_scale : list of ndarray, optional
        The same for each Omega_occ entry.
    """
    parts_d: list[F64] = []
    parts_c: list[npt.NDArray[np.int32]] = []
    parts_o: list[npt.NDArray[np.int64]] = []
    x0s: list[F64] = []
    occ_flags: list[npt.NDArray[np.bool_]] = []
    which: list[npt.NDArray[np.int64]] = []
    first = 0
    none: list[F64 | None] = [None] * len(footprints)
    fss: list[F64 | None] = list(free_scale) if free_scale is not None else none
    oss: list[F64 | None] = list(occ_scale) if occ_scale is not None else none
    for fp, e, fs, os_ in zip(footprints, echo, fss, oss, strict=True):
        for cs, keep, flag, sc in ((fp.free, np.ones_like(e), False, fs), (fp.occ, e, True, os_)):
            d, c, o, x0, idx = _rows(cs, keep, sc)
            which.append(idx + first)
            parts_d.append(d)
            parts_c.append(c)
            parts_o.append(o)
            x0s.append(x0)
            occ_flags.append(np.full(len(x0), flag))
        first += fp.free.n_readings
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
    reading = np.concatenate([which[i] for i in order]) if order else np.empty(0, np.int64)
    touched, local = np.unique(cols, return_inverse=True)
    W = sp.csr_matrix((data, local.astype(np.int32), indptr), shape=(len(X0), len(touched)))
    W.sum_duplicates()
    return ForwardProblem(
        W=W,
        WT=W.T.tocsr(),
        X0=X0,
        is_occ=is_occ,
        cells=touched.astype(np.int64),
        pen=pen,
        reading=reading,
    )
