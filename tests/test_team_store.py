"""The robot's long-term store: bounded memory, time stamps, reliabilities, pose and
region compression, merging, and the deletion-only choice of poses to send."""

from __future__ import annotations

import math
from dataclasses import replace

import gtsam
import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError, InputError
from sonarmap.team.records import (
    ClosureEdge,
    Landmarks,
    LocalMap,
    OdometryEdge,
    Pose,
    compose,
    invert,
    make_uid,
    robot_of,
    size_of,
)
from sonarmap.team.store import (
    MERGE_COUNTER_BASE,
    Layer,
    RobotStore,
    StoreParams,
    compress_for_sending,
    compress_pose,
    local_bound,
    region_limits,
)

F64 = npt.NDArray[np.float64]
COV = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-5)
BIG = StoreParams(pose_limit=10**7, region_limit=10**8, store_limit=0)


def make_landmarks(
    points: npt.ArrayLike,
    *,
    reliability: float | npt.ArrayLike = 0.5,
    stamp: float | npt.ArrayLike = 0.0,
    ids: npt.ArrayLike | None = None,
    seed: int = 0,
) -> Landmarks:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    rng = np.random.default_rng(seed)
    return Landmarks(
        pts.astype(np.float32),
        rng.integers(0, 256, (n, 128), dtype=np.uint8),
        np.broadcast_to(np.asarray(reliability, dtype=np.float32), (n,)).copy(),
        np.broadcast_to(np.asarray(stamp, dtype=np.float64), (n,)).copy(),
        np.arange(n) if ids is None else np.asarray(ids),
    )


def make_pose(
    robot: int,
    counter: int,
    landmarks: Landmarks,
    *,
    estimate: tuple[float, float, float] = (0.0, 0.0, 0.0),
    region: int = 0,
    time: float = 0.0,
    local_map: LocalMap | None = None,
) -> Pose:
    uid = make_uid(robot, counter)
    return Pose(uid, time, region, np.array(estimate), landmarks, local_map)


def closure(a: Pose, b: Pose, matches: list[tuple[int, int]]) -> ClosureEdge:
    """The true closure between two poses (from their estimates)."""
    tf = compose(invert(a.estimate), b.estimate)
    return ClosureEdge(a.uid, b.uid, (tf[0], tf[1], tf[2]), COV, len(matches), 0.01, tuple(matches))


def odometry(a: Pose, b: Pose) -> OdometryEdge:
    tf = compose(invert(a.estimate), b.estimate)
    return OdometryEdge(a.uid, b.uid, (tf[0], tf[1], tf[2]), COV, 10.0)


