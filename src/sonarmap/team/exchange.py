"""The exchange of poses between robots' stores (thesis 002, section 2.4): the
good-network and the limited-network protocols over a :class:`~.transport.Transport`.

Three kinds of message, each a msgpack map (never pickle), compressed as one zstd frame
with a preset dictionary (:data:`PRESET_DICTIONARY`), in a transport envelope (a pose's
local map is mostly unknown cells and shrinks about eight times; its landmarks'
descriptors hardly shrink):

``"advert"``
    The sender's table of patch stamps: ``(source, region) -> (stamp, held)`` for every
    patch it holds (its own local patches and its received ones), ``held`` the number of
    poses it has of that patch. Sent to every peer each ``advert_every`` seconds, so the
    others know who is newest: whole every ``full_advert_every`` seconds and to a peer
    newly in reach; in between, a *delta* (the key ``gone`` present) carries only the
    rows that changed since the last whole table sent to that peer (``base``, its send
    time ``t``) and the patches dropped since. Deltas are cumulative, so a lost one is
    made good by the next; an advert older than one already heard is ignored.
``"request"``
    A set of one-patch requests ``(source, region, requester's stamp, short list, edge
    fingerprints)``; in the limited mode also the requester's full list, and all
    patches of one request belong to one source and are adjacent regions. The edge
    fingerprints (:func:`edge_fingerprints`, 4 bytes an edge) are of the odometry edges
    the requester holds that touch its poses of the patch.
``"answer"``
    Per requested patch: the answerer's stamp, its short (good mode) or full (limited
    mode) list when it is newer, the poses sent and the odometry edges attached, poses
    and edges as their records' own msgpack encodings (:func:`.records.encode`).

Every body is decoded strictly: every field type- and range-checked, UIDs checked to be
the source's, poses to lie in their patch's region; a bad body is rejected as a whole
(logged on ``sonarmap.team.exchange``, counted in ``stats.rejected`` by reason), and
nothing of it is applied. A valid answer is applied patch by patch, each patch whole,
so a peer that vanishes mid-exchange leaves nothing half-applied: its request times out
and is sent again, to it or another holder.

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
  edge held is never sent again (version 3 sent one 8-byte digest of them all, and on
  any difference every edge of the patch: on the office, 3 robots, 120 s, 335 of 775
  edges sent were already held). An edge to a pose outside the patch that the
  requester lacks may come; the receiver keeps only edges whose two poses it holds, so
  such an edge comes again with a later answer. Two edges of one patch share a
  fingerprint with odds of about 1 in 4e9 per pair; the one the requester lacks would
  then not come until the patch's edges change.
- When to ask (``refresh``): a patch of a region the robot visits soon (the caller's
  ``wanted_regions``, the patrol's next moves, thesis l.1863-1872) is asked for as
  soon as a peer has it newer; any other patch at most once per ``refresh`` seconds
  since it was last asked for, so that the poses a source makes and compresses away
  within that time never travel. A patch we have never asked for is asked for at
  once (what the robot knows nothing of is worth most; delaying it too saved nothing
  on the office plan: 213 k against 212 k bytes per robot-minute, same F1). With no
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

import functools
import hashlib
import logging
import math
import struct
import threading
from collections import Counter, deque
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import msgpack
import numpy as np
import zstandard

from ..errors import ConfigError, InputError
from .anchors import AnchorChooser, is_anchor
from .quantise import check_quantisation, quantise_pose
from .records import (
    ClosureEdge,
    Landmarks,
    LocalMap,
    OdometryEdge,
    Pose,
    RecordError,
    UnpackError,
    decode,
    encode,
    make_uid,
    robot_of,
    size_of,
    unpack_strict,
)
from .store import Layer, Patch, RobotStore, compress_for_sending
from .transport import ROBOT_LIMIT, Message, SimTransport, Transport, ZmqTransport

__all__ = [
    "KINDS",
    "LEAN",
    "MODES",
    "PROTOCOLS",
    "Advert",
    "AdvertEntry",
    "Answer",
    "ExchangeError",
    "ExchangeParams",
    "ExchangeStats",
    "Exchanger",
    "PatchAnswer",
    "PatchRequest",
    "Request",
    "decode_advert",
    "decode_answer",
    "decode_request",
    "edge_fingerprint",
    "edge_fingerprints",
    "encode_advert",
    "encode_answer",
    "encode_request",
    "is_anchor",
]

logger = logging.getLogger("sonarmap.team.exchange")

#: Message kinds, the transport envelope's ``kind``.
KINDS = ("advert", "request", "answer")
#: The two protocols (the modes messages may carry).
MODES = ("good", "limited")
#: What :attr:`ExchangeParams.mode` may be: the two protocols, or the naive baseline that
#: :class:`~.naive.NaiveExchanger` runs (it has its own messages).
PROTOCOLS = (*MODES, "naive")
#: The bodies' version, field ``v`` (2: requests carry an edge digest per patch; 3: bodies
#: are deflated; 4: edge fingerprints instead of the digest; 5: delta adverts, adverts
#: stamped with their send time, odometry edges in float32, a preset deflate dictionary;
#: 6: zstd instead of deflate, with the same dictionary).
VERSION = 6
#: Bytes a body may expand to at most; a compressed body that would grow past it (a
#: decompression bomb) is refused before it is expanded.
MAX_INFLATED = 64 << 20
#: Bytes of an edge's fingerprint (:func:`edge_fingerprints`).
FINGERPRINT_BYTES = 4
#: Edges one patch request may name at most.
_MAX_EDGES = 1 << 20
_UID_LIMIT = 2**63
_REGION_LIMIT = 2**31
_ID_LIMIT = 2**63
#: Patches one request may name at most (whatever the sender's ``max_patches``).
_MAX_PATCHES = 4096
#: Bytes of a transport's envelope around a body, at most (map keys, ints, kind).
_ENVELOPE_SLACK = 128

PatchKey = tuple[int, int]
OnReceived = Callable[[int, Pose], Sequence[ClosureEdge]]


class ExchangeError(InputError):
    """A message body that is not valid; ``code`` is the short reason (the stats key)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


# --- parameters and counters ------------------------------------------------------------


