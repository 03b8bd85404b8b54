"""How a robot's messages reach another robot (issue 15): one interface,
:class:`Transport`, over the simulated network (:class:`SimTransport`) or real sockets
(:class:`ZmqTransport`). The exchange protocol sits on top and sees only
:meth:`Transport.send` and :meth:`Transport.poll`.

Every message travels in an envelope, a msgpack map (never pickle)::

    {"v": 1, "src": int, "dst": int, "seq": int, "kind": str, "body": bytes}

``seq`` counts the messages a robot sent to one destination (from 0), so a gap tells
the receiver that the network lost one. On receipt the envelope is checked strictly
(:func:`decode_envelope`): a frame too long, bad msgpack, truncated or with trailing
bytes, not a map, missing or extra keys, another version, a field of the wrong type or
out of range, addressed to another robot, or claiming another sender than the one it
came from is rejected. A rejection is logged (logger ``sonarmap.team.transport``,
warning; each line clipped and their rate bounded, :class:`~.rejects.RejectLog`) and
counted in ``stats.rejected`` by reason; :meth:`Transport.poll` never raises on a
peer's bytes. The decoder's length limits keep a forged length field from
allocating more than the frame itself.

Sends never block: a message that cannot leave now (no route, no connection, queue
full, too large) is counted in ``stats.dropped`` by reason and :meth:`Transport.send`
returns False. The exchange above must expect losses either way.
"""

from __future__ import annotations

import abc
import logging
import math
import re
import time
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Self

import msgpack
import numpy.typing as npt
import zmq

from ..errors import ConfigError, InputError
from .keys import ZAP_DOMAIN, KeyGate, TeamKey
from .network import Delivery, SimNetwork
from .records import UnpackError, unpack_strict
from .rejects import RejectLog

__all__ = [
    "DEFAULT_MAX_MESSAGE",
    "ENVELOPE_VERSION",
    "EnvelopeError",
    "Message",
    "SimHub",
    "SimTransport",
    "Transport",
    "TransportStats",
    "ZmqTransport",
    "decode_envelope",
    "encode_envelope",
]

logger = logging.getLogger("sonarmap.team.transport")

#: The envelope's version, its field ``v``.
ENVELOPE_VERSION = 1
#: Largest envelope (bytes) a transport sends or takes by default: 1 MiB.
DEFAULT_MAX_MESSAGE = 1 << 20
#: Robot ids are below this, as in :func:`records.make_uid`.
ROBOT_LIMIT = 2**23
_SEQ_LIMIT = 2**63
_KIND_MAX = 64
_KEYS = frozenset({"v", "src", "dst", "seq", "kind", "body"})
#: zmq itself drops frames over this many times ``max_message`` (and disconnects their
#: sender); frames between the two are read, then rejected and logged as oversized.
_ZMQ_SLACK = 2
#: Frames one poll reads at most, so a flood cannot hold the caller forever.
_DRAIN = 10_000


@dataclass(frozen=True)
class Message:
    """A received message: ``body`` of the envelope as ``payload``."""

    src: int
    dst: int
    payload: bytes = field(repr=False)
    seq: int
    kind: str = "data"


class EnvelopeError(ValueError):
    """A frame that is not a valid envelope; ``reason`` is a short code (the stats key)."""

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


def encode_envelope(src: int, dst: int, seq: int, kind: str, body: bytes) -> bytes:
    """The envelope's msgpack bytes."""
    d = {"v": ENVELOPE_VERSION, "src": src, "dst": dst, "seq": seq, "kind": kind, "body": body}
    return bytes(msgpack.packb(d, use_bin_type=True))


#: What a frame that is not one whole msgpack object is told, by reason.
_ENVELOPE_DETAIL = {
    "trailing": "bytes after the envelope",
    "truncated": "the frame ends inside the envelope",
}