def world_xy(pose: Pose, points: npt.ArrayLike) -> F64:
    """Landmark points of a pose in the global frame (x, y)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x, y, t = pose.estimate
    c, s = math.cos(t), math.sin(t)
    return np.column_stack([x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1]])


# --- a small synthetic mission --------------------------------------------------------

CENTRE = np.array([15.0, 15.0])
STEPS_PER_LAP = 38


class Mission:
    """A robot circling the centre of a 30 m square of 2000 landmarks; a camera of 90
    degrees and 8 m; regions are the four quadrants around the centre; association is
    faked by the landmarks' true identities."""

    def __init__(self, params: StoreParams, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.points = np.column_stack([rng.uniform(0, 30, (2000, 2)), rng.uniform(0, 2, 2000)])
        self.desc = rng.integers(0, 256, (2000, 128), dtype=np.uint8)
        self.rng = rng
        self.store = RobotStore(0, params)
        self.last: Pose | None = None

    def truth(self, k: int) -> tuple[float, float, float]:
        lap, step = divmod(k, STEPS_PER_LAP)
        ang = 2 * math.pi * step / STEPS_PER_LAP
        r = 6.0 + 0.2 * (lap % 3 - 1)
        x, y = CENTRE + r * np.array([math.cos(ang), math.sin(ang)])
        return (float(x), float(y), math.remainder(ang + math.pi / 2, 2 * math.pi))

    def observe(self, k: int, now: float) -> Pose:
        x, y, t = self.truth(k)
        c, s = math.cos(t), math.sin(t)
        dx, dy = self.points[:, 0] - x, self.points[:, 1] - y
        local = np.column_stack([c * dx + s * dy, -s * dx + c * dy, self.points[:, 2]])
        seen = (np.abs(np.arctan2(local[:, 1], local[:, 0])) <= math.pi / 4) & (
            np.linalg.norm(local, axis=1) <= 8.0
        )
        idx = np.flatnonzero(seen)
        pts = local[idx] + self.rng.normal(0, 0.01, (len(idx), 3))
        lm = Landmarks(
            pts.astype(np.float32),
            self.desc[idx],
            np.full(len(idx), 0.5, dtype=np.float32),
            np.full(len(idx), now),
            idx.astype(np.int64),
        )
        region = int(x > CENTRE[0]) + 2 * int(y > CENTRE[1])
        grid = np.zeros((16, 16))
        grid[4:12, 8] = 2.0
        return Pose(
            make_uid(0, k), now, region, np.array([x, y, t]), lm, LocalMap.from_logodds(grid, 0.25)
        )

    def associate(self, new: Pose) -> list[ClosureEdge]:
        out = []
        for old in self.store.local.poses.values():
            if np.hypot(*(old.estimate[:2] - new.estimate[:2])) > 3.0:
                continue
            _, i, j = np.intersect1d(old.landmarks.ids, new.landmarks.ids, return_indices=True)
            if len(i) >= 6:
                out.append(closure(old, new, list(zip(i.tolist(), j.tolist(), strict=True))))
        return out

    def step(self, k: int) -> None:
        now = 10.0 * k
        pose = self.observe(k, now)
        edge = None if self.last is None else odometry(self.last, pose)
        self.store.add_own_pose(pose, edge, self.associate(pose), now)
        self.last = pose


def test_memory_stays_bounded_as_the_mission_grows() -> None:
    params = StoreParams(pose_limit=8000, region_limit=32000)
    bound = 4 * params.region_limit
    mission = Mission(params)
    store = mission.store
    peaks: dict[int, int] = {}
    merged = 0
    for k in range(400):
        mission.step(k)
        assert store.local.bytes() <= bound + params.pose_limit
        for region in range(4):
            assert store.local.region_bytes(region) <= params.region_limit
        assert max(store.local.pose_bytes(u) for u in store.local.poses) <= params.pose_limit
        merged = max(merged, sum(1 for p in store.local.poses.values() if p.merged_from))
        if k + 1 in (40, 160, 400):
            peaks[k + 1] = store.peak_local_bytes
    assert peaks[40] <= bound + params.pose_limit
    assert peaks[40] >= 0.6 * bound  # the regions were full from the first lap
    assert max(peaks.values()) <= 1.10 * peaks[40]
    assert merged > 0
    # The graph stays whole: no edge or closure points at a pose that is gone.
    uids = set(store.local.poses)
    assert all(e.a in uids and e.b in uids for e in store.local.edges)
    assert all(c.a in uids and c.b in uids for c in store.closures)
    assert len(store.local.edges) >= len(uids) - 1
    for c in store.closures:
        na, nb = len(store.local.poses[c.a].landmarks), len(store.local.poses[c.b].landmarks)
        assert all(0 <= i < na and 0 <= j < nb for i, j in c.matches)
        ia, jb = zip(*c.matches, strict=True) if c.matches else ((), ())
        ids_a = store.local.poses[c.a].landmarks.ids[list(ia)]
        ids_b = store.local.poses[c.b].landmarks.ids[list(jb)]
        assert np.array_equal(ids_a, ids_b)  # matches still name the same landmarks


@pytest.mark.parametrize("store_limit", [0, 70_000])
def test_the_store_limit_holds_the_layer_below_the_regions_bound(store_limit: int) -> None:
    # Four regions of 32 kB would hold 128 kB; a 70 kB store budget must hold the layer
    # there from the first lap on, every visited region keeping a share; 0 lets it fill.
    params = StoreParams(pose_limit=8000, region_limit=32000, store_limit=store_limit)
    bound = local_bound(params, 4)
    mission = Mission(params)
    store = mission.store
    peaks = []
    for k in range(160):
        mission.step(k)
        assert store.local.bytes() <= bound
        if store_limit:
            assert store.local.bytes() <= store_limit
        if k + 1 in (40, 160):
            peaks.append(store.peak_local_bytes)
    assert max(peaks) <= bound
    if store_limit:
        assert bound < 4 * params.region_limit  # the budget, not the regions, binds
        assert peaks[-1] <= 1.05 * peaks[0]
        regions = {p.region for p in store.local.poses.values()}
        assert regions == {0, 1, 2, 3}  # no region forgotten whole
        shares = [store.local.region_bytes(r) for r in range(4)]
        assert max(shares) <= 2.5 * min(shares)
    else:
        assert peaks[-1] > 100_000  # without the budget the regions fill to 4 x 32 kB
    uids = set(store.local.poses)
    assert all(e.a in uids and e.b in uids for e in store.local.edges)
    assert all(c.a in uids and c.b in uids for c in store.closures)


def test_local_bound_is_the_smaller_of_the_regions_and_the_budget() -> None:
    p = StoreParams(pose_limit=10_000, region_limit=50_000, store_limit=120_000)
    slack = local_bound(p, 1) - 50_000 - 10_000
    assert 0 < slack < 300  # the new pose's odometry edge
    assert local_bound(p, 2) == 100_000 + 10_000 + slack
    assert local_bound(p, 10) == 120_000 + 10_000 + slack
    assert local_bound(replace(p, store_limit=0), 10) == 500_000 + 10_000 + slack


# --- pose compression -----------------------------------------------------------------


def test_compression_drops_old_unreliable_landmarks_first() -> None:
    n = 12
    pts = np.column_stack([np.arange(n) * 5.0, np.zeros(n), np.ones(n)])  # isolated
    now = 1000.0
    rel = np.full(n, 0.5)
    stamp = np.full(n, now - 300.0)
    rel[3], stamp[3] = 0.1, now - 500.0
    rel[7], stamp[7] = 0.9, now - 1.0
    pose = make_pose(0, 0, make_landmarks(pts, reliability=rel, stamp=stamp))
    limit = size_of(pose.with_landmarks(pose.landmarks.take(np.arange(n - 2))))
    out, kept = compress_pose(pose, limit, now, BIG)
    assert size_of(out) <= limit
    assert len(kept) == n - 2  # exactly as many as needed
    assert 3 not in kept
    assert 7 in kept


def test_compression_prefers_landmarks_in_dense_clusters() -> None:
    cluster = np.column_stack([np.linspace(0, 0.2, 6), np.zeros(6), np.ones(6)])
    lone = np.array([[5.0, 0.0, 1.0]])
    pose = make_pose(0, 0, make_landmarks(np.vstack([cluster, lone]), stamp=10.0))
    limit = size_of(pose.with_landmarks(pose.landmarks.take(np.arange(6))))
    _, kept = compress_pose(pose, limit, 10.0, BIG)
    assert 6 in kept
    assert len(kept) == 6


def test_batched_compression_never_drops_more_than_needed() -> None:
    rng = np.random.default_rng(3)
    n = 600
    lm = make_landmarks(
        rng.uniform(-5, 5, (n, 3)), reliability=rng.uniform(0, 1, n), stamp=rng.uniform(0, 900, n)
    )
    pose = make_pose(0, 0, lm)
    for limit in (5000, 33_333, 70_001):
        out, kept = compress_pose(pose, limit, 1000.0, BIG)
        assert size_of(out) <= limit
        one_more = pose.with_landmarks(lm.take(np.arange(len(kept) + 1)))
        assert size_of(one_more) > limit
        assert np.array_equal(out.landmarks.ids, lm.ids[kept])


def test_a_pose_whose_map_alone_exceeds_the_limit_is_a_config_error() -> None:
    big_map = LocalMap.from_logodds(np.ones((100, 100)), 0.1)
    pose = make_pose(0, 0, make_landmarks(np.zeros((3, 3))), local_map=big_map)
    with pytest.raises(ConfigError, match="pose_limit"):
        compress_pose(pose, 2000, 0.0, BIG)


# --- reliabilities and time stamps ----------------------------------------------------


def reliability_scene(
    params: StoreParams,
) -> tuple[RobotStore, Pose, Pose, ClosureEdge]:
    """Own pose A at the origin and B 0.5 m ahead; ten landmarks matched. A's unmatched
    landmarks: 10 in B's view among B's landmarks, 11 behind B, 12 far beyond range, 13
    just outside B's field of view and 14 just beyond its range, both within a kernel
    width of B's landmarks (so only the visibility test keeps them unchanged)."""
    ys = np.linspace(-1, 1, 10)
    shared = np.column_stack([np.full(10, 4.0), ys, np.ones(10)])
    extra_a = [[4.0, 0.05, 1.0], [-3.0, 0.0, 1.0], [20.0, 0.0, 1.0], [2.5, 2.3, 1.0]]
    a_pts = np.vstack([shared, extra_a, [[8.8, 0.0, 1.0]]])
    b_pts = np.vstack([shared - [0.5, 0.0, 0.0], [[2.0, 1.9, 1.0], [7.8, 0.0, 1.0]]])
    a = make_pose(0, 0, make_landmarks(a_pts, stamp=0.0))
    b = make_pose(0, 1, make_landmarks(b_pts, stamp=10.0), estimate=(0.5, 0.0, 0.0), time=10.0)
    store = RobotStore(0, params)
    store.add_own_pose(a, None, [], now=0.0)
    c = closure(a, b, [(i, i) for i in range(10)])
    return store, a, b, c


def test_reliability_rises_for_matches_and_falls_for_visible_unmatched() -> None:
    store, a, b, c = reliability_scene(BIG)
    store.add_own_pose(b, odometry(a, b), [c], now=10.0)
    ra = store.local.poses[a.uid].landmarks.reliability
    rb = store.local.poses[b.uid].landmarks.reliability
    np.testing.assert_allclose(ra[:10], 0.75, rtol=1e-6)  # 1 - 0.5 * 0.5
    np.testing.assert_allclose(rb[:10], 0.75, rtol=1e-6)
    np.testing.assert_array_equal(rb[10:], 0.5)
    assert 0.5 / BIG.decay_cap <= ra[10] < 0.5
    np.testing.assert_array_equal(ra[11:], 0.5)  # out of the camera's view or range


def test_reliability_decay_is_capped_by_decay_cap() -> None:
    params = replace(BIG, beta=1000.0, decay_cap=3.0)
    store, a, b, c = reliability_scene(params)
    store.add_own_pose(b, odometry(a, b), [c], now=10.0)
    r = store.local.poses[a.uid].landmarks.reliability[10]
    assert r == pytest.approx(0.5 / 3.0, rel=1e-6)


def test_closures_with_received_poses_change_no_reliability() -> None:
    store, _a, b, c = reliability_scene(BIG)
    other = replace(b, uid=make_uid(1, 0))
    store.add_received_pose(1, other, [], [replace(c, b=other.uid)], now=10.0)
    b2 = replace(b, uid=make_uid(0, 2))
    back = closure(other, b2, [(i, i) for i in range(10)])
    store.add_own_pose(b2, None, [back], now=20.0)
    for layer in (store.local, store.received[1]):
        for p in layer.poses.values():
            assert np.all(p.landmarks.reliability == np.float32(0.5))


def test_removing_a_received_pose_takes_its_edges_and_closures() -> None:
    store = RobotStore(0, BIG)
    mine = make_pose(0, 0, make_landmarks(np.zeros((3, 3))))
    store.add_own_pose(mine, None, [], now=0.0)
    p, q, r = (
        make_pose(1, k, make_landmarks(np.zeros((3, 3))), estimate=(k, 0, 0)) for k in range(3)
    )
    store.add_received_pose(1, p, [], [], now=1.0)
    store.add_received_pose(1, q, [odometry(p, q)], [closure(mine, q, [])], now=1.0)
    store.add_received_pose(1, r, [odometry(q, r)], [closure(mine, r, [])], now=1.0)
    layer = store.received[1]
    layer.patches[0].stamp, layer.patches[0].full = 5.0, {p.uid, q.uid, r.uid}
    assert store.remove_received_pose(1, q.uid) is q
    assert set(layer.poses) == {p.uid, r.uid}
    assert layer.edges == []
    assert [(c.a, c.b) for c in store.closures] == [(mine.uid, r.uid)]
    assert layer.patches[0].short == {p.uid, r.uid}
    assert layer.patches[0].full == {p.uid, q.uid, r.uid}  # what the source had at 5.0
    assert layer.patches[0].stamp == 5.0
    assert set(store.local.poses) == {mine.uid}
    with pytest.raises(InputError, match=r"pose \d+ is not in received layer 1"):
        store.remove_received_pose(1, q.uid)
    with pytest.raises(InputError, match="not in received layer 0"):
        store.remove_received_pose(0, mine.uid)  # never the local layer


def test_time_stamps_take_the_max_in_every_layer() -> None:
    pts = np.column_stack([np.arange(5.0), np.zeros(5), np.ones(5)])
    a = make_pose(0, 0, make_landmarks(pts, stamp=10.0))
    r = make_pose(1, 0, make_landmarks(pts, stamp=30.0))
    store = RobotStore(0, BIG)
    store.add_own_pose(a, None, [], now=10.0)
    store.add_received_pose(1, r, [], [closure(a, r, [(0, 0), (1, 1), (2, 2)])], now=40.0)
    np.testing.assert_array_equal(store.local.poses[a.uid].landmarks.stamp, [30, 30, 30, 10, 10])
    np.testing.assert_array_equal(store.received[1].poses[r.uid].landmarks.stamp, 30.0)
    b = make_pose(0, 1, make_landmarks(pts, stamp=100.0), time=100.0)
    store.add_own_pose(b, odometry(a, b), [closure(r, b, [(1, 3), (4, 4)])], now=100.0)
    got = store.received[1].poses[r.uid].landmarks.stamp
    np.testing.assert_array_equal(got, [30, 100, 30, 30, 100])  # max, not 130
    np.testing.assert_array_equal(store.local.poses[b.uid].landmarks.stamp, 100.0)
    np.testing.assert_array_equal(r.landmarks.stamp, 30.0)  # the sender's copy untouched


# --- region compression: deleting and merging -----------------------------------------


def merge_scene(params: StoreParams) -> tuple[RobotStore, Pose, Pose, Pose, ClosureEdge]:
    """P and Q 0.41 m apart sharing 25 of their 30 landmarks; X further on; edges
    P -> Q -> X and closures P-Q and Q-X."""
    rng = np.random.default_rng(5)
    world = np.column_stack([rng.uniform(5, 9, (35, 2)), rng.uniform(0, 2, 35)])
    grid = np.zeros((64, 64))
    p_est = (2.0, 3.0, 0.3)
    q_est = tuple(compose(p_est, (0.4, 0.1, 0.2)))
    x_est = tuple(compose(q_est, (1.5, 0.0, 0.0)))

    def seen_from(est: tuple[float, ...], ids: npt.NDArray[np.int64], counter: int) -> Pose:
        x, y, t = est
        c, s = math.cos(t), math.sin(t)
        d = world[ids, :2] - [x, y]
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
        lm = make_landmarks(
            np.column_stack([local, world[ids, 2]]), stamp=float(counter), ids=ids, seed=counter
        )
        m = grid.copy()
        m[20 + counter, 40] = 3.0  # one wall cell, different in each map
        return make_pose(
            0,
            counter,
            lm,
            estimate=(est[0], est[1], est[2]),
            time=float(counter),
            local_map=LocalMap.from_logodds(m, 0.1),
        )

    p = seen_from(p_est, np.arange(0, 30), 0)
    q = seen_from(q_est, np.arange(5, 35), 1)
    x = seen_from(x_est, np.arange(10, 35), 2)
    pq = closure(p, q, [(i + 5, i) for i in range(25)])
    qx = closure(q, x, [(i + 5, i) for i in range(25)])
    store = RobotStore(0, params)
    store.add_own_pose(p, None, [], now=0.0)
    store.add_own_pose(q, odometry(p, q), [pq], now=1.0)
    store.add_own_pose(x, odometry(q, x), [qx], now=2.0)
    return store, p, q, x, pq


def test_merging_makes_a_new_uid_keeps_landmarks_and_rewires() -> None:
    store, p, q, x, pq = merge_scene(BIG)
    before = {u: pp.landmarks for u, pp in store.local.poses.items()}
    uid = store.merge_poses(pq, now=3.0)
    assert uid not in (p.uid, q.uid, x.uid)
    assert robot_of(uid) == 0
    assert uid >= make_uid(0, MERGE_COUNTER_BASE)
    assert set(store.local.poses) == {uid, x.uid}
    m = store.local.poses[uid]
    assert m.merged_from == (p.uid, q.uid)
    assert len(m.landmarks) == 35  # 30 of P + 5 more of Q, the 25 shared merged
    # Every landmark keeps its place in the world.
    got = dict(zip(m.landmarks.ids.tolist(), world_xy(m, m.landmarks.points), strict=True))
    for pose in (p, q):
        want = world_xy(pose, pose.landmarks.points)
        for i, w in zip(pose.landmarks.ids.tolist(), want, strict=True):
            np.testing.assert_allclose(got[i], w, atol=2e-3)  # shared ones are averaged
    shared = np.isin(m.landmarks.ids, np.arange(5, 30))
    r_p, r_q = before[p.uid].reliability[5:30], before[q.uid].reliability[:25]
    want_r = 1 - (1 - r_p.astype(float)) * (1 - r_q)
    np.testing.assert_allclose(m.landmarks.reliability[shared], want_r, rtol=1e-6)
    want_t = np.maximum(before[p.uid].stamp[5:30], before[q.uid].stamp[:25])
    np.testing.assert_array_equal(m.landmarks.stamp[shared], want_t)
    # Both wall cells: P's where it was, Q's moved into P's frame.
    assert m.local_map is not None
    assert m.local_map.logodds[20, 40] > 0
    qx, qy = 40 * 0.1 - 3.15, 3.15 - 21 * 0.1  # Q's cell (21, 40) in Q's frame
    px, py, _ = compose((0.4, 0.1, 0.2), (qx, qy, 0.0))
    row, col = round(31.5 - py / 0.1), round(px / 0.1 + 31.5)
    assert m.local_map.logodds[row - 1 : row + 2, col - 1 : col + 2].max() > 0
    assert np.count_nonzero(m.local_map.logodds) == 2
    # The edge Q -> X now leaves the merged pose and still puts X where it is.
    (edge,) = store.local.edges
    assert (edge.a, edge.b) == (uid, x.uid)
    np.testing.assert_allclose(compose(m.estimate, edge.transform), x.estimate, atol=1e-9)
    (clo,) = store.closures  # P-Q consumed; Q-X rewritten
    assert (clo.a, clo.b) == (uid, x.uid)
    np.testing.assert_allclose(compose(m.estimate, clo.transform), x.estimate, atol=1e-9)
    i, j = np.array(clo.matches).T
    np.testing.assert_array_equal(m.landmarks.ids[i], x.landmarks.ids[j])


def test_region_compression_merges_a_close_well_matched_pair() -> None:
    store, p, q, x, _ = merge_scene(BIG)
    limit = store.local.region_bytes(0) - 1
    store2, *_ = merge_scene(StoreParams(pose_limit=12_000, region_limit=limit))
    assert store2.local.region_bytes(0) <= limit
    assert x.uid in store2.local.poses  # the newest pose is kept
    merged = [pp for pp in store2.local.poses.values() if pp.merged_from]
    assert [pp.merged_from for pp in merged] == [(p.uid, q.uid)]


@pytest.mark.parametrize(("need", "merges"), [(0, False), (25, True), (26, False)])
def test_merge_on_closure_merges_a_reliable_pair_at_once(need: int, merges: bool) -> None:
    # The region is far under its limit, so only the eager rule can merge: P-Q has 25
    # inliers; Q-X joins the newest pose, which stays until the next one comes.
    store, p, q, x, _ = merge_scene(replace(BIG, merge_on_closure=need))
    merged = [pp for pp in store.local.poses.values() if pp.merged_from]
    if not merges:
        assert merged == []
        assert set(store.local.poses) == {p.uid, q.uid, x.uid}
        assert store.merge_reliable(3.0) == []  # asked directly, still by the option
        return
    (m,) = merged
    assert m.merged_from == (p.uid, q.uid)
    assert set(store.local.poses) == {m.uid, x.uid}
    # The loop is in the layer now: the edge Q -> X runs from the merged pose.
    (edge,) = store.local.edges
    assert (edge.a, edge.b) == (m.uid, x.uid)
    np.testing.assert_allclose(compose(m.estimate, edge.transform), x.estimate, atol=1e-9)
    assert store.merge_reliable(3.0) == []  # nothing left to merge


def test_merge_on_closure_leaves_the_newest_pose_until_the_next() -> None:
    # X is 1.9 m from the merged pose's frame: a wider radius lets them merge.
    store, _p, _q, x, _ = merge_scene(replace(BIG, merge_on_closure=25, merge_radius=3.0))
    (m,) = [pp for pp in store.local.poses.values() if pp.merged_from]
    assert x.uid in store.local.poses
    y = make_pose(
        0,
        3,
        make_landmarks(np.zeros((3, 3)), seed=3),
        estimate=tuple(compose(x.estimate, (1.0, 0.0, 0.0))),
        time=3.0,
    )
    store.add_own_pose(y, odometry(x, y), [], now=3.0)
    # X is no longer the newest, so its closure with the merged pose merges them.
    assert x.uid not in store.local.poses
    (m2,) = [pp for pp in store.local.poses.values() if pp.merged_from and pp.uid != m.uid]
    assert m2.merged_from == (m.uid, x.uid)
    assert set(store.local.poses) == {m2.uid, y.uid}


def test_deleting_a_pose_chains_its_neighbours() -> None:
    store, p, q, x, _ = merge_scene(BIG)
    store.delete_pose(q.uid, now=3.0)
    (edge,) = store.local.edges
    assert (edge.a, edge.b) == (p.uid, x.uid)
    np.testing.assert_allclose(compose(p.estimate, edge.transform), x.estimate, atol=1e-9)
    assert edge.max_distance == 20.0
    cov = edge.cov()
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert cov[0, 0] > COV[0]
    # Q's closures go to X (its link of least uncertainty): P-Q becomes P-X, through
    # the edge Q -> X; Q-X would join X to itself and goes.
    (c,) = store.closures
    assert (c.a, c.b) == (p.uid, x.uid)
    np.testing.assert_allclose(compose(p.estimate, c.transform), x.estimate, atol=1e-9)
    assert c.inliers == 0
    assert c.matches == ()
    assert np.linalg.eigvalsh(c.cov()).min() > 0
    assert c.cov()[0, 0] > closure(p, q, [(5, 0)]).cov()[0, 0]


def test_carried_closures_between_one_pair_fuse_into_one() -> None:
    # Deleting Q, then a pose made after X whose closure to P lands on X too: two
    # closures P-X fuse into one, less uncertain than either, between both transforms.
    store, p, q, x, _ = merge_scene(BIG)
    store.delete_pose(q.uid, now=3.0)
    (first,) = store.closures
    y_est = tuple(compose(x.estimate, (0.5, 0.0, 0.0)))
    y = make_pose(0, 3, make_landmarks(np.zeros((3, 3)), seed=3), estimate=y_est, time=3.0)
    z = make_pose(0, 4, make_landmarks(np.zeros((3, 3)), seed=4), estimate=y_est, time=4.0)
    store.add_own_pose(y, odometry(x, y), [closure(p, y, [(0, 0)])], now=3.0)
    loose = replace(odometry(y, z), covariance=tuple(100.0 * v for v in COV))
    store.add_own_pose(z, loose, [], now=4.0)
    store.delete_pose(y.uid, now=5.0)
    carried = [c for c in store.closures if {c.a, c.b} == {p.uid, x.uid}]
    assert len(carried) == 1
    (fused,) = carried
    assert fused.inliers == 0
    assert np.trace(fused.cov()) < np.trace(first.cov())
    np.testing.assert_allclose(compose(p.estimate, fused.transform), x.estimate, atol=1e-6)


# --- choosing what to send ------------------------------------------------------------


def test_compress_for_sending_fits_the_cap_and_makes_no_uid() -> None:
    rng = np.random.default_rng(9)
    layer = Layer(2)
    for k in range(15):
        lm = make_landmarks(
            rng.uniform(-4, 4, (int(rng.integers(10, 60)), 3)),
            reliability=rng.uniform(0, 1),
            stamp=rng.uniform(0, 1000),
            seed=k,
        )
        est = (float(rng.uniform(0, 10)), float(rng.uniform(0, 10)), 0.0)
        layer.put_pose(make_pose(2, k, lm, estimate=est, region=int(k >= 12), time=k))
    region0 = {u for u, p in layer.poses.items() if p.region == 0}
    total = sum(layer.pose_bytes(u) for u in region0)
    for cap in (0, 100, 5000, 20_000, total - 1, total):
        sent = compress_for_sending(layer, 0, cap, 1000.0)
        assert set(sent) <= region0
        assert sum(layer.pose_bytes(u) for u in sent) <= cap
    assert set(compress_for_sending(layer, 0, total, 1000.0)) == region0
    assert compress_for_sending(layer, 0, 100, 1000.0) == []
    both = compress_for_sending(layer, [0, 1], 10**9, 1000.0)
    assert set(both) == set(layer.poses)
    only = compress_for_sending(layer, 0, 10**9, 1000.0, uids=[make_uid(2, 1), make_uid(2, 14)])
    assert only == [make_uid(2, 1)]


def test_compress_for_sending_keeps_the_fresh_reliable_pose() -> None:
    pts = np.column_stack([np.arange(20.0), np.zeros(20), np.ones(20)])
    layer = Layer(1)
    stale = make_pose(1, 0, make_landmarks(pts, reliability=0.1, stamp=0.0))
    fresh = make_pose(1, 1, make_landmarks(pts, reliability=0.9, stamp=990.0))
    layer.put_pose(stale)
    layer.put_pose(fresh)
    cap = max(layer.pose_bytes(stale.uid), layer.pose_bytes(fresh.uid))
    assert compress_for_sending(layer, 0, cap, 1000.0) == [fresh.uid]


# --- configuration --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"pose_limit": 200}, "pose_limit"),
        ({"pose_limit": 20_000, "region_limit": 10_000}, "region_limit"),
        ({"landmark_sigma": -1.0}, "landmark_sigma"),
        ({"decay_cap": 0.5}, "decay_cap"),
        ({"fov": 400.0}, "fov"),
        ({"merge_min_inliers": 2.5}, "merge_min_inliers"),
        ({"s": math.nan}, "s"),
        ({"fold": 1}, "fold"),
        ({"merge_on_closure": -1}, "merge_on_closure"),
        ({"merge_on_closure": 8.5}, "merge_on_closure"),
        ({"store_limit": 10_000}, "store_limit"),
        ({"store_limit": -1}, "store_limit"),
        ({"store_limit": 1.5e6}, "store_limit"),
    ],
)
def test_bad_params_name_the_field(kwargs: dict[str, float], name: str) -> None:
    with pytest.raises(ConfigError, match=rf"\b{name}\b"):
        StoreParams(**kwargs)  # type: ignore[arg-type]


