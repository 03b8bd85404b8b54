"""Anchors: which own poses travel with their landmarks (sonarmap.team.anchors), and the
exchange carrying them (loop anchors on the source, relays forwarding poses as received)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.team.anchors import AnchorChooser
from sonarmap.team.exchange import ExchangeParams, Exchanger
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.records import ClosureEdge, counter_of, make_uid
from sonarmap.team.store import MERGE_COUNTER_BASE, RobotStore
from sonarmap.team.transport import SimHub
from test_team_exchange import BIG, COV, DT, FAST, odometry, pose


def closure(a: int, b: int) -> ClosureEdge:
    return ClosureEdge(a, b, (0.5, 0.0, 0.0), COV, 9, 0.1, ())


def own(k: int) -> int:
    return make_uid(0, k)


def chosen(chooser: AnchorChooser) -> list[int]:
    return sorted(counter_of(u) for u in chooser.anchors)


def test_every_kth_pose_is_an_anchor_without_loops() -> None:
    ch = AnchorChooser(0, every=4)
    ch.choose([own(k) for k in range(10)], [closure(own(k - 1), own(k)) for k in range(1, 10)])
    assert chosen(ch) == [0, 4, 8]
    assert ch.decided == 9


def test_merged_poses_go_by_their_counter_when_merges_are_common() -> None:
    from sonarmap.team.anchors import is_anchor
    from sonarmap.team.records import Landmarks, Pose

    def merged(m: int) -> Pose:
        uid = make_uid(0, MERGE_COUNTER_BASE + m)
        return Pose(uid, 0.0, 0, np.zeros(3), Landmarks.empty(), None, (1, 2))

    assert is_anchor(merged(3), 8)
    assert is_anchor(merged(0), 8)
    assert not is_anchor(merged(3), 8, merged_whole=False)
    assert is_anchor(merged(16), 8, merged_whole=False)
    assert is_anchor(merged(3), 1, merged_whole=False)


def test_a_return_to_an_old_anchor_makes_an_anchor() -> None:
    ch = AnchorChooser(0, every=4)
    loops = [
        closure(own(0), own(12)),  # back at anchor 0, 12 poses later: a loop
        closure(own(1), own(13)),  # back at pose 1, which travels bare: no receiver can close it
        closure(own(8), own(10)),  # anchor 8 only 2 poses back: the path, not a loop
    ]
    ch.choose([own(k) for k in range(14)], loops)
    assert chosen(ch) == [0, 4, 8, 12]
    ch2 = AnchorChooser(0, every=4)
    ch2.choose([own(k) for k in range(14)], [*loops, closure(own(0), own(11))])
    assert chosen(ch2) == [0, 4, 8, 11, 12]


def test_a_meeting_and_a_merged_pose_make_anchors() -> None:
    ch = AnchorChooser(0, every=4)
    merged = make_uid(0, MERGE_COUNTER_BASE + 2)
    ch.choose(
        [own(k) for k in range(8)],
        [closure(make_uid(3, 7), own(2)), closure(merged, own(5))],
    )
    assert chosen(ch) == [0, 2, 4, 5]


def test_a_choice_is_made_once_and_survives_a_checkpoint() -> None:
    ch = AnchorChooser(0, every=4)
    ch.choose([own(k) for k in range(6)], [closure(make_uid(1, 0), own(3))])
    assert chosen(ch) == [0, 3, 4]
    # Later closures (or closures dropped by the graph) do not change what was decided.
    assert ch.pending([own(k) for k in range(8)]) == [own(6), own(7)]
    again = AnchorChooser(0, every=4)
    again.restore(ch.state())
    again.choose([own(6), own(7)], [closure(make_uid(1, 0), own(3)), closure(own(0), own(7))])
    assert chosen(again) == [0, 3, 4, 7]
    with pytest.raises(ValueError, match="every"):
        AnchorChooser(0, every=0)


def test_loop_anchors_must_be_a_boolean() -> None:
    with pytest.raises(ConfigError, match="loop_anchors"):
        ExchangeParams(loop_anchors=1)  # type: ignore[arg-type]


def _source(n: int = 12) -> RobotStore:
    """Robot 0's poses 0..n-1 of 30 landmarks; pose 5 closed with robot 2's pose and
    pose 10 came back to pose 0."""
    store = RobotStore(0, BIG)
    last = None
    loops = {5: [closure(make_uid(2, 0), own(5))], 10: [closure(own(0), own(10))]}
    for k in range(n):
        p = pose(0, k, 0, float(k), 30)
        store.add_own_pose(p, None if last is None else odometry(last, p), loops.get(k, []), k)
        last = p
    return store


@pytest.mark.parametrize("loop_anchors", [False, True])
def test_loop_anchors_travel_whole_and_relays_forward_them_as_received(
    loop_anchors: bool,
) -> None:
    # A chain 0 - 1 - 2: robot 2 gets robot 0's poses from robot 1 only.
    stores = [_source(), RobotStore(1, BIG), RobotStore(2, BIG)]
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 3))
    reach = {0: [1], 1: [0, 2], 2: [1]}
    params = ExchangeParams(**FAST, anchor_every=4, loop_anchors=loop_anchors)  # type: ignore[arg-type]
    exs = [Exchanger(s, hub.transport(s.robot), params, peers=reach[s.robot].copy) for s in stores]
    for _ in range(24):
        hub.step(DT)
        for ex in exs:
            ex.step(hub.now)
    want = [0, 4, 5, 8, 10] if loop_anchors else [0, 4, 8]
    for holder in stores[1:]:
        got = holder.received[0].poses
        assert set(got) == set(stores[0].local.poses)
        assert sorted(counter_of(u) for u, p in got.items() if len(p.landmarks)) == want
        assert all(len(p.landmarks) in (0, 30) for p in got.values())
    # The source keeps every landmark of its own.
    assert all(len(p.landmarks) == 30 for p in stores[0].local.poses.values())
    if loop_anchors:
        assert np.array_equal(
            stores[2].received[0].poses[own(5)].landmarks.points,
            stores[0].local.poses[own(5)].landmarks.points,
        )


def test_a_checkpoint_keeps_the_anchors_chosen() -> None:
    import msgpack

    def exchanger(store: RobotStore) -> Exchanger:
        hub = SimHub(SimNetwork(NetworkParams(kind="full"), 3))
        return Exchanger(store, hub.transport(0), ExchangeParams(anchor_every=4, loop_anchors=True))

    e = exchanger(_source())
    e.step(1.0)
    assert e.outgoing.chooser is not None
    assert chosen(e.outgoing.chooser) == [0, 4, 5, 8, 10]
    state = msgpack.unpackb(msgpack.packb(e.state()), raw=False)
    # Restored onto a store whose closures were since dropped (as the graph may): the
    # poses already decided keep their choice.
    bare = _source()
    bare.closures.clear()
    back = exchanger(bare)
    back.restore(state)
    back.step(2.0)
    assert back.outgoing.chooser is not None
    assert chosen(back.outgoing.chooser) == [0, 4, 5, 8, 10]


@pytest.mark.parametrize(
    ("naive", "want"),
    [
        (0.0, [0, 4, 8]),  # nothing to spend: the anchors by counter only
        (1e12, list(range(12))),  # far under the target: every pose whole
    ],
)
def test_the_byte_target_adds_whole_poses_while_under_it(naive: float, want: list[int]) -> None:
    stores = [_source(), RobotStore(1, BIG)]
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    params = ExchangeParams(**FAST, anchor_every=4, anchor_share=0.2)  # type: ignore[arg-type]
    exs = [Exchanger(s, hub.transport(s.robot), params, naive_bytes=lambda: naive) for s in stores]
    for _ in range(16):
        hub.step(DT)
        for ex in exs:
            ex.step(hub.now)
    got = stores[1].received[0].poses
    assert set(got) == set(stores[0].local.poses)
    assert sorted(counter_of(u) for u, p in got.items() if len(p.landmarks)) == want


def test_the_byte_target_decides_each_pose_once_and_keeps_it_in_a_checkpoint() -> None:
    import msgpack

    spent = [1e12]
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    params = ExchangeParams(anchor_every=4, anchor_share=0.5)
    e = Exchanger(_source(), hub.transport(0), params, naive_bytes=lambda: spent[0])
    p1, p2 = (e.store.local.poses[own(k)] for k in (1, 2))
    assert e.outgoing.travels_whole(p1)
    spent[0] = 0.0  # over the target from now on
    assert e.outgoing.travels_whole(p1)  # decided
    assert not e.outgoing.travels_whole(p2)
    state = msgpack.unpackb(msgpack.packb(e.state()), strict_map_key=False)
    hub2 = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    fresh = Exchanger(_source(), hub2.transport(0), params, naive_bytes=lambda: 1e12)
    fresh.restore(state)
    assert fresh.outgoing.travels_whole(p1)
    assert not fresh.outgoing.travels_whole(p2)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"anchor_every": 4, "anchor_share": 1.5}, "anchor_share"),
        ({"anchor_every": 4, "anchor_share": -0.1}, "anchor_share"),
        ({"anchor_share": 0.2}, "anchor_every > 1"),
    ],
)
def test_bad_byte_targets_are_refused(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ExchangeParams(**kwargs)  # type: ignore[arg-type]


def test_a_byte_target_needs_the_baselines_bytes() -> None:
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    with pytest.raises(ConfigError, match="naive_bytes"):
        Exchanger(RobotStore(0), hub.transport(0), ExchangeParams(anchor_every=4, anchor_share=0.2))


def test_the_byte_target_follows_the_baseline_a_hold_behind() -> None:
    # With a 5 s hold nothing is offered in the first 5 s, while the baseline would
    # already have sent: the target counts the baseline as it was 5 s before.
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    params = ExchangeParams(anchor_every=4, anchor_share=0.5, hold=5.0)
    e = Exchanger(_source(), hub.transport(0), params, naive_bytes=lambda: 1e12)
    e.step(0.0)
    e.step(3.0)
    assert not e.outgoing.travels_whole(e.store.local.poses[own(1)])
    e.step(6.0)
    assert e.outgoing.travels_whole(e.store.local.poses[own(2)])


def _finished_exchanger(naive: Callable[[], float]) -> Exchanger:
    """Robot 0's exchanger with a byte target, its pose 1 decided during the mission."""
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    params = ExchangeParams(anchor_every=4, anchor_share=0.5)
    e = Exchanger(_source(), hub.transport(0), params, naive_bytes=naive)
    e.step(0.0)
    assert e.outgoing.travels_whole(e.store.local.poses[own(1)])
    e.finish()
    e.step(1.0)
    return e


