"""A team over a real network (issue 15): every robot its own OS process, exchanging
over ZeroMQ on TCP (:class:`~.transport.ZmqTransport`). :func:`run_node` runs one
robot; :func:`run_zmq_team` starts a local team of such processes
(``python -m sonarmap team node``) and gathers their summaries.

**The clock: lock-step.** A robot's own store does depend on the exchange (its new
poses are associated with the poses it received; closures change landmark stamps, and
so compression, and the graph batches move its estimates), so a node cannot drive its
route alone and exchange afterwards without changing its results. Instead the nodes
advance mission time together, tick by tick, exactly as :func:`~.simulation.run_team`
does on its simulated full network (no loss, no delay, no bandwidth cap):

- The ticks are the union of every robot's route time stamps, then the quiet phase's
  ticks of the median step. Every node needs every route: the launcher draws them once
  (or takes the given ones, e.g. the patroller's) and hands them over as ``.npy`` files
  (:func:`save_routes`, exact float64); a node given none draws them from the seed.
- At tick ``n`` robot ``i`` processes its route up to the tick, then hands its
  exchanger the messages the simulation would have delivered by then: those robots
  ``j < i`` sent at tick ``n`` and robots ``j > i`` sent at tick ``n - 1``, in the
  simulation's order (tick, sender, send order). Then it steps its exchanger and sends
  what the exchanger sent, followed by a ``done`` marker for the tick, which carries
  the robot's count of poses added and deleted by the exchange and whether it awaits
  an answer.
- A node waits (on the wall clock) until those markers arrived. With every node's
  markers of a tick in hand, each evaluates the simulation's quiet-network rule on the
  team's sums and all stop at the same tick.

So "same results" here means: on the same seeded mission (plan, :class:`MissionConfig`,
robots, :class:`ExchangeParams`), each node ends with the same own store, byte for byte
(:func:`store_digest`), the same received layers, the same held pose UIDs (so
``duplicate_poses`` and ``identical_maps`` agree), the same exchange counters and the
same scores as robot ``i`` of ``run_team`` with ``NetworkParams(kind="full")``, except
for the wall-clock keys and the scores of closures to another robot's merged poses
(the node knows a merged pose's origin only from the poses it received; the simulation
looks it up in the other robots' memory). The exchanger's ``request_timeout`` and
``peer_timeout`` count mission time, which stops while a peer is away, so they never
fire on the zmq transport: a peer that vanishes stops the team's clock until it
returns (up to ``wait_timeout`` wall seconds, then each waiting node fails with one
line naming the silent peer).

**Reliable frames over a lossy socket.** Every frame a node sends a peer (exchanger
messages and markers) is numbered per destination and kept in a log until the peer
acknowledges it durably (its checkpoint holds it); a receiver takes frames in number
order, drops the ones it has and keeps early ones aside. A node stuck waiting asks the
peer to send again from the first number it lacks (``hello``), which covers a socket
that refused a frame (peer not connected yet) and a restarted peer.

**Kill and restart.** A node writes its whole state every ``checkpoint_every`` wall
seconds to ``state_dir/state.msgpack`` (msgpack of the records' own encodings, never
pickle; written to a temporary file and renamed): the store (all layers, patches,
closures and the store's counters), the agent's route position and scoring counters,
the exchanger's stamps, adverts and pending requests, and the frame logs. Restarted on
the same ``state_dir`` it resumes at the tick after its checkpoint and asks its peers
to send again what it has not yet taken; the ticks it repeats make the same frames
with the same numbers (everything is deterministic), which the peers drop. The team
ends as it would have without the kill.

A node's frames on the wire (envelope kinds): ``lock`` (a numbered frame:
``{"q", "t", "k", "b"}``, ``k`` an exchanger kind, ``done`` or ``bye``) and ``hello``
(``{"next", "ack"}``: send again from frame ``next``; frames below ``ack`` are durable
here). Bad frames are rejected whole and logged (logger ``sonarmap.team.node``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import ChainMap, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError, InputError
from ..files import atomic_folder, atomic_outputs, atomic_write, atomic_write_text, json_dumps
from ..io.rosmap import OccupancyMap, read_map, write_map
from .exchange import (
    KINDS,
    MODES,
    AdvertEntry,
    ExchangeParams,
    Exchanger,
    PatchKey,
    _Pending,
)
from .mission import ODOMETRY_NOISE, MissionConfig, RobotAgent
from .naive import NaiveMeter
from .network import NetworkParams
from .records import (
    ClosureEdge,
    OdometryEdge,
    Pose,
    RecordError,
    UnpackError,
    decode,
    encode,
    make_uid,
    unpack_strict,
)
from .regions import region_adjacency
from .simulation import held_uids, map_agreement
from .store import Layer, Patch, RobotStore, StoreParams
from .transport import DEFAULT_MAX_MESSAGE, Message, Transport, ZmqTransport
from .world import make_world, odometry, patrol_route

__all__ = [
    "STATE_FILE",
    "SUMMARY_FILE",
    "LockstepParams",
    "ZmqTeamResult",
    "load_routes",
    "parse_exchange",
    "parse_peers",
    "run_node",
    "run_zmq_team",
    "save_routes",
    "store_digest",
]

logger = logging.getLogger("sonarmap.team.node")

F64 = npt.NDArray[np.float64]
Progress = Callable[[int, int], None]

#: The checkpoint's file name in a node's state folder.
STATE_FILE = "state.msgpack"
#: The node's summary in its output folder.
SUMMARY_FILE = "summary.json"
_STATE_VERSION = 1
_LOCK_KINDS = frozenset({*KINDS, "done", "bye"})
_Q_LIMIT = 2**62
#: Frames a receiver keeps aside ahead of the one it waits for, at most.
_WINDOW = 100_000
#: Bytes a lock frame adds around an exchanger body, at most.
_LOCK_SLACK = 4096


@dataclass(frozen=True)
class LockstepParams:
    """Wall-clock settings of a node (none changes its results).

    Attributes
    ----------
    wait_timeout : float
        Seconds a node waits for a silent peer before failing: 300.
    retry : float
        Seconds between requests to send again while waiting: 0.5.
    checkpoint_every : float
        Seconds between checkpoints (with a state folder): 5.
    linger : float
        Seconds a finished node stays to serve its peers' last requests: 120.
    """

    wait_timeout: float = 300.0
    retry: float = 0.5
    checkpoint_every: float = 5.0
    linger: float = 120.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ConfigError(f"node: {f.name} must be a number > 0, got {v!r}")
            if not math.isfinite(v):
                raise ConfigError(f"node: {f.name} must be finite, got {v!r}")


def parse_peers(text: str, robot: int) -> dict[int, str]:
    """``--peers``: comma-separated ``ID=ADDRESS`` items, or bare addresses given to the
    robots 0, 1, ... other than ``robot``, in order."""
    items = [s.strip() for s in text.split(",") if s.strip()]
    out: dict[int, str] = {}
    bare = [s for s in items if "=" not in s]
    if bare and len(bare) != len(items):
        raise ConfigError("--peers: give every peer as ID=ADDRESS, or none")
    if bare:
        ids = [j for j in range(len(items) + 1) if j != robot]
        return dict(zip(ids, items, strict=False))
    for s in items:
        key, _, address = s.partition("=")
        if not key.strip().isdigit():
            raise ConfigError(f"--peers: {key.strip()!r} in {s!r} is not a robot id")
        j = int(key)
        if j in out:
            raise ConfigError(f"--peers: robot {j} is given twice")
        out[j] = address.strip()
    return out


def _parse_bool(text: str) -> bool:
    """``true``/``false`` (any case) or ``1``/``0``; ValueError otherwise."""
    low = text.lower()
    if low in ("true", "1"):
        return True
    if low in ("false", "0"):
        return False
    raise ValueError(text)


def parse_exchange(items: Sequence[str]) -> ExchangeParams:
    """``--exchange KEY=VALUE`` items as :class:`ExchangeParams` (the others default)."""
    kinds = {f.name: type(getattr(ExchangeParams(), f.name)) for f in fields(ExchangeParams)}
    values: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or key not in kinds:
            raise ConfigError(
                f"--exchange expects KEY=VALUE with KEY one of {', '.join(kinds)}, got {item!r}"
            )
        try:
            values[key] = _parse_bool(value) if kinds[key] is bool else kinds[key](value)
        except ValueError:
            raise ConfigError(
                f"--exchange {key}: {kinds[key].__name__} expected, got {value!r}"
            ) from None
    ex = ExchangeParams(**values)
    if ex.mode not in MODES:
        raise ConfigError(
            f"--exchange mode: the zmq transport runs {' and '.join(MODES)}, not {ex.mode!r}"
        )
    return ex


def save_routes(folder: Path, routes: Sequence[F64]) -> None:
    """Write each robot's route (T, 4) to ``folder/robotK.npy`` (exact float64: the
    nodes must drive the very routes the launcher drew)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, r in enumerate(routes):
        with atomic_outputs(folder / f"robot{i}.npy") as (tmp,), open(tmp, "wb") as f:
            np.save(f, np.asarray(r, dtype=np.float64), allow_pickle=False)