def decode_envelope(data: bytes, *, max_message: int = DEFAULT_MAX_MESSAGE) -> Message:
    """The message in ``data``; :class:`EnvelopeError` if it is not a valid envelope."""
    if len(data) > max_message:
        raise EnvelopeError("oversized", f"{len(data)} bytes > max_message {max_message}")
    try:
        d = unpack_strict(
            data,
            max_bin=max_message,
            max_str=max(_KIND_MAX, 16),
            max_array=16,
            max_map=16,
        )
    except UnpackError as e:
        raise EnvelopeError(e.reason, _ENVELOPE_DETAIL.get(e.reason, str(e))) from None
    if not isinstance(d, dict):
        raise EnvelopeError("not_map", f"a map expected, got {type(d).__name__}")
    if set(d) != _KEYS:
        missing, extra = sorted(_KEYS - set(d)), sorted(set(d) - _KEYS)
        raise EnvelopeError("keys", f"missing {missing}, unexpected {extra}")
    v = d["v"]
    if not _is_int(v) or v != ENVELOPE_VERSION:
        raise EnvelopeError("version", f"version {v!r}, expected {ENVELOPE_VERSION}")
    for key, limit in (("src", ROBOT_LIMIT), ("dst", ROBOT_LIMIT), ("seq", _SEQ_LIMIT)):
        if not _is_int(d[key]):
            raise EnvelopeError("type", f"{key}: {type(d[key]).__name__} where int expected")
        if not 0 <= d[key] < limit:
            raise EnvelopeError("range", f"{key}: {d[key]} not in [0, {limit})")
    kind, body = d["kind"], d["body"]
    if not isinstance(kind, str) or not 0 < len(kind) <= _KIND_MAX:
        raise EnvelopeError("type", f"kind: a string of 1..{_KIND_MAX} characters expected")
    if not isinstance(body, bytes):
        raise EnvelopeError("type", f"body: {type(body).__name__} where bytes expected")
    return Message(d["src"], d["dst"], body, d["seq"], kind)


def _is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


@dataclass
class TransportStats:
    """A transport's counters: messages and bytes (whole envelopes) sent and taken;
    sends refused by reason (``dropped``); frames received and refused by reason
    (``rejected``)."""

    messages_sent: int = 0
    messages_received: int = 0
    bytes_sent: int = 0
    bytes_received: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    rejected: Counter[str] = field(default_factory=Counter)


class Transport(abc.ABC):
    """One robot's end of the team's network.

    Parameters
    ----------
    robot : int
        This robot's id, in [0, 2**23).
    max_message : int
        Largest envelope, bytes, sent or accepted.
    """

    def __init__(self, robot: int, *, max_message: int = DEFAULT_MAX_MESSAGE) -> None:
        if not _is_int(robot) or not 0 <= robot < ROBOT_LIMIT:
            raise ConfigError(f"robot id must be an int in [0, {ROBOT_LIMIT}), got {robot!r}")
        if not _is_int(max_message) or max_message < 64:
            raise ConfigError(f"max_message must be an int >= 64 bytes, got {max_message!r}")
        self.robot = robot
        self.max_message = max_message
        self.stats = TransportStats()
        self.closed = False
        self._rejects = RejectLog(logger)
        self._seq: dict[int, int] = {}

    def send(self, dst: int, payload: bytes, kind: str = "data") -> bool:
        """Send ``payload`` to robot ``dst`` without blocking; False (counted in
        ``stats.dropped``) if it cannot leave now. Delivery is never confirmed."""
        if not _is_int(dst) or not 0 <= dst < ROBOT_LIMIT or dst == self.robot:
            raise InputError(f"robot {self.robot} cannot send to {dst!r}", field="dst")
        if not isinstance(payload, bytes):
            raise InputError(f"payload must be bytes, got {type(payload).__name__}")
        if not isinstance(kind, str) or not 0 < len(kind) <= _KIND_MAX:
            raise InputError(f"kind must be a string of 1..{_KIND_MAX} characters", field="kind")
        if self.closed:
            return self._refuse("closed")
        seq = self._seq.get(dst, 0)
        data = encode_envelope(self.robot, dst, seq, kind, payload)
        if len(data) > self.max_message:
            return self._refuse("oversized")
        reason = self._send_frame(dst, data)
        if reason is not None:
            return self._refuse(reason)
        # A refused send keeps its number: a gap in seq means the network lost a message.
        self._seq[dst] = seq + 1
        self.stats.messages_sent += 1
        self.stats.bytes_sent += len(data)
        return True

    @abc.abstractmethod
    def poll(self, timeout: float = 0.0) -> list[Message]:
        """The valid messages received, in arrival order; waits up to ``timeout`` seconds
        for the first one."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the transport; later sends are refused ("closed")."""

    @abc.abstractmethod
    def _send_frame(self, dst: int, data: bytes) -> str | None:
        """Hand ``data`` on without blocking: None if it left, else the reason why not."""

    def _refuse(self, reason: str) -> bool:
        self.stats.dropped[reason] += 1
        return False

    def _accept(self, data: bytes, sender: int | None, origin: str) -> Message | None:
        """The message in a received frame, or None (logged and counted) if invalid.

        ``sender`` is the robot the frame came from by the transport's own account,
        None if unknown; the envelope must claim that one."""
        try:
            msg = decode_envelope(data, max_message=self.max_message)
            if msg.dst != self.robot:
                raise EnvelopeError("misaddressed", f"for robot {msg.dst}")
            if sender is not None and msg.src != sender:
                raise EnvelopeError("spoofed", f"claims robot {msg.src}, came from {sender}")
        except EnvelopeError as e:
            self._reject(e.reason, str(e), origin)
            return None
        except Exception as e:
            # The frame is a stranger's bytes: nothing it makes the decoder raise may
            # stop the receiver.
            self._reject("decode", f"{type(e).__name__}: {e}", origin)
            return None
        self.stats.messages_received += 1
        self.stats.bytes_received += len(data)
        return msg

    def _reject(self, reason: str, detail: str, origin: str) -> None:
        self.stats.rejected[reason] += 1
        self._rejects.warn(f"robot {self.robot} rejected a frame from {origin[:48]}: {detail}")

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _check_timeout(timeout: float) -> float:
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)):
        raise ConfigError(f"timeout must be a number of seconds, got {timeout!r}")
    if not (math.isfinite(timeout) and timeout >= 0):
        raise ConfigError(f"timeout must be finite and >= 0 seconds, got {timeout!r}")
    return float(timeout)


