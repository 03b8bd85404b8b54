"""The exchange of poses between robots' stores (thesis 002, section 2.4): the
good-network and the limited-network protocols over a :class:`~.transport.Transport`,
with the messages of :mod:`.wire` and the outgoing-pose policy of :mod:`.outgoing`.

A bad body is rejected as a whole (logged on ``sonarmap.team.exchange``, counted in
``stats.rejected`` by reason), and nothing of it is applied. A valid answer is applied
patch by patch, each patch whole, so a peer that vanishes mid-exchange leaves nothing
half-applied: its request times out and is sent again, to it or another holder.

Choices where the thesis is silent (each is documented where it is made):

- The source's stamp. A local patch's stamp is the time it last changed; that is what
  the source advertises. It answers with ``now`` (the thesis) as the stamp, and if its
  patch changes at the very instant of an answer, later adverts carry a stamp just above
  the one handed out, so the change is never hidden by an equal stamp.
- Whom to ask. The source when it is a live peer (its advert heard within
  ``peer_timeout`` and the transport can reach it), comparing our stamp with the one it
  advertises; else the live peer advertising the newest stamp (ties: more poses held,
  then the lowest robot id). Comparing against the source's own advert, not against
  other holders' "now" stamps, keeps holders from re-asking each other forever.
- A patch whose full list names poses we lack (the limited mode's capped answers) is
  asked for again, from the source or the peers that hold most; a peer whose answer
  changed nothing in our store (a new stamp alone is no change: a source always
  answers with ``now``) is not asked again until its advert or our patch changes, or
  ``backoff`` seconds have passed.
- "Attached odometry edges": only those the requester lacks. The request names the
  edges the requester holds touching its poses of the patch by 4-byte fingerprints,
  and the answerer sends every edge touching the patch whose ends in the patch the
  requester holds or is sent, and whose fingerprint it did not name. That is how the
  edges a source adds when it deletes a pose (chaining its neighbours, which stamps
  both neighbours' patches anew) reach holders that already had both ends, and an
  edge held is never sent again (an earlier version sent every edge of the patch on
  any difference, most of them already held). An edge to a pose outside the patch that the
  requester lacks may come; the receiver keeps only edges whose two poses it holds, so
  such an edge comes again with a later answer. Two edges of one patch share a
  fingerprint with odds of about 1 in 4e9 per pair; the one the requester lacks would
  then not come until the patch's edges change.
- When to ask (``refresh``): a patch of a region the robot visits soon (the caller's
  ``wanted_regions``, the patrol's next moves, thesis l.1863-1872) is asked for as
  soon as a peer has it newer; any other patch at most once per ``refresh`` seconds
  since it was last asked for, so that the poses a source makes and compresses away
  within that time never travel. A patch we have never asked for is asked for at
  once (what the robot knows nothing of is worth most; delaying it too saved
  nothing measurable). With no
  ``wanted_regions`` (None: no patrol plan, e.g. the quiet network after a mission)
  every newer patch is asked for at once, so that a full network still converges. A
  patch whose request timed out is asked for again at once (a lost message is
  retried).
- Starved patches (the limited mode's cap T below the size of every pose the
  requester lacks): an answer entry that brought no pose while its list names poses we
  lack marks the patch starved; a starved patch loses its ``wanted_regions`` urgency
  (it waits for ``refresh`` like the others), and a peer whose answer changed nothing
  is not asked again for it until its advert or our patch changes, or ``backoff``
  seconds have passed.
- A patch the answerer has nothing newer for is answered by an empty entry, so the
  requester stops waiting at once instead of at the timeout.
- Limited mode, answerer older: after offering its poses, it adopts the requester's
  full list and stamp and drops its poses missing from that list (they were deleted at
  the source), so that its short list stays within its full list.
- Good mode: a patch whose full list (the answerer's short list) names poses we lack
  (an answer raced with a deletion) is asked for with no stamp, so that any holder sends
  what is missing.

Everything is deterministic: time comes from the caller's ``now``, iteration orders are
sorted, request ids count from 0.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from ..errors import ConfigError, InputError
from .outgoing import OutgoingPolicy
from .peerclosures import closures_to_send, encode_closures, pair_of
from .quantise import check_quantisation
from .records import ClosureEdge, OdometryEdge, Pose, encode, robot_of, size_of
from .rejects import RejectLog
from .store import Layer, Patch, RobotStore, compress_for_sending
from .transport import Message, SimTransport, Transport, ZmqTransport
from .wire import (
    ENVELOPE_SLACK,
    MODES,
    VERSION,
    Advert,
    AdvertEntry,
    Answer,
    ExchangeError,
    PatchAnswer,
    PatchKey,
    PatchRequest,
    Request,
    answer_row,
    decode_advert,
    decode_answer,
    decode_request,
    delta_advert,
    edge_fingerprint,
    edge_fingerprints,
    encode_advert,
    encode_request,
    pack,
    sorted_ids,
    split_fingerprints,
    stamp_or_none,
)

__all__ = [
    "LEAN",
    "PROTOCOLS",
    "ExchangeParams",
    "ExchangeStats",
    "Exchanger",
    "OnReceived",
    "check_pair",
    "check_time",
    "default_peers",
]

logger = logging.getLogger("sonarmap.team.exchange")

#: What :attr:`ExchangeParams.mode` may be: the two protocols, or the naive baseline that
#: :class:`~.naive.NaiveExchanger` runs (it has its own messages).
PROTOCOLS = (*MODES, "naive")
OnReceived = Callable[[int, Pose], Sequence[ClosureEdge]]


# --- parameters and counters ------------------------------------------------------------


@dataclass(frozen=True)
class ExchangeParams:
    """How a robot exchanges. The thesis gives no values, so every default is our
    choice; how they were chosen is on the team results pages of the docs
    (``docs/results/``) and in ``docs/team.md``.

    Attributes
    ----------
    mode : str
        ``"good"`` (a good network: whole patches) or ``"limited"`` (answers capped at
        ``cap_bytes``, full id lists kept); ``"naive"`` is the baseline of
        :class:`~.naive.NaiveExchanger` (every new pose to everyone). Default ``"good"``.
    cap_bytes : int
        T, bytes of poses one limited-mode answer may carry (edges are not counted):
        65536, four poses at the store's default ``pose_limit``.
    advert_every : float
        Seconds between adverts: 5.
    full_advert_every : float
        Seconds at least between two whole adverts to a peer; in between, adverts carry
        only the rows changed since the last whole one (a *delta*), and a peer the last
        round's advert did not reach gets a whole one. 0: every advert whole. Default 30.
    request_every : float
        Seconds between rounds of requests: 1.
    max_patches : int
        Patches one request names at most: 8.
    request_timeout : float
        Seconds after which an unanswered request is forgotten, so its patches can be
        asked for again (a lost message is retried): 10.
    peer_timeout : float
        Seconds an advert is trusted; a peer not heard from for longer is not asked:
        30. At least ``advert_every``.
    max_outstanding : int
        Requests awaiting an answer at most: 8.
    refresh : float
        Seconds at least between two requests for a patch outside the regions the robot
        visits next (``wanted_regions`` of :meth:`Exchanger.step`), and for a starved
        patch: 30.
    backoff : float
        Seconds after which a peer whose answer for a patch changed nothing is asked
        for it again though neither its advert nor our patch changed: 120.
    budget : float
        Bytes per second of answers this robot lets its requests bring in; 0 (default):
        no budget. The robot keeps a balance that grows at ``budget`` up to
        ``cap_bytes`` and pays for each answer it receives, and sends a request only
        while the balance is positive and no request awaits an answer.
    anchor_every : int
        k: a pose travels with its landmarks only if it is an *anchor*: every k-th pose
        its robot made (by the UID's counter) and every merged pose; the others travel
        bare (estimate, local map, odometry edges). 1 (default): every pose whole.
    loop_anchors : bool
        Also make an anchor of every own pose that closed a loop with an older anchor or
        with another robot's pose (:class:`.anchors.AnchorChooser`). Default False.
    anchor_share : float
        A byte target in (0, 1]: an own pose also travels whole while this robot has
        sent less than this share of what the naive baseline would have
        (:mod:`.outgoing`). 0 (default): off. Needs ``anchor_every`` > 1.
    hold : float
        Seconds a robot keeps a new own pose to itself before it offers it, so a pose
        its store deletes or merges within that time never travels (:mod:`.outgoing`).
        0 (default): at once.
    descriptor_bits : int
        Bits each landmark descriptor byte keeps as it travels (1..8); below 8 the
        landmarks' points and reliabilities also travel in float16 and their stamps in
        float32 (:func:`.quantise.quantise_pose`). 8 (default): exact.
    ternary_maps : bool
        Local maps travel as free, occupied and unknown, each class at its mean
        log-odds in that map (:func:`.quantise.ternary_logodds`). Default False.
    send_closures : bool
        Answers carry the answerer's loop closures that touch the poses sent, in a
        compact form (:mod:`.peerclosures`; the thesis keeps closures private). A robot
        takes the closures it receives whatever its own setting. Default False.
    """

    mode: str = "good"
    cap_bytes: int = 65_536
    advert_every: float = 5.0
    full_advert_every: float = 30.0
    request_every: float = 1.0
    max_patches: int = 8
    request_timeout: float = 10.0
    peer_timeout: float = 30.0
    max_outstanding: int = 8
    refresh: float = 30.0
    backoff: float = 120.0
    budget: float = 0.0
    anchor_every: int = 1
    loop_anchors: bool = False
    anchor_share: float = 0.0
    hold: float = 0.0
    descriptor_bits: int = 8
    ternary_maps: bool = False
    send_closures: bool = False

    def __post_init__(self) -> None:
        if self.mode not in PROTOCOLS:
            raise ConfigError(
                f"exchange: mode must be one of {', '.join(PROTOCOLS)}, got {self.mode!r}",
                field="mode",
            )
        for f in fields(self):
            if f.name in ("mode", "ternary_maps", "loop_anchors", "send_closures"):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(
                    f"exchange: {f.name} must be a finite number, got {v!r}", field=f.name
                )
            may_be_0 = f.name in ("budget", "hold", "full_advert_every", "anchor_share")
            if v < 0 or (v == 0 and not may_be_0):
                bound = ">= 0" if may_be_0 else "> 0"
                raise ConfigError(f"exchange: {f.name} must be {bound}, got {v}", field=f.name)
        for name in ("cap_bytes", "max_patches", "max_outstanding", "anchor_every"):
            if not isinstance(getattr(self, name), int):
                raise ConfigError(
                    f"exchange: {name} must be an integer, got {getattr(self, name)!r}", field=name
                )
        check_quantisation(self.descriptor_bits, self.ternary_maps)
        if self.anchor_share > 1:
            raise ConfigError(
                f"exchange: anchor_share must be <= 1, got {self.anchor_share}",
                field="anchor_share",
            )
        if self.anchor_share > 0 and self.anchor_every == 1:
            raise ConfigError(
                "exchange: anchor_share needs anchor_every > 1 (with 1 every pose travels whole)",
                field="anchor_share",
            )
        for name in ("loop_anchors", "send_closures"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(
                    f"exchange: {name} must be true or false, got {getattr(self, name)!r}",
                    field=name,
                )
        if self.peer_timeout < self.advert_every:
            raise ConfigError(
                f"exchange: peer_timeout {self.peer_timeout} s is below advert_every "
                f"{self.advert_every} s (every peer would be forgotten between adverts)",
                field="peer_timeout",
            )


#: The lean exchange (``team run --lean``, with the store's ``fold`` and
#: :data:`LEAN_MERGE_ON_CLOSURE`): landmarks on every 12th pose and while under 15 % of
#: the naive baseline's bytes, poses offered once 30 s old, 3-bit descriptors, ternary
#: maps, adverts every 10 s (whole every 60 s), the answerer's closures with the poses
#: they touch (``send_closures``). How it was chosen on training plans and how it does
#: on held-out ones: the team results pages of the docs.
LEAN = ExchangeParams(
    advert_every=10.0,
    full_advert_every=60.0,
    anchor_every=12,
    anchor_share=0.15,
    hold=30.0,
    descriptor_bits=3,
    ternary_maps=True,
    send_closures=True,
)
#: The store's ``merge_on_closure`` with :data:`LEAN`: own poses merge at closures of 8 or
#: more inliers, so that receivers, which hold most poses bare, get the robot's loops as
#: edges.
LEAN_MERGE_ON_CLOSURE = 8


@dataclass
class ExchangeStats:
    """An exchanger's counters. Bytes are message bodies (the transport adds its
    envelope); a message counts as sent when the transport took it.

    Attributes
    ----------
    bytes_sent, bytes_received, messages_sent, messages_received : int
    poses_sent : int
        Poses in the answers sent.
    poses_received : int
        Poses in the valid answers received.
    poses_added, poses_deleted : int
        Poses the exchange put into or took out of the received layers.
    requests_sent : int
    retries : int
        Patches asked for again after their request timed out.
    stale : int
        Answer entries not applied because the patch had meanwhile become newer.
    stale_adverts : int
        Adverts ignored because one sent later had already arrived.
    refused : int
        Messages the transport would not take (no route, too large, closed).
    closures_sent : int
        Closures in the answers sent (``send_closures``).
    closures_received : int
        Closures in the valid answers received.
    closures_added : int
        Of those, the ones the store took (:meth:`.store.RobotStore.add_peer_closures`).
    closures_duplicate, closures_unheld : int
        Of those, the ones refused as joining two poses already joined (either
        direction) and as naming a pose the store does not hold.
    closures_withheld : int
        Closures that would have gone with an answer but that a receiver refuses
        (:func:`.peerclosures.closures_to_send`: a rule broken, or past the cap per pose).
    rejected : Counter
        Messages rejected, by reason (``"truncated"``, ``"type"``, ``"unsolicited"``...).
    bytes_by_kind : Counter
        ``bytes_sent`` split by message kind (``"advert"``, ``"request"``, ``"answer"``;
        the naive baseline's ``"pose"``).
    """

    bytes_sent: int = 0
    bytes_received: int = 0
    messages_sent: int = 0
    messages_received: int = 0
    poses_sent: int = 0
    poses_received: int = 0
    poses_added: int = 0
    poses_deleted: int = 0
    requests_sent: int = 0
    retries: int = 0
    stale: int = 0
    stale_adverts: int = 0
    refused: int = 0
    closures_sent: int = 0
    closures_received: int = 0
    closures_added: int = 0
    closures_duplicate: int = 0
    closures_unheld: int = 0
    closures_withheld: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    bytes_by_kind: Counter[str] = field(default_factory=Counter)

    def count_sent(self, kind: str, size: int) -> None:
        """Count one message of ``kind`` and ``size`` body bytes the transport took."""
        self.messages_sent += 1
        self.bytes_sent += size
        self.bytes_by_kind[kind] += size

    def state(self) -> dict[str, Any]:
        """The counters as plain msgpack values (:meth:`restore`)."""
        counters = ("rejected", "bytes_by_kind")
        plain = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in counters}
        return {
            "stats": plain,
            "rejected": dict(self.rejected),
            "bytes_by_kind": dict(self.bytes_by_kind),
        }

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`."""
        for name, v in state["stats"].items():
            setattr(self, name, v)
        self.rejected.clear()
        self.rejected.update({str(k): int(v) for k, v in state["rejected"].items()})
        self.bytes_by_kind.clear()
        self.bytes_by_kind.update(
            {str(k): int(v) for k, v in state.get("bytes_by_kind", {}).items()}
        )


# --- the exchanger ------------------------------------------------------------------------


@dataclass
class _Pending:
    """A request sent and not wholly answered: the patches still awaited."""

    peer: int
    patches: set[PatchKey]
    sent: float
    deadline: float


def _pending_state(p: _Pending) -> list[Any]:
    return [p.peer, sorted([list(k) for k in p.patches]), p.sent, p.deadline]


def _pending_from(v: Any) -> _Pending:
    return _Pending(int(v[0]), {(int(a), int(b)) for a, b in v[1]}, float(v[2]), float(v[3]))


def _entry_state(e: AdvertEntry | None) -> list[Any] | None:
    return None if e is None else [e.source, e.region, float(e.stamp), e.held]


def _entry_from(v: Any) -> AdvertEntry | None:
    return None if v is None else AdvertEntry(int(v[0]), int(v[1]), float(v[2]), int(v[3]))


def _tables_state(
    tables: Mapping[int, tuple[float, Mapping[PatchKey, AdvertEntry]]],
) -> list[list[Any]]:
    """Per peer, a time and an advert table as ``[peer, time, rows]``."""
    return [[p, t, [_entry_state(x) for x in table.values()]] for p, (t, table) in tables.items()]


def _tables_from(rows: Iterable[Any]) -> dict[int, tuple[float, dict[PatchKey, AdvertEntry]]]:
    out = {}
    for p, t, table in rows:
        entries = [x for x in (_entry_from(r) for r in table) if x is not None]
        out[int(p)] = (float(t), {(x.source, x.region): x for x in entries})
    return out


@dataclass(frozen=True)
class _Plan:
    """How a limited-mode answerer treats one requested patch."""

    request: PatchRequest
    case: str  # "none", "older", "newer" or "equal"
    stamp: float | None = None
    offer: set[int] = field(default_factory=set)
    listed: set[int] = field(default_factory=set)
    adopt_stamp: float | None = None
    adopt_full: frozenset[int] | None = None


@dataclass(frozen=True)
class _Out:
    """An answer entry ready to send: its wire map and byte size."""

    row: dict[str, Any]
    size: int
    poses: int
    closures: int = 0


def check_pair(store: RobotStore, transport: Transport) -> None:
    """An exchanger's store and transport must be one robot's."""
    if transport.robot != store.robot:
        raise ConfigError(
            f"exchange: the store is robot {store.robot}'s, the transport robot {transport.robot}'s"
        )


def check_time(now: object, last: float) -> None:
    """An exchanger's clock: a finite time, never before the ``last`` step's."""
    if isinstance(now, bool) or not isinstance(now, (int, float)) or not math.isfinite(now):
        raise InputError(f"exchange: now must be a finite time, got {now!r}", field="now")
    if now < last:
        raise InputError(f"exchange: time goes back from {last} to {now}", field="now")


def default_peers(transport: Transport) -> Callable[[], Iterable[int]]:
    if isinstance(transport, SimTransport):
        hub, robot = transport.hub, transport.robot
        return lambda: hub.network.reachable(robot)
    if isinstance(transport, ZmqTransport):
        return lambda: sorted(transport.peers)
    raise ConfigError(
        f"exchange: cannot tell the peers of a {type(transport).__name__}; pass peers="
    )


class Exchanger:
    """One robot's side of the exchange: answers requests, advertises its patches and
    asks its peers for the patches they have newer.

    Parameters
    ----------
    store : RobotStore
        The robot's store. The exchange changes only its received layers and closures
        (never the local layer).
    transport : Transport
        The robot's transport; the exchanger reads all its messages.
    params : ExchangeParams
    adjacency : mapping of int to collection of int, optional
        The prior map's regions and their neighbours (:func:`.regions.region_adjacency`).
        Needed for limited-mode requests of several patches (without it each covers one
        patch); it also bounds the regions a message may name.
    on_received : callable, optional
        ``on_received(source, pose) -> closures``, called for each received pose before
        it enters the store (association; the mission passes it); the closures go to
        the store with the pose. Its exceptions are not caught.
    peers : callable, optional
        ``peers() -> robot ids`` the transport can reach now. Default: the simulated
        network's :meth:`~.network.SimNetwork.reachable`, or a ZeroMQ transport's peers.

    Attributes
    ----------
    stats : ExchangeStats
    """

    def __init__(
        self,
        store: RobotStore,
        transport: Transport,
        params: ExchangeParams | None = None,
        *,
        adjacency: Mapping[int, Collection[int]] | None = None,
        on_received: OnReceived | None = None,
        peers: Callable[[], Iterable[int]] | None = None,
        naive_bytes: Callable[[], float] | None = None,
    ) -> None:
        check_pair(store, transport)
        if params is not None and params.mode not in MODES:
            raise ConfigError(
                f"exchange: mode {params.mode!r} is not a protocol of Exchanger "
                "(the naive baseline is naive.NaiveExchanger; naive.make_exchanger picks)"
            )
        self.store = store
        self.transport = transport
        self.params = params if params is not None else ExchangeParams()
        self.adjacency: dict[int, frozenset[int]] | None = (
            None
            if adjacency is None
            else {int(r): frozenset(int(n) for n in ns) for r, ns in adjacency.items()}
        )
        self.on_received = on_received
        self.stats = ExchangeStats()
        self._rejects = RejectLog(logger)
        self._peers = peers if peers is not None else default_peers(transport)
        self._now = -math.inf
        self._next_advert = -math.inf
        self._next_request = -math.inf
        self._adverts: dict[int, tuple[float, dict[PatchKey, AdvertEntry]]] = {}
        # Per peer: the send time of the newest advert heard from it and the last whole
        # table heard (its send time and rows); the last whole table sent to it and
        # when. The peers an advert reached at the last round (another gets a whole).
        self._heard: dict[int, float] = {}
        self._whole: dict[int, tuple[float, dict[PatchKey, AdvertEntry]]] = {}
        self._told: dict[int, tuple[float, dict[PatchKey, AdvertEntry]]] = {}
        self._in_reach: frozenset[int] = frozenset()
        self._pending: dict[int, _Pending] = {}
        self._expired: dict[int, _Pending] = {}
        self._waiting: dict[PatchKey, int] = {}
        self._timed_out: set[PatchKey] = set()
        # (peer, source, region) -> (advert entry, our stamp, short and full sizes, when).
        self._futile: dict[tuple[int, int, int], tuple[object, ...]] = {}
        self._handed: dict[int, tuple[float, frozenset[int]]] = {}
        # When each patch was last asked for, and when it was found starved.
        self._fetched: dict[PatchKey, float] = {}
        self._starved: dict[PatchKey, float] = {}
        self._next_id = 0
        # The budget's balance (bytes) and when it was last topped up.
        self._balance = float(self.params.cap_bytes)
        self._balance_at = -math.inf
        # What of the robot's own poses travels, and when.
        p = self.params
        self.outgoing = OutgoingPolicy(
            store,
            anchor_every=p.anchor_every,
            loop_anchors=p.loop_anchors,
            anchor_share=p.anchor_share,
            hold=p.hold,
            descriptor_bits=p.descriptor_bits,
            ternary_maps=p.ternary_maps,
            naive_bytes=naive_bytes,
            sent=lambda: self.stats.bytes_sent,
            live_peers=lambda: len(self._live(self._now)),
        )

    @property
    def robot(self) -> int:
        return self.store.robot

    def finish(self) -> None:
        """The mission is over: from the next step every own pose is offered, however
        young (:meth:`.outgoing.OutgoingPolicy.finish`)."""
        self.outgoing.finish()

    @property
    def now(self) -> float:
        """Mission time of the last :meth:`step`, seconds (-inf before any)."""
        return self._now

    def peer_table(self, peer: int) -> dict[PatchKey, AdvertEntry]:
        """The advert table this robot holds of ``peer`` (empty if none heard)."""
        return dict(self._adverts.get(peer, (0.0, {}))[1])

    @property
    def outstanding(self) -> dict[int, tuple[int, list[PatchKey]]]:
        """Requests awaiting an answer: id -> (peer, patches still awaited)."""
        return {i: (p.peer, sorted(p.patches)) for i, p in sorted(self._pending.items())}

    # --- the loop ------------------------------------------------------------------------

    def step(self, now: float, wanted_regions: Sequence[int] | None = None) -> None:
        """Handle every message received, then advertise and request when due.

        Parameters
        ----------
        now : float
            Mission time, seconds; never decreasing.
        wanted_regions : sequence of int, optional
            Regions the robot visits next, most urgent first: their patches are asked
            for before the others, and as soon as a peer has them newer; the others at
            most every ``refresh`` seconds. None (no patrol plan, e.g. the quiet network
            after a mission): every patch as soon as a peer has it newer.
        """
        check_time(now, self._now)
        wanted = None if wanted_regions is None else [int(r) for r in wanted_regions]
        self._now = float(now)
        self.outgoing.update(self._now)
        for msg in self.transport.poll(0.0):
            self.handle(msg, self._now)
        self._expire(self._now)
        if self._now >= self._next_advert:
            self._advertise(self._now)
            self._next_advert = self._now + self.params.advert_every
        if self._now >= self._next_request:
            self._request(self._now, wanted)
            self._next_request = self._now + self.params.request_every

    # --- sending -------------------------------------------------------------------------

    def _send(self, dst: int, kind: str, body: bytes) -> bool:
        if not self.transport.send(dst, body, kind=kind):
            self.stats.refused += 1
            return False
        self.stats.count_sent(kind, len(body))
        return True

    def _live(self, now: float) -> dict[int, dict[PatchKey, AdvertEntry]]:
        """Peers reachable now whose advert is fresh, with their tables."""
        reach = set(self._peers())
        return {
            p: table
            for p, (at, table) in sorted(self._adverts.items())
            if p in reach and now - at <= self.params.peer_timeout
        }

    # --- stamps of the local layer --------------------------------------------------------

    def _own_stamp(self, region: int) -> float:
        """The stamp the source advertises for a local patch: the time it last changed,
        or just above the last stamp it handed out if it changed at that very time."""
        patch = self.outgoing.offered.patches[region]
        stamp = patch.stamp
        handed = self._handed.get(region)
        if handed is not None and stamp <= handed[0] and handed[1] != frozenset(patch.short):
            stamp = math.nextafter(handed[0], math.inf)
        return stamp

    def _source_stamp(self, region: int, now: float) -> float:
        """The stamp the source answers with (``now``, thesis), remembered with the list."""
        patch = self.outgoing.offered.patches.get(region)
        if patch is None:
            return now
        stamp = max(now, self._own_stamp(region))
        self._handed[region] = (stamp, frozenset(patch.short))
        return stamp

    # --- adverts -------------------------------------------------------------------------

    def advert(self) -> Advert:
        """This robot's table: every local patch (its stamp as the source) and every
        received patch with a stamp, sorted by (source, region)."""
        rows: list[AdvertEntry] = []
        own = self.outgoing.offered
        for r in sorted(own.patches):
            stamp = self._own_stamp(r)
            if math.isfinite(stamp):
                rows.append(AdvertEntry(self.robot, r, stamp, len(own.patches[r].short)))
        for src in sorted(self.store.received):
            layer = self.store.received[src]
            for r in sorted(layer.patches):
                p = layer.patches[r]
                if math.isfinite(p.stamp):
                    rows.append(AdvertEntry(src, r, p.stamp, len(p.short)))
        return Advert(tuple(rows))

    def _advertise(self, now: float) -> None:
        """Send each peer in reach the table, whole or as a delta (``full_advert_every``)."""
        rows = self.advert().entries
        table = {(e.source, e.region): e for e in rows}
        whole = encode_advert(Advert(rows, t=now))
        deltas: dict[float, bytes | None] = {}
        reached = set()
        for peer in sorted(set(self._peers()) - {self.robot}):
            told = self._told.get(peer)
            body = None
            if (
                told is not None
                and peer in self._in_reach
                and now - told[0] < self.params.full_advert_every
            ):
                if told[0] not in deltas:
                    deltas[told[0]] = delta_advert(told, table, now)
                body = deltas[told[0]]
            if body is not None:
                if self._send(peer, "advert", body):
                    reached.add(peer)
            elif self._send(peer, "advert", whole):
                self._told[peer] = (now, table)
                reached.add(peer)
        self._in_reach = frozenset(reached)

    # --- requests ------------------------------------------------------------------------

    def _layer(self, source: int) -> Layer | None:
        return self.store.received.get(source)

    def _held(self, key: PatchKey) -> Patch | None:
        layer = self._layer(key[0])
        return None if layer is None else layer.patches.get(key[1])

    def _our_stamp(self, key: PatchKey) -> float | None:
        p = self._held(key)
        return p.stamp if p is not None and math.isfinite(p.stamp) else None

    def _incomplete(self, key: PatchKey) -> bool:
        p = self._held(key)
        return p is not None and not p.full <= p.short

    def _futile_state(
        self, peer: int, key: PatchKey, entry: AdvertEntry | None
    ) -> tuple[object, ...]:
        p = self._held(key)
        mine = (None, 0, 0) if p is None else (p.stamp, len(p.short), len(p.full))
        return (entry, *mine)

    def _is_futile(self, peer: int, key: PatchKey, entry: AdvertEntry, now: float) -> bool:
        """Whether ``peer``'s last answer for ``key`` changed nothing, and neither its
        advert nor our patch changed since, within ``backoff`` seconds."""
        v = self._futile.get((peer, *key))
        if v is None or tuple(v[:4]) != self._futile_state(peer, key, entry):
            return False
        at = v[4] if len(v) > 4 else None
        return isinstance(at, (int, float)) and now - at < self.params.backoff

    def _choose(
        self, key: PatchKey, live: Mapping[int, Mapping[PatchKey, AdvertEntry]], now: float
    ) -> int | None:
        """The peer to ask for patch ``key``, or None if no one has anything for us."""
        ours = self._our_stamp(key)
        src = key[0]
        if src in live:
            entry = live[src].get(key)
            if entry is None:
                return None
            if ours is None or entry.stamp > ours:
                return src
            if self._incomplete(key) and not self._is_futile(src, key, entry, now):
                return src
            return None
        holders = sorted(
            ((t[key], p) for p, t in live.items() if key in t and p != self.robot),
            key=lambda ep: (-ep[0].stamp, -ep[0].held, ep[1]),
        )
        if not holders:
            return None
        best, peer = holders[0]
        if ours is None or best.stamp > ours:
            return peer
        if self._incomplete(key):
            for entry, peer in sorted(holders, key=lambda ep: (-ep[0].held, -ep[0].stamp, ep[1])):
                if entry.held > 0 and not self._is_futile(peer, key, entry, now):
                    return peer
        return None

    def _patch_request(self, key: PatchKey) -> PatchRequest:
        p = self._held(key)
        layer = self._layer(key[0])
        short = frozenset() if p is None else frozenset(p.short)
        stamp = self._our_stamp(key)
        mine = (
            ()
            if layer is None or not short
            else [e for e in layer.edges if e.a in short or e.b in short]
        )
        prints = edge_fingerprints(mine)
        if self.params.mode == "good":
            if self._incomplete(key):
                stamp = None  # any holder sends what we lack
            return PatchRequest(key[0], key[1], stamp, short, None, prints)
        full = frozenset() if p is None else frozenset(p.full | p.short)
        return PatchRequest(key[0], key[1], stamp, short, full, prints)

    def _due(self, key: PatchKey, now: float, urgent: Collection[int] | None) -> bool:
        """Whether patch ``key`` may be asked for now if a peer has it newer: the
        refresh policy of the module's choices (``urgent``: the wanted regions, None
        without a plan)."""
        if urgent is None or key in self._timed_out:
            return True
        if key in self._starved and not self._incomplete(key):
            del self._starved[key]
        if key[1] in urgent and key not in self._starved:
            return True
        last = self._fetched.get(key)
        return last is None or now - last >= self.params.refresh

    def _request(self, now: float, wanted: Sequence[int] | None) -> None:
        live = self._live(now)
        keys: set[PatchKey] = set()
        for table in live.values():
            keys.update(k for k in table if k[0] != self.robot)
        rank: dict[int, int] = {}
        for i, r in enumerate(wanted or ()):
            rank.setdefault(r, i)
        urgent = None if wanted is None else rank.keys()
        order = sorted(keys, key=lambda k: (rank.get(k[1], len(rank)), k[0], k[1]))
        chosen: dict[PatchKey, int] = {}
        for k in order:
            if k in self._waiting or not self._due(k, now, urgent):
                continue
            peer = self._choose(k, live, now)
            if peer is not None:
                chosen[k] = peer
        groups = self._group(order, chosen)
        for peer, group in groups:
            if len(self._pending) >= self.params.max_outstanding or not self._affordable(now):
                break
            self._send_request(peer, group, now)

    def _affordable(self, now: float) -> bool:
        """Whether the budget allows one more request now (always without a budget)."""
        budget = self.params.budget
        if budget == 0:
            return True
        cap = float(self.params.cap_bytes)
        if math.isfinite(self._balance_at):
            self._balance = min(cap, self._balance + budget * (now - self._balance_at))
        self._balance_at = now
        # The balance never exceeds the cap, so one request awaiting an answer (which
        # may cost a cap) is all the budget allows at a time.
        return not self._pending and self._balance > 0

    def _group(
        self, order: Sequence[PatchKey], chosen: Mapping[PatchKey, int]
    ) -> list[tuple[int, list[PatchKey]]]:
        """Requests in priority order: good mode, patches by peer up to ``max_patches``;
        limited mode, connected sets of adjacent patches of one source and one peer."""
        cap = self.params.max_patches
        out: list[tuple[int, list[PatchKey]]] = []
        if self.params.mode == "good":
            open_: dict[int, list[PatchKey]] = {}
            for k in order:
                if k not in chosen:
                    continue
                peer = chosen[k]
                group = open_.get(peer)
                if group is None or len(group) >= cap:
                    group = open_[peer] = []
                    out.append((peer, group))
                group.append(k)
            return out
        done: set[PatchKey] = set()
        for k in order:
            if k not in chosen or k in done:
                continue
            peer, src = chosen[k], k[0]
            group, todo = [k], [k]
            done.add(k)
            while todo and len(group) < cap and self.adjacency is not None:
                r = todo.pop(0)
                for n in sorted(self.adjacency.get(r[1], ())):
                    nk = (src, n)
                    if nk in chosen and nk not in done and chosen[nk] == peer and len(group) < cap:
                        done.add(nk)
                        group.append(nk)
                        todo.append(nk)
            out.append((peer, group))
        return out

    def _send_request(self, peer: int, keys: list[PatchKey], now: float) -> None:
        rid = self._next_id
        self._next_id += 1
        req = Request(rid, self.params.mode, tuple(self._patch_request(k) for k in keys))
        if not self._send(peer, "request", encode_request(req)):
            return
        self.stats.requests_sent += 1
        self.stats.retries += sum(1 for k in keys if k in self._timed_out)
        self._timed_out.difference_update(keys)
        self._pending[rid] = _Pending(peer, set(keys), now, now + self.params.request_timeout)
        for k in keys:
            self._waiting[k] = rid
            self._fetched[k] = now

    def _expire(self, now: float) -> None:
        for rid in [i for i, p in sorted(self._pending.items()) if p.deadline <= now]:
            p = self._pending.pop(rid)
            for k in p.patches:
                if self._waiting.get(k) == rid:
                    del self._waiting[k]
            self._timed_out.update(p.patches)
            self._expired[rid] = p
        # A late answer is still welcome for another timeout; then it is unsolicited.
        for rid in [
            i for i, p in self._expired.items() if p.deadline + self.params.request_timeout <= now
        ]:
            del self._expired[rid]

    # --- receiving -----------------------------------------------------------------------

    def handle(self, msg: Message, now: float) -> None:
        """Take one message at mission time ``now`` (seconds), as :meth:`step` does with
        each it polls: decoded strictly, then applied, or rejected, logged and counted."""
        body = msg.payload
        self.stats.messages_received += 1
        self.stats.bytes_received += len(body)
        regions = None if self.adjacency is None else self.adjacency.keys()
        try:
            if msg.kind == "advert":
                self._take_advert(msg.src, decode_advert(body, regions=regions), now)
            elif msg.kind == "request":
                request = decode_request(body, regions=regions, adjacency=self.adjacency)
                self._answer(msg.src, request, now)
            elif msg.kind == "answer":
                # Paid for before it is checked: a rejected answer used the link too.
                self._balance -= len(body)
                answer = decode_answer(body, regions=regions)
                self._take(msg.src, answer, now)
            else:
                raise ExchangeError("kind", f"unknown kind {msg.kind!r}")
        except ExchangeError as e:
            self.stats.rejected[e.code] += 1
            self._rejects.warn(
                f"robot {self.robot} rejected a {msg.kind[:16]!r} from robot {msg.src} "
                f"({e.code}): {e.reason}"
            )

    def _take_advert(self, peer: int, advert: Advert, now: float) -> None:
        """Bring our copy of the peer's table up to ``advert``. One sent before an
        advert already heard (delayed, reordered) is ignored. A delta goes over the
        whole table it follows if we heard that one; else over our copy, whose rows it
        does not name may then stay stale (never older than we held) until the next
        whole table."""
        t = advert.t
        if t is not None:
            if t <= self._heard.get(peer, -math.inf):
                self.stats.stale_adverts += 1
                return
            self._heard[peer] = t
        table = {(e.source, e.region): e for e in advert.entries}
        if advert.delta:
            whole = self._whole.get(peer)
            if whole is not None and whole[0] == advert.base:
                base = whole[1]
            else:
                base = self._adverts.get(peer, (now, {}))[1]
            held = dict(base)
            for key in advert.gone:
                held.pop(key, None)
            held.update(table)
            table = held
        else:
            self._whole[peer] = (-math.inf if t is None else t, table)
        self._adverts[peer] = (now, table)

    # --- answering -----------------------------------------------------------------------

    def _answer(self, peer: int, request: Request, now: float) -> None:
        """Answer a validated request (each mode by its rules), then send it."""
        if request.mode != self.params.mode:
            raise ExchangeError("mode", f"a {request.mode} request to a {self.params.mode} robot")
        if any(p.source == peer for p in request.patches):
            raise ExchangeError("own", f"robot {peer} asks for its own poses")
        # A closure between poses of two patches of one answer travels once.
        pairs: set[frozenset[int]] = set()
        if self.params.mode == "good":
            outs = [self._good_entry(p, now, pairs) for p in request.patches]
        else:
            outs = self._limited_entries(request.patches, now, pairs)
        self._send_answer(peer, request, outs)

    def _patch_of(self, source: int, region: int) -> tuple[Layer | None, Patch | None]:
        layer = self.outgoing.offered if source == self.robot else self.store.received.get(source)
        patch = None if layer is None else layer.patches.get(region)
        if patch is not None and source != self.robot and not math.isfinite(patch.stamp):
            patch = None
        return layer, patch

    @staticmethod
    def _empty(p: PatchRequest) -> _Out:
        row = answer_row(PatchAnswer(p.source, p.region, None, None, None), [], [])
        return _Out(row, len(pack(row)), 0)

    def _entry(
        self,
        layer: Layer,
        p: PatchRequest,
        stamp: float | None,
        short: Collection[int] | None,
        full: Collection[int] | None,
        send: Sequence[int],
        pairs: set[frozenset[int]],
    ) -> _Out:
        """The entry for patch ``p`` sending ``send``; its closures' pairs join ``pairs``
        (the ones already in this answer, which it does not carry again)."""
        poses = [encode(self.outgoing.wire(layer.poses[u])) for u in send]
        edges = self._edges_for(layer, p, send)
        row: dict[str, Any] = {
            "src": p.source,
            "r": p.region,
            "s": stamp_or_none(stamp),
            "short": sorted_ids(short),
            "full": sorted_ids(full),
            "poses": poses,
            "edges": [encode(e) for e in edges],
        }
        closures = self._closures_for(layer, p, send, pairs) if self.params.send_closures else []
        pairs.update(pair_of(c) for c in closures)
        if closures:
            row["c"] = encode_closures(closures)
        return _Out(row, len(pack(row)), len(poses), len(closures))

    def _closures_for(
        self,
        layer: Layer,
        p: PatchRequest,
        send: Collection[int],
        skip: Collection[frozenset[int]],
    ) -> list[ClosureEdge]:
        """Our closures that go with the poses ``send`` of patch ``p`` and are not in
        ``skip`` (:func:`.peerclosures.closures_to_send`): the requester lacks a pose of
        the patch its short list does not name, and an own pose we have not offered yet.
        Those the receiver's rules would refuse are counted in ``closures_withheld``."""
        poses, offered = layer.poses, self.outgoing.offered.poses

        def may_hold(u: int) -> bool:
            if u in poses and poses[u].region == p.region:
                return u in p.short
            return robot_of(u) != self.robot or u in offered

        chosen = closures_to_send(self.store.closures, set(send), may_hold, skip)
        self.stats.closures_withheld += chosen.dropped
        return chosen.closures

    @staticmethod
    def _edges_for(layer: Layer, p: PatchRequest, send: Collection[int]) -> list[OdometryEdge]:
        """The odometry edges to attach to the answer for patch ``p``: every edge touching
        the patch whose ends in the patch the requester holds or is sent, and whose
        fingerprint the requester did not name (the module's choices)."""
        poses, region = layer.poses, p.region
        held, sent = p.short, set(send)
        have = split_fingerprints(p.edges)
        out = set()
        for e in layer.edges:
            ends = [u for u in (e.a, e.b) if u in poses and poses[u].region == region]
            if (
                ends
                and all(u in held or u in sent for u in ends)
                and edge_fingerprint(e) not in have
            ):
                out.add(e)
        return sorted(out, key=lambda e: (e.a, e.b, e.transform))

    def _good_entry(self, p: PatchRequest, now: float, pairs: set[frozenset[int]]) -> _Out:
        """Good network: nothing if we are not the source and not newer; else the poses
        of the patch the requester lacks, our short list and our stamp."""
        layer, patch = self._patch_of(p.source, p.region)
        source = p.source == self.robot
        if layer is None or (patch is None and not source):
            return self._empty(p)
        short = set() if patch is None else set(patch.short)
        if source:
            stamp = self._source_stamp(p.region, now)
        else:
            assert patch is not None
            stamp = patch.stamp
            if p.stamp is not None and stamp <= p.stamp:
                return self._empty(p)
        send = sorted(short - p.short, key=lambda u: (layer.poses[u].time, u))
        return self._entry(layer, p, stamp, short, None, send, pairs)

    def _limited_entries(
        self, patches: Sequence[PatchRequest], now: float, pairs: set[frozenset[int]]
    ) -> list[_Out]:
        """Limited network: per patch by stamps (ours older: offer what the requester's
        full list names and it lacks, then adopt its full list; newer: our full list and
        stamp and the short-list poses it lacks; equal: those poses), then the subset of
        best efficiency within ``cap_bytes``."""
        src = patches[0].source
        source = src == self.robot
        layer = self.outgoing.offered if source else self.store.received.get(src)
        if layer is None:
            return [self._empty(p) for p in patches]
        plans: list[_Plan] = []
        for p in patches:
            assert p.full is not None  # decode_request: a limited request has full lists
            _, patch = self._patch_of(src, p.region)
            if patch is None and not source:
                plans.append(_Plan(p, "none"))
                continue
            short = set() if patch is None else set(patch.short)
            if source:
                stamp = self._source_stamp(p.region, now)
                full = set(short)
            else:
                assert patch is not None
                stamp, full = patch.stamp, set(patch.full | patch.short)
            if not source and p.stamp is not None and stamp < p.stamp:
                offer = (short & p.full) - p.short
                plans.append(_Plan(p, "older", None, offer, short & p.full, p.stamp, p.full))
            elif p.stamp is None or stamp != p.stamp:
                plans.append(_Plan(p, "newer", stamp, short - p.short, full))
            else:
                plans.append(_Plan(p, "equal", None, short - p.short, short))
        offered = set().union(*(q.offer for q in plans))
        chosen = set(
            compress_for_sending(
                layer,
                sorted({p.region for p in patches}),
                self.params.cap_bytes,
                now,
                params=self.store.params,
                uids=offered,
                size=None
                if self.params.anchor_every == 1
                else lambda u: size_of(self.outgoing.wire(layer.poses[u])),
            )
        )
        outs: list[_Out] = []
        for q in plans:
            if q.case == "none":
                outs.append(self._empty(q.request))
                continue
            send = sorted(q.offer & chosen, key=lambda u: (layer.poses[u].time, u))
            full_out = q.listed if q.case == "newer" else None
            outs.append(self._entry(layer, q.request, q.stamp, None, full_out, send, pairs))
        # Older than the requester: adopt its full list and stamp, after the answer is
        # built (the poses offered are in that list, so none of them goes).
        for q in plans:
            if q.adopt_stamp is not None and q.adopt_full is not None:
                self._adopt(src, q.request.region, q.adopt_stamp, q.adopt_full)
        return outs

    def _adopt(self, source: int, region: int, stamp: float, full: Collection[int]) -> None:
        layer = self.store.received[source]
        patch = layer.patches[region]
        for u in sorted(patch.short - set(full)):
            self.store.remove_received_pose(source, u)
            self.stats.poses_deleted += 1
        patch.full = set(full)
        patch.stamp = stamp

    def _send_answer(self, peer: int, request: Request, outs: Sequence[_Out]) -> None:
        """Pack the entries into as few messages as the transport takes; an entry too
        large for any message is not sent (the requester times out)."""
        budget = self.transport.max_message - ENVELOPE_SLACK
        head = len(pack({"v": VERSION, "id": request.id, "mode": request.mode, "patches": []}))
        batches: list[list[_Out]] = []
        size = budget
        for o in outs:
            if head + 5 + o.size > budget:
                logger.warning(
                    "robot %d cannot answer patch (%d, %d) to robot %d: %d bytes > %d",
                    self.robot,
                    o.row["src"],
                    o.row["r"],
                    peer,
                    o.size,
                    budget,
                )
                self.stats.refused += 1
                continue
            if size + o.size > budget:
                batches.append([])
                size = head + 5
            batches[-1].append(o)
            size += o.size
        for batch in batches:
            body = pack(
                {
                    "v": VERSION,
                    "id": request.id,
                    "mode": request.mode,
                    "patches": [o.row for o in batch],
                }
            )
            if self._send(peer, "answer", body):
                self.stats.poses_sent += sum(o.poses for o in batch)
                self.stats.closures_sent += sum(o.closures for o in batch)

    # --- taking answers ------------------------------------------------------------------

    def _take(self, peer: int, answer: Answer, now: float) -> None:
        """Check an answer against our request and our state, then apply it."""
        if answer.mode != self.params.mode:
            raise ExchangeError("mode", f"a {answer.mode} answer to a {self.params.mode} robot")
        pending = self._pending.get(answer.id) or self._expired.get(answer.id)
        if pending is None or pending.peer != peer:
            raise ExchangeError("unsolicited", f"no request {answer.id} to robot {peer} awaits")
        for e in answer.patches:
            if e.source == self.robot:
                raise ExchangeError("own", f"robot {peer} sends us our own poses")
            if (e.source, e.region) not in pending.patches:
                raise ExchangeError(
                    "unsolicited",
                    f"patch ({e.source}, {e.region}) not awaited from request {answer.id}",
                )
        self.stats.poses_received += sum(len(e.poses) for e in answer.patches)
        advert = self._adverts.get(peer, (0.0, {}))[1]
        changed = False
        closures: list[ClosureEdge] = []
        for e in answer.patches:
            key = (e.source, e.region)
            pending.patches.discard(key)
            if self._waiting.get(key) == answer.id:
                del self._waiting[key]
            took, carried_closures = self._apply(e, now)
            changed = took or changed
            closures.extend(carried_closures)
        # After every entry: a closure may join poses of two entries of the answer.
        if closures:
            self._take_closures(closures)
        # A peer whose answer brought nothing is not asked for these patches again until
        # its advert or our patch changes (a capped answer spent on sibling patches is
        # not a futile one).
        carried = any(e.poses for e in answer.patches)
        for e in answer.patches:
            key = (e.source, e.region)
            if changed:
                self._futile.pop((peer, *key), None)
            else:
                state = self._futile_state(peer, key, advert.get(key))
                self._futile[(peer, *key)] = (*state, now)
            # Its list names poses we lack and the answer carried none (none fitted under
            # the cap): asking again at every change of the patch would bring none either.
            if carried or not self._incomplete(key):
                self._starved.pop(key, None)
            else:
                self._starved[key] = now
        if not pending.patches:
            self._pending.pop(answer.id, None)
            self._expired.pop(answer.id, None)

    def _apply(self, e: PatchAnswer, now: float) -> tuple[bool, tuple[ClosureEdge, ...]]:
        """Apply one patch's answer (whole) but its closures: whether the store changed,
        and the closures to take (none when the entry is not applied)."""
        layer = self.store.received.get(e.source)
        patch = None if layer is None else layer.patches.get(e.region)
        current = patch.stamp if patch is not None else -math.inf
        listed = e.short if self.params.mode == "good" else e.full
        if e.stamp is None and not e.poses:
            return False, ()
        if e.stamp is not None and e.stamp < current:
            # The patch became newer meanwhile (another answer came first).
            self.stats.stale += 1
            if self.params.mode == "good":
                return False, ()
            e = PatchAnswer(e.source, e.region, None, None, None, e.poses, e.edges, e.closures)
            listed = None
        if e.stamp is None and (patch is None or not patch.full):
            return False, ()  # poses offered against a full list we do not have
        if layer is None:
            layer = self.store.received.setdefault(e.source, Layer(e.source))
        patch = layer.patch(e.region)
        changed = False
        if e.stamp is not None and listed is not None:
            for u in sorted(patch.short - listed):
                self.store.remove_received_pose(e.source, u)
                self.stats.poses_deleted += 1
                changed = True
            # A new stamp alone is no change: a source always answers with now.
            changed = changed or patch.full != set(listed)
            patch.stamp = e.stamp
            patch.full = set(listed)
        for pose in sorted(e.poses, key=lambda q: (q.time, q.uid)):
            if pose.uid in layer.poses or pose.uid not in patch.full:
                continue
            closures = [] if self.on_received is None else list(self.on_received(e.source, pose))
            held = set(layer.poses) | {pose.uid}
            edges = [
                x
                for x in e.edges
                if pose.uid in (x.a, x.b) and x.a in held and x.b in held and x not in layer.edges
            ]
            self.store.add_received_pose(e.source, pose, edges, closures, now)
            self.stats.poses_added += 1
            changed = True
        for x in e.edges:
            if x.a in layer.poses and x.b in layer.poses and x not in layer.edges:
                layer.add_edge(x)
                changed = True
        return changed, e.closures

    def _take_closures(self, closures: Sequence[ClosureEdge]) -> None:
        added, duplicate, unheld = self.store.add_peer_closures(closures)
        self.stats.closures_received += len(closures)
        self.stats.closures_added += added
        self.stats.closures_duplicate += duplicate
        self.stats.closures_unheld += unheld

    # --- state ---------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """The exchanger's state (its stamps, tables, pending requests, outgoing policy
        and counters) as plain msgpack values; :meth:`restore` takes it back. The store
        has its own (:meth:`.store.RobotStore.state`)."""
        futile = [
            [list(k), _entry_state(v[0]) if isinstance(v[0], AdvertEntry) else None, *v[1:]]
            for k, v in self._futile.items()
        ]
        return {
            "now": self._now,
            "next_advert": self._next_advert,
            "next_request": self._next_request,
            "adverts": _tables_state(self._adverts),
            "heard": [[p, t] for p, t in self._heard.items()],
            "whole": _tables_state(self._whole),
            "told": _tables_state(self._told),
            "in_reach": sorted(self._in_reach),
            "pending": [[i, _pending_state(p)] for i, p in self._pending.items()],
            "expired": [[i, _pending_state(p)] for i, p in self._expired.items()],
            "waiting": [[k[0], k[1], i] for k, i in self._waiting.items()],
            "timed_out": sorted([list(k) for k in self._timed_out]),
            "futile": futile,
            "handed": [[r, s, sorted(u)] for r, (s, u) in self._handed.items()],
            "fetched": [[k[0], k[1], t] for k, t in self._fetched.items()],
            "starved": [[k[0], k[1], t] for k, t in self._starved.items()],
            "next_id": self._next_id,
            "balance": [self._balance, self._balance_at],
            **self.outgoing.state(),
            **self.stats.state(),
        }

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`; keys a state of an older version lacks start
        afresh."""
        d = state
        self._now = float(d["now"])
        self._next_advert = float(d["next_advert"])
        self._next_request = float(d["next_request"])
        self._adverts = _tables_from(d["adverts"])
        self._heard = {int(p): float(t) for p, t in d.get("heard", [])}
        self._whole = _tables_from(d.get("whole", []))
        self._told = _tables_from(d.get("told", []))
        self._in_reach = frozenset(int(p) for p in d.get("in_reach", []))
        self._pending = {int(i): _pending_from(v) for i, v in d["pending"]}
        self._expired = {int(i): _pending_from(v) for i, v in d["expired"]}
        self._waiting = {(int(a), int(b)): int(i) for a, b, i in d["waiting"]}
        self._timed_out = {(int(a), int(b)) for a, b in d["timed_out"]}
        self._futile = {}
        for k, entry, *rest in d["futile"]:
            key = (int(k[0]), int(k[1]), int(k[2]))
            self._futile[key] = (_entry_from(entry), *rest)
        self._handed = {
            int(r): (float(s), frozenset(int(u) for u in us)) for r, s, us in d["handed"]
        }
        self._fetched = {(int(a), int(b)): float(t) for a, b, t in d.get("fetched", [])}
        self._starved = {(int(a), int(b)): float(t) for a, b, t in d.get("starved", [])}
        self._next_id = int(d["next_id"])
        if "balance" in d:
            self._balance, self._balance_at = (float(v) for v in d["balance"])
        self.outgoing.restore(d)
        self.stats.restore(d)
