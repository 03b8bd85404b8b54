"""Deterministic forward model solved by optimisation (Shvets, Shepelev, Nikolaev 2016).

Every reading must be explained by the whole map: its Omega_free holds little obstacle
area and its Omega_occ enough (methods.md section 2). The objective is convex (the P
terms and R1) plus concave (the tent R2), minimised from x = 0.5 over the cells some
reading touches; untouched cells stay unknown.

Solvers (``solver=``):

``gd``
    The documents' plain gradient descent, for reproduction: a fixed step ``step`` (0.02)
    along the subgradient, from x = 0.5, keeping the best iterate, stopped when the best
    objective has improved by less than ``tol`` (relative) over ``patience`` steps, or
    after ``max_iter``. The documents give neither.
    The step: 0.002, 0.005 and 0.02 give the same binarised maps on ``doorways`` and
    ``passages``; 0.02 gets there in the fewest steps. A fixed-step subgradient method
    does not decrease the objective monotonically (it oscillates about the kinks), hence
    the best iterate and the stall rule.
``pgd``
    Projected subgradient descent: R1 is replaced by the exact projection on [0, 1] (the
    minimiser of the penalised and the constrained problems coincide for c1 larger than
    the P slopes), with a step decaying as 1/sqrt(k) and the best iterate kept.
``lbfgs``
    L-BFGS-B with bounds [0, 1] on a smoothed surrogate: every kink of P and of R2 is
    smoothed over a width that shrinks over three rounds (continuation), each round
    warm-started from the last.
``ccp``
    The convex-concave procedure: R2 is replaced by its linearisation at the current point,
    the remaining piecewise-linear convex problem is solved exactly as a linear programme
    (HiGHS), until the point stops moving. Each step cannot increase S. With the printed
    ``r2="abs"`` the whole objective is convex and the first LP is the exact optimum.

Robust form (``robust``, on by default): terms re-weighted from leave-one-out
residuals through a saturating penalty, the map re-solved (see :class:`GradientMapper`
and :func:`~sonarmap.mappers._forward.robust_weights`).

Named parameter sets (:data:`PRESETS`, ``--preset``): ``thesis000`` (a1 0.05, a2 0.01,
c1 5, c2 1: paper 001, thesis 000 and thesis 002's synthetic passages) and ``thesis002``
(c1 10, c2 1, a1 0.05, a2 0.001: thesis 002 section 4.5.2). They set the model's
constants, turn the robust form off (the documents' model explains every reading), put
the band on the echo and let no-echo readings clear their beam, as the documents do;
the solver, the tent and the band's half-width stay sonarmap's.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable

import numba as nb
import numpy as np
import numpy.typing as npt
import scipy.optimize as so
import scipy.sparse as sp

from ..errors import ConfigError
from ..raster import Footprint
from ..readings import Readings
from ._base import Mapper, Progress, register
from ._checks import choice, integer, number
from ._correlated import reading_weights
from ._forward import (
    R2_FORMS,
    ROBUST_TERMS,
    ForwardProblem,
    Penalties,
    build_problem,
    robust_weights,
    shell_factors,
)
from ._incidence import shield
from ._stream import StreamEngine

__all__ = ["GradientMapper"]

F64 = npt.NDArray[np.float64]
SOLVERS = ("gd", "pgd", "lbfgs", "ccp")

#: The documents' parameter sets (see the module notes).
PRESETS: dict[str, dict[str, float | str]] = {
    "thesis000": {
        "a1": 0.05,
        "a2": 0.01,
        "c1": 5.0,
        "c2": 1.0,
        "robust": 0.0,
        "band_offset": 0.0,
        "no_echo": "free",
    },
    "thesis002": {
        "a1": 0.05,
        "a2": 0.001,
        "c1": 10.0,
        "c2": 1.0,
        "robust": 0.0,
        "band_offset": 0.0,
        "no_echo": "free",
    },
}


@register
class GradientMapper(Mapper):
    """Forward-model map by minimising the deterministic objective.

    Defaults before issue 39 (a2 0.03, c1 10, no-echo readings clearing their beam,
    projected subgradient for at most 300 steps, stopped after 100 without progress) had the
    highest mean quality (wall F1 and passage F1 together) in ``sonarmap sweep
    sweeps/tune.yaml``: its defaults and 60 settings of a1, a2, c1, c2, band, no-echo
    handling, solver and stopping rule, on the ten training scenes every method was
    tuned on (0.307; the runner-up 0.237).
    The robust form's defaults (tau 0.1, both kinds of term, 2 rounds, support 3) were
    chosen on training scenes (``sweeps/robust.yaml``, ``sweeps/rigs6-robust.yaml``); see
    docs/results/2026-11-23-gradient-issue-14.md and
    docs/results/2026-12-06-rig-defaults.md. ``robust=0`` is the plain model.
    a1 0.3, c2 1 and the band moved half a cell behind the echo (the rasteriser's
    half-width) had the highest in ``sonarmap sweep sweeps/band.yaml`` (the defaults
    before and 60 settings of the band's offset and half-width, a1, a2 and c2): 0.358
    against 0.355 before, with wall F1 0.253 against 0.184 and passage F1 0.462
    against 0.526.
    No-echo readings ignored and a2 0.1 had the highest quality (the geometric mean of
    wall F1, passage F1 and observed-wall recall) in ``sonarmap sweep sweeps/rigs.yaml``
    (issue 39: the defaults before and a2 0.03, 0.1 and 0.2 with no-echo readings
    ignored, on training scenes mapped by six MaxSonar EZ1s, six HC-SR04s and a ring of
    16 Polaroid sonars): 0.353 against 0.191 before, observed-wall recall 0.69 against
    0.32. An acoustic sonar's no-echo reading is mostly a beam a smooth wall mirrored
    away; clearing its whole beam erased the walls it crossed.
    The band three quarters of a cell behind the echo (half a cell before) was chosen
    on training maps (``sonarmap sweep sweeps/rigs8-band.yaml``, issue 39; the figures,
    the tie it broke and what it cost: docs/results/2026-12-07-gradient-wall-thickness.md).
    Half a cell behind, the cells just in front of a wall's surface were often in as
    many echoes' bands as the surface's own, and the objective kept them occupied: the
    walls came out a cell thick on the side the beams come from.

    Parameters
    ----------
    a1, a2 : float
        Slopes of P_free below X0 and of P_occ above X0, in (0, 1) (0.3, 0.1; the
        documents' 0.05, 0.01).
    c1, c2 : float
        Weights of the box regulariser R1 and the tent R2, >= 0 (10, 1; the
        documents' 5, 1).
    r2 : {"tent", "abs"}
        Form of R2: the tent ``c2 (0.5 - |x - 0.5|)`` (default, thesis 000), or
        ``c2 |x - 0.5|`` as paper 001 and thesis 002 print it, which pulls cells
        towards 0.5 rather than away (for reproduction). Streaming leaves R2 out either way.
    solver : {"gd", "pgd", "lbfgs", "ccp"}
        See the module notes.
    step : float or None
        Step of ``gd`` (default 0.02) and initial step of ``pgd`` (default 0.05).
    max_iter : int
        Iteration limit (gradient steps; LP solves for ``ccp``) (300).
    tol : float
        Relative improvement of the best objective below which a solver counts as stalled.
    patience : int
        Stalled steps after which ``gd`` and ``pgd`` stop (100).
    no_echo : {"free", "ignore"}
        Whether no-echo readings contribute Omega_free terms (default ``ignore``: they
        do not).
    no_echo_share : float
        How far a no-echo reading's Omega_free reaches, as a share of the sensor's
        ``r_max``, in (0, 1] (default 1: out to ``r_max`` less the band's half-width,
        as :func:`~sonarmap.raster.rasterise` has it). A reading that heard nothing says
        that no surface *facing* the sensor lies in the beam; a wall met at a slant
        mirrors the pulse at any range, so the nearer part of the beam is the surer.
        Needs ``no_echo="free"``. Offline only: streaming refuses it.
    no_echo_weight : float
        Weight of a no-echo reading's Omega_free term, in (0, 1] (default 1: as an
        echo's). The robust form's and ``correlated``'s weights multiply it. Needs
        ``no_echo="free"``. Offline only: streaming refuses it.
    dr : float or None
        Half-width of the Omega_occ band, metres; None (default): the rasteriser's.
    band_offset : float or None
        How far behind the echo the Omega_occ band's centre lies, metres (>= 0); None
        (default): 0.75 of a cell. See :mod:`sonarmap.raster` for why.
    band_growth : float
        Growth of the Omega_occ band's half-width with the echo's range, metres per
        metre, in [0, 1) (default 0: every band ``dr`` wide either side; at 1 the band
        would reach back to the sensor and swallow the beam). With g > 0 an echo
        at range r has the half-width ``max(dr, g r)``: a sonar's range error (the
        speed of sound, the timing of a weakening echo) grows with the range, and so
        does the patch of a wall across the beam whose points lie within a band of the
        nearest one. Streaming takes it as well.
    robust : float
        Scale tau of the robust form, >= 0 (0.1); 0 is the plain model. With tau > 0
        the map is solved, then ``robust_rounds`` times each term's weight is set to
        ``v = tau^2 / (tau + r)^2`` from its residual r (in [0, 1]) at the current map
        and the weighted objective ``sum_t v_t P_t + R`` re-solved from the same start
        (iteratively reweighted, the weight being the derivative of the saturating
        penalty ``rho(r) = tau r / (tau + r)``). An occ term's residual is
        leave-one-out: how unexplained its reading is once the cells of its band that
        other readings see through, and no other band covers, are emptied (see
        :func:`~sonarmap.mappers._forward.robust_weights`). A lone short reading that
        others see through gets r = 1 and stops pulling; a wall reading whose band
        neighbouring readings share keeps r near 0 and weight near 1. Offline only:
        streaming ignores it.
    robust_terms : {"occ", "both"}
        Which terms are reweighted: Omega_occ terms only, or the Omega_free terms as
        well (default), by their own residual ``P_free(X)`` (a long reading through a
        wall).
    robust_rounds : int
        How many times the weights are re-estimated and the map re-solved (2); each
        round is one more run of the solver.
    robust_support : float
        How much other readings' bands must detect a cell for it to count as supported
        in the leave-one-out residual: the sum over the other occ terms covering it of
        ``v_s w0`` (w0 = s / S in [0, 1], so about how many other bands see the cell) (3).
    correlated : float
        Down-weighting of correlated readings (Konolige 1997), metres; 0 (default) is off.
        With c > 0 the n readings of one sonar from poses in the same c-metre bin (and
        10-degree heading bin) with ranges in the same c-metre bin each weigh 1 / n, so a
        burst from one pose counts as one reading (see
        :func:`~sonarmap.mappers._correlated.correlation_weights`), scaled so that the
        weights' mean is 1; the robust form's weights multiply these. Offline only:
        streaming refuses it (see :mod:`sonarmap.mappers._stream`). Off by default: in
        ``sonarmap sweep sweeps/correlated.yaml`` (bins of 2, 5, 10 and 20 cm, the ten
        training scenes) 2 cm tied with off (quality 0.358 both), 5 cm scored 0.315 and
        10-20 cm 0.21.
    init : {"uniform", "inverse"}
        Where the offline solve starts: every cell at 0.5, the papers' neutral start
        (default), or the inverse mapper's map at its defaults (0.5 where it has no
        evidence), so the descent refines a map that already places the walls. The
        robust form's rounds restart from the same map. Streaming starts at 0.5.
    specular_deg : float
        Angular width of a smooth surface's echo, degrees, in [0, 90); 0 (default) is
        off. With a width, each Omega_free weight is scaled by how well a surface at the
        cell would face the beam: surface normals are estimated from the echoes' bands,
        and a cell that only echoes and slanted beams have met counts little to a beam
        crossing it at a slant (see :func:`~sonarmap.mappers._incidence.free_factors`).
        The weights are scaled after the normalisation, so X0 stays one detectable
        obstacle of the whole beam. Offline only: streaming refuses it. Off by default:
        on the training scenes it kept more of the observed walls but detected fewer
        passages, a lower quality (docs/results/2026-12-06-rig-defaults.md).
    convex_start : bool
        Solve the objective without the tent R2 first (a convex problem; L-BFGS-B on
        its smoothed surrogate, as ``solver="lbfgs"``), then run the solver with the
        tent from that map (default False: from the start map directly). From 0.5 the
        tent binarises each cell by the sign of its first subgradients; from the convex
        optimum, by where the readings together put it. Off by default, for the same
        trade on the same training scenes. Offline only.
    sparsity : float
        Weight l1 >= 0 of a sparsity term ``l1 x`` per cell (the cost of occupancy 1),
        added to the objective (0, off: the documents' model has none). The P_occ terms
        ask for one detectable obstacle in each echo's band and no more; from the start
        at 0.5 nothing else tells the band's cells apart where no beam crosses them (the
        cells just behind a surface) or only slanted ones do, and the tent takes them
        all to 1, a wall one cell thicker than the surface. With l1 > 0 each occupied
        cell has to be paid for by the echoes it explains, so the map keeps the fewest
        cells that explain them. Too large a weight empties walls as well.
        Offline only: streaming refuses it (:class:`~sonarmap.errors.ConfigError`).
    free_shell : float
        Weight >= 0 of the first-return evidence per range shell (0, off: the
        documents' model weighs a free cell by its share of the whole beam). With
        g > 0 each Omega_free entry's weight is scaled by ``1 + g sum(w0) / sum(w0 over
        its shell)``, the beam's shells being fixed slices of distance from the sensor,
        ``[k 2 dr, (k + 1) 2 dr)``, one echo band's width deep (see
        :func:`~sonarmap.mappers._forward.shell_factors`), so that a cell passed by a
        beam weighs against it about g over its shell's size, as an echo band's cell
        weighs for it one over the band's. The shells stay ``2 dr`` deep whatever
        ``band_growth``: far echoes' grown bands span several shells. Offline only:
        streaming refuses it.
    polish : float
        Sparsity weight l1 >= 0 of a last pass over the solved map (0, off): each
        occupied cell, cheapest first, is emptied when that lowers ``S(x) + l1 sum x``,
        the objective with the sparsity term (see :func:`polish`). The descent from 0.5
        settles each cell by its first subgradients, and a cell just in front of a wall
        that echo bands reach about as often as the wall itself ends occupied: emptying it
        alone raises S, by less than emptying the wall's own cells does. Offline only:
        streaming refuses it (:class:`~sonarmap.errors.ConfigError`).

    Attributes
    ----------
    objective_ : float
        S(x) at the returned map; with the robust form or ``correlated``, the weighted
        S_v(x) that the last round minimised.
    n_iter_ : int
        Iterations taken.
    history_ : list of float
        Objective at each check (each round's weighted objective, in turn).
    term_weights_ : ndarray, shape (terms,)
        The final weight of each term of :meth:`problem` (the robust form's times
        the correlation weight; all ones without either).
    """

    name = "gradient"
    offset_cells = 0.75
    presets = PRESETS

    def __init__(
        self,
        *,
        a1: float = 0.3,
        a2: float = 0.1,
        c1: float = 10.0,
        c2: float = 1.0,
        r2: str = "tent",
        solver: str = "pgd",
        step: float | None = None,
        max_iter: int = 300,
        tol: float = 1e-4,
        patience: int = 100,
        no_echo: str = "ignore",
        no_echo_share: float = 1.0,
        no_echo_weight: float = 1.0,
        dr: float | None = None,
        band_offset: float | None = None,
        band_growth: float = 0.0,
        robust: float = 0.1,
        robust_terms: str = "both",
        robust_rounds: int = 2,
        robust_support: float = 3.0,
        correlated: float = 0.0,
        init: str = "uniform",
        specular_deg: float = 0.0,
        convex_start: bool = False,
        sparsity: float = 0.0,
        free_shell: float = 0.0,
        polish: float = 0.0,
    ) -> None:
        self.a1 = a1
        self.a2 = a2
        self.c1 = c1
        self.c2 = c2
        self.r2 = r2
        self.solver = solver
        self.step = step
        self.max_iter = max_iter
        self.tol = tol
        self.patience = patience
        self.no_echo = no_echo
        self.no_echo_share = no_echo_share
        self.no_echo_weight = no_echo_weight
        self.dr = dr
        self.band_offset = band_offset
        self.band_growth = band_growth
        self.robust = robust
        self.robust_terms = robust_terms
        self.robust_rounds = robust_rounds
        self.robust_support = robust_support
        self.correlated = correlated
        self.init = init
        self.specular_deg = specular_deg
        self.convex_start = convex_start
        self.sparsity = sparsity
        self.free_shell = free_shell
        self.polish = polish
        number("a1", a1, 0.0, 1.0, lo_open=True, hi_open=True)
        number("a2", a2, 0.0, 1.0, lo_open=True, hi_open=True)
        number("c1", c1, 0.0, None)
        number("c2", c2, 0.0, None)
        choice("r2", r2, R2_FORMS)
        choice("solver", solver, SOLVERS)
        if step is not None:
            number("step", step, 0.0, None, lo_open=True)
        integer("max_iter", max_iter, 1)
        number("tol", tol, 0.0, None)
        integer("patience", patience, 1)
        choice("no_echo", no_echo, ("free", "ignore"))
        number("no_echo_share", no_echo_share, 0.0, 1.0, lo_open=True)
        number("no_echo_weight", no_echo_weight, 0.0, 1.0, lo_open=True)
        if no_echo == "ignore" and (no_echo_share < 1.0 or no_echo_weight < 1.0):
            raise ConfigError(
                "no_echo_share and no_echo_weight bound the evidence of no-echo readings: "
                "they need no_echo='free', got no_echo='ignore'"
            )
        if dr is not None:
            number("dr", dr, 0.0, None)
        if band_offset is not None:
            number("band_offset", band_offset, 0.0, None)
        number("band_growth", band_growth, 0.0, 1.0, hi_open=True)
        number("robust", robust, 0.0, None)
        choice("robust_terms", robust_terms, ROBUST_TERMS)
        integer("robust_rounds", robust_rounds, 1)
        number("robust_support", robust_support, 0.0, None)
        number("correlated", correlated, 0.0, None)
        choice("init", init, ("uniform", "inverse"))
        number("specular_deg", specular_deg, 0.0, 90.0, hi_open=True)
        number("sparsity", sparsity, 0.0, None)
        number("free_shell", free_shell, 0.0, None)
        number("polish", polish, 0.0, None)
        if not isinstance(convex_start, bool):
            got = repr(convex_start)
            raise ConfigError(f"parameter 'convex_start' must be true or false, got {got}")

    # The objective couples all readings, so batches are kept and the map re-solved,
    # warm-started from the previous solution.
    def _reset(self) -> None:
        self._x: F64 | None = None
        self._cells: npt.NDArray[np.int64] = np.empty(0, np.int64)
        self.objective_ = float("nan")
        self.n_iter_ = 0
        self.history_: list[float] = []
        self.term_weights_: F64 = np.empty(0)

    def _initial_map(self, readings: Readings, cells: npt.NDArray[np.int64]) -> F64:
        """The start of the solve at ``cells`` (see ``init``)."""
        if self.init == "uniform":
            return np.full(len(cells), 0.5)
        from .inverse import InverseMapper

        inv = InverseMapper().fit(readings, self.grid, self.sensor).occupancy_.ravel()
        return np.nan_to_num(inv[cells].astype(np.float64), nan=0.5)

    def _add(self, readings: Readings, progress: Progress | None) -> None:
        everything = self._accumulate(readings)
        problem = self.problem(everything)
        x = self._initial_map(everything, problem.cells)
        if self._x is not None:
            old = dict(zip(self._cells.tolist(), self._x.tolist(), strict=True))
            pairs = zip(problem.cells.tolist(), x.tolist(), strict=True)
            x = np.array([old.get(c, v) for c, v in pairs])
        start = x
        x, self.n_iter_, self.history_ = self.solve(problem, start, progress)
        prior = np.ones(problem.n_terms) if problem.v is None else problem.v
        if self.robust > 0 and problem.n_cells > 0:
            for _ in range(self.robust_rounds):
                v = robust_weights(problem, x, self.robust, self.robust_terms, self.robust_support)
                problem = dataclasses.replace(problem, v=v * prior)
                # From the same start, not warm: the tent drives cells to 0 or 1, where
                # a down-weighted term's cells would stay (the free terms' pull on a cell
                # at 1 is only a1 w0 / sum w0).
                x, n, hist = self.solve(problem, start, progress)
                self.n_iter_ += n
                self.history_ += hist
        if self.polish > 0 and problem.n_cells > 0:
            x = polish(problem, x, self.polish)
        self._x = x
        self.term_weights_ = np.ones(problem.n_terms) if problem.v is None else problem.v
        self._cells = problem.cells
        self.objective_ = problem.value(self._x)

    def problem(self, readings: Readings) -> ForwardProblem:
        """The objective for ``readings`` on the mapper's grid (after :meth:`start`)."""
        if self.no_echo == "ignore":
            # A no-echo reading has only an Omega_free term; ignoring it drops the reading.
            readings = self._echoes(readings)
        reach = self.no_echo_share * self.sensor.r_max if self.no_echo_share < 1.0 else None
        fps = self.kept_footprints(
            readings,
            dr=self.dr,
            offset=self.band_offset_for(self.grid),
            no_echo_reach=reach,
            band_growth=self.band_growth,
        )
        bounds = np.cumsum([0] + [fp.free.n_readings for fp in fps])
        scale = self._slanted(readings, fps, bounds) if self.specular_deg > 0 else None
        if self.free_shell > 0:
            shells = [shell_factors(fp.free, 2.0 * fp.dr, self.free_shell) for fp in fps]
            scale = shells if scale is None else [a * b for a, b in zip(scale, shells, strict=True)]
        echo = [readings.range[a:b] < self.sensor.r_max for a, b in itertools.pairwise(bounds)]
        pen = Penalties(self.a1, self.a2, self.c1, self.c2, self.r2, self.sparsity)
        problem = build_problem(fps, echo, self.grid.size, pen, scale)
        if self.no_echo_weight < 1.0 and problem.reading is not None:
            quiet = readings.range[problem.reading] >= self.sensor.r_max
            problem = dataclasses.replace(problem, v=np.where(quiet, self.no_echo_weight, 1.0))
        if self.correlated > 0 and problem.reading is not None:
            # Scaled to mean 1: 1 / n alone weakens every term against the unscaled
            # R2, and walls lose to the tent (training quality 0.14 at 10 cm bins).
            c = reading_weights(readings, self.correlated, self.sensor.r_max)
            v = c[problem.reading] if problem.v is None else problem.v * c[problem.reading]
            problem = dataclasses.replace(problem, v=v)
        return problem

    def _slanted(
        self, readings: Readings, fps: list[Footprint], bounds: npt.NDArray[np.int64]
    ) -> list[F64]:
        """Per batch, each Omega_free entry's detectability at the beam's incidence
        (``specular_deg``; see :func:`~sonarmap.mappers._incidence.free_factors`)."""
        x, y = readings.x, readings.y
        sh = shield(self.grid, fps, x, y, math.radians(self.specular_deg))
        pairs = itertools.pairwise(bounds)
        return [sh.factors(fp.free, x[a:b], y[a:b]) for (a, b), fp in zip(pairs, fps, strict=True)]

    def solve(
        self, problem: ForwardProblem, x: F64, progress: Progress | None = None
    ) -> tuple[F64, int, list[float]]:
        """Descend ``problem`` from ``x`` with the mapper's solver and stopping rule.

        One solve, without the robust rounds :meth:`fit` adds (``robust``).

        Parameters
        ----------
        problem : ForwardProblem
            The objective, from :meth:`problem`.
        x : ndarray of float64, shape (problem.n_cells,)
            The start, occupancy in [0, 1] per cell of ``problem.cells``; not modified.
        progress : Progress or None, optional
            Told of each iteration (default None: silent).

        Returns
        -------
        x : ndarray of float64, shape (problem.n_cells,)
            The solution, unclipped.
        n_iter : int
            Iterations taken (0 when the problem has no cells).
        history : list of float
            The objective after each iteration.
        """
        if problem.n_cells == 0:
            return x, 0, []
        solve = {"gd": _gd, "pgd": _pgd, "lbfgs": _lbfgs, "ccp": _ccp}[self.solver]
        if not self.convex_start:
            return solve(problem, x, self, progress)
        # Without the concave tent the problem is convex, and L-BFGS-B on its smoothed
        # surrogate solves it; the tent's descent then starts from that map instead of
        # from the first subgradient's signs.
        flat = dataclasses.replace(problem, pen=dataclasses.replace(problem.pen, c2=0.0))
        x, k0, h0 = _lbfgs(flat, x, self, progress)
        x, k1, h1 = solve(problem, np.clip(x, 0.0, 1.0), self, progress)
        return x, k0 + k1, h0 + h1

    @property
    def solution_(self) -> F64 | None:
        """The solver's occupancy values (unclipped) on the cells the readings touch;
        None before a fit."""
        return self._x

    def _occupancy(self) -> npt.NDArray[np.float32]:
        out = np.full(self.grid.size, np.nan, dtype=np.float32)
        if self._x is not None:
            out[self._cells] = np.clip(self._x, 0.0, 1.0)
        return out


def emptying_costs(p: ForwardProblem, x: F64, l1: float = 0.0) -> F64:
    """Per cell, how much emptying it alone changes ``S(x) + l1 sum x``.

    Parameters
    ----------
    p : ForwardProblem
        The objective S, ``p.value`` (its terms' weights ``p.v`` and its own sparsity
        weight ``p.pen.l1`` count; ``l1`` is added to the latter).
    x : ndarray of float64, shape (p.n_cells,)
        A map in [0, 1].
    l1 : float
        Cost of occupancy 1 in a cell, >= 0 (default 0: the objective alone).

    Returns
    -------
    ndarray of float64, shape (p.n_cells,)
        The change of the objective when the cell is set to 0 and nothing else moves
        (negative: emptying it lowers the objective); 0 where x is 0.
    """
    return _Emptying(p, x, l1).all()


def polish(p: ForwardProblem, x: F64, l1: float) -> F64:
    """Empty the occupied cells of ``x`` whose emptying lowers ``S(x) + l1 sum x``.

    One pass over the cells above 0.5, in the order of :func:`emptying_costs` at ``x``
    (cheapest first); each change is recomputed at the map as it stands when the cell's
    turn comes (earlier cells may have been emptied), and the cell set to 0 when the
    objective with the sparsity term falls. The terms' weights ``p.v`` count; the box
    R1 does not change (``x`` in [0, 1]) and R2 is counted.

    Parameters
    ----------
    p : ForwardProblem
        The objective S, ``p.value`` (with its own sparsity term ``p.pen.l1 sum x``,
        to which ``l1`` is added).
    x : ndarray of float64, shape (p.n_cells,)
        The solved map; not modified (clipped to [0, 1] in the copy returned).
    l1 : float
        Cost of occupancy 1 in a cell, >= 0.

    Returns
    -------
    ndarray of float64, shape (p.n_cells,)
        The polished map.
    """
    e = _Emptying(p, np.clip(x, 0.0, 1.0), l1)
    full = np.flatnonzero(e.x > 0.5)
    first = e.all()[full]
    for j in full[np.argsort(first, kind="stable")].tolist():
        if e.change(j) < 0.0:
            e.empty(j)
    return e.x


class _Emptying:
    """A map, its term sums ``X = W x`` and what emptying one cell changes."""

    def __init__(self, p: ForwardProblem, x: F64, l1: float) -> None:
        # The problem's own sparsity term is part of S (``p.value``): emptying a cell
        # saves it as well as the extra ``l1``.
        self.p, self.l1 = p, l1 + p.pen.l1
        self.x = np.array(x, dtype=np.float64)
        self.X = np.asarray(p.W @ self.x, dtype=np.float64)
        W = p.W.tocsc()
        self.ptr, self.rows, self.data = W.indptr, W.indices, W.data

    def _r2(self, v: float) -> float:
        c2 = self.p.pen.c2
        return c2 * (0.5 - abs(v - 0.5)) if self.p.pen.r2 == "tent" else c2 * abs(v - 0.5)

    def change(self, j: int) -> float:
        """``S + l1 sum x`` with cell j emptied, minus as it is (S with its own
        sparsity term ``p.pen.l1 sum x``)."""
        r = self.rows[self.ptr[j] : self.ptr[j + 1]]
        w = self.data[self.ptr[j] : self.ptr[j + 1]]
        xj = float(self.x[j])
        sub = _terms(self.p, r)
        before = sub.term_values(self.X[r])
        after = sub.term_values(self.X[r] - w * xj)
        terms = float(np.sum(after) - np.sum(before))
        return terms + self._r2(0.0) - self._r2(xj) - self.l1 * xj

    def all(self) -> F64:
        """:meth:`change` of every cell (0 where the cell is empty already)."""
        out = np.zeros(len(self.x))
        for j in np.flatnonzero(self.x > 0.0).tolist():
            out[j] = self.change(j)
        return out

    def empty(self, j: int) -> None:
        """Set cell j to 0."""
        r = self.rows[self.ptr[j] : self.ptr[j + 1]]
        self.X[r] -= self.data[self.ptr[j] : self.ptr[j + 1]] * self.x[j]
        self.x[j] = 0.0


def _terms(p: ForwardProblem, r: npt.NDArray[np.int32]) -> ForwardProblem:
    """The problem's terms ``r`` alone (for their values; ``W`` left out)."""
    return dataclasses.replace(p, X0=p.X0[r], is_occ=p.is_occ[r], v=None if p.v is None else p.v[r])


def _stalled(history: list[float], tol: float, patience: int) -> bool:
    """Whether the best objective has improved by less than ``tol`` (relative) lately."""
    if len(history) <= patience:
        return False
    best_then = min(history[:-patience])
    best_now = min(history[-patience:])
    return best_now > best_then - tol * max(abs(best_then), 1.0)


#: Default steps, measured on the doorways and passages scenes: 0.002-0.02 give gd the
#: same maps; pgd keeps them with 0.05-0.1 and stops soonest at 0.05.
STEP = {"gd": 0.02, "pgd": 0.05}


def _descend(
    p: ForwardProblem, x: F64, m: GradientMapper, progress: Progress | None, projected: bool
) -> tuple[F64, int, list[float]]:
    """Subgradient descent; projected on [0, 1] with a 1/sqrt(k) step, or plain and fixed.

    A subgradient method does not decrease the objective monotonically, so the best
    iterate is kept and the run stops when the best has stalled.
    """
    step = m.step if m.step is not None else STEP["pgd" if projected else "gd"]
    if projected:
        x = np.clip(x, 0.0, 1.0)
    # X = W x is kept between the objective and the next subgradient: each step costs
    # the two sparse products W x and W^T P'(X), not three.
    X = p.W @ x
    best, best_x = p.value(x, X), x.copy()
    history = [best]
    k = 0
    for k in range(1, m.max_iter + 1):
        g = p.grad(x, X, box=not projected)
        x = np.clip(x - step / np.sqrt(k) * g, 0.0, 1.0) if projected else x - step * g
        X = p.W @ x
        v = p.value(x, X)
        history.append(v)
        if v < best:
            best, best_x = v, x.copy()
        if progress is not None and k % 50 == 0:
            progress(k, m.max_iter)
        if _stalled(history, m.tol, m.patience):
            break
    return best_x, k, history


def _gd(
    p: ForwardProblem, x: F64, m: GradientMapper, progress: Progress | None
) -> tuple[F64, int, list[float]]:
    return _descend(p, x, m, progress, projected=False)


def _pgd(
    p: ForwardProblem, x: F64, m: GradientMapper, progress: Progress | None
) -> tuple[F64, int, list[float]]:
    return _descend(p, x, m, progress, projected=True)


def _softplus(u: F64, tau: F64) -> tuple[F64, F64]:
    """tau * log(1 + exp(u / tau)) and its derivative, computed stably."""
    z = u / tau
    val = tau * np.logaddexp(0.0, z)
    der = 0.5 * (1.0 + np.tanh(0.5 * z))
    return val, der


def _lbfgs(
    p: ForwardProblem, x: F64, m: GradientMapper, progress: Progress | None
) -> tuple[F64, int, list[float]]:
    below, above = p.slopes()
    base = p.bases()
    # The absolute value's kink smoothed like the tent's, with the opposite sign.
    c2 = -m.c2 if m.r2 == "abs" else m.c2
    l1 = p.pen.l1
    history = [p.value(x)]
    total = 0
    for rnd, kappa in enumerate((0.5, 0.15, 0.03)):
        tau = kappa * p.X0
        eps = kappa * 0.1

        def fun(z: F64, tau: F64 = tau, eps: float = eps) -> tuple[float, F64]:
            X = p.W @ z
            sp_val, sp_der = _softplus(X - p.X0, tau)
            f = base + below * X + (above - below) * sp_val
            dfdX = below + (above - below) * sp_der
            u = z - 0.5
            root = np.sqrt(u * u + eps * eps)
            r2 = c2 * (0.5 - (root - eps))
            dr2 = -c2 * u / root
            value = float(np.sum(f) + np.sum(r2)) + l1 * float(np.sum(z))
            return value, np.asarray(p.WT @ dfdX) + dr2 + l1

        res = so.minimize(
            fun,
            x,
            jac=True,
            method="L-BFGS-B",
            bounds=so.Bounds(np.zeros_like(x), np.ones_like(x)),
            options={"maxiter": max(1, m.max_iter // 3), "gtol": 1e-9, "ftol": m.tol * 1e-3},
        )
        x = np.asarray(res.x)
        total += int(res.nit)
        history.append(p.value(x))
        if progress is not None:
            progress(rnd + 1, 3)
    return x, total, history


def _ccp(
    p: ForwardProblem, x: F64, m: GradientMapper, progress: Progress | None
) -> tuple[F64, int, list[float]]:
    below, above = p.slopes()
    base = p.bases()
    at_x0 = base + below * p.X0
    n, t = p.n_cells, p.n_terms
    convex = m.r2 == "abs"
    # The printed R2 is convex: c2 |x - 0.5| becomes c2 s with s >= +-(x - 0.5), n more
    # variables and 2n more rows, so the LP holds the whole objective.
    s_n = n if convex else 0
    eye = sp.identity(t, format="csr")
    none = sp.csr_matrix((t, s_n))
    # t_r >= base_r + below_r X_r  and  t_r >= at_x0_r + above_r (X_r - X0_r)
    rows = [
        sp.hstack([sp.diags(below) @ p.W, -eye, none]),
        sp.hstack([sp.diags(above) @ p.W, -eye, none]),
    ]
    b_parts = [-base, -(at_x0 - above * p.X0)]
    if convex:
        one, zero = sp.identity(n, format="csr"), sp.csr_matrix((n, t))
        rows += [sp.hstack([one, zero, -one]), sp.hstack([-one, zero, -one])]
        b_parts += [np.full(n, 0.5), np.full(n, -0.5)]
    A = sp.vstack(rows).tocsr()
    b = np.concatenate(b_parts)
    bounds = [(0.0, 1.0)] * n + [(None, None)] * t + [(0.0, None)] * s_n
    x = np.clip(x, 0.0, 1.0)
    history = [p.value(x)]
    k = 0
    for k in range(1, min(m.max_iter, 30) + 1):
        # reg_grad holds the sparsity term's slope; the convex form's LP needs it alone.
        g = np.full(n, p.pen.l1) if convex else p.reg_grad(x, box=False)
        c = np.concatenate([g, np.ones(t), np.full(s_n, m.c2)])
        res = so.linprog(c, A_ub=A, b_ub=b, bounds=bounds, method="highs")
        if res.status != 0:
            break
        new = np.clip(np.asarray(res.x[:n]), 0.0, 1.0)
        history.append(p.value(new))
        moved = float(np.max(np.abs(new - x)))
        x = new
        if progress is not None:
            progress(k, 30)
        if moved < 1e-6:
            break
    return x, k, history


# -- streaming -----------------------------------------------------------------------

#: A cell's step in streaming is ``step / sqrt(k)`` after its k-th update, with k capped
#: here so that a cell seen for a long time still follows new evidence.
STREAM_STEP_CAP = 100


#: Terms whose sums :func:`_term_sums` runs side by side (its column loop is written
#: out for eight: two AVX2 vectors' worth, enough to hide an addition's latency).
LANES = 8


@nb.njit(cache=True)
def _term_sums(
    t_start: npt.NDArray[np.int64],
    t_spans: npt.NDArray[np.int64],
    t_len: npt.NDArray[np.int64],
    order: npt.NDArray[np.int64],
    sp_cell: npt.NDArray[np.int32],
    sp_len: npt.NDArray[np.int32],
    sp_w: npt.NDArray[np.float32],
    x: F64,
    out: F64,
    buf: F64,
) -> None:
    """``out[t]``: the sum of ``w x[c]`` over the entries of term t, added in their order.

    Term t is spans ``t_start[t] .. t_start[t] + t_spans[t]`` holding ``t_len[t]``
    entries. Each sum is the one a loop over the entries makes, to the bit: its
    additions come in the same order. A single such loop waits on every addition (a
    float sum is not reassociated), so the terms go :data:`LANES` at a time, in
    ``order`` (by length, so that a group needs little padding): each term's products
    are laid out in a row of ``buf`` (at least ``LANES`` times the longest term), the
    shorter rows padded with +0.0, and the rows are summed column by column, the
    ``LANES`` additions of a column independent of each other. Padding changes no sum:
    a partial sum starting from +0.0 is never -0.0, and adding +0.0 to anything else
    leaves it as it is.
    """
    n_terms = order.shape[0]
    for g0 in range(0, n_terms, LANES):
        m = 0
        for lane in range(min(LANES, n_terms - g0)):
            m = max(m, t_len[order[g0 + lane]])
        for lane in range(LANES):
            k = lane * m
            if g0 + lane < n_terms:
                t = order[g0 + lane]
                for q in range(t_start[t], t_start[t] + t_spans[t]):
                    wq = np.float64(sp_w[q])
                    n = sp_len[q]
                    xs = x[sp_cell[q] : sp_cell[q] + n]
                    row = buf[k : k + n]
                    for i in range(n):
                        row[i] = wq * xs[i]
                    k += n
            buf[k : (lane + 1) * m] = 0.0
        b0 = buf[0:m]
        b1 = buf[m : 2 * m]
        b2 = buf[2 * m : 3 * m]
        b3 = buf[3 * m : 4 * m]
        b4 = buf[4 * m : 5 * m]
        b5 = buf[5 * m : 6 * m]
        b6 = buf[6 * m : 7 * m]
        b7 = buf[7 * m : 8 * m]
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
        for i in range(m):
            s0 += b0[i]
            s1 += b1[i]
            s2 += b2[i]
            s3 += b3[i]
            s4 += b4[i]
            s5 += b5[i]
            s6 += b6[i]
            s7 += b7[i]
        sums = (s0, s1, s2, s3, s4, s5, s6, s7)
        for lane in range(min(LANES, n_terms - g0)):
            out[order[g0 + lane]] = sums[lane]


#: Machine epsilon of float64, for :func:`_stream_steps`' rounding allowance.
EPS = float(np.finfo(np.float64).eps)


@nb.njit(cache=True, inline="always")
def _slot_term(
    s: int,
    part: int,
    fs_start: npt.NDArray[np.int64],
    fs_len: npt.NDArray[np.int64],
    os_start: npt.NDArray[np.int64],
    os_len: npt.NDArray[np.int64],
    f_len: npt.NDArray[np.int64],
    o_len: npt.NDArray[np.int64],
    f_sum: F64,
    o_sum: F64,
    echo: npt.NDArray[np.bool_],
) -> tuple[int, int, int, float]:
    """Slot ``s``'s free (``part`` 0) or occ (1) term as the pool's spans: its first
    span, spans, entries and total weight; no entries for a no-echo reading's occ term."""
    if part == 0:
        return fs_start[s], fs_len[s], f_len[s], f_sum[s]
    if not echo[s]:
        return 0, 0, 0, 0.0
    return os_start[s], os_len[s], o_len[s], o_sum[s]


@nb.njit(cache=True, inline="always")
def _side_unknown(known_x: float, known_at: float, drift: float, m: int, x0: float) -> bool:
    """Whether a term's X, known as ``known_x`` when the moves totalled ``known_at``,
    may since have crossed X0 = ``x0`` (the moves now total ``drift``; ``m`` entries):
    then it must be summed again. See :func:`_stream_steps`."""
    moved = (drift - known_at) * (1.0 + 1e-6)
    return not abs(known_x - x0) > moved + 4.0 * (m + 4) * EPS


@nb.njit(cache=True, inline="always")
def _term_slope(part: int, big_x: float, x0: float, a1: float, a2: float) -> tuple[bool, float]:
    """The slope of a free (``part`` 0) or occ (1) term in X on the side of X0 = ``x0``
    where ``big_x`` lies, and False at X0 itself (no side: the term adds nothing)."""
    if part == 0:
        below = a1
        above = (1.0 - a1 * x0) / (1.0 - x0) if x0 < 1.0 else a1
    else:
        below = -(1.0 - a2 + a2 * x0) / x0
        above = -a2
    if big_x < x0:
        return True, below
    if big_x > x0:
        return True, above
    return False, 0.0


@nb.njit(cache=True)
def _stream_steps(
    sel: npt.NDArray[np.int64],
    fs_start: npt.NDArray[np.int64],
    fs_len: npt.NDArray[np.int64],
    os_start: npt.NDArray[np.int64],
    os_len: npt.NDArray[np.int64],
    f_len: npt.NDArray[np.int64],
    o_len: npt.NDArray[np.int64],
    f_sum: F64,
    o_sum: F64,
    echo: npt.NDArray[np.bool_],
    sp_cell: npt.NDArray[np.int32],
    sp_len: npt.NDArray[np.int32],
    sp_w: npt.NDArray[np.float32],
    x: F64,
    g: F64,
    dirty: npt.NDArray[np.int64],
    cov: npt.NDArray[np.int32],
    kcount: npt.NDArray[np.int32],
    a1: float,
    a2: float,
    steps: F64,
    n_steps: int,
    known: F64,
    known_at: F64,
    drift: F64,
    fixed: F64 | None = None,
) -> None:
    """Projected subgradient steps on the cells ``dirty``, over the terms of ``sel``.

    The P terms of the offline objective (see ``_forward``) on the box [0, 1]; every
    term touching a cell of ``dirty`` is in ``sel``, so the gradient there is exact.
    The concave tent R2 is left out: see :class:`GradientStream`. A cell's k-th step
    (k counted in ``kcount``, capped at the length of ``steps``) is ``steps[k - 1]``
    times its gradient.

    The terms are read as the pool's spans (free then occ entries of each slot, in
    arena order), so both passes over a term go through slices of the map: its value
    ``X = W x`` by :func:`_term_sums`, its gradient into ``g``, which numba vectorises.
    ``g`` is zero on entry and on return.

    A term's gradient needs of X only which side of X0 it lies on, and X is a mean of
    the map weighted by w >= 0, so it moves by at most the largest move of any cell.
    ``known[s, part]`` keeps the X last summed for each slot's free (0) and occ (1)
    term, ``known_at[s, part]`` the value then of ``drift[0]``, the running total of
    every step's largest move, rounded up (-inf: nothing known, as for a reading just
    entered). While X was farther from X0 than the moves since (with 1e-6 of them to
    spare for the rounding of the moves, their total and the weights' total) plus an
    allowance for the rounding of two sums of n products (4 (n + 4) eps, above their
    error bound), the side is the one a new sum would give, and the known X stands in
    for it. Otherwise the term is summed again. Either way the slopes, and so the map,
    are the ones summing every term at every step gives, to the bit. On the office
    ring a term's X lies 0.3-0.5 from X0 and the map moves by 0.005 an update, so most
    terms are summed once, when they enter.

    ``fixed`` (per grid cell), when given, is added to each dirty cell's gradient: the
    terms of readings that have left, frozen at their slope then (:func:`_fold_terms`).
    """
    n_terms = 0
    t_start = np.empty(2 * sel.shape[0], np.int64)
    t_spans = np.empty(2 * sel.shape[0], np.int64)
    t_len = np.empty(2 * sel.shape[0], np.int64)
    t_tot = np.empty(2 * sel.shape[0])
    t_slot = np.empty(2 * sel.shape[0], np.int64)
    t_part = np.empty(2 * sel.shape[0], np.int64)
    for s in sel:
        for part in range(2):
            a, n, m, tot = _slot_term(
                s, part, fs_start, fs_len, os_start, os_len, f_len, o_len, f_sum, o_sum, echo
            )
            if m == 0 or tot <= 0.0:
                continue
            t_start[n_terms] = a
            t_spans[n_terms] = n
            t_len[n_terms] = m
            t_tot[n_terms] = tot
            t_slot[n_terms] = s
            t_part[n_terms] = part
            n_terms += 1
    big = np.empty(n_terms)
    due = np.empty(n_terms, np.int64)
    k_cap = steps.shape[0]
    for _ in range(n_steps):
        n_due = 0
        longest = 0
        for t in range(n_terms):
            s, part = t_slot[t], t_part[t]
            x0 = 1.0 / t_tot[t]
            if _side_unknown(known[s, part], known_at[s, part], drift[0], t_len[t], x0):
                due[n_due] = t
                n_due += 1
                longest = max(longest, t_len[t])
        if n_due > 0:
            order = due[:n_due][np.argsort(t_len[due[:n_due]])]
            buf = np.empty(LANES * longest)
            _term_sums(t_start, t_spans, t_len, order, sp_cell, sp_len, sp_w, x, big, buf)
            for t in due[:n_due]:
                known[t_slot[t], t_part[t]] = big[t] / t_tot[t]
                known_at[t_slot[t], t_part[t]] = drift[0]
        lo = g.shape[0]
        hi = 0
        for t in range(n_terms):
            tot = t_tot[t]
            sided, slope = _term_slope(t_part[t], known[t_slot[t], t_part[t]], 1.0 / tot, a1, a2)
            if not sided:
                continue
            f = slope / tot
            for q in range(t_start[t], t_start[t] + t_spans[t]):
                fw = f * np.float64(sp_w[q])
                c0 = sp_cell[q]
                n = sp_len[q]
                lo = min(lo, c0)
                hi = max(hi, c0 + n)
                gs = g[c0 : c0 + n]
                for i in range(n):
                    gs[i] += fw
        largest = 0.0
        for c in dirty:
            if cov[c] > 0:
                k = min(kcount[c] + 1, k_cap)
                kcount[c] = k
                gc = g[c]
                if fixed is not None:
                    gc += fixed[c]
                v = x[c] - steps[k - 1] * gc
                v = min(max(v, 0.0), 1.0)
                largest = max(largest, abs(v - x[c]))
                x[c] = v
        # Rounded up, so that a difference of two totals never falls short of the
        # moves between them, however long the stream (the subtraction of two totals
        # is then off by at most its own rounding, which the 1e-6 above covers).
        drift[0] = (drift[0] + largest) * (1.0 + 2.0 * EPS)
        # Cells outside ``dirty`` gathered gradient too (testing each entry's cell
        # cost more than clearing the range); nothing reads it, and it is cleared.
        g[lo:hi] = 0.0


@nb.njit(cache=True)
def _fold_terms(
    gone: npt.NDArray[np.int64],
    fs_start: npt.NDArray[np.int64],
    fs_len: npt.NDArray[np.int64],
    os_start: npt.NDArray[np.int64],
    os_len: npt.NDArray[np.int64],
    f_len: npt.NDArray[np.int64],
    o_len: npt.NDArray[np.int64],
    f_sum: F64,
    o_sum: F64,
    echo: npt.NDArray[np.bool_],
    sp_cell: npt.NDArray[np.int32],
    sp_len: npt.NDArray[np.int32],
    sp_w: npt.NDArray[np.float32],
    x: F64,
    a1: float,
    a2: float,
    known: F64,
    known_at: F64,
    drift: F64,
    fixed: F64,
) -> None:
    """Add to ``fixed`` the gradient of the terms of the slots ``gone`` at the map ``x``:
    each term linearised where it stands when its reading leaves (its slope on the side
    of X0 its X lies, as :func:`_stream_steps` takes it), so that it keeps pulling its
    cells as it did, without its reading. A term's X is summed again only when the
    known one (``known``, ``known_at``, ``drift``: see :func:`_stream_steps`) cannot
    tell its side."""
    for s in gone:
        for part in range(2):
            a, n, m, tot = _slot_term(
                s, part, fs_start, fs_len, os_start, os_len, f_len, o_len, f_sum, o_sum, echo
            )
            if m == 0 or tot <= 0.0:
                continue
            x0 = 1.0 / tot
            big_x = known[s, part]
            if _side_unknown(big_x, known_at[s, part], drift[0], m, x0):
                big = 0.0
                for q in range(a, a + n):
                    c0 = sp_cell[q]
                    w = np.float64(sp_w[q])
                    for i in range(sp_len[q]):
                        big += w * x[c0 + i]
                big_x = big / tot
            sided, slope = _term_slope(part, big_x, x0, a1, a2)
            if not sided:
                continue
            f = slope / tot
            for q in range(a, a + n):
                c0 = sp_cell[q]
                fw = f * np.float64(sp_w[q])
                fs = fixed[c0 : c0 + sp_len[q]]
                for i in range(sp_len[q]):
                    fs[i] += fw


def stream_step_sizes(step: float, k_cap: int = STREAM_STEP_CAP) -> F64:
    """The step of a cell's k-th update, k = 1 .. ``k_cap``: ``step / sqrt(k)``."""
    return np.array([step / math.sqrt(k) for k in range(1, k_cap + 1)])


class GradientStream(StreamEngine):
    """The gradient method over a bounded set of readings.

    Each update adds the entering readings' terms to the objective and drops the leaving
    ones' (the pool holds each term's cells and weights), then takes ``effort`` projected
    subgradient steps on the cells those readings touch, warm-started from the current
    map, against every term in play that touches them. :meth:`improve` takes steps over
    every term in play. The mapper's ``solver``, ``max_iter``, ``tol`` and ``patience``
    are for the offline solve and are not used here.

    The stream minimises the P terms on the box [0, 1] without the tent R2 (``c2``).
    The tent is concave: it pushes each cell towards 0 or 1 on whatever evidence it has
    when first seen, and a cell at 1 cannot come back, because each later free term
    pulls it by only ``a1 w0 / sum w0``. Measured on the first minute of the ``office``
    scene (last:1000, one step per 0.5 s update): with the tent the binarised streaming
    map agrees with the offline map on 96.0 % of cells (F1 0.13 against the offline
    0.29); without it on 99.6 % (F1 0.285).
    """

    spans = True
    can_fold = True

    def _setup(self) -> None:
        m = self.mapper
        assert isinstance(m, GradientMapper)
        self.x = np.full(self.grid.size, 0.5)
        self._g = np.zeros(self.grid.size)
        self._k = np.zeros(self.grid.size, np.int32)
        self._steps = stream_step_sizes(m.step if m.step is not None else STEP["pgd"])
        # Each slot's terms' last X, when it was summed and how far the map has moved
        # since the stream began (see _stream_steps).
        self._known = np.zeros((self.pool.capacity, 2))
        self._known_at = np.full((self.pool.capacity, 2), -np.inf)
        self._drift = np.zeros(1)
        #: Per cell, the gradient of the terms of readings that have left (see _leave).
        self.fixed = np.zeros(self.grid.size)
        self.steps_ = 0

    def default_fold(self, mapper: Mapper) -> bool:
        # The fold keeps a wall's echoes against the no-echo beams that would clear it
        # once they have left; with no-echo readings ignored there are none, and the
        # fold's frozen slopes cost walls over long training logs (the measurements:
        # docs/results/2026-12-06-streaming.md, "fifth pass").
        assert isinstance(mapper, GradientMapper)
        return mapper.no_echo == "free"

    def _leave(self, gone: npt.NDArray[np.int64]) -> None:
        # A leaving reading's terms keep pulling their cells, frozen at their slope of
        # the moment: without them a wall's cells lose their echoes when those leave,
        # and the long no-echo beams still in play clear them.
        if len(gone) == 0 or not self.fold:
            return
        m = self.mapper
        assert isinstance(m, GradientMapper)
        p = self.pool
        _fold_terms(
            gone,
            *p.span_terms(),
            self.x,
            m.a1,
            m.a2,
            self._known,
            self._known_at,
            self._drift,
            self.fixed,
        )

    def _enter(self, new: npt.NDArray[np.int64]) -> None:
        cap = self.pool.capacity
        if len(self._known) < cap:
            grow = cap - len(self._known)
            self._known = np.concatenate([self._known, np.zeros((grow, 2))])
            self._known_at = np.concatenate([self._known_at, np.full((grow, 2), -np.inf)])
        # A slot's new reading is not the one its X was summed for.
        self._known_at[new] = -np.inf

    def _run(self, sel: npt.NDArray[np.int64], dirty: npt.NDArray[np.int64], n: int) -> None:
        m = self.mapper
        assert isinstance(m, GradientMapper)
        p = self.pool
        _stream_steps(
            sel,
            *p.span_terms(),
            self.x,
            self._g,
            dirty,
            self.cov,
            self._k,
            m.a1,
            m.a2,
            self._steps,
            n,
            self._known,
            self._known_at,
            self._drift,
            self.fixed if self.fold else None,
        )
        self.steps_ += n

    def _optimise(self, dirty: npt.NDArray[np.int64], box: tuple[int, int, int, int]) -> None:
        self._run(self.touching_dirty(box), dirty, self.effort)

    def improve(self, budget: float) -> int:
        return self._improve_with(budget, lambda sel, cells: self._run(sel, cells, 1))

    def finish(self, passes: int, stop: Callable[[], bool] | None = None) -> int:
        # A cell takes a step only in the updates whose readings touch it, and most
        # leave the window short of the optimum over the readings in play.
        return self._finish_with(passes, stop, lambda sel, cells: self._run(sel, cells, 1))

    def nbytes(self) -> int:
        """Memory of the state: the base engine's plus the map, its gradient and step
        counts, the folded evidence and each slot's summed terms."""
        own = (self.x, self._g, self._k, self.fixed, self._known, self._known_at, self._steps)
        return super().nbytes() + sum(int(a.nbytes) for a in own)

    def occupancy(self) -> npt.NDArray[np.float32]:
        # Not the folded terms' own optimum (0 or 1 by the sign of the fixed gradient)
        # where no reading in play touches a cell: the fold freezes each term's slope
        # on its side of X0, and over long logs the frozen occ slopes outweigh the
        # free ones on cells the steps had left free (benchmarks/stream_finish.py).
        return self._seen_only(self.x)


GradientMapper.streamer = GradientStream
