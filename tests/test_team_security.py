"""A team's network under attack (issue 38): frames that cannot crash a decoder, claims
that cannot make a node forget what its peer lacks, peers judged by their progress.

Every socket is on 127.0.0.1; every wait is bounded in time."""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import socket
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zmq
import zstandard
from benchmarks.team_fuzz import fuzz_node

from sonarmap.cli import main
from sonarmap.errors import InputError, OutputError
from sonarmap.io.rosmap import write_map
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.checkpoint import StateLock, read_state, write_state
from sonarmap.team.exchange import ExchangeParams, Exchanger
from sonarmap.team.keys import make_team_key, read_team_key
from sonarmap.team.launcher import KEY_FILE, node_args, run_zmq_team
from sonarmap.team.link import ReliableLink
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.node import SUMMARY_FILE, LockstepParams, run_node, store_digest
from sonarmap.team.records import Landmarks, Pose, RecordError, decode, encode, make_uid
from sonarmap.team.rejects import LINE_WIDTH, RejectLog
from sonarmap.team.simulation import run_team
from sonarmap.team.store import RobotStore, StoreParams
from sonarmap.team.transport import Message, SimHub, ZmqTransport, encode_envelope
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


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _node_fed(
    tmp_path: Path, frames: list[bytes], *, wait_timeout: float, deadline: float
) -> BaseException | None:
    """Run robot 0 as a node on 127.0.0.1 in a thread while the test, as robot 1, sends
    it ``frames`` on the lockstep channel; return what the node raised (None if it
    returned). Bounded: sends and the join give up ``deadline`` seconds after the start,
    and the node must have ended by then."""
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    cfg = MissionConfig(duration=5.0, seed=1)
    addresses = [f"tcp://127.0.0.1:{_free_port()}" for _ in range(2)]
    out: dict[str, BaseException] = {}

    def node() -> None:
        try:
            run_node(
                plan,
                cfg,
                0,
                addresses[0],
                {1: addresses[1]},
                out=tmp_path / "robot0",
                timing=LockstepParams(wait_timeout=wait_timeout, retry=0.2, linger=1.0),
            )
        except BaseException as e:  # handed to the test's thread
            out["error"] = e

    runner = threading.Thread(target=node)
    with ZmqTransport(1, addresses[1], {0: addresses[0]}) as me:
        runner.start()
        end = time.monotonic() + deadline
        for f in frames:
            while not me.send(0, f, "lock") and time.monotonic() < end:
                time.sleep(0.05)
        runner.join(timeout=max(1.0, end - time.monotonic()))
    assert not runner.is_alive()
    return out.get("error")


