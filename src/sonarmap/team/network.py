"""The team's simulated network (issue 15): which robots can send to which, how fast, with
what loss and delay. A deterministic discrete-event model the exchange runs over in
simulation; :mod:`.transport` puts the same interface over real sockets.

Links are the patrolling simulator's (:mod:`sonarmap.patrol.network`): ``full`` links
every pair, ``none`` no pair, ``limited`` a pair within ``r_max`` metres with a line of
sight on the prior map. Links change only at :meth:`SimNetwork.update`, when the robots
move; between two updates they are fixed.

Model (every figure a choice, named in :class:`NetworkParams`):

- A link is directed: each direction of a pair has its own bandwidth (full duplex).
- Bandwidth is a token bucket per directed link: tokens flow in at the link's current
  capacity, up to ``burst`` bytes saved while idle. A message leaves when its last byte
  has been paid for, so with ``burst = 0`` a link is a serial line and a message of S
  bytes takes S / capacity seconds. Messages wait on a link first come, first served.
- Capacity = ``bandwidth`` x a factor that is piecewise constant: one value per link
  pair (both directions alike) and per period of ``bandwidth_period`` seconds, drawn
  uniformly in [``bandwidth_min_factor``, 1]. Each value is drawn from a generator
  seeded by (seed, pair, period), so it does not depend on the order of queries.
  Independent periods model fading and interference better than a random walk's slow
  drift, and keep the mean capacity known: bandwidth x (1 + min_factor) / 2.
- Each hop, once transmitted, is lost with probability ``loss``, else reaches the next
  robot ``delay`` + U(0, ``jitter``) seconds later; arrivals on a link keep their order.
- With ``relay``, a message follows a shortest chain of links (fewest hops, ties to the
  lowest robot index), chosen hop by hop on the links of the moment; without it only
  a direct link carries it. Every hop uses that link's bandwidth.
- A link that breaks drops the messages waiting on or being sent over it; a message
  reaching a relay with no way on is dropped too (both ``dropped_link_broken``).

Counters are per robot; the drops of a message are charged to its source, so over the
team ``messages_sent = messages_received + dropped_lost + dropped_link_broken +
in_flight``. Refused messages (no route, too large) are not sent: they count in
``dropped_unroutable`` and ``dropped_oversized`` only.

Random draws (losses, jitter) come from numpy Generators seeded by ``seed`` in event
order, so the same calls with the same seed give the same deliveries.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass, field, fields

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError, InputError
from ..grid import Grid
from ..patrol.network import NETWORKS, line_of_sight

__all__ = ["MAX_PERIODS", "Delivery", "NetworkParams", "NetworkStats", "SimNetwork"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bools = npt.NDArray[np.bool_]

# Event kinds. Events at one time run in the order they were scheduled.
_HOP_DONE = 0
_ARRIVE = 1
#: Bandwidth periods a varying link's schedule is stepped through for one message at
#: most; a message it has not carried by then never arrives (10^5 periods: 11.6 days at
#: the default 10 s, 2.8 h at 0.1 s; a few seconds of stepping).
MAX_PERIODS = 100_000
#: Seed-sequence tag of the bandwidth factors, apart from the loss and jitter streams.
_FACTOR_TAG = 0xBA4D
#: Factors kept in memory at most; past that the cache restarts (they are recomputable).
_FACTOR_CACHE = 1 << 16


@dataclass(frozen=True)
class NetworkParams:
    """The simulated network; every value is checked (:class:`ConfigError` names it).

    Attributes
    ----------
    kind : str
        ``"full"``, ``"limited"`` or ``"none"``.
    r_max : float
        Range (m) of a ``limited`` link: 70, as in the patrolling simulator.
    bandwidth : float or None
        Bytes/s (> 0) of each directed link at factor 1; None: unlimited (messages
        leave at once). With a varying factor, a message not carried within
        :data:`MAX_PERIODS` periods of its start never arrives, and neither do those
        queued behind it on that link.
    bandwidth_min_factor : float
        Lowest capacity factor, in (0, 1]; 1 keeps the capacity constant.
    bandwidth_period : float
        Seconds (> 0) between changes of the capacity factor: 10.
    burst : float
        Bytes (>= 0) a link's bucket saves while idle: 0, a serial line.
    loss : float
        Probability in [0, 1] that a message is lost on one hop.
    delay : float
        Seconds (>= 0) from the end of a hop's transmission to its arrival.
    jitter : float
        Seconds (>= 0): a uniform random extra delay in [0, jitter] per hop.
    relay : bool
        Robots forward messages along chains of links.
    max_message : int
        Largest payload (bytes, >= 1) the network takes: 1 MiB.
    """

    kind: str = "full"
    r_max: float = 70.0
    bandwidth: float | None = None
    bandwidth_min_factor: float = 1.0
    bandwidth_period: float = 10.0
    burst: float = 0.0
    loss: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0
    relay: bool = True
    max_message: int = 1 << 20

    def __post_init__(self) -> None:
        m = self.max_message
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ConfigError(
                f"network parameter 'max_message' must be an int >= 1, got {m!r}",
                field="max_message",
            )
        if self.kind not in NETWORKS:
            raise ConfigError(
                f"network parameter 'kind' must be one of {', '.join(NETWORKS)}, got {self.kind!r}",
                field="kind",
            )
        if self.bandwidth is not None:
            _check(self.bandwidth, "bandwidth", low=0.0, open_low=True)
        _check(self.r_max, "r_max", low=0.0, open_low=True)
        _check(self.bandwidth_min_factor, "bandwidth_min_factor", 0.0, 1.0, open_low=True)
        _check(self.bandwidth_period, "bandwidth_period", low=0.0, open_low=True)
        _check(self.burst, "burst", low=0.0)
        _check(self.loss, "loss", 0.0, 1.0)
        _check(self.delay, "delay", low=0.0)
        _check(self.jitter, "jitter", low=0.0)
        if not isinstance(self.relay, (bool, np.bool_)):
            raise ConfigError(
                f"network parameter 'relay' must be a bool, got {self.relay!r}", field="relay"
            )


def _check(
    v: object, name: str, low: float, high: float = math.inf, *, open_low: bool = False
) -> None:
    x = math.nan
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        x = float(v)
    if math.isfinite(x) and (x > low if open_low else x >= low) and x <= high:
        return
    if high == math.inf:
        span = f"{'>' if open_low else '>='} {low:g}"
    else:
        span = f"in {'(' if open_low else '['}{low:g}, {high:g}]"
    raise ConfigError(
        f"network parameter '{name}' must be a finite number {span}, got {v!r}", field=name
    )


@dataclass(frozen=True)
class Delivery:
    """A message that reached its destination.

    Attributes
    ----------
    src, dst : int
        Robot indices.
    payload : bytes
    sent, arrived : float
        Simulated times (s) of :meth:`SimNetwork.send` and of arrival.
    hops : int
        Links it crossed.
    id : int
        The network's count of accepted messages when it was sent (from 0).
    """

    src: int
    dst: int
    payload: bytes = field(repr=False)
    sent: float
    arrived: float
    hops: int
    id: int


@dataclass
class NetworkStats:
    """Counters per robot, arrays (N,) of int64. Drops are charged to the message's
    source; ``bytes_relayed`` to the robot that forwarded; ``links_made`` and
    ``links_broken`` count the direct links that came up (the first ones included) and
    went down at the robot: how often it met and parted from another."""

    bytes_sent: I64
    bytes_received: I64
    bytes_relayed: I64
    messages_sent: I64
    messages_received: I64
    dropped_lost: I64
    dropped_unroutable: I64
    dropped_link_broken: I64
    dropped_oversized: I64
    links_made: I64
    links_broken: I64

    @classmethod
    def zeros(cls, n: int) -> NetworkStats:
        return cls(*(np.zeros(n, dtype=np.int64) for _ in fields(cls)))

    def as_dict(self, robot: int) -> dict[str, int]:
        """One robot's counters."""
        return {f.name: int(getattr(self, f.name)[robot]) for f in fields(self)}


