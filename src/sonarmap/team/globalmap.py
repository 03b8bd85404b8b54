"""The robot's global map (thesis 002, l.1827-1862), recomputed in batches.

Three steps, each a function over plain records:

1. :func:`optimise_graph`: the graph of all poses of all layers, odometry and
   loop-closure edges as between-factors, optimised with gtsam's graduated
   non-convexity (GNC, truncated-least-squares loss) so that false closures are
   rejected; the closures inconsistent with the result are reported for the closure
   store to remove.
2. :func:`fuse_local_maps`: every pose's local occupancy map (int8 log-odds in the
   pose's frame) resampled into one global grid at the pose's estimate and summed.
3. :func:`align_to_prior`: the fused map, in the robot's own global frame, aligned to
   the prior map by FFT correlation over all rotations and shifts, the ``n_best``
   hypotheses refined by a particle filter.

:func:`plot_pose_graph` draws the graph over the prior map; :func:`plot_team` draws a
team's graphs, one colour per robot.

Transforms follow :mod:`sonarmap.team.records`: ``(x, y, theta)`` maps a frame's
coordinates into its parent's, ``p_parent = R(theta) p + (x, y)``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import gtsam
import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from scipy import fft as sfft
from scipy import ndimage, stats

from ..errors import ConfigError, InputError
from ..files import atomic_write
from ..grid import Grid
from ..io.rosmap import OCCUPIED, OccupancyMap
from .records import LOGODDS_SCALE, ClosureEdge, OdometryEdge, Pose, compose, invert

__all__ = [
    "Alignment",
    "GraphResult",
    "Hypothesis",
    "align_to_prior",
    "fuse_local_maps",
    "grid_around",
    "layer_frames",
    "optimise_graph",
    "plot_pose_graph",
    "plot_team",
]

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]
Estimates = Mapping[int, F64] | Mapping[int, Sequence[float]]

#: Squared Mahalanobis distance below which a 3-D residual is an inlier with 99 %
#: probability: chi-square quantile 0.99 with 3 degrees of freedom.
CHI2_99_3DOF = float(stats.chi2.ppf(0.99, 3))


# --- pose graph ------------------------------------------------------------------------


@dataclass(frozen=True)
class GraphResult:
    """The optimised pose graph.

    Attributes
    ----------
    estimates : dict of int to ndarray (3,)
        New global ``(x, y, theta)`` of every pose, by UID.
    anchor : int
        The UID held at its previous estimate.
    weights : ndarray (n_closures,)
        GNC's final weight of each closure (1 inlier, 0 outlier; 1 for every closure
        without GNC). NaN for closures not used (see ``skipped``).
    residuals : ndarray (n_closures,)
        Each closure's squared Mahalanobis residual ``r^T C^-1 r`` at the result
        (NaN for closures not used).
    gnc_outliers : tuple of int
        Indices (into the ``closures`` given) of the closures GNC rejected (weight < 0.5).
    gate_outliers : tuple of int
        Indices of the closures whose residual exceeds the chi-square gate.
    skipped : tuple of int
        Indices of closures naming a pose not in the graph; not used, not judged.
    error_initial, error_final : float
        gtsam's graph error (half the sum of squared whitened residuals) at the initial
        values with every factor, and at the result without the rejected closures.
    iterations : int or None
        Levenberg-Marquardt iterations (``robust="none"``); gtsam does not expose GNC's.
    """

    estimates: dict[int, F64]
    anchor: int
    weights: F64
    residuals: F64
    gnc_outliers: tuple[int, ...]
    gate_outliers: tuple[int, ...]
    skipped: tuple[int, ...]
    error_initial: float
    error_final: float
    iterations: int | None = None

    @property
    def inconsistent(self) -> tuple[int, ...]:
        """Indices of the closures inconsistent with the result (GNC or gate): the ones
        the closure store removes."""
        return tuple(sorted(set(self.gnc_outliers) | set(self.gate_outliers)))

    def consistent_closures(self, closures: Sequence[ClosureEdge]) -> list[ClosureEdge]:
        """The closures to keep: ``closures`` (the ones optimised) minus the inconsistent."""
        bad = set(self.inconsistent)
        return [c for i, c in enumerate(closures) if i not in bad]


def _pose_dict(poses: Mapping[int, Pose] | Sequence[Pose]) -> dict[int, Pose]:
    if isinstance(poses, Mapping):
        out = dict(poses)
        for uid, p in out.items():
            if p.uid != uid:
                raise InputError(f"poses: key {uid} holds the pose of UID {p.uid}")
    else:
        out = {}
        for p in poses:
            if p.uid in out:
                raise InputError(f"poses: UID {p.uid} given twice")
            out[p.uid] = p
    if not out:
        raise InputError("poses: the graph has no pose")
    for uid, p in out.items():
        if not np.isfinite(p.estimate).all():
            raise InputError(f"pose {uid}: estimate {p.estimate.tolist()} is not finite")
    return out


def _check_edge(e: OdometryEdge | ClosureEdge, what: str) -> None:
    if e.a == e.b:
        raise InputError(f"{what} {e.a} -> {e.b}: an edge joins two different poses")
    if not all(math.isfinite(v) for v in e.transform):
        raise InputError(f"{what} {e.a} -> {e.b}: transform {e.transform} is not finite")
    cov = e.cov()
    if not np.isfinite(cov).all() or not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12):
        raise InputError(f"{what} {e.a} -> {e.b}: covariance is not a finite symmetric 3x3")
    if np.linalg.eigvalsh(cov).min() <= 0:
        raise InputError(f"{what} {e.a} -> {e.b}: covariance is not positive definite")


def _components(uids: Iterable[int], edges: Iterable[tuple[int, int]]) -> dict[int, int]:
    """Connected-component label of each UID (union-find)."""
    parent = {u: u for u in uids}

    def find(u: int) -> int:
        while parent[u] != u:
            parent[u] = parent[parent[u]]
            u = parent[u]
        return u

    for a, b in edges:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return {u: find(u) for u in parent}


def _oldest(uids: Iterable[int], poses: Mapping[int, Pose]) -> int:
    return min(uids, key=lambda u: (poses[u].time, u))


def _chain_odometry(
    poses: Mapping[int, Pose], odometry: Sequence[OdometryEdge], roots: Sequence[int]
) -> dict[int, F64]:
    """Initial values: odometry chained breadth-first from each root's estimate; poses
    no root reaches keep their estimate."""
    nbrs: dict[int, list[tuple[int, F64]]] = {u: [] for u in poses}
    for e in odometry:
        t = np.array(e.transform, dtype=np.float64)
        nbrs[e.a].append((e.b, t))
        nbrs[e.b].append((e.a, invert(t)))
    init: dict[int, F64] = {}
    for root in roots:
        if root in init:
            continue
        init[root] = poses[root].estimate.copy()
        queue = deque([root])
        while queue:
            u = queue.popleft()
            for v, t in nbrs[u]:
                if v not in init:
                    init[v] = compose(init[u], t)
                    queue.append(v)
    for u, p in poses.items():
        init.setdefault(u, p.estimate.copy())
    return init


def optimise_graph(
    poses: Mapping[int, Pose] | Sequence[Pose],
    odometry: Sequence[OdometryEdge],
    closures: Sequence[ClosureEdge],
    *,
    robust: Literal["gnc", "none"] = "gnc",
    inlier_threshold: float = CHI2_99_3DOF,
    gate: float | None = None,
    anchor: int | None = None,
    anchor_sigma: tuple[float, float, float] = (1e-4, 1e-4, 1e-5),
    free_sigma: tuple[float, float, float] = (1e3, 1e3, 10.0),
    initial: Literal["odometry", "estimates"] = "odometry",
    max_iterations: int = 100,
) -> GraphResult:
    """Optimise the pose graph and judge the closures.

    Parameters
    ----------
    poses : mapping of UID to Pose, or sequence of Pose
        Every pose of every layer.
    odometry : sequence of OdometryEdge
        Edges between two poses of ``poses`` (others: :class:`InputError`). Known
        inliers: GNC never rejects one.
    closures : sequence of ClosureEdge
        Loop closures; those naming a pose not in ``poses`` are skipped (the pose may
        have been deleted since), listed in ``GraphResult.skipped``.
    robust : {"gnc", "none"}
        ``"gnc"``: gtsam's GncLMOptimizer with the truncated-least-squares loss;
        ``"none"``: plain Levenberg-Marquardt (every closure trusted).
    inlier_threshold : float
        GNC's inlier bound on a closure's squared Mahalanobis residual; default the
        0.99 chi-square quantile with 3 degrees of freedom (11.34). (The thesis gives
        no value.)
    gate : float, optional
        After optimisation, a closure whose squared Mahalanobis residual exceeds this
        is inconsistent too; default ``inlier_threshold``.
    anchor : int, optional
        UID held at its current estimate by a tight prior; default the oldest pose
        (smallest ``time``, then smallest UID).
    anchor_sigma : tuple of float
        Standard deviations (m, m, rad) of the anchor's prior.
    free_sigma : tuple of float
        Standard deviations of the loose prior put on the oldest pose of each
        odometry-connected group without the anchor (another robot's layer) at its
        initial value, so that the problem stays determined when GNC rejects every
        closure joining it to the rest. Loose enough to have no effect otherwise.
    initial : {"odometry", "estimates"}
        Initial values: odometry chained from the anchor (and from the oldest pose of
        each other group, at its stored estimate), or the poses' stored estimates.
    max_iterations : int
        Iteration cap of each Levenberg-Marquardt run (GNC's outer loop keeps gtsam's
        default, 100: gtsam warns against changing it).

    Returns
    -------
    GraphResult

    Raises
    ------
    InputError
        No pose, an odometry edge naming an unknown pose, a degenerate edge or
        covariance, an unknown anchor.
    ConfigError
        A bad parameter.
    """
    if robust not in ("gnc", "none"):
        raise ConfigError(f"robust must be 'gnc' or 'none', got {robust!r}")
    if initial not in ("odometry", "estimates"):
        raise ConfigError(f"initial must be 'odometry' or 'estimates', got {initial!r}")
    if not (math.isfinite(inlier_threshold) and inlier_threshold > 0):
        raise ConfigError(f"inlier_threshold must be > 0, got {inlier_threshold}")
    gate = inlier_threshold if gate is None else gate
    if not (math.isfinite(gate) and gate > 0):
        raise ConfigError(f"gate must be > 0, got {gate}")
    if max_iterations < 1:
        raise ConfigError(f"max_iterations must be >= 1, got {max_iterations}")
    for name, sig in (("anchor_sigma", anchor_sigma), ("free_sigma", free_sigma)):
        if len(sig) != 3 or not all(math.isfinite(s) and s > 0 for s in sig):
            raise ConfigError(f"{name} must be three positive numbers, got {sig}")
    table = _pose_dict(poses)
    for e in odometry:
        _check_edge(e, "odometry edge")
        for u in (e.a, e.b):
            if u not in table:
                raise InputError(f"odometry edge {e.a} -> {e.b}: pose {u} is not in the graph")
    used: list[int] = []
    skipped: list[int] = []
    for i, c in enumerate(closures):
        _check_edge(c, "closure")
        (used if c.a in table and c.b in table else skipped).append(i)
    if anchor is None:
        anchor = _oldest(table, table)
    elif anchor not in table:
        raise InputError(f"anchor {anchor} is not a pose of the graph")

    uids = sorted(table)
    # UIDs reach 2^63; dense indices keep gtsam's keys small and printable.
    key = {u: i for i, u in enumerate(uids)}
    group = _components(uids, ((e.a, e.b) for e in odometry))
    members: dict[int, list[int]] = {}
    for u in uids:
        members.setdefault(group[u], []).append(u)
    others = sorted(g for g in members if g != group[anchor])
    roots = [anchor, *(_oldest(members[g], table) for g in others)]
    if initial == "odometry":
        init = _chain_odometry(table, odometry, roots)
    else:
        init = {u: p.estimate.copy() for u, p in table.items()}

    graph = gtsam.NonlinearFactorGraph()
    graph.add(
        gtsam.PriorFactorPose2(
            key[anchor],
            gtsam.Pose2(*table[anchor].estimate),
            gtsam.noiseModel.Diagonal.Sigmas(np.array(anchor_sigma, dtype=np.float64)),
        )
    )
    for r in roots[1:]:
        graph.add(
            gtsam.PriorFactorPose2(
                key[r],
                gtsam.Pose2(*init[r]),
                gtsam.noiseModel.Diagonal.Sigmas(np.array(free_sigma, dtype=np.float64)),
            )
        )
    for e in odometry:
        graph.add(_between(e, key))
    n_known = graph.size()
    for i in used:
        graph.add(_between(closures[i], key))

    values = gtsam.Values()
    for u in uids:
        values.insert(key[u], gtsam.Pose2(*init[u]))
    error_initial = float(graph.error(values))

    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(max_iterations)
    iterations: int | None = None
    w_used = np.ones(len(used), dtype=np.float64)
    if robust == "gnc" and used:
        params = gtsam.GncLMParams(lm)
        params.setLossType(gtsam.GncLossType.TLS)
        params.setKnownInliers(list(range(n_known)))
        gnc = gtsam.GncLMOptimizer(graph, values, params)
        # gtsam compares a factor's error, half the squared Mahalanobis residual.
        gnc.setInlierCostThresholds(inlier_threshold / 2.0)
        result = gnc.optimize()
        w_used = np.asarray(gnc.getWeights(), dtype=np.float64)[n_known:]
    else:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
        result = opt.optimize()
        iterations = int(opt.iterations())

    n = len(closures)
    weights = np.full(n, np.nan)
    residuals = np.full(n, np.nan)
    weights[used] = w_used
    # A factor's error is half its squared Mahalanobis residual.
    residuals[used] = [2.0 * graph.at(n_known + j).error(result) for j in range(len(used))]
    gnc_out = tuple(i for i, w in zip(used, w_used, strict=True) if w < 0.5)
    gate_out = tuple(i for i in used if residuals[i] > gate)
    final = gtsam.NonlinearFactorGraph()
    for k in range(n_known):
        final.add(graph.at(k))
    for j in range(len(used)):
        if w_used[j] >= 0.5:
            final.add(graph.at(n_known + j))
    estimates = {u: _pose2_array(result.atPose2(key[u])) for u in uids}
    return GraphResult(
        estimates=estimates,
        anchor=anchor,
        weights=weights,
        residuals=residuals,
        gnc_outliers=gnc_out,
        gate_outliers=gate_out,
        skipped=tuple(skipped),
        error_initial=error_initial,
        error_final=float(final.error(result)),
        iterations=iterations,
    )


def layer_frames(
    own: Mapping[int, F64],
    layers: Mapping[int, Mapping[int, F64]],
    closures: Sequence[ClosureEdge],
) -> dict[int, F64]:
    """Where each received layer's frame lies in the robot's own, from the closures
    joining the layer's poses to the robot's own poses.

    A received pose's estimate is its source's, in the source's frame (the source's
    believed start, which need not be ours); each closure between an
    own pose ``a`` and a pose ``b`` of a layer says where ``b`` is in our frame, and so
    proposes ``(est_a (+) T_ab) (+) inv(est_b)`` as the layer's frame. The layer's
    frame is the median of its proposals (x and y each, the heading by the median of
    its sine and cosine), so that a few false closures do not move it.

    Parameters
    ----------
    own : mapping of UID to ndarray (3,)
        The robot's own poses' estimates (x, y, theta) in its frame.
    layers : mapping of int to mapping of UID to ndarray (3,)
        Each received layer (by source robot): its poses' estimates in its source's
        frame.
    closures : sequence of ClosureEdge
        The closure store; closures not joining an own pose to a layer's are ignored.

    Returns
    -------
    dict of int to ndarray (3,)
        ``(x, y, theta)`` of each layer's frame in ours, for the layers that share at
        least one closure with an own pose (the others are left out).
    """
    owner = {u: s for s, poses in layers.items() for u in poses}
    proposals: dict[int, list[F64]] = {}
    for c in closures:
        t = np.array(c.transform, dtype=np.float64)
        for a, b, ab in ((c.a, c.b, t), (c.b, c.a, invert(t))):
            if a in own and b in owner:
                where = compose(np.asarray(own[a], dtype=np.float64), ab)
                est_b = np.asarray(layers[owner[b]][b], dtype=np.float64)
                proposals.setdefault(owner[b], []).append(compose(where, invert(est_b)))
    out: dict[int, F64] = {}
    for source, props in proposals.items():
        arr = np.array(props).reshape(-1, 3)
        heading = math.atan2(
            float(np.median(np.sin(arr[:, 2]))), float(np.median(np.cos(arr[:, 2])))
        )
        out[source] = np.array([np.median(arr[:, 0]), np.median(arr[:, 1]), heading])
    return out


def _between(e: OdometryEdge | ClosureEdge, key: Mapping[int, int]) -> Any:
    return gtsam.BetweenFactorPose2(
        key[e.a],
        key[e.b],
        gtsam.Pose2(*e.transform),
        gtsam.noiseModel.Gaussian.Covariance(e.cov()),
    )


def _pose2_array(p: Any) -> F64:
    return np.array([p.x(), p.y(), p.theta()], dtype=np.float64)


# --- fused occupancy map ----------------------------------------------------------------


def _estimate_array(v: Any, uid: int) -> F64:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"estimate of pose {uid}: three finite numbers expected, got {v!r}")
    return a


def grid_around(
    estimates: Estimates | npt.ArrayLike,
    radius: float,
    resolution: float,
    margin: float = 0.0,
) -> Grid:
    """A grid covering every pose's local map.

    Parameters
    ----------
    estimates : mapping of UID to (x, y, theta), or array (n, 3)
        Pose estimates in the global frame.
    radius : float
        Half the side of the local maps (metres): a local map of ``n`` cells of ``h``
        metres has ``radius = n h / 2``. The grid covers the disc of radius
        ``radius * sqrt(2)`` about each pose, where the map's corners reach at any
        heading.
    resolution : float
        Cell side of the grid (metres).
    margin : float
        Extra border (metres), default none.

    Returns
    -------
    Grid
    """
    if isinstance(estimates, Mapping):
        pts = np.array([_estimate_array(v, u) for u, v in estimates.items()]).reshape(-1, 3)
    else:
        pts = np.asarray(estimates, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise InputError("grid_around: no pose estimate given")
    if not np.isfinite(pts).all():
        raise InputError("grid_around: estimates are not finite")
    if not (math.isfinite(radius) and radius > 0):
        raise ConfigError(f"radius must be > 0 metres, got {radius}")
    if not (math.isfinite(margin) and margin >= 0):
        raise ConfigError(f"margin must be >= 0 metres, got {margin}")
    reach = radius * math.sqrt(2.0) + margin
    lo = pts[:, :2].min(axis=0) - reach
    hi = pts[:, :2].max(axis=0) + reach
    return Grid.from_bounds(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), resolution)


def _local_indices(x: F64, y: F64, pose: F64, size: int, h: float) -> tuple[F64, F64]:
    """Fractional (row, col) in a local map of world points: cell centres are whole."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = x - pose[0], y - pose[1]
    lx = c * dx + s * dy
    ly = -s * dx + c * dy
    half = size * h / 2.0
    col = (lx + half) / h - 0.5
    row = size - 1 - ((ly + half) / h - 0.5)
    return row, col


