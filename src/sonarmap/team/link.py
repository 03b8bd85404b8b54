"""Reliable numbered frames between ZeroMQ nodes (:mod:`.node`), and the transport
the exchanger of a node sees.

Every frame a node sends a peer (exchanger messages and the lock-step's markers) is
numbered per destination and kept in a log until the peer acknowledges it durably (its
checkpoint holds it); a receiver takes frames in number order, drops the ones it has
and keeps early ones aside. A node stuck waiting asks the peer to send again from the
first number it lacks (``hello``), which covers a socket that refused a frame (peer not
connected yet) and a restarted peer. Such requests are served with the whole log at most
once per half ``retry``, so a peer that asks in a loop cannot make a node flood the wire.

A peer's claims are checked against what was sent to it: a ``hello`` (or a ``done``
marker's ``ack``) claiming frames this node never sent is a protocol error, rejected and
not acted on (acting on it would drop frames the peer still lacks, and the two would
then ask each other to send again forever). After a resume from a checkpoint, frames
sent before the kill but after the checkpoint may be claimed: those claims are only
clamped to what was sent since, not logged. A peer is judged by its progress, not its
traffic: one that sends no new frame for ``wait_timeout`` s while awaited ends the wait
with one line naming it, whatever else it sends.

A node's frames on the wire (envelope kinds): ``lock`` (a numbered frame:
``{"q", "t", "k", "b"}``, ``k`` an exchanger kind, ``done`` or ``bye``) and ``hello``
(``{"next", "ack"}``: send again from frame ``next``; frames below ``ack`` are durable
here). Bad frames are rejected whole and logged (logger ``sonarmap.team.node``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack

from ..errors import InputError
from .records import UnpackError, unpack_strict
from .rejects import RejectLog
from .transport import Message, Transport, ZmqTransport
from .wire import KINDS

__all__ = [
    "DEFAULT_MAX_QUEUE",
    "LOCK_SLACK",
    "ExchangerPort",
    "Frame",
    "FrameError",
    "ReliableLink",
    "decode_done",
    "decode_frame",
    "decode_hello",
]

logger = logging.getLogger("sonarmap.team.node")

_LOCK_KINDS = frozenset({*KINDS, "done", "bye"})
_Q_LIMIT = 2**62
#: Frames a receiver keeps aside ahead of the one it waits for, at most.
_WINDOW = 100_000
#: Bytes a lock frame adds around an exchanger body, at most.
LOCK_SLACK = 4096
#: Bytes of frames kept per peer, by default: sent and not yet acknowledged, and
#: received ahead of the one awaited (each bound on its own).
DEFAULT_MAX_QUEUE = 64 << 20
#: Bytes a frame is counted for besides its body (its number, tick, kind, the list).
_FRAME_OVERHEAD = 64


# --- the messages the exchanger sees ---------------------------------------------------


class ExchangerPort(Transport):
    """The exchanger's transport: what it sends is collected for the tick, what it
    polls is what the lock-step hands it."""

    def __init__(self, robot: int, peers: Iterable[int], max_message: int) -> None:
        super().__init__(robot, max_message=max_message)
        self.peers = set(peers)
        self.inbox: list[Message] = []
        self.outbox: list[tuple[int, str, bytes]] = []
        self._next: tuple[str, bytes] = ("data", b"")

    def send(self, dst: int, payload: bytes, kind: str = "data") -> bool:
        # The base class checks and sizes the envelope as the simulated transport does;
        # the envelope itself is the outer transport's business.
        self._next = (kind, payload)
        return super().send(dst, payload, kind)

    def _send_frame(self, dst: int, data: bytes) -> str | None:
        if dst not in self.peers:
            return "unknown_peer"
        self.outbox.append((dst, *self._next))
        return None

    def poll(self, timeout: float = 0.0) -> list[Message]:
        out, self.inbox = self.inbox, []
        return out

    def close(self) -> None:
        self.closed = True


# --- reliable numbered frames ----------------------------------------------------------


@dataclass
class Frame:
    q: int
    tick: int
    kind: str
    body: bytes


def _pack(d: Any) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


class FrameError(ValueError):
    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(detail)


def _int_field(d: Mapping[str, Any], key: str, limit: int = _Q_LIMIT) -> int:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < limit:
        raise FrameError("type", f"{key}: an int in [0, {limit}) expected, got {v!r}")
    return v


def _strict_map(body: bytes, keys: set[str]) -> dict[str, Any]:
    try:
        d = unpack_strict(body, max_bin=len(body), max_str=64, max_array=8, max_map=8)
    except UnpackError as e:
        raise FrameError(e.reason, str(e)) from None
    if not isinstance(d, dict) or set(d) != keys:
        raise FrameError("keys", f"a map of {sorted(keys)} expected")
    return d


def decode_frame(body: bytes) -> Frame:
    d = _strict_map(body, {"q", "t", "k", "b"})
    q, tick = _int_field(d, "q"), _int_field(d, "t")
    kind, inner = d["k"], d["b"]
    if not isinstance(kind, str) or kind not in _LOCK_KINDS:
        raise FrameError("kind", f"frame kind {kind!r} unknown")
    if not isinstance(inner, bytes):
        raise FrameError("type", "b: bytes expected")
    if kind == "done":
        decode_done(inner)
    return Frame(q, tick, kind, inner)


def decode_done(body: bytes) -> tuple[int, bool, int]:
    d = _strict_map(body, {"ch", "out", "ack"})
    out = d["out"]
    if not isinstance(out, bool):
        raise FrameError("type", "out: a bool expected")
    return _int_field(d, "ch"), out, _int_field(d, "ack")


def decode_hello(body: bytes) -> tuple[int, int]:
    """A ``hello``'s (next, ack)."""
    d = _strict_map(body, {"next", "ack"})
    return _int_field(d, "next"), _int_field(d, "ack")


