"""One robot's long-term store (thesis 002, sections 2.2-2.3): its own pose graph, one
layer per robot it received data from, its loop closures, and the algorithms that keep
the whole bounded: time stamps, reliabilities, pose compression and region compression
(deletion and merging of poses).

The thesis gives the formulas but no values; every value here is a choice, named in
:class:`StoreParams`. Kernel densities are unnormalised sums of Gaussians (each point
counts itself, so a density is >= 1 at a stored point), cut at four sigma.

Memory is the msgpack size of the records (:func:`records.size_of`). A region's bytes
are those of its poses plus the odometry edges that end (``b``) at one of them, so the
regions of a layer add up to the layer.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from sonarmap.errors import ConfigError, InputError
from sonarmap.team.records import (
    ClosureEdge,
    Landmarks,
    LocalMap,
    OdometryEdge,
    Pose,
    compose,
    compose_covariance,
    decode_as,
    encode,
    invert,
    invert_covariance,
    make_uid,
    robot_of,
    size_of,
)

__all__ = [
    "MERGE_COUNTER_BASE",
    "Layer",
    "Patch",
    "RobotStore",
    "StoreParams",
    "compress_for_sending",
    "compress_pose",
    "kernel_density",
    "local_bound",
    "pose_floor",
    "region_limits",
    "utility",
]

F64 = npt.NDArray[np.float64]
Index = npt.NDArray[np.intp]
Transform = tuple[float, float, float]

#: Merged poses take UID counters from here up, so they never collide with the
#: counters (from 0) the robot gives the poses it makes.
MERGE_COUNTER_BASE = 1 << 39
#: Bytes of a pose's encoding that change with its landmark count besides the rows
#: themselves: five arrays, each with a bin header (2-5 bytes) and a shape entry (1-5).
_HEADER_SLACK = 40
#: Kernel densities ignore points farther than this many sigmas (weight < 3.4e-4).
_KERNEL_CUTOFF = 4.0


@dataclass(frozen=True)
class StoreParams:
    """Parameters of a robot's store; the thesis names them but gives no values.

    Attributes
    ----------
    pose_limit : int
        M_pose, bytes: a larger pose loses landmarks. 16384 (about 90 SIFT landmarks
        besides a small local map).
    region_limit : int
        M_r, bytes of one region of the local layer (poses and the odometry edges ending
        at them). 131072 (eight full poses).
    region_density : float
        Bytes per square metre of a region's area that the region may hold, when that
        is more than ``region_limit``: region r holds at most
        M_r(r) = max(region_limit, region_density x area_r) (:meth:`RobotStore.region_limit`;
        the areas come from the prior map's regions). 4096 (about one 6-7 kB pose per
        1.6 m^2, poses a metre or so apart over the whole region): a region of the
        project's 20 x 16 m buildings (15-20 m^2) keeps the thesis's M_r, while a
        200 m^2 hall of a real plan, which 128 kB held at one pose in 10 m^2, may hold
        800 kB. 0: every region M_r (the thesis's).
    store_limit : int
        M_store, bytes of the whole local layer, every region together: past it, the
        layer is compressed across its regions by the same rule as one region (the
        deletion or merge of best E over all its poses), so a building with more
        regions than the budget holds thins its poses instead of growing. 2097152
        (2 MiB: sixteen regions full at the default M_r, about what the project's
        20 x 16 m buildings fill). 0: no bound but the regions' (regions x M_r).
    a, g, s : float
        The utility's phi(t, r) = a exp(-g t^2 (1 - r)^2 / s^2): scale 1, gain 1 and time
        scale 600 s (a landmark of reliability 0 keeps 1/e of its value after ten
        minutes; one of reliability 0.9 after 100 minutes).
    landmark_sigma : float
        Kernel width (m) of landmark densities (utility and reliability decay): 0.5.
    pose_sigma : float
        Kernel width (m) of pose densities (region compression), over the poses'
        estimated positions: 2.0.
    beta : float or None
        The reliability decay r <- r / (1 + beta d). None (default): chosen per new pose
        as (L - 1) / (the new pose's largest density at its own landmarks), so a landmark
        where the new pose's landmarks are densest decays by L and one where it has none
        keeps its reliability (the thesis ties beta to the landmark counts).
    decay_cap : float
        L >= 1: 1 + beta d is clipped to L, so one update divides a reliability by at
        most L. 2.0.
    fov : float
        The camera's horizontal field of view, degrees: 90.
    camera_range : float
        Metres (3-D distance) within which a landmark could have been seen: 8.
    merge_radius : float
        Two poses merge only if their closure puts them closer than this (m): 1.0.
    merge_min_inliers : int
        N_l, the inliers a closure needs for a merge: 20.
    merge_max_std : float
        Largest standard deviation (m, largest axis of the x-y covariance) of a closure
        used for a merge: 0.1.
    merge_max_angle_std : float
        Largest standard deviation (rad) of its angle: 0.05.
    descriptor_dim : int
        Descriptor bytes, used only to check that ``pose_limit`` holds one landmark: 128.
    merge_on_closure : int
        0 (default): poses merge only when region compression picks a merge (thesis
        2.3.2). N > 0: besides, two own poses merge as soon as a closure joins them with
        at least N inliers and the other merge conditions hold (``merge_radius``,
        ``merge_max_std``, ``merge_max_angle_std``, one region, neither the newest).
        Without ``ExchangeParams.send_closures`` the closure store is never exchanged,
        so another robot holding the two poses sees the loop only if it finds the
        closure again from their landmarks; a merge puts the loop into the local layer
        itself, which is exchanged (the edges of both poses now meet at the merged
        one).
    fold : bool
        When compression deletes a pose, add its local map to that of its nearest
        odometry neighbour in the local layer (:meth:`RobotStore.fold_target`), resampled
        into the neighbour's frame by the odometry edge between them; the neighbour keeps
        its grid, so cells outside it are lost. The thesis deletes a pose's map with it;
        each pose's map holds only the readings since the pose before, so a deletion
        leaves a hole in the map where no other pose saw. The memory is unchanged (a
        local map's grid is fixed), so every bound holds as before. Only a pose no other
        robot holds (:meth:`RobotStore.share`) is changed, so every copy of a pose stays
        what its source sent, and a deleted pose's readings reach the other robots once,
        with the pose that took them. True (default); False: the thesis's deletion.
    """

    pose_limit: int = 16_384
    region_limit: int = 131_072
    region_density: float = 4096.0
    store_limit: int = 2_097_152
    a: float = 1.0
    g: float = 1.0
    s: float = 600.0
    landmark_sigma: float = 0.5
    pose_sigma: float = 2.0
    beta: float | None = None
    decay_cap: float = 2.0
    fov: float = 90.0
    camera_range: float = 8.0
    merge_radius: float = 1.0
    merge_min_inliers: int = 20
    merge_max_std: float = 0.1
    merge_max_angle_std: float = 0.05
    descriptor_dim: int = 128
    merge_on_closure: int = 0
    fold: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.fold, bool):
            raise ConfigError(f"store: fold must be true or false, got {self.fold!r}", field="fold")
        for f in fields(self):
            if f.name == "fold":
                continue
            v = getattr(self, f.name)
            if v is None and f.name == "beta":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(
                    f"store: {f.name} must be a finite number, got {v!r}", field=f.name
                )
            zero_ok = ("a", "g", "beta", "merge_on_closure", "store_limit", "region_density")
            if v < 0 or (v == 0 and f.name not in zero_ok):
                least = ">= 0" if f.name in zero_ok else "> 0"
                raise ConfigError(f"store: {f.name} must be {least}, got {v}", field=f.name)
        for name in (
            "pose_limit",
            "region_limit",
            "store_limit",
            "merge_min_inliers",
            "merge_on_closure",
            "descriptor_dim",
        ):
            if not isinstance(getattr(self, name), int):
                raise ConfigError(f"store: {name} must be an integer", field=name)
        if self.decay_cap < 1:
            raise ConfigError(
                f"store: decay_cap (L) must be >= 1, got {self.decay_cap}", field="decay_cap"
            )
        if self.fov > 360:
            raise ConfigError(f"store: fov must be <= 360 degrees, got {self.fov}", field="fov")
        one = _one_landmark_bytes(self.descriptor_dim)
        if self.pose_limit < one:
            raise ConfigError(
                f"store: pose_limit {self.pose_limit} B is below the size of a pose with one "
                f"landmark ({one} B)",
                field="pose_limit",
            )
        if self.region_limit < self.pose_limit:
            raise ConfigError(
                f"store: region_limit {self.region_limit} B is below pose_limit "
                f"{self.pose_limit} B",
                field="region_limit",
            )
        if 0 < self.store_limit < self.pose_limit:
            raise ConfigError(
                f"store: store_limit {self.store_limit} B is below pose_limit "
                f"{self.pose_limit} B: the store could not hold one pose",
                field="store_limit",
            )


def pose_floor(params: StoreParams, map_cells: int) -> int:
    """Bytes of the largest pose the store must be able to keep: one landmark and a
    local map of ``map_cells`` x ``map_cells`` cells, none of them unknown (pose
    compression drops landmarks, never map cells).

    Parameters
    ----------
    params : StoreParams
        For the descriptor's length.
    map_cells : int
        Cells along a side of a pose's local map (0: no map).
    """
    lm = Landmarks(
        np.zeros((1, 3), dtype=np.float32),
        np.zeros((1, params.descriptor_dim), dtype=np.uint8),
        np.full(1, 0.5, dtype=np.float32),
        np.zeros(1),
        np.full(1, -1, dtype=np.int64),
    )
    local = None
    if map_cells > 0:
        local = LocalMap(np.full((map_cells, map_cells), 127, dtype=np.int8), 0.1)
    uid = make_uid(2**23 - 1, 2**40 - 1)
    return size_of(Pose(uid, 0.0, 2**31 - 1, np.zeros(3), lm, local))


#: The largest odometry edge's encoding (UIDs of the largest size): the edge that
#: arrives with a new pose, which the local layer holds before it is compressed.
_EDGE_BYTES = size_of(
    OdometryEdge(
        make_uid(2**23 - 1, 2**40 - 1),
        make_uid(2**23 - 1, 2**40 - 1),
        (1.0, 1.0, 1.0),
        tuple(1.0 for _ in range(9)),
        1e9,
        1.0,
    )
)


def region_limits(params: StoreParams, areas: Sequence[float]) -> list[int]:
    """Bytes each region may hold, M_r(r) = max(region_limit, region_density x area_r).

    Parameters
    ----------
    params : StoreParams
    areas : sequence of float
        Area (m^2) of regions 0..K-1 of the prior map.
    """
    return [max(params.region_limit, int(params.region_density * float(a))) for a in areas]


def local_bound(params: StoreParams, regions: int | Sequence[float]) -> int:
    """The configured bound of a robot's local layer, bytes: every region full (the sum
    of :func:`region_limits`) or the store's budget M_store if that is less, plus the
    newest pose and its odometry edge, which the layer holds before it is compressed.

    Parameters
    ----------
    params : StoreParams
    regions : int or sequence of float
        The areas (m^2) of the prior map's regions; a count stands for regions of no
        area (each holds ``region_limit``).
    """
    areas = [0.0] * regions if isinstance(regions, int) else list(regions)
    full = sum(region_limits(params, areas))
    if params.store_limit > 0:
        full = min(full, params.store_limit)
    return int(full + params.pose_limit + _EDGE_BYTES)


def _one_landmark_bytes(dim: int) -> int:
    """Bytes of the largest-UID pose with one landmark and no local map."""
    lm = Landmarks(
        np.zeros((1, 3), dtype=np.float32),
        np.zeros((1, dim), dtype=np.uint8),
        np.full(1, 0.5, dtype=np.float32),
        np.zeros(1),
        np.full(1, -1, dtype=np.int64),
    )
    return size_of(Pose(make_uid(2**23 - 1, 2**40 - 1), 0.0, 2**31 - 1, np.zeros(3), lm))


# --- densities and utility ------------------------------------------------------------


def kernel_density(at: npt.ArrayLike, points: npt.ArrayLike, sigma: float) -> F64:
    """Unnormalised Gaussian kernel density of ``points`` at each row of ``at``.

    Parameters
    ----------
    at : array (m, k)
        Where to evaluate.
    points : array (n, k)
        The kernels' centres.
    sigma : float
        Kernel width.

    Returns
    -------
    ndarray (m,)
        sum_j exp(-|at_i - points_j|^2 / (2 sigma^2)) over points within four sigma.
    """
    q = np.asarray(at, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    if len(q) == 0 or len(p) == 0:
        return np.zeros(len(q))
    pairs = cKDTree(q).sparse_distance_matrix(
        cKDTree(p), _KERNEL_CUTOFF * sigma, output_type="ndarray"
    )
    w = np.exp(-(pairs["v"] ** 2) / (2.0 * sigma**2))
    return np.bincount(pairs["i"], weights=w, minlength=len(q)).astype(np.float64)


def utility(landmarks: Landmarks, now: float, params: StoreParams) -> F64:
    """U = phi(t, r) / d of each landmark (thesis eq. 2.3).

    phi = a exp(-g t^2 (1 - r)^2 / s^2) with t = now - stamp (a stamp in the future, from
    another robot's clock, counts as age 0) and d the landmarks' own kernel density at
    the landmark (>= 1: it counts itself).
    """
    t = np.maximum(now - landmarks.stamp, 0.0)
    r = landmarks.reliability.astype(np.float64)
    phi = params.a * np.exp(-params.g * (t * (1.0 - r)) ** 2 / params.s**2)
    d = kernel_density(landmarks.points, landmarks.points, params.landmark_sigma)
    return np.asarray(phi / np.maximum(d, 1.0), dtype=np.float64)


def _row_bytes(lm: Landmarks) -> int:
    return int(
        lm.points.itemsize * 3
        + lm.descriptors.shape[1] * lm.descriptors.itemsize
        + lm.reliability.itemsize
        + lm.stamp.itemsize
        + lm.ids.itemsize
    )


def compress_pose(pose: Pose, limit: int, now: float, params: StoreParams) -> tuple[Pose, Index]:
    """Thesis 2.3 pose compression: drop the landmarks of lowest utility until the pose's
    encoding fits in ``limit`` bytes.

    Landmarks go in batches: each batch is the fewest the byte count proves necessary
    (excess minus the header slack, over the bytes of one landmark row), so the pose
    never loses more than it must; utilities are recomputed between batches, since
    densities change as landmarks go.

    Returns
    -------
    pose : Pose
        The pose itself if it fits, else a copy with fewer landmarks.
    kept : ndarray of int
        Indices (into the original landmarks) of those kept, in order.

    Raises
    ------
    ConfigError
        If not even one landmark fits (the pose's local map alone is too big).
    """
    lm = pose.landmarks
    kept: Index = np.arange(len(lm), dtype=np.intp)
    size = size_of(pose)
    if size <= limit:
        return pose, kept
    one = size_of(pose.with_landmarks(lm.take(kept[:1])))
    if len(lm) == 0 or one > limit:
        raise ConfigError(
            f"store: pose_limit {limit} B is below pose {pose.uid}'s size with at most one "
            f"landmark ({one} B)"
        )
    per = _row_bytes(lm)
    current = pose
    while size > limit:
        cur = current.landmarks
        k = min(max(1, math.ceil((size - limit - _HEADER_SLACK) / per)), len(cur) - 1)
        order = np.argsort(utility(cur, now, params), kind="stable")
        keep = np.ones(len(cur), dtype=bool)
        keep[order[:k]] = False
        kept = kept[keep]
        current = pose.with_landmarks(cur.take(keep))
        size = size_of(current)
    return current, kept


# --- transforms with covariances ------------------------------------------------------


def _tf(v: Iterable[float]) -> Transform:
    x, y, t = (float(u) for u in v)
    return (x, y, t)


def _cov_tuple(c: F64) -> tuple[float, ...]:
    return tuple(float(v) for v in c.reshape(9))


def _reframe(
    a: int,
    b: int,
    transform: Transform,
    cov: F64,
    old: int,
    new: int,
    where: Transform,
) -> tuple[int, int, Transform, F64]:
    """An edge (a, b, transform of b in a) after pose ``old`` became part of ``new``,
    whose frame holds old's frame at ``where`` (taken as exact)."""
    zero = np.zeros((3, 3))
    if a == old:
        a = new
        cov = compose_covariance(where, zero, transform, cov)
        transform = _tf(compose(where, transform))
    if b == old:
        b = new
        back = _tf(invert(where))
        cov = compose_covariance(transform, cov, back, zero)
        transform = _tf(compose(transform, back))
    return a, b, transform, cov


def _fuse_closures(d: ClosureEdge, c: ClosureEdge) -> ClosureEdge:
    """Two closures between the same two poses as one, in ``d``'s direction: the
    information-weighted mean of the transforms (linearised about ``d``'s, which
    holds for the centimetres and degrees two right closures differ by), covariance
    the inverse of the summed information, error the smaller."""
    tf, cov = _tf(c.transform), c.cov()
    if c.a != d.a:
        tf, cov = _tf(invert(tf)), invert_covariance(tf, cov)
    x0 = np.asarray(d.transform, dtype=np.float64)
    delta = np.asarray(tf, dtype=np.float64) - x0
    delta[2] = math.remainder(float(delta[2]), 2.0 * math.pi)
    info_d, info_c = np.linalg.inv(d.cov()), np.linalg.inv(cov)
    fused_cov = np.linalg.inv(info_d + info_c)
    fused_cov = (fused_cov + fused_cov.T) / 2.0
    x = x0 + fused_cov @ info_c @ delta
    x[2] = math.remainder(float(x[2]), 2.0 * math.pi)
    return replace(
        d, transform=_tf(x), covariance=_cov_tuple(fused_cov), error=min(d.error, c.error)
    )


def _to_frame(points: npt.NDArray[np.float32], where: Transform) -> npt.NDArray[np.float64]:
    """Points of a frame held at ``where`` in another frame, expressed in that other."""
    c, s = math.cos(where[2]), math.sin(where[2])
    p = points.astype(np.float64)
    out = p.copy()
    out[:, 0] = c * p[:, 0] - s * p[:, 1] + where[0]
    out[:, 1] = s * p[:, 0] + c * p[:, 1] + where[1]
    return out


# --- layers ---------------------------------------------------------------------------


@dataclass
class Patch:
    """One region of one layer: its time stamp, the short id list (UIDs of the layer's
    poses in the region) and the full id list (what the source had at the stamp, kept
    by the limited-network exchange; equal to the short list in the local layer).
    A patch nobody has sent yet has stamp -inf."""

    stamp: float = -math.inf
    short: set[int] = field(default_factory=set)
    full: set[int] = field(default_factory=set)


class _Sizes:
    """Encoded sizes of records, remembered per object (records are replaced, not
    edited, when their size can change)."""

    def __init__(self) -> None:
        self._cache: dict[int, tuple[object, int]] = {}

    def of(self, record: Pose | OdometryEdge | ClosureEdge) -> int:
        hit = self._cache.get(id(record))
        if hit is not None and hit[0] is record:
            return hit[1]
        n = size_of(record)
        self._cache[id(record)] = (record, n)
        return n

    def total(self, records: Iterable[Pose | OdometryEdge | ClosureEdge]) -> int:
        """Sum of sizes; forgets records no longer passed."""
        old, self._cache = self._cache, {}
        n = 0
        for r in records:
            hit = old.get(id(r))
            size = hit[1] if hit is not None and hit[0] is r else size_of(r)
            self._cache[id(r)] = (r, size)
            n += size
        return n


class Layer:
    """One robot's pose graph as another robot (or itself) stores it.

    Change it through the methods, which keep the patches' id lists right.

    Parameters
    ----------
    source : int
        The robot that made the layer's poses.
    own : bool
        True for a robot's local layer: its full id lists follow the short ones and a
        patch's stamp is the time it last changed.

    Attributes
    ----------
    poses : dict of int to Pose
    edges : list of OdometryEdge
    patches : dict of int to Patch
        By region id.
    """

    def __init__(self, source: int, *, own: bool = False) -> None:
        self.source = source
        self.own = own
        self.poses: dict[int, Pose] = {}
        self.edges: list[OdometryEdge] = []
        self.patches: dict[int, Patch] = {}
        self._pose_sizes = _Sizes()
        self._edge_sizes = _Sizes()

    def patch(self, region: int) -> Patch:
        """The region's patch, created empty if new."""
        return self.patches.setdefault(region, Patch())

    def put_pose(self, pose: Pose, now: float | None = None) -> None:
        """Add a pose, or replace the one with its UID."""
        self.poses[pose.uid] = pose
        patch = self.patch(pose.region)
        patch.short.add(pose.uid)
        if self.own:
            patch.full.add(pose.uid)
            if now is not None:
                patch.stamp = now

    def remove_pose(self, uid: int, now: float | None = None) -> Pose:
        """Remove a pose and every odometry edge touching it."""
        pose = self.poses.pop(uid)
        patch = self.patch(pose.region)
        patch.short.discard(uid)
        if self.own:
            patch.full.discard(uid)
            if now is not None:
                patch.stamp = now
        self.edges = [e for e in self.edges if uid not in (e.a, e.b)]
        return pose

    def add_edge(self, edge: OdometryEdge) -> None:
        """Add an odometry edge unless the same edge is there."""
        if edge not in self.edges:
            self.edges.append(edge)

    def edges_of(self, uid: int) -> list[OdometryEdge]:
        return [e for e in self.edges if uid in (e.a, e.b)]

    def pose_bytes(self, uid: int) -> int:
        return self._pose_sizes.of(self.poses[uid])

    def bytes(self) -> int:
        """Encoded size of all poses and edges (the layer's memory figure)."""
        return self._pose_sizes.total(self.poses.values()) + self._edge_sizes.total(self.edges)

    def region_bytes(self, region: int) -> int:
        """Bytes of the region's poses and of the edges ending at them."""
        uids = self.patches[region].short if region in self.patches else set()
        n = sum(self.pose_bytes(u) for u in uids)
        return n + sum(self._edge_sizes.of(e) for e in self.edges if e.b in uids)

    def state(self) -> dict[str, Any]:
        """The layer as plain msgpack values: poses and edges as their records' own
        encodings, patches as ``[region, stamp, short, full]`` (:meth:`from_state`)."""
        return {
            "source": self.source,
            "poses": [encode(p) for p in self.poses.values()],
            "edges": [encode(e) for e in self.edges],
            "patches": [
                [r, float(p.stamp), sorted(p.short), sorted(p.full)]
                for r, p in self.patches.items()
            ],
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any], *, own: bool = False) -> Layer:
        """The layer a :meth:`state` describes; :class:`~.records.RecordError` or
        ``KeyError`` / ``TypeError`` / ``ValueError`` if it is not one."""
        layer = cls(int(state["source"]), own=own)
        for b in state["poses"]:
            p = decode_as(b, Pose)
            layer.poses[p.uid] = p
        layer.edges = [decode_as(b, OdometryEdge) for b in state["edges"]]
        layer.patches = {
            int(r): Patch(float(stamp), {int(u) for u in short}, {int(u) for u in full})
            for r, stamp, short, full in state["patches"]
        }
        return layer


# --- merging --------------------------------------------------------------------------


def _merge_maps(mp: LocalMap | None, mq: LocalMap | None, where: Transform) -> LocalMap | None:
    """Q's local map resampled (nearest cell) into P's grid, Q's frame held at ``where``
    in P's, and added to P's: log-odds summed and clipped, 0 (unknown) where both are.
    The grid stays P's (merged poses are close), so Q's cells outside it are lost; with
    no map in P, Q's grid size and resolution are used, centred on P's origin."""
    if mq is None:
        return mp
    grid = mp if mp is not None else LocalMap(np.zeros_like(mq.logodds), mq.resolution)
    n, res = grid.size, grid.resolution
    c = (n - 1) / 2.0
    rows, cols = np.mgrid[0:n, 0:n].astype(np.float64)
    dx = (cols - c) * res - where[0]
    dy = (c - rows) * res - where[1]
    ct, st = math.cos(where[2]), math.sin(where[2])
    xq, yq = ct * dx + st * dy, -st * dx + ct * dy
    cq = (mq.size - 1) / 2.0
    coords = np.stack([cq - yq / mq.resolution, xq / mq.resolution + cq])
    moved = map_coordinates(
        mq.logodds.astype(np.int16), coords, order=0, mode="constant", cval=0
    ).astype(np.int16)
    out = np.clip(grid.logodds.astype(np.int16) + moved, -127, 127).astype(np.int8)
    return LocalMap(out, res)


def _unique_pairs(matches: Sequence[tuple[int, int]], na: int, nb: int) -> tuple[Index, Index]:
    """Valid match pairs, each landmark in at most one (the first)."""
    seen_a: set[int] = set()
    seen_b: set[int] = set()
    ia: list[int] = []
    ib: list[int] = []
    for i, j in matches:
        if 0 <= i < na and 0 <= j < nb and i not in seen_a and j not in seen_b:
            seen_a.add(i)
            seen_b.add(j)
            ia.append(i)
            ib.append(j)
    return np.array(ia, dtype=np.intp), np.array(ib, dtype=np.intp)


def _combine(r1: npt.ArrayLike, r2: npt.ArrayLike) -> F64:
    """Reliability of two independent confirmations: 1 - (1 - r1)(1 - r2)."""
    a = np.asarray(r1, dtype=np.float64)
    b = np.asarray(r2, dtype=np.float64)
    return np.asarray(1.0 - (1.0 - a) * (1.0 - b), dtype=np.float64)


@dataclass
class _MergePlan:
    """A merge worked out but not applied: P (closure.a) and Q (closure.b) into ``pose``
    in P's frame; ``p_index`` / ``q_index`` give each of their landmarks' index in it
    (-1: gone)."""

    closure: ClosureEdge
    pose: Pose
    p_index: Index
    q_index: Index
    freed: int
    lost_utility: float


def _plan_merge(
    p: Pose, q: Pose, closure: ClosureEdge, uid: int, now: float, params: StoreParams
) -> _MergePlan:
    where = _tf(closure.transform)
    lp, lq = p.landmarks, q.landmarks
    ip, jq = _unique_pairs(closure.matches, len(lp), len(lq))
    q_pts = _to_frame(lq.points, where)
    pts = lp.points.astype(np.float64)
    pts[ip] = (pts[ip] + q_pts[jq]) / 2.0
    desc = lp.descriptors.copy()
    desc[ip] = ((lp.descriptors[ip].astype(np.uint16) + lq.descriptors[jq] + 1) // 2).astype(
        np.uint8
    )
    rel = lp.reliability.astype(np.float64)
    rel[ip] = _combine(rel[ip], lq.reliability[jq])
    stamp = lp.stamp.copy()
    stamp[ip] = np.maximum(stamp[ip], lq.stamp[jq])
    ids = lp.ids.copy()
    ids[ip] = np.where(ids[ip] >= 0, ids[ip], lq.ids[jq])
    rest = np.ones(len(lq), dtype=bool)
    rest[jq] = False
    moved = lq.take(rest)
    moved.points = q_pts[rest].astype(np.float32)
    landmarks = Landmarks.concat(
        [Landmarks(pts.astype(np.float32), desc, rel.astype(np.float32), stamp, ids), moved]
    )
    merged = Pose(
        uid,
        max(p.time, q.time),
        p.region,
        p.estimate.copy(),
        landmarks,
        _merge_maps(p.local_map, q.local_map, where),
        (p.uid, q.uid),
    )
    u_merged = utility(landmarks, now, params)
    compressed, kept = compress_pose(merged, params.pose_limit, now, params)
    final = np.full(len(landmarks), -1, dtype=np.intp)
    final[kept] = np.arange(len(kept))
    q_index = np.empty(len(lq), dtype=np.intp)
    q_index[jq] = final[ip]
    q_index[rest] = final[len(lp) + np.arange(int(rest.sum()))]
    dropped = np.ones(len(landmarks), dtype=bool)
    dropped[kept] = False
    lost = float(utility(lq, now, params)[jq].sum() + u_merged[dropped].sum())
    freed = size_of(p) + size_of(q) - size_of(compressed)
    return _MergePlan(closure, compressed, final[: len(lp)], q_index, freed, lost)


def _efficiency(freed: int, density: float, lost: float) -> float:
    """E = M / (d sum U) (thesis eq. 2.4); infinite when nothing is lost."""
    cost = density * lost
    return math.inf if cost <= 0 else freed / cost


# --- the store ------------------------------------------------------------------------


class RobotStore:
    """A robot's stores: local layer, received layers and closures (thesis 2.2-2.3).

    Parameters
    ----------
    robot : int
        The owner.
    params : StoreParams, optional
    region_areas : sequence of float, optional
        Area (m^2) of regions 0..K-1 of the prior map, for :meth:`region_limit`; without
        them every region holds ``params.region_limit``.

    Attributes
    ----------
    local : Layer
        The robot's own poses; only it changes them.
    received : dict of int to Layer
        By source robot; changed only in landmark time stamps (and by the exchange).
    closures : list of ClosureEdge
        The closures this robot found, and those peers sent with their poses
        (:meth:`add_peer_closures`; those carry no matches). Their ``matches`` follow
        the poses' landmarks through compression and merging.
    peak_bytes, peak_local_bytes : int
        The largest :meth:`bytes` and ``local.bytes()`` seen, measured once a new pose
        is compressed (step 5) and before its region is, and again after.
    """

    def __init__(
        self,
        robot: int,
        params: StoreParams | None = None,
        region_areas: Sequence[float] | None = None,
    ) -> None:
        self.robot = robot
        self.params = params if params is not None else StoreParams()
        self._region_limits = (
            {}
            if region_areas is None
            else dict(enumerate(region_limits(self.params, region_areas)))
        )
        self.local = Layer(robot, own=True)
        self.received: dict[int, Layer] = {}
        self.closures: list[ClosureEdge] = []
        self.peak_bytes = 0
        self.peak_local_bytes = 0
        self._closure_sizes = _Sizes()
        self._merges = 0
        self._newest: int | None = None
        #: Own poses another robot may hold (:meth:`share`): the fold leaves them as sent.
        self._shared: set[int] = set()
        #: Pose pairs whose closure pairwise consistency rejected (:meth:`reject_closures`).
        self._rejected_pairs: set[frozenset[int]] = set()
        #: Pose pairs whose closure pairwise consistency judged and kept (:meth:`keep_judged`).
        self._judged_pairs: set[frozenset[int]] = set()

    # state

    def state(self) -> dict[str, Any]:
        """Everything the store holds, as plain msgpack values (:meth:`restore`)."""
        return {
            "local": self.local.state(),
            "received": [self.received[s].state() for s in self.received],
            "closures": [encode(c) for c in self.closures],
            "peak_bytes": self.peak_bytes,
            "peak_local_bytes": self.peak_local_bytes,
            "merges": self._merges,
            "newest": self._newest,
            "shared": sorted(self._shared),
            "rejected_pairs": sorted(sorted(p) for p in self._rejected_pairs),
            "judged_pairs": sorted(sorted(p) for p in self._judged_pairs),
        }

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state` (the parameters stay the store's own)."""
        self.local = Layer.from_state(state["local"], own=True)
        self.received = {}
        for s in state["received"]:
            layer = Layer.from_state(s, own=False)
            self.received[layer.source] = layer
        self.closures = [decode_as(b, ClosureEdge) for b in state["closures"]]
        self.peak_bytes = int(state["peak_bytes"])
        self.peak_local_bytes = int(state["peak_local_bytes"])
        self._merges = int(state["merges"])
        self._newest = None if state["newest"] is None else int(state["newest"])
        self._shared = {int(u) for u in state.get("shared", ())}
        # A state saved before the rejected pairs were kept has none.
        self._rejected_pairs = {
            frozenset(int(u) for u in p) for p in state.get("rejected_pairs", ())
        }
        # A state saved before the judged pairs were kept has none: its closures are
        # judged again, once, in the next pass.
        self._judged_pairs = {frozenset(int(u) for u in p) for p in state.get("judged_pairs", ())}

    def region_limit(self, region: int) -> int:
        """Bytes region ``region`` of the local layer may hold: :func:`region_limits` of
        the areas given, ``region_limit`` for a region without one."""
        return self._region_limits.get(region, self.params.region_limit)

    def share(self, uids: Iterable[int]) -> None:
        """Own poses that have left for other robots (offered to or sent to a peer):
        the fold (``StoreParams.fold``) never changes them afterwards, so that every
        copy of a pose is the one its source sent and no reading is fused twice.
        UIDs the local layer does not hold are ignored."""
        poses = self.local.poses
        self._shared = {u for u in self._shared if u in poses}
        self._shared.update(u for u in uids if u in poses)

    def shared(self, uid: int) -> bool:
        """Whether own pose ``uid`` was passed to :meth:`share` (and is still held)."""
        return uid in self._shared and uid in self.local.poses

    # accounting

    def bytes(self) -> int:
        """All the robot stores: layers and closures."""
        n = self.local.bytes() + sum(layer.bytes() for layer in self.received.values())
        return n + self.closure_bytes()

    def closure_bytes(self) -> int:
        """The closure store's encoded bytes."""
        return self._closure_sizes.total(self.closures)

    def _note_peak(self) -> None:
        self.peak_local_bytes = max(self.peak_local_bytes, self.local.bytes())
        self.peak_bytes = max(self.peak_bytes, self.bytes())

    def _holders(self, uid: int) -> list[Layer]:
        layers = [self.local, *self.received.values()]
        return [layer for layer in layers if uid in layer.poses]

    # adding poses

    def add_own_pose(
        self,
        pose: Pose,
        odometry_edge: OdometryEdge | None,
        closures: Sequence[ClosureEdge],
        now: float,
    ) -> None:
        """A new pose of this robot, with the closures association found for it.

        (1) The pose and its odometry edge into the local layer; (2) the closures into
        the closure store; (3) time stamps; (4) reliabilities (closures between two own
        poses); (5) pose compression, then compression of its region, then of the whole
        layer if it exceeds ``store_limit`` (:meth:`compress_store`). The new pose is
        kept whole by region compression until the next one arrives: the next odometry
        edge starts from it.
        """
        if robot_of(pose.uid) != self.robot:
            raise InputError(f"pose {pose.uid} is robot {pose.robot}'s", field="uid")
        if pose.uid in self.local.poses:
            raise InputError(f"pose {pose.uid} is already stored", field="uid")
        if odometry_edge is not None and (
            odometry_edge.b != pose.uid or odometry_edge.a not in self.local.poses
        ):
            raise InputError(
                f"odometry edge {odometry_edge.a} -> {odometry_edge.b} must run from a "
                f"stored pose to the new pose {pose.uid}",
                field="odometry_edge",
            )
        self.local.put_pose(pose, now)
        if odometry_edge is not None:
            self.local.add_edge(odometry_edge)
        self.closures.extend(closures)
        self._update_stamps(closures)
        for c in closures:
            self._update_reliability(c, pose.uid)
        self._newest = pose.uid
        stored = self.local.poses[pose.uid]
        compressed, kept = compress_pose(stored, self.params.pose_limit, now, self.params)
        if compressed is not stored:
            self.local.put_pose(compressed, now)
            self._rewrite_closures(pose.uid, pose.uid, self._index_map(len(stored.landmarks), kept))
        self._note_peak()
        self.compress_region(pose.region, now)
        if self.params.merge_on_closure:
            self.merge_reliable(now)
        self.compress_store(now)
        self._note_peak()

    def merge_reliable(self, now: float) -> list[int]:
        """Merge every pair of own poses a reliable closure joins
        (``StoreParams.merge_on_closure``), the best closure first (most inliers, then
        least error, then the oldest poses), until none is left; the merged UIDs are
        returned. A merged pose may merge again with a third pose. Nothing when the
        option is off (0)."""
        out: list[int] = []
        need = self.params.merge_on_closure
        poses = self.local.poses
        while need > 0:
            best: ClosureEdge | None = None
            for c in self.closures:
                if c.inliers < need or c.a not in poses:
                    continue
                if not self._mergeable(c, poses[c.a].region, need):
                    continue
                if best is None or (c.inliers, -c.error, -min(c.a, c.b)) > (
                    best.inliers,
                    -best.error,
                    -min(best.a, best.b),
                ):
                    best = c
            if best is None:
                break
            out.append(self.merge_poses(best, now))
        return out

    def add_received_pose(
        self,
        source: int,
        pose: Pose,
        odometry_edges: Sequence[OdometryEdge],
        closures: Sequence[ClosureEdge],
        now: float,
    ) -> None:
        """A pose of robot ``source``, received: into its layer with its odometry edges,
        closures stored, time stamps updated; no reliability changes and no compression
        (received data are not ours to change)."""
        if source == self.robot or robot_of(pose.uid) != source:
            raise InputError(
                f"pose {pose.uid} of robot {pose.robot} cannot join received layer {source} "
                f"of robot {self.robot}",
                field="source",
            )
        layer = self.received.setdefault(source, Layer(source))
        if pose.uid in layer.poses:
            raise InputError(f"pose {pose.uid} is already stored", field="uid")
        layer.put_pose(pose)
        for e in odometry_edges:
            layer.add_edge(e)
        self.closures.extend(closures)
        self._update_stamps(closures)
        self._note_peak()

    def reject_closures(self, closures: Iterable[ClosureEdge]) -> list[ClosureEdge]:
        """Remember the pose pairs of closures pairwise consistency rejected
        (:mod:`.pcm`), so that :meth:`add_peer_closures` refuses them hereafter.

        Returns
        -------
        list of ClosureEdge
            The closures whose pair was not rejected before (each pair once).
        """
        new = []
        for c in closures:
            if c.pair not in self._rejected_pairs:
                self._rejected_pairs.add(c.pair)
                new.append(c)
        return new

    def keep_judged(self, closures: Iterable[ClosureEdge]) -> None:
        """Remember the pose pairs of closures pairwise consistency judged and kept
        (:mod:`.pcm`, closures judged once), and forget those of closures the store no
        longer holds, so that the set stays within the closure store's size."""
        held = {c.pair for c in self.closures}
        self._judged_pairs = {p for p in self._judged_pairs if p in held}
        self._judged_pairs.update(c.pair for c in closures if c.pair in held)

    @property
    def judged_pairs(self) -> frozenset[frozenset[int]]:
        """Pose pairs of the closures pairwise consistency judged and kept
        (:meth:`keep_judged`)."""
        return frozenset(self._judged_pairs)

    def add_peer_closures(self, closures: Iterable[ClosureEdge]) -> tuple[int, int, int]:
        """Closures another robot found, as they arrive with its poses
        (:mod:`.peerclosures`): each is stored if the store holds both its poses and no
        closure already joins them, in either direction, so that a closure received
        twice, found here too or sent back is one factor. A pair pairwise consistency
        rejected here (:meth:`reject_closures`) is refused too. Time stamps and
        reliabilities do not change (a peer's closure carries no landmark matches).

        Returns
        -------
        (added, duplicates, unheld) : tuple of int
            Closures stored; refused as joining a pair already joined or rejected;
            refused as naming a pose the store does not hold.
        """
        held = set(self.local.poses).union(*(ly.poses for ly in self.received.values()))
        joined = {c.pair for c in self.closures} | self._rejected_pairs
        added = duplicates = unheld = 0
        for c in closures:
            pair = c.pair
            if c.a == c.b or not pair <= held:
                unheld += 1
            elif pair in joined:
                duplicates += 1
            else:
                self.closures.append(c)
                joined.add(pair)
                added += 1
        if added:
            self._note_peak()
        return added, duplicates, unheld

    def remove_received_pose(self, source: int, uid: int) -> Pose:
        """Remove a pose of received layer ``source`` (the exchange: its source no longer
        has it) with the odometry edges and the closures touching it. The patch keeps its
        stamp and full id list; the short list loses the UID.

        Raises
        ------
        InputError
            If the layer or the pose is not stored.
        """
        layer = self.received.get(source)
        if source == self.robot or layer is None or uid not in layer.poses:
            raise InputError(
                f"pose {uid} is not in received layer {source} of robot {self.robot}", field="uid"
            )
        pose = layer.remove_pose(uid)
        self.closures = [c for c in self.closures if uid not in (c.a, c.b)]
        return pose

    # time stamps and reliabilities

    def _update_stamps(self, closures: Sequence[ClosureEdge]) -> None:
        """Every landmark in a matched pair, in every layer holding its pose, takes the
        largest stamp among the landmarks matched to it, directly or through others
        (max, not sum: no double counting)."""
        parent: dict[tuple[int, int], tuple[int, int]] = {}

        def find(k: tuple[int, int]) -> tuple[int, int]:
            while parent.setdefault(k, k) != k:
                parent[k] = parent[parent[k]]
                k = parent[k]
            return k

        for c in closures:
            ha, hb = self._holders(c.a), self._holders(c.b)
            if not ha or not hb:
                continue
            ia, ib = _unique_pairs(
                c.matches, len(ha[0].poses[c.a].landmarks), len(hb[0].poses[c.b].landmarks)
            )
            for i, j in zip(ia.tolist(), ib.tolist(), strict=True):
                parent[find((c.a, i))] = find((c.b, j))
        groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
        for k in list(parent):
            groups.setdefault(find(k), []).append(k)
        updates: dict[int, dict[int, float]] = {}
        for members in groups.values():
            top = max(
                float(layer.poses[uid].landmarks.stamp[i])
                for uid, i in members
                for layer in self._holders(uid)
            )
            for uid, i in members:
                updates.setdefault(uid, {})[i] = top
        for uid, new in updates.items():
            idx = np.fromiter(new, dtype=np.intp, count=len(new))
            val = np.fromiter(new.values(), dtype=np.float64, count=len(new))
            for layer in self._holders(uid):
                p = layer.poses[uid]
                if np.array_equal(p.landmarks.stamp[idx], val):
                    continue
                stamp = p.landmarks.stamp.copy()
                stamp[idx] = val
                layer.poses[uid] = p.with_landmarks(replace(p.landmarks, stamp=stamp))

    def _update_reliability(self, c: ClosureEdge, new_uid: int) -> None:
        """Reliabilities after a closure between two of our own poses (thesis 2.3.1):
        matched pairs both become 1 - (1 - r1)(1 - r2); an unmatched landmark X of the
        old pose that the new pose's camera could have seen is divided by
        min(1 + beta d, L), d the new pose's landmark density at X."""
        poses = self.local.poses
        if robot_of(c.a) != self.robot or robot_of(c.b) != self.robot or c.a == c.b:
            return
        if c.a not in poses or c.b not in poses:
            return
        old, new, where = c.a, c.b, _tf(c.transform)
        pairs = [(i, j) for i, j in c.matches]
        if c.a == new_uid:
            old, new, where = c.b, c.a, _tf(invert(where))
            pairs = [(j, i) for i, j in pairs]
        lo, ln = poses[old].landmarks, poses[new].landmarks
        io, jn = _unique_pairs(pairs, len(lo), len(ln))
        r_old = lo.reliability.astype(np.float64)
        r_new = ln.reliability.astype(np.float64)
        both = _combine(r_old[io], r_new[jn])
        unmatched = np.ones(len(lo), dtype=bool)
        unmatched[io] = False
        cand = np.flatnonzero(unmatched)
        seen = _to_frame(lo.points[cand], _tf(invert(where)))
        visible = self._visible(seen)
        cand, seen = cand[visible], seen[visible]
        d = kernel_density(seen, ln.points, self.params.landmark_sigma)
        L = self.params.decay_cap
        beta = self.params.beta
        if beta is None:
            own = kernel_density(ln.points, ln.points, self.params.landmark_sigma)
            beta = (L - 1.0) / float(own.max()) if len(own) else 0.0
        r_old[cand] /= np.minimum(1.0 + beta * d, L)
        r_old[io] = both
        r_new[jn] = both
        for uid, lm, r in ((old, lo, r_old), (new, ln, r_new)):
            self.local.poses[uid] = poses[uid].with_landmarks(
                replace(lm, reliability=np.clip(r, 0.0, 1.0).astype(np.float32))
            )

    def _visible(self, points: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
        """Points (a pose's frame) within the camera's horizontal field of view (x
        forward) and range."""
        bearing = np.abs(np.arctan2(points[:, 1], points[:, 0]))
        near = np.linalg.norm(points, axis=1) <= self.params.camera_range
        return np.asarray((bearing <= math.radians(self.params.fov) / 2.0) & near)

    # closures and edges under compression

    @staticmethod
    def _index_map(n: int, kept: Index) -> Index:
        out = np.full(n, -1, dtype=np.intp)
        out[kept] = np.arange(len(kept))
        return out

    def _rewrite_closures(
        self, old: int, new: int, index: Index, where: Transform = (0.0, 0.0, 0.0)
    ) -> None:
        """Closures touching pose ``old`` moved to ``new`` (old's frame at ``where`` in
        it, old's landmark i at new's index[i]); pairs whose landmark went are dropped,
        and so are closures that now join a pose to itself."""
        out: list[ClosureEdge] = []
        for c in self.closures:
            if old not in (c.a, c.b):
                out.append(c)
                continue
            a, b, tf, cov = _reframe(c.a, c.b, _tf(c.transform), c.cov(), old, new, where)
            if a == b:
                continue

            def moved(k: int, side: int) -> int:
                if side != old:
                    return k
                return int(index[k]) if 0 <= k < len(index) else -1

            pairs = ((moved(i, c.a), moved(j, c.b)) for i, j in c.matches)
            matches = tuple((i, j) for i, j in pairs if i >= 0 and j >= 0)
            cov_t = _cov_tuple(cov)
            out.append(replace(c, a=a, b=b, transform=tf, covariance=cov_t, matches=matches))
        self.closures = out

    # region compression

    def delete_pose(self, uid: int, now: float) -> set[int]:
        """Delete a local pose (region compression). Its odometry neighbours, ordered by
        time, are chained by edges composed through it, so the graph stays connected,
        and the patches of their ends are stamped ``now`` (they changed); its closures
        go. Returns the regions whose edges changed."""
        layer = self.local
        links: dict[int, tuple[Transform, F64, float, float]] = {}
        for e in layer.edges_of(uid):
            other = e.b if e.a == uid else e.a
            if other in links or other not in layer.poses:
                continue
            tf, cov = _tf(e.transform), e.cov()
            if e.b == uid:
                tf, cov = _tf(invert(tf)), invert_covariance(tf, cov)
            links[other] = (tf, cov, e.max_distance, e.max_turn)
        layer.remove_pose(uid, now)
        if uid == self._newest:
            self._newest = None
        self._carry_closures(uid, links)
        order = sorted(links, key=lambda n: (layer.poses[n].time, n))
        touched: set[int] = set()
        for n1, n2 in itertools.pairwise(order):
            t1, c1, d1, a1 = links[n1]
            t2, c2, d2, a2 = links[n2]
            back = _tf(invert(t1))
            cov = compose_covariance(back, invert_covariance(t1, c1), t2, c2)
            layer.add_edge(
                OdometryEdge(
                    n1, n2, _tf(compose(back, t2)), _cov_tuple(cov), d1 + d2, min(math.pi, a1 + a2)
                )
            )
            # The patches of both ends changed (a new edge): their new stamps tell the
            # holders to ask again, and the edge reaches them with the answer.
            for n in (n1, n2):
                layer.patch(layer.poses[n].region).stamp = now
            touched.add(layer.poses[n2].region)
        return touched

    def _carry_closures(
        self, uid: int, links: Mapping[int, tuple[Transform, F64, float, float]]
    ) -> None:
        """The closures of deleted pose ``uid`` carried to its odometry neighbour of
        least uncertain link (``links``: neighbour to (transform of the neighbour in
        uid's frame, its covariance, ...)), composed through that link; a carried
        closure keeps no landmark matches and counts 0 inliers (it pairs no landmarks
        of its new end, so it never drives a merge), and one joining a pair a carried
        closure already joins is fused with it (:func:`_fuse_closures`). Without a
        neighbour, or when the carried closure would join a pose to itself, it goes.

        Region compression deletes most poses of a route that stays in a few regions;
        dropping their closures left the graph only the odometry chained through them,
        which undid every correction association had made."""
        mine = [c for c in self.closures if uid in (c.a, c.b)]
        if not mine:
            return
        self.closures = [c for c in self.closures if uid not in (c.a, c.b)]
        if not links:
            return
        heir = min(links, key=lambda n: (float(np.trace(links[n][1])), n))
        link_tf, link_cov = links[heir][0], links[heir][1]
        for c in mine:
            tf, cov, other = _tf(c.transform), c.cov(), c.a
            if c.a == uid:
                tf, cov, other = _tf(invert(tf)), invert_covariance(tf, cov), c.b
            if other == heir:
                continue
            carried = ClosureEdge(
                other,
                heir,
                _tf(compose(tf, link_tf)),
                _cov_tuple(compose_covariance(tf, cov, link_tf, link_cov)),
                0,
                c.error,
            )
            self._add_carried(carried)

    def _add_carried(self, c: ClosureEdge) -> None:
        """Store a carried closure, fused with a carried one between the same poses."""
        for i, d in enumerate(self.closures):
            if d.inliers == 0 and {d.a, d.b} == {c.a, c.b}:
                self.closures[i] = _fuse_closures(d, c)
                return
        self.closures.append(c)

    def fold_target(self, uid: int) -> tuple[int, Transform] | None:
        """The pose whose local map takes deleted pose ``uid``'s (``StoreParams.fold``)
        and where ``uid``'s frame lies in its frame: of ``uid``'s odometry neighbours in
        the local layer that no other robot holds (:meth:`share`), the nearest by the
        edge between them, if within half the width of ``uid``'s local map (ties: the
        lower UID). None if there is none, or ``uid`` has no map.

        The edge, not the two estimates, places the map: odometry over a metre or two
        is off by centimetres, while the estimates of an older and a newer pose can
        disagree by the whole correction of the last closures until the next batch
        moves the older one (folding by the estimates into the nearest pose of the
        region cost the depot's map, measured in docs/results)."""
        layer = self.local
        gone = layer.poses[uid]
        if gone.local_map is None:
            return None
        reach = gone.local_map.size * gone.local_map.resolution / 2.0
        best: tuple[float, int, Transform] | None = None
        for e in layer.edges_of(uid):
            other = e.b if e.a == uid else e.a
            if other == uid or other not in layer.poses or other in self._shared:
                continue
            # Where uid's frame lies in other's frame.
            where = _tf(invert(e.transform)) if e.a == uid else _tf(e.transform)
            d = math.hypot(where[0], where[1])
            if d <= reach and (best is None or (d, other) < best[:2]):
                best = (d, other, where)
        return None if best is None else (best[1], best[2])

    def _fold(self, uid: int, now: float) -> None:
        """Add local pose ``uid``'s map to its :meth:`fold_target`'s."""
        found = self.fold_target(uid)
        if found is None:
            return
        target, where = found
        layer = self.local
        gone, keep = layer.poses[uid], layer.poses[target]
        layer.put_pose(
            replace(keep, local_map=_merge_maps(keep.local_map, gone.local_map, where)), now
        )

    def merge_poses(self, closure: ClosureEdge, now: float) -> int:
        """Merge closure.a and closure.b into a new pose in a's frame (thesis 2.3.2);
        its UID is returned. Edges and closures follow; the merged pose is compressed
        if it exceeds the pose limit."""
        if closure.a == closure.b or not {closure.a, closure.b} <= set(self.local.poses):
            raise InputError(
                f"closure {closure.a} - {closure.b} does not join two local poses",
                field="closure",
            )
        p, q = self.local.poses[closure.a], self.local.poses[closure.b]
        uid = make_uid(self.robot, MERGE_COUNTER_BASE + self._merges)
        plan = _plan_merge(p, q, closure, uid, now, self.params)
        self._apply_merge(plan, now)
        return uid

    def _apply_merge(self, plan: _MergePlan, now: float) -> None:
        c, uid = plan.closure, plan.pose.uid
        self._merges += 1
        layer = self.local
        edges = layer.edges_of(c.a) + layer.edges_of(c.b)
        layer.remove_pose(c.a, now)
        layer.remove_pose(c.b, now)
        layer.put_pose(plan.pose, now)
        if self._newest in (c.a, c.b):
            self._newest = uid
        where = _tf(c.transform)
        for e in edges:
            a, b, tf, cov = _reframe(e.a, e.b, _tf(e.transform), e.cov(), c.a, uid, (0, 0, 0))
            a, b, tf, cov = _reframe(a, b, tf, cov, c.b, uid, where)
            if a != b:
                layer.add_edge(replace(e, a=a, b=b, transform=tf, covariance=_cov_tuple(cov)))
        self._rewrite_closures(c.a, uid, plan.p_index)
        self._rewrite_closures(c.b, uid, plan.q_index, where)

    def _mergeable(self, c: ClosureEdge, region: int, min_inliers: int | None = None) -> bool:
        poses = self.local.poses
        if c.a == c.b or c.a not in poses or c.b not in poses or self._newest in (c.a, c.b):
            return False
        if poses[c.a].region != region or poses[c.b].region != region:
            return False
        cov = c.cov()
        xy_std = math.sqrt(max(0.0, float(np.linalg.eigvalsh(cov[:2, :2]).max())))
        return (
            c.inliers >= (self.params.merge_min_inliers if min_inliers is None else min_inliers)
            and math.hypot(c.transform[0], c.transform[1]) < self.params.merge_radius
            and xy_std <= self.params.merge_max_std
            and math.sqrt(max(0.0, cov[2, 2])) <= self.params.merge_max_angle_std
        )

    def compress_region(self, region: int, now: float) -> None:
        """Thesis 2.3.2 region compression of the local layer: while the region exceeds
        :meth:`region_limit`, apply the deletion or merge of best efficiency
        E = M / (d sum U). Regions that gain an edge from a deletion are checked too."""
        todo = {region}
        while todo:
            r = min(todo)
            todo.discard(r)
            todo |= self._compress_one(r, now)

    def _compress_one(self, region: int, now: float) -> set[int]:
        layer = self.local
        touched = self._compress(
            lambda: layer.region_bytes(region) > self.region_limit(region), region, now
        )
        touched.discard(region)
        return touched

    def compress_store(self, now: float) -> None:
        """Compression of the whole local layer (``StoreParams.store_limit``): while the
        layer exceeds M_store, the region holding the most bytes loses the deletion or
        merge of best efficiency E = M / (d sum U) among its poses (one step of region
        compression). The regions' shares so even out: every region the robot visited
        keeps about M_store / (regions visited) bytes, instead of the oldest regions
        being forgotten whole. Nothing when ``store_limit`` is 0."""
        limit = self.params.store_limit
        if limit <= 0:
            return
        layer = self.local
        stuck: set[int] = set()
        while layer.bytes() > limit:
            sizes = {
                r: layer.region_bytes(r)
                for r, p in layer.patches.items()
                if p.short and r not in stuck
            }
            if not sizes:
                break
            region = max(sizes, key=lambda r: (sizes[r], -r))
            before = layer.bytes()
            touched = self._compress(lambda: True, region, now, steps=1)
            if layer.bytes() >= before:
                stuck.add(region)  # only the newest pose, or nothing it could free
            for r in sorted(touched - {region}):
                self.compress_region(r, now)

    def _compress(
        self,
        over: Callable[[], bool],
        region: int,
        now: float,
        *,
        steps: int | None = None,
    ) -> set[int]:
        """The greedy loop of region compression over the poses of ``region`` while
        ``over()``, at most ``steps`` deletions or merges (None: no limit); merges of
        two of its poses compete with deletions. Returns the regions whose edges
        changed."""
        layer, params = self.local, self.params
        lost: dict[int, float] = {}
        plans: dict[tuple[int, int], _MergePlan] = {}
        touched: set[int] = set()
        done = 0
        while over() and (steps is None or done < steps):
            done += 1
            uids = sorted(layer.patches[region].short)
            where = np.array([layer.poses[u].estimate[:2] for u in uids]).reshape(-1, 2)
            density = dict(zip(uids, kernel_density(where, where, params.pose_sigma), strict=True))
            best: tuple[float, int, int, _MergePlan | None] | None = None
            for u in uids:
                if u == self._newest:
                    continue
                if u not in lost:
                    lost[u] = float(utility(layer.poses[u].landmarks, now, params).sum())
                e = _efficiency(layer.pose_bytes(u), density[u], lost[u])
                # Ties: deletion before merging, then the oldest UID.
                if best is None or (e, 1, -u) > best[:3]:
                    best = (e, 1, -u, None)
            for key, c in self._merge_candidates(region).items():
                if key not in plans:
                    uid = make_uid(self.robot, MERGE_COUNTER_BASE + self._merges)
                    p, q = layer.poses[c.a], layer.poses[c.b]
                    plans[key] = _plan_merge(p, q, c, uid, now, params)
                plan = plans[key]
                if plan.freed <= 0:
                    continue
                e = _efficiency(plan.freed, density[c.a], plan.lost_utility)
                if best is None or (e, 0, -c.a) > best[:3]:
                    best = (e, 0, -c.a, plan)
            if best is None:
                break
            if best[3] is None:
                if params.fold:
                    self._fold(-best[2], now)
                touched |= self.delete_pose(-best[2], now)
            else:
                plans.clear()  # the UIDs planned ahead are now taken
                self._apply_merge(best[3], now)
        return touched

    def _merge_candidates(self, region: int) -> dict[tuple[int, int], ClosureEdge]:
        """The best mergeable closure (most inliers, then least error) of each pair."""
        out: dict[tuple[int, int], ClosureEdge] = {}
        for c in self.closures:
            if not self._mergeable(c, region):
                continue
            key = (min(c.a, c.b), max(c.a, c.b))
            have = out.get(key)
            if have is None or (c.inliers, -c.error) > (have.inliers, -have.error):
                out[key] = c
        return out


def compress_for_sending(
    layer: Layer,
    region: int | Collection[int],
    cap_bytes: int,
    now: float,
    *,
    params: StoreParams | None = None,
    uids: Collection[int] | None = None,
    size: Callable[[int], int] | None = None,
) -> list[int]:
    """The poses of ``region`` (one or several) to send within ``cap_bytes`` (poses'
    bytes; edges are not counted): deletion-only region compression, dropping the pose
    of best E = M / (d sum U) until the rest fits (a merge would make a UID the
    receiver does not know).

    Parameters
    ----------
    layer : Layer
    region : int or collection of int
    cap_bytes : int
        T, the reply's cap.
    now : float
        Mission time, for the landmarks' ages.
    params : StoreParams, optional
        Utility constants and pose kernel width.
    uids : collection of int, optional
        Only these poses are candidates (e.g. those the receiver lacks).
    size : callable, optional
        ``size(uid)``: a pose's bytes as it will travel; default its stored bytes.

    Returns
    -------
    list of int
        UIDs to send, by pose time then UID.
    """
    params = params if params is not None else StoreParams()
    regions = {region} if isinstance(region, int) else set(region)
    cand = sorted(
        u for u, p in layer.poses.items() if p.region in regions and (uids is None or u in uids)
    )
    bytes_of = layer.pose_bytes if size is None else size
    sizes = np.array([bytes_of(u) for u in cand], dtype=np.float64)
    lost = np.array([utility(layer.poses[u].landmarks, now, params).sum() for u in cand])
    keep = np.ones(len(cand), dtype=bool)
    while keep.any() and sizes[keep].sum() > cap_bytes:
        idx = np.flatnonzero(keep)
        where = np.array([layer.poses[cand[i]].estimate[:2] for i in idx])
        d = kernel_density(where, where, params.pose_sigma)
        e = [_efficiency(int(sizes[i]), float(d[k]), float(lost[i])) for k, i in enumerate(idx)]
        keep[idx[int(np.argmax(e))]] = False
    chosen = [cand[i] for i in np.flatnonzero(keep)]
    return sorted(chosen, key=lambda u: (layer.poses[u].time, u))
