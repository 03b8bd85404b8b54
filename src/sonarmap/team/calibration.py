"""The robot's own odometry calibrated from its pose graph: a heading bias per metre.

Wheel odometry whose two wheels differ in diameter turns by a constant amount per metre
driven (an error of the wheel base instead turns in proportion to the angle turned); the
simulator injects the first as ``bias_theta`` (:func:`~sonarmap.team.world.odometry`).
The odometry model counts it as independent noise per edge, so along a stretch that no
closure reaches the graph follows the biased odometry, and the error grows with the
square of the stretch's length. The robot cannot know the bias in advance, but every
optimised graph measures it: each odometry edge's heading change as the optimised
estimates give it, minus the edge's own, is ``-bias x length`` plus noise. The least
squares slope over the robot's own edges, with its standard error, is one step of the
estimate (:func:`heading_bias_fit`). The residuals are neither independent (the graph
spreads a closure's correction over a stretch of consecutive edges) nor alike (a
composed edge is long and noisy), so the standard error is a batch-means one over
contiguous stretches of the trajectory (:func:`slope_stderr`), as the ordinary one
understates it; but with few stretches the batch sums can cancel and that error
collapses, so the gate takes the larger of the two and needs :data:`MIN_BATCHES`
stretches. The estimate so far plus the step is applied only when it exceeds the
Student-t threshold at the :data:`SIGNIFICANCE` level (:func:`critical_value`) times
that error, and is otherwise 0 (:func:`gated_bias`), so an odometry without the bias is
left as measured unless the graph shows one. Each new edge's covariance counts the
robot's prior :data:`HEADING_BIAS_PRIOR` as noise, calibrating or not, or, if the robot
is told to (``RobotAgent(bias_sd="remaining")``), what the calibration leaves of the
bias (its standard error, or the estimate not applied; :func:`remaining_bias_sd`). A
robot alone (:class:`~sonarmap.team.mission.RobotAgent`) updates its estimate batch
after batch, corrects every odometry edge it stores by each change
(:func:`debias_edges`) and each new one by the estimate so far, as an odometry
calibration from loop closures does. The store composes edges when it deletes a pose,
so the edges are corrected where they are kept, not only in the graph.

Only this one term is modelled: a wheel-base error (heading error per radian turned) or
a scale error is not estimated.

An edge's length is the straight distance between its poses (poses are made every
metre or half radian, where the path and the chord differ by centimetres).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.stats import norm as normal
from scipy.stats import t as student_t

from .records import OdometryEdge

__all__ = [
    "HEADING_BIAS_PRIOR",
    "MAX_HEADING_BIAS",
    "MIN_BATCHES",
    "SIGNIFICANCE",
    "BiasFit",
    "batches",
    "bias_fit",
    "calibrated_bias",
    "critical_value",
    "debias",
    "debias_edges",
    "gated_bias",
    "heading_bias_fit",
    "heading_bias_step",
    "remaining_bias_sd",
    "slope_stderr",
]

F64 = npt.NDArray[np.float64]

#: Radians per metre: the largest bias an estimate may reach (wheels 5 % apart in
#: diameter on a 0.3 m wheel base turn about 0.17 rad per metre; ten times the simulated
#: 0.003 is still far beyond a robot that drives straight enough to patrol).
MAX_HEADING_BIAS = 0.05

#: Radians per metre: the robot's prior on the size of its heading bias, the standard
#: deviation its edges' covariance counts before a calibration measures it, and always
#: when the robot does not calibrate (:func:`~sonarmap.team.world.odometry_covariance`).
#: Wheels matched to 0.1 % in diameter on a 0.3 m wheel base turn 0.0033 rad per metre;
#: a robot's maker can state that, not the bias itself. (The simulator's default bias is
#: the same 0.003, :data:`~sonarmap.team.world.ODOMETRY_NOISE`; the prior is not read
#: from it.)
HEADING_BIAS_PRIOR = 0.003

#: The significance gate's level as a normal's standard errors: about the two-sided 5 %
#: level, a statistical convention, not a tuned value. A step of the estimate must
#: exceed the Student-t quantile at the same level (:func:`critical_value`).
SIGNIFICANCE = 2.0

#: The fewest batches (:func:`batches`; 92 edges) whose fit may change the applied
#: bias (:func:`gated_bias`): with three or four, the batch sums of an optimised graph's
#: residuals can cancel and the batch-means error collapse (with the ordinary error as a
#: floor, a few batches would also leave the Student-t threshold too wide to find a
#: bias: 4.5 standard errors at 2 degrees of freedom, 2.9 at 4). Stated, not tuned.
MIN_BATCHES = 5


class BiasFit(NamedTuple):
    """A least-squares fit of the heading bias on a graph's odometry edges.

    Attributes
    ----------
    step : float
        Radians per metre to add to the bias the edges were corrected with.
    stderr : float
        The slope's standard error allowing for the residuals' correlation along the
        trajectory and their unequal variances (batch means, :func:`slope_stderr`),
        radians per metre; inf with fewer than two edges of nonzero length. The
        significance gate takes the larger of it and :attr:`stderr_iid`.
    edges : int
        The edges the fit used.
    stderr_iid : float
        The ordinary least-squares standard error, which takes the residuals as
        independent, radians per metre: the gate's floor (:func:`gated_bias`).
    dof : int
        ``stderr``'s degrees of freedom: the batches less one (:func:`critical_value`).
    """

    step: float
    stderr: float
    edges: int
    stderr_iid: float = math.inf
    dof: int = 0


def debias(transform: Sequence[float] | F64, bias: float) -> tuple[float, float, float]:
    """Remove a heading bias from one odometry step.

    Parameters
    ----------
    transform : sequence of 3 floats
        The step ``(x, y, theta)``: the second pose in the first's frame, metres and
        radians.
    bias : float
        Radians per metre.

    Returns
    -------
    tuple of 3 floats
        The heading change less ``bias`` times the step's length, the translation turned
        back by half of that (the bias turned the robot gradually along the step).
    """
    x, y, theta = (float(v) for v in transform)
    turn = bias * math.hypot(x, y)
    c, s = math.cos(-turn / 2), math.sin(-turn / 2)
    return (c * x - s * y, s * x + c * y, theta - turn)


def debias_edges(edges: Sequence[OdometryEdge], bias: float) -> list[OdometryEdge]:
    """Remove a heading bias from odometry edges.

    Parameters
    ----------
    edges : sequence of OdometryEdge
    bias : float
        Radians per metre.

    Returns
    -------
    list of OdometryEdge
        The edges with their transforms :func:`debias`-ed (covariances unchanged); the
        same items when ``bias`` is 0.
    """
    if bias == 0.0:
        return list(edges)
    return [replace(e, transform=debias(e.transform, bias)) for e in edges]


def batches(n: int) -> int:
    """The contiguous stretches :func:`slope_stderr` cuts ``n`` edges into.

    Parameters
    ----------
    n : int
        Edges.

    Returns
    -------
    int
        ``round(n^(1/3))``, at least 2 and at most ``n``: batches of about ``n^(2/3)``
        edges, the usual batch-means rule (batches long against the correlation, enough
        of them to estimate the variance; Flegal and Jones, Annals of Statistics 38(2),
        2010), stated, not tuned.
    """
    return max(2, min(n, round(math.cbrt(n))))


def slope_stderr(d: F64, e: F64, count: int) -> float:
    """The batch-means standard error of a least-squares slope through the origin.

    Parameters
    ----------
    d : ndarray (n,)
        The regressor (edge lengths, metres), in trajectory order.
    e : ndarray (n,)
        The fit's residuals, in the same order.
    count : int
        The batches ``B``: contiguous stretches of (nearly) equal edge counts.

    Returns
    -------
    float
        ``sqrt(B / (B - 1) sum_k (sum_{t in k} d_t e_t)^2) / sum_t d_t^2``: the slope's
        sandwich variance with the scores summed within each stretch, so the residuals'
        correlation along the trajectory and their unequal variances (a composed edge
        is long and noisy) both count, as long as the stretches are long against the
        correlation. The ratio of the slope to it is Student-t with ``B - 1`` degrees of
        freedom (the cluster-robust variance of a regression on ``B`` clusters). Inf
        with fewer than two batches or no length.
    """
    n = len(d)
    den = float(d @ d)
    if count < 2 or n < count or den <= 0:
        return math.inf
    u = d * e
    sums = np.array([float(part.sum()) for part in np.array_split(u, count)])
    return math.sqrt(float(sums @ sums) * count / (count - 1)) / den


def critical_value(dof: int) -> float:
    """The significance gate's threshold in standard errors.

    Parameters
    ----------
    dof : int
        The standard error's degrees of freedom (batches less one).

    Returns
    -------
    float
        The Student-t quantile with ``dof`` degrees of freedom at the normal's
        :data:`SIGNIFICANCE` quantile (two-sided 4.6 % at 2): 2.0 for many batches, 2.3
        for 9, 4.5 for 2; inf for none.
    """
    if dof < 1:
        return math.inf
    return float(student_t.ppf(normal.cdf(SIGNIFICANCE), dof))


def heading_bias_fit(edges: Sequence[OdometryEdge], estimates: Mapping[int, F64]) -> BiasFit:
    """Fit the heading bias the optimised estimates still show on the edges.

    Parameters
    ----------
    edges : sequence of OdometryEdge
        The robot's own odometry edges, as stored (corrected by the bias so far), in any
        order: they are taken in trajectory order (their first pose's UID, which a robot
        numbers as it goes).
    estimates : mapping of int to ndarray (3,)
        The optimised poses ``x, y, theta`` by UID; edges naming a pose without one are
        skipped.

    Returns
    -------
    BiasFit
        The least-squares slope through the origin of each edge's heading residual (the
        estimates' heading change less the edge's, radians) on its length (metres),
        negated; its batch-means standard error (:func:`slope_stderr` over
        :func:`batches` stretches of the trajectory), since the optimised graph spreads
        a closure's correction over a stretch of consecutive edges, whose residuals are
        therefore correlated, and composed edges are longer and noisier than the rest;
        and the ordinary (independent, equal residuals) standard error, for comparison.
        A step of 0 and infinite errors when no edge has a length.
    """
    r_list: list[float] = []
    d_list: list[float] = []
    for e in sorted(edges, key=lambda e: (e.a, e.b)):
        a, b = estimates.get(e.a), estimates.get(e.b)
        if a is None or b is None:
            continue
        d_list.append(math.hypot(e.transform[0], e.transform[1]))
        r_list.append(math.remainder(float(b[2]) - float(a[2]) - e.transform[2], 2 * math.pi))
    return bias_fit(np.array(d_list), np.array(r_list))


def bias_fit(d: F64, r: F64) -> BiasFit:
    """:func:`heading_bias_fit` on its edges' lengths and heading residuals.

    Parameters
    ----------
    d : ndarray (n,)
        The edges' lengths, metres, in trajectory order.
    r : ndarray (n,)
        Their heading residuals (the estimates' heading change less the edge's),
        radians.

    Returns
    -------
    BiasFit
        As :func:`heading_bias_fit`.
    """
    den = float(d @ d) if len(d) else 0.0
    if den <= 0:
        return BiasFit(0.0, math.inf, 0, math.inf, 0)
    slope = float(r @ d) / den
    n = int(np.count_nonzero(d))
    if n < 2:
        return BiasFit(-slope, math.inf, n, math.inf, 0)
    resid = r - slope * d
    iid = math.sqrt(float(resid @ resid) / (len(d) - 1) / den)
    count = batches(len(d))
    return BiasFit(-slope, slope_stderr(d, resid, count), n, iid, count - 1)


def heading_bias_step(edges: Sequence[OdometryEdge], estimates: Mapping[int, F64]) -> float:
    """The step of the heading bias, significant or not.

    Parameters
    ----------
    edges, estimates
        As for :func:`heading_bias_fit`.

    Returns
    -------
    float
        :func:`heading_bias_fit`'s step, radians per metre.
    """
    return heading_bias_fit(edges, estimates).step


def gated_bias(current: float, fit: BiasFit) -> float:
    """The heading bias to correct the odometry by, given one more fit.

    Parameters
    ----------
    current : float
        The bias the fitted edges were corrected with, radians per metre.
    fit : BiasFit
        :func:`heading_bias_fit` on those edges.

    Returns
    -------
    float
        ``current`` unchanged when the fit has fewer than :data:`MIN_BATCHES`
        batches (``fit.dof + 1``). Otherwise ``current`` plus the fit's step when that
        total exceeds :func:`critical_value` (``fit.dof``) times the larger of the
        fit's two standard errors (:attr:`BiasFit.stderr`, :attr:`BiasFit.stderr_iid`),
        else 0 (an estimate the graph cannot tell from noise is not applied, and one
        applied earlier is taken back), clipped to :data:`MAX_HEADING_BIAS`; radians per
        metre.

    Notes
    -----
    The batch-means error can only be trusted with enough batches: the residuals of
    an optimised graph sum nearly to zero over a stretch a closure spans, so with
    three or four batches their sums, and the error, can collapse far below the
    scatter of the residuals (on a 300 s office mission without a bias, 74 edges in 4
    batches gave a batch-means error 8 times below the ordinary one and a step of 15
    of it). Hence the minimum number of batches, and the larger of the two errors: the
    ordinary one is the floor that residuals which do not cancel would give.
    """
    if fit.dof + 1 < MIN_BATCHES:
        return current
    total = current + fit.step
    if not abs(total) > critical_value(fit.dof) * max(fit.stderr, fit.stderr_iid):
        return 0.0
    return min(MAX_HEADING_BIAS, max(-MAX_HEADING_BIAS, total))


def calibrated_bias(
    current: float, edges: Sequence[OdometryEdge], estimates: Mapping[int, F64]
) -> float:
    """The heading bias to correct the odometry by after one more optimised graph.

    Parameters
    ----------
    current : float
        The bias the ``edges`` were corrected with, radians per metre.
    edges, estimates
        As for :func:`heading_bias_fit`.

    Returns
    -------
    float
        :func:`gated_bias` of :func:`heading_bias_fit`, radians per metre.
    """
    return gated_bias(current, heading_bias_fit(edges, estimates))


def remaining_bias_sd(current: float, fit: BiasFit, applied: float) -> float:
    """The robot's uncertainty about the heading bias left once ``applied`` is taken out.

    Parameters
    ----------
    current : float
        The bias the fitted edges were corrected with, radians per metre.
    fit : BiasFit
        :func:`heading_bias_fit` on those edges.
    applied : float
        The bias now applied (:func:`gated_bias`), radians per metre.

    Returns
    -------
    float
        ``hypot(current + step - applied, stderr)``, radians per metre: the root mean
        square of the bias left, with the estimate ``current + step`` and its standard
        error (the estimate not applied counts in full); :data:`HEADING_BIAS_PRIOR`
        when the fit has no finite error yet.
    """
    if not math.isfinite(fit.stderr):
        return HEADING_BIAS_PRIOR
    return math.hypot(current + fit.step - applied, fit.stderr)