def _footprint(grid: Grid, pose: F64, radius: float) -> tuple[slice, slice] | None:
    r0, c0 = grid.world_to_cell(pose[0] - radius, pose[1] + radius)
    r1, c1 = grid.world_to_cell(pose[0] + radius, pose[1] - radius)
    rs = slice(max(int(r0), 0), min(int(r1) + 1, grid.rows))
    cs = slice(max(int(c0), 0), min(int(c1) + 1, grid.cols))
    if rs.start >= rs.stop or cs.start >= cs.stop:
        return None
    return rs, cs


def fuse_local_maps(
    poses: Mapping[int, Pose] | Sequence[Pose],
    estimates: Estimates | None,
    grid: Grid,
    *,
    order: int = 1,
    clip: float = 10.0,
) -> OccupancyMap:
    """The global occupancy map: every local map resampled at its pose's estimate.

    Parameters
    ----------
    poses : mapping of UID to Pose, or sequence of Pose
        Poses without a local map are skipped.
    estimates : mapping of UID to (x, y, theta), optional
        Global estimates (e.g. ``GraphResult.estimates``); a pose missing from it (or
        every pose, when ``None``) uses its stored ``estimate``.
    grid : Grid
        The global grid (:func:`grid_around` makes one covering every local map).
    order : {0, 1}
        Sampling of the local log-odds: 0 nearest cell, 1 bilinear. Bilinear sampling
        is normalised by the bilinear weight of the known (non-zero) cells, so that
        unknown cells do not pull a wall's log-odds towards 0; a global cell is seen
        when that weight is at least 0.5.
    clip : float
        Bound of the summed (natural) log-odds; default 10 (probability 0.99995), a
        choice: the thesis is silent.

    Returns
    -------
    OccupancyMap
        Probabilities of the clipped sums; NaN where no local map saw the cell.
    """
    if order not in (0, 1):
        raise ConfigError(f"order must be 0 (nearest) or 1 (bilinear), got {order}")
    if not (math.isfinite(clip) and clip > 0):
        raise ConfigError(f"clip must be > 0, got {clip}")
    table = _pose_dict(poses)
    total = np.zeros(grid.shape, dtype=np.float64)
    seen = np.zeros(grid.shape, dtype=bool)
    for uid, p in sorted(table.items()):
        lm = p.local_map
        if lm is None:
            continue
        est = p.estimate if estimates is None or uid not in estimates else estimates[uid]
        pose = _estimate_array(est, uid)
        n, h = lm.size, lm.resolution
        box = _footprint(grid, pose, n * h / 2.0 * math.sqrt(2.0) + grid.resolution)
        if box is None:
            continue
        rr, cc = np.mgrid[box]
        x, y = grid.cell_centres(rr, cc)
        row, col = _local_indices(x, y, pose, n, h)
        lo = lm.logodds.astype(np.float64) / LOGODDS_SCALE
        known = (lm.logodds != 0).astype(np.float64)
        at = np.stack([row, col])
        wsum = ndimage.map_coordinates(known, at, order=order, mode="constant", cval=0.0)
        vsum = ndimage.map_coordinates(lo, at, order=order, mode="constant", cval=0.0)
        hit = wsum >= 0.5
        total[box][hit] += vsum[hit] / wsum[hit]
        seen[box] |= hit
    total = np.clip(total, -clip, clip)
    prob = 1.0 / (1.0 + np.exp(-total))
    return OccupancyMap(grid, np.where(seen, prob, np.nan).astype(np.float32))


