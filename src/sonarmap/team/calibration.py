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
estimate (:func:`heading_bias_fit`). The estimate so far plus the step is applied only
when it exceeds :data:`SIGNIFICANCE` standard errors, and is otherwise 0
(:func:`calibrated_bias`), so an odometry without the bias is left as measured unless
the graph shows one. A robot alone (:class:`~sonarmap.team.mission.RobotAgent`) updates
its estimate batch after batch, corrects every odometry edge it stores by each change
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

from .records import OdometryEdge

__all__ = [
    "MAX_HEADING_BIAS",
    "SIGNIFICANCE",
    "BiasFit",
    "calibrated_bias",
    "debias",
    "debias_edges",
    "heading_bias_fit",
    "heading_bias_step",
]

F64 = npt.NDArray[np.float64]

#: Radians per metre: the largest bias an estimate may reach (wheels 5 % apart in
#: diameter on a 0.3 m wheel base turn about 0.17 rad per metre; ten times the simulated
#: 0.003 is still far beyond a robot that drives straight enough to patrol).
MAX_HEADING_BIAS = 0.05

#: Standard errors a step of the estimate must exceed to be taken: about the two-sided
#: 5 % level, a statistical convention, not a tuned value.
SIGNIFICANCE = 2.0


class BiasFit(NamedTuple):
    """A least-squares fit of the heading bias on a graph's odometry edges.

    Attributes
    ----------
    step : float
        Radians per metre to add to the bias the edges were corrected with.
    stderr : float
        The slope's standard error, radians per metre (inf with fewer than two edges
        of nonzero length).
    edges : int
        The edges the fit used.
    """

    step: float
    stderr: float
    edges: int


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


def heading_bias_fit(edges: Sequence[OdometryEdge], estimates: Mapping[int, F64]) -> BiasFit:
    """Fit the heading bias the optimised estimates still show on the edges.

    Parameters
    ----------
    edges : sequence of OdometryEdge
        The robot's own odometry edges, as stored (corrected by the bias so far).
    estimates : mapping of int to ndarray (3,)
        The optimised poses ``x, y, theta`` by UID; edges naming a pose without one are
        skipped.

    Returns
    -------
    BiasFit
        The least-squares slope through the origin of each edge's heading residual (the
        estimates' heading change less the edge's, radians) on its length (metres),
        negated, and its standard error. A step of 0 and an infinite error when no edge
        has a length.
    """
    r_list: list[float] = []
    d_list: list[float] = []
    for e in edges:
        a, b = estimates.get(e.a), estimates.get(e.b)
        if a is None or b is None:
            continue
        d_list.append(math.hypot(e.transform[0], e.transform[1]))
        r_list.append(math.remainder(float(b[2]) - float(a[2]) - e.transform[2], 2 * math.pi))
    d, r = np.array(d_list), np.array(r_list)
    den = float(d @ d) if len(d) else 0.0
    if den <= 0:
        return BiasFit(0.0, math.inf, 0)
    slope = float(r @ d) / den
    n = int(np.count_nonzero(d))
    if n < 2:
        return BiasFit(-slope, math.inf, n)
    resid = r - slope * d
    stderr = math.sqrt(float(resid @ resid) / (len(d) - 1) / den)
    return BiasFit(-slope, stderr, n)


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
        ``current`` plus the fit's step when that total exceeds :data:`SIGNIFICANCE`
        standard errors of the fit's slope, else 0 (an estimate the graph cannot tell
        from noise is not applied, and one applied earlier is taken back), clipped to
        :data:`MAX_HEADING_BIAS`; radians per metre.
    """
    fit = heading_bias_fit(edges, estimates)
    total = current + fit.step
    if not abs(total) > SIGNIFICANCE * fit.stderr:
        return 0.0
    return min(MAX_HEADING_BIAS, max(-MAX_HEADING_BIAS, total))