@pytest.mark.slow
def test_a_live_node_rejects_the_poison_answer_and_goes_on(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Robot 0 runs as a node on 127.0.0.1; the test plays robot 1 and sends it the
    poison answer in tick 0, then tick 0's marker. The node rejects the answer, counts
    it, and goes on to wait for tick 1's marker, which never comes: it ends with one
    line naming robot 1 (it ended with the decoder's ValueError before)."""
    done = _pack({"ch": 0, "out": False, "ack": 0})
    frames = [
        _pack({"q": 0, "t": 0, "k": "answer", "b": _poison_answer()}),
        _pack({"q": 1, "t": 0, "k": "done", "b": done}),
    ]
    with caplog.at_level(logging.WARNING):
        error = _node_fed(tmp_path, frames, wait_timeout=2.0, deadline=120.0)
    assert isinstance(error, InputError), repr(error)
    assert "peer robot 1" in str(error)
    assert "rejected a 'answer' from robot 1 (record)" in caplog.text


@pytest.mark.slow
def test_done_markers_that_skip_ticks_end_the_node_with_one_line_not_a_key_error(
    tmp_path: Path,
) -> None:
    """Found by benchmarks.team_fuzz: a key-holding peer whose numbered frames are
    well formed but whose ``done`` markers skip ticks (tick 0, then tick 50) made the
    node look up the skipped tick's marker and die of a KeyError. It now ends with one
    line naming the peer."""
    done = _pack({"ch": 0, "out": False, "ack": 0})
    frames = [_pack({"q": q, "t": t, "k": "done", "b": done}) for q, t in enumerate([0, 50])]
    error = _node_fed(tmp_path, frames, wait_timeout=5.0, deadline=60.0)
    assert isinstance(error, InputError), repr(error)
    assert "peer robot 1" in str(error)
    assert "no marker for tick" in str(error)
    assert "\n" not in str(error)


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


def _linked(
    pair: tuple[ZmqTransport, ZmqTransport], wait: float, retry: float = 0.05
) -> ReliableLink:
    link = ReliableLink(pair[0], [1], wait_timeout=wait, retry=retry)
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


def test_a_peer_asking_again_in_a_loop_gets_the_log_once_per_half_retry(
    pair: tuple[ZmqTransport, ZmqTransport],
) -> None:
    """Twenty requests to send everything again, faster than half a retry: the log
    goes out once; a request from an earlier frame gets only the frames below the
    ones already covered."""
    a, b = pair
    _send(a, 1, _pack({"next": 0, "ack": 0}), "hello")  # connected both ways
    link = _linked(pair, 5.0, retry=30.0)
    _send(b, 0, _pack({"next": 1, "ack": 0}), "hello")
    for _ in range(20):
        _send(b, 0, _pack({"next": 1, "ack": 0}), "hello")
    _send(b, 0, _pack({"next": 0, "ack": 0}), "hello")
    end = time.monotonic() + 2.0
    arrived = 0
    while time.monotonic() < end:
        link.pump(0.05)
        arrived += sum(m.kind == "lock" for m in b.poll(0.0))
    assert link.rejected == 0
    assert link.resent == 3  # frames 1 and 2 once, then frame 0 once
    assert arrived == 6  # the first sends and the three sent again


def test_a_request_after_half_a_retry_gets_the_whole_log_again(
    pair: tuple[ZmqTransport, ZmqTransport],
) -> None:
    _, b = pair
    link = _linked(pair, 5.0, retry=0.2)
    for _ in range(2):
        _send(b, 0, _pack({"next": 0, "ack": 0}), "hello")
        end = time.monotonic() + DEADLINE
        before = link.resent
        while link.resent == before and time.monotonic() < end:
            link.pump(0.05)
        time.sleep(0.15)  # past half a retry
    assert link.resent == 6
    assert [f.q for f in link.log[1]] == [0, 1, 2]  # nothing acknowledged, all kept


def test_after_a_resume_claims_past_what_was_sent_are_clamped_not_rejected(
    pair: tuple[ZmqTransport, ZmqTransport],
) -> None:
    """A node resumed from a checkpoint may have sent frames after it that the peer
    holds: the peer's claims past what was sent since are legitimate; only the part
    below what was sent is acted on."""
    link = _linked(pair, 5.0)
    state = msgpack.unpackb(_pack(link.state()))
    resumed = ReliableLink(pair[0], [1], wait_timeout=5.0, retry=0.05)
    resumed.restore(state)
    _, b = pair
    _send(b, 0, _pack({"next": 5, "ack": 5}), "hello")
    end = time.monotonic() + DEADLINE
    while resumed.acked_by[1] < 3 and time.monotonic() < end:
        resumed.pump(0.05)
    assert resumed.rejected == 0
    assert resumed.acked_by[1] == 3  # clamped to the 3 frames sent
    assert resumed.log[1] == []


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


# --- C: a keyed team ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def key_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("key") / "team.key"
    assert main_exit(["team", "key", "-o", str(path), "--robots", "3"]) == 0
    return path


def main_exit(argv: list[str]) -> int:
    try:
        main(argv)
    except SystemExit as e:
        return int(e.code or 0)
    return 0


def test_team_key_writes_an_owner_only_file_of_one_key_pair_per_robot(
    key_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert stat.S_IMODE(key_file.stat().st_mode) == 0o600
    key = read_team_key(key_file)
    assert key.robots == 3
    assert len(set(key.public.values())) == 3
    assert key.robot_of(key.public[2]) == 2
    assert key.robot_of(zmq.curve_keypair()[0]) is None
    # Not overwritten by accident; damaged or readable by others: one line, exit 2.
    capsys.readouterr()
    assert main_exit(["team", "key", "-o", str(key_file)]) == 2
    assert "exists" in capsys.readouterr().err
    copy = key_file.with_name("copy.key")
    copy.write_text(key_file.read_text())
    copy.chmod(0o644)
    with pytest.raises(InputError, match="readable by others"):
        read_team_key(copy)
    copy.chmod(0o600)
    copy.write_text(key_file.read_text().replace('"id": 1', '"id": 7'))
    with pytest.raises(InputError, match=r"robots\[1\]: id 7, expected 1"):
        read_team_key(copy)


@pytest.fixture
def keyed(key_file: Path) -> Iterator[tuple[ZmqTransport, ZmqTransport]]:
    key = read_team_key(key_file)
    a = ZmqTransport(0, "tcp://127.0.0.1:0", key=key)
    b = ZmqTransport(1, "tcp://127.0.0.1:0", {0: a.address}, key=key)
    a.connect(1, b.address)
    try:
        yield a, b
    finally:
        a.close()
        b.close()


def _stranger(to: str, identity: bytes, curve: tuple[bytes, bytes, bytes] | None) -> Any:
    """A raw DEALER claiming ``identity``; with ``curve`` (server public, own public,
    own secret) it attempts CURVE."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDTIMEO, 100)
    sock.setsockopt(zmq.IDENTITY, identity)
    if curve is not None:
        sock.setsockopt(zmq.CURVE_SERVERKEY, curve[0])
        sock.setsockopt(zmq.CURVE_PUBLICKEY, curve[1])
        sock.setsockopt(zmq.CURVE_SECRETKEY, curve[2])
    sock.connect(to)
    return ctx, sock


def _forged_end() -> list[bytes]:
    """Robot 1's "tick done" for every tick and its "bye": what made robot 0 finish
    alone in the issue."""
    done = _pack({"ch": 0, "out": False, "ack": 0})
    frames = [_pack({"q": q, "t": q, "k": "done", "b": done}) for q in range(40)]
    frames.append(_pack({"q": 40, "t": 40, "k": "bye", "b": b""}))
    return [encode_envelope(1, 0, seq, "lock", f) for seq, f in enumerate(frames)]


@pytest.mark.parametrize("curve", ["plain", "own key"])
def test_a_stranger_without_the_key_is_not_admitted(
    keyed: tuple[ZmqTransport, ZmqTransport], key_file: Path, curve: str
) -> None:
    a, b = keyed
    key = read_team_key(key_file)
    link = ReliableLink(a, [1, 2], wait_timeout=5.0, retry=0.5)
    public, secret = zmq.curve_keypair()
    ctx, sock = _stranger(
        a.address, b"1", None if curve == "plain" else (key.public[0], public, secret)
    )
    try:
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            for f in _forged_end():
                with contextlib.suppress(zmq.Again):
                    sock.send(f, zmq.NOBLOCK)
            link.pump(0.05)
        assert link.done == {1: -1, 2: -1}
        assert link.bye == set()
        assert link.next_q == {1: 0, 2: 0}
        if curve == "own key":
            assert a.stats.rejected["unauthenticated"] >= 1
        # The real robot 1 still gets through.
        _send(b, 0, b"genuine", "data")
        got: list[Message] = []
        end = time.monotonic() + DEADLINE
        while not got and time.monotonic() < end:
            got = a.poll(0.05)
        assert [(m.src, m.payload) for m in got] == [(1, b"genuine")]
    finally:
        sock.close(0)
        ctx.term()


def test_a_robot_is_known_by_its_key_not_by_the_identity_it_claims(
    keyed: tuple[ZmqTransport, ZmqTransport], key_file: Path
) -> None:
    """Robot 2's key with envelopes claiming robot 1: spoofed. (Its routing identity is
    not "1": the real robot 1 holds that one on this socket, and ZeroMQ would refuse a
    second connection under it before any check of ours, depending on who came first.)"""
    a, _ = keyed
    key = read_team_key(key_file)
    ctx, sock = _stranger(a.address, b"one", (key.public[0], key.public[2], key.secret[2]))
    try:
        end = time.monotonic() + DEADLINE
        while not a.stats.rejected["spoofed"] and time.monotonic() < end:
            with contextlib.suppress(zmq.Again):
                sock.send(encode_envelope(1, 0, 0, "lock", b"x"), zmq.NOBLOCK)
            assert a.poll(0.05) == []
        assert a.stats.rejected["spoofed"] >= 1
        sock.send(encode_envelope(2, 0, 0, "data", b"as myself"))
        got: list[Message] = []
        end = time.monotonic() + DEADLINE
        while not got and time.monotonic() < end:
            got = a.poll(0.05)
        assert [(m.src, m.payload) for m in got] == [(2, b"as myself")]
    finally:
        sock.close(0)
        ctx.term()


def test_without_a_key_a_node_listens_on_loopback_only() -> None:
    with pytest.raises(InputError, match="without a team key") as err:
        ZmqTransport(0, "tcp://0.0.0.0:0")
    assert "--insecure" in str(err.value)
    with pytest.raises(InputError, match="without a team key"):
        ZmqTransport(0, "tcp://*:0")
    ZmqTransport(0, "tcp://localhost:0").close()


@pytest.mark.slow
def test_a_keyed_team_gives_the_simulated_teams_results(tmp_path: Path) -> None:
    """The launcher keys its team (a fresh key, owner-only, in its folder); the nodes
    then end exactly as the simulated team's robots (and so as an unkeyed team's)."""
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    cfg = MissionConfig(duration=10.0, seed=2, store=StoreParams(region_limit=32_768))
    z = run_zmq_team(plan, cfg, 2, seed=3, folder=tmp_path, timeout=300.0)
    s = run_team(
        plan, cfg, 2, network=NetworkParams(kind="full"), exchange=ExchangeParams(), seed=3
    )
    assert stat.S_IMODE((tmp_path / KEY_FILE).stat().st_mode) == 0o600
    assert read_team_key(tmp_path / KEY_FILE).robots == 2
    assert z.held == s.held
    assert z.summary["store_digests"] == [store_digest(r.store) for r in s.robots]
    assert z.summary["duplicate_poses"] == s.summary["duplicate_poses"]
    assert sum(n["rejected_frames"] for n in z.nodes) == 0


# --- D: bounded queues -------------------------------------------------------------------


def _frame(q: int, size: int) -> bytes:
    return _pack({"q": q, "t": 0, "k": "advert", "b": bytes(size)})


def test_frames_kept_aside_are_bounded_in_bytes(
    pair: tuple[ZmqTransport, ZmqTransport], caplog: pytest.LogCaptureFixture
) -> None:
    """Out-of-order frames of 1000 bytes past a 10 kB queue: rejected, naming the peer;
    the frame awaited is still taken, and the ones kept aside after it."""
    a, b = pair
    link = ReliableLink(a, [1], wait_timeout=5.0, retry=0.5, max_queue=10_000)
    with caplog.at_level(logging.WARNING, logger="sonarmap.team.node"):
        for q in range(1, 31):
            _send(b, 0, _frame(q, 1000), "lock")
        end = time.monotonic() + DEADLINE
        while len(link.early[1]) + link.rejected < 30 and time.monotonic() < end:
            link.pump(0.05)
    kept = len(link.early[1])
    assert 5 <= kept < 10
    assert link.early_bytes[1] <= 10_000
    assert link.rejected == 30 - kept
    assert "frames kept aside from robot 1 would pass 10000 bytes" in caplog.text
    _send(b, 0, _frame(0, 1000), "lock")
    end = time.monotonic() + DEADLINE
    while link.next_q[1] == 0 and time.monotonic() < end:
        link.pump(0.05)
    assert link.next_q[1] == kept + 1
    assert link.early_bytes[1] == 0


def test_frames_a_peer_does_not_acknowledge_are_bounded_naming_it(
    pair: tuple[ZmqTransport, ZmqTransport],
) -> None:
    link = ReliableLink(pair[0], [1], wait_timeout=5.0, retry=0.5, max_queue=10_000)
    for _ in range(9):
        link.send(1, 0, "advert", bytes(1000))
    with pytest.raises(InputError, match="sent to robot 1 and not acknowledged") as err:
        link.send(1, 0, "advert", bytes(1000))
    assert "--max-queue" in str(err.value)
    assert len(link.log[1]) == 9


def test_without_a_state_folder_frames_taken_are_acknowledged(
    pair: tuple[ZmqTransport, ZmqTransport],
) -> None:
    """The issue: sent-frame logs were trimmed only at the peer's checkpoint, so a team
    without --state kept every frame it ever sent."""
    a, b = pair
    sender = ReliableLink(a, [1], wait_timeout=5.0, retry=0.5, durable=False)
    receiver = ReliableLink(b, [0], wait_timeout=5.0, retry=0.5, durable=False)
    end = time.monotonic() + DEADLINE
    while not a.send(1, _pack({"next": 0, "ack": 0}), "hello") and time.monotonic() < end:
        time.sleep(0.01)  # connected: the frames below are not refused
    for _ in range(20):
        sender.send(1, 0, "advert", bytes(1000))
    assert sender.log_bytes[1] > 20_000
    while receiver.next_q[0] < 20 and time.monotonic() < end:
        receiver.pump(0.05)
    receiver.mark_done(0, 0, False)
    while sender.log[1] and time.monotonic() < end:
        sender.pump(0.05)
    assert sender.log[1] == []
    assert sender.log_bytes[1] == 0


# --- E: checkpoints that are safe --------------------------------------------------------


def _state() -> bytes:
    return _pack({"v": 1, "clock": {"next": 7}, "blob": bytes(range(256)) * 8})


def test_every_damaged_checkpoint_is_refused_with_one_line(tmp_path: Path) -> None:
    """The issue: 7 of 20 corruptions resumed silently. Here 200 of them: a byte
    changed anywhere, or the file cut short; each is one InputError naming the file."""
    path = tmp_path / "state.msgpack"
    write_state(path, _state())
    assert read_state(path) == msgpack.unpackb(_state())
    good = path.read_bytes()
    rng = np.random.default_rng(5)
    for k in range(200):
        bad = bytearray(good)
        if k % 4 == 3:
            bad = bad[: int(rng.integers(0, len(bad)))]
        else:
            at = int(rng.integers(0, len(bad)))
            bad[at] ^= int(rng.integers(1, 256))
        path.write_bytes(bytes(bad))
        with pytest.raises(InputError) as err:
            read_state(path)
        assert str(path) in str(err.value)
        assert "\n" not in str(err.value)
    # A version-1 file (the bare state, no checksum) is named as such.
    path.write_bytes(_state())
    with pytest.raises(InputError, match="not a node checkpoint"):
        read_state(path)


def test_a_full_disk_keeps_the_previous_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "state.msgpack"
    write_state(path, _state())
    before = path.read_bytes()

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError) as err:
        write_state(path, _pack({"v": 1, "clock": {"next": 8}}))
    monkeypatch.undo()
    assert "No space left on device" in str(err.value)
    assert "previous one is kept" in str(err.value)
    assert "\n" not in str(err.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.msgpack"]  # no temporary


def test_a_state_folder_is_locked_against_a_second_process(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The same robot id on the same state folder twice: the second fails at once, one
    line naming the robot, before any socket or work (a live node holds the lock)."""
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    write_map(plan, tmp_path / "plan")
    state = tmp_path / "robot1.state"
    with StateLock(state, "robot 1"):
        second = StateLock(state, "robot 1")
        with pytest.raises(InputError, match=r"in use by robot 1 \(process \d+\): robot 1 st"):
            second.__enter__()
        capsys.readouterr()
        argv = ["team", "node", "--map", str(tmp_path / "plan.yaml"), "-o", str(tmp_path / "o")]
        argv += ["--id", "1", "--listen", "tcp://127.0.0.1:0", "--peers", "0=tcp://127.0.0.1:9"]
        assert main_exit([*argv, "--state", str(state)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert "robot 1 started twice" in err
    # Released with its holder.
    with StateLock(state, "robot 1"):
        pass


def test_team_node_without_a_key_off_loopback_and_a_short_key_are_one_line(
    tmp_path: Path, key_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    write_map(plan, tmp_path / "plan")
    argv = ["team", "node", "--map", str(tmp_path / "plan.yaml"), "-o", str(tmp_path / "o")]
    four = ",".join(f"{j}=tcp://127.0.0.1:9" for j in range(1, 4))
    cases = [
        (["--id", "0", "--listen", "tcp://0.0.0.0:0"], "without a team key"),
        (
            ["--id", "0", "--listen", "tcp://127.0.0.1:0", "--key", str(key_file), "--peers", four],
            "the team key is for 3 robots, the team has 4",
        ),
        (["--id", "0", "--listen", "tcp://127.0.0.1:0", "--key", str(tmp_path)], "team key"),
    ]
    for args, expected in cases:
        capsys.readouterr()
        assert main_exit([*argv, *args]) == 2, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert expected in err


# --- F: tests that attack ----------------------------------------------------------------


@pytest.mark.slow
def test_an_insider_fuzzing_a_live_node_neither_crashes_nor_hangs_it(tmp_path: Path) -> None:
    """3,000 frames from robot 1's own key (so every one reaches a decoder): mutated,
    retyped, truncated, huge, forged; then an honest end. The node exits 0 having
    counted the rejections, and its memory grows by less than 200 MB under the attack
    and peaks within 200 MB of its undisturbed run's (benchmarks.team_fuzz: the same
    at scale)."""
    ref = fuzz_node(0, 38, tmp_path / "undisturbed", timeout=60.0)
    got = fuzz_node(3000, 38, tmp_path / "fuzzed", timeout=60.0)
    assert ref.exit_code == 0, ref.last_line
    assert got.exit_code == 0, got.last_line
    assert not got.hung
    assert (got.sent, got.refused) == (3000, 0)
    assert got.asked >= 1  # it asked for robot 1's frames: it was up and waiting
    # Some attack frames are valid (a hello asking again, a frame kept aside far ahead):
    # most are not, and each of those is counted.
    assert got.rejected >= (got.sent - got.inner) // 2
    assert "rejected a " in (tmp_path / "fuzzed" / "robot0.log").read_text()
    assert got.rss_peak_mb - ref.rss_peak_mb < 200.0
    assert got.rss_attacked_mb - got.rss_start_mb < 200.0


def _node_cmd(i: int, addresses: list[str], folder: Path, args: list[str]) -> list[str]:
    """Robot ``i``'s ``team node`` command, as the launcher builds it."""
    peer = ",".join(f"{j}={a}" for j, a in enumerate(addresses) if j != i)
    cmd = [sys.executable, "-m", "sonarmap", "team", "node", "--id", str(i)]
    cmd += ["--listen", addresses[i], "--peers", peer, "--map", str(folder / "plan.yaml")]
    return [*cmd, "-o", str(folder / f"robot{i}"), "--key", str(folder / KEY_FILE), *args]


def _start(
    i: int, addresses: list[str], folder: Path, args: list[str], log: Any
) -> subprocess.Popen[bytes]:
    cmd = _node_cmd(i, addresses, folder, args)
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)


def _listening(address: str) -> bool:
    port = int(address.rsplit(":", 1)[1])
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.slow
def test_a_stranger_before_robot_1_starts_changes_nothing(tmp_path: Path) -> None:
    """The issue's acceptance scenario: a 2-robot keyed team on loopback; a stranger
    without the key connects to robot 0 before robot 1 starts, calls itself robot 1 and
    sends forged tick and bye frames, a forged hello and 2,000 random frames. Both
    robots exit 0 and robot 0 ends with the poses and store digest of an undisturbed
    run (the simulated team's: a keyed zmq team's results are the same)."""
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    cfg = MissionConfig(duration=10.0, seed=2, store=StoreParams(region_limit=32_768))
    undisturbed = run_team(
        plan, cfg, 2, network=NetworkParams(kind="full"), exchange=ExchangeParams(), seed=3
    )
    write_map(plan, tmp_path / "plan")
    make_team_key(2).write(tmp_path / KEY_FILE)
    args = node_args(cfg, ExchangeParams(), 30.0, None, 120.0, LockstepParams(wait_timeout=60.0))
    addresses = [f"tcp://127.0.0.1:{_free_port()}" for _ in range(2)]
    logs = [open(tmp_path / f"robot{i}.log", "wb") for i in range(2)]  # noqa: SIM115
    procs: list[subprocess.Popen[bytes]] = []
    forged = _forged_end()
    forged.append(encode_envelope(1, 0, 41, "hello", _pack({"next": 10**6, "ack": 10**6})))
    rng = np.random.default_rng(38)
    forged += [rng.bytes(int(rng.integers(1, 300))) for _ in range(2000)]
    server = read_team_key(tmp_path / KEY_FILE).public[0]
    public, secret = zmq.curve_keypair()
    # Without CURVE, and with CURVE and robot 0's public key but a key of its own.
    strangers = [_stranger(addresses[0], b"1", c) for c in (None, (server, public, secret))]
    sent = 0

    def attack(frames: int) -> None:
        nonlocal sent
        for _ in range(frames):
            for _, sock in strangers:
                with contextlib.suppress(zmq.Again):
                    sock.send(forged[sent % len(forged)], zmq.NOBLOCK)
            sent += 1

    try:
        procs.append(_start(0, addresses, tmp_path, args, logs[0]))
        end = time.monotonic() + 60.0
        while not _listening(addresses[0]) and time.monotonic() < end:
            time.sleep(0.1)
        # Robot 0 is up: attacked for 3 s and every forged frame, before robot 1 starts.
        end = time.monotonic() + 3.0
        while (time.monotonic() < end or sent < len(forged)) and time.monotonic() < end + DEADLINE:
            attack(50)
            time.sleep(0.01)
        procs.append(_start(1, addresses, tmp_path, args, logs[1]))
        end = time.monotonic() + 240.0
        while any(p.poll() is None for p in procs) and time.monotonic() < end:
            attack(50)  # and all along
            time.sleep(0.1)
        codes = [p.poll() for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
        for log in logs:
            log.close()
        for ctx, sock in strangers:
            sock.close(0)
            ctx.term()
    assert codes == [0, 0], (tmp_path / "robot0.log").read_text()[-2000:]
    summary = json.loads((tmp_path / "robot0" / SUMMARY_FILE).read_text())
    # The stranger with a key of its own was turned away at the handshake, counted.
    assert "denied" in (tmp_path / "robot0.log").read_text()
    assert summary["rejected_frames"] >= 1
    assert set(summary["held"]) == undisturbed.held[0]
    assert summary["local_digest"] == store_digest(undisturbed.robots[0].store)