# --- simulation ----------------------------------------------------------------------


class SimHub:
    """The simulated clock and the mailboxes of the :class:`SimTransport` s sharing one
    :class:`~sonarmap.team.network.SimNetwork`.

    Simulated time moves only by :meth:`advance` / :meth:`step`, never by a transport's
    poll timeout: the simulation loop advances the hub, then each robot polls and sends.
    """

    def __init__(self, network: SimNetwork, t0: float = 0.0) -> None:
        self.network = network
        self.now = float(t0)
        #: Messages that reached a robot with no open transport (they are discarded).
        self.undelivered = 0
        self._boxes: dict[int, deque[Delivery]] = {}

    def advance(self, t: float) -> None:
        """Simulated time is ``t`` (never earlier than now)."""
        if not (math.isfinite(t) and t >= self.now):
            raise InputError(f"hub time goes from {self.now} to {t}", field="t")
        self.now = float(t)
        self._pump()

    def step(self, dt: float) -> None:
        """Simulated time moves on by ``dt`` seconds."""
        self.advance(self.now + dt)

    def update(self, xy: npt.ArrayLike) -> None:
        """The robots are at ``xy`` (N, 2) from now on (the network's links follow)."""
        self.network.update(self.now, xy)

    def transport(self, robot: int, **kwargs: Any) -> SimTransport:
        """A transport for ``robot`` (an index of the network) on this hub."""
        return SimTransport(self, robot, **kwargs)

    def join(self, robot: int) -> None:
        """Give ``robot`` a mailbox (its :class:`SimTransport` calls this); a robot outside
        the network or already joined is a :class:`ConfigError`."""
        if not 0 <= robot < self.network.n:
            raise ConfigError(f"robot {robot} is not in the network's 0..{self.network.n - 1}")
        if robot in self._boxes:
            raise ConfigError(f"robot {robot} already has a transport on this hub")
        self._boxes[robot] = deque()

    def leave(self, robot: int) -> None:
        """Close ``robot``'s mailbox; what it still held counts as undelivered."""
        self.undelivered += len(self._boxes.pop(robot, ()))

    def _pump(self) -> None:
        for d in self.network.deliver(self.now):
            box = self._boxes.get(d.dst)
            if box is None:
                self.undelivered += 1
            else:
                box.append(d)

    def take(self, robot: int) -> list[Delivery]:
        """Everything delivered to ``robot`` by now, in delivery order, and empty its
        mailbox."""
        self._pump()
        box = self._boxes.get(robot)
        if not box:
            return []
        out = list(box)
        box.clear()
        return out


