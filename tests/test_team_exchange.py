"""The exchange between robot stores (thesis 002, 2.4): convergence on full, lossy,
relayed and bandwidth-limited networks, deletion propagating, the limited mode's cap
and its three stamp cases, strict rejection of bad bodies, retries after a lost answer
and consistency when a peer vanishes."""

from __future__ import annotations

import logging
import math
import struct
from collections import defaultdict
from collections.abc import Callable, Sequence
from typing import Any

import msgpack
import numpy as np
import pytest
import zstandard

from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.team.exchange import (
    ExchangeParams,
    Exchanger,
)
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.records import (
    ClosureEdge,
    Landmarks,
    OdometryEdge,
    Pose,
    compose,
    decode,
    encode,
    invert,
    make_uid,
    robot_of,
)
from sonarmap.team.store import Layer, RobotStore, StoreParams
from sonarmap.team.transport import SimHub, SimTransport, Transport
from sonarmap.team.wire import (
    MAX_INFLATED,
    VERSION,
    ZSTD_LEVEL,
    Advert,
    AdvertEntry,
    Answer,
    ExchangeError,
    PatchAnswer,
    PatchRequest,
    Request,
    decode_advert,
    decode_answer,
    decode_request,
    encode_advert,
    encode_answer,
    encode_request,
    inflate,
)

LOGGER = "sonarmap.team.exchange"
BIG = StoreParams(pose_limit=10**7, region_limit=10**8, store_limit=0)
COV = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-5)
FAST = {"advert_every": 1.0, "request_every": 0.5, "request_timeout": 3.0, "peer_timeout": 5.0}
DT = 0.5


# --- synthetic stores ---------------------------------------------------------------------


def landmarks(n: int, seed: int) -> Landmarks:
    rng = np.random.default_rng(seed)
    return Landmarks(
        rng.uniform(0, 5, (n, 3)).astype(np.float32),
        rng.integers(0, 256, (n, 128), dtype=np.uint8),
        np.full(n, 0.5, dtype=np.float32),
        np.zeros(n),
        np.arange(n),
    )


def pose(robot: int, k: int, region: int, t: float, n: int = 4) -> Pose:
    est = np.array([float(k), 3.0 * robot, 0.0])
    return Pose(make_uid(robot, k), t, region, est, landmarks(n, 1000 * robot + k))


def odometry(a: Pose, b: Pose) -> OdometryEdge:
    tf = compose(invert(a.estimate), b.estimate)
    return OdometryEdge(a.uid, b.uid, (tf[0], tf[1], tf[2]), COV, 10.0)


def own_store(robot: int, regions: Sequence[int], t0: float = 0.0, n: int = 4) -> RobotStore:
    """A robot that made one pose per entry of ``regions`` (its region), chained by
    odometry, at times t0, t0 + 1, ..."""
    store = RobotStore(robot, BIG)
    last: Pose | None = None
    for k, r in enumerate(regions):
        p = pose(robot, k, r, t0 + k, n)
        store.add_own_pose(p, None if last is None else odometry(last, p), [], t0 + k)
        last = p
    return store


def add_own(store: RobotStore, k: int, region: int, t: float) -> Pose:
    """One more own pose, chained to the newest."""
    last = max(store.local.poses.values(), key=lambda p: (p.time, p.uid))
    p = pose(store.robot, k, region, t)
    store.add_own_pose(p, odometry(last, p), [], t)
    return p


def uids(layer: Layer | None) -> set[int]:
    return set() if layer is None else set(layer.poses)


def check_consistent(store: RobotStore) -> None:
    """Own poses only in the local layer, no UID twice, lists matching the poses, short
    within full in received layers, no edge or closure naming a missing pose."""
    seen: set[int] = set()
    for layer in (store.local, *store.received.values()):
        if layer is store.local:
            assert all(robot_of(u) == store.robot for u in layer.poses)
        else:
            assert layer.source != store.robot
            assert all(robot_of(u) == layer.source for u in layer.poses)
        assert not seen & set(layer.poses)
        seen |= set(layer.poses)
        by_region: dict[int, set[int]] = defaultdict(set)
        for u, p in layer.poses.items():
            by_region[p.region].add(u)
        for r, patch in layer.patches.items():
            assert patch.short == by_region.get(r, set())
            if layer is not store.local:
                assert patch.short <= patch.full
        assert set(by_region) <= set(layer.patches)
        assert all(e.a in layer.poses and e.b in layer.poses for e in layer.edges)
    assert all(c.a in seen and c.b in seen for c in store.closures)


def snapshot(store: RobotStore) -> tuple[Any, ...]:
    """Everything the exchange may change, to compare byte for byte."""
    layers = {}
    for src, layer in sorted(store.received.items()):
        patches = {r: (p.stamp, sorted(p.short), sorted(p.full)) for r, p in layer.patches.items()}
        layers[src] = (
            sorted(layer.poses),
            patches,
            sorted(encode(e) for e in layer.edges),
            layer.bytes(),
        )
    local = store.local
    own = (
        {u: encode(p) for u, p in local.poses.items()},
        {r: (p.stamp, sorted(p.short), sorted(p.full)) for r, p in local.patches.items()},
        sorted(encode(e) for e in local.edges),
    )
    return store.bytes(), layers, own, sorted(encode(c) for c in store.closures)


# --- a team on a simulated network -----------------------------------------------------------


class Team:
    def __init__(
        self,
        stores: Sequence[RobotStore],
        net: NetworkParams | None = None,
        *,
        grid: Grid | None = None,
        xy: np.ndarray | None = None,
        on_received: Callable[[RobotStore], Callable[[int, Pose], list[ClosureEdge]]] | None = None,
        adjacency: dict[int, set[int]] | None = None,
        seed: int = 0,
        **params: Any,
    ) -> None:
        net = net if net is not None else NetworkParams(kind="full")
        clear = None if grid is None else np.ones(grid.shape, dtype=bool)
        network = SimNetwork(net, len(stores), seed=seed, clear=clear, grid=grid)
        self.hub = SimHub(network)
        if xy is not None:
            self.hub.update(xy)
        self.stores = list(stores)
        self.transports = [self.hub.transport(s.robot) for s in stores]
        self.params = ExchangeParams(**{**FAST, **params})
        self.ex = [
            Exchanger(
                s,
                t,
                self.params,
                adjacency=adjacency,
                on_received=None if on_received is None else on_received(s),
            )
            for s, t in zip(stores, self.transports, strict=True)
        ]

    def run(self, steps: int, wanted: Sequence[int] | None = None) -> None:
        for _ in range(steps):
            self.hub.step(DT)
            for ex in self.ex:
                ex.step(self.hub.now, wanted)


def converged(team: Team) -> bool:
    return all(
        uids(a.received.get(b.robot)) == uids(b.local)
        for a in team.stores
        for b in team.stores
        if a is not b
    )


def record_sends(
    t: Transport, kinds: Sequence[str] = ("answer",), *, destinations: bool = False
) -> list[Any]:
    """Bodies (or with ``destinations``, (dst, body) pairs) of the messages of ``kinds``
    this transport sends, in order."""
    out: list[Any] = []
    send = t.send

    def spy(dst: int, payload: bytes, kind: str = "data") -> bool:
        if kind in kinds:
            out.append((dst, payload) if destinations else payload)
        return send(dst, payload, kind)

    t.send = spy  # type: ignore[method-assign]
    return out


def drop_sends(t: Transport, dropped_kind: str, count: int) -> list[bytes]:
    """The next ``count`` messages of ``kind`` vanish (the transport claims them sent)."""
    dropped: list[bytes] = []
    send = t.send

    def lossy(dst: int, payload: bytes, kind: str = "data") -> bool:
        if kind == dropped_kind and len(dropped) < count:
            dropped.append(payload)
            return True
        return send(dst, payload, kind)

    t.send = lossy  # type: ignore[method-assign]
    return dropped


