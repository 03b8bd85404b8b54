"""Pairwise consistency maximisation (PCM, Mangelson et al., ICRA 2018) over a robot's
loop closures: keep, for each pair of layers, the closures consistent with each other,
reject the rest.

Two closures joining the same two layers (robot A's and robot B's, or A's with
itself) close a loop with those layers' trajectories: ``a1 -> b1`` by the first
closure, ``b1 -> b2`` along B, ``b2 -> a2`` by the second closure inverted, ``a2 ->
a1`` along A. The relative poses along a layer, mean and covariance, are the layer's
odometry edges composed between the two poses (:class:`LayerChain`), what those poses
would be with no closure at all (PCM's choice: a closure is not judged by the closures
it is judged against, nor by a graph they have moved). The two closures are consistent
when the loop's squared Mahalanobis distance is within the chi-square quantile at 99 %
for 3 degrees of freedom (:data:`~.globalmap.CHI2_99_3DOF`, the graph's own), a fact
of the test, not a tuned number. Two poses joined by no odometry (a layer received with
a gap, different layers) give a loop that cannot be tested: it counts as consistent.
Within one layer the loop's two odometry stretches are one walk
(:func:`loop_residual`): edges walked both ways cancel, so every pair of revisits is
tested.

Which closures go (:func:`pcm_gate`): PCM as published keeps a maximum clique of the
consistency graph (:func:`networkx.max_weight_clique`, exact, unweighted), every pass
judging each window again; a chance failure (1 % of true loops) then costs a true
closure in every pass that tests it. Judged once instead (``frozen``, what
:mod:`.mission` uses), a closure is judged until it has been tested against
``min_failures`` closures still in (two by default), then kept for good if kept, and is
rejected only when it fails with ``min_failures`` of them.

Each pair of layers is judged on its ``max_per_pair`` newest closures only
(:data:`MAX_PER_PAIR`, 40: 780 loops a pair; exact maximum clique is exponential in the
worst case); older closures are left as earlier passes judged them.

Why PCM and not gtsam's GNC: the robot's graph already runs GNC over every closure
(:func:`~.globalmap.optimise_graph`), and that is where the held-out wrong closures
between robots survive: GNC judges each closure against the one estimate the graph
converges to, which a run of wrong closures in repeated structure can pull to itself.
PCM judges closures against each other, through the odometry alone, before the graph.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Mapping, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
import numpy.typing as npt

from .calibration import HEADING_BIAS_PRIOR
from .globalmap import CHI2_99_3DOF
from .records import (
    ClosureEdge,
    OdometryEdge,
    adjoint,
    compose,
    invert,
    invert_covariance,
)

__all__ = [
    "FORESTS",
    "MAX_PER_PAIR",
    "MIN_FAILURES",
    "LayerChain",
    "PcmResult",
    "loop_distance",
    "loop_residual",
    "orient",
    "pcm_gate",
]

F64 = npt.NDArray[np.float64]
#: An odometry edge as walked from a pose: the other pose, the transform, its
#: covariance and the heading bias's perturbation, both at the other pose.
_Step = tuple[int, F64, F64, F64]

#: Closures of one pair of layers that a batch judges (the newest): the bound on the
#: maximum clique's size (40 nodes, 780 pairwise loops).
MAX_PER_PAIR = 40

#: How :class:`LayerChain` spans a layer's odometry graph: ``"hops"`` breadth first
#: (fewest edges from the root), ``"least"`` by least summed x and y variance.
FORESTS = ("hops", "least")

#: Loops a new closure must fail, with closures still kept, to be rejected when
#: closures are judged once (:func:`pcm_gate` with ``frozen``): one failure is what a
#: true pair shows by chance.
MIN_FAILURES = 2


class LayerChain:
    """The odometry of one layer, for the relative pose (mean and covariance) of any
    two of its poses, and of a loop's two stretches together, by the odometry alone.

    The layer's odometry edges are a graph, not one chain: a merge at a closure
    (``StoreParams.merge_on_closure``) gives the merged pose the edges of both poses,
    and deleting a pose chains its neighbours by time. The poses are joined by a
    spanning forest of those edges (breadth first from the lowest UID of each
    connected part, or by least position variance with ``forest="least"``; an edge
    closing a cycle is left out), each tree dead-reckoned from
    its root. A path between two poses of one tree is the tree's; its edges' noise
    (each edge's covariance in its end's frame) is kept per edge as that covariance
    moved to the root's frame, and each pose knows the edges on its path from the root,
    so the edges of a path, or of two paths at once, are a difference of those sets.

    A pose merged at a closure carries that closure in its edges (the store reframed
    them through it), so a path through it holds the merge's transform, not its noise.

    Parameters
    ----------
    edges : iterable of OdometryEdge
        The layer's odometry edges.
    bias_sd : float, optional
        Radians per metre: the standard deviation of one heading bias shared by every
        edge of the layer (each edge driven forward turns by the bias times its chord
        length), added to the edges' own noise. Default
        :data:`~sonarmap.team.calibration.HEADING_BIAS_PRIOR` (0.003, the uncalibrated
        prior, also for a robot that calibrates: conservative); 0 counts the edges' own
        noise only. Two walks in one layer but on different trees each get their own
        bias term (their cross term is left out).
    forest : {"hops", "least"}, optional
        How the spanning forest is grown: fewest edges from the root (``"hops"``,
        default) or least x/y variance (``"least"``, Dijkstra on the edges' variances).
    """

    def __init__(
        self,
        edges: Iterable[OdometryEdge],
        *,
        bias_sd: float = HEADING_BIAS_PRIOR,
        forest: str = "hops",
    ) -> None:
        if not (math.isfinite(bias_sd) and bias_sd >= 0.0):
            raise ValueError(f"LayerChain: bias_sd must be finite and >= 0, got {bias_sd}")
        if forest not in FORESTS:
            raise ValueError(
                f"LayerChain: forest must be one of {', '.join(FORESTS)}, got {forest!r}"
            )
        #: Radians per metre: the standard deviation of the heading bias shared by every
        #: edge of the layer (:meth:`bias`).
        self.bias_sd = float(bias_sd)
        adj: dict[int, list[_Step]] = {}
        for e in edges:
            if e.a == e.b:
                continue
            t = np.asarray(e.transform, dtype=np.float64)
            q = e.cov()
            # A heading bias turns the robot by bias x metres driven, the same sign on
            # every edge driven forward (a to b): a perturbation at b of (0, 0, s) per
            # unit of bias, s the edge's chord (poses are a metre apart or less).
            turn = np.array([0.0, 0.0, math.hypot(float(t[0]), float(t[1]))])
            adj.setdefault(e.a, []).append((e.b, t, q, turn))
            # Walked backwards: the inverse, its covariance in its own end's frame, and
            # the bias's perturbation at the inverse's end (exp(-e) T^-1 = T^-1 exp(-Ad e)).
            back = -adjoint(t) @ turn
            adj.setdefault(e.b, []).append(
                (e.a, np.asarray(invert(t)), invert_covariance(t, q), back)
            )
        #: Pose UID -> (tree, row in that tree's arrays).
        self.where: dict[int, tuple[int, int]] = {}
        self._pose: list[F64] = []
        self._paths: list[npt.NDArray[np.int8]] = []
        self._noise: list[F64] = []
        self._turn: list[F64] = []
        self._length: list[F64] = []
        self._ends: list[npt.NDArray[np.int64]] = []
        for root in sorted(adj):
            if root in self.where:
                continue
            tree = len(self._pose)
            poses, parent_row, parent_edge, noise, turns, ends = self._grow(root, tree, adj, forest)
            paths = np.zeros((len(poses), len(noise)), dtype=np.int8)
            for row in range(1, len(poses)):  # parents come first (either forest)
                paths[row] = paths[parent_row[row]]
                paths[row, parent_edge[row]] = 1
            self._pose.append(np.array(poses))
            self._paths.append(paths)
            self._noise.append(np.array(noise).reshape(-1, 3, 3))
            self._turn.append(np.array(turns).reshape(-1, 3))
            self._length.append(np.abs(self._turn[-1][:, 2]))
            self._ends.append(np.array(ends, dtype=np.int64).reshape(-1, 2))

    def _grow(
        self, root: int, tree: int, adj: Mapping[int, list[_Step]], forest: str
    ) -> tuple[list[F64], list[int], list[int], list[F64], list[F64], list[tuple[int, int]]]:
        """Tree ``tree`` spanning ``root``'s connected part, each pose in :attr:`where`:
        the poses (root frame), each row's parent row and edge, and each edge's noise
        and bias perturbation at the root's origin and its two ends."""
        self.where[root] = (tree, 0)
        poses, parent_row, parent_edge = [np.zeros(3)], [-1], [-1]
        noise: list[F64] = []
        turns: list[F64] = []
        ends: list[tuple[int, int]] = []

        def attach(uid: int, other: int, t: F64, q: F64, turn: F64) -> None:
            row = self.where[uid][1]
            x = compose(poses[row], t)
            self.where[other] = (tree, len(poses))
            poses.append(np.asarray(x, dtype=np.float64))
            parent_row.append(row)
            parent_edge.append(len(noise))
            # Edge noise at its end, as a perturbation at the root's origin.
            noise.append(invert_covariance(x, q))
            turns.append(adjoint(x) @ turn)
            ends.append((uid, other))

        if forest == "hops":
            queue = [root]
            for uid in queue:  # breadth first; the queue grows as it is read
                for other, t, q, turn in sorted(adj[uid], key=lambda n: n[0]):
                    if other not in self.where:
                        attach(uid, other, t, q, turn)
                        queue.append(other)
        else:
            # Least position variance from the root (Dijkstra): each pose joins by the
            # path whose edges' summed x and y variance is least.
            best = {root: 0.0}
            via: dict[int, _Step] = {}
            heap = [(0.0, root)]
            while heap:
                d, uid = heapq.heappop(heap)
                if uid != root:
                    if uid in self.where:
                        continue
                    parent, t, q, turn = via[uid]
                    attach(parent, uid, t, q, turn)
                for other, t, q, turn in adj[uid]:
                    nd = d + float(q[0, 0] + q[1, 1])
                    if other not in self.where and nd < best.get(other, math.inf):
                        best[other] = nd
                        via[other] = (uid, t, q, turn)
                        heapq.heappush(heap, (nd, other))
        return poses, parent_row, parent_edge, noise, turns, ends

    def pose(self, uid: int) -> tuple[int, F64] | None:
        """Pose ``uid``'s tree and its dead-reckoned pose in the tree's root frame; None
        for a pose with no odometry edge."""
        at = self.where.get(uid)
        if at is None:
            return None
        return at[0], self._pose[at[0]][at[1]]

    def path(self, u: int, w: int) -> npt.NDArray[np.int8]:
        """The signed edges walked from pose ``u`` to ``w`` on their tree (+1 away from
        the root, -1 towards it, 0 off the path); both must be on one tree."""
        (tree, i), (_, j) = self.where[u], self.where[w]
        paths = self._paths[tree]
        return np.asarray(paths[j] - paths[i], dtype=np.int8)

    def noise(self, tree: int, counts: npt.NDArray[np.int8]) -> F64:
        """The covariance, as a perturbation at tree ``tree``'s root origin, of a walk
        that takes each edge ``counts`` times (signed): an edge walked once each way
        cancels, to first order, in a walk that comes back to where it was."""
        n2 = counts.astype(np.float64) ** 2
        independent = np.einsum("k,kij->ij", n2, self._noise[tree])
        return np.asarray(independent + self.bias(tree, counts), dtype=np.float64)

    def walk_metres(self, tree: int, counts: npt.NDArray[np.int8]) -> float:
        """Metres a walk taking each edge of tree ``tree`` ``counts`` times (signed)
        drives, each edge's chord counted once per time it is walked."""
        return float(np.abs(counts.astype(np.float64)) @ self._length[tree])

    def walk_poses(self, tree: int, counts: npt.NDArray[np.int8]) -> dict[int, int]:
        """The poses at either end of the edges a walk on tree ``tree`` takes
        (``counts`` nonzero), by UID, each with how many of those edges meet at it (two
        or more: the walk passes through it)."""
        ends = self._ends[tree][np.flatnonzero(counts)].ravel()
        uids, n = np.unique(ends, return_counts=True)
        return {int(u): int(k) for u, k in zip(uids, n, strict=True)}

    def bias(self, tree: int, counts: npt.NDArray[np.int8]) -> F64:
        """The covariance, at tree ``tree``'s root origin, that the layer's heading bias
        (:attr:`bias_sd` radians per metre, unknown, the same on every edge) gives a
        walk taking each edge ``counts`` times: one direction, so it grows with the
        square of the metres walked one way, where the edges' own noise grows with the
        metres. The edges' covariances count the bias as independent per edge
        (:func:`~.world.odometry_covariance`), which a walk of n metres understates n
        times; this term is added on top (a metre's worth counted twice)."""
        g = counts.astype(np.float64) @ self._turn[tree]
        return np.asarray(self.bias_sd**2 * np.outer(g, g), dtype=np.float64)

    def relative(self, u: int, w: int) -> tuple[F64, F64] | None:
        """Pose ``w`` in pose ``u``'s frame by the odometry between them (the
        dead-reckoned tree, not any estimate a graph has moved) and its covariance in
        ``w``'s frame; None when the two are not on one tree. ``w`` may come before
        ``u``."""
        if u == w:  # the same pose, on a tree or not
            return np.zeros(3), np.zeros((3, 3))
        pu, pw = self.pose(u), self.pose(w)
        if pu is None or pw is None or pu[0] != pw[0]:
            return None
        mean = np.asarray(compose(invert(pu[1]), pw[1]), dtype=np.float64)
        at_root = self.noise(pu[0], self.path(u, w))
        return mean, invert_covariance(invert(pw[1]), at_root)

    def covariance(self, u: int, w: int) -> F64 | None:
        """The covariance of :meth:`relative`, or None when it has none."""
        rel = self.relative(u, w)
        return None if rel is None else rel[1]


def _oriented(c: ClosureEdge, flip: bool) -> tuple[int, int, F64, F64]:
    t = np.asarray(c.transform, dtype=np.float64)
    if not flip:
        return c.a, c.b, t, c.cov()
    return c.b, c.a, np.asarray(invert(t), dtype=np.float64), invert_covariance(t, c.cov())


def orient(c: ClosureEdge, la: int, layer_of: Mapping[int, int]) -> tuple[int, int, F64, F64]:
    """Closure ``c`` as :func:`loop_residual` takes it: ``(a, b, transform,
    covariance)`` from layer ``la``'s pose to the other layer's (as stored within one
    layer); ``layer_of`` gives each pose's layer."""
    return _oriented(c, layer_of[c.a] != la)


def loop_residual(
    c1: tuple[int, int, F64, F64],
    c2: tuple[int, int, F64, F64],
    chain_a: LayerChain,
    chain_b: LayerChain,
) -> tuple[F64, F64] | None:
    """The loop two closures close and its first-order covariance, or None when it
    cannot be tested (a pair of poses on no common tree of their layer).

    The loop is ``a1 -> b1 -> b2 -> a2 -> a1``: closure 1, B's odometry from ``b1`` to
    ``b2``, closure 2 inverted, A's odometry from ``a2`` to ``a1``. Its covariance is
    taken where the loop holds (the null hypothesis): each noise, a perturbation at
    the place the loop passes it, moved to the loop's end. Within one tree of one
    layer, the two stretches are one walk, so an edge walked once each way cancels and
    one walked twice the same way counts four times its covariance (two revisits in a
    row, or interleaved, are tested like any other pair).

    Parameters
    ----------
    c1, c2 : (a, b, transform, covariance)
        Closures oriented from layer A's pose ``a`` to layer B's pose ``b``
        (``transform`` ``b`` in ``a``'s frame, covariance in ``b``'s).
    chain_a, chain_b : LayerChain
        The two layers' odometry (the same object for a layer with itself).

    Returns
    -------
    (residual, covariance) : tuple of ndarray or None
        The loop as a transform (x, y in metres, theta in radians wrapped to
        (-pi, pi]) in ``a1``'s frame, and its 3 x 3 covariance there.
    """
    a1, b1, t1, s1 = c1
    a2, b2, t2, s2 = c2
    ends = [chain_b.pose(b1), chain_b.pose(b2), chain_a.pose(a2), chain_a.pose(a1)]
    along_b = chain_b.relative(b1, b2)
    along_a = chain_a.relative(a2, a1)
    if along_b is None or along_a is None:
        return None
    loop = compose(compose(compose(t1, along_b[0]), invert(t2)), along_a[0])
    r = np.asarray(loop, dtype=np.float64).copy()
    r[2] = math.remainder(float(r[2]), 2 * math.pi)
    # Where each noise enters, in a1's frame: closure 1 at b1, closure 2 at b2.
    at_b2 = compose(t1, along_b[0])
    cov = invert_covariance(t1, s1) + invert_covariance(at_b2, s2)
    pb1, pb2, pa2, pa1 = ends
    if b1 != b2 and pb1 is not None and pb2 is not None:
        root_b = compose(t1, invert(pb1[1]))  # B's tree root in a1's frame
        walk_b = chain_b.path(b1, b2)
        one_tree = chain_a is chain_b and pa1 is not None and pa1[0] == pb1[0]
        if a1 != a2 and one_tree and pa1 is not None:  # one walk: shared edges cancel
            walk = walk_b + chain_a.path(a2, a1)
            root = invert(pa1[1])
            return r, cov + invert_covariance(root, chain_a.noise(pa1[0], walk))
        cov = cov + invert_covariance(root_b, chain_b.noise(pb1[0], walk_b))
    if a1 != a2 and pa1 is not None and pa2 is not None:
        root_a = invert(pa1[1])
        cov = cov + invert_covariance(root_a, chain_a.noise(pa1[0], chain_a.path(a2, a1)))
    return r, cov


def loop_distance(
    c1: tuple[int, int, F64, F64],
    c2: tuple[int, int, F64, F64],
    chain_a: LayerChain,
    chain_b: LayerChain,
) -> float | None:
    """The squared Mahalanobis distance ``r^T S^-1 r`` of the loop two closures close
    (:func:`loop_residual`), or None when it cannot be tested (no common tree, or a
    singular covariance). Parameters as :func:`loop_residual`'s."""
    found = loop_residual(c1, c2, chain_a, chain_b)
    if found is None:
        return None
    r, cov = found
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
    #: Closures judged. Without ``frozen``: those of the windows with at least one
    #: tested loop. With ``frozen``: those settled in this pass, rejected or frozen
    #: (:attr:`newly_kept`), each once; a new closure with fewer tested partners is
    #: not counted (it is judged again in the next pass).
    judged: int
    #: Pairs of closures whose loop could be tested.
    loops_tested: int
    #: Pairs of closures whose loop could not be tested (counted consistent).
    loops_untestable: int = 0
    #: The closures to freeze: with ``frozen``, those judged in this pass for the first
    #: time, kept, and tested against at least ``min_failures`` closures still in;
    #: without, every kept closure of the windows.
    newly_kept: list[ClosureEdge] = field(default_factory=list)


def _most_failing(failing: Mapping[int, set[int]], movable: Iterable[int], least: int) -> set[int]:
    """Remove, one at a time, the movable closure failing the most loops with the
    closures still in (ties: the newest), while it fails at least ``least``; the removed
    are returned."""
    fails = {p: set(q) for p, q in failing.items()}
    out: set[int] = set()
    movable = set(movable)
    while True:
        worst = max(
            (p for p in movable if p not in out), key=lambda p: (len(fails[p]), p), default=None
        )
        if worst is None or len(fails[worst]) < least:
            return out
        out.add(worst)
        for q in fails.pop(worst):
            fails[q].discard(worst)
        fails[worst] = set()


def pcm_gate(
    closures: Sequence[ClosureEdge],
    layer_of: Mapping[int, int],
    chains: Mapping[int, LayerChain],
    *,
    max_per_pair: int = MAX_PER_PAIR,
    threshold: float = CHI2_99_3DOF,
    frozen: AbstractSet[frozenset[int]] | None = None,
    min_failures: int = MIN_FAILURES,
) -> PcmResult:
    """Keep each pair of layers' consistent closures, reject the rest.

    Two ways to judge. Without ``frozen`` (None, PCM as published): every closure of
    each window is judged again in every pass, and the set kept is a maximum clique of
    the consistency graph. With ``frozen`` (the pose pairs of closures judged in an
    earlier pass and kept): a new closure is judged against every closure of its
    window (frozen or new; loops between two frozen closures are not tested again),
    and is rejected only when its loops fail with ``min_failures`` or more of the
    closures still in: the new closure failing the most is rejected first (its
    failures then leave the others' counts), until none fails so often. A kept closure
    is frozen (:attr:`PcmResult.newly_kept`) once its loops with ``min_failures`` or
    more of the closures still in were tested; until then it stays new and is judged
    again in the next pass. A frozen closure is never rejected. One failing loop is what a
    true pair shows by chance (1 % of loops at the default ``threshold``); a closure
    out of place fails with every true partner it can be tested with.

    Parameters
    ----------
    closures : sequence of ClosureEdge
        The closure store, oldest first.
    layer_of : mapping of UID to int
        Each pose's layer (its source robot). A closure with a pose in none is kept,
        unjudged.
    chains : mapping of int to LayerChain
        Each layer's odometry (the loops' means and covariances).
    max_per_pair : int
        Newest closures of a pair of layers judged (default :data:`MAX_PER_PAIR`, at
        least 1); the older ones are kept.
    threshold : float
        Largest squared Mahalanobis distance of a consistent loop; default the 0.99
        chi-square quantile with 3 degrees of freedom.
    frozen : set of frozenset of int, optional
        Pose pairs judged and kept before (:attr:`PcmResult.newly_kept` of earlier
        passes); None (default) judges every window afresh by maximum clique.
    min_failures : int
        With ``frozen``: failing loops that reject a new closure, and tested loops
        that freeze a kept one (default :data:`MIN_FAILURES`, at least 1).

    Returns
    -------
    PcmResult

    Raises
    ------
    ValueError
        If ``max_per_pair`` or ``min_failures`` is below 1.
    """
    if max_per_pair < 1:
        raise ValueError(f"pcm_gate: max_per_pair must be at least 1, got {max_per_pair}")
    if min_failures < 1:
        raise ValueError(f"pcm_gate: min_failures must be at least 1, got {min_failures}")
    groups: dict[tuple[int, int], list[int]] = {}
    for i, c in enumerate(closures):
        la, lb = layer_of.get(c.a), layer_of.get(c.b)
        if la is None or lb is None:
            continue
        groups.setdefault((min(la, lb), max(la, lb)), []).append(i)
    rejected: set[int] = set()
    newly: set[int] = set()
    judged = tested = untestable = 0
    for (la, lb), idx in sorted(groups.items()):
        window = idx[-max_per_pair:]
        old = (
            set()
            if frozen is None
            else {p for p, i in enumerate(window) if closures[i].pair in frozen}
        )
        new = [p for p in range(len(window)) if p not in old]
        if len(window) < 2 or not new:
            # Nothing to test against: a lone new closure waits, unjudged, for partners.
            continue
        oriented = [orient(closures[i], la, layer_of) for i in window]
        failing: dict[int, set[int]] = {p: set() for p in range(len(window))}
        partners: dict[int, set[int]] = {p: set() for p in range(len(window))}
        for p in range(len(window)):
            for q in range(p + 1, len(window)):
                if p in old and q in old:
                    continue
                d2 = loop_distance(oriented[p], oriented[q], chains[la], chains[lb])
                if d2 is None:
                    untestable += 1
                    continue
                tested += 1
                partners[p].add(q)
                partners[q].add(p)
                if d2 > threshold:
                    failing[p].add(q)
                    failing[q].add(p)
        if frozen is None:
            g: nx.Graph = nx.complement(nx.Graph(failing))
            g.add_nodes_from(range(len(window)))
            clique, _ = nx.max_weight_clique(g, weight=None)
            out = set(range(len(window))) - set(clique)
            newly.update(window[p] for p in new)
            judged += sum(1 for p in new if partners[p])
        else:
            out = _most_failing(failing, new, min_failures)
            # Frozen only once tested against enough closures still in to have been
            # rejected: a closure first of its pair (or untestable so far) would
            # otherwise be frozen unjudged, and lock out every later closure it fails.
            settled = {p for p in new if p not in out and len(partners[p] - out) >= min_failures}
            newly.update(window[p] for p in settled)
            judged += len(settled) + len(out)
        rejected.update(window[p] for p in out)
    kept = [c for i, c in enumerate(closures) if i not in rejected]
    gone = [c for i, c in enumerate(closures) if i in rejected]
    fresh = [c for i, c in enumerate(closures) if i in newly and i not in rejected]
    return PcmResult(kept, gone, judged, tested, untestable, fresh)
