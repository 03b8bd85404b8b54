"""Poses travelling quantised (issue 15's bandwidth goal): the error bounds, idempotence
(a relay forwards the bytes it got), what stays exact, and the exchange and the naive
baseline sending quantised poses while the sources keep theirs exact."""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.naive import NaiveExchanger
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.quantise import (
    check_quantisation,
    quantise_descriptors,
    quantise_pose,
    ternary_logodds,
)
from sonarmap.team.records import LocalMap, Pose, encode, make_uid
from sonarmap.team.store import RobotStore
from sonarmap.team.transport import SimHub
from test_team_exchange import (
    BIG,
    _chain,
    converged,
    landmarks,
    odometry,
    record_sends,
    uids,
)


def _local_map(seed: int) -> LocalMap:
    rng = np.random.default_rng(seed)
    lo = rng.choice(np.array([0, 0, -3, -6, -9, -12, -15, 20, 33, 127, -128]), (40, 40))
    return LocalMap(lo.astype(np.int8), 0.1)


def _store(robot: int, regions: Sequence[int], t0: float = 0.0) -> RobotStore:
    """Like the exchange tests' own stores, with 30 landmarks and a local map a pose."""
    store = RobotStore(robot, BIG)
    last: Pose | None = None
    for k, r in enumerate(regions):
        est = np.array([float(k), 3.0 * robot, 0.0])
        seed = 1000 * robot + k
        p = Pose(make_uid(robot, k), t0 + k, r, est, landmarks(30, seed), _local_map(seed))
        store.add_own_pose(p, None if last is None else odometry(last, p), [], t0 + k)
        last = p
    return store


def test_descriptors_keep_their_high_bits_within_half_a_step() -> None:
    d = np.arange(256, dtype=np.uint8)
    for bits in range(1, 8):
        q = quantise_descriptors(d, bits)
        step = 2 ** (8 - bits)
        assert q.dtype == np.uint8
        assert np.abs(q.astype(int) - d.astype(int)).max() <= step // 2
        assert len(np.unique(q)) == 2**bits
        assert np.array_equal(quantise_descriptors(q, bits), q)
    assert quantise_descriptors(d, 8) is d


def test_ternary_maps_keep_each_cells_class_and_each_class_total() -> None:
    lo = np.array([[0, -3, -6, -9], [-12, 20, 33, 0], [127, -128, 1, -1]], dtype=np.int8)
    t = ternary_logodds(lo)
    assert t.dtype == np.int8
    assert np.array_equal(np.sign(t), np.sign(lo))  # what is known, and its class, is kept
    free, occ = lo < 0, lo > 0
    assert set(t[free].tolist()) == {round(np.abs(lo[free].astype(int)).mean()) * -1}
    assert set(t[occ].tolist()) == {round(lo[occ].astype(int).mean())}
    assert np.array_equal(ternary_logodds(t), t)
    weak = np.array([[0, 1], [-1, 0]], dtype=np.int8)
    assert np.array_equal(ternary_logodds(weak), weak)  # at least one unit: still known
    assert not ternary_logodds(np.zeros((3, 3), dtype=np.int8)).any()


def test_a_quantised_pose_keeps_its_identity_and_quantises_once() -> None:
    p = Pose(make_uid(2, 7), 12.5, 3, np.array([1.0, 2.0, 0.3]), landmarks(30, 5), _local_map(5))
    q = quantise_pose(p, 4, True)
    assert (q.uid, q.time, q.region, q.merged_from) == (p.uid, p.time, p.region, p.merged_from)
    assert np.array_equal(q.estimate, p.estimate)
    assert np.array_equal(q.landmarks.ids, p.landmarks.ids)
    assert np.abs(q.landmarks.points - p.landmarks.points).max() < 0.004  # points < 5 m
    assert np.abs(q.landmarks.descriptors.astype(int) - p.landmarks.descriptors).max() <= 8
    assert q.local_map is not None
    assert p.local_map is not None
    assert np.array_equal(q.local_map.logodds != 0, p.local_map.logodds != 0)
    assert encode(quantise_pose(q, 4, True)) == encode(q)
    assert encode(quantise_pose(q, 8, False)) == encode(q)
    assert quantise_pose(p, 8, False) is p
    far = p.with_landmarks(landmarks(30, 5))
    far.landmarks.points[0, 0] = 1e5  # beyond float16: the points stay float32
    assert np.array_equal(quantise_pose(far, 4, False).landmarks.points, far.landmarks.points)
    assert np.abs(q.landmarks.stamp - p.landmarks.stamp).max() < 1e-3
    assert np.abs(q.landmarks.reliability - p.landmarks.reliability).max() < 1e-3
    # What shrinks is the deflated body: the uniform descriptors, by about half.
    exact, small = (len(zlib.compress(encode(x), 6)) for x in (p, q))
    assert small < 0.7 * exact


@pytest.mark.parametrize(
    ("bits", "ternary"), [(0, False), (9, False), (2.5, False), (True, False), (4, 1), (4, "no")]
)
def test_bad_quantisation_is_refused(bits: Any, ternary: Any) -> None:
    with pytest.raises(ConfigError, match=r"descriptor_bits|ternary_maps"):
        check_quantisation(bits, ternary)
    with pytest.raises(ConfigError):
        ExchangeParams(descriptor_bits=bits, ternary_maps=ternary)


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_poses_travel_quantised_and_a_relay_forwards_what_it_got(mode: str) -> None:
    def run(**q: Any) -> tuple[list[RobotStore], int]:
        stores = [_store(r, [0, 1, 1, r], t0=0.1 * r) for r in range(3)]
        team = _chain(stores, mode=mode, cap_bytes=10**6, **q)
        sent = [record_sends(t) for t in team.transports]
        team.run(14)
        assert converged(team)
        for ex in team.ex:
            assert sum(ex.stats.bytes_by_kind.values()) == ex.stats.bytes_sent
            assert ex.stats.bytes_by_kind["answer"] == sum(map(len, sent[team.ex.index(ex)]))
        return stores, sum(len(b) for s in sent for b in s)

    exact_stores, exact_bytes = run()
    stores, quantised_bytes = run(descriptor_bits=4, ternary_maps=True)
    a, b, c = stores
    assert uids(c.received[0]) == uids(a.local)
    for u, own in a.local.poses.items():
        travelled = encode(quantise_pose(own, 4, True))
        assert encode(b.received[0].poses[u]) == travelled
        assert encode(c.received[0].poses[u]) == travelled  # c never heard a: b forwarded it
        # Quantising what travels leaves the source's own poses alone.
        assert encode(own) == encode(exact_stores[0].local.poses[u])
    assert quantised_bytes < 0.75 * exact_bytes


def test_the_naive_baseline_quantises_only_when_asked() -> None:
    def run(**q: Any) -> tuple[RobotStore, RobotStore, int]:
        a, b = _store(0, [0, 0, 1]), _store(1, [1])
        hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2, seed=0))
        ts = [hub.transport(0), hub.transport(1)]
        params = ExchangeParams(mode="naive", **q)
        ex = [NaiveExchanger(s, t, params) for s, t in zip((a, b), ts, strict=True)]
        for _ in range(4):
            hub.step(0.5)
            for e in ex:
                e.step(hub.now)
        return a, b, ex[0].stats.bytes_sent

    a, b, exact = run()
    assert all(encode(b.received[0].poses[u]) == encode(p) for u, p in a.local.poses.items())
    a, b, small = run(descriptor_bits=4)
    for u, p in a.local.poses.items():
        assert encode(b.received[0].poses[u]) == encode(quantise_pose(p, 4, False))
    assert small < 0.75 * exact