# --- convergence --------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_two_robots_exchange_everything_and_leave_local_layers_alone(mode: str) -> None:
    a = own_store(0, [0, 0, 1, 1, 2])
    b = own_store(1, [2, 3, 3, 0], t0=0.5)
    before = [snapshot(s)[2] for s in (a, b)]
    team = Team([a, b], mode=mode, cap_bytes=10**6)
    team.run(8)
    assert uids(a.received[1]) == uids(b.local)
    assert uids(b.received[0]) == uids(a.local)
    assert [snapshot(s)[2] for s in (a, b)] == before  # local layers unchanged
    for s in (a, b):
        check_consistent(s)
        assert set(s.received) == {1 - s.robot}  # never a layer of its own poses
    # The edges came too: the received layer is the source's graph.
    assert {(e.a, e.b) for e in a.received[1].edges} == {(e.a, e.b) for e in b.local.edges}
    # Once equal, nobody asks again.
    sent = [ex.stats.requests_sent for ex in team.ex]
    team.run(10)
    assert [ex.stats.requests_sent for ex in team.ex] == sent
    assert all(not ex.stats.rejected for ex in team.ex)


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_three_robots_converge_on_a_full_network(mode: str) -> None:
    stores = [own_store(r, [r, (r + 1) % 4, 3, r], t0=0.1 * r) for r in range(3)]
    team = Team(stores, mode=mode, cap_bytes=10**6)
    team.run(10)
    assert converged(team)
    for s in stores:
        check_consistent(s)
    # New poses keep flowing, including one made at the very time of an answer.
    add_own(stores[0], 10, 1, team.hub.now)
    team.run(6)
    assert converged(team)
    add_own(stores[2], 11, 0, team.hub.now)
    team.run(1)
    add_own(stores[2], 12, 0, team.hub.now)  # same region, right after an answer
    team.run(8)
    assert converged(team)


def test_a_change_at_the_instant_of_an_answer_is_advertised_newer() -> None:
    a, b = own_store(0, [0]), own_store(1, [0])
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    ta, tb = hub.transport(0), hub.transport(1)
    eb = Exchanger(b, tb, ExchangeParams(**FAST))  # type: ignore[arg-type]
    hub.advance(5.0)
    req = Request(0, "good", (PatchRequest(1, 0, None, frozenset()),))
    ta.send(1, encode_request(req), kind="request")
    eb.step(5.0)
    (answer,) = [decode_answer(m.payload) for m in ta.poll() if m.kind == "answer"]
    assert answer.patches[0].stamp == 5.0  # the source answers with now
    add_own(b, 1, 0, 5.0)  # its patch changes at that very time
    (entry,) = [e for e in eb.advert().entries if e.source == 1]
    assert entry.stamp > 5.0  # so a holder stamped 5.0 sees it is behind
    # In a team: the source's pose made right after it answered still reaches the other.
    team = Team([a, own_store(1, [0])])
    answers = record_sends(team.transports[1])
    while not answers:
        team.run(1)
    add_own(team.stores[1], 1, 0, team.hub.now)
    team.run(6)
    assert converged(team)


def test_a_lossy_network_converges_through_retries() -> None:
    stores = [own_store(r, [0, 1, 2, 3, r], t0=0.1 * r) for r in range(3)]
    team = Team(stores, NetworkParams(kind="full", loss=0.4), seed=3)
    team.run(60)
    assert converged(team)
    assert sum(ex.stats.retries for ex in team.ex) > 0
    for s in stores:
        check_consistent(s)


def _chain(stores: Sequence[RobotStore], **params: Any) -> Team:
    """Robots 0 - 1 - 2 in a line, 50 m apart, range 70 m, no relaying: 0 and 2 cannot
    talk."""
    grid = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(20, 200))
    net = NetworkParams(kind="limited", r_max=70.0, relay=False)
    xy = np.array([[10.0, 10.0], [60.0, 10.0], [110.0, 10.0]])
    return Team(stores, net, grid=grid, xy=xy, **params)


def test_a_middle_robot_carries_poses_between_robots_out_of_range() -> None:
    stores = [own_store(r, [0, 1, 1, r], t0=0.1 * r) for r in range(3)]
    team = _chain(stores)
    assert team.hub.network.reachable(0) == [1]
    team.run(12)
    assert converged(team)
    a, b, c = stores
    # C holds A's poses although it never heard A: B answered from its received layer
    # (B is newest among C's peers), with B's stamp.
    assert uids(c.received[0]) == uids(a.local)
    assert c.received[0].patches[1].stamp == b.received[0].patches[1].stamp
    assert team.ex[0].stats.messages_received > 0
    assert not team.ex[0].peer_table(2)  # A never heard C
    # A deletion at A travels the same way.
    gone = make_uid(0, 1)
    a.delete_pose(gone, team.hub.now)
    team.run(10)
    assert gone not in b.received[0].poses
    assert gone not in c.received[0].poses
    assert converged(team)
    for s in stores:
        check_consistent(s)


def _fake_association(store: RobotStore) -> Callable[[int, Pose], list[ClosureEdge]]:
    """Every received pose "matches" the robot's first own pose (no landmark pairs, so
    no stamps change)."""

    def associate(source: int, p: Pose) -> list[ClosureEdge]:
        first = min(store.local.poses)
        return [ClosureEdge(first, p.uid, (0.0, 0.0, 0.0), COV, 10, 0.1, ())]

    return associate


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_a_deletion_at_the_source_removes_the_pose_its_edges_and_closures(mode: str) -> None:
    stores = [own_store(r, [0, 0, 0, 1], t0=0.1 * r) for r in range(3)]
    team = Team(stores, mode=mode, on_received=_fake_association, cap_bytes=10**6)
    team.run(8)
    assert converged(team)
    gone = make_uid(0, 1)
    for s in stores[1:]:
        assert any(gone in (c.a, c.b) for c in s.closures)
        assert any(gone in (e.a, e.b) for e in s.received[0].edges)
    stores[0].delete_pose(gone, team.hub.now)
    team.run(6)
    assert converged(team)
    for s in stores[1:]:
        assert gone not in s.received[0].poses
        assert not any(gone in (c.a, c.b) for c in s.closures)
        # The edge the source chained around the deleted pose reached the receivers.
        assert {(e.a, e.b) for e in s.received[0].edges} == {
            (e.a, e.b) for e in stores[0].local.edges
        }
        check_consistent(s)


# --- the limited network -------------------------------------------------------------------


def _pose_bytes_per_answer(bodies: Sequence[bytes]) -> list[int]:
    out = []
    for body in bodies:
        d = msgpack.unpackb(inflate(body), raw=False)
        out.append(sum(len(p) for row in d["patches"] for p in row["poses"]))
    return out


def test_limited_answers_respect_the_cap_and_converge_over_rounds() -> None:
    a = own_store(0, [0] * 6 + [1] * 6)
    b = own_store(1, [1] * 5)
    one = max(a.local.pose_bytes(u) for u in a.local.poses)
    cap = int(2.5 * one)
    adjacency = {0: {1}, 1: {0}}
    team = Team(
        [a, b],
        NetworkParams(kind="full", bandwidth=20_000.0),
        mode="limited",
        cap_bytes=cap,
        adjacency=adjacency,
    )
    bodies = record_sends(team.transports[0])
    team.run(4)
    assert 0 < len(b.received[0].poses) < len(a.local.poses)  # capped: not all at once
    assert b.received[0].patches[0].full == a.local.patches[0].short  # but knows the rest
    team.run(40)
    assert converged(team)
    sizes = _pose_bytes_per_answer(bodies)
    assert max(sizes) <= cap
    assert sum(1 for s in sizes if s > one) > 0  # answers do carry two poses
    assert len([s for s in sizes if s > 0]) >= 12 // 2
    check_consistent(b)