def load_routes(folder: Path, robots: int) -> list[F64]:
    """The routes :func:`save_routes` wrote for robots 0..robots-1."""
    out: list[F64] = []
    for i in range(robots):
        path = Path(folder) / f"robot{i}.npy"
        try:
            r = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read robot {i}'s route: {e}", path=path) from None
        ok = r.ndim == 2 and r.shape[1] == 4 and len(r) > 0 and r.dtype == np.float64
        if not ok or not np.isfinite(r).all() or (np.diff(r[:, 0]) <= 0).any():
            raise InputError("a route is rows of finite t, x, y, theta, t increasing", path=path)
        out.append(r)
    return out


def _check_team(robot: int, peers: Mapping[int, str]) -> list[int]:
    ids = sorted({robot, *peers})
    if robot in peers:
        raise ConfigError(f"--peers: robot {robot} is this node itself")
    if ids != list(range(len(ids))):
        raise ConfigError(
            f"robot ids must be 0..N-1 (they seed the routes, as in 'team run'), got {ids}"
        )
    return ids


# --- the messages the exchanger sees ---------------------------------------------------


class _Inner(Transport):
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
class _Frame:
    q: int
    tick: int
    kind: str
    body: bytes


def _pack(d: Any) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


class _FrameError(ValueError):
    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(detail)


def _int_field(d: Mapping[str, Any], key: str, limit: int = _Q_LIMIT) -> int:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < limit:
        raise _FrameError("type", f"{key}: an int in [0, {limit}) expected, got {v!r}")
    return v


def _strict_map(body: bytes, keys: set[str]) -> dict[str, Any]:
    try:
        d = unpack_strict(body, max_bin=len(body), max_str=64, max_array=8, max_map=8)
    except UnpackError as e:
        raise _FrameError(e.reason, str(e)) from None
    if not isinstance(d, dict) or set(d) != keys:
        raise _FrameError("keys", f"a map of {sorted(keys)} expected")
    return d


def _decode_lock(body: bytes) -> _Frame:
    d = _strict_map(body, {"q", "t", "k", "b"})
    q, tick = _int_field(d, "q"), _int_field(d, "t")
    kind, inner = d["k"], d["b"]
    if not isinstance(kind, str) or kind not in _LOCK_KINDS:
        raise _FrameError("kind", f"frame kind {kind!r} unknown")
    if not isinstance(inner, bytes):
        raise _FrameError("type", "b: bytes expected")
    if kind == "done":
        _decode_done(inner)
    return _Frame(q, tick, kind, inner)


def _decode_done(body: bytes) -> tuple[int, bool, int]:
    d = _strict_map(body, {"ch", "out", "ack"})
    out = d["out"]
    if not isinstance(out, bool):
        raise _FrameError("type", "out: a bool expected")
    return _int_field(d, "ch"), out, _int_field(d, "ack")


