"""Transports: the envelope and its strict decoding, round trips over the simulated
network and over ZeroMQ on loopback, malformed frames rejected and logged without
stopping the receiver, vanished peers and busy addresses."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack

import msgpack
import numpy as np
import pytest
import zmq

from sonarmap.errors import InputError
from sonarmap.grid import Grid
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.transport import (
    EnvelopeError,
    Message,
    SimHub,
    SimTransport,
    Transport,
    ZmqTransport,
    decode_envelope,
    encode_envelope,
)

LOGGER = "sonarmap.team.transport"
LOOPBACK = "tcp://127.0.0.1:0"
#: Upper bound on any wait in this file: a broken transport fails, it does not hang.
DEADLINE = 5.0


def _pack(d: object) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


GOOD = {"v": 1, "src": 7, "dst": 1, "seq": 0, "kind": "data", "body": b"payload"}
BAD_FRAMES = {
    "random": (bytes(np.random.default_rng(0).integers(0, 256, 40, dtype=np.uint8)), None),
    "truncated": (encode_envelope(7, 1, 0, "data", b"x" * 100)[:-10], "truncated"),
    "trailing": (encode_envelope(7, 1, 0, "data", b"x") + b"\x00", "trailing"),
    "not a map": (_pack([1, 2, 3]), "not_map"),
    "missing key": (_pack({k: v for k, v in GOOD.items() if k != "seq"}), "keys"),
    "extra key": (_pack({**GOOD, "pickle": b"cos\nsystem"}), "keys"),
    "version 2": (_pack({**GOOD, "v": 2}), "version"),
    "src as str": (_pack({**GOOD, "src": "7"}), "type"),
    "seq as bool": (_pack({**GOOD, "seq": True}), "type"),
    "seq as float": (_pack({**GOOD, "seq": 1.0}), "type"),
    "body as str": (_pack({**GOOD, "body": "text"}), "type"),
    "empty kind": (_pack({**GOOD, "kind": ""}), "type"),
    "negative seq": (_pack({**GOOD, "seq": -1}), "range"),
    "int key": (_pack({1: 2}), "msgpack"),
    "ext type": (_pack(msgpack.ExtType(5, b"abc")), "msgpack"),
    # A bin claiming 4 GiB in a 30-byte frame: refused without allocating it.
    "huge bin length": (_pack({**GOOD, "body": b""})[:-1] + b"\xc6\xff\xff\xff\xff", None),
}


def test_envelope_round_trip() -> None:
    data = encode_envelope(3, 9, 41, "patch", b"\x00\xff" * 10)
    msg = decode_envelope(data)
    assert msg == Message(3, 9, b"\x00\xff" * 10, 41, "patch")
    with pytest.raises(EnvelopeError, match="oversized"):
        decode_envelope(encode_envelope(7, 1, 0, "data", b"x" * 1000), max_message=1000)


@pytest.mark.parametrize("name", sorted(BAD_FRAMES))
def test_a_bad_envelope_is_refused_with_its_reason(name: str) -> None:
    data, reason = BAD_FRAMES[name]
    with pytest.raises(EnvelopeError) as err:
        decode_envelope(data, max_message=1000)
    if reason is not None:
        assert err.value.reason == reason


# --- simulated transports ----------------------------------------------------------


def _chain_hub(**kw: object) -> tuple[SimHub, list[SimTransport]]:
    grid = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(20, 200))
    params = NetworkParams(kind="limited", r_max=70.0, **kw)  # type: ignore[arg-type]
    net = SimNetwork(params, 3, clear=np.ones(grid.shape, dtype=bool), grid=grid)
    hub = SimHub(net)
    hub.update(np.array([[10.0, 10.0], [60.0, 10.0], [110.0, 10.0]]))
    return hub, [hub.transport(r) for r in range(3)]


def test_sim_round_trip_over_a_relay() -> None:
    hub, (a, b, c) = _chain_hub(bandwidth=1000.0, delay=0.5)
    assert a.send(2, b"first", kind="patch")
    assert a.send(2, b"second")
    assert c.poll() == []
    hub.step(1.0)
    assert c.poll() == []  # two hops of 0.5 s plus transmission
    hub.step(1.0)
    got = c.poll()
    assert [(m.src, m.dst, m.seq, m.kind, m.payload) for m in got] == [
        (0, 2, 0, "patch", b"first"),
        (0, 2, 1, "data", b"second"),
    ]
    assert c.send(0, b"reply")
    hub.step(5.0)
    (reply,) = a.poll()
    assert (reply.src, reply.seq, reply.payload) == (2, 0, b"reply")
    assert a.stats.messages_sent == 2
    assert c.stats.messages_received == 2
    assert b.poll() == []  # the relay sees nothing


def test_sim_refusals_are_counted() -> None:
    _, (a, _, c) = _chain_hub(relay=False, max_message=200)
    assert not a.send(2, b"x")  # no direct link
    assert not a.send(1, b"x" * 300)  # envelope over max_message
    assert a.stats.dropped == {"unroutable": 1, "oversized": 1}
    c.close()
    assert not c.send(1, b"x")
    assert c.stats.dropped == {"closed": 1}
    with pytest.raises(InputError, match="field 'dst'"):
        a.send(0, b"to myself")


def test_sim_rejects_a_forged_envelope(caplog: pytest.LogCaptureFixture) -> None:
    hub, (a, b, _) = _chain_hub()
    # Robot 2 puts a frame on the air claiming to come from robot 0.
    hub.network.send(hub.now, 2, 1, encode_envelope(0, 1, 0, "data", b"forged"))
    hub.network.send(hub.now, 2, 1, b"\xc1garbage")
    assert a.send(1, b"genuine")
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        got = b.poll()
    assert [m.payload for m in got] == [b"genuine"]
    assert b.stats.rejected == {"spoofed": 1, "msgpack": 1}
    assert "claims robot 0, came from 2" in caplog.text


# --- ZeroMQ transports -------------------------------------------------------------


@pytest.fixture
def stack() -> Iterator[ExitStack]:
    with ExitStack() as s:
        yield s


def _team(stack: ExitStack, n: int, **kw: object) -> list[ZmqTransport]:
    team = [stack.enter_context(ZmqTransport(r, LOOPBACK, **kw)) for r in range(n)]  # type: ignore[arg-type]
    for t in team:
        for u in team:
            if u is not t:
                t.connect(u.robot, u.address)
    return team


def _until(cond: Callable[[], bool], what: str) -> None:
    end = time.monotonic() + DEADLINE
    while not cond():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


def _send(t: Transport, dst: int, payload: bytes) -> None:
    # IMMEDIATE refuses until the TCP connection is up: a few milliseconds on loopback.
    _until(lambda: t.send(dst, payload), f"robot {t.robot} to connect to {dst}")


def _collect(t: Transport, n: int) -> list[Message]:
    got: list[Message] = []
    end = time.monotonic() + DEADLINE
    while len(got) < n and time.monotonic() < end:
        got += t.poll(0.05)
    return got


def test_zmq_round_trip_between_three_robots(stack: ExitStack) -> None:
    team = _team(stack, 3)
    for t in team:
        for u in team:
            if u is not t:
                for k in range(3):
                    _send(t, u.robot, f"{t.robot}->{u.robot} #{k}".encode())
    for u in team:
        got = _collect(u, 6)
        assert len(got) == 6
        for src in {0, 1, 2} - {u.robot}:
            mine = [m for m in got if m.src == src]
            assert [m.seq for m in mine] == [0, 1, 2]
            assert [m.payload for m in mine] == [
                f"{src}->{u.robot} #{k}".encode() for k in range(3)
            ]
            assert all(m.dst == u.robot for m in mine)
        assert u.stats.messages_sent == 6
        assert u.stats.messages_received == 6
        assert not u.stats.rejected
    assert team[0].poll(0.0) == []


def _raw_dealer(
    stack: ExitStack, ctx: zmq.Context[zmq.Socket[bytes]], to: str, identity: bytes | None
) -> zmq.Socket[bytes]:
    sock = ctx.socket(zmq.DEALER)
    stack.callback(sock.close, 0)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDTIMEO, int(DEADLINE * 1000))
    if identity is not None:
        sock.setsockopt(zmq.IDENTITY, identity)
    sock.connect(to)
    return sock


def test_zmq_rejects_malformed_frames_and_keeps_working(
    stack: ExitStack, caplog: pytest.LogCaptureFixture
) -> None:
    a, b = _team(stack, 2, max_message=1000)
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    stack.callback(ctx.term)
    evil = _raw_dealer(stack, ctx, b.address, b"7")
    frames = [data for data, _ in BAD_FRAMES.values()]
    frames += [
        encode_envelope(7, 1, 0, "data", b"x" * 1100),  # over max_message, under zmq's cap
        encode_envelope(7, 0, 0, "data", b"for robot 0"),  # misaddressed
        encode_envelope(3, 1, 0, "data", b"I am robot 3"),  # not the identity it came with
    ]
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        for f in frames:
            evil.send(f)
        evil.send_multipart([b"two", b"frames"])
        anonymous = _raw_dealer(stack, ctx, b.address, None)
        anonymous.send(encode_envelope(7, 1, 0, "data", b"who am I"))
        good = encode_envelope(7, 1, 0, "data", b"valid at last")
        evil.send(good)
        # Rejections are counted as poll reads them: poll until all are in.
        got: list[Message] = []
        end = time.monotonic() + DEADLINE
        while sum(b.stats.rejected.values()) < len(frames) + 2 and time.monotonic() < end:
            got += b.poll(0.01)
        got += b.poll(0.05)
    assert [(m.src, m.payload) for m in got] == [(7, b"valid at last")]
    rejected = b.stats.rejected
    assert sum(rejected.values()) == len(frames) + 2
    for reason in ("truncated", "keys", "type", "oversized", "misaddressed", "spoofed"):
        assert rejected[reason] >= 1, reason
    assert rejected["frames"] == 1
    assert rejected["identity"] == 1
    records = [r for r in caplog.records if r.name == LOGGER]
    assert len(records) == len(frames) + 2
    assert all("robot 1 rejected a frame from peer" in r.getMessage() for r in records)
    # Far over max_message: zmq drops it and the sender's connection, unread.
    evil.send(b"\x00" * 5000)
    # The transport still serves its real peers.
    _send(a, 1, b"still here")
    assert [m.payload for m in _collect(b, 1)] == [b"still here"]


def test_zmq_a_vanished_peer_neither_crashes_nor_blocks(stack: ExitStack) -> None:
    a, b, c = _team(stack, 3)
    _send(a, 1, b"hello")
    assert [m.payload for m in _collect(b, 1)] == [b"hello"]
    b.close()
    assert b.poll(0.1) == []
    assert not b.send(0, b"x")
    before = a.stats.messages_sent + sum(a.stats.dropped.values())
    start = time.monotonic()
    sent = [a.send(1, b"y" * 1000) for _ in range(3000)]
    assert time.monotonic() - start < 2.0
    assert a.stats.messages_sent + sum(a.stats.dropped.values()) == before + 3000
    assert not sent[-1]  # the connection was found gone: refused, not queued forever
    assert a.stats.dropped["unavailable"] >= 1
    # The others go on.
    _send(a, 2, b"to c")
    assert [m.payload for m in _collect(c, 1)] == [b"to c"]
    assert not a.send(5, b"nobody")
    assert a.stats.dropped["unknown_peer"] == 1


def test_zmq_a_restarted_peer_is_reached_again(stack: ExitStack) -> None:
    a, b = _team(stack, 2)
    address = b.address
    b.close()
    b2 = stack.enter_context(ZmqTransport(1, address))
    _send(a, 1, b"again")
    assert [(m.src, m.payload) for m in _collect(b2, 1)] == [(0, b"again")]


def test_zmq_refuses_an_envelope_over_max_message(stack: ExitStack) -> None:
    (a, _) = _team(stack, 2, max_message=500)
    assert not a.send(1, b"x" * 500)
    assert a.stats.dropped["oversized"] == 1


@pytest.mark.parametrize(
    "address", ["tcp://127.0.0.1:port", "udp://127.0.0.1:5000", "tcp://127.0.0.1:70000", "", 5]
)
def test_zmq_an_unparsable_listen_address_is_one_input_error(address: str) -> None:
    with pytest.raises(InputError, match="field 'listen': cannot listen on") as err:
        ZmqTransport(0, address)
    assert "\n" not in str(err.value)


def test_zmq_an_address_in_use_is_an_input_error(stack: ExitStack) -> None:
    (a,) = _team(stack, 1)
    with pytest.raises(InputError, match="Address already in use") as err:
        ZmqTransport(1, a.address)
    assert a.address in str(err.value)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="field 'peers'"):
        a.connect(2, "tcp://127.0.0.1:*")