def test_a_budget_bounds_the_answers_a_robot_brings_in() -> None:
    def received_by_b(budget: float, steps: int) -> tuple[int, RobotStore]:
        a = own_store(0, [0] * 8 + [1] * 8 + [2] * 8, n=20)
        b = own_store(1, [1])
        team = Team(
            [a, b],
            mode="limited",
            cap_bytes=2 * a.local.pose_bytes(make_uid(0, 0)),
            adjacency={0: {1}, 1: {0, 2}, 2: {1}},
            budget=budget,
        )
        bodies = record_sends(team.transports[0])
        team.run(steps)
        return sum(len(x) for x in bodies), b

    budget, steps = 1500.0, 20  # 10 s
    free, b_free = received_by_b(0.0, steps)
    paced, b_paced = received_by_b(budget, steps)
    cap = 2 * b_free.received[0].pose_bytes(make_uid(0, 0))
    # The balance starts full (one cap) and grows at the budget; one answer (at most the
    # cap, plus lists and edges) may overdraw it.
    assert paced <= budget * steps * DT + 2 * cap + 2048
    assert paced < free / 2
    assert 0 < len(b_paced.received[0].poses) < len(b_free.received[0].poses)
    check_consistent(b_paced)


def test_a_budget_must_be_a_rate() -> None:
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ConfigError, match="budget"):
            ExchangeParams(budget=bad)


def test_limited_requests_cover_adjacent_patches_of_one_source() -> None:
    a = own_store(0, [0, 1, 2, 3, 5])
    b = own_store(1, [0])
    adjacency = {0: {1}, 1: {0, 2}, 2: {1}, 3: {5}, 5: {3}, 4: set()}
    team = Team([a, b], mode="limited", adjacency=adjacency, max_outstanding=1)
    requests = record_sends(team.transports[1], ("request",))
    team.run(3, wanted=[3])
    first = decode_request(requests[0])
    assert [(p.source, p.region) for p in first.patches] == [(0, 3), (0, 5)]  # wanted first
    team.run(3)
    regions = [sorted(p.region for p in decode_request(r).patches) for r in requests[1:]]
    assert [0, 1, 2] in regions
    # A limited request naming regions that do not touch is refused.
    bad = Request(
        99, "limited", tuple(PatchRequest(1, r, None, frozenset(), frozenset()) for r in (0, 2))
    )
    team.transports[1].send(0, encode_request(bad), kind="request")
    team.run(1)
    assert team.ex[0].stats.rejected["adjacency"] == 1


# The three stamp cases, from the answerer's side. Robot 2 is the source (absent); A is
# robot 0, B robot 1. Source poses 0..5, all in region 0.
SRC = [pose(2, k, 0, float(k)) for k in range(6)]


def _holder(robot: int, held: Sequence[int], stamp: float, full: Sequence[int]) -> RobotStore:
    store = RobotStore(robot, BIG)
    for k in held:
        edges = [odometry(SRC[k - 1], SRC[k])] if k > 0 and k - 1 in held else []
        store.add_received_pose(2, SRC[k], edges, [], 0.0)
    layer = store.received.setdefault(2, Layer(2))
    patch = layer.patch(0)
    patch.stamp = stamp
    patch.full = {SRC[k].uid for k in full}
    return store


def _ask(
    b: RobotStore, a_held: Sequence[int], a_stamp: float, a_full: Sequence[int]
) -> PatchAnswer:
    """A's request for source 2's region 0 sent to B; B's answer as decoded."""
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 3))
    ta, tb = hub.transport(0), hub.transport(1)
    ex = Exchanger(b, tb, ExchangeParams(mode="limited", **FAST))  # type: ignore[arg-type]
    short = frozenset(SRC[k].uid for k in a_held)
    full = frozenset(SRC[k].uid for k in a_full)
    req = Request(7, "limited", (PatchRequest(2, 0, a_stamp, short, full),))
    assert ta.send(1, encode_request(req), kind="request")
    ex.step(1.0)
    answers = [m for m in ta.poll() if m.kind == "answer"]
    assert len(answers) == 1
    answer = decode_answer(answers[0].payload)
    assert answer.id == 7
    (entry,) = answer.patches
    return entry


def _uid_set(ks: Sequence[int]) -> set[int]:
    return {SRC[k].uid for k in ks}


def test_stamp_case_answerer_newer_sends_its_full_list_stamp_and_missing_poses() -> None:
    # The source deleted pose 0 and made 4 and 5 at t=20; B knows, A saw t=10.
    b = _holder(1, [1, 2, 3, 4], 20.0, [1, 2, 3, 4, 5])
    entry = _ask(b, [0, 1], 10.0, [0, 1, 2])
    assert entry.stamp == 20.0
    assert entry.full == frozenset(_uid_set([1, 2, 3, 4, 5]))
    assert {p.uid for p in entry.poses} == _uid_set([2, 3, 4])  # B's short minus A's
    assert entry.short is None


def test_stamp_case_answerer_older_offers_and_adopts_the_newer_full_list() -> None:
    # A (t=20) knows the source dropped 3 and made 5; B (t=10) still has 3.
    b = _holder(1, [1, 2, 3, 4], 10.0, [1, 2, 3, 4])
    entry = _ask(b, [1], 20.0, [1, 2, 4, 5])
    assert entry.stamp is None
    assert entry.full is None
    # Poses in A's full list that A lacks and B has.
    assert {p.uid for p in entry.poses} == _uid_set([2, 4])
    patch = b.received[2].patches[0]
    assert patch.stamp == 20.0
    assert patch.full == _uid_set([1, 2, 4, 5])
    assert set(b.received[2].poses) == _uid_set([1, 2, 4])  # 3 is gone at the source
    check_consistent(b)


def test_stamp_case_equal_stamps_send_only_the_short_list_poses_missing() -> None:
    b = _holder(1, [1, 3], 10.0, [1, 2, 3])
    before = snapshot(b)
    entry = _ask(b, [1], 10.0, [1, 2, 3])
    assert entry.stamp is None
    assert entry.full is None
    assert {p.uid for p in entry.poses} == _uid_set([3])
    assert snapshot(b) == before  # equal: the answerer changes nothing


@pytest.mark.parametrize(
    ("a_state", "b_state", "after"),
    [
        # (held, stamp, full) of A, of B; A's poses after, and its stamp.
        (([0, 1], 10.0, [0, 1, 2]), ([1, 2, 3, 4], 20.0, [1, 2, 3, 4, 5]), ([1, 2, 3, 4], 20.0)),
        (([1], 20.0, [1, 2, 4, 5]), ([1, 2, 3, 4], 10.0, [1, 2, 3, 4]), ([1, 2, 4], 20.0)),
        (([1], 10.0, [1, 2, 3]), ([1, 3], 10.0, [1, 2, 3]), ([1, 3], 10.0)),
    ],
    ids=["B newer", "B older", "equal"],
)
def test_stamp_cases_applied_by_the_requester(
    a_state: tuple[list[int], float, list[int]],
    b_state: tuple[list[int], float, list[int]],
    after: tuple[list[int], float],
) -> None:
    a, b = _holder(0, *a_state), _holder(1, *b_state)
    team = Team([a, b], NetworkParams(kind="full"), mode="limited")
    # The source is away: robots 0 and 1 only (robot 2 has no transport).
    team.run(6)
    held, stamp = after
    assert set(a.received[2].poses) == _uid_set(held)
    assert a.received[2].patches[0].stamp == stamp
    for s in (a, b):
        check_consistent(s)