class _Link:
    """Numbered, acknowledged frames between this node and each peer, over a
    :class:`ZmqTransport`."""

    def __init__(
        self, transport: ZmqTransport, peers: Sequence[int], timing: LockstepParams
    ) -> None:
        self.zmq = transport
        self.robot = transport.robot
        self.peers = list(peers)
        self.timing = timing
        self.out_q = dict.fromkeys(self.peers, 0)
        self.log: dict[int, list[_Frame]] = {j: [] for j in self.peers}
        self.next_q = dict.fromkeys(self.peers, 0)
        self.early: dict[int, dict[int, _Frame]] = {j: {} for j in self.peers}
        self.inbox: dict[int, list[_Frame]] = {j: [] for j in self.peers}
        #: Highest tick whose ``done`` marker came from each peer (-1: none).
        self.done = dict.fromkeys(self.peers, -1)
        self.markers: dict[int, dict[int, tuple[int, bool]]] = {j: {} for j in self.peers}
        self.bye: set[int] = set()
        #: Frames below these numbers are durable at the peer (its acks).
        self.acked_by = dict.fromkeys(self.peers, 0)
        #: Frames below these numbers are durable here (in our last checkpoint).
        self.ack_mine = dict.fromkeys(self.peers, 0)
        self.heard = dict.fromkeys(self.peers, time.monotonic())
        self.rejected = 0

    # state

    def state(self) -> dict[str, Any]:
        def frames(fs: Iterable[_Frame]) -> list[Any]:
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
        def frames(rows: Iterable[Any]) -> list[_Frame]:
            return [_Frame(int(q), int(t), str(k), bytes(b)) for q, t, k, b in rows]

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

    # sending

    def send(self, dst: int, tick: int, kind: str, body: bytes) -> None:
        f = _Frame(self.out_q[dst], tick, kind, body)
        self.out_q[dst] += 1
        self.log[dst].append(f)
        self._transmit(dst, f)

    def _transmit(self, dst: int, f: _Frame) -> None:
        # A refused send stays in the log: the peer asks again when it waits for it.
        self.zmq.send(dst, _pack({"q": f.q, "t": f.tick, "k": f.kind, "b": f.body}), "lock")

    def hello(self, peers: Iterable[int]) -> None:
        for j in peers:
            self.zmq.send(j, _pack({"next": self.next_q[j], "ack": self.ack_mine[j]}), "hello")

    def _trim(self, j: int) -> None:
        log, ack = self.log[j], self.acked_by[j]
        if log and log[0].q < ack:
            self.log[j] = [f for f in log if f.q >= ack]

    def _resend(self, j: int, start: int) -> None:
        log = self.log[j]
        first = log[0].q if log else self.out_q[j]
        if start < first:
            logger.error(
                "robot %d: robot %d asks again from frame %d, but frames before %d are gone "
                "(its state folder was lost?)",
                self.robot,
                j,
                start,
                first,
            )
        for f in log:
            if f.q >= start:
                self._transmit(j, f)

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
            self.heard[j] = time.monotonic()
            try:
                if msg.kind == "hello":
                    d = _strict_map(msg.payload, {"next", "ack"})
                    start, ack = _int_field(d, "next"), _int_field(d, "ack")
                    self.acked_by[j] = max(self.acked_by[j], ack)
                    self._trim(j)
                    self._resend(j, start)
                elif msg.kind == "lock":
                    progress = self._take(j, _decode_lock(msg.payload)) or progress
                else:
                    raise _FrameError("kind", f"envelope kind {msg.kind!r} unknown")
            except _FrameError as e:
                self._reject(j, e.reason, str(e))
        return progress

    def _reject(self, j: int, reason: str, detail: str) -> None:
        self.rejected += 1
        logger.warning(
            "robot %d rejected a frame from robot %d (%s): %s", self.robot, j, reason, detail
        )

    def _take(self, j: int, f: _Frame) -> bool:
        if f.q < self.next_q[j]:
            return False  # a copy of one we have
        if f.q >= self.next_q[j] + _WINDOW:
            raise _FrameError("window", f"frame {f.q} is far ahead of {self.next_q[j]}")
        self.early[j][f.q] = f
        progress = False
        while self.next_q[j] in self.early[j]:
            g = self.early[j].pop(self.next_q[j])
            self.next_q[j] += 1
            progress = True
            if g.kind == "done":
                ch, out, ack = _decode_done(g.body)
                self.done[j] = max(self.done[j], g.tick)
                self.markers[j][g.tick] = (ch, out)
                self.acked_by[j] = max(self.acked_by[j], ack)
                self._trim(j)
            elif g.kind == "bye":
                self.bye.add(j)
            else:
                self.inbox[j].append(g)
        return progress

    def wait(self, ready: Callable[[], list[int]], what: str) -> None:
        """Pump until ``ready()`` names no peer still awaited; ask the awaited peers to
        send again every ``retry`` s; fail after ``wait_timeout`` s of silence."""
        last_ask = time.monotonic()
        while True:
            missing = ready()
            if not missing:
                return
            now = time.monotonic()
            for j in missing:
                if now - self.heard[j] > self.timing.wait_timeout:
                    raise InputError(
                        f"robot {self.robot}: peer robot {j} ({self.zmq.peers.get(j, '?')}) "
                        f"sent nothing for {self.timing.wait_timeout:g} s while awaited for "
                        f"{what}: not started, unreachable, or stopped and not restarted",
                        field="peers",
                    )
            if now - last_ask >= self.timing.retry:
                self.hello(missing)
                last_ask = now
            self.pump(min(self.timing.retry, 0.05))

    def take(self, upto: Mapping[int, int]) -> list[tuple[int, int, _Frame]]:
        """The exchanger frames of each peer up to tick ``upto[j]``, in the simulated
        network's delivery order: (tick, sender, number)."""
        out: list[tuple[int, int, _Frame]] = []
        for j in self.peers:
            keep: list[_Frame] = []
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


# --- state of the store, the agent and the exchanger -------------------------------------


def _layer_state(layer: Layer) -> dict[str, Any]:
    return {
        "source": layer.source,
        "poses": [encode(p) for p in layer.poses.values()],
        "edges": [encode(e) for e in layer.edges],
        "patches": [
            [r, float(p.stamp), sorted(p.short), sorted(p.full)] for r, p in layer.patches.items()
        ],
    }


def _layer_from(s: Mapping[str, Any], own: bool) -> Layer:
    layer = Layer(int(s["source"]), own=own)
    for b in s["poses"]:
        p = _record(b, Pose)
        layer.poses[p.uid] = p
    layer.edges = [_record(b, OdometryEdge) for b in s["edges"]]
    layer.patches = {
        int(r): Patch(float(stamp), {int(u) for u in short}, {int(u) for u in full})
        for r, stamp, short, full in s["patches"]
    }
    return layer


def _record(b: Any, kind: type[Any]) -> Any:
    if not isinstance(b, bytes):
        raise RecordError("a record's bytes expected")
    rec = decode(b)
    if not isinstance(rec, kind):
        raise RecordError(f"a {kind.__name__} expected, got {type(rec).__name__}")
    return rec


def _store_state(store: RobotStore) -> dict[str, Any]:
    return {
        "local": _layer_state(store.local),
        "received": [_layer_state(store.received[s]) for s in store.received],
        "closures": [encode(c) for c in store.closures],
        "peak_bytes": store.peak_bytes,
        "peak_local_bytes": store.peak_local_bytes,
        "merges": store._merges,
        "newest": store._newest,
    }


def _store_into(store: RobotStore, s: Mapping[str, Any]) -> None:
    store.local = _layer_from(s["local"], own=True)
    store.received = {}
    for ls in s["received"]:
        layer = _layer_from(ls, own=False)
        store.received[layer.source] = layer
    store.closures = [_record(b, ClosureEdge) for b in s["closures"]]
    store.peak_bytes = int(s["peak_bytes"])
    store.peak_local_bytes = int(s["peak_local_bytes"])
    store._merges = int(s["merges"])
    store._newest = None if s["newest"] is None else int(s["newest"])


#: RobotAgent attributes kept as plain msgpack values.
_AGENT_PLAIN = (
    "bytes_per_pose",
    "n_true_pairs",
    "n_correct",
    "n_closures",
    "n_found",
    "n_same_place",
    "received_closures",
    "received_correct",
    "wrong",
    "stage_removed",
    "stages",
    "by_half",
    "assoc_seconds",
    "prev_k",
    "prev_uid",
    "counter",
    "k",
)


def _agent_state(a: RobotAgent) -> dict[str, Any]:
    d: dict[str, Any] = {name: getattr(a, name) for name in _AGENT_PLAIN}
    d["truth"] = [[u, [float(v) for v in x]] for u, x in a.truth.items()]
    d["odo_poses"] = [[u, [float(v) for v in x]] for u, x in a.odo_poses.items()]
    d["made"] = [encode(p) for p in a.made.values()]
    d["graph_dropped"] = [[k[0], k[1], v] for k, v in a.graph_dropped.items()]
    d["drift"] = [float(v) for v in np.asarray(a.drift).ravel()]
    return d


