"""A team's network under attack (issue 38): frames that cannot crash a decoder, claims
that cannot make a node forget what its peer lacks, peers judged by their progress.

Every socket is on 127.0.0.1; every wait is bounded in time."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator

import msgpack
import numpy as np
import pytest
import zstandard

from sonarmap.errors import InputError
from sonarmap.team.exchange import ExchangeParams, Exchanger
from sonarmap.team.link import ReliableLink
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.records import Landmarks, Pose, RecordError, decode, encode, make_uid
from sonarmap.team.rejects import LINE_WIDTH, RejectLog
from sonarmap.team.store import RobotStore
from sonarmap.team.transport import Message, SimHub, ZmqTransport
from sonarmap.team.wire import PRESET_DICTIONARY, VERSION, ExchangeError, decode_answer, pack

#: Upper bound on any wait in this file.
DEADLINE = 10.0


def _pack(d: object) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


def _poison_pose() -> bytes:
    """A pose whose points claim shape [65536]*4 with no data: 65536**4 is 2**64, which
    numpy's int64 product wraps to 0, the size of the empty data."""
    d = msgpack.unpackb(encode(Pose(make_uid(1, 0), 1.0, 0, np.zeros(3), Landmarks.empty())))
    d["points"] = {"dtype": "float32", "shape": [65536] * 4, "data": b""}
    return _pack(d)


def _poison_answer() -> bytes:
    row = {"src": 1, "r": 0, "s": 1.0, "short": [make_uid(1, 0)], "full": None}
    row |= {"poses": [_poison_pose()], "edges": []}
    return pack({"v": VERSION, "id": 0, "mode": "good", "patches": [row]})


# --- A: decoding that cannot crash -----------------------------------------------------


def test_the_poison_shape_is_a_record_error_not_a_crash() -> None:
    with pytest.raises(RecordError, match="does not fill shape"):
        decode(_poison_pose())
    with pytest.raises(ExchangeError) as err:
        decode_answer(_poison_answer())
    assert err.value.code == "record"


def test_the_poison_answer_is_rejected_and_counted_by_the_exchanger(
    caplog: pytest.LogCaptureFixture,
) -> None:
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
    e = Exchanger(RobotStore(0), hub.transport(0), ExchangeParams())
    with caplog.at_level(logging.WARNING, logger="sonarmap.team.exchange"):
        e.handle(Message(1, 0, _poison_answer(), 0, "answer"), 1.0)
    assert e.stats.rejected == {"record": 1}
    assert "does not fill shape" in caplog.text


def test_mutated_answers_raise_nothing_but_exchange_errors() -> None:
    """Bytes of a valid answer's msgpack changed one at a time: whatever the decoder
    makes of each, it is a valid answer or an ExchangeError, never another exception."""
    pose = Pose(make_uid(1, 0), 1.0, 0, np.zeros(3), Landmarks.empty())
    row = {"src": 1, "r": 0, "s": 1.0, "short": [pose.uid], "full": None}
    row |= {"poses": [encode(pose)], "edges": []}
    raw = _pack({"v": VERSION, "id": 0, "mode": "good", "patches": [row]})
    dictionary = zstandard.ZstdCompressionDict(
        PRESET_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT
    )
    zstd = zstandard.ZstdCompressor(level=1, dict_data=dictionary)
    rng = np.random.default_rng(38)
    codes: set[str] = set()
    for k in range(len(raw)):
        for value in rng.integers(0, 256, 3):
            bad = bytearray(raw)
            bad[k] = int(value)
            try:
                decode_answer(zstd.compress(bytes(bad)))
            except ExchangeError as err:
                codes.add(err.code)
    assert {"record", "type"} <= codes


def test_rejection_lines_are_clipped_and_their_rate_bounded(
    caplog: pytest.LogCaptureFixture,
) -> None:
    now = [0.0]
    log = RejectLog(logging.getLogger("sonarmap.test.rejects"), burst=5, clock=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="sonarmap.test.rejects"):
        for _ in range(1000):
            log.warn("evil\n" + "x" * 10_000)
        assert len(caplog.records) == 5
        now[0] += 1.0
        assert log.warn("after a second")
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 6
    assert all("\n" not in s and len(s) <= LINE_WIDTH for s in lines[:5])
    assert lines[-1] == "after a second (995 more rejections not logged)"