@pytest.mark.parametrize(("b_stamp", "sends"), [(30.0, True), (20.0, False), (10.0, False)])
def test_good_mode_a_holder_answers_only_when_newer(b_stamp: float, sends: bool) -> None:
    b = _holder(1, [1, 2, 3], b_stamp, [1, 2, 3])
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 3))
    ta, tb = hub.transport(0), hub.transport(1)
    ex = Exchanger(b, tb, ExchangeParams(**FAST))  # type: ignore[arg-type]
    short = frozenset(_uid_set([0, 1]))
    ta.send(
        1, encode_request(Request(4, "good", (PatchRequest(2, 0, 20.0, short),))), kind="request"
    )
    ex.step(1.0)
    (answer,) = [decode_answer(m.payload) for m in ta.poll() if m.kind == "answer"]
    (entry,) = answer.patches
    if sends:
        assert entry.stamp == b_stamp
        assert entry.short == frozenset(_uid_set([1, 2, 3]))
        assert {p.uid for p in entry.poses} == _uid_set([2, 3])
        assert {(e.a, e.b) for e in entry.edges} >= {(SRC[1].uid, SRC[2].uid)}
    else:  # not the source and not newer: nothing for that patch
        assert (entry.stamp, entry.short, entry.poses, entry.edges) == (None, None, (), ())


def test_the_source_is_asked_when_reachable_else_the_newest_holder() -> None:
    # Robot 1 is the source of region 0; robots 2 and 3 hold copies stamped later than
    # the source's last change (they got them at "now"), 3's the newest.
    source = own_store(1, [0, 0])
    stores = [RobotStore(0, BIG), source]
    for r, stamp in ((2, 40.0), (3, 50.0)):
        h = RobotStore(r, BIG)
        for p in source.local.poses.values():
            h.add_received_pose(1, p, [], [], 0.0)
        h.received[1].patches[0].stamp = stamp
        h.received[1].patches[0].full = set(source.local.poses)
        stores.append(h)
    for reach in ([1, 2, 3], [2, 3]):
        hub = SimHub(SimNetwork(NetworkParams(kind="full"), 4))
        ts = [hub.transport(r) for r in range(4)]
        requests = record_sends(ts[0], ("request",), destinations=True)
        a = RobotStore(0, BIG)
        params = ExchangeParams(**FAST)  # type: ignore[arg-type]
        exs = [Exchanger(a, ts[0], params, peers=reach.copy)]
        exs += [Exchanger(s, t, params) for s, t in zip(stores[1:], ts[1:], strict=True)]
        for _ in range(4):
            hub.step(DT)
            for ex in exs:
                ex.step(hub.now)
        assert set(a.received[1].poses) == set(source.local.poses)
        stamp = a.received[1].patches[0].stamp
        if 1 in reach:
            assert [dst for dst, _ in requests] == [1]  # not 3, whose stamp is newer
            assert stamp < 40.0  # the source's now
        else:
            assert [dst for dst, _ in requests] == [3]
            assert stamp == 50.0  # the holder's stamp


# --- bad bodies ------------------------------------------------------------------------------


def _zstd(raw: bytes, **options: Any) -> bytes:
    """A zstd frame of ``raw`` made without the preset dictionary (which any reader takes)."""
    return zstandard.ZstdCompressor(**options).compress(raw)


def pack(d: object) -> bytes:
    return _zstd(bytes(msgpack.packb(d, use_bin_type=True)))


def _lying_frame() -> bytes:
    """A frame of 1 MiB of zeros whose header says it holds 100 bytes."""
    frame = _zstd(bytes(1 << 20))
    at = frame.index(struct.pack("<I", 1 << 20), 4)
    return frame[:at] + struct.pack("<I", 100) + frame[at + 4 :]


@pytest.fixture
def asking() -> tuple[Exchanger, SimTransport, RobotStore, int]:
    """A (robot 0, with a received layer already) has asked B (robot 1, raw transport)
    for B's region 0; yields A's exchanger, B's transport, B's store and the request id."""
    a = own_store(0, [0, 1])
    b = own_store(1, [0, 0, 1])
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 3))
    ta, tb = hub.transport(0), hub.transport(1)
    ex = Exchanger(a, ta, ExchangeParams(**FAST))  # type: ignore[arg-type]
    a.add_received_pose(2, pose(2, 0, 0, 0.0), [], [], 0.0)
    a.received[2].patches[0].stamp = 0.0
    a.received[2].patches[0].full = {make_uid(2, 0)}
    advert = Advert((AdvertEntry(1, 0, 2.0, 2),))
    tb.send(0, encode_advert(advert), kind="advert")
    hub.step(1.0)
    ex.step(hub.now)
    (req,) = [m for m in tb.poll() if m.kind == "request"]
    rid = decode_request(req.payload).id
    return ex, tb, b, rid


def _good_entry(b: RobotStore, ks: Sequence[int], region: int = 0) -> dict[str, Any]:
    ps = [b.local.poses[make_uid(1, k)] for k in ks]
    return {
        "src": 1,
        "r": region,
        "s": 2.0,
        "short": sorted(b.local.patches[region].short),
        "full": None,
        "poses": [encode(p) for p in ps],
        "edges": [encode(e) for e in b.local.edges],
    }


def _answer(rid: int, *rows: dict[str, Any], **top: Any) -> bytes:
    return pack({"v": VERSION, "id": rid, "mode": "good", "patches": list(rows), **top})


def _request_body(drop: Sequence[str] = (), **changes: Any) -> bytes:
    """A good request for robot 2's region 0 with its one patch's fields changed, and
    those named in ``drop`` left out."""
    d = msgpack.unpackb(
        inflate(encode_request(Request(0, "good", (PatchRequest(2, 0, None, frozenset()),))))
    )
    row = {k: v for k, v in {**d["patches"][0], **changes}.items() if k not in drop}
    return pack({**d, "patches": [row]})


#: A travelling closure's covariance (peerclosures' layout: xx, xy, xt, yy, yt, tt).
CLOSURE_COV = struct.pack("<6f", 1e-4, 0.0, 0.0, 1e-4, 0.0, 1e-5)


def _closure_row(**changes: Any) -> list[Any]:
    """A valid travelling closure from B's pose 0 (sent) to A's own pose 0, changed."""
    row = {
        "a": make_uid(1, 0),
        "b": make_uid(0, 0),
        "x": 500,
        "y": -20,
        "t": 100,
        "cov": CLOSURE_COV,
        "inliers": 12,
    }
    row.update(changes)
    return list(row.values())


def _bad_closure_bodies(rid: int, entry: dict[str, Any]) -> dict[str, tuple[str, bytes, str]]:
    """A peer's bad or forged closures riding on a good entry: name -> (kind, body,
    reason)."""

    def body(rows: Any) -> bytes:
        return _answer(rid, {**entry, "c": rows})

    nan_cov = struct.pack("<6f", math.nan, 0.0, 0.0, 1e-4, 0.0, 1e-5)
    indefinite = struct.pack("<6f", 1e-4, 1.0, 0.0, 1e-4, 0.0, 1e-5)
    return {
        "closures not a list": ("answer", body({"a": 1}), "type"),
        "closure short": ("answer", body([_closure_row()[:6]]), "type"),
        "closure covariance nan": ("answer", body([_closure_row(cov=nan_cov)]), "range"),
        "closure covariance not definite": (
            "answer",
            body([_closure_row(cov=indefinite)]),
            "range",
        ),
        "closure covariance tiny": (
            "answer",
            body([_closure_row(cov=struct.pack("<6f", 1e-20, 0, 0, 1e-20, 0, 1e-20))]),
            "range",
        ),
        "closure covariance as list": ("answer", body([_closure_row(cov=[1e-4] * 6)]), "type"),
        "closure covariance cut": ("answer", body([_closure_row(cov=CLOSURE_COV[:20])]), "range"),
        "closure touching no pose sent": (
            "answer",
            body([_closure_row(a=make_uid(1, 2), b=make_uid(0, 0))]),
            "inconsistent",
        ),
        "closure to itself": (
            "answer",
            body([_closure_row(b=make_uid(1, 0))]),
            "inconsistent",
        ),
        "closure uid past 2^63": ("answer", body([_closure_row(b=2**64 - 1)]), "range"),
        "closure 10 km long": ("answer", body([_closure_row(x=10**7)]), "range"),
        "closure 150 m long": ("answer", body([_closure_row(x=100_000, y=100_000)]), "range"),
        "closure turn past pi": ("answer", body([_closure_row(t=40_000)]), "range"),
        "closure x as float": ("answer", body([_closure_row(x=0.5)]), "type"),
        "closure a as bool": ("answer", body([_closure_row(a=True)]), "type"),
        "closure inliers negative": ("answer", body([_closure_row(inliers=-1)]), "range"),
        "closure pair twice": (
            "answer",
            body([_closure_row(), _closure_row(a=make_uid(0, 0), b=make_uid(1, 0))]),
            "duplicate",
        ),
        "closures oversized": ("answer", body([_closure_row()] * 129), "oversized"),
        # Variances of 1e-4, but x and y nearly one direction: an eigenvalue near 2e-11.
        "closure covariance nearly singular": (
            "answer",
            body([_closure_row(cov=struct.pack("<6f", 1e-4, 1e-4 * (1 - 2e-7), 0, 1e-4, 0, 1e-4))]),
            "range",
        ),
        "closure covariance infinite": (
            "answer",
            body([_closure_row(cov=struct.pack("<6f", math.inf, 0, 0, 1e-4, 0, 1e-4))]),
            "range",
        ),
        "closure a negative": ("answer", body([_closure_row(a=-1)]), "range"),
        "closure inliers 65,536": ("answer", body([_closure_row(inliers=65_536)]), "range"),
        "closures on an entry with no poses": (
            "answer",
            _answer(rid, {**entry, "poses": [], "edges": [], "c": [_closure_row()]}),
            "inconsistent",
        ),
    }