def _agent_into(a: RobotAgent, d: Mapping[str, Any]) -> None:
    for name in _AGENT_PLAIN:
        setattr(a, name, d[name])
    a.truth = {int(u): np.array(x, dtype=np.float64) for u, x in d["truth"]}
    a.odo_poses = {int(u): np.array(x, dtype=np.float64) for u, x in d["odo_poses"]}
    made = [_record(b, Pose) for b in d["made"]]
    a.made = {p.uid: p for p in made}
    a.graph_dropped = {(int(x), int(y)): bool(v) for x, y, v in d["graph_dropped"]}
    a.drift = np.array(d["drift"], dtype=np.float64).reshape(3, 3)


def _entry(e: AdvertEntry | None) -> list[Any] | None:
    return None if e is None else [e.source, e.region, float(e.stamp), e.held]


def _futile_entry(v: object) -> list[Any] | None:
    return _entry(v) if isinstance(v, AdvertEntry) else None


def _entry_from(v: Any) -> AdvertEntry | None:
    return None if v is None else AdvertEntry(int(v[0]), int(v[1]), float(v[2]), int(v[3]))


def _pending_state(p: _Pending) -> list[Any]:
    return [p.peer, sorted([list(k) for k in p.patches]), p.sent, p.deadline]


def _pending_from(v: Any) -> _Pending:
    return _Pending(int(v[0]), {(int(a), int(b)) for a, b in v[1]}, float(v[2]), float(v[3]))


def _tables_state(
    tables: Mapping[int, tuple[float, Mapping[PatchKey, AdvertEntry]]],
) -> list[list[Any]]:
    """Per peer, a time and an advert table as ``[peer, time, rows]`` (:func:`_table_from`)."""
    return [[p, t, [_entry(x) for x in table.values()]] for p, (t, table) in tables.items()]


def _table_from(rows: Sequence[Any]) -> dict[PatchKey, AdvertEntry]:
    entries = [x for x in (_entry_from(r) for r in rows) if x is not None]
    return {(x.source, x.region): x for x in entries}


def _exchanger_state(e: Exchanger) -> dict[str, Any]:
    counters = ("rejected", "bytes_by_kind")
    stats = {f.name: getattr(e.stats, f.name) for f in fields(e.stats) if f.name not in counters}
    return {
        "now": e._now,
        "next_advert": e._next_advert,
        "next_request": e._next_request,
        "adverts": _tables_state(e._adverts),
        "heard": [[p, t] for p, t in e._heard.items()],
        "whole": _tables_state(e._whole),
        "told": _tables_state(e._told),
        "in_reach": sorted(e._in_reach),
        "pending": [[i, _pending_state(p)] for i, p in e._pending.items()],
        "expired": [[i, _pending_state(p)] for i, p in e._expired.items()],
        "waiting": [[k[0], k[1], i] for k, i in e._waiting.items()],
        "timed_out": sorted([list(k) for k in e._timed_out]),
        "futile": [[list(k), _futile_entry(v[0]), *v[1:]] for k, v in e._futile.items()],
        "handed": [[r, s, sorted(u)] for r, (s, u) in e._handed.items()],
        "fetched": [[k[0], k[1], t] for k, t in e._fetched.items()],
        "starved": [[k[0], k[1], t] for k, t in e._starved.items()],
        "next_id": e._next_id,
        "published": None if e._published is None else _layer_state(e._published),
        "finished": e._finished,
        "anchors": None if e._chooser is None else e._chooser.state(),
        "by_share": [[u, w] for u, w in sorted(e._by_share.items())],
        "naive_log": [list(x) for x in e._naive_log],
        "end_spent": e._end_spent,
        "stats": stats,
        "rejected": dict(e.stats.rejected),
        "bytes_by_kind": dict(e.stats.bytes_by_kind),
    }


def _exchanger_into(e: Exchanger, d: Mapping[str, Any]) -> None:
    e._now = float(d["now"])
    e._next_advert = float(d["next_advert"])
    e._next_request = float(d["next_request"])
    e._adverts = {int(p): (float(at), _table_from(rows)) for p, at, rows in d["adverts"]}
    # A state saved before delta adverts has none of these: whole tables to everyone.
    e._heard = {int(p): float(t) for p, t in d.get("heard", [])}
    e._whole = {int(p): (float(t), _table_from(rows)) for p, t, rows in d.get("whole", [])}
    e._told = {int(p): (float(at), _table_from(rows)) for p, at, rows in d.get("told", [])}
    e._in_reach = frozenset(int(p) for p in d.get("in_reach", []))
    e._pending = {int(i): _pending_from(v) for i, v in d["pending"]}
    e._expired = {int(i): _pending_from(v) for i, v in d["expired"]}
    e._waiting = {(int(a), int(b)): int(i) for a, b, i in d["waiting"]}
    e._timed_out = {(int(a), int(b)) for a, b in d["timed_out"]}
    e._futile = {}
    for k, entry, *rest in d["futile"]:
        key = (int(k[0]), int(k[1]), int(k[2]))
        e._futile[key] = (_entry_from(entry), *rest)
    e._handed = {int(r): (float(s), frozenset(int(u) for u in us)) for r, s, us in d["handed"]}
    # A state saved before the refresh policy has neither: nothing fetched, nothing starved.
    e._fetched = {(int(a), int(b)): float(t) for a, b, t in d.get("fetched", [])}
    e._starved = {(int(a), int(b)): float(t) for a, b, t in d.get("starved", [])}
    e._next_id = int(d["next_id"])
    # A state saved before the hold existed has neither: nothing held back.
    pub = d.get("published")
    e._published = None if pub is None else _layer_from(pub, own=True)
    e._finished = bool(d.get("finished", False))
    # A state saved before loop anchors has none: the chooser starts afresh.
    if e._chooser is not None and d.get("anchors") is not None:
        e._chooser.restore(d["anchors"])
    # A state saved before the byte target has none: nothing decided yet.
    e._by_share = {int(u): bool(w) for u, w in d.get("by_share", [])}
    e._naive_log = deque((float(t), float(b)) for t, b in d.get("naive_log", []))
    e._end_spent = float(d.get("end_spent", 0.0))
    for name, v in d["stats"].items():
        setattr(e.stats, name, v)
    e.stats.rejected.clear()
    e.stats.rejected.update({str(k): int(v) for k, v in d["rejected"].items()})
    e.stats.bytes_by_kind.clear()
    # A state saved before the split by kind has none.
    e.stats.bytes_by_kind.update({str(k): int(v) for k, v in d.get("bytes_by_kind", {}).items()})


def store_digest(store: RobotStore) -> str:
    """SHA-256 of a store's local layer (poses and odometry edges, their encodings in
    UID order) and its closures: equal digests, equal own stores byte for byte."""
    h = hashlib.sha256()
    for uid in sorted(store.local.poses):
        h.update(encode(store.local.poses[uid]))
    for e in sorted(store.local.edges, key=lambda x: (x.a, x.b)):
        h.update(encode(e))
    for c in sorted(encode(c) for c in store.closures):
        h.update(c)
    return h.hexdigest()