class SimTransport(Transport):
    """A robot's transport over the simulated network of a :class:`SimHub`; robot ids are
    the network's indices. ``max_message`` defaults to the network's."""

    def __init__(self, hub: SimHub, robot: int, *, max_message: int | None = None) -> None:
        net_max = hub.network.params.max_message
        super().__init__(robot, max_message=net_max if max_message is None else max_message)
        hub.join(robot)
        self.hub = hub

    def _send_frame(self, dst: int, data: bytes) -> str | None:
        if dst >= self.hub.network.n:
            return "unknown_peer"
        if len(data) > self.hub.network.params.max_message:
            return "oversized"
        if not self.hub.network.send(self.hub.now, self.robot, dst, data):
            return "unroutable"
        return None

    def poll(self, timeout: float = 0.0) -> list[Message]:
        """The messages that reached this robot by the hub's time; ``timeout`` is checked
        but does not move simulated time (see :class:`SimHub`)."""
        _check_timeout(timeout)
        if self.closed:
            return []
        out = []
        for d in self.hub.take(self.robot):
            msg = self._accept(d.payload, d.src, f"robot {d.src}")
            if msg is not None:
                out.append(msg)
        return out

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.hub.leave(self.robot)


# --- ZeroMQ --------------------------------------------------------------------------

_ADDRESS = re.compile(r"tcp://(?P<host>\*|\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(?P<port>\*|\d{1,5})")


def _parse_address(address: object, *, bind: bool) -> str:
    """``tcp://HOST:PORT`` checked; for a bind, port 0 or * takes a free port."""
    what, name = ("listen on", "listen") if bind else ("connect to", "peers")
    m = _ADDRESS.fullmatch(address) if isinstance(address, str) else None
    if m is None:
        raise InputError(f"cannot {what} {address!r}: not a tcp://HOST:PORT address", field=name)
    host, port = m["host"], m["port"]
    if port == "*" or int(port) == 0:
        if not bind:
            raise InputError(f"cannot {what} {address!r}: a port is needed", field=name)
        return f"tcp://{host}:*"
    if int(port) > 65535:
        raise InputError(f"cannot {what} {address!r}: port out of 1..65535", field=name)
    if host == "*" and not bind:
        raise InputError(f"cannot {what} {address!r}: a host is needed", field=name)
    return f"tcp://{host}:{int(port)}"


def _loopback(endpoint: str) -> bool:
    """Whether a parsed ``tcp://HOST:PORT`` is on this machine only."""
    host = endpoint[len("tcp://") :].rsplit(":", 1)[0]
    return host in ("localhost", "[::1]") or re.fullmatch(r"127(\.\d{1,3}){3}", host) is not None


def _why(e: zmq.ZMQError) -> str:
    """zmq's reason in one line (its str() repeats the address)."""
    return zmq.strerror(e.errno) if e.errno else str(e)