def _bad_bodies(b: RobotStore, rid: int) -> dict[str, tuple[str, bytes, str]]:
    """name -> (kind, body, reason)."""
    good = _answer(rid, _good_entry(b, [0, 1]))
    entry = _good_entry(b, [0, 1])
    wrong_region = pose(1, 7, 1, 0.0)
    a_pose = pose(0, 5, 0, 0.0)
    return {
        "not zstd": ("answer", b"\xc1garbage", "zstd"),
        "not msgpack": ("answer", _zstd(b"\xc1garbage"), "msgpack"),
        "zstd bomb": ("answer", _zstd(bytes(MAX_INFLATED + 1), level=19), "oversized"),
        "size not stated": ("answer", _zstd(b"\x80", write_content_size=False), "zstd"),
        "size understated": ("answer", _lying_frame(), "zstd"),
        "truncated": ("answer", good[:-40], "truncated"),
        "trailing": ("answer", good + b"\x00", "trailing"),
        "not a map": ("answer", pack([1, 2, 3]), "not_map"),
        "missing key": ("answer", pack({"v": VERSION, "id": rid, "mode": "good"}), "keys"),
        "extra key": ("answer", _answer(rid, entry, pickle=b"cos\nsystem"), "keys"),
        "version": ("answer", _answer(rid, entry, v=VERSION + 1), "version"),
        # A peer of wire version 6 knows no closures: refused by version, not by keys.
        "older version": ("answer", _answer(rid, entry, v=VERSION - 1), "version"),
        "id as str": ("answer", _answer(rid, entry, id=str(rid)), "type"),
        "stamp as int": ("answer", _answer(rid, {**entry, "s": 2}), "type"),
        "stamp nan": ("answer", _answer(rid, {**entry, "s": math.nan}), "range"),
        "negative region": ("answer", _answer(rid, {**entry, "r": -1}), "range"),
        "uid as float": ("answer", _answer(rid, {**entry, "short": [1.5]}), "type"),
        "uid of another robot": (
            "answer",
            _answer(rid, {**entry, "short": [make_uid(3, 0)]}),
            "inconsistent",
        ),
        "uid twice": (
            "answer",
            _answer(rid, {**entry, "short": [make_uid(1, 0)] * 2}),
            "duplicate",
        ),
        "garbage pose": ("answer", _answer(rid, {**entry, "poses": [b"\x93\x01"]}), "record"),
        "pose as str": ("answer", _answer(rid, {**entry, "poses": ["pose"]}), "type"),
        "edge for a pose": (
            "answer",
            _answer(rid, {**entry, "edges": [entry["poses"][0]]}),
            "record",
        ),
        "pose in another region": (
            "answer",
            _answer(rid, {**entry, "poses": [*entry["poses"], encode(wrong_region)]}),
            "inconsistent",
        ),
        "pose not in the list": (
            "answer",
            _answer(rid, {**entry, "short": [make_uid(1, 0)]}),
            "inconsistent",
        ),
        # One good patch and one bad: nothing of the message is applied.
        "second patch bad": (
            "answer",
            _answer(rid, entry, {**_good_entry(b, [2], 1), "poses": [b"junk"]}),
            "record",
        ),
        "limited answer": ("answer", _answer(rid, entry, mode="limited"), "inconsistent"),
        "unknown id": ("answer", _answer(rid + 50, entry), "unsolicited"),
        "patch not asked": ("answer", _answer(rid, _good_entry(b, [2], 1)), "unsolicited"),
        "own poses": (
            "answer",
            _answer(
                rid,
                {**entry, "src": 0, "short": [a_pose.uid], "poses": [encode(a_pose)], "edges": []},
            ),
            "own",
        ),
        "advert row short": ("advert", pack({"v": VERSION, "patches": [[1, 0, 2.0]]}), "type"),
        "advert stamp inf": (
            "advert",
            pack({"v": VERSION, "patches": [[1, 0, math.inf, 1]]}),
            "range",
        ),
        "advert twice": (
            "advert",
            pack({"v": VERSION, "patches": [[1, 0, 1.0, 1]] * 2}),
            "duplicate",
        ),
        "request no patches": (
            "request",
            pack({"v": VERSION, "id": 0, "mode": "good", "patches": []}),
            "range",
        ),
        "request full in good": (
            "request",
            encode_request(
                Request(0, "good", (PatchRequest(0, 0, None, frozenset(), frozenset()),))
            ),
            "inconsistent",
        ),
        "request for the asker's own poses": (
            "request",
            encode_request(Request(0, "good", (PatchRequest(1, 0, None, frozenset()),))),
            "own",
        ),
        "request of the other mode": (
            "request",
            encode_request(
                Request(0, "limited", (PatchRequest(0, 0, None, frozenset(), frozenset()),))
            ),
            "mode",
        ),
        "request fingerprints cut": ("request", _request_body(e=b"\x00" * 7), "range"),
        "request fingerprints as str": ("request", _request_body(e="0" * 8), "type"),
        "request without fingerprints": ("request", _request_body(drop=("e",)), "keys"),
        "unknown kind": ("gossip", good, "kind"),
    }


def test_bad_bodies_are_rejected_counted_logged_and_change_nothing(
    asking: tuple[Exchanger, SimTransport, RobotStore, int], caplog: pytest.LogCaptureFixture
) -> None:
    ex, tb, b, rid = asking
    a = ex.store
    bad = _bad_bodies(b, rid)
    before = snapshot(a)
    expected: dict[str, int] = defaultdict(int)
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        for name, (kind, body, reason) in bad.items():
            assert tb.send(0, body, kind=kind), name
            expected[reason] += 1
            ex.step(ex.now)
            assert ex.stats.rejected == expected, name
            assert snapshot(a) == before, name
    records = [r for r in caplog.records if r.name == LOGGER]
    assert len(records) == len(bad)
    assert all("\n" not in r.getMessage() for r in records)
    assert all("robot 0 rejected a" in r.getMessage() for r in records)
    assert ex.outstanding  # still waiting for the real answer
    # The real answer is still taken afterwards.
    tb.send(0, _answer(rid, _good_entry(b, [0, 1])), kind="answer")
    ex.step(ex.now)
    assert uids(a.received[1]) == {make_uid(1, 0), make_uid(1, 1)}
    assert not ex.outstanding
    check_consistent(a)