@dataclass(frozen=True)
class ExchangeParams:
    """How a robot exchanges; the thesis gives no values, so every default is our choice.

    Attributes
    ----------
    mode : str
        ``"good"`` (a good network: whole patches) or ``"limited"`` (answers capped at
        ``cap_bytes``, full id lists kept); ``"naive"`` is the baseline of
        :class:`~.naive.NaiveExchanger` (every new pose to everyone), not this module's.
        Default ``"good"``.
    cap_bytes : int
        T, bytes of poses one limited-mode answer may carry (edges are not counted):
        65536, four poses at the store's default ``pose_limit``.
    advert_every : float
        Seconds between adverts: 5.
    full_advert_every : float
        Seconds at least between two whole adverts to a peer; the adverts between carry
        only the rows changed since the last whole one (a *delta*), and a peer the last
        round's advert did not reach gets a whole one. 0: every advert whole. Default
        30, the ``peer_timeout``: a receiver that missed a whole advert may hold rows
        stale until the next one, each lost whole advert adding that long, about as
        long as a peer that stops advertising is trusted. With the lean exchange
        (``LEAN``; 300 s) adverts of 32 rows on average were 13 % of the bytes on
        building 7 (4 robots); deltas took the exchange there from 25.2 % to 23.7 %
        of the naive baseline's bytes, and on building 8 (3 robots) from 23.2 % to
        22.2 %, with the same maps (``benchmarks.team_exchange``).
    request_every : float
        Seconds between rounds of requests: 1.
    max_patches : int
        Patches one request names at most: 8.
    request_timeout : float
        Seconds after which an unanswered request is forgotten, so its patches can be
        asked for again (a lost message is retried): 10.
    peer_timeout : float
        Seconds an advert is trusted; a peer not heard from for longer is not asked:
        30 (six adverts). At least ``advert_every``.
    max_outstanding : int
        Requests awaiting an answer at most, so that a robot far behind does not flood
        the network: 8.
    refresh : float
        Seconds at least between two requests for a patch outside the regions the robot
        visits next (``wanted_regions`` of :meth:`Exchanger.step`), and for a starved
        patch: 30. Measured on the office plan only (2 robots, 300 s, seed 2, full
        network, good protocol): bytes per robot-minute 221 k at 10 s, 212 k at 30 s,
        208 k at 60 s, team F1 0.317, 0.320, 0.314; the poses sent barely change (256,
        254, 254: a source deletes poses minutes after making them, so a short
        mission's bytes are its final poses), and 30 s keeps a peer's map at most
        half a minute behind.
    backoff : float
        Seconds after which a peer whose answer for a patch changed nothing is asked
        for it again though neither its advert nor our patch changed: 120.
    budget : float
        Bytes per second of answers this robot lets its requests bring in, so that the
        exchange keeps to a known share of the network; 0 (default): no budget. The
        robot keeps a balance that grows at ``budget`` up to ``cap_bytes`` and pays for
        each answer it receives (the body as it came), and it sends a request only
        while the balance is positive and no request awaits an answer. Its answers thus
        average at most ``budget`` bytes per second plus one answer. The regions it
        visits next are asked for first, and a limited-mode answer carries the poses of
        best E (the thesis's deletion-only compression), so a small budget buys the
        poses that matter most first.
    anchor_every : int
        k: a pose travels with its landmarks only if it is an *anchor*: every k-th pose
        its robot made (by the UID's counter) and every merged pose; the others travel
        with their estimate, local map and odometry edges but no landmarks, so a
        receiver maps with them and finds its closures to the other robot through the
        anchors, the odometry edges carrying them to the poses between. 1 (default):
        every pose whole, as the thesis stores it. A pose's landmarks are about four
        fifths of its deflated bytes (office, 300 s: 2.36 of 2.96 MB of poses sent).
    loop_anchors : bool
        Also make an anchor of every own pose that, when it was made, closed a loop with
        an older anchor or with another robot's pose (:class:`.anchors.AnchorChooser`),
        so that receivers can close it too. False (default): the anchors are every
        ``anchor_every``-th pose and the merged ones (:func:`.anchors.is_anchor`).
    anchor_share : float
        A byte target for anchors: besides the anchors above, an own pose travels whole
        when, the first time it is prepared to travel, this robot has sent less than
        ``anchor_share`` times what the naive baseline would have sent by then on the
        same mission (the ``naive_bytes`` an :class:`Exchanger` is given, in the team
        run :class:`.naive.NaiveMeter`), as it was ``hold`` seconds before, since a
        held pose is offered that much later. Each pose is decided once, so every
        holder gets the same copy. After :meth:`Exchanger.finish` the last hold's
        poses, offered in one batch, are made whole only as far as their landmarks'
        bytes to every live peer fit under the target. The quiet phase and the bare
        poses come on top, so a run ends above the target. A fixed ``anchor_every``
        spends a different share on each floor plan (the office 14 %, building 8 20 %
        at k = 8), so a sparse ``k`` with a share target lets the plans with bytes to
        spare buy landmarks. 0 (default): off. Needs ``anchor_every`` > 1.
    hold : float
        Seconds a robot keeps a new own pose to itself before it offers the pose to
        its peers (COVINS sends keyframes once final): a pose its store deletes or
        merges within that time never travels. Until :meth:`Exchanger.finish` (the
        mission is over: everything is offered at once) the robot advertises and
        answers from a *published* copy of its local layer that holds the poses at
        least ``hold`` seconds old and the odometry edges between them. 0 (default):
        every pose as soon as it is made. On the office (3 robots, 300 s) 28 % of the
        pose bytes the good protocol sent were of poses deleted before the end.
    descriptor_bits : int
        Bits each landmark descriptor byte keeps as it travels (1..8); below 8 the
        landmarks' points and reliabilities also travel in float16 and their stamps in
        float32 (:func:`.quantise.quantise_pose`). 8 (default): exact. What a robot
        stores of its own poses stays exact; what it receives is what travelled.
    ternary_maps : bool
        Local maps travel as free, occupied and unknown, each class at its mean
        log-odds in that map (:func:`.quantise.ternary_logodds`). False (default):
        exact.
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

    def __post_init__(self) -> None:
        if self.mode not in PROTOCOLS:
            raise ConfigError(
                f"exchange: mode must be one of {', '.join(PROTOCOLS)}, got {self.mode!r}",
                field="mode",
            )
        for f in fields(self):
            if f.name in ("mode", "ternary_maps", "loop_anchors"):
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
        if not isinstance(self.loop_anchors, bool):
            raise ConfigError(
                f"exchange: loop_anchors must be true or false, got {self.loop_anchors!r}",
                field="loop_anchors",
            )
        if self.peer_timeout < self.advert_every:
            raise ConfigError(
                f"exchange: peer_timeout {self.peer_timeout} s is below advert_every "
                f"{self.advert_every} s (every peer would be forgotten between adverts)",
                field="peer_timeout",
            )


#: The lean exchange's settings (``team run --lean``, with the store's ``fold`` and
#: :data:`LEAN_MERGE_ON_CLOSURE`): landmarks on every 12th pose and on any pose prepared to
#: travel while the robot has sent less than 15 % of the naive baseline's bytes, poses
#: offered once 30 s old, 3-bit descriptors, ternary maps, and adverts every 10 s (whole
#: every 60 s). Chosen on the training plans (office, buildings 7 and 8; 300 s, seeds
#: 0-2; ``benchmarks.team_goal``): it met the issue's goal (within 0.05 F1 of the central
#: bound at <= 20 % of naive's bytes) in 5 of the 9 runs against 4 for anchors on every
#: 8th pose with merging; then adverts every 10 s instead of 5 s, which cut adverts and
#: requests from 16-17 % of the bytes sent to 11-12 % on buildings 7 and 8, with the
#: byte target counting the end's batch pose by pose, met it in 8. The buildings 11-14
#: were held out (README). A meeting shorter than an advert period may pass without an
#: exchange.
LEAN = ExchangeParams(
    advert_every=10.0,
    full_advert_every=60.0,
    anchor_every=12,
    anchor_share=0.15,
    hold=30.0,
    descriptor_bits=3,
    ternary_maps=True,
)
#: The store's ``merge_on_closure`` with :data:`LEAN`: own poses merge at closures of 8 or
#: more inliers, so that receivers, which hold most poses without landmarks, get the
#: robot's loops as edges. With it, ``LEAN``'s former setting (anchors on every 8th
#: pose) came from a mean gap to the central bound of -0.061, -0.045 and -0.043 to
#: -0.055, -0.037 and -0.026 on the training plans.
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
    rejected: Counter[str] = field(default_factory=Counter)
    bytes_by_kind: Counter[str] = field(default_factory=Counter)

    def count_sent(self, kind: str, size: int) -> None:
        """Count one message of ``kind`` and ``size`` body bytes the transport took."""
        self.messages_sent += 1
        self.bytes_sent += size
        self.bytes_by_kind[kind] += size


@functools.lru_cache(maxsize=1 << 16)
def _fingerprint(a: int, b: int, transform: tuple[float, float, float]) -> bytes:
    h = hashlib.blake2b(struct.pack("<qq3d", a, b, *transform), digest_size=FINGERPRINT_BYTES)
    return h.digest()


def edge_fingerprint(edge: OdometryEdge) -> bytes:
    """An odometry edge's 4-byte fingerprint (blake2b of its ends and transform; the
    transform is included so that an edge re-made between the same two poses, a source
    chaining across a deleted pose, differs)."""
    return _fingerprint(edge.a, edge.b, edge.transform)


def edge_fingerprints(edges: Iterable[OdometryEdge]) -> bytes:
    """The fingerprints of a set of odometry edges, sorted and concatenated: any order
    of the same edges gives the same bytes.

    Examples
    --------
    >>> e = OdometryEdge(1, 2, (1.0, 0.0, 0.0), (0.0,) * 9, 5.0)
    >>> len(edge_fingerprints([e, e])), edge_fingerprints([]) == b""
    (4, True)
    """
    return b"".join(sorted({edge_fingerprint(e) for e in edges}))


def _split_fingerprints(blob: bytes) -> set[bytes]:
    n = FINGERPRINT_BYTES
    return {blob[i : i + n] for i in range(0, len(blob), n)}


# --- messages -----------------------------------------------------------------------------


@dataclass(frozen=True)
class AdvertEntry:
    """One patch its sender holds: its stamp and how many poses of it the sender has."""

    source: int
    region: int
    stamp: float
    held: int


@dataclass(frozen=True)
class Advert:
    """The sender's table of patch stamps, by (source, region): whole, or (``delta``)
    the rows that changed since the whole table the sender sent to this peer at time
    ``base`` and the patches it has dropped since (``gone``). ``t``: when the sender
    sent it (None: unordered, always taken; a delta has both times)."""

    entries: tuple[AdvertEntry, ...]
    delta: bool = False
    gone: tuple[PatchKey, ...] = ()
    t: float | None = None
    base: float | None = None


@dataclass(frozen=True)
class PatchRequest:
    """One patch asked for: the requester's stamp (None if it has none) and short list;
    in the limited mode also its full list (None in the good mode); ``edges``, the
    :func:`edge_fingerprints` of the odometry edges the requester holds touching its
    poses of the patch (default: none)."""

    source: int
    region: int
    stamp: float | None
    short: frozenset[int]
    full: frozenset[int] | None = None
    edges: bytes = b""


@dataclass(frozen=True)
class Request:
    """A request: an id the answer echoes, the protocol, the patches."""

    id: int
    mode: str
    patches: tuple[PatchRequest, ...]


@dataclass(frozen=True)
class PatchAnswer:
    """The answer for one patch.

    Good mode: ``stamp`` and ``short`` (the answerer's short list) when the answerer is
    the source or newer, else all None and no poses. Limited mode: ``stamp`` and
    ``full`` when the answerer is newer, else None; ``short`` is always None. ``poses``
    and ``edges`` are what was sent.
    """

    source: int
    region: int
    stamp: float | None
    short: frozenset[int] | None
    full: frozenset[int] | None
    poses: tuple[Pose, ...] = ()
    edges: tuple[OdometryEdge, ...] = ()


@dataclass(frozen=True)
class Answer:
    """An answer (possibly one of several messages) to request ``id``."""

    id: int
    mode: str
    patches: tuple[PatchAnswer, ...]


def _preset_dictionary() -> bytes:
    """The deflate dictionary every body is compressed with: one message of each kind
    (the naive baseline's too) around a pose with two landmarks, an empty 6 m map and an
    odometry edge, all placeholder values. It holds the field names and the byte runs
    every body repeats, which a small body could not otherwise amortise; it is part of
    the protocol (:data:`VERSION`), so it must never change within a version."""
    n = 2
    landmarks = Landmarks(
        np.zeros((n, 3), np.float32),
        np.zeros((n, 128), np.uint8),
        np.full(n, 0.5, np.float32),
        np.zeros(n),
        np.arange(n),
    )
    uid, nxt = make_uid(1, 1), make_uid(1, 2)
    pose = Pose(uid, 1.0, 1, np.zeros(3), landmarks, LocalMap(np.zeros((60, 60), np.int8), 0.1))
    cov = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-5)
    edge = encode(OdometryEdge(uid, nxt, (0.5, 0.0, 0.1), cov, 1.0))
    patch = {"src": 1, "r": 2, "s": 1.5, "short": [uid], "full": None}
    bodies = [
        {"v": VERSION, "pose": encode(pose), "edges": [edge]},
        {"v": VERSION, "t": 1.0, "base": 0.5, "patches": [[1, 2, 3.5, 4]], "gone": [[1, 3]]},
        {"v": VERSION, "id": 1, "mode": "good", "patches": [{**patch, "edges": bytes(4)}]},
        {
            "v": VERSION,
            "id": 1,
            "mode": "good",
            "patches": [{**patch, "poses": [encode(pose)], "edges": [edge]}],
        },
    ]
    return b"".join(bytes(msgpack.packb(b, use_bin_type=True)) for b in bodies)


#: See :func:`_preset_dictionary`. On messages of a lean exchange (building 8, 3 robots,
#: 120 s) it saved 11 % of the deflated bytes: 28 % of the requests', 10 % of the
#: answers', 8 % of the adverts'.
PRESET_DICTIONARY = _preset_dictionary()


#: zstd's level for every body. Measured on the bodies of 120 s runs on the office (3
#: robots, full network, seed 1) against deflate at level 6 with the same dictionary:
#: level 19 sent 12.5 % fewer bytes for the lean exchange (answers 14 %; adverts grew 7 %)
#: and 4.2 % fewer for the naive baseline; level 12, 7.4 % and 3.7 %. 19 costs about
#: 1.5 ms per body.
ZSTD_LEVEL = 19
_ZSTD_DICT = zstandard.ZstdCompressionDict(
    PRESET_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT
)
# A zstd context must not be shared between threads, and exchangers may run in several
# (a Dask worker's, a caller's).
_codecs = threading.local()


def _compressor() -> zstandard.ZstdCompressor:
    c: zstandard.ZstdCompressor | None = getattr(_codecs, "compressor", None)
    if c is None:
        c = _codecs.compressor = zstandard.ZstdCompressor(
            level=ZSTD_LEVEL, dict_data=_ZSTD_DICT, write_checksum=False
        )
    return c


def _decompressor() -> zstandard.ZstdDecompressor:
    d: zstandard.ZstdDecompressor | None = getattr(_codecs, "decompressor", None)
    if d is None:
        d = _codecs.decompressor = zstandard.ZstdDecompressor(dict_data=_ZSTD_DICT)
    return d


def _pack(d: Mapping[str, Any]) -> bytes:
    # The frame states its content size, which _inflate checks before expanding it.
    return _compressor().compress(bytes(msgpack.packb(d, use_bin_type=True)))


def _bare(pose: Pose) -> Pose:
    """The pose without its landmarks, as a non-anchor travels."""
    return pose.with_landmarks(pose.landmarks.take(np.zeros(0, dtype=np.intp)))


def _ids(s: Collection[int] | None) -> list[int] | None:
    return None if s is None else sorted(int(u) for u in s)


def _stamp_out(s: float | None) -> float | None:
    return None if s is None else float(s)


def encode_advert(advert: Advert) -> bytes:
    """An advert's body."""
    rows = [[e.source, e.region, float(e.stamp), e.held] for e in advert.entries]
    d: dict[str, Any] = {"v": VERSION, "patches": rows}
    if advert.t is not None:
        d["t"] = float(advert.t)
    if advert.delta:
        if advert.t is None or advert.base is None:
            raise ValueError("a delta advert has its send time and its base's")
        d["base"] = float(advert.base)
        d["gone"] = [[s, r] for s, r in advert.gone]
    elif advert.gone or advert.base is not None:
        raise ValueError("a whole advert has no gone patches and no base")
    return _pack(d)


def _request_dict(p: PatchRequest) -> dict[str, Any]:
    return {
        "src": p.source,
        "r": p.region,
        "s": _stamp_out(p.stamp),
        "short": _ids(p.short),
        "full": _ids(p.full),
        "e": bytes(p.edges),
    }


def encode_request(request: Request) -> bytes:
    """A request's body."""
    return _pack(
        {
            "v": VERSION,
            "id": request.id,
            "mode": request.mode,
            "patches": [_request_dict(p) for p in request.patches],
        }
    )


def _answer_dict(
    p: PatchAnswer, poses: Sequence[bytes] | None = None, edges: Sequence[bytes] | None = None
) -> dict[str, Any]:
    return {
        "src": p.source,
        "r": p.region,
        "s": _stamp_out(p.stamp),
        "short": _ids(p.short),
        "full": _ids(p.full),
        "poses": list(poses) if poses is not None else [encode(q) for q in p.poses],
        "edges": list(edges) if edges is not None else [encode(e) for e in p.edges],
    }


def encode_answer(answer: Answer) -> bytes:
    """An answer's body."""
    return _pack(
        {
            "v": VERSION,
            "id": answer.id,
            "mode": answer.mode,
            "patches": [_answer_dict(p) for p in answer.patches],
        }
    )


# --- strict decoding ----------------------------------------------------------------------


#: What a body that is not one whole msgpack object is told, by reason.
_BODY_DETAIL = {"trailing": "bytes after the body", "truncated": "the body ends early"}


def _inflate(body: bytes) -> bytes:
    """The body expanded: one zstd frame that states its size, nothing after it."""
    try:
        size = zstandard.frame_content_size(body)
    except zstandard.ZstdError as e:
        raise ExchangeError("zstd", f"body: not a zstd frame ({e})") from None
    if size < 0:
        raise ExchangeError("zstd", "body: the zstd frame does not state its size")
    if size > MAX_INFLATED:
        raise ExchangeError("oversized", f"body: expands to {size} bytes, past {MAX_INFLATED}")
    z = _decompressor().decompressobj()
    try:
        # zstd stops, rather than writes, past the size the frame states.
        out = z.decompress(body)
    except zstandard.ZstdError as e:
        raise ExchangeError("zstd", f"body: a bad zstd frame ({e})") from None
    if not z.eof:
        raise ExchangeError("truncated", _BODY_DETAIL["truncated"])
    if z.unused_data:
        raise ExchangeError("trailing", _BODY_DETAIL["trailing"])
    return out


def _unpack(body: bytes) -> dict[str, Any]:
    if not isinstance(body, bytes):
        raise ExchangeError("type", f"body: bytes expected, got {type(body).__name__}")
    body = _inflate(body)
    n = len(body)
    try:
        # No length field may claim more than the body holds.
        d = unpack_strict(body, max_bin=n, max_str=n, max_array=n, max_map=n)
    except UnpackError as e:
        raise ExchangeError(e.reason, _BODY_DETAIL.get(e.reason, str(e))) from None
    if not isinstance(d, dict):
        raise ExchangeError("not_map", f"body: a map expected, got {type(d).__name__}")
    return d


def _keys(d: Mapping[str, Any], keys: Collection[str], where: str) -> None:
    if set(d) != set(keys):
        missing, extra = sorted(set(keys) - set(d)), sorted(set(d) - set(keys))
        raise ExchangeError("keys", f"{where}: missing {missing}, unexpected {extra}")


def _int(v: Any, where: str, limit: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ExchangeError("type", f"{where}: {type(v).__name__} where int expected")
    if not 0 <= v < limit:
        raise ExchangeError("range", f"{where}: {v} not in [0, {limit})")
    return v


def _stamp(v: Any, where: str, *, optional: bool) -> float | None:
    if v is None and optional:
        return None
    if not isinstance(v, float):
        raise ExchangeError("type", f"{where}: {type(v).__name__} where float expected")
    if not math.isfinite(v):
        raise ExchangeError("range", f"{where}: {v} is not finite")
    return v


def _list(v: Any, where: str) -> list[Any]:
    if not isinstance(v, list):
        raise ExchangeError("type", f"{where}: {type(v).__name__} where list expected")
    return v


def _uid_set(v: Any, source: int, where: str, *, optional: bool) -> frozenset[int] | None:
    if v is None and optional:
        return None
    uids = [_int(u, where, _UID_LIMIT) for u in _list(v, where)]
    out = frozenset(uids)
    if len(out) != len(uids):
        raise ExchangeError("duplicate", f"{where}: a UID is listed twice")
    bad = sorted(u for u in out if robot_of(u) != source)
    if bad:
        raise ExchangeError("inconsistent", f"{where}: pose {bad[0]} is not robot {source}'s")
    return out


def _version(d: Mapping[str, Any]) -> None:
    v = d["v"]
    if isinstance(v, bool) or not isinstance(v, int) or v != VERSION:
        raise ExchangeError("version", f"version {v!r}, expected {VERSION}")


def _mode(v: Any) -> str:
    if not isinstance(v, str):
        raise ExchangeError("type", f"mode: {type(v).__name__} where str expected")
    if v not in MODES:
        raise ExchangeError("range", f"mode {v!r} is not one of {', '.join(MODES)}")
    return v


def _region(v: Any, where: str, regions: Collection[int] | None) -> int:
    r = _int(v, where, _REGION_LIMIT)
    if regions is not None and r not in regions:
        raise ExchangeError("range", f"{where}: region {r} is not on the prior map")
    return r


def _unique_keys(keys: Sequence[PatchKey], where: str) -> None:
    if len(set(keys)) != len(keys):
        raise ExchangeError("duplicate", f"{where}: a patch is named twice")


def decode_advert(body: bytes, *, regions: Collection[int] | None = None) -> Advert:
    """The advert in ``body``; :class:`ExchangeError` if it is not a valid one.

    ``regions``, if given, are the prior map's regions: any other is out of range."""
    d = _unpack(body)
    delta = "gone" in d
    if delta:
        _keys(d, ("v", "t", "base", "patches", "gone"), "advert")
    else:
        _keys(d, ("v", "t", "patches") if "t" in d else ("v", "patches"), "advert")
    _version(d)
    t = _stamp(d.get("t"), "advert.t", optional=not delta)
    base = _stamp(d.get("base"), "advert.base", optional=not delta)
    if base is not None and t is not None and base > t:
        raise ExchangeError("inconsistent", f"advert: base {base} after its send time {t}")
    gone: list[PatchKey] = []
    for i, row in enumerate(_list(d["gone"], "advert.gone") if delta else []):
        where = f"advert.gone[{i}]"
        if not isinstance(row, list) or len(row) != 2:
            raise ExchangeError("type", f"{where}: [source, region] expected")
        gone.append(
            (
                _int(row[0], f"{where}.source", ROBOT_LIMIT),
                _region(row[1], f"{where}.region", regions),
            )
        )
    rows = _list(d["patches"], "advert.patches")
    entries: list[AdvertEntry] = []
    for i, row in enumerate(rows):
        where = f"advert.patches[{i}]"
        if not isinstance(row, list) or len(row) != 4:
            raise ExchangeError("type", f"{where}: [source, region, stamp, held] expected")
        src = _int(row[0], f"{where}.source", ROBOT_LIMIT)
        region = _region(row[1], f"{where}.region", regions)
        stamp = _stamp(row[2], f"{where}.stamp", optional=False)
        assert stamp is not None
        held = _int(row[3], f"{where}.held", _UID_LIMIT)
        entries.append(AdvertEntry(src, region, stamp, held))
    _unique_keys([(e.source, e.region) for e in entries] + gone, "advert")
    return Advert(tuple(entries), delta, tuple(gone), t, base)


def _delta_body(
    told: tuple[float, Mapping[PatchKey, AdvertEntry]],
    table: Mapping[PatchKey, AdvertEntry],
    now: float,
) -> bytes | None:
    """The delta advert sent at ``now`` from the whole table ``told`` (its send time,
    its rows) to ``table``; None when it would list at least half as many rows as the
    whole table (the whole one then costs little more and refreshes the peer's base)."""
    base, rows = told
    changed = tuple(e for k, e in table.items() if rows.get(k) != e)
    gone = tuple(k for k in rows if k not in table)
    if 2 * (len(changed) + len(gone)) >= max(1, len(table)):
        return None
    return encode_advert(Advert(changed, delta=True, gone=gone, t=now, base=base))


def _connected(regions: Sequence[int], adjacency: Mapping[int, Collection[int]]) -> bool:
    todo, seen = [regions[0]], {regions[0]}
    wanted = set(regions)
    while todo:
        r = todo.pop()
        for n in adjacency.get(r, ()):
            if n in wanted and n not in seen:
                seen.add(n)
                todo.append(n)
    return seen == wanted


def decode_request(
    body: bytes,
    *,
    regions: Collection[int] | None = None,
    adjacency: Mapping[int, Collection[int]] | None = None,
) -> Request:
    """The request in ``body``; :class:`ExchangeError` if it is not a valid one.

    Checked besides types and ranges: UIDs are the source's, no patch twice, edge
    fingerprints come in whole 4-byte pieces, the good mode sends no full list and the
    limited mode one including the short list; a limited request names one source and (with
    ``adjacency``) adjacent regions."""
    d = _unpack(body)
    _keys(d, ("v", "id", "mode", "patches"), "request")
    _version(d)
    rid = _int(d["id"], "request.id", _ID_LIMIT)
    mode = _mode(d["mode"])
    rows = _list(d["patches"], "request.patches")
    if not 0 < len(rows) <= _MAX_PATCHES:
        raise ExchangeError("range", f"request: {len(rows)} patches, 1..{_MAX_PATCHES} allowed")
    patches: list[PatchRequest] = []
    for i, row in enumerate(rows):
        where = f"request.patches[{i}]"
        if not isinstance(row, dict):
            raise ExchangeError("type", f"{where}: a map expected")
        _keys(row, ("src", "r", "s", "short", "full", "e"), where)
        src = _int(row["src"], f"{where}.src", ROBOT_LIMIT)
        region = _region(row["r"], f"{where}.r", regions)
        stamp = _stamp(row["s"], f"{where}.s", optional=True)
        short = _uid_set(row["short"], src, f"{where}.short", optional=False)
        assert short is not None
        full = _uid_set(row["full"], src, f"{where}.full", optional=mode == "good")
        if mode == "good" and full is not None:
            raise ExchangeError("inconsistent", f"{where}.full: no full list in the good mode")
        if full is not None and not short <= full:
            raise ExchangeError("inconsistent", f"{where}: the short list is not in the full one")
        prints = row["e"]
        if not isinstance(prints, bytes):
            raise ExchangeError("type", f"{where}.e: {type(prints).__name__} where bytes expected")
        if len(prints) % FINGERPRINT_BYTES or len(prints) > _MAX_EDGES * FINGERPRINT_BYTES:
            raise ExchangeError(
                "range",
                f"{where}.e: {len(prints)} bytes, a multiple of {FINGERPRINT_BYTES} expected "
                f"(at most {_MAX_EDGES} edges)",
            )
        patches.append(PatchRequest(src, region, stamp, short, full, prints))
    _unique_keys([(p.source, p.region) for p in patches], "request")
    if mode == "limited":
        if len({p.source for p in patches}) != 1:
            raise ExchangeError("inconsistent", "request: a limited request names one source")
        if adjacency is not None and not _connected([p.region for p in patches], adjacency):
            raise ExchangeError("adjacency", "request: the regions are not adjacent")
    return Request(rid, mode, tuple(patches))


def _record(data: Any, kind: type[Pose] | type[OdometryEdge], where: str) -> Any:
    if not isinstance(data, bytes):
        raise ExchangeError("type", f"{where}: {type(data).__name__} where bytes expected")
    try:
        rec = decode(data)
    except RecordError as e:
        raise ExchangeError("record", f"{where}: {e}") from None
    if not isinstance(rec, kind):
        raise ExchangeError("record", f"{where}: a {type(rec).__name__} where {kind.__name__}")
    return rec


def _answer_entry(row: Any, mode: str, where: str, regions: Collection[int] | None) -> PatchAnswer:
    if not isinstance(row, dict):
        raise ExchangeError("type", f"{where}: a map expected")
    _keys(row, ("src", "r", "s", "short", "full", "poses", "edges"), where)
    src = _int(row["src"], f"{where}.src", ROBOT_LIMIT)
    region = _region(row["r"], f"{where}.r", regions)
    stamp = _stamp(row["s"], f"{where}.s", optional=True)
    short = _uid_set(row["short"], src, f"{where}.short", optional=True)
    full = _uid_set(row["full"], src, f"{where}.full", optional=True)
    poses: list[Pose] = [
        _record(p, Pose, f"{where}.poses[{k}]")
        for k, p in enumerate(_list(row["poses"], f"{where}.poses"))
    ]
    edges: list[OdometryEdge] = [
        _record(e, OdometryEdge, f"{where}.edges[{k}]")
        for k, e in enumerate(_list(row["edges"], f"{where}.edges"))
    ]
    for p in poses:
        if robot_of(p.uid) != src or p.region != region:
            raise ExchangeError(
                "inconsistent", f"{where}: pose {p.uid} is not of robot {src} in region {region}"
            )
    for e in edges:
        if robot_of(e.a) != src or robot_of(e.b) != src:
            raise ExchangeError("inconsistent", f"{where}: edge {e.a} -> {e.b} is not {src}'s")
    # What each mode may carry.
    if mode == "good":
        if full is not None or (stamp is None) != (short is None):
            raise ExchangeError("inconsistent", f"{where}: a good answer has stamp and short list")
        listed = short
    else:
        if short is not None or (stamp is None) != (full is None):
            raise ExchangeError(
                "inconsistent", f"{where}: a limited answer has stamp and full list"
            )
        listed = full
    if stamp is None and mode == "good" and (poses or edges):
        raise ExchangeError("inconsistent", f"{where}: poses without a stamp")
    if listed is not None:
        extra = sorted(p.uid for p in poses if p.uid not in listed)
        if extra:
            raise ExchangeError("inconsistent", f"{where}: pose {extra[0]} is not in its list")
    return PatchAnswer(src, region, stamp, short, full, tuple(poses), tuple(edges))


def decode_answer(body: bytes, *, regions: Collection[int] | None = None) -> Answer:
    """The answer in ``body``; :class:`ExchangeError` if it is not a valid one.

    Checked besides types and ranges: every pose and edge decodes as its record, is the
    patch's source's and (a pose) lies in the patch's region; no pose twice; each mode
    carries what it may (see :class:`PatchAnswer`) and sent poses are in the list sent."""
    d = _unpack(body)
    _keys(d, ("v", "id", "mode", "patches"), "answer")
    _version(d)
    rid = _int(d["id"], "answer.id", _ID_LIMIT)
    mode = _mode(d["mode"])
    rows = _list(d["patches"], "answer.patches")
    if len(rows) > _MAX_PATCHES:
        raise ExchangeError("range", f"answer: {len(rows)} patches, at most {_MAX_PATCHES}")
    patches = tuple(
        _answer_entry(row, mode, f"answer.patches[{i}]", regions) for i, row in enumerate(rows)
    )
    _unique_keys([(p.source, p.region) for p in patches], "answer")
    uids = [q.uid for p in patches for q in p.poses]
    if len(set(uids)) != len(uids):
        raise ExchangeError("duplicate", "answer: a pose is sent twice")
    return Answer(rid, mode, patches)


# --- the exchanger ------------------------------------------------------------------------


@dataclass
class _Pending:
    """A request sent and not wholly answered: the patches still awaited."""

    peer: int
    patches: set[PatchKey]
    sent: float
    deadline: float


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


def _check_pair(store: RobotStore, transport: Transport) -> None:
    """An exchanger's store and transport must be one robot's."""
    if transport.robot != store.robot:
        raise ConfigError(
            f"exchange: the store is robot {store.robot}'s, the transport robot {transport.robot}'s"
        )


def _check_time(now: object, last: float) -> None:
    """An exchanger's clock: a finite time, never before the ``last`` step's."""
    if isinstance(now, bool) or not isinstance(now, (int, float)) or not math.isfinite(now):
        raise InputError(f"exchange: now must be a finite time, got {now!r}", field="now")
    if now < last:
        raise InputError(f"exchange: time goes back from {last} to {now}", field="now")


def _default_peers(transport: Transport) -> Callable[[], Iterable[int]]:
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
        _check_pair(store, transport)
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
        self._peers = peers if peers is not None else _default_peers(transport)
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
        # With a hold, the copy of the local layer this robot offers (ExchangeParams.hold),
        # kept by _publish; finish() ends the hold.
        self._published = Layer(self.robot, own=True) if self.params.hold > 0 else None
        self._finished = False
        # Anchors where loops close (ExchangeParams.loop_anchors), decided as own poses
        # appear.
        self._chooser = (
            AnchorChooser(self.robot, every=self.params.anchor_every)
            if self.params.loop_anchors and self.params.anchor_every > 1
            else None
        )
        # Own poses the byte target (ExchangeParams.anchor_share) has decided: whole or not.
        if self.params.anchor_share > 0 and naive_bytes is None:
            raise ConfigError(
                "exchange: anchor_share needs the naive baseline's bytes (naive_bytes)"
            )
        self._naive_bytes = naive_bytes
        self._by_share: dict[int, bool] = {}
        # (time, naive bytes) at each step over the last ``hold`` seconds: a held pose is
        # offered ``hold`` seconds after the baseline would have sent it, so the target
        # follows the baseline that far behind (else every pose of the first minute,
        # when nothing has been offered yet, would go whole).
        self._naive_log: deque[tuple[float, float]] = deque()
        # Bytes the byte target has committed since finish(): the end's poses are decided
        # in a batch before any of them is sent, so each whole one counts at once.
        self._end_spent = 0.0

    @property
    def robot(self) -> int:
        return self.store.robot

    @property
    def _own(self) -> Layer:
        """The local layer as this robot offers it: all of it, or what the hold let out."""
        return self.store.local if self._published is None else self._published

    def finish(self) -> None:
        """The mission is over: from the next step every own pose is offered, however
        young (ends ``hold``). A robot that stops making poses has nothing left to wait
        for, and the team's maps are wanted whole."""
        self._finished = True

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
        _check_time(now, self._now)
        wanted = None if wanted_regions is None else [int(r) for r in wanted_regions]
        self._now = float(now)
        if self._chooser is not None:
            self._chooser.update(self.store)
        if self._naive_bytes is not None and self.params.anchor_share > 0:
            log = self._naive_log
            log.append((self._now, self._naive_bytes()))
            while len(log) > 1 and log[1][0] <= self._now - self.params.hold:
                log.popleft()
        self._publish(self._now)
        for msg in self.transport.poll(0.0):
            self._handle(msg, self._now)
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

    # --- the published layer -------------------------------------------------------------

    def _publish(self, now: float) -> None:
        """Bring the published layer up to the local one: poses the store no longer holds
        leave it, poses ``hold`` seconds old (all once finished) enter it, and so do the
        odometry edges between its poses; each change stamps its patch ``now``, as the
        local layer's own changes do."""
        pub = self._published
        if pub is None:
            return
        local = self.store.local
        for u in [u for u in pub.poses if u not in local.poses]:
            pub.remove_pose(u, now)
        for u, pose in local.poses.items():
            if u in pub.poses:
                # The same pose, its landmarks' stamps and reliabilities moved on: not a
                # change of the patch (exchanges never carry them again).
                pub.poses[u] = pose
            elif self._finished or now - pose.time >= self.params.hold:
                pub.put_pose(pose, now)
        edges = set(local.edges)
        if any(e not in edges for e in pub.edges):
            for e in pub.edges:
                if e not in edges:
                    for u in (e.a, e.b):
                        pub.patch(pub.poses[u].region).stamp = now
            pub.edges = [e for e in pub.edges if e in edges]
        have = set(pub.edges)
        for e in local.edges:
            if e.a in pub.poses and e.b in pub.poses and e not in have:
                pub.edges.append(e)
                have.add(e)
                for u in (e.a, e.b):
                    pub.patch(pub.poses[u].region).stamp = now

    def _wire(self, pose: Pose) -> Pose:
        """The pose as it travels: an own pose with its landmarks only if it is an
        anchor (``anchor_every``, ``loop_anchors``), quantised as ``descriptor_bits``
        and ``ternary_maps`` say. A received pose goes on as its source sent it."""
        if (
            self.params.anchor_every > 1
            and len(pose.landmarks)
            and robot_of(pose.uid) == self.robot
            and not self._travels_whole(pose)
        ):
            pose = _bare(pose)
        return self._quantised(pose)

    def _quantised(self, pose: Pose) -> Pose:
        return quantise_pose(pose, self.params.descriptor_bits, self.params.ternary_maps)

    def _travels_whole(self, pose: Pose) -> bool:
        """Whether an own pose is an anchor."""
        chooser = self._chooser
        if chooser is None:
            whole = is_anchor(
                pose,
                self.params.anchor_every,
                merged_whole=not self.store.params.merge_on_closure,
            )
        else:
            if chooser.pending([pose.uid]):
                chooser.update(self.store)
            whole = chooser.travels_whole(pose)
        if whole or self.params.anchor_share <= 0:
            return whole
        decided = self._by_share.get(pose.uid)
        if decided is None:
            target = self.params.anchor_share * self._naive_behind()
            if self._finished:
                decided = self._end_whole(pose, target)
            else:
                decided = self.stats.bytes_sent < target
            self._by_share[pose.uid] = decided
        return decided

    def _end_whole(self, pose: Pose, target: float) -> bool:
        """The byte target after :meth:`finish`: the last hold's poses are offered in one
        batch, all decided against one figure of bytes sent, so under the target every
        one would go whole (the office: 3-5 % of naive's bytes). Each pose made whole
        here counts at once, its landmarks' bytes times the live peers, until sent and
        after (so the end spends at most the target)."""
        extra = len(_pack({"p": encode(self._quantised(pose))})) - len(
            _pack({"p": encode(self._quantised(_bare(pose)))})
        )
        cost = extra * max(1, len(self._live(self._now)))
        if self.stats.bytes_sent + self._end_spent + cost > target:
            return False
        self._end_spent += cost
        return True

    def _naive_behind(self) -> float:
        """The naive baseline's bytes ``hold`` seconds ago (all of them once the hold
        has ended), for the byte target."""
        assert self._naive_bytes is not None
        if self._finished or self.params.hold <= 0:
            return self._naive_bytes()
        log = self._naive_log
        return log[0][1] if log and log[0][0] <= self._now - self.params.hold else 0.0

    # --- stamps of the local layer --------------------------------------------------------

    def _own_stamp(self, region: int) -> float:
        """The stamp the source advertises for a local patch: the time it last changed,
        or just above the last stamp it handed out if it changed at that very time."""
        patch = self._own.patches[region]
        stamp = patch.stamp
        handed = self._handed.get(region)
        if handed is not None and stamp <= handed[0] and handed[1] != frozenset(patch.short):
            stamp = math.nextafter(handed[0], math.inf)
        return stamp

    def _source_stamp(self, region: int, now: float) -> float:
        """The stamp the source answers with (``now``, thesis), remembered with the list."""
        patch = self._own.patches.get(region)
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
        own = self._own
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
                    deltas[told[0]] = _delta_body(told, table, now)
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

    def _handle(self, msg: Message, now: float) -> None:
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
            logger.warning(
                "robot %d rejected a %r from robot %d (%s): %s",
                self.robot,
                msg.kind[:16],
                msg.src,
                e.code,
                e.reason,
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
        if self.params.mode == "good":
            outs = [self._good_entry(p, now) for p in request.patches]
        else:
            outs = self._limited_entries(request.patches, now)
        self._send_answer(peer, request, outs)

    def _patch_of(self, source: int, region: int) -> tuple[Layer | None, Patch | None]:
        layer = self._own if source == self.robot else self.store.received.get(source)
        patch = None if layer is None else layer.patches.get(region)
        if patch is not None and source != self.robot and not math.isfinite(patch.stamp):
            patch = None
        return layer, patch

    @staticmethod
    def _empty(p: PatchRequest) -> _Out:
        row = _answer_dict(PatchAnswer(p.source, p.region, None, None, None), [], [])
        return _Out(row, len(_pack(row)), 0)

    def _entry(
        self,
        layer: Layer,
        p: PatchRequest,
        stamp: float | None,
        short: Collection[int] | None,
        full: Collection[int] | None,
        send: Sequence[int],
    ) -> _Out:
        poses = [encode(self._wire(layer.poses[u])) for u in send]
        edges = self._edges_for(layer, p, send)
        row = {
            "src": p.source,
            "r": p.region,
            "s": _stamp_out(stamp),
            "short": _ids(short),
            "full": _ids(full),
            "poses": poses,
            "edges": [encode(e) for e in edges],
        }
        return _Out(row, len(_pack(row)), len(poses))

    @staticmethod
    def _edges_for(layer: Layer, p: PatchRequest, send: Collection[int]) -> list[OdometryEdge]:
        """The odometry edges to attach to the answer for patch ``p``: every edge touching
        the patch whose ends in the patch the requester holds or is sent, and whose
        fingerprint the requester did not name (the module's choices)."""
        poses, region = layer.poses, p.region
        held, sent = p.short, set(send)
        have = _split_fingerprints(p.edges)
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

    def _good_entry(self, p: PatchRequest, now: float) -> _Out:
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
        return self._entry(layer, p, stamp, short, None, send)

    def _limited_entries(self, patches: Sequence[PatchRequest], now: float) -> list[_Out]:
        """Limited network: per patch by stamps (ours older: offer what the requester's
        full list names and it lacks, then adopt its full list; newer: our full list and
        stamp and the short-list poses it lacks; equal: those poses), then the subset of
        best efficiency within ``cap_bytes``."""
        src = patches[0].source
        source = src == self.robot
        layer = self._own if source else self.store.received.get(src)
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
                else lambda u: size_of(self._wire(layer.poses[u])),
            )
        )
        outs: list[_Out] = []
        for q in plans:
            if q.case == "none":
                outs.append(self._empty(q.request))
                continue
            send = sorted(q.offer & chosen, key=lambda u: (layer.poses[u].time, u))
            full_out = q.listed if q.case == "newer" else None
            outs.append(self._entry(layer, q.request, q.stamp, None, full_out, send))
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
        budget = self.transport.max_message - _ENVELOPE_SLACK
        head = len(_pack({"v": VERSION, "id": request.id, "mode": request.mode, "patches": []}))
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
            body = _pack(
                {
                    "v": VERSION,
                    "id": request.id,
                    "mode": request.mode,
                    "patches": [o.row for o in batch],
                }
            )
            if self._send(peer, "answer", body):
                self.stats.poses_sent += sum(o.poses for o in batch)

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
        for e in answer.patches:
            key = (e.source, e.region)
            pending.patches.discard(key)
            if self._waiting.get(key) == answer.id:
                del self._waiting[key]
            changed = self._apply(e, now) or changed
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

    def _apply(self, e: PatchAnswer, now: float) -> bool:
        """Apply one patch's answer (whole); True if the store changed."""
        layer = self.store.received.get(e.source)
        patch = None if layer is None else layer.patches.get(e.region)
        current = patch.stamp if patch is not None else -math.inf
        listed = e.short if self.params.mode == "good" else e.full
        if e.stamp is None and not e.poses:
            return False
        if e.stamp is not None and e.stamp < current:
            # The patch became newer meanwhile (another answer came first).
            self.stats.stale += 1
            if self.params.mode == "good":
                return False
            e = PatchAnswer(e.source, e.region, None, None, None, e.poses, e.edges)
            listed = None
        if e.stamp is None and (patch is None or not patch.full):
            return False  # poses offered against a full list we do not have
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
        return changed