# --- alignment to the prior map -------------------------------------------------------------


@dataclass(frozen=True)
class Hypothesis:
    """One correlation peak: ``transform`` (x, y, theta) from the built map's frame
    into the prior's, and ``score``, the mean near-miss value of the built map's
    occupied points there (1 every point on a prior wall, 0 none within reach)."""

    transform: tuple[float, float, float]
    score: float


@dataclass(frozen=True)
class Alignment:
    """The built map aligned to the prior.

    Attributes
    ----------
    transform : ndarray (3,)
        ``(x, y, theta)`` taking built-map coordinates into the prior's frame.
    score : float
        Mean distance (metres, capped at ``reach``) from the built map's occupied
        points, so moved, to the prior's nearest occupied cell: lower is better.
    hypotheses : tuple of Hypothesis
        The correlation's best peaks, best first.
    inlier_fraction : float
        Fraction of the moved occupied points within one prior cell of a prior wall.
    """

    transform: F64
    score: float
    hypotheses: tuple[Hypothesis, ...]
    inlier_fraction: float = field(default=math.nan)


def _occupied_points(m: OccupancyMap, what: str) -> F64:
    occ = m.classes() == OCCUPIED
    if not occ.any():
        raise InputError(f"{what} map has no occupied cell: nothing to align")
    rr, cc = np.nonzero(occ)
    x, y = m.grid.cell_centres(rr, cc)
    return np.column_stack([x, y])