def test_bad_closures_are_rejected_counted_logged_and_change_nothing(
    asking: tuple[Exchanger, SimTransport, RobotStore, int], caplog: pytest.LogCaptureFixture
) -> None:
    ex, tb, b, rid = asking
    a = ex.store
    bad = _bad_closure_bodies(rid, _good_entry(b, [0, 1]))
    before = snapshot(a)
    expected: dict[str, int] = defaultdict(int)
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        for name, (kind, body, reason) in bad.items():
            assert tb.send(0, body, kind=kind), name
            expected[reason] += 1
            ex.step(ex.now)
            assert ex.stats.rejected == expected, name
            assert snapshot(a) == before, name
    records = [r for r in caplog.records if r.name == LOGGER]
    assert len(records) == len(bad)
    assert all(".c[" in r.getMessage() or ".c:" in r.getMessage() for r in records)
    assert ex.outstanding
    # The real answer, with a good closure, is still taken afterwards.
    tb.send(0, _answer(rid, {**_good_entry(b, [0, 1]), "c": [_closure_row()]}), kind="answer")
    ex.step(ex.now)
    assert uids(a.received[1]) == {make_uid(1, 0), make_uid(1, 1)}
    assert len(a.closures) == 1
    check_consistent(a)


def test_a_peers_closure_is_taken_once_whichever_way_and_however_often_it_comes(
    asking: tuple[Exchanger, SimTransport, RobotStore, int],
) -> None:
    ex, tb, b, rid = asking
    a = ex.store
    entry = _good_entry(b, [0, 1])
    # A closure to A's own pose, and one to a pose of robot 2 that A does not hold.
    rows = [_closure_row(), _closure_row(b=make_uid(2, 9))]
    tb.send(0, _answer(rid, {**entry, "c": rows}), kind="answer")
    ex.step(ex.now)
    assert not ex.stats.rejected
    (got,) = a.closures
    assert (got.a, got.b, got.inliers, got.matches) == (make_uid(1, 0), make_uid(0, 0), 12, ())
    assert got.transform == pytest.approx((0.5, -0.02, 0.01))
    assert got.cov() == pytest.approx(np.diag([1e-4, 1e-4, 1e-5]), rel=1e-6)
    assert (ex.stats.closures_received, ex.stats.closures_added) == (2, 1)
    assert ex.stats.closures_unheld == 1
    check_consistent(a)
    # The same closure again, and the other way round (as the receiver would find it
    # itself, or a peer would send it back): one factor still.
    back = ClosureEdge(got.b, got.a, (-0.5, 0.02, -0.01), got.covariance, 9, 0.1)
    before = snapshot(a)
    assert a.add_peer_closures([got, back]) == (0, 2, 0)
    assert snapshot(a) == before


def test_a_closure_pcm_rejected_is_not_taken_back_from_a_peer(
    asking: tuple[Exchanger, SimTransport, RobotStore, int],
) -> None:
    ex, tb, b, rid = asking
    a = ex.store
    tb.send(0, _answer(rid, {**_good_entry(b, [0, 1]), "c": [_closure_row()]}), kind="answer")
    ex.step(ex.now)
    (got,) = a.closures
    # Pairwise consistency rejects it (as MissionRobot._pcm does): the pair is counted
    # once however often it is rejected, and a peer cannot bring it back either way.
    a.closures = []
    assert a.reject_closures([got]) == [got]
    back = ClosureEdge(got.b, got.a, (-0.5, 0.02, -0.01), got.covariance, 9, 0.1)
    assert a.reject_closures([back]) == []
    assert a.add_peer_closures([got, back]) == (0, 2, 0)
    assert a.closures == []
    # The rejected pairs survive state()/restore(); a state saved before they were kept
    # restores with none.
    state = a.state()
    a.restore(state)
    assert a.add_peer_closures([got]) == (0, 1, 0)
    old = {k: v for k, v in state.items() if k != "rejected_pairs"}
    a.restore(old)
    assert a.add_peer_closures([got]) == (1, 0, 0)


def test_decoders_raise_an_input_error_with_the_reason() -> None:
    with pytest.raises(ExchangeError, match="the body ends early") as err:
        decode_answer(encode_answer(Answer(1, "good", ()))[:-1])
    assert err.value.code == "truncated"
    assert isinstance(err.value, InputError)
    entry = PatchAnswer(1, 0, 1.0, frozenset({make_uid(1, 0)}), None, (pose(1, 0, 0, 0.0),))
    assert decode_answer(encode_answer(Answer(3, "good", (entry,)))).patches[0].poses[0].uid == (
        make_uid(1, 0)
    )
    with pytest.raises(ExchangeError, match="not robot 1's"):
        decode_request(
            encode_request(Request(0, "good", (PatchRequest(1, 0, None, frozenset({5})),)))
        )


def test_an_answer_older_than_the_patch_is_not_applied(
    asking: tuple[Exchanger, SimTransport, RobotStore, int],
) -> None:
    ex, tb, b, rid = asking
    a = ex.store
    # Meanwhile A got robot 1's region 0 newer (t=50) from elsewhere: only pose 0.
    a.add_received_pose(1, b.local.poses[make_uid(1, 0)], [], [], 0.0)
    a.received[1].patches[0].stamp = 50.0
    a.received[1].patches[0].full = {make_uid(1, 0)}
    before = snapshot(a)
    tb.send(0, _answer(rid, _good_entry(b, [1])), kind="answer")  # stamped 2.0
    ex.step(ex.now)
    assert ex.stats.stale == 1
    assert not ex.stats.rejected
    assert snapshot(a) == before
    assert not ex.outstanding


# --- what answers carry, and when patches are asked for -----------------------------------


def _answer_rows(bodies: Sequence[bytes]) -> list[dict[str, Any]]:
    return [row for body in bodies for row in msgpack.unpackb(inflate(body), raw=False)["patches"]]


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_answers_do_not_repeat_the_edges_the_requester_holds(mode: str) -> None:
    a, b = own_store(0, [0]), own_store(1, [0, 0, 0, 0])
    team = Team([a, b], mode=mode, cap_bytes=10**6)
    team.run(6)
    assert converged(team)
    answers = record_sends(team.transports[1])
    new = add_own(b, 4, 0, team.hub.now)
    team.run(4)
    assert converged(team)
    rows = [r for r in _answer_rows(answers) if r["poses"]]
    assert len(rows) == 1
    # Only the new pose's edge, not the patch's four.
    (edge,) = [decode(e) for e in rows[0]["edges"]]
    assert isinstance(edge, OdometryEdge)
    assert edge.b == new.uid
    assert {(e.a, e.b) for e in a.received[1].edges} == {(e.a, e.b) for e in b.local.edges}


@pytest.mark.parametrize("regions", [[0, 0, 0, 0], [0, 1, 2, 2]], ids=["one", "three"])
def test_a_chaining_edge_reaches_a_requester_holding_both_ends(regions: list[int]) -> None:
    a, b = own_store(0, [3]), own_store(1, regions)
    team = Team([a, b])
    team.run(6)
    assert converged(team)
    first, gone, last = make_uid(1, 0), make_uid(1, 1), make_uid(1, 2)
    b.delete_pose(gone, team.hub.now)  # chains first -> last, maybe across regions
    assert any((e.a, e.b) == (first, last) for e in b.local.edges)
    answers = record_sends(team.transports[1])
    team.run(6)
    assert converged(team)
    assert {(e.a, e.b) for e in a.received[1].edges} == {(e.a, e.b) for e in b.local.edges}
    assert all(not r["poses"] for r in _answer_rows(answers))  # edges came without poses
    check_consistent(a)