@dataclass(eq=False)
class _Message:
    id: int
    src: int
    dst: int
    payload: bytes
    sent: float
    hops: int = 0
    alive: bool = True


@dataclass(eq=False)
class _Link:
    """One directed link's bucket: ``level`` tokens at ``free_at``, the end of the last
    transmission queued on it (the link is idle from then on)."""

    free_at: float
    level: float
    last_arrival: float = -math.inf
    queued: deque[_Message] = field(default_factory=deque)


class SimNetwork:
    """The team's network between ``n`` robots, stepped by the caller's clock.

    Times passed to :meth:`update`, :meth:`send` and :meth:`deliver` never decrease;
    each call first plays the network's events up to its time.

    Parameters
    ----------
    params : NetworkParams
    n : int
        Robots, indexed 0 .. n-1.
    seed : int
        Seeds losses, jitter and the capacity factors.
    clear, grid : optional
        The prior map's cells a link may cross, on its grid; required by ``limited``.
    """

    def __init__(
        self,
        params: NetworkParams,
        n: int,
        *,
        seed: int = 0,
        clear: Bools | None = None,
        grid: Grid | None = None,
    ) -> None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ConfigError(f"a network needs n >= 1 robots, got {n!r}")
        if params.kind == "limited":
            if clear is None or grid is None:
                raise ConfigError("a 'limited' network needs the prior map: clear and grid")
            if np.shape(clear) != grid.shape:
                raise ConfigError(f"clear has shape {np.shape(clear)}, the grid {grid.shape}")
        self.params = params
        self.n = int(n)
        self.seed = int(seed)
        self._clear = None if clear is None else np.asarray(clear, dtype=bool)
        self._grid = grid
        loss_seq, jitter_seq = np.random.SeedSequence(self.seed).spawn(2)
        self._loss_rng = np.random.default_rng(loss_seq)
        self._jitter_rng = np.random.default_rng(jitter_seq)
        self._factors: dict[tuple[int, int, int], float] = {}
        self.now = -math.inf
        self.positions: F64 = np.full((self.n, 2), np.nan)
        self.stats = NetworkStats.zeros(self.n)
        self._events: list[tuple[float, int, int, _Message, int, int]] = []
        self._order = 0
        self._accepted = 0
        self._in_flight = 0
        self._outbox: list[Delivery] = []
        self._links: dict[tuple[int, int], _Link] = {}
        self._adj: Bools = np.zeros((self.n, self.n), dtype=bool)
        self._next: I64 = np.full((self.n, self.n), -1, dtype=np.int64)
        adj = np.zeros((self.n, self.n), dtype=bool)
        if params.kind == "full":
            adj = ~np.eye(self.n, dtype=bool)
        self._set_links(adj)

    # --- queries -----------------------------------------------------------------------

    @property
    def in_flight(self) -> int:
        """Accepted messages neither delivered nor dropped yet."""
        return self._in_flight

    def neighbours(self, src: int) -> list[int]:
        """Robots ``src`` has a direct link to now, in increasing order."""
        self._robot(src, "src")
        return [int(j) for j in np.flatnonzero(self._adj[src])]

    def reachable(self, src: int) -> list[int]:
        """Robots a message from ``src`` can reach now: its neighbours, or with relay
        every robot of its connected component (itself excluded)."""
        self._robot(src, "src")
        return [int(j) for j in np.flatnonzero(self._next[src] >= 0)]

    def links(self) -> I64:
        """The current links as pairs (i, j), i < j, one row each (K, 2)."""
        i, j = np.nonzero(np.triu(self._adj, 1))
        return np.stack([i, j], axis=1).astype(np.int64)

    def capacity(self, t: float, a: int, b: int) -> float:
        """Bytes/s of link a -> b at time ``t`` (inf when unlimited)."""
        bw = self.params.bandwidth
        if bw is None:
            return math.inf
        return bw * self._factor(a, b, math.floor(t / self.params.bandwidth_period))

    # --- the caller's clock ----------------------------------------------------------

    def update(self, t: float, xy: npt.ArrayLike) -> None:
        """The robots are at ``xy`` (N, 2) metres from time ``t`` on: links follow."""
        self._advance(t)
        pts = np.asarray(xy, dtype=np.float64)
        if pts.shape != (self.n, 2) or not np.isfinite(pts).all():
            raise InputError(
                f"robot positions must be {self.n} finite (x, y) rows, got shape {pts.shape}",
                field="xy",
            )
        self.positions = pts.copy()
        if self.params.kind == "limited":
            self._set_links(self._limited_links(pts))

    def send(self, t: float, src: int, dst: int, payload: bytes) -> bool:
        """Queue ``payload`` from ``src`` to ``dst`` at time ``t``; False (and counted) if
        it exceeds ``max_message`` or no route leads to ``dst`` now."""
        self._advance(t)
        self._robot(src, "src")
        self._robot(dst, "dst")
        if src == dst:
            raise InputError(f"robot {src} sends to itself", field="dst")
        if not isinstance(payload, (bytes, bytearray, memoryview)):
            raise InputError(f"payload must be bytes, got {type(payload).__name__}")
        data = bytes(payload)
        if len(data) > self.params.max_message:
            self.stats.dropped_oversized[src] += 1
            return False
        if self._next[src, dst] < 0:
            self.stats.dropped_unroutable[src] += 1
            return False
        msg = _Message(self._accepted, src, dst, data, t)
        self._accepted += 1
        self._in_flight += 1
        self.stats.messages_sent[src] += 1
        self.stats.bytes_sent[src] += len(data)
        self._enqueue(msg, src, t)
        return True

    def deliver(self, t: float) -> list[Delivery]:
        """Messages that arrived by time ``t`` and were not returned before, by arrival
        time, then by send order."""
        self._advance(t)
        out = sorted(self._outbox, key=lambda d: (d.arrived, d.id))
        self._outbox = []
        return out

    # --- internals ---------------------------------------------------------------------

    def _robot(self, i: int, name: str) -> None:
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < self.n:
            raise InputError(f"robot {i!r} is not in 0..{self.n - 1}", field=name)

    def _limited_links(self, pts: F64) -> Bools:
        assert self._clear is not None
        assert self._grid is not None
        d = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
        adj = np.zeros((self.n, self.n), dtype=bool)
        for i, j in zip(*np.nonzero(np.triu(d <= self.params.r_max, 1)), strict=True):
            x0, y0 = pts[i]
            x1, y1 = pts[j]
            adj[i, j] = adj[j, i] = line_of_sight(x0, y0, x1, y1, self._clear, self._grid)
        return adj

    def _set_links(self, adj: Bools) -> None:
        """New links from now on: drop what waits on broken ones, reroute."""
        self.stats.links_made += (adj & ~self._adj).sum(axis=1)
        self.stats.links_broken += (self._adj & ~adj).sum(axis=1)
        for key in [k for k in self._links if not adj[k]]:
            for msg in self._links.pop(key).queued:
                self._drop(msg, self.stats.dropped_link_broken)
        self._adj = adj
        self._next = _next_hops(adj, relay=self.params.relay)

    def _link(self, a: int, b: int, t: float) -> _Link:
        link = self._links.get((a, b))
        if link is None:
            # A new link starts with a full bucket: the pair had nothing to send before.
            link = self._links[(a, b)] = _Link(t, self.params.burst)
        return link

    def _push(self, t: float, kind: int, msg: _Message, a: int, b: int) -> None:
        heapq.heappush(self._events, (t, self._order, kind, msg, a, b))
        self._order += 1

    def _enqueue(self, msg: _Message, at: int, t: float) -> None:
        nxt = int(self._next[at, msg.dst])
        if nxt < 0:
            self._drop(msg, self.stats.dropped_link_broken)
            return
        if at != msg.src:
            self.stats.bytes_relayed[at] += len(msg.payload)
        link = self._link(at, nxt, t)
        done = self._transmit(link, at, nxt, t, len(msg.payload))
        link.queued.append(msg)
        self._push(done, _HOP_DONE, msg, at, nxt)

    def _transmit(self, link: _Link, a: int, b: int, t: float, size: int) -> float:
        """When the last of ``size`` bytes queued at ``t`` leaves; updates the bucket."""
        start = max(t, link.free_at)
        if self.params.bandwidth is None:
            link.free_at = start
            return start
        level = link.level
        if start > link.free_at and level < self.params.burst:
            level = min(self.params.burst, level + self._supply(a, b, link.free_at, start))
        if level >= size:
            link.free_at, link.level = start, level - size
        else:
            link.free_at, link.level = self._paid(a, b, start, size - level), 0.0
        return link.free_at

    def _factor(self, a: int, b: int, k: int) -> float:
        lo = self.params.bandwidth_min_factor
        if lo >= 1.0:
            return 1.0
        key = (min(a, b), max(a, b), k)
        f = self._factors.get(key)
        if f is None:
            if len(self._factors) >= _FACTOR_CACHE:
                self._factors.clear()
            # Keyed draws: a period's factor is the same whoever asks first. Seed
            # sequences take non-negative words only, hence the offset of k.
            rng = np.random.default_rng([self.seed, _FACTOR_TAG, key[0], key[1], k + (1 << 32)])
            f = self._factors[key] = lo + (1.0 - lo) * float(rng.random())
        return f

    def _supply(self, a: int, b: int, t0: float, t1: float) -> float:
        """Bytes link a -> b can carry from t0 to t1."""
        bw, period = self.params.bandwidth, self.params.bandwidth_period
        assert bw is not None
        if self.params.bandwidth_min_factor >= 1.0:
            return bw * (t1 - t0)
        total, t, k = 0.0, t0, math.floor(t0 / period)
        while t < t1:
            end = min(t1, (k + 1) * period)
            total += bw * self._factor(a, b, k) * max(0.0, end - t)
            t, k = end, k + 1
        return total

    def _paid(self, a: int, b: int, t0: float, need: float) -> float:
        """The time from which link a -> b has carried ``need`` bytes since t0; inf if
        not within :data:`MAX_PERIODS` periods (a varying factor) or t0 is inf."""
        bw, period = self.params.bandwidth, self.params.bandwidth_period
        assert bw is not None
        if self.params.bandwidth_min_factor >= 1.0 or not math.isfinite(t0):
            return t0 + need / bw
        # The period counter moves on by itself: floor(t / period) at a boundary can
        # round back into the period just finished.
        t, k = t0, math.floor(t0 / period)
        for _ in range(MAX_PERIODS):
            rate = bw * self._factor(a, b, k)
            end = (k + 1) * period
            if t + need / rate <= end:
                return t + need / rate
            need -= rate * max(0.0, end - t)
            t, k = max(t, end), k + 1
        return math.inf

    def _drop(self, msg: _Message, counter: I64) -> None:
        if msg.alive:
            msg.alive = False
            counter[msg.src] += 1
            self._in_flight -= 1

    def _advance(self, t: float) -> None:
        if not math.isfinite(t):
            raise InputError(f"time must be finite, got {t!r}", field="t")
        if t < self.now:
            raise InputError(f"time goes back from {self.now} to {t}", field="t")
        self.now = float(t)
        while self._events and self._events[0][0] <= t:
            when, _, kind, msg, a, b = heapq.heappop(self._events)
            if not msg.alive:
                continue
            if kind == _HOP_DONE:
                self._hop_done(when, msg, a, b)
            elif b == msg.dst:
                self._arrive(when, msg)
            else:
                self._enqueue(msg, b, when)

    def _hop_done(self, t: float, msg: _Message, a: int, b: int) -> None:
        link = self._links[(a, b)]
        # A link serves first come, first served, so its finished message is the first.
        link.queued.popleft()
        msg.hops += 1
        p = self.params
        if p.loss > 0 and self._loss_rng.random() < p.loss:
            self._drop(msg, self.stats.dropped_lost)
            return
        extra = p.jitter * self._jitter_rng.random() if p.jitter > 0 else 0.0
        arrival = max(t + p.delay + extra, link.last_arrival)
        link.last_arrival = arrival
        self._push(arrival, _ARRIVE, msg, a, b)

    def _arrive(self, t: float, msg: _Message) -> None:
        msg.alive = False
        self._in_flight -= 1
        self.stats.messages_received[msg.dst] += 1
        self.stats.bytes_received[msg.dst] += len(msg.payload)
        self._outbox.append(Delivery(msg.src, msg.dst, msg.payload, msg.sent, t, msg.hops, msg.id))


def _next_hops(adj: Bools, *, relay: bool) -> I64:
    """``next[u, d]``: the robot u hands a message for d to, -1 if none (and on the
    diagonal). With relay, the lowest-index neighbour on a shortest chain to d."""
    n = len(adj)
    nxt = np.full((n, n), -1, dtype=np.int64)
    if not relay:
        rows, cols = np.nonzero(adj)
        nxt[rows, cols] = cols
        return nxt
    # Hop counts by breadth-first growth of every robot's reach at once.
    hops = np.where(np.eye(n, dtype=bool), 0, -1).astype(np.int64)
    reach = np.eye(n, dtype=bool)
    step = adj.astype(np.int64)
    for k in range(1, n):
        grown = (reach.astype(np.int64) @ step > 0) & ~reach
        if not grown.any():
            break
        hops[grown] = k
        reach |= grown
    for u in range(n):
        # Neighbours w one hop closer to d; argmax takes the lowest index.
        closer = adj[u][:, None] & (hops == hops[u][None, :] - 1) & (hops[u] > 0)[None, :]
        has = closer.any(axis=0)
        nxt[u, has] = np.argmax(closer[:, has], axis=0)
    return nxt