def _rot(theta: float) -> F64:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _coarse_near(near: F64, grid: Grid, factor: int) -> tuple[F64, Grid]:
    """The near-miss image max-pooled over ``factor`` x ``factor`` blocks, and its grid.

    The image is padded with zeros at the top and the right so that the coarse grid
    keeps the fine grid's lower-left corner: a coarse cell's value is the best fine
    value under it, so a coarse score never ranks a place below what the fine image
    would give there (the multi-resolution search's bound).
    """
    if factor == 1:
        return near, grid
    rows = -(-grid.rows // factor)
    cols = -(-grid.cols // factor)
    padded = np.zeros((rows * factor, cols * factor), dtype=np.float64)
    # Row 0 is the top: the fine rows go to the bottom of the padded image.
    padded[rows * factor - grid.rows :, : grid.cols] = near
    pooled = padded.reshape(rows, factor, cols, factor).max(axis=(1, 3))
    return pooled, Grid(grid.resolution * factor, grid.origin, (rows, cols))


def _correlate_all(
    pts: F64, near: F64, grid: Grid, angles: int
) -> Iterator[tuple[float, npt.NDArray[np.float64], int, int]]:
    """Per rotation, the correlation of the rotated points (about their centroid)
    with ``near``; yields (theta, map, row offset, col offset) where map index
    ``(k, l)`` puts the centroid on cell ``(k - row offset, l - col offset)`` of
    ``grid``. One map at a time: a caller that keeps only its peaks holds one map's
    memory, not ``angles`` maps'."""
    h = grid.resolution
    rmax = float(np.max(np.hypot(pts[:, 0], pts[:, 1])))
    half = math.ceil(rmax / h) + 1
    d = 2 * half + 1
    shape = (sfft.next_fast_len(grid.rows + d - 1), sfft.next_fast_len(grid.cols + d - 1))
    f_near = sfft.rfft2(near, s=shape)
    for k in range(angles):
        theta = 2.0 * math.pi * k / angles
        q = pts @ _rot(theta).T
        img = np.zeros((d, d), dtype=np.float64)
        # Row grows downwards (-y), column with +x; the centroid sits at (half, half).
        img[half - np.rint(q[:, 1] / h).astype(int), half + np.rint(q[:, 0] / h).astype(int)] = 1
        count = img.sum()
        corr = sfft.irfft2(f_near * np.conj(sfft.rfft2(img, s=shape)), s=shape)
        # Circular lags -(d-1)..-1 wrap to the end; roll them in front of lag 0.
        corr = np.roll(corr, (d - 1, d - 1), axis=(0, 1))[: grid.rows + d - 1, : grid.cols + d - 1]
        # Lag m puts image cell (a, b) on grid cell (a + m); the centroid on half + m.
        yield (theta, corr / count, d - 1 - half, d - 1 - half)


def _weigh(
    m: tuple[float, F64, int, int],
    grid: Grid,
    centroid: F64,
    guess: tuple[float, float, float],
    sigma: tuple[float, float],
    start: F64,
) -> tuple[float, F64, int, int]:
    """One heading's correlation map times the Gaussian belief in the guess.

    At heading ``theta`` the believed start still lands where the guess puts it, so
    the centroid is expected there plus the start-to-centroid arm turned by
    ``theta``: a heading error moves the map by its lever arm, not about its centroid.
    """
    theta, corr, roff, coff = m
    landed = _rot(guess[2]) @ start + np.asarray(guess[:2], dtype=np.float64)
    expected = landed + _rot(theta) @ (centroid - start)
    x, _ = grid.cell_centres(0, np.arange(corr.shape[1]) - coff)
    _, y = grid.cell_centres(np.arange(corr.shape[0]) - roff, 0)
    turn = math.remainder(theta - guess[2], 2 * math.pi)
    w = np.exp(
        -((y[:, None] - expected[1]) ** 2 + (x[None, :] - expected[0]) ** 2) / (2 * sigma[0] ** 2)
        - turn**2 / (2 * sigma[1] ** 2)
    )
    return theta, corr * w, roff, coff


def _peaks(
    maps: Iterable[tuple[float, F64, int, int]],
    grid: Grid,
    centroid: F64,
    n_best: int,
    nms_distance: float,
    nms_angle: float,
) -> list[Hypothesis]:
    h = grid.resolution
    win = 2 * max(1, round(nms_distance / h)) + 1
    cands: list[tuple[float, float, float, float]] = []
    for theta, corr, roff, coff in maps:
        peak = (corr == ndimage.maximum_filter(corr, size=win, mode="constant")) & (corr > 0)
        kk, ll = np.nonzero(peak)
        best = np.argsort(-corr[kk, ll], kind="stable")[:n_best]
        for j in best:
            x, y = grid.cell_centres(kk[j] - roff, ll[j] - coff)
            cands.append((float(corr[kk[j], ll[j]]), theta, float(x), float(y)))
    cands.sort(key=lambda c: -c[0])
    kept: list[tuple[float, float, float, float]] = []
    for c in cands:
        if all(
            abs(math.remainder(c[1] - k[1], 2 * math.pi)) > nms_angle
            or math.hypot(c[2] - k[2], c[3] - k[3]) > nms_distance
            for k in kept
        ):
            kept.append(c)
        if len(kept) == n_best:
            break
    out = []
    for score, theta, tx, ty in kept:
        t = np.array([tx, ty]) - _rot(theta) @ centroid
        out.append(Hypothesis((float(t[0]), float(t[1]), theta), score))
    return out


class _DistanceField:
    """Distance (metres, capped) to the nearest occupied prior cell, bilinear."""

    def __init__(self, prior: OccupancyMap, reach: float) -> None:
        occ = prior.classes() == OCCUPIED
        self.grid = prior.grid
        self.reach = reach
        dist = ndimage.distance_transform_edt(~occ) * prior.grid.resolution
        self.dist = np.minimum(dist, reach)

    def at(self, xy: F64) -> F64:
        """Distances at points ``xy`` (..., 2); ``reach`` outside the grid."""
        g = self.grid
        col = (xy[..., 0] - g.origin[0]) / g.resolution - 0.5
        row = g.rows - 1 - ((xy[..., 1] - g.origin[1]) / g.resolution - 0.5)
        # Edge cells extend to the grid's border; beyond it nothing is known.
        d = ndimage.map_coordinates(self.dist, np.stack([row, col]), order=1, mode="nearest")
        out = (row < -0.5) | (row > g.rows - 0.5) | (col < -0.5) | (col > g.cols - 0.5)
        return np.asarray(np.where(out, self.reach, d), dtype=np.float64)


def _particle_costs(particles: F64, pts: F64, field_: _DistanceField) -> F64:
    """Mean capped distance of the points moved by each particle (tx, ty, theta),
    the rotation being about the points' centroid (``pts`` are centred)."""
    c, s = np.cos(particles[:, 2]), np.sin(particles[:, 2])
    x = c[:, None] * pts[None, :, 0] - s[:, None] * pts[None, :, 1] + particles[:, 0:1]
    y = s[:, None] * pts[None, :, 0] + c[:, None] * pts[None, :, 1] + particles[:, 1:2]
    costs: F64 = field_.at(np.stack([x, y], axis=-1)).mean(axis=1)
    return costs


def _systematic(weights: F64, rng: np.random.Generator) -> npt.NDArray[np.intp]:
    n = len(weights)
    cum = np.cumsum(weights / weights.sum())
    cum[-1] = 1.0
    return np.searchsorted(cum, (rng.random() + np.arange(n)) / n).astype(np.intp)


def align_to_prior(
    built: OccupancyMap,
    prior: OccupancyMap,
    *,
    angles: int = 72,
    n_best: int = 5,
    particles: int = 300,
    rounds: int = 8,
    reach: float = 0.5,
    nms_distance: float = 1.0,
    nms_angle: float | None = None,
    shrink: float = 0.6,
    max_points: int = 4000,
    seed: int = 0,
    guess: tuple[float, float, float] | None = None,
    guess_sigma: tuple[float, float] = (3.0, math.radians(30.0)),
    guess_start: tuple[float, float] | None = None,
    coarse_resolution: float = 0.1,
) -> Alignment:
    """Align the built map (robot's global frame) to the prior map.

    Coarse to fine, as correlative scan matching does it: the built map's occupied
    cell centres are rotated about their centroid for each of ``angles`` headings,
    rasterised on a coarse grid (the prior's cells grouped by ``coarse_resolution``)
    and cross-correlated (FFT) with a near-miss image of the prior,
    ``max(0, 1 - d / reach)`` with ``d`` the distance to the nearest occupied prior
    cell (so that points just off a wall still score), max-pooled onto the coarse
    grid. The ``n_best`` peaks over all headings after non-maximum suppression seed
    a particle filter over ``(x, y, theta)`` at the prior's full resolution, whose
    first jitter covers two coarse cells: each round jitters the particles,
    scores each by the mean capped distance of the moved points to the prior's walls,
    and resamples (systematic) with weights ``exp(-(cost - min cost) / tau)``,
    ``tau`` a quarter of a prior cell; the jitter shrinks by ``shrink`` per round.
    The best particle seen is the answer.

    Parameters
    ----------
    built, prior : OccupancyMap
        Only occupied cells (probability > 0.5) are used (the thesis correlates the
        maps "in the L2 sense"; with free space mostly unobserved in a sonar map the
        walls carry the alignment).
    angles : int
        Headings tried by the correlation (72: every 5 degrees).
    n_best : int
        Hypotheses kept.
    particles : int
        Particles of the filter, shared among the hypotheses at the start.
    rounds : int
        Jitter-score-resample rounds.
    reach : float
        Metres: the near-miss image falls to 0 and the particle cost is capped here.
    nms_distance : float
        Metres: two peaks closer than this (and closer than ``nms_angle``) are one.
    nms_angle : float, optional
        Radians; default two heading steps.
    shrink : float
        Factor on the jitter per round; the first jitter is half a heading step and
        two cells of the coarse search (``coarse_resolution``, or the prior's cell
        when that is finer).
    max_points : int
        The built map's occupied points are thinned (evenly, deterministically) to at
        most this many.
    seed : int
        Of the particle filter's random generator.
    coarse_resolution : float
        Metres: the correlation's cell, the prior's cell times the largest whole number
        that stays within this (the prior's cell when it is coarser). The search's
        memory and time grow with the square of the coarse grid's side; the particle
        filter restores the prior's resolution.
    guess : (x, y, theta), optional
        What the robot believes the transform is (e.g. from a roughly known start).
        Each heading's correlation is then weighed by a Gaussian of the centroid's
        landing point and the heading about the guess (``guess_sigma``: metres,
        radians; 3 m and 30 degrees), so that a partial map of one of several alike
        rooms goes to the room the robot is in. Without it every alignment is equally
        likely, as the thesis has it.
    guess_start : (x, y), optional
        Metres, in the built map's frame: where the robot believes it started, the
        point the guess is surest of. At each heading the centroid is expected where
        the guess puts this point plus the point-to-centroid arm turned by the
        heading, so that a start heading off by ``d`` moves the expected map by
        ``d`` times its distance from the start. Default the built map's centroid
        (the heading then turns the map about itself: no lever arm).

    Returns
    -------
    Alignment

    Raises
    ------
    InputError
        Either map has no occupied cell.
    ConfigError
        A bad parameter.
    """
    for name, v in (("angles", angles), ("n_best", n_best), ("particles", particles)):
        if v < 1:
            raise ConfigError(f"{name} must be >= 1, got {v}")
    if rounds < 0 or max_points < 3:
        raise ConfigError(f"rounds must be >= 0 and max_points >= 3, got {rounds}, {max_points}")
    for name, f in (
        ("reach", reach),
        ("nms_distance", nms_distance),
        ("shrink", shrink),
        ("coarse_resolution", coarse_resolution),
    ):
        if not (math.isfinite(f) and f > 0):
            raise ConfigError(f"{name} must be > 0, got {f}")
    if guess_start is not None and not all(math.isfinite(v) for v in guess_start):
        raise ConfigError(f"guess_start must be finite, got {guess_start}")
    step = 2.0 * math.pi / angles
    nms_angle = 2.0 * step if nms_angle is None else nms_angle
    pts = _occupied_points(built, "built")
    _occupied_points(prior, "prior")
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).astype(int)]
    centroid = pts.mean(axis=0)
    pts = pts - centroid

    field_ = _DistanceField(prior, reach)
    near = np.maximum(0.0, 1.0 - field_.dist / reach)
    h = prior.grid.resolution
    # At most the whole prior in one coarse cell: a larger factor only pads with zeros.
    factor = min(max(1, math.floor(coarse_resolution / h + 1e-9)), max(prior.grid.shape))
    near_c, grid_c = _coarse_near(near, prior.grid, factor)
    maps = _correlate_all(pts, near_c, grid_c, angles)
    if guess is not None:
        g = guess
        about = centroid if guess_start is None else np.asarray(guess_start, dtype=np.float64)
        maps = (_weigh(m, grid_c, centroid, g, guess_sigma, about) for m in maps)
    hyps = _peaks(maps, grid_c, centroid, n_best, nms_distance, nms_angle)

    # Particles carry (where the centroid lands, heading): a heading change then
    # does not swing the whole map about a far-away origin.
    seeds = np.array(
        [[*(_rot(hp.transform[2]) @ centroid + hp.transform[:2]), hp.transform[2]] for hp in hyps]
    )
    rng = np.random.default_rng(seed)
    cloud = seeds[np.arange(particles) % len(seeds)]
    hc = grid_c.resolution
    sigma = np.array([2.0 * hc, 2.0 * hc, step / 2.0])
    tau = h / 4.0
    costs = _particle_costs(cloud, pts, field_)
    best_i = int(np.argmin(costs))
    best, best_cost = cloud[best_i].copy(), float(costs[best_i])
    for _ in range(rounds):
        cloud = cloud + rng.normal(size=cloud.shape) * sigma
        costs = _particle_costs(cloud, pts, field_)
        i = int(np.argmin(costs))
        if costs[i] < best_cost:
            best, best_cost = cloud[i].copy(), float(costs[i])
        cloud = cloud[_systematic(np.exp(-(costs - costs.min()) / tau), rng)]
        sigma = sigma * shrink
    theta = math.remainder(float(best[2]), 2 * math.pi)
    t = best[:2] - _rot(theta) @ centroid
    moved = pts @ _rot(theta).T + best[:2]
    inl = float(np.mean(field_.at(moved) <= h))
    return Alignment(np.array([t[0], t[1], theta]), best_cost, tuple(hyps), inl)