def test_refresh_delays_patches_not_wanted_and_the_quiet_network_converges() -> None:
    a, b = own_store(0, [0]), own_store(1, [1, 2])
    team = Team([a, b], refresh=20.0)
    team.run(4, wanted=[0])
    assert converged(team)  # never asked for: at once
    asked: dict[int, int] = defaultdict(int)
    requests = record_sends(team.transports[0], ("request",))
    for k in range(10):  # B maps regions 1 and 2, one pose a second in each
        add_own(b, 10 + 2 * k, 1, team.hub.now)
        add_own(b, 11 + 2 * k, 2, team.hub.now)
        team.run(2, wanted=[0, 2])  # A heads for region 2, not 1
    for body in requests:
        for p in decode_request(body).patches:
            asked[p.region] += 1
    assert asked[1] <= 1  # once per refresh at most
    assert asked[2] >= 8  # wanted: each time it is newer
    assert uids(a.received[1]) != uids(b.local)
    team.run(4)  # no plan any more (None): everything newer at once
    assert converged(team)
    check_consistent(a)


def test_limited_mode_below_one_pose_stops_asking_and_sends_no_edges() -> None:
    a, b = own_store(0, [0]), own_store(1, [0, 0, 1, 1])
    team = Team([a, b], mode="limited", cap_bytes=16, backoff=30.0)
    answers = record_sends(team.transports[1])
    team.run(10)
    first = team.ex[0].stats.requests_sent
    assert not a.received.get(1) or not a.received[1].poses  # nothing fits under T
    assert a.received[1].patches[0].full == b.local.patches[0].short  # but the lists came
    team.run(40)  # 20 s: neither side changes, so nobody asks again
    assert team.ex[0].stats.requests_sent == first <= 4
    assert all(not r["poses"] and not r["edges"] for r in _answer_rows(answers))
    team.run(30)  # after the backoff, asked again once
    assert first < team.ex[0].stats.requests_sent <= first + 2


# --- losses and vanishing peers -----------------------------------------------------------


def test_a_lost_answer_is_asked_for_again_after_the_timeout() -> None:
    a, b = own_store(0, [0]), own_store(1, [0, 1])
    team = Team([a, b])
    dropped = drop_sends(team.transports[1], "answer", 1)
    team.run(2)  # adverts, then A's request; B's answer is lost
    assert len(dropped) == 1
    assert team.ex[0].stats.requests_sent == 1
    assert team.ex[0].outstanding
    team.run(int(team.params.request_timeout / DT) - 1)  # deduplicated while outstanding
    assert team.ex[0].stats.requests_sent == 1
    assert 1 not in a.received
    team.run(3)
    assert team.ex[0].stats.retries >= 1
    assert team.ex[0].stats.requests_sent == 2
    assert converged(team)


def test_a_peer_vanishing_mid_answer_leaves_the_store_whole() -> None:
    a = own_store(0, [0])
    b = own_store(1, [0, 0, 0, 1, 1, 1, 2, 2, 2])
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    ta = hub.transport(0)
    # B's messages are small: its answer leaves in several parts, one patch each.
    tb = hub.transport(1, max_message=3000)
    params = ExchangeParams(**FAST)  # type: ignore[arg-type]
    ea, eb = Exchanger(a, ta, params), Exchanger(b, tb, params)
    parts: list[bytes] = []
    send = tb.send

    def vanishing(dst: int, payload: bytes, kind: str = "data") -> bool:
        if kind == "answer":
            parts.append(payload)
            if len(parts) == 2:
                tb.close()  # B is gone after the first part of its answer
        return send(dst, payload, kind)

    tb.send = vanishing  # type: ignore[method-assign]
    for _ in range(2):
        hub.step(DT)
        ea.step(hub.now)
        eb.step(hub.now)
    hub.step(DT)
    ea.step(hub.now)
    assert len(parts) >= 2
    assert [r["r"] for r in msgpack.unpackb(inflate(parts[0]), raw=False)["patches"]] == [0]
    layer = a.received[1]
    assert set(layer.poses) == set(b.local.patches[0].short)  # the first part, whole
    assert all(p.short == p.full for p in layer.patches.values())
    check_consistent(a)
    assert ea.outstanding  # regions 1 and 2 still awaited
    for _ in range(int(params.request_timeout / DT) + 2):
        hub.step(DT)
        ea.step(hub.now)
    assert ea.stats.retries >= 1  # asked again after the timeout
    assert set(layer.poses) == set(b.local.patches[0].short)
    check_consistent(a)


# --- parameters ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"mode": "bad"}, "mode"),
        ({"cap_bytes": 0}, "cap_bytes"),
        ({"cap_bytes": 1.5}, "cap_bytes"),
        ({"advert_every": math.inf}, "advert_every"),
        ({"request_every": -1.0}, "request_every"),
        ({"max_patches": True}, "max_patches"),
        ({"peer_timeout": 1.0, "advert_every": 2.0}, "peer_timeout"),
    ],
)
def test_bad_params_name_the_field(kwargs: dict[str, Any], name: str) -> None:
    with pytest.raises(ConfigError, match=rf"\b{name}\b"):
        ExchangeParams(**kwargs)


def test_the_exchanger_checks_its_inputs() -> None:
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    with pytest.raises(ConfigError, match="robot 1's"):
        Exchanger(RobotStore(0), hub.transport(1))
    ex = Exchanger(RobotStore(0), hub.transport(0))
    ex.step(2.0)
    with pytest.raises(InputError, match="time goes back"):
        ex.step(1.0)
    with pytest.raises(InputError, match="field 'now'"):
        ex.step(math.nan)


# --- the lean exchange: a hold on young poses, landmarks only on anchors ----------------------


def _answered(bodies: Sequence[bytes]) -> list[Pose]:
    return [p for b in bodies for e in decode_answer(b).patches for p in e.poses]


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_a_hold_keeps_young_poses_home_until_they_age_or_the_mission_ends(mode: str) -> None:
    a = own_store(0, [0, 0, 1])  # poses made at 0, 1 and 2 s
    b = own_store(1, [2], t0=0.5)
    team = Team([a, b], mode=mode, cap_bytes=10**6, hold=10.0)
    before = snapshot(a)[2]
    team.run(8)  # to 4 s: nothing of a's is 10 s old
    assert uids(b.received.get(0)) == uids(a.received.get(1)) == set()
    team.run(20)  # to 14 s
    assert uids(b.received[0]) == uids(a.local)
    assert {(e.a, e.b) for e in b.received[0].edges} == {(e.a, e.b) for e in a.local.edges}
    young = add_own(a, 3, 1, team.hub.now)
    team.run(6)
    assert young.uid not in uids(b.received[0])
    # What was offered is shared (the store's fold leaves it as sent); the young one not.
    assert all(a.shared(u) for u in uids(b.received[0]))
    assert not a.shared(young.uid)
    team.ex[0].finish()  # the mission is over: everything goes, however young
    team.run(6)
    assert uids(b.received[0]) == uids(a.local)
    assert a.shared(young.uid)
    assert snapshot(a)[2][0] == {**before[0], young.uid: encode(young)}
    for s in (a, b):
        check_consistent(s)
    assert all(not ex.stats.rejected for ex in team.ex)


def test_a_pose_deleted_within_its_hold_never_travels_and_deletions_still_do() -> None:
    a = own_store(0, [0, 1, 0, 0])
    b = own_store(1, [2])
    team = Team([a, b], hold=5.0)
    answers = record_sends(team.transports[0])
    team.run(20)  # to 10 s: all four out
    assert uids(b.received[0]) == uids(a.local)
    brief = add_own(a, 4, 0, team.hub.now)
    team.run(2)
    a.delete_pose(brief.uid, team.hub.now)  # region compression, within the hold
    # And an old, published pose, alone in its region: the edge chaining its neighbours
    # changes region 0 only.
    a.delete_pose(make_uid(0, 1), team.hub.now)
    team.run(16)
    assert brief.uid not in {p.uid for p in _answered(answers)}
    assert uids(b.received[0]) == uids(a.local)  # the old one's deletion reached b
    # The edge that chains around the deleted pose came too.
    assert {(e.a, e.b) for e in b.received[0].edges} == {(e.a, e.b) for e in a.local.edges}
    check_consistent(b)