def _size(f: Frame) -> int:
    return len(f.body) + _FRAME_OVERHEAD


class ReliableLink:
    """Numbered, acknowledged frames between this node and each peer, over a
    :class:`ZmqTransport`.

    Parameters
    ----------
    transport : ZmqTransport
    peers : sequence of int
    wait_timeout : float
        Seconds an awaited peer may go without sending a new frame (:meth:`wait`).
    retry : float
        Seconds between requests to send again while waiting; a peer's requests are
        served with the whole log at most once per half of it (the peers of a team
        share one value, so a waiting peer is served at every request).
    max_queue : int
        Bytes of frames kept per peer: sent and not acknowledged (past it the node
        fails, naming the peer), and received early (past it an early frame is
        rejected; the peer sends it again when asked). Default
        :data:`DEFAULT_MAX_QUEUE`.
    durable : bool
        Whether this node checkpoints what it receives: True. A node without a state
        folder cannot resume, so it acknowledges frames as it takes them and its peers
        need not keep them.
    """

    def __init__(
        self,
        transport: ZmqTransport,
        peers: Sequence[int],
        *,
        wait_timeout: float,
        retry: float,
        max_queue: int = DEFAULT_MAX_QUEUE,
        durable: bool = True,
    ) -> None:
        self.zmq = transport
        self.robot = transport.robot
        self.peers = list(peers)
        self.wait_timeout = wait_timeout
        self.retry = retry
        self.max_queue = max_queue
        self.durable = durable
        self.log_bytes = dict.fromkeys(self.peers, 0)
        self.early_bytes = dict.fromkeys(self.peers, 0)
        self.out_q = dict.fromkeys(self.peers, 0)
        self.log: dict[int, list[Frame]] = {j: [] for j in self.peers}
        self.next_q = dict.fromkeys(self.peers, 0)
        self.early: dict[int, dict[int, Frame]] = {j: {} for j in self.peers}
        self.inbox: dict[int, list[Frame]] = {j: [] for j in self.peers}
        #: Highest tick whose ``done`` marker came from each peer (-1: none).
        self.done = dict.fromkeys(self.peers, -1)
        self.markers: dict[int, dict[int, tuple[int, bool]]] = {j: {} for j in self.peers}
        self.bye: set[int] = set()
        #: Frames below these numbers are durable at the peer (its acks).
        self.acked_by = dict.fromkeys(self.peers, 0)
        #: Frames below these numbers are durable here (in our last checkpoint).
        self.ack_mine = dict.fromkeys(self.peers, 0)
        now = time.monotonic()
        #: When each peer last sent anything valid, and last sent a new frame in order.
        self.heard = dict.fromkeys(self.peers, now)
        self.progressed = dict.fromkeys(self.peers, now)
        self.rejected = 0
        #: Frames sent again at a peer's request, over all peers.
        self.resent = 0
        #: When the log was last sent again to each peer, and from which frame: a
        #: request that soon after is served only with the frames below that one.
        self.resent_at = dict.fromkeys(self.peers, -float("inf"))
        self.resent_from = dict.fromkeys(self.peers, 0)
        #: Restored from a checkpoint: frames may have gone out after it (see the module).
        self.resumed = False
        self._rejects = RejectLog(logger)

    # state

    def state(self) -> dict[str, Any]:
        def frames(fs: Iterable[Frame]) -> list[Any]:
            return [[f.q, f.tick, f.kind, f.body] for f in fs]

        return {
            "out_q": _pairs(self.out_q),
            "log": [[j, frames(self.log[j])] for j in self.peers],
            "next_q": _pairs(self.next_q),
            "early": [[j, frames(self.early[j].values())] for j in self.peers],
            "inbox": [[j, frames(self.inbox[j])] for j in self.peers],
            "done": _pairs(self.done),
            "markers": [
                [j, [[t, c, o] for t, (c, o) in sorted(self.markers[j].items())]]
                for j in self.peers
            ],
            "bye": sorted(self.bye),
            "acked_by": _pairs(self.acked_by),
        }

    def restore(self, s: Mapping[str, Any]) -> None:
        def frames(rows: Iterable[Any]) -> list[Frame]:
            return [Frame(int(q), int(t), str(k), bytes(b)) for q, t, k, b in rows]

        self.out_q = _unpairs(s["out_q"])
        self.log = {int(j): frames(fs) for j, fs in s["log"]}
        self.next_q = _unpairs(s["next_q"])
        self.early = {int(j): {f.q: f for f in frames(fs)} for j, fs in s["early"]}
        self.inbox = {int(j): frames(fs) for j, fs in s["inbox"]}
        self.done = _unpairs(s["done"])
        self.markers = {
            int(j): {int(t): (int(c), bool(o)) for t, c, o in rows} for j, rows in s["markers"]
        }
        self.bye = {int(j) for j in s["bye"]}
        self.acked_by = _unpairs(s["acked_by"])
        self.ack_mine = dict(self.next_q)
        self.resumed = True
        self.log_bytes = {j: sum(map(_size, fs)) for j, fs in self.log.items()}
        self.early_bytes = {j: sum(map(_size, fs.values())) for j, fs in self.early.items()}

    # sending

    def send(self, dst: int, tick: int, kind: str, body: bytes) -> None:
        """Number, log and send a frame; :class:`InputError` naming ``dst`` if the
        frames it has not acknowledged would pass ``max_queue`` bytes."""
        f = Frame(self.out_q[dst], tick, kind, body)
        if self.log_bytes[dst] + _size(f) > self.max_queue:
            raise InputError(
                f"robot {self.robot}: the frames sent to robot {dst} and not acknowledged "
                f"would pass {self.max_queue} bytes (--max-queue): robot {dst} takes or "
                "checkpoints nothing",
                field="max_queue",
            )
        self.out_q[dst] += 1
        self.log[dst].append(f)
        self.log_bytes[dst] += _size(f)
        self._transmit(dst, f)

    def _transmit(self, dst: int, f: Frame) -> None:
        # A refused send stays in the log: the peer asks again when it waits for it.
        self.zmq.send(dst, _pack({"q": f.q, "t": f.tick, "k": f.kind, "b": f.body}), "lock")

    def mark_done(self, tick: int, changes: int, outstanding: bool) -> None:
        """Send every peer the ``done`` marker of ``tick``: the robot's count of poses
        the exchange added and deleted, and whether it awaits an answer."""
        for j in self.peers:
            done = _pack({"ch": changes, "out": outstanding, "ack": self._ack(j)})
            self.send(j, tick, "done", done)

    def _ack(self, j: int) -> int:
        """Frames of ``j`` below this number need not be sent again."""
        return self.ack_mine[j] if self.durable else self.next_q[j]

    def forget_markers(self, before: int) -> None:
        """Drop the peers' markers of ticks before ``before``."""
        for j in self.peers:
            for old in [k for k in self.markers[j] if k < before]:
                del self.markers[j][old]

    def hello(self, peers: Iterable[int]) -> None:
        for j in peers:
            self.zmq.send(j, _pack({"next": self.next_q[j], "ack": self._ack(j)}), "hello")

    def _trim(self, j: int) -> None:
        log, ack = self.log[j], self.acked_by[j]
        if log and log[0].q < ack:
            self.log[j] = [f for f in log if f.q >= ack]
            self.log_bytes[j] = sum(map(_size, self.log[j]))

    def _resend(self, j: int, start: int) -> None:
        # A request to send again is served with the whole log at most once per half
        # retry; one sooner gets only the frames below those the last one covered. A
        # peer asking in a loop (a bug or a forgery) then costs one log per half
        # retry, not one per request, and one line at most.
        now = time.monotonic()
        fresh = now - self.resent_at[j] >= self.retry / 2
        if fresh:
            self.resent_at[j], self.resent_from[j] = now, self.out_q[j]
        stop = self.resent_from[j]
        self.resent_from[j] = min(start, stop)
        log = self.log[j]
        first = log[0].q if log else self.out_q[j]
        if start < first and fresh:
            logger.error(
                "robot %d: robot %d asks again from frame %d, but frames before %d are gone "
                "(its state folder was lost?)",
                self.robot,
                j,
                start,
                first,
            )
        for f in log:
            if start <= f.q < stop:
                self._transmit(j, f)
                self.resent += 1

    # receiving

    def pump(self, timeout: float) -> bool:
        """Take what arrived (waiting up to ``timeout`` s for a first message); True if
        any frame came in order."""
        progress = False
        for msg in self.zmq.poll(timeout):
            j = msg.src
            if j not in self.next_q:
                self._reject(j, "peer", f"robot {j} is not a peer")
                continue
            try:
                if msg.kind == "hello":
                    start, ack = decode_hello(msg.payload)
                    self.heard[j] = time.monotonic()
                    self._hello_from(j, start, ack)
                elif msg.kind == "lock":
                    f = decode_frame(msg.payload)
                    self.heard[j] = time.monotonic()
                    if self._take(j, f):
                        progress = True
                        self.progressed[j] = self.heard[j]
                else:
                    raise FrameError("kind", f"envelope kind {msg.kind[:16]!r} unknown")
            except FrameError as e:
                self._reject(j, e.reason, str(e))
            except Exception as e:
                # A peer's bytes: whatever they make the decoder raise rejects the frame.
                self._reject(j, "decode", f"{type(e).__name__}: {e}")
        return progress

    def _claim(self, j: int, what: str, claimed: int) -> int:
        """A peer's claim to hold our frames below ``claimed``, checked against what we
        sent it: the part beyond is never acted on, and (unless we resumed, see the
        module) a protocol error."""
        if claimed <= self.out_q[j]:
            return claimed
        if not self.resumed:
            raise FrameError(
                "claim", f"{what} {claimed} claims frames never sent (sent {self.out_q[j]})"
            )
        return self.out_q[j]

    def _hello_from(self, j: int, start: int, ack: int) -> None:
        start, ack = self._claim(j, "next", start), self._claim(j, "ack", ack)
        self.acked_by[j] = max(self.acked_by[j], ack)
        self._trim(j)
        self._resend(j, start)

    def _reject(self, j: int, reason: str, detail: str) -> None:
        self.rejected += 1
        self._rejects.warn(
            f"robot {self.robot} rejected a frame from robot {j} ({reason}): {detail}"
        )

    def _take(self, j: int, f: Frame) -> bool:
        if f.q < self.next_q[j]:
            return False  # a copy of one we have
        if f.q >= self.next_q[j] + _WINDOW:
            raise FrameError("window", f"frame {f.q} is far ahead of {self.next_q[j]}")
        if f.kind == "done":
            # Checked on arrival, before it can take its place in the sequence.
            self._claim(j, "done ack", decode_done(f.body)[2])
        if f.q in self.early[j]:
            return False  # a copy of one kept aside
        if f.q != self.next_q[j] and self.early_bytes[j] + _size(f) > self.max_queue:
            raise FrameError(
                "queue",
                f"frames kept aside from robot {j} would pass {self.max_queue} bytes "
                f"(--max-queue); frame {f.q} dropped, to be asked for again",
            )
        self.early[j][f.q] = f
        self.early_bytes[j] += _size(f)
        progress = False
        while self.next_q[j] in self.early[j]:
            g = self.early[j].pop(self.next_q[j])
            self.early_bytes[j] -= _size(g)
            self.next_q[j] += 1
            progress = True
            if g.kind == "done":
                ch, out, ack = decode_done(g.body)
                self.done[j] = max(self.done[j], g.tick)
                self.markers[j][g.tick] = (ch, out)
                self.acked_by[j] = max(self.acked_by[j], min(ack, self.out_q[j]))
                self._trim(j)
            elif g.kind == "bye":
                self.bye.add(j)
            else:
                self.inbox[j].append(g)
        return progress

    def wait(self, ready: Callable[[], list[int]], what: str) -> None:
        """Pump until ``ready()`` names no peer still awaited; ask the awaited peers to
        send again every ``retry`` s; fail after ``wait_timeout`` s without a new frame
        from an awaited peer (whatever else it sends meanwhile)."""
        last_ask = time.monotonic()
        while True:
            missing = ready()
            if not missing:
                return
            now = time.monotonic()
            for j in missing:
                if now - self.progressed[j] > self.wait_timeout:
                    where = f"peer robot {j} ({self.zmq.peers.get(j, '?')})"
                    if now - self.heard[j] > self.wait_timeout:
                        raise InputError(
                            f"robot {self.robot}: {where} sent nothing for "
                            f"{self.wait_timeout:g} s while awaited for {what}: not started, "
                            "unreachable, or stopped and not restarted",
                            field="peers",
                        )
                    raise InputError(
                        f"robot {self.robot}: {where} sent no new frame for "
                        f"{self.wait_timeout:g} s while awaited for {what}, only requests "
                        "or frames out of sequence: a peer that lost its state, or not one "
                        "of the team",
                        field="peers",
                    )
            if now - last_ask >= self.retry:
                self.hello(missing)
                last_ask = now
            self.pump(min(self.retry, 0.05))

    def take(self, upto: Mapping[int, int]) -> list[tuple[int, int, Frame]]:
        """The exchanger frames of each peer up to tick ``upto[j]``, in the simulated
        network's delivery order: (tick, sender, number)."""
        out: list[tuple[int, int, Frame]] = []
        for j in self.peers:
            keep: list[Frame] = []
            for f in self.inbox[j]:
                if f.tick <= upto[j]:
                    out.append((f.tick, j, f))
                else:
                    keep.append(f)
            self.inbox[j] = keep
        out.sort(key=lambda x: (x[0], x[1], x[2].q))
        return out


def _pairs(d: Mapping[int, int]) -> list[list[int]]:
    return [[k, v] for k, v in d.items()]


def _unpairs(rows: Iterable[Any]) -> dict[int, int]:
    return {int(k): int(v) for k, v in rows}
