"""The robot's own odometry calibrated from its pose graph: a heading bias per metre.

Wheel odometry with an uncalibrated wheel base turns by a constant amount per metre
driven (the simulator's ``bias_theta``, :func:`~sonarmap.team.world.odometry`). The
odometry model counts it as independent noise per edge, so along a stretch that no
closure reaches the graph follows the biased odometry, and the error grows with the
square of the stretch's length. The robot cannot know the bias in advance, but every
optimised graph measures it: each odometry edge's heading change as the optimised
estimates give it, minus the edge's own, is ``-bias x length`` plus noise. The least
squares slope over the robot's own edges is one step of the estimate
(:func:`heading_bias_step`). A robot alone (:class:`~sonarmap.team.mission.RobotAgent`)
adds it up batch after batch, corrects every odometry edge it stores by each change
(:func:`debias_edges`) and each new one by the estimate so far, as an odometry
calibration from loop closures does. The store composes edges when it deletes a pose,
so the edges are corrected where they are kept, not only in the graph.

An edge's length is the straight distance between its poses (poses are made every
metre or half radian, where the path and the chord differ by centimetres).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from .records import OdometryEdge

__all__ = ["MAX_HEADING_BIAS", "debias", "debias_edges", "heading_bias_step"]

F64 = npt.NDArray[np.float64]

#: Radians per metre: the largest bias an estimate may reach (a wheel base 5 % off on
#: a 0.3 m robot turns about 0.17 rad per metre; ten times the simulated 0.003 is
#: still far beyond a robot that drives straight enough to patrol).
MAX_HEADING_BIAS = 0.05


def debias(transform: Sequence[float] | F64, bias: float) -> tuple[float, float, float]:
    """An odometry step ``(x, y, theta)`` (the second pose in the first's frame) with
    ``bias`` radians per metre removed: the heading change less ``bias`` times the
    step's length, the translation turned back by half of that (the bias turned the
    robot gradually along the step)."""
    x, y, theta = (float(v) for v in transform)
    turn = bias * math.hypot(x, y)
    c, s = math.cos(-turn / 2), math.sin(-turn / 2)
    return (c * x - s * y, s * x + c * y, theta - turn)


def debias_edges(edges: Sequence[OdometryEdge], bias: float) -> list[OdometryEdge]:
    """The edges with their transforms :func:`debias`-ed (covariances unchanged); the
    same list's items when ``bias`` is 0."""
    if bias == 0.0:
        return list(edges)
    return [replace(e, transform=debias(e.transform, bias)) for e in edges]


def heading_bias_step(edges: Sequence[OdometryEdge], estimates: Mapping[int, F64]) -> float:
    """Radians per metre to add to the bias the ``edges`` were corrected with: the
    least-squares slope of each edge's heading residual (the optimised estimates'
    heading change less the edge's) on its length, negated. Edges naming a pose
    without an estimate are skipped; 0 when no edge has a length."""
    num = den = 0.0
    for e in edges:
        a, b = estimates.get(e.a), estimates.get(e.b)
        if a is None or b is None:
            continue
        d = math.hypot(e.transform[0], e.transform[1])
        r = math.remainder(float(b[2]) - float(a[2]) - e.transform[2], 2 * math.pi)
        num += r * d
        den += d * d
    return -num / den if den > 0 else 0.0