def test_without_a_hold_a_pose_travels_at_once() -> None:
    a, b = own_store(0, [0]), own_store(1, [1])
    team = Team([a, b])
    team.run(4)
    assert uids(b.received[0]) == uids(a.local)
    assert all(a.shared(u) for u in uids(a.local))


@pytest.mark.parametrize("mode", ["good", "limited"])
def test_only_anchors_travel_with_their_landmarks(mode: str) -> None:
    a = own_store(0, [0] * 10, n=30)
    b = own_store(1, [1])
    lean = Team([a, b], mode=mode, cap_bytes=10**6, anchor_every=4)
    before = snapshot(a)[2]
    sent = record_sends(lean.transports[0])
    lean.run(10)
    got = b.received[0].poses
    assert set(got) == uids(a.local)
    for u, p in got.items():
        anchor = (u & ((1 << 40) - 1)) % 4 == 0
        assert len(p.landmarks) == (30 if anchor else 0)
        assert np.array_equal(p.local_map is None, a.local.poses[u].local_map is None)
        assert np.array_equal(p.estimate, a.local.poses[u].estimate)
    assert sum(1 for u in got if len(got[u].landmarks)) == 3  # counters 0, 4 and 8
    assert snapshot(a)[2] == before  # the source's own poses keep their landmarks
    # The same exchange with every pose whole costs several times the bytes.
    a2, b2 = own_store(0, [0] * 10, n=30), own_store(1, [1])
    whole = Team([a2, b2], mode=mode, cap_bytes=10**6)
    sent2 = record_sends(whole.transports[0])
    whole.run(10)
    assert sum(map(len, sent)) < 0.5 * sum(map(len, sent2))


def test_merged_poses_are_always_anchors() -> None:
    from sonarmap.team.anchors import is_anchor

    p = pose(0, 3, 0, 0.0)
    assert not is_anchor(p, 2)
    p.merged_from = (make_uid(0, 1), make_uid(0, 2))
    assert is_anchor(p, 2)
    assert is_anchor(p, 1000)


def test_the_limited_cap_counts_poses_as_they_travel() -> None:
    # Poses of about 4 kB each, 140 bytes or so without their landmarks; T = 2 kB.
    def run(anchor_every: int) -> set[int]:
        a, b = own_store(0, [0] * 6, n=30), own_store(1, [1])
        team = Team([a, b], mode="limited", cap_bytes=2000, anchor_every=anchor_every)
        team.run(12)
        return uids(b.received.get(0))

    assert run(1) == set()  # starved: no whole pose fits
    got = run(1000)  # only counter 0 is an anchor, and it does not fit either
    assert got == {make_uid(0, k) for k in range(1, 6)}


@pytest.mark.parametrize(
    "bad", [{"anchor_every": 0}, {"anchor_every": 2.5}, {"hold": -1.0}, {"hold": math.inf}]
)
def test_bad_lean_settings_are_refused(bad: dict[str, Any]) -> None:
    with pytest.raises(ConfigError):
        ExchangeParams(**bad)


def test_an_answer_carries_only_the_edges_the_requester_lacks() -> None:
    a = own_store(0, [0] * 8)
    b = own_store(1, [1])
    team = Team([a, b])
    team.run(6)
    assert uids(b.received[0]) == uids(a.local)
    answers = record_sends(team.transports[0])
    a.delete_pose(make_uid(0, 3), team.hub.now)  # chains poses 2 and 4 by a new edge
    team.run(6)
    sent = [e for body in answers for p in decode_answer(body).patches for e in p.edges]
    chained = {(e.a, e.b) for e in a.local.edges} - {(e.a, e.b) for e in b.received[0].edges}
    assert chained == set()  # b has the new edge...
    assert [(e.a, e.b) for e in sent] == [(make_uid(0, 2), make_uid(0, 4))]  # ...and no other


def test_edge_fingerprints_ignore_order_and_tell_remade_edges_apart() -> None:
    from sonarmap.team.wire import edge_fingerprint, edge_fingerprints

    p, q, r = pose(0, 0, 0, 0.0), pose(0, 1, 0, 1.0), pose(0, 2, 0, 2.0)
    e1, e2 = odometry(p, q), odometry(q, r)
    assert edge_fingerprints([e1, e2]) == edge_fingerprints([e2, e1, e2])
    remade = OdometryEdge(e1.a, e1.b, (e1.transform[0] + 1e-5, *e1.transform[1:]), COV, 10.0)
    assert edge_fingerprint(remade) != edge_fingerprint(e1)


def test_bodies_are_compressed_with_the_preset_dictionary() -> None:
    advert = Advert((AdvertEntry(1, 0, 2.0, 2), AdvertEntry(2, 3, 4.0, 1)), t=5.0)
    body = encode_advert(advert)
    plain = _zstd(inflate(body), level=ZSTD_LEVEL)
    assert len(body) < len(plain)
    with pytest.raises(zstandard.ZstdError):
        zstandard.ZstdDecompressor().decompress(body)  # a reader without the dictionary
    assert decode_advert(plain) == decode_advert(body) == advert


@pytest.mark.parametrize("mode", ["good", "limited"])
@pytest.mark.parametrize("send", [True, False])
def test_a_sources_closures_travel_with_its_poses_only_when_asked(mode: str, send: bool) -> None:
    a, c = own_store(0, [0, 1]), own_store(2, [1])
    b = own_store(1, [0, 0, 1, 0])
    loop = ClosureEdge(make_uid(1, 0), make_uid(1, 3), (3.0, 0.0, 0.0), COV, 15, 0.2)
    b.closures.append(loop)
    team = Team([a, b, c], mode=mode, cap_bytes=10**6, send_closures=send)
    team.run(12)
    assert converged(team)
    for s in (a, c):
        check_consistent(s)
        got = [x for x in s.closures if {x.a, x.b} == {loop.a, loop.b}]
        assert len(got) == (1 if send else 0)  # one factor, though relays may send it too
        if send:
            assert got[0].transform == pytest.approx(loop.transform, abs=1e-3)
    assert (team.ex[1].stats.closures_sent > 0) == send
    assert sum(e.stats.closures_added for e in team.ex) == (2 if send else 0)


def test_a_sender_sends_only_closures_the_receiver_takes_each_once_an_answer() -> None:
    a = own_store(0, [0])
    b = own_store(1, [0, 0, 1, 1])
    good = ClosureEdge(make_uid(1, 0), make_uid(1, 3), (3.0, 0.0, 0.0), COV, 15, 0.2)
    # Finite and positive definite, so the store takes it, but nearly singular: a
    # receiver refuses it, and with it the answer.
    thin = np.array([[1e-4, 1e-4 * (1 - 2e-7), 0], [1e-4 * (1 - 2e-7), 1e-4, 0], [0, 0, 1e-4]])
    bad = ClosureEdge(make_uid(1, 1), make_uid(1, 2), (1.0, 0.0, 0.0), tuple(thin.ravel()), 9, 0.1)
    b.closures.extend([good, bad])
    team = Team([a, b], send_closures=True, cap_bytes=10**6)
    answers = record_sends(team.transports[1])
    team.run(12)
    assert converged(team)
    assert not team.ex[0].stats.rejected
    assert team.ex[1].stats.closures_withheld > 0
    assert [(x.a, x.b) for x in a.closures] == [(good.a, good.b)]
    check_consistent(a)
    # The good closure joins region 0's pose 0 to region 1's pose 3: both regions go in
    # one answer, the closure in only one of its entries.
    bodies = [decode_answer(body) for body in answers]
    both = [x for x in bodies if {e.region for e in x.patches if e.poses} == {0, 1}]
    assert both
    for x in both:
        assert sum(len(e.closures) for e in x.patches) == 1
    assert team.ex[0].stats.closures_unheld == 0