def _fingerprint(
    plan: OccupancyMap,
    cfg: MissionConfig,
    robot: int,
    ids: Sequence[int],
    ex: ExchangeParams,
    routes: Sequence[F64],
) -> str:
    """What a state file must belong to: the same plan, mission, team, routes and
    exchange."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(plan.classes()).tobytes())
    for r in routes:
        h.update(np.ascontiguousarray(r, dtype=np.float64).tobytes())
    h.update(json.dumps([asdict(cfg), robot, list(ids), asdict(ex)], default=str).encode())
    return h.hexdigest()


# --- one node ------------------------------------------------------------------------------


def _route_truth(
    plan: OccupancyMap, cfg: MissionConfig, robot: int, route: F64 | None
) -> tuple[F64, dict[int, F64]]:
    """Another robot's route and the true pose of every pose it makes, by UID (what
    :meth:`RobotAgent.step` decides from odometry alone), for scoring received
    closures as the simulation does."""
    seed = cfg.seed + 7919 * robot
    true = patrol_route(plan, cfg.duration, seed=seed) if route is None else route
    true = np.asarray(true, dtype=np.float64)
    true = true[true[:, 0] <= true[0, 0] + cfg.duration]
    odo, _ = odometry(true, seed=seed + 1, **ODOMETRY_NOISE)
    truth: dict[int, F64] = {}
    prev: int | None = None
    for k in range(len(true)):
        if prev is not None:
            d = odo[k, 1:3] - odo[prev, 1:3]
            turn = abs(math.remainder(odo[k, 3] - odo[prev, 3], 2 * math.pi))
            near = math.hypot(d[0], d[1]) < cfg.pose_every and turn < cfg.pose_turn
            if near and k < len(true) - 1:
                continue
        truth[make_uid(robot, len(truth))] = true[k, 1:4].copy()
        prev = k
    return true, truth


@dataclass
class _Clock:
    """Where the node is on the team's clock (saved with the state)."""

    next: int = 0
    t: float = math.nan
    last_change: float = math.nan
    count: int = 0
    sent: int = 0
    settled: bool = False
    done: bool = False
    restarts: int = 0