@pytest.fixture
def pair() -> Iterator[tuple[ZmqTransport, ZmqTransport]]:
    a = ZmqTransport(0, "tcp://127.0.0.1:0")
    b = ZmqTransport(1, "tcp://127.0.0.1:0", {0: a.address})
    a.connect(1, b.address)
    try:
        yield a, b
    finally:
        a.close()
        b.close()


def _send(t: ZmqTransport, dst: int, body: bytes, kind: str) -> None:
    end = time.monotonic() + DEADLINE
    while not t.send(dst, body, kind):
        assert time.monotonic() < end, "no connection"
        time.sleep(0.01)


def test_a_flood_of_bad_frames_logs_a_bounded_number_of_lines(
    pair: tuple[ZmqTransport, ZmqTransport], caplog: pytest.LogCaptureFixture
) -> None:
    a, b = pair
    link = ReliableLink(a, [1], wait_timeout=5.0, retry=0.5)
    with caplog.at_level(logging.WARNING, logger="sonarmap.team.node"):
        for k in range(300):
            _send(b, 0, b"\xc1" + bytes([k % 256]) * 500, "lock")
        end = time.monotonic() + DEADLINE
        while link.rejected < 300 and time.monotonic() < end:
            link.pump(0.05)
    assert link.rejected == 300
    lines = [r.getMessage() for r in caplog.records if r.name == "sonarmap.team.node"]
    assert 1 <= len(lines) <= 60
    assert all(len(s) <= LINE_WIDTH + 60 for s in lines)


# --- B: no livelock --------------------------------------------------------------------


def _linked(pair: tuple[ZmqTransport, ZmqTransport], wait: float) -> ReliableLink:
    link = ReliableLink(pair[0], [1], wait_timeout=wait, retry=0.05)
    for k in range(3):
        link.send(1, 0, "advert", f"frame {k}".encode())
    return link


def test_a_hello_claiming_frames_never_sent_is_rejected_and_not_acted_on(
    pair: tuple[ZmqTransport, ZmqTransport], caplog: pytest.LogCaptureFixture
) -> None:
    link = _linked(pair, 5.0)
    _, b = pair
    with caplog.at_level(logging.WARNING, logger="sonarmap.team.node"):
        _send(b, 0, _pack({"next": 10**6, "ack": 10**6}), "hello")
        forged_done = _pack({"ch": 0, "out": False, "ack": 10**6})
        _send(b, 0, _pack({"q": 0, "t": 0, "k": "done", "b": forged_done}), "lock")
        end = time.monotonic() + DEADLINE
        while link.rejected < 2 and time.monotonic() < end:
            link.pump(0.05)
    assert link.rejected == 2
    assert "claims frames never sent (sent 3)" in caplog.text
    # The unacknowledged frames are kept, to be sent again when the peer asks.
    assert [f.q for f in link.log[1]] == [0, 1, 2]
    assert link.acked_by[1] == 0
    assert link.next_q[1] == 0  # the forged marker did not take its place in the sequence
    # A true claim still trims.
    _send(b, 0, _pack({"next": 2, "ack": 2}), "hello")
    end = time.monotonic() + DEADLINE
    while link.acked_by[1] < 2 and time.monotonic() < end:
        link.pump(0.05)
    assert [f.q for f in link.log[1]] == [2]


def test_a_peer_that_only_asks_again_times_out_naming_it(
    pair: tuple[ZmqTransport, ZmqTransport],
) -> None:
    """The livelock: the peer keeps sending requests to send again (valid traffic, no
    progress); the wait ends after wait_timeout with one line naming it."""
    link = _linked(pair, 0.5)
    _, b = pair
    start = time.monotonic()

    def awaited() -> list[int]:
        if time.monotonic() - start > DEADLINE:
            return []  # the bug: never timing out; the assertion below then fails
        b.send(0, _pack({"next": 0, "ack": 0}), "hello")
        return [1]

    with pytest.raises(InputError) as err:
        link.wait(awaited, "tick 3")
    assert time.monotonic() - start < DEADLINE
    message = str(err.value)
    assert "peer robot 1" in message
    assert "sent no new frame for 0.5 s" in message
    assert "\n" not in message
    assert link.heard[1] > start  # it was heard all along
