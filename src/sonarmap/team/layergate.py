"""A gate on closures between two layers: is a candidate closure consistent with where
the robot currently places the layers it joins?

A robot holds its own layer and one received layer per other robot. A received pose's
estimate is in its source's frame; the robot places the whole layer in its own frame by
the closures joining the layer's poses to its own poses
(:func:`~.globalmap.layer_frames`, a median, so that a few wrong closures do not move it).
With the layer placed, a new closure between two layers predicts nothing new about where
the layers lie: its transform should agree with the relative pose the placements give,
within the closure's covariance and the placement's own spread. Repeated structure (the
same shelf, door or pillar every few metres) gives closures that fit their landmarks well
and put the pose a period away; those disagree with the placement by metres.

The test is a chi-square test at 99 % with 3 degrees of freedom on the closure's
residual against the placements (the same quantile the graph's GNC and gate use,
:data:`~.globalmap.CHI2_99_3DOF`). A layer's placement spread is measured, not set: the
residuals of the closures that place it, scaled robustly (the normal-consistent median
of absolute values, so the wrong closures among them do not inflate it). A layer with
fewer than ``min_support`` closures to the robot's own poses is not placed, and closures
to it pass untested.

Closures between two poses of one layer are never tested here: the single-robot path
(odometry priors, :func:`~.association.associate`) judges those.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import stats

from .globalmap import CHI2_99_3DOF, layer_frames
from .records import ClosureEdge, compose, invert

__all__ = [
    "MIN_SUPPORT",
    "LayerPlacement",
    "closure_residual",
    "gate_closures",
    "layer_placements",
]

F64 = npt.NDArray[np.float64]

#: Closures to the robot's own poses a layer needs before it counts as placed: below
#: this, the median frame and the spread of its residuals rest on too few samples.
MIN_SUPPORT = 10
#: 1 / Phi^-1(3/4): median(|x|) times this is sigma for zero-mean normal x.
_NORMAL_MAD = float(1.0 / stats.norm.ppf(0.75))


@dataclass(frozen=True)
class LayerPlacement:
    """Where a received layer lies in the robot's frame, and how well that holds.

    Attributes
    ----------
    frame : ndarray (3,)
        ``(x, y, theta)`` of the layer's frame (its source's) in the robot's: a pose of
        the layer at estimate ``e`` lies at ``frame (+) e``.
    sigma_xy : float
        Robust standard deviation (m) of the position residuals of the closures that
        place the layer (x and y pooled).
    sigma_theta : float
        Likewise of the heading residuals (rad).
    support : int
        Closures between the layer and the robot's own poses that placed it.
    """

    frame: F64
    sigma_xy: float
    sigma_theta: float
    support: int

    def covariance(self) -> F64:
        """The placement's spread as a 3 x 3 covariance (isotropic in x and y, so the
        same in every pose's frame)."""
        return np.diag([self.sigma_xy**2, self.sigma_xy**2, self.sigma_theta**2])


def closure_residual(at_a: F64, at_b: F64, transform: Sequence[float] | F64) -> F64:
    """How far a closure's transform is from the relative pose of its two poses' places.

    Parameters
    ----------
    at_a, at_b : ndarray (3,)
        The closure's poses ``a`` and ``b`` in one frame (x, y in m, theta in rad).
    transform : sequence of 3 float
        The closure's ``b`` in ``a``'s frame.

    Returns
    -------
    ndarray (3,)
        ``inv(inv(at_a) (+) at_b) (+) transform``, in the predicted ``b``'s frame (the
        frame the closure's covariance is kept in), theta wrapped to [-pi, pi).
    """
    predicted = compose(invert(np.asarray(at_a, dtype=np.float64)), at_b)
    r = np.asarray(compose(invert(predicted), np.asarray(transform, dtype=np.float64)))
    r = r.astype(np.float64, copy=True)
    r[2] = math.remainder(float(r[2]), 2 * math.pi)
    return r