class _Node:
    def __init__(
        self,
        plan: OccupancyMap,
        cfg: MissionConfig,
        robot: int,
        listen: str,
        peers: Mapping[int, str],
        exchange: ExchangeParams,
        *,
        state_dir: Path | None,
        lookahead: float,
        quiet: float | None,
        settle: float,
        timing: LockstepParams,
        max_message: int,
        progress: Progress | None,
        routes: Sequence[F64 | None] | None,
    ) -> None:
        ids = _check_team(robot, peers)
        self.robot = robot
        self.others = [j for j in ids if j != robot]
        self.cfg = cfg
        self.exchange = exchange
        self.lookahead = lookahead
        self.quiet = (
            2 * exchange.advert_every + 2 * exchange.request_every if quiet is None else quiet
        )
        self.settle = settle
        self.timing = timing
        self.progress = progress
        self.state_path = None if state_dir is None else Path(state_dir) / STATE_FILE
        # The sockets first: a bad or busy address fails before any work.
        self.zmq = ZmqTransport(robot, listen, peers, max_message=max_message + _LOCK_SLACK)
        try:
            self._setup(plan, ids, max_message, routes)
        except BaseException:
            self.zmq.close()
            raise

    def _setup(
        self,
        plan: OccupancyMap,
        ids: Sequence[int],
        max_message: int,
        given: Sequence[F64 | None] | None,
    ) -> None:
        cfg, robot = self.cfg, self.robot
        if given is not None and len(given) != len(ids):
            raise ConfigError(f"routes: {len(given)} given for a team of {len(ids)}")
        world = make_world(plan, seed=cfg.seed, duration=cfg.duration)
        own = None if given is None else given[robot]
        self.agent = agent = RobotAgent(plan, cfg, world=world, robot=robot, route=own)
        routes = [agent.route]
        others_truth: dict[int, F64] = {}
        for j in self.others:
            route, truth = _route_truth(plan, cfg, j, None if given is None else given[j])
            routes.append(route)
            others_truth.update(truth)
        self.times = np.unique(np.concatenate([r[:, 0] for r in routes]))
        self.received_merged: dict[int, Pose] = {}
        agent.peers_truth = ChainMap(agent.truth, others_truth)
        agent.peers_made = ChainMap(agent.made, self.received_merged)
        self.inner = _Inner(robot, self.others, max_message)
        # What the naive baseline would send: the share of it the team reports, and the
        # byte target of ExchangeParams.anchor_share.
        self.meter = NaiveMeter(agent.store, agent.made if cfg.store.fold else None)
        self.exchanger = Exchanger(
            agent.store,
            self.inner,
            self.exchange,
            adjacency=region_adjacency(agent.labels),
            on_received=self._received,
            peers=lambda: list(self.others),
            naive_bytes=lambda: float(self.meter.bytes),
        )
        self.link = _Link(self.zmq, self.others, self.timing)
        self.clock = _Clock()
        self.fingerprint = _fingerprint(plan, cfg, robot, ids, self.exchange, routes)
        self.last_checkpoint = time.monotonic()

    def _received(self, source: int, pose: Pose) -> list[ClosureEdge]:
        if pose.merged_from:
            self.received_merged[pose.uid] = pose
        return self.agent.receive(source, pose)

    # state

    def save(self, finished: bool = False) -> None:
        if self.state_path is None:
            return
        state: dict[str, Any] = {
            "v": _STATE_VERSION,
            "fingerprint": self.fingerprint,
            "finished": finished,
            "clock": asdict(self.clock),
            "link": self.link.state(),
        }
        if not finished:
            state["store"] = _store_state(self.agent.store)
            state["agent"] = _agent_state(self.agent)
            state["exchanger"] = _exchanger_state(self.exchanger)
            state["meter"] = self.meter.state()
            state["received_merged"] = [encode(p) for p in self.received_merged.values()]
        data = _pack(state)
        acked = dict(self.link.next_q)

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())

        atomic_write(self.state_path, write)
        self.link.ack_mine = acked
        self.last_checkpoint = time.monotonic()

    def load(self) -> bool:
        """Resume from the state file if there is one; True if it says finished."""
        path = self.state_path
        if path is None or not path.exists():
            return False
        try:
            data = path.read_bytes()
            n = len(data)
            s = unpack_strict(data, max_bin=n, max_str=n, max_array=n, max_map=n)
            if not isinstance(s, dict) or s.get("v") != _STATE_VERSION:
                raise InputError("not a node state of this version")
            if s["fingerprint"] != self.fingerprint:
                raise InputError(
                    "the state belongs to another mission (plan, settings, robot or team)"
                )
            self.link.restore(s["link"])
            clock = _Clock(**s["clock"])
            if not s["finished"]:
                _store_into(self.agent.store, s["store"])
                _agent_into(self.agent, s["agent"])
                # The restored agent has a new dict of the poses it made: the meter and
                # the view over every robot's poses must look at that one.
                if self.meter.made is not None:
                    self.meter.made = self.agent.made
                self.agent.peers_made = ChainMap(self.agent.made, self.received_merged)
                _exchanger_into(self.exchanger, s["exchanger"])
                # A state saved before the meter has none: it counts from here.
                if "meter" in s:
                    self.meter.restore(s["meter"])
                for b in s["received_merged"]:
                    p = _record(b, Pose)
                    self.received_merged[p.uid] = p
        except InputError as e:
            raise InputError(e.reason, path=path) from None
        except (UnpackError, RecordError, KeyError, TypeError, ValueError) as e:
            raise InputError(f"cannot resume from this state: {e}", path=path) from None
        clock.restarts += 1
        self.clock = clock
        logger.warning(
            "robot %d resumes at tick %d from %s (restart %d)",
            self.robot,
            clock.next,
            path,
            clock.restarts,
        )
        return bool(s["finished"])

    # the clock

    def _slot(self, n: int, t: float, wanted: list[int] | None) -> None:
        """Tick ``n`` of the exchange, at mission time ``t``."""
        need = {j: n if j < self.robot else n - 1 for j in self.others}
        link = self.link
        link.wait(lambda: [j for j in self.others if link.done[j] < need[j]], f"tick {n}")
        for j in self.others:
            for old in [k for k in link.markers[j] if k < n - 1]:
                del link.markers[j][old]
        self.inner.inbox = [
            Message(j, self.robot, f.body, f.q, f.kind) for _, j, f in link.take(need)
        ]
        self.exchanger.step(t, wanted)
        self.meter.step(len(self.others))
        out, self.inner.outbox = self.inner.outbox, []
        for dst, kind, body in out:
            link.send(dst, n, kind, body)
        changes = self.exchanger.stats.poses_added + self.exchanger.stats.poses_deleted
        outstanding = bool(self.exchanger.outstanding)
        self.own_marker = (changes, outstanding)
        for j in self.others:
            done = _pack({"ch": changes, "out": outstanding, "ack": link.ack_mine[j]})
            link.send(j, n, "done", done)

    def _team(self, n: int) -> tuple[int, bool]:
        """The team's exchange changes and whether anyone awaits an answer, at tick n."""
        link = self.link
        link.wait(lambda: [j for j in self.others if link.done[j] < n], f"the end of tick {n}")
        total, outstanding = self.own_marker
        for j in self.others:
            c, o = link.markers[j][n]
            total += c
            outstanding = outstanding or o
        return total, outstanding

    def run(self) -> None:
        clock, times = self.clock, self.times
        T = len(times)
        end = float(times[-1])
        dt = float(np.median(np.diff(times))) if T > 1 else self.exchange.request_every
        agent = self.agent
        while not clock.done:
            n = clock.next
            if n < T:
                t = float(times[n])
                agent.advance_to(t)
                self._slot(n, t, agent.wanted_regions(self.lookahead))
                if n == T - 1:
                    clock.count, _ = self._team(n)
                    clock.sent = self.exchanger.stats.bytes_sent
                    clock.t = clock.last_change = end
                    clock.done = not clock.t < end + self.settle
                if self.progress is not None:
                    self.progress(n + 1, T)
            else:
                t = clock.t + dt
                self.exchanger.finish()
                self._slot(n, t, None)
                now, outstanding = self._team(n)
                clock.t = t
                if now != clock.count or outstanding:
                    clock.count, clock.last_change = now, t
                elif t - clock.last_change >= self.quiet:
                    clock.settled = clock.done = True
                if not clock.t < end + self.settle:
                    clock.done = True
            clock.next = n + 1
            if time.monotonic() - self.last_checkpoint >= self.timing.checkpoint_every:
                self.save()

    def summary(self) -> tuple[dict[str, Any], Any]:
        agent, e = self.agent, self.exchanger
        held, twice = held_uids(agent.store)
        result = agent.finish()
        row = dict(result.summary)
        row.update(
            {
                "bytes_sent": e.stats.bytes_sent,
                "bytes_by_kind": dict(sorted(e.stats.bytes_by_kind.items())),
                "bytes_received": e.stats.bytes_received,
                "messages": e.stats.messages_sent,
                "messages_received": e.stats.messages_received,
                "poses_local": len(agent.store.local.poses),
                "poses_received": sum(len(x.poses) for x in agent.store.received.values()),
                "received_closures": agent.received_closures,
                "received_closures_correct": agent.received_correct,
            }
        )
        times = self.times
        node = {
            "robot": self.robot,
            "row": row,
            "held": sorted(held),
            "duplicates": twice,
            "bytes_sent_mission": self.clock.sent,
            "naive_bytes": self.meter.bytes,
            "route_seconds": float(times[-1] - times[0]),
            "settle_seconds": self.clock.t - float(times[-1]),
            "settled": self.clock.settled,
            "last_change_s": self.clock.last_change - float(times[-1]),
            "ticks": self.clock.next,
            "restarts": self.clock.restarts,
            "local_digest": store_digest(agent.store),
            "rejected_frames": self.link.rejected + sum(self.zmq.stats.rejected.values()),
        }
        return node, result

    def linger(self) -> None:
        """Say goodbye, then serve the peers' requests to send again until every peer
        said goodbye too (or ``linger`` s passed)."""
        link = self.link
        for j in self.others:
            link.send(j, self.clock.next, "bye", b"")
        deadline = time.monotonic() + self.timing.linger
        last_ask = time.monotonic()
        while set(self.others) - link.bye and time.monotonic() < deadline:
            link.pump(0.05)
            if time.monotonic() - last_ask >= self.timing.retry:
                link.hello(sorted(set(self.others) - link.bye))
                last_ask = time.monotonic()
        missing = sorted(set(self.others) - link.bye)
        if missing:
            logger.warning("robot %d: no goodbye from robots %s; leaving", self.robot, missing)