def _log_right(t: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Right-perturbation error of samples ``t`` (N, 3) around ``mean``, through gtsam."""
    m = gtsam.Pose2(*mean)
    return np.array([gtsam.Pose2.Logmap(m.between(gtsam.Pose2(*row))) for row in t])


def _sample_right(
    mean: tuple[float, float, float], cov: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    m = gtsam.Pose2(*mean)
    xi = rng.multivariate_normal(np.zeros(3), cov, size=n)
    out = [m.compose(gtsam.Pose2.Expmap(v)) for v in xi]
    return np.array([[p.x(), p.y(), p.theta()] for p in out])


def test_covariances_propagate_in_the_end_frame_as_gtsam_takes_them() -> None:
    from sonarmap.team.records import compose_covariance as _compose_cov
    from sonarmap.team.records import invert_covariance as _invert_cov

    rng = np.random.default_rng(5)
    a, b = (1.0, 2.0, 0.7), (3.0, -1.0, -1.2)
    ca = np.diag([0.01, 0.02, 0.003])
    cb = np.diag([0.005, 0.001, 0.004])
    sa = _sample_right(a, ca, 20000, rng)
    sb = _sample_right(b, cb, 20000, rng)
    mean = compose(np.asarray(a), np.asarray(b))
    err = _log_right(compose(sa, sb), mean)
    np.testing.assert_allclose(np.cov(err.T), _compose_cov(a, ca, b, cb), atol=2e-3, rtol=0.1)
    err = _log_right(invert(sa), invert(np.asarray(a)))
    np.testing.assert_allclose(np.cov(err.T), _invert_cov(a, ca), atol=2e-3, rtol=0.1)


def _square_map(cells: list[tuple[int, int]], value: int = 60) -> LocalMap:
    lo = np.zeros((21, 21), dtype=np.int8)
    for r, c in cells:
        lo[r, c] = value
    return LocalMap(lo, 0.1)


@pytest.mark.parametrize("mode", ["off", "alone", "shared"])
def test_a_deleted_poses_map_folds_into_its_nearest_unshared_odometry_neighbour(
    mode: str,
) -> None:
    # Two poses in region 0 fill it; the third (newest) makes the store delete one.
    params = StoreParams(pose_limit=1000, region_limit=2500, fold=mode != "off")
    store = RobotStore(0, params)  # poses of 944 B
    lm = make_landmarks(np.zeros((1, 3)))
    # Pose 0's map marks the cell 0.5 m ahead of it (row 10, column 15); pose 1's the
    # cell 0.7 m behind and 0.7 m left of it (row 3, column 3). The poses lie on the x
    # axis at 0, 0.1 and 0.3 m, chained by odometry 0 -> 1 -> 2.
    maps = [_square_map([(10, 15)]), _square_map([(3, 3)]), _square_map([])]
    xs = [0.0, 0.1, 0.3]
    poses = [
        make_pose(0, k, lm, estimate=(xs[k], 0.0, 0.0), time=float(k), local_map=maps[k])
        for k in range(3)
    ]
    store.add_own_pose(poses[0], None, [], 0.0)
    store.add_own_pose(poses[1], odometry(poses[0], poses[1]), [], 1.0)
    if mode == "shared":
        store.share([poses[0].uid, poses[1].uid])  # both sent: only pose 2 may change
        assert store.shared(poses[0].uid)
        assert not store.shared(poses[2].uid)
    store.add_own_pose(poses[2], odometry(poses[1], poses[2]), [], 2.0)
    gone = {p.uid for p in poses} - set(store.local.poses)
    assert len(gone) == 1  # the region held only two
    held = {u: p.local_map for u, p in store.local.poses.items()}
    marked = {u: sorted(zip(*np.nonzero(m.logodds), strict=True)) for u, m in held.items() if m}
    before = {
        p.uid: sorted(zip(*np.nonzero(maps[k].logodds), strict=True)) for k, p in enumerate(poses)
    }
    if mode == "off":
        assert all(marked[u] == before[u] for u in marked)  # the map goes with the pose
        return
    if poses[0].uid in gone:
        # Its one neighbour, pose 1 (0.1 m ahead): the cell 0.4 m ahead of it.
        want = {poses[1].uid: [(3, 3), (10, 14)]} if mode == "alone" else {}
    else:
        # Pose 1's neighbours: pose 0 (0.1 m behind it, nearest) unless sent, else pose 2
        # (0.2 m ahead): the cell moves 0.1 m or 0.2 m further left in their squares.
        want = {poses[0].uid: [(3, 4), (10, 15)]} if mode == "alone" else {poses[2].uid: [(3, 1)]}
    for u in marked:
        assert marked[u] == want.get(u, before[u]), u


def test_a_regions_limit_grows_with_its_area_and_the_bound_with_it() -> None:
    params = StoreParams(region_limit=131_072, region_density=4096.0, store_limit=0)
    assert region_limits(params, [10.0, 100.0]) == [131_072, 409_600]
    assert local_bound(params, [10.0, 100.0]) == local_bound(params, 2) + 409_600 - 131_072
    capped = replace(params, store_limit=300_000)
    assert local_bound(capped, [10.0, 100.0]) == local_bound(capped, 3)
    store = RobotStore(0, params, [10.0, 100.0])
    assert (store.region_limit(0), store.region_limit(1), store.region_limit(7)) == (
        131_072,
        409_600,
        131_072,
    )
    with pytest.raises(ConfigError, match="region_density must be >= 0"):
        StoreParams(region_density=-1.0)
