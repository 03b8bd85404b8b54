"""Pairwise consistency maximisation (PCM, Mangelson et al., ICRA 2018) over a robot's
loop closures: keep, for each pair of layers, the largest set of mutually consistent
closures, reject the rest.

Two closures joining the same two layers (robot A's and robot B's, or A's with
itself) close a loop with those layers' trajectories: ``a1 -> b1`` by the first
closure, ``b1 -> b2`` along B, ``b2 -> a2`` by the second closure inverted, ``a2 ->
a1`` along A. The relative poses along a layer, mean and covariance, are the layer's
odometry edges composed between the two poses (:meth:`LayerChain.relative`), what
those poses would be with no closure at all (PCM's choice: a closure is not judged by
the closures it is judged against, nor by a graph they have moved). The two
closures are consistent when the loop's squared Mahalanobis distance is within the
chi-square quantile at 99 % for 3 degrees of freedom (:data:`~.globalmap.CHI2_99_3DOF`,
the graph's own), a fact of the test, not a tuned number. Two poses with no odometry
chain between them (a layer received with a gap, different layers' chains) give a loop
that cannot be tested: the two closures count as consistent.

Within one layer each closure is oriented from its earlier pose to its later one (by
their places on the chain), so that the loop's two odometry stretches are apart for
two revisits of one place however they were stored; two closures whose stretches still
share edges (the revisits interleave) give a loop that is not tested either, since the
stretches would not be independent.

The closures kept are a maximum clique of the consistency graph
(:func:`networkx.max_weight_clique`, exact, unweighted). Exact maximum clique is
exponential in the worst case, so each pair of layers is judged on its
``max_per_pair`` newest closures only (:data:`MAX_PER_PAIR`, 40: 780 loops a pair);
older closures are left as earlier batches judged them.

Why PCM and not gtsam's GNC: the robot's graph already runs GNC over every closure
(:func:`~.globalmap.optimise_graph`), and that is where the held-out wrong closures
between robots survive: GNC judges each closure against the one estimate the graph
converges to, which a run of wrong closures in repeated structure can pull to itself.
PCM judges closures against each other, through the odometry alone, before the graph.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import networkx as nx
import numpy as np
import numpy.typing as npt

from .globalmap import CHI2_99_3DOF
from .records import (
    ClosureEdge,
    OdometryEdge,
    compose,
    compose_covariance,
    invert,
    invert_covariance,
)

__all__ = [
    "MAX_PER_PAIR",
    "LayerChain",
    "PcmResult",
    "loop_distance",
    "pcm_gate",
]

F64 = npt.NDArray[np.float64]

#: Closures of one pair of layers that a batch judges (the newest): the bound on the
#: maximum clique's size (40 nodes, 780 pairwise loops).
MAX_PER_PAIR = 40

_J2 = np.array([[0.0, -1.0], [1.0, 0.0]])


def _rot3(theta: float) -> F64:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class LayerChain:
    """The odometry chains of one layer, for the relative pose (mean and covariance)
    of any two of its poses on one chain by the odometry alone.

    Each chain is dead-reckoned from its first pose (its own frame); the noise of edge
    ``k`` (covariance in its end's frame, as every edge keeps it) moves pose ``j > k``
    by ``B_k delta + delta_theta (J2 t_j, 0)``. The sums over edges of the terms of
    that product are kept as prefix sums, so a pair costs O(1).

    Parameters
    ----------
    edges : iterable of OdometryEdge
        The layer's odometry edges; a pose with two edges out or in breaks its chain
        there (only the first is followed).
    """

    def __init__(self, edges: Iterable[OdometryEdge]) -> None:
        nxt: dict[int, OdometryEdge] = {}
        has_in: set[int] = set()
        for e in edges:
            if e.a in nxt or e.b in has_in or e.a == e.b:
                continue
            nxt[e.a] = e
            has_in.add(e.b)
        #: Pose UID -> (chain, index on it).
        self.where: dict[int, tuple[int, int]] = {}
        self._pose: list[F64] = []
        self._m: list[F64] = []
        self._v: list[F64] = []
        self._s: list[F64] = []
        for start in sorted(set(nxt) - has_in):
            chain = len(self._pose)
            poses = [np.zeros(3)]
            m, v, s = [np.zeros((3, 3))], [np.zeros(3)], [0.0]
            uid = start
            self.where[uid] = (chain, 0)
            while uid in nxt:
                e = nxt[uid]
                x = compose(poses[-1], np.asarray(e.transform, dtype=np.float64))
                q = e.cov()
                b = _rot3(float(x[2]))
                b[:2, 2] = -_J2 @ x[:2]
                bq = b @ q
                m.append(m[-1] + bq @ b.T)
                v.append(v[-1] + bq[:, 2])
                s.append(s[-1] + float(q[2, 2]))
                poses.append(np.asarray(x, dtype=np.float64))
                uid = e.b
                if uid in self.where:  # a cycle: stop
                    break
                self.where[uid] = (chain, len(poses) - 1)
            self._pose.append(np.array(poses))
            self._m.append(np.array(m))
            self._v.append(np.array(v))
            self._s.append(np.array(s))

    def covariance(self, u: int, w: int) -> F64 | None:
        """The covariance of pose ``w`` relative to pose ``u`` by the odometry between
        them, in ``w``'s frame (as a closure ``u -> w`` keeps its own); None when the
        two are not on one chain. ``w`` may come before ``u``."""
        if u == w:
            return np.zeros((3, 3))
        cu, cw = self.where.get(u), self.where.get(w)
        if cu is None or cw is None or cu[0] != cw[0]:
            return None
        chain, i, j = cu[0], cu[1], cw[1]
        lo, hi = min(i, j), max(i, j)
        poses = self._pose[chain]
        c = np.zeros(3)
        c[:2] = _J2 @ poses[hi, :2]
        m = self._m[chain][hi] - self._m[chain][lo]
        v = self._v[chain][hi] - self._v[chain][lo]
        s = float(self._s[chain][hi] - self._s[chain][lo])
        sig = m + np.outer(v, c) + np.outer(c, v) + s * np.outer(c, c)
        # From the chain's frame to the later pose's (a perturbation on its right).
        r = _rot3(float(poses[hi, 2]))
        cov = r.T @ sig @ r
        if i <= j:
            return np.asarray(cov, dtype=np.float64)
        rel = compose(invert(poses[j]), poses[i])
        return invert_covariance(rel, cov)

    def relative(self, u: int, w: int) -> tuple[F64, F64] | None:
        """Pose ``w`` in pose ``u``'s frame by the odometry between them (the
        dead-reckoned chain, not any estimate a graph has moved) and its covariance in
        ``w``'s frame; None when the two are not on one chain. ``w`` may come before
        ``u``."""
        if u == w:  # the same pose, on a chain or not (as covariance() has it)
            return np.zeros(3), np.zeros((3, 3))
        cov = self.covariance(u, w)
        if cov is None:
            return None
        (chain, i), (_, j) = self.where[u], self.where[w]
        poses = self._pose[chain]
        mean = np.asarray(compose(invert(poses[i]), poses[j]), dtype=np.float64)
        return mean, cov

    def stretch(self, u: int, w: int) -> tuple[int, int, int] | None:
        """The chain holding poses ``u`` and ``w`` and their places on it, lower first;
        None when they are not on one chain."""
        cu, cw = self.where.get(u), self.where.get(w)
        if cu is None or cw is None or cu[0] != cw[0]:
            return None
        return cu[0], min(cu[1], cw[1]), max(cu[1], cw[1])


def _oriented(c: ClosureEdge, flip: bool) -> tuple[int, int, F64, F64]:
    t = np.asarray(c.transform, dtype=np.float64)
    if not flip:
        return c.a, c.b, t, c.cov()
    return c.b, c.a, np.asarray(invert(t), dtype=np.float64), invert_covariance(t, c.cov())


def _orient(
    c: ClosureEdge, la: int, layer_of: Mapping[int, int], chain: LayerChain
) -> tuple[int, int, F64, F64]:
    """Closure ``c`` from layer ``la`` to the other; within layer ``la`` itself, from
    its earlier pose to its later one on their chain (as stored when on none)."""
    if layer_of[c.a] != layer_of[c.b]:
        return _oriented(c, layer_of[c.a] != la)
    ca, cb = chain.where.get(c.a), chain.where.get(c.b)
    flip = ca is not None and cb is not None and ca[0] == cb[0] and ca[1] > cb[1]
    return _oriented(c, flip)


def loop_distance(
    c1: tuple[int, int, F64, F64],
    c2: tuple[int, int, F64, F64],
    chain_a: LayerChain,
    chain_b: LayerChain,
) -> float | None:
    """The squared Mahalanobis distance of the loop two closures close, or None when it
    cannot be tested (a pair of poses on no common chain, or, within one layer, two
    odometry stretches that share edges).

    Parameters
    ----------
    c1, c2 : (a, b, transform, covariance)
        Closures oriented from layer A's pose ``a`` to layer B's pose ``b``
        (``transform`` ``b`` in ``a``'s frame, covariance in ``b``'s).
    chain_a, chain_b : LayerChain
        The two layers' chains (the same object for a layer with itself); the loop's
        stretches along them are the odometry's (:meth:`LayerChain.relative`).

    Returns
    -------
    float or None
        ``r^T S^-1 r``, ``r`` the loop ``a1 -> b1 -> b2 -> a2 -> a1`` (theta wrapped)
        and ``S`` its first-order covariance.
    """
    a1, b1, t1, s1 = c1
    a2, b2, t2, s2 = c2
    along_b = chain_b.relative(b1, b2)
    along_a = chain_a.relative(a2, a1)
    if along_b is None or along_a is None:
        return None
    if chain_a is chain_b:
        sa, sb = chain_a.stretch(a1, a2), chain_b.stretch(b1, b2)
        # Stretches sharing an edge are not independent: their covariances don't add.
        if sa and sb and sa[0] == sb[0] and sa[1] < sb[2] and sb[1] < sa[2]:
            return None
    rel_b, cov_b = along_b
    rel_a, cov_a = along_a
    inv_t2 = invert(t2)
    loop, cov = t1, s1
    for step, step_cov in (
        (rel_b, cov_b),
        (inv_t2, invert_covariance(t2, s2)),
        (rel_a, cov_a),
    ):
        cov = compose_covariance(loop, cov, step, step_cov)
        loop = compose(loop, step)
    r = np.asarray(loop, dtype=np.float64).copy()
    r[2] = math.remainder(float(r[2]), 2 * math.pi)
    try:
        return float(r @ np.linalg.solve(cov, r))
    except np.linalg.LinAlgError:
        return None


@dataclass
class PcmResult:
    """What one PCM pass kept and rejected."""

    #: The closures kept, in the order given.
    kept: list[ClosureEdge]
    #: The closures rejected, in the order given.
    rejected: list[ClosureEdge]
    #: Closures judged (in a window of some pair of layers).
    judged: int
    #: Pairs of closures whose loop could be tested.
    loops_tested: int
    #: Pairs of closures whose loop could not be tested (counted consistent).
    loops_untestable: int = 0


def pcm_gate(
    closures: Sequence[ClosureEdge],
    layer_of: Mapping[int, int],
    chains: Mapping[int, LayerChain],
    *,
    max_per_pair: int = MAX_PER_PAIR,
    threshold: float = CHI2_99_3DOF,
) -> PcmResult:
    """Keep each pair of layers' largest set of mutually consistent closures.

    Parameters
    ----------
    closures : sequence of ClosureEdge
        The closure store, oldest first.
    layer_of : mapping of UID to int
        Each pose's layer (its source robot). A closure with a pose in none is kept,
        unjudged.
    chains : mapping of int to LayerChain
        Each layer's odometry chains (the loops' means and covariances).
    max_per_pair : int
        Newest closures of a pair of layers judged (default :data:`MAX_PER_PAIR`, at
        least 1); the older ones are kept.
    threshold : float
        Largest squared Mahalanobis distance of a consistent loop; default the 0.99
        chi-square quantile with 3 degrees of freedom.

    Returns
    -------
    PcmResult

    Raises
    ------
    ValueError
        If ``max_per_pair`` is below 1.
    """
    if max_per_pair < 1:
        raise ValueError(f"pcm_gate: max_per_pair must be at least 1, got {max_per_pair}")
    groups: dict[tuple[int, int], list[int]] = {}
    for i, c in enumerate(closures):
        la, lb = layer_of.get(c.a), layer_of.get(c.b)
        if la is None or lb is None:
            continue
        groups.setdefault((min(la, lb), max(la, lb)), []).append(i)
    rejected: set[int] = set()
    judged = tested = untestable = 0
    for (la, lb), idx in sorted(groups.items()):
        window = idx[-max_per_pair:]
        judged += len(window)
        if len(window) < 2:
            continue
        oriented = [_orient(closures[i], la, layer_of, chains[la]) for i in window]
        g: nx.Graph = nx.Graph()
        g.add_nodes_from(range(len(window)))
        for p in range(len(window)):
            for q in range(p + 1, len(window)):
                d2 = loop_distance(oriented[p], oriented[q], chains[la], chains[lb])
                if d2 is not None:
                    tested += 1
                else:
                    untestable += 1
                if d2 is None or d2 <= threshold:
                    g.add_edge(p, q)
        clique, _ = nx.max_weight_clique(g, weight=None)
        keep = set(clique)
        rejected.update(window[p] for p in range(len(window)) if p not in keep)
    kept = [c for i, c in enumerate(closures) if i not in rejected]
    gone = [c for i, c in enumerate(closures) if i in rejected]
    return PcmResult(kept, gone, judged, tested, untestable)
