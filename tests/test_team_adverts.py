"""Delta adverts (``ExchangeParams.full_advert_every``): between whole tables a peer is
sent only the rows changed since the last whole one; the receiver's table follows the
sender's, a lost advert leaves rows stale but never wrong, and a peer newly in reach
gets the whole table."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from sonarmap.team.exchange import (
    ExchangeParams,
    Exchanger,
)
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.transport import Message, SimHub
from sonarmap.team.wire import (
    VERSION,
    Advert,
    AdvertEntry,
    ExchangeError,
    PatchKey,
    decode_advert,
    encode_advert,
    pack,
    unpack,
)
from test_team_exchange import FAST, add_own, own_store


def table_of(ex: Exchanger) -> dict[PatchKey, AdvertEntry]:
    return {(e.source, e.region): e for e in ex.advert().entries}


def test_a_delta_round_trips_and_a_whole_advert_has_nothing_gone() -> None:
    delta = Advert((AdvertEntry(1, 3, 2.5, 4),), True, ((2, 0), (1, 5)), t=7.0, base=5.0)
    assert decode_advert(encode_advert(delta)) == delta
    empty = Advert((), delta=True, t=7.0, base=7.0)
    assert decode_advert(encode_advert(empty)) == empty
    for whole in (Advert((AdvertEntry(1, 3, 2.5, 4),)), Advert((), t=3.0)):
        assert decode_advert(encode_advert(whole)) == whole
        assert "gone" not in unpack(encode_advert(whole))
    with pytest.raises(ValueError, match="gone"):
        encode_advert(Advert((), gone=((1, 0),)))
    with pytest.raises(ValueError, match="send time"):
        encode_advert(Advert((), delta=True, t=1.0))


@pytest.mark.parametrize(
    ("gone", "regions", "times", "code"),
    [
        ([[1]], None, {}, "type"),
        ("x", None, {}, "type"),
        ([[1, -1]], None, {}, "range"),
        ([[1, 9]], {0, 1}, {}, "range"),
        ([[1, 0]], None, {}, "duplicate"),  # the same patch both changed and gone
        ([[2, 0], [2, 0]], None, {}, "duplicate"),
        ([], None, {"base": 3.5}, "inconsistent"),  # its base sent after it
        ([], None, {"t": None}, "type"),
        ([], None, {"base": float("inf")}, "range"),
    ],
)
def test_a_bad_delta_is_rejected_by_reason(
    gone: object, regions: set[int] | None, times: dict[str, object], code: str
) -> None:
    d = {"v": VERSION, "t": 3.0, "base": 1.0, "patches": [[1, 0, 1.0, 2]], "gone": gone}
    body = pack({**d, **times})
    with pytest.raises(ExchangeError) as e:
        decode_advert(body, regions=regions)
    assert e.value.code == code


def _pair(
    full_every: float, reach: Callable[[], set[int]] | None = None
) -> tuple[Exchanger, Exchanger, SimHub]:
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    params = ExchangeParams(**FAST, full_advert_every=full_every)  # type: ignore[arg-type]
    a = Exchanger(own_store(0, list(range(10))), hub.transport(0), params, peers=reach)
    b = Exchanger(own_store(1, [0]), hub.transport(1), params)
    return a, b, hub


def _adverts(to: Exchanger) -> list[Message]:
    return [m for m in to.transport.poll() if m.kind == "advert"]


def test_the_receiver_follows_the_table_through_deltas() -> None:
    a, b, hub = _pair(full_every=30.0)
    kinds = []
    for k in range(2, 12):
        t = float(k)
        add_own(a.store, 10 + k, k % 2, t)
        a.step(t)
        hub.step(t + 0.1)
        for m in _adverts(b):
            kinds.append("gone" in unpack(m.payload))
            b.handle(m, t + 0.1)
        assert b.peer_table(0) == table_of(a)
    # One whole table, then deltas: two patches of ten change.
    assert kinds[0] is False
    assert all(kinds[1:]), kinds
    assert a.stats.bytes_by_kind["advert"] > 0


def test_with_full_advert_every_0_every_advert_is_whole() -> None:
    a, b, hub = _pair(full_every=0.0)
    for k in range(2, 6):
        add_own(a.store, 10 + k, 0, float(k))
        a.step(float(k))
        hub.step(k + 0.1)
        assert all("gone" not in unpack(m.payload) for m in _adverts(b))


def test_a_lost_whole_advert_leaves_rows_stale_not_wrong_until_the_next() -> None:
    a, b, hub = _pair(full_every=4.0)
    history: dict[PatchKey, list[AdvertEntry]] = {}
    a.step(1.0)
    hub.step(1.1)
    lost = _adverts(b)  # the first whole table never arrives
    assert len(lost) == 1
    assert "gone" not in unpack(lost[0].payload)
    whole_again = False
    for k in range(2, 8):
        t = float(k)
        add_own(a.store, 10 + k, 2 + k % 2, t)
        a.step(t)
        for key, e in table_of(a).items():
            history.setdefault(key, []).append(e)
        hub.step(t + 0.1)
        for m in _adverts(b):
            whole_again |= "gone" not in unpack(m.payload)
            b.handle(m, t + 0.1)
        held = b.peer_table(0)
        # Every row b holds is one a advertised at some time.
        assert all(e in history[key] for key, e in held.items())
        if whole_again:
            assert held == table_of(a)
    assert whole_again
    # Before the whole table came again, b lacked a's patches that did not change.
    assert (0, 0) in b.peer_table(0)


def test_a_peer_newly_in_reach_gets_the_whole_table() -> None:
    reach = {1}
    a, b, hub = _pair(full_every=100.0, reach=lambda: reach)
    whole = []
    for k in range(2, 8):
        reach = set() if k == 4 else {1}
        add_own(a.store, 10 + k, 0, float(k))
        a.step(float(k))
        hub.step(k + 0.1)
        whole += ["gone" not in unpack(m.payload) for m in _adverts(b)]
    # k = 2 whole, 3 delta, 4 out of reach, 5 whole again, 6 and 7 deltas.
    assert whole == [True, False, True, False, False]


def _deliver(a: Exchanger, b: Exchanger, hub: SimHub, t: float) -> list[Message]:
    a.step(t)
    hub.step(t + 0.1)
    got = _adverts(b)
    for m in got:
        b.handle(m, t + 0.1)
    return got


def _hold_b_patch(a: Exchanger, b: Exchanger, t: float) -> None:
    """a receives one of b's poses at ``t``: a holds patch (1, 0)."""
    a.store.add_received_pose(1, b.store.local.poses[min(b.store.local.poses)], [], [], t)
    a.store.received[1].patches[0].stamp = t