# --- picture ---------------------------------------------------------------------------------


def _axes_over(prior: OccupancyMap | None) -> tuple[Any, Any]:
    """A square figure with the prior map in grey (white free, black occupied, light
    grey unknown) under what is drawn next."""
    fig, ax = plt.subplots(figsize=(7, 7))
    if prior is not None:
        occ = np.where(np.isnan(prior.occupancy), 0.25, prior.occupancy)
        ax.imshow(1.0 - occ, cmap="gray", vmin=0, vmax=1, extent=prior.grid.extent, origin="upper")
    return fig, ax


def _save_axes(fig: Any, ax: Any, title: str, path: str | Path) -> Path:
    """Label the axes in metres, add the title and legend, write the PNG atomically."""
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title)
    ax.legend(loc="upper right", fontsize="small")
    p = Path(path)
    atomic_write(p, lambda tmp: fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png"))
    plt.close(fig)
    return p


def plot_pose_graph(
    prior: OccupancyMap | None,
    estimates: Estimates,
    odometry: Sequence[OdometryEdge],
    closures: Sequence[ClosureEdge],
    path: str | Path,
    truth: Estimates | None = None,
    *,
    rejected: Iterable[int] = (),
    title: str = "",
) -> Path:
    """Draw the pose graph over the prior map and save a PNG.

    Parameters
    ----------
    prior : OccupancyMap, optional
        Drawn in grey (white free, black occupied, light grey unknown).
    estimates : mapping of UID to (x, y, theta)
        Poses drawn as dots; edges naming a pose missing here are not drawn.
    odometry, closures : sequences of edges
        Odometry as grey-blue lines, closures in orange (rejected ones, given by index
        in ``rejected``, dashed red).
    path : str or Path
        The PNG written.
    truth : mapping of UID to (x, y, theta), optional
        True poses, drawn as green crosses.
    rejected : iterable of int
        Indices into ``closures`` to draw as rejected (e.g. ``GraphResult.inconsistent``).
    title : str
        Axes title.

    Returns
    -------
    Path
    """
    est = {u: _estimate_array(v, u) for u, v in estimates.items()}
    bad = set(rejected)
    fig, ax = _axes_over(prior)
    for e in odometry:
        if e.a in est and e.b in est:
            ax.plot(*np.column_stack([est[e.a][:2], est[e.b][:2]]), color="#4a6fa5", lw=1)
    for i, c in enumerate(closures):
        if c.a in est and c.b in est:
            colour, ls = ("red", "--") if i in bad else ("orange", "-")
            ax.plot(*np.column_stack([est[c.a][:2], est[c.b][:2]]), color=colour, ls=ls, lw=1)
    xy = np.array([v[:2] for v in est.values()]).reshape(-1, 2)
    ax.plot(xy[:, 0], xy[:, 1], ".", color="#1f3d7a", ms=4, label="estimates")
    if truth is not None:
        txy = np.array([_estimate_array(v, u)[:2] for u, v in truth.items()]).reshape(-1, 2)
        ax.plot(txy[:, 0], txy[:, 1], "x", color="green", ms=4, label="truth")
    ax.plot([], [], color="orange", label="closures")
    if bad:
        ax.plot([], [], color="red", ls="--", label="rejected closures")
    return _save_axes(fig, ax, title, path)


def plot_team(
    prior: OccupancyMap | None,
    robots: Sequence[tuple[str, Estimates, Sequence[OdometryEdge]]],
    path: str | Path,
    *,
    title: str = "",
) -> Path:
    """Draw several robots' pose graphs over the prior map, one colour each; save a PNG.

    Parameters
    ----------
    prior : OccupancyMap, optional
        Drawn in grey, as by :func:`plot_pose_graph`.
    robots : sequence of (label, estimates, odometry edges)
        Each robot's poses (in the prior's frame) and the edges between them.
    path : str or Path
        The PNG written.
    title : str
        Axes title.

    Returns
    -------
    Path
    """
    fig, ax = _axes_over(prior)
    colours = plt.get_cmap("tab10")
    for k, (label, estimates, odometry) in enumerate(robots):
        colour = colours(k % 10)
        est = {u: _estimate_array(v, u) for u, v in estimates.items()}
        for e in odometry:
            if e.a in est and e.b in est:
                ax.plot(*np.column_stack([est[e.a][:2], est[e.b][:2]]), color=colour, lw=0.8)
        xy = np.array([v[:2] for v in est.values()]).reshape(-1, 2)
        ax.plot(xy[:, 0], xy[:, 1], ".", color=colour, ms=4, label=label)
    return _save_axes(fig, ax, title, path)