class ZmqTransport(Transport):
    """A robot's transport over TCP with ZeroMQ.

    The robot binds a ROUTER socket on ``listen`` and keeps one DEALER per peer,
    connected to the peer's listen address, with its identity set to this robot's id
    (decimal ASCII). A frame's sender is read from that identity and must match the
    envelope's ``src``. Messages between two robots arrive in order; from several
    peers they are fair-queued.

    With a team ``key`` (:mod:`.keys`) every connection is encrypted and authenticated
    with CURVE: the ROUTER is a CURVE server with this robot's key pair and admits, by
    its ZAP handler (:class:`~.keys.KeyGate`), only clients holding one of the team's
    keys; each DEALER checks its peer's public key. A frame's sender is then the robot
    whose key the connection proved (ZAP's User-Id), whatever routing identity it set.
    Without a key, anyone who can reach the port can claim any robot id: a keyless
    transport binds only to loopback unless ``insecure``.

    Sockets never block the caller: LINGER 0 (close discards what is queued), send
    with NOBLOCK and IMMEDIATE (a peer with no live connection refuses at once, counted
    "unavailable", rather than queueing for a robot that may be gone), high-water marks
    of ``hwm`` messages ("unavailable" too once full), reconnection every
    ``reconnect`` s backing off to ``reconnect_max`` s, and MAXMSGSIZE so that zmq
    drops frames far over ``max_message`` before they are read.

    Parameters
    ----------
    robot : int
    listen : str
        ``tcp://HOST:PORT``; port 0 or ``*`` takes a free port (see :attr:`address`).
    peers : mapping of int to str, optional
        Robot id -> listen address; more with :meth:`connect`.
    max_message : int
    hwm : int
        Messages queued at most per socket and direction: 1000.
    reconnect, reconnect_max : float
        Seconds between reconnection attempts, first and at most: 0.1 and 2.
    context : zmq.Context, optional
        Shared context (not terminated by :meth:`close`); else the transport's own.
        A keyed transport needs its own (ZAP has one handler per context).
    key : TeamKey, optional
        The team's key; None: plain TCP.
    insecure : bool
        Without a key, bind to an address other than loopback all the same: False.

    Raises
    ------
    InputError
        ``listen`` (or a peer's address) cannot be parsed, or the address cannot be
        bound (in use, not an address of this machine, not loopback without a key).
    """

    def __init__(
        self,
        robot: int,
        listen: str,
        peers: Mapping[int, str] | None = None,
        *,
        max_message: int = DEFAULT_MAX_MESSAGE,
        hwm: int = 1000,
        reconnect: float = 0.1,
        reconnect_max: float = 2.0,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
        key: TeamKey | None = None,
        insecure: bool = False,
    ) -> None:
        super().__init__(robot, max_message=max_message)
        if not _is_int(hwm) or hwm < 1:
            raise ConfigError(f"hwm must be an int >= 1, got {hwm!r}")
        if not (0 < reconnect <= reconnect_max and math.isfinite(reconnect_max)):
            raise ConfigError(
                f"reconnect intervals must satisfy 0 < reconnect <= reconnect_max, got "
                f"{reconnect!r} and {reconnect_max!r}"
            )
        endpoint = _parse_address(listen, bind=True)
        if key is None and not insecure and not _loopback(endpoint):
            raise InputError(
                f"cannot listen on {listen!r} without a team key: anyone reaching it could "
                "pose as a robot (give --key FILE, or --insecure on a trusted network)",
                field="listen",
            )
        if key is not None:
            if robot >= key.robots:
                raise ConfigError(f"robot {robot} is not in the team key's 0..{key.robots - 1}")
            if context is not None:
                raise ConfigError("a keyed transport needs its own zmq context")
        self.key = key
        self._gate: KeyGate | None = None
        self._hwm = hwm
        self._reconnect = (int(reconnect * 1000) or 1, int(reconnect_max * 1000) or 1)
        self._own_context = context is None
        self._ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context() if context is None else context
        self._peers: dict[int, zmq.Socket[bytes]] = {}
        if key is not None:
            self._gate = KeyGate(self._ctx, key)
            self._gate.start()
            self._denied = 0
        self._router = self._socket(zmq.ROUTER, endpoint)
        if key is not None:
            self._router.setsockopt(zmq.ZAP_DOMAIN, ZAP_DOMAIN)
            self._router.setsockopt(zmq.CURVE_SERVER, 1)
            self._router.setsockopt(zmq.CURVE_PUBLICKEY, key.public[robot])
            self._router.setsockopt(zmq.CURVE_SECRETKEY, key.secret[robot])
        # A restarted peer reconnects with its old identity: the new connection wins.
        self._router.setsockopt(zmq.ROUTER_HANDOVER, 1)
        try:
            self._router.bind(endpoint)
        except zmq.ZMQError as e:
            self._shutdown()
            reason = f"cannot listen on {listen!r}: {_why(e)}"
            raise InputError(reason, field="listen") from None
        #: The bound endpoint, with the port zmq chose for port 0.
        self.address: str = self._router.getsockopt_string(zmq.LAST_ENDPOINT)
        self._poller = zmq.Poller()
        self._poller.register(self._router, zmq.POLLIN)
        try:
            for peer, address in (peers or {}).items():
                self.connect(peer, address)
        except BaseException:
            self._shutdown()
            raise

    @property
    def peers(self) -> dict[int, str]:
        """Robot id -> the address its DEALER connects to."""
        return {r: s.getsockopt_string(zmq.LAST_ENDPOINT) for r, s in self._peers.items()}

    def connect(self, robot: int, address: str) -> None:
        """Send to ``robot`` at its listen ``address`` from now on (replaces an older
        address). Connecting is asynchronous: a peer that is not up yet is retried."""
        if not _is_int(robot) or not 0 <= robot < ROBOT_LIMIT or robot == self.robot:
            raise InputError(f"robot {self.robot} cannot have peer {robot!r}", field="peers")
        if self.closed:
            raise InputError(f"robot {self.robot}'s transport is closed", field="peers")
        endpoint = _parse_address(address, bind=False)
        key = self.key
        if key is not None and robot >= key.robots:
            raise InputError(
                f"robot {robot} is not in the team key's 0..{key.robots - 1}", field="peers"
            )
        sock = self._socket(zmq.DEALER, endpoint)
        sock.setsockopt(zmq.IDENTITY, str(self.robot).encode())
        if key is not None:
            # The peer must prove it holds robot `robot`'s secret key.
            sock.setsockopt(zmq.CURVE_SERVERKEY, key.public[robot])
            sock.setsockopt(zmq.CURVE_PUBLICKEY, key.public[self.robot])
            sock.setsockopt(zmq.CURVE_SECRETKEY, key.secret[self.robot])
        sock.setsockopt(zmq.IMMEDIATE, 1)
        sock.setsockopt(zmq.RECONNECT_IVL, self._reconnect[0])
        sock.setsockopt(zmq.RECONNECT_IVL_MAX, self._reconnect[1])
        try:
            sock.connect(endpoint)
        except zmq.ZMQError as e:
            sock.close(linger=0)
            reason = f"cannot connect to {address!r}: {_why(e)}"
            raise InputError(reason, field="peers") from None
        self.disconnect(robot)
        self._peers[robot] = sock

    def disconnect(self, robot: int) -> None:
        """Forget peer ``robot`` (what is queued for it is discarded)."""
        sock = self._peers.pop(robot, None)
        if sock is not None:
            sock.close(linger=0)

    def _socket(self, kind: int, endpoint: str) -> zmq.Socket[bytes]:
        sock = self._ctx.socket(kind)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SNDHWM, self._hwm)
        sock.setsockopt(zmq.RCVHWM, self._hwm)
        sock.setsockopt(zmq.MAXMSGSIZE, _ZMQ_SLACK * self.max_message)
        if endpoint.startswith("tcp://["):
            sock.setsockopt(zmq.IPV6, 1)
        return sock

    def _send_frame(self, dst: int, data: bytes) -> str | None:
        sock = self._peers.get(dst)
        if sock is None:
            return "unknown_peer"
        try:
            sock.send(data, zmq.NOBLOCK)
        except zmq.Again:
            return "unavailable"
        except zmq.ZMQError as e:
            logger.warning("robot %d could not send to robot %d: %s", self.robot, dst, e)
            return "error"
        return None

    def poll(self, timeout: float = 0.0) -> list[Message]:
        """The valid messages received; waits up to ``timeout`` s for a first one."""
        deadline = time.monotonic() + _check_timeout(timeout)
        if self.closed:
            return []
        out: list[Message] = []
        self._count_denied()
        while True:
            wait = max(0.0, deadline - time.monotonic())
            if dict(self._poller.poll(math.ceil(wait * 1000))).get(self._router):
                self._drain(out)
            if out or time.monotonic() >= deadline:
                return out

    def _drain(self, out: list[Message]) -> None:
        for _ in range(_DRAIN):
            try:
                frames = self._router.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            except zmq.ZMQError as e:
                logger.warning("robot %d could not receive: %s", self.robot, e)
                return
            msg = self._frames(frames)
            if msg is not None:
                out.append(msg)

    def _count_denied(self) -> None:
        """The handshakes the key's gate denied, into ``stats.rejected``."""
        if self._gate is not None:
            denied = self._gate.denied
            if denied > self._denied:
                self.stats.rejected["unauthenticated"] += denied - self._denied
                self._rejects.warn(
                    f"robot {self.robot} denied {denied - self._denied} connection(s) "
                    "without the team's key"
                )
                self._denied = denied

    def _frames(self, parts: list[zmq.Frame]) -> Message | None:
        frames = [p.bytes for p in parts]
        identity = frames[0]
        if self.key is not None:
            # The robot is the one whose key the connection proved, not the routing
            # identity it chose.
            try:
                user = parts[-1].get("User-Id")
            except zmq.ZMQError:
                user = ""
            identity = str(user).encode(errors="replace")
        digits = identity.isdigit() and len(identity) <= 7
        sender = int(identity) if digits and int(identity) < ROBOT_LIMIT else None
        origin = f"peer {identity[:16]!r}"
        if sender is None:
            self._reject("identity", f"identity {identity[:16]!r} is not a robot id", origin)
            return None
        if len(frames) != 2:
            self._reject("frames", f"{len(frames) - 1} frames where 1 expected", origin)
            return None
        return self._accept(frames[1], sender, origin)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._shutdown()

    def _shutdown(self) -> None:
        for robot in list(self._peers):
            self.disconnect(robot)
        router = getattr(self, "_router", None)
        if router is not None:
            router.close(linger=0)
        gate = getattr(self, "_gate", None)
        if gate is not None:
            gate.stop()
        if self._own_context:
            self._ctx.term()