def test_a_dropped_patch_is_listed_gone_and_leaves_the_receivers_table() -> None:
    a, b, hub = _pair(full_every=30.0)
    # A patch in the whole table, dropped later: listed gone.
    _hold_b_patch(a, b, 0.5)
    _deliver(a, b, hub, 1.0)
    assert (1, 0) in b.peer_table(0)
    del a.store.received[1]
    (m,) = _deliver(a, b, hub, 2.0)
    assert unpack(m.payload)["gone"] == [[1, 0]]
    assert b.peer_table(0) == table_of(a)
    # A patch that came with a delta and was dropped before the next: not gone (the
    # whole table never had it), and still not in the receiver's table.
    _hold_b_patch(a, b, 2.5)
    _deliver(a, b, hub, 3.0)
    assert (1, 0) in b.peer_table(0)
    del a.store.received[1]
    (m,) = _deliver(a, b, hub, 4.0)
    assert "gone" in unpack(m.payload)
    assert b.peer_table(0) == table_of(a)


def test_a_checkpoint_keeps_both_sides_bases() -> None:
    import msgpack

    a, b, hub = _pair(full_every=30.0)
    _deliver(a, b, hub, 1.0)
    _deliver(b, a, hub, 1.0)
    for e in (a, b):
        state = msgpack.unpackb(msgpack.packb(e.state()), raw=False)
        back = Exchanger(e.store, e.transport, e.params)
        back.restore(state)
        assert back.state() == e.state()
        assert state["told"]  # each sent a whole table, each heard one
        assert state["whole"]
    # A restarted sender goes on with deltas against the table its peer holds.
    back = Exchanger(a.store, a.transport, a.params)
    back.restore(msgpack.unpackb(msgpack.packb(a.state()), raw=False))
    add_own(a.store, 20, 3, 1.5)
    (m,) = _deliver(back, b, hub, 2.0)
    assert "gone" in unpack(m.payload)
    assert b.peer_table(0) == table_of(back)


def test_a_delta_missing_its_times_is_rejected() -> None:
    body = pack({"v": VERSION, "patches": [], "gone": []})
    with pytest.raises(ExchangeError) as e:
        decode_advert(body)
    assert e.value.code == "keys"


def test_a_lost_whole_table_never_brings_back_a_dropped_patch() -> None:
    a, b, hub = _pair(full_every=3.0)
    _hold_b_patch(a, b, 0.5)
    _deliver(a, b, hub, 1.0)
    del a.store.received[1]
    (m,) = _deliver(a, b, hub, 2.0)
    assert (1, 0) not in b.peer_table(0)
    # The next whole table (t = 4) is lost; the deltas after it follow that one.
    a.step(4.0)
    hub.step(4.1)
    (lost,) = _adverts(b)
    assert "gone" not in unpack(lost.payload)
    for t in (5.0, 6.0):
        add_own(a.store, 30 + int(t), 4, t)
        (m,) = _deliver(a, b, hub, t)
        assert "gone" in unpack(m.payload)
        held = b.peer_table(0)
        assert (1, 0) not in held
        assert held[(0, 4)] == table_of(a)[(0, 4)]
    _deliver(a, b, hub, 7.0)
    assert b.peer_table(0) == table_of(a)


def test_an_advert_older_than_one_heard_is_ignored() -> None:
    a, b, hub = _pair(full_every=30.0)
    a.step(1.0)
    add_own(a.store, 40, 5, 1.5)
    a.step(2.0)
    hub.step(2.1)
    first, second = _adverts(b)
    b.handle(second, 2.1)  # a delta overtook the whole table it follows
    b.handle(first, 2.1)
    assert b.stats.stale_adverts == 1
    assert b.peer_table(0)[(0, 5)] == table_of(a)[(0, 5)]
    # A delta applied over our copy: its rows are the newest, the rest as held.
    assert b.peer_table(0) == {k: e for k, e in table_of(a).items() if k == (0, 5)}


def test_a_refused_advert_makes_the_next_one_whole() -> None:
    a, b, hub = _pair(full_every=30.0)
    _deliver(a, b, hub, 1.0)
    send = a.transport.send
    a.transport.send = lambda *args, **kwargs: False  # type: ignore[method-assign]
    a.step(2.0)
    a.transport.send = send  # type: ignore[method-assign]
    assert a.stats.refused == 1
    (m,) = _deliver(a, b, hub, 3.0)
    assert "gone" not in unpack(m.payload)