def layer_placements(
    own: Mapping[int, F64],
    layers: Mapping[int, Mapping[int, F64]],
    closures: Sequence[ClosureEdge],
    min_support: int = MIN_SUPPORT,
) -> dict[int, LayerPlacement]:
    """Each received layer's placement in the robot's frame, for the layers placed by at
    least ``min_support`` closures to the robot's own poses.

    Parameters
    ----------
    own : mapping of UID to ndarray (3,)
        The robot's own poses' estimates in its frame.
    layers : mapping of int to mapping of UID to ndarray (3,)
        Each received layer (by source robot): its poses' estimates in its source's
        frame.
    closures : sequence of ClosureEdge
        The closure store; only closures joining an own pose to a layer's count.
    min_support : int
        Closures a layer needs to be placed (default :data:`MIN_SUPPORT`).

    Returns
    -------
    dict of int to LayerPlacement
    """
    frames = layer_frames(own, layers, closures)
    owner = {u: s for s, poses in layers.items() for u in poses}
    residuals: dict[int, list[F64]] = {}
    for c in closures:
        if c.a in own and c.b in owner:
            source = owner[c.b]
            if source not in frames:
                continue
            at_b = compose(frames[source], np.asarray(layers[source][c.b], dtype=np.float64))
            r = closure_residual(np.asarray(own[c.a], dtype=np.float64), at_b, c.transform)
        elif c.b in own and c.a in owner:
            source = owner[c.a]
            if source not in frames:
                continue
            at_a = compose(frames[source], np.asarray(layers[source][c.a], dtype=np.float64))
            r = closure_residual(at_a, np.asarray(own[c.b], dtype=np.float64), c.transform)
        else:
            continue
        residuals.setdefault(source, []).append(r)
    out: dict[int, LayerPlacement] = {}
    for source, rows in residuals.items():
        if len(rows) < min_support:
            continue
        arr = np.array(rows)
        out[source] = LayerPlacement(
            frame=np.asarray(frames[source], dtype=np.float64),
            sigma_xy=_NORMAL_MAD * float(np.median(np.abs(arr[:, :2]))),
            sigma_theta=_NORMAL_MAD * float(np.median(np.abs(arr[:, 2]))),
            support=len(rows),
        )
    return out


def gate_closures(
    closures: Sequence[ClosureEdge],
    placed: Mapping[int, tuple[F64, F64]],
    threshold: float = CHI2_99_3DOF,
) -> tuple[list[ClosureEdge], list[ClosureEdge]]:
    """Split closures into those consistent with where their poses are placed and those
    that are not.

    Parameters
    ----------
    closures : sequence of ClosureEdge
        Closures between poses of two different layers.
    placed : mapping of UID to (ndarray (3,), ndarray (3, 3))
        Each placed pose's ``(x, y, theta)`` in the robot's frame and the covariance of
        that placement (x, y rotation-invariant or in the robot's frame). A closure with
        a pose not in it passes untested.
    threshold : float
        Largest squared Mahalanobis residual kept; default the 0.99 chi-square quantile
        with 3 degrees of freedom.

    Returns
    -------
    kept, rejected : list of ClosureEdge
        In the given order.
    """
    kept: list[ClosureEdge] = []
    rejected: list[ClosureEdge] = []
    for c in closures:
        if c.a not in placed or c.b not in placed:
            kept.append(c)
            continue
        (at_a, cov_a), (at_b, cov_b) = placed[c.a], placed[c.b]
        r = closure_residual(at_a, at_b, c.transform)
        # The placements' covariances into b's frame, where the closure's is kept.
        ct, st = math.cos(float(at_b[2])), math.sin(float(at_b[2]))
        turn = np.array([[ct, st, 0.0], [-st, ct, 0.0], [0.0, 0.0, 1.0]])
        cov = c.cov() + turn @ (cov_a + cov_b) @ turn.T
        d2 = float(r @ np.linalg.solve(cov, r))
        (kept if d2 <= threshold else rejected).append(c)
    return kept, rejected