def run_node(
    plan: OccupancyMap,
    cfg: MissionConfig,
    robot_id: int,
    listen: str,
    peers: Mapping[int, str],
    *,
    out: Path,
    exchange: ExchangeParams | None = None,
    state_dir: Path | None = None,
    lookahead: float = 30.0,
    quiet: float | None = None,
    settle: float = 120.0,
    timing: LockstepParams | None = None,
    max_message: int = DEFAULT_MAX_MESSAGE,
    progress: Progress | None = None,
    routes: Sequence[F64 | None] | None = None,
) -> dict[str, Any]:
    """Run robot ``robot_id``'s mission as one node of a team over ZeroMQ.

    Parameters
    ----------
    plan : OccupancyMap
        The floor (also the prior map).
    cfg : MissionConfig
        The team's mission (every node the same); the robot's route and sensors are
        seeded from ``cfg.seed + 7919 robot_id``, as in :func:`~.simulation.run_team`.
    robot_id : int
        This robot; the team is robots 0..N-1, this one and ``peers``.
    listen : str
        ``tcp://HOST:PORT`` this node binds.
    peers : mapping of int to str
        Every other robot's listen address.
    out : Path
        Folder for ``summary.json`` (this robot's row of run_team's summary, its held
        pose UIDs, :func:`store_digest` and the clock's figures) and ``map.*``.
    exchange : ExchangeParams, optional
    state_dir : Path, optional
        Folder of the checkpoint; a node started on a folder holding one resumes.
    lookahead, quiet, settle : float
        As in :func:`~.simulation.run_team`.
    timing : LockstepParams, optional
    max_message : int
        Largest exchanger message, bytes (the simulated network's default, 1 MiB).
    progress : callable, optional
        ``progress(tick, ticks)`` after each tick of the routes.
    routes : sequence of ndarray (T, 4) or None, optional
        One per robot of the team (``t, x, y, theta``), as run_team's ``routes``; None
        draws a robot's patrol route from the seed.

    Returns
    -------
    dict
        What ``summary.json`` holds.

    Raises
    ------
    InputError
        A bad or busy address, a peer silent for ``timing.wait_timeout`` s, or a state
        file of another mission.
    """
    ex = exchange if exchange is not None else ExchangeParams()
    node = _Node(
        plan,
        cfg,
        robot_id,
        listen,
        peers,
        ex,
        state_dir=state_dir,
        lookahead=lookahead,
        quiet=quiet,
        settle=settle,
        timing=timing if timing is not None else LockstepParams(),
        max_message=max_message,
        progress=progress,
        routes=routes,
    )
    try:
        finished = node.load()
        node.link.hello(node.others)
        if finished:
            summary = json.loads((Path(out) / SUMMARY_FILE).read_text())
        else:
            node.run()
            summary, result = node.summary()
            with atomic_folder(Path(out)) as tmp:
                atomic_write_text(tmp / SUMMARY_FILE, json_dumps(summary))
                write_map(result.global_map, tmp / "map")
            node.save(finished=True)
        node.linger()
        return dict(summary)
    finally:
        node.zmq.close()


# --- a local team of processes -------------------------------------------------------------


@dataclass
class ZmqTeamResult:
    """What a team of node processes made.

    Attributes
    ----------
    summary : dict
        run_team's summary keys (``robots`` rows, ``duplicate_poses``,
        ``identical_maps``, ``bytes_per_robot_minute``, ``naive_bytes_per_robot_minute``,
        ``share_of_naive``, ``settle_seconds``, ``settled``, ``robots_n``, ``network``,
        ``exchange``, ``seed``) and
        ``transport`` ("zmq"), ``wall_seconds``, ``restarts`` (per robot) and
        ``store_digests`` (per robot, :func:`store_digest`).
    held : list of set of int
        The pose UIDs each robot held once the network was quiet.
    nodes : list of dict
        Each node's ``summary.json``.
    folder : Path
        Where the nodes wrote (their outputs ``robotK/``, states ``robotK.state/``,
        logs ``robotK.log`` and process ids ``robotK.pid``).
    """

    summary: dict[str, Any]
    held: list[set[int]]
    nodes: list[dict[str, Any]]
    folder: Path


def _free_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


def _node_args(
    cfg: MissionConfig,
    exchange: ExchangeParams,
    lookahead: float,
    quiet: float | None,
    settle: float,
    timing: LockstepParams,
) -> list[str]:
    base = MissionConfig(
        duration=cfg.duration,
        seed=cfg.seed,
        store=StoreParams(
            pose_limit=cfg.store.pose_limit,
            region_limit=cfg.store.region_limit,
            fold=cfg.store.fold,
            merge_on_closure=cfg.store.merge_on_closure,
        ),
    )
    if base != cfg:
        raise ConfigError(
            "run_zmq_team: the nodes take only the mission's duration, seed, pose_limit, "
            "region_limit, fold and merge_on_closure; other MissionConfig settings differ "
            "from their defaults"
        )
    args = [
        "--duration",
        repr(float(cfg.duration)),
        "--seed",
        str(cfg.seed),
        "--pose-limit",
        str(cfg.store.pose_limit),
        "--region-limit",
        str(cfg.store.region_limit),
        "--fold" if cfg.store.fold else "--no-fold",
        "--merge-on-closure",
        str(cfg.store.merge_on_closure),
        "--lookahead",
        repr(float(lookahead)),
        "--settle",
        repr(float(settle)),
        "--wait-timeout",
        repr(float(timing.wait_timeout)),
        "--checkpoint-every",
        repr(float(timing.checkpoint_every)),
    ]
    if quiet is not None:
        args += ["--quiet", repr(float(quiet))]
    for f in fields(exchange):
        args += ["--exchange", f"{f.name}={getattr(exchange, f.name)!r}".replace("'", "")]
    return args


def _last_line(path: Path) -> str:
    try:
        lines = [s for s in path.read_text(errors="replace").splitlines() if s.strip()]
    except OSError:
        return ""
    return lines[-1].strip() if lines else ""


def run_zmq_team(
    plan: OccupancyMap | Path,
    cfg: MissionConfig,
    robots: int,
    *,
    network: NetworkParams | None = None,
    exchange: ExchangeParams | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    lookahead: float = 30.0,
    quiet: float | None = None,
    settle: float = 120.0,
    folder: Path | None = None,
    timing: LockstepParams | None = None,
    restarts: int = 3,
    timeout: float | None = None,
    python: str | None = None,
    routes: Sequence[F64 | None] | None = None,
) -> ZmqTeamResult:
    """Run ``robots`` robots as local processes (``python -m sonarmap team node``) on
    loopback ports, exchanging over ZeroMQ; the same mission as :func:`run_team`.

    Parameters
    ----------
    plan : OccupancyMap or Path
        The floor, or a map_server YAML of it.
    cfg : MissionConfig
        Only ``duration``, ``seed`` and the store's two limits may differ from the
        defaults (they are what a node's command line takes).
    robots : int
        Robots (processes), ids 0..robots-1; >= 1.
    network : NetworkParams, optional
        The real network is what it is: only ``kind="full"`` with no loss, delay,
        jitter or bandwidth cap describes it (else :class:`ConfigError`); recorded in
        the summary.
    exchange : ExchangeParams, optional
    seed : int
        The simulated network's seed in run_team; recorded only.
    progress : callable, optional
        ``progress(done, robots)`` as nodes finish.
    lookahead, quiet, settle : float
        As in :func:`run_team`.
    folder : Path, optional
        Where the nodes write; a temporary folder (removed) when not given.
    timing : LockstepParams, optional
    restarts : int
        Times a node killed by a signal is started again (it resumes from its state).
    timeout : float, optional
        Wall seconds for the whole team; default 600 + 10 x the mission's seconds.
    python : str, optional
        The interpreter; this one by default.
    routes : sequence of ndarray (T, 4) or None, optional
        One per robot, as run_team's: a given route replaces the robot's patrol route.
        The launcher draws the others and hands every node all of them, so that no
        node spends its start drawing routes.

    Returns
    -------
    ZmqTeamResult
    """
    if isinstance(robots, bool) or not isinstance(robots, int) or robots < 1:
        raise ConfigError(f"robots must be an int >= 1, got {robots!r}")
    net = network if network is not None else NetworkParams(kind="full")
    if (
        net.kind != "full"
        or net.loss
        or net.delay
        or net.jitter
        or net.bandwidth is not None
        or net.max_message != DEFAULT_MAX_MESSAGE
    ):
        raise ConfigError(
            "the zmq transport runs over the real network: only --network full, with no "
            "--bandwidth or --loss, describes it (use --transport sim for the others)"
        )
    ex = exchange if exchange is not None else ExchangeParams()
    timing = timing if timing is not None else LockstepParams()
    args = _node_args(cfg, ex, lookahead, quiet, settle, timing)
    limit = 600.0 + 10.0 * cfg.duration if timeout is None else timeout
    with tempfile.TemporaryDirectory(prefix="sonarmap-zmq-") as scratch:
        where = Path(folder) if folder is not None else Path(scratch)
        where.mkdir(parents=True, exist_ok=True)
        if isinstance(plan, OccupancyMap):
            write_map(plan, where / "plan")
            plan_path = where / "plan.yaml"
        else:
            plan_path = Path(plan)
            plan = read_map(plan_path)
        if routes is not None and len(routes) != robots:
            raise ConfigError(f"routes: {len(routes)} given for {robots} robots")
        drawn = [
            patrol_route(plan, cfg.duration, seed=cfg.seed + 7919 * i)
            if routes is None or routes[i] is None
            else routes[i]
            for i in range(robots)
        ]
        save_routes(where / "routes", [np.asarray(r, dtype=np.float64) for r in drawn])
        args = [*args, "--routes", str(where / "routes")]
        addresses = [f"tcp://127.0.0.1:{p}" for p in _free_ports(robots)]
        return _launch(
            where,
            plan_path,
            robots,
            addresses,
            args,
            net,
            ex,
            seed,
            restarts,
            limit,
            python,
            progress,
        )