def test_after_the_mission_the_byte_target_still_spends_what_it_has() -> None:
    e = _finished_exchanger(lambda: 1e12)
    assert all(e.outgoing.travels_whole(e.store.local.poses[own(k)]) for k in (1, 2, 3, 4))
    assert e.outgoing.end_spent > 0


def test_after_the_mission_each_whole_pose_counts_at_once() -> None:
    # The last hold's poses are decided in one batch before any is sent. With room for
    # one pose's landmarks, the first goes whole and the next bare, though nothing more
    # has been sent between the two decisions.
    cost = _finished_exchanger(lambda: 1e12)
    p2, p3 = (cost.store.local.poses[own(k)] for k in (2, 3))
    assert cost.outgoing.travels_whole(p2)
    one = cost.outgoing.end_spent
    room = [1e12]
    e = _finished_exchanger(lambda: room[0])
    room[0] = (e.stats.bytes_sent + 1.5 * one) / e.params.anchor_share
    assert e.outgoing.travels_whole(p2)
    assert e.outgoing.end_spent == one
    assert not e.outgoing.travels_whole(p3)
    assert e.outgoing.travels_whole(e.store.local.poses[own(1)])  # decided before: kept
    assert e.outgoing.travels_whole(e.store.local.poses[own(4)])  # an anchor by its counter
