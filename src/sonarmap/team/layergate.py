"""A gate on closures between two layers: is a candidate closure consistent with where
the robot currently places the layers it joins?

A robot holds its own layer and one received layer per other robot. A received pose's
estimate is in its source's frame; each closure joining a layer's pose to an own pose
proposes where the layer's frame lies in the robot's (as :func:`~.globalmap.layer_frames`
uses them). With a layer placed, a new closure between two layers predicts nothing new
about where the layers lie: its transform should agree with the relative pose the
placements give, within the closure's covariance and the placement's own spread.
Repeated structure (the same shelf, door or pillar every few metres) gives closures that
fit their landmarks well and put the pose a period away; those disagree with the
placement by metres.

A pose is placed by the ``min_support`` proposals made nearest it in its layer's frame
(:class:`LayerPlacement`): a layer's shape as sent is not rigid, so one frame for the
whole layer would fit its far ends badly. The test is a chi-square test at 99 % with 3
degrees of freedom on the closure's residual against the placements (the quantile the
graph's GNC and gate use, :data:`~.globalmap.CHI2_99_3DOF`). A placement's spread is
measured, not set: the residuals of the proposals that place it, scaled robustly (the
normal-consistent median of absolute values, so wrong closures among them do not
inflate it), the heading's carried over the distance to them. A layer with fewer than
``min_support`` closures to the robot's own poses is not placed, and closures to it
pass untested.

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
from scipy.spatial import cKDTree

from .globalmap import CHI2_99_3DOF
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


def _heading_median(theta: F64) -> float:
    return math.atan2(float(np.median(np.sin(theta))), float(np.median(np.cos(theta))))


@dataclass(eq=False)
class LayerPlacement:
    """Where a received layer lies in the robot's frame, near each of its poses, and how
    well that holds there.

    A layer's shape as its source sent it is not rigid (each pose's estimate is the
    source's when it was sent, before later revisits bent its trajectory into place), so
    one frame for the whole layer fits its far ends badly. Each closure joining the
    layer to an own pose proposes a frame (``est_own (+) T (+) inv(est_layer)``); a pose
    of the layer is placed by the ``support`` proposals made nearest it in the layer's
    frame: their median frame, with the robust spread of their residuals about it, and
    the heading's spread carried over the distance from those closures' poses to the
    pose placed.

    Parameters
    ----------
    at : ndarray (n, 2)
        Each supporting closure's layer pose's position in the layer's frame (m).
    proposals : ndarray (n, 3)
        The frame each closure proposes, ``(x, y, theta)`` of the layer's frame in ours.
    support : int
        Proposals that place a pose (at most ``n``).
    """

    at: F64
    proposals: F64
    support: int = 10

    def __post_init__(self) -> None:
        self.at = np.asarray(self.at, dtype=np.float64).reshape(-1, 2)
        self.proposals = np.asarray(self.proposals, dtype=np.float64).reshape(-1, 3)
        if not len(self.at) or len(self.at) != len(self.proposals):
            raise ValueError(
                f"a placement needs one proposal per supporting pose and at least one: "
                f"{len(self.at)} poses, {len(self.proposals)} proposals"
            )
        self._tree = cKDTree(self.at)

    def place(self, estimate: F64) -> tuple[F64, F64]:
        """A pose of the layer in the robot's frame, and the covariance of that place.

        Parameters
        ----------
        estimate : ndarray (3,)
            The pose's estimate in the layer's (its source's) frame.

        Returns
        -------
        at : ndarray (3,)
            ``frame (+) estimate``, ``frame`` the median of the nearest proposals.
        covariance : ndarray (3, 3)
            ``diag(s_xy^2 + (s_theta d)^2, same, s_theta^2)``: ``s_xy`` and
            ``s_theta`` the normal-consistent median absolute residuals of those
            proposals' closures (position pooled over x and y; heading), ``d`` the
            distance (m) from the pose to their poses' centroid in the layer's frame.
        """
        est = np.asarray(estimate, dtype=np.float64)
        k = min(self.support, len(self.at))
        _, idx = self._tree.query(est[:2], k=k)
        idx = np.atleast_1d(idx)
        props = self.proposals[idx]
        frame = np.array(
            [np.median(props[:, 0]), np.median(props[:, 1]), _heading_median(props[:, 2])]
        )
        # Each proposal's disagreement with the frame, at its own pose (so a heading
        # difference counts by how far it moves that pose).
        res = np.array(
            [
                compose(invert(compose(frame, np.r_[a, 0.0])), compose(p, np.r_[a, 0.0]))
                for a, p in zip(self.at[idx], props, strict=True)
            ]
        )
        res[:, 2] = np.remainder(res[:, 2] + math.pi, 2 * math.pi) - math.pi
        s_xy = _NORMAL_MAD * float(np.median(np.abs(res[:, :2])))
        s_t = _NORMAL_MAD * float(np.median(np.abs(res[:, 2])))
        d = float(np.hypot(*(est[:2] - self.at[idx].mean(axis=0))))
        var_xy = s_xy**2 + (s_t * d) ** 2
        return compose(frame, est), np.diag([var_xy, var_xy, s_t**2])


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
        frame the closure's covariance is kept in), theta wrapped to [-pi, pi].
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
        Closures a layer needs to be placed, and the nearest of them that place each of
        its poses (default :data:`MIN_SUPPORT`).

    Returns
    -------
    dict of int to LayerPlacement
    """
    owner = {u: s for s, poses in layers.items() for u in poses}
    at: dict[int, list[F64]] = {}
    proposals: dict[int, list[F64]] = {}
    for c in closures:
        t = np.array(c.transform, dtype=np.float64)
        for a, b, ab in ((c.a, c.b, t), (c.b, c.a, invert(t))):
            if a in own and b in owner:
                source = owner[b]
                est_b = np.asarray(layers[source][b], dtype=np.float64)
                where = compose(np.asarray(own[a], dtype=np.float64), ab)
                proposals.setdefault(source, []).append(compose(where, invert(est_b)))
                at.setdefault(source, []).append(est_b[:2])
    return {
        source: LayerPlacement(np.array(at[source]), np.array(props), min_support)
        for source, props in proposals.items()
        if len(props) >= min_support
    }


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