def _launch(
    where: Path,
    plan_path: Path,
    robots: int,
    addresses: list[str],
    args: list[str],
    net: NetworkParams,
    ex: ExchangeParams,
    seed: int,
    restarts: int,
    limit: float,
    python: str | None,
    progress: Progress | None,
) -> ZmqTeamResult:
    exe = python or sys.executable
    cmds = []
    for i in range(robots):
        peers = ",".join(f"{j}={addresses[j]}" for j in range(robots) if j != i)
        cmd = [exe, "-m", "sonarmap", "team", "node", "--id", str(i), "--listen", addresses[i]]
        if peers:
            cmd += ["--peers", peers]
        cmd += ["--map", str(plan_path), "-o", str(where / f"robot{i}")]
        cmd += ["--state", str(where / f"robot{i}.state"), *args]
        cmds.append(cmd)
    env = dict(os.environ)
    src = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH")) if p)
    procs: dict[int, subprocess.Popen[bytes]] = {}
    logs: dict[int, Any] = {}
    used = dict.fromkeys(range(robots), 0)
    lock = threading.Lock()

    def start(i: int) -> None:
        log = logs.get(i)
        if log is None:
            log = logs[i] = open(where / f"robot{i}.log", "ab")  # noqa: SIM115
        procs[i] = subprocess.Popen(cmds[i], stdout=log, stderr=subprocess.STDOUT, env=env)
        atomic_write_text(where / f"robot{i}.pid", f"{procs[i].pid}\n")

    t0 = time.monotonic()
    try:
        with lock:
            for i in range(robots):
                start(i)
        finished: set[int] = set()
        while len(finished) < robots:
            if time.monotonic() - t0 > limit:
                raise InputError(f"the zmq team did not finish within {limit:g} s (see {where})")
            for i in range(robots):
                if i in finished:
                    continue
                rc = procs[i].poll()
                if rc is None:
                    continue
                if rc == 0:
                    finished.add(i)
                    if progress is not None:
                        progress(len(finished), robots)
                elif rc < 0 and used[i] < restarts:
                    # Killed by a signal: started again, it resumes from its state.
                    used[i] += 1
                    logger.warning("robot %d killed (signal %d); starting it again", i, -rc)
                    start(i)
                else:
                    why = _last_line(where / f"robot{i}.log") or f"exit code {rc}"
                    raise InputError(f"robot {i}'s node failed: {why}")
            time.sleep(0.1)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGKILL)
                p.wait()
        for log in logs.values():
            log.close()
    nodes = [json.loads((where / f"robot{i}" / SUMMARY_FILE).read_text()) for i in range(robots)]
    return _team_summary(nodes, net, ex, seed, time.monotonic() - t0, where)


def _team_summary(
    nodes: list[dict[str, Any]],
    net: NetworkParams,
    ex: ExchangeParams,
    seed: int,
    wall: float,
    where: Path,
) -> ZmqTeamResult:
    robots = len(nodes)
    held = [set(n["held"]) for n in nodes]
    identical = all(h == held[0] for h in held)
    settled = all(bool(n["settled"]) for n in nodes)
    f1 = [float(n["row"]["map_f1"]) for n in nodes if n["row"]["map_f1"] is not None]
    minutes = max(float(nodes[0]["route_seconds"]), 1e-9) / 60.0
    sent_all = sum(int(n["row"]["bytes_sent"]) for n in nodes) / robots / minutes
    # Nodes of a release before the meter report none.
    naive = (
        sum(int(n["naive_bytes"]) for n in nodes) / robots / minutes
        if all("naive_bytes" in n for n in nodes)
        else None
    )
    maps = [where / f"robot{i}" / "map.yaml" for i in range(robots)]
    agreement = (
        map_agreement([read_map(m) for m in maps]) if all(m.exists() for m in maps) else None
    )
    summary: dict[str, Any] = {
        "robots": [n["row"] for n in nodes],
        "robots_n": robots,
        "duplicate_poses": sum(int(n["duplicates"]) for n in nodes),
        "identical_maps": identical,
        "map_agreement": agreement,
        "convergence_s": float(nodes[0]["last_change_s"]) if settled and identical else None,
        "bytes_per_robot_minute": sum(int(n["bytes_sent_mission"]) for n in nodes)
        / robots
        / minutes,
        "bytes_per_robot_minute_all": sent_all,
        "naive_bytes_per_robot_minute": naive,
        "share_of_naive": sent_all / naive if naive else None,
        "map_f1_team": float(np.mean(f1)) if f1 else math.nan,
        # The central bound needs every robot's data in one process: 'team run --transport sim'.
        "map_f1_central": None,
        "central": None,
        "settle_seconds": max(float(n["settle_seconds"]) for n in nodes),
        "settled": settled,
        "network": asdict(net),
        "exchange": asdict(ex),
        "seed": seed,
        "transport": "zmq",
        "wall_seconds": wall,
        "restarts": [int(n["restarts"]) for n in nodes],
        "store_digests": [n["local_digest"] for n in nodes],
    }
    return ZmqTeamResult(summary, held, nodes, where)
