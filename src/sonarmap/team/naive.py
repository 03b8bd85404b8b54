"""The naive baseline of the exchange (issue 15): every robot sends each new pose of its
local layer, once, to every robot it can reach. The bandwidth figures of the thesis's
protocols (:mod:`.exchange`) are measured against it.

One kind of message, ``"pose"``: a msgpack map ``{"v": VERSION, "pose": bytes,
"edges": [bytes, ...]}``, compressed as :mod:`.exchange` compresses its own bodies: the
pose and the odometry edges touching it in the sender's local layer as their records'
own encodings (:func:`.records.encode`), so its bytes compare with the
protocols' answers, which carry the same records. It goes through the same transport
and network.

Choices (the issue names the baseline, not its details):

- **New pose**: a UID that appears in the sender's local layer (made, or made by a
  merge), sent at the sender's first :meth:`NaiveExchanger.step` after, as stored then
  (after pose compression: the robot keeps nothing bigger). Deletions are never sent:
  a receiver keeps every pose it got, so its store is not bounded by the thesis's
  limits, and its pose set differs from the source's once the source deletes or merges.
- **Everyone** is every robot the transport can reach at that step; one it cannot reach
  then never gets the pose (no retries, no store-and-forward), and a lost message is
  lost for good.
- **Quantised** only if its params say so (``descriptor_bits``, ``ternary_maps``, as the
  protocols quantise): by default the baseline sends the records exact, as stored;
  with the protocols' quantisation it shows what that alone saves.
- **Receiving**: a pose already held is ignored (duplicates are impossible by
  construction); otherwise it is associated (``on_received``) and put in its source's
  received layer with the edges whose two poses are held.

Every body is decoded strictly as :mod:`.exchange` decodes its own: a bad body is
rejected whole, logged on ``sonarmap.team.naive`` and counted in ``stats.rejected`` by
reason.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any

from ..errors import ConfigError
from .exchange import (
    ExchangeParams,
    Exchanger,
    ExchangeStats,
    OnReceived,
    check_pair,
    check_time,
    default_peers,
)
from .quantise import quantise_pose
from .records import OdometryEdge, Pose, encode, robot_of
from .rejects import RejectLog
from .store import RobotStore
from .transport import Message, Transport
from .wire import (
    VERSION,
    ExchangeError,
    check_keys,
    check_version,
    pack,
    read_list,
    read_record,
    strict_decoder,
    unpack,
)

__all__ = [
    "KIND",
    "NaiveExchanger",
    "NaiveMeter",
    "decode_pose_message",
    "encode_pose_message",
    "make_exchanger",
]

logger = logging.getLogger("sonarmap.team.naive")

#: The transport envelope's ``kind`` of the baseline's one message.
KIND = "pose"


def _new_poses(store: RobotStore, sent: Collection[int]) -> list[int]:
    """The local poses not sent yet, oldest first: what the baseline sends at a step."""
    local = store.local
    return sorted((u for u in local.poses if u not in sent), key=lambda u: (local.poses[u].time, u))


class NaiveMeter:
    """The bytes the naive baseline (exact records) would send for one robot, measured
    beside another protocol on the same mission, so that one run reports its share of
    the baseline's bytes.

    At each :meth:`step` every local pose not seen before is priced as the baseline's
    message for it (:func:`encode_pose_message`, the pose and its odometry edges as
    stored then) times the robots reachable then, as :class:`NaiveExchanger` sends it.
    It is an estimate of a baseline run, not one: the routes and the poses made are the
    same, but a baseline run's robots receive other poses, find other closures and so
    hold slightly other estimates, and its messages meet the network's caps and losses
    (the meter counts what the baseline would offer).

    Parameters
    ----------
    store : RobotStore
        The robot's store (read only).
    made : mapping of int to Pose, optional
        For a store that folds deleted poses' maps into kept ones
        (``StoreParams.fold``): the poses as they were made, by UID. A pose found there
        is priced with its local map as made: the baseline sends each pose as soon as it
        is made, before a fold could change it.
    merged : bool, optional
        Price merged poses too. Default: unless the store merges at every reliable
        closure (``StoreParams.merge_on_closure``), since the baseline's store merges
        only under region compression, so it would have sent the poses as made and
        none of those merges (pricing them put the estimate well above a real baseline run).

    Attributes
    ----------
    bytes : int
        Bytes the baseline would have sent so far.
    poses : int
        Poses priced so far.
    """

    def __init__(
        self,
        store: RobotStore,
        made: Mapping[int, Pose] | None = None,
        *,
        merged: bool | None = None,
    ) -> None:
        self.store = store
        self.made = made
        self.merged = not store.params.merge_on_closure if merged is None else merged
        self.bytes = 0
        self.poses = 0
        self._seen: set[int] = set()

    def state(self) -> dict[str, Any]:
        """What a checkpoint keeps (:meth:`restore` reads it)."""
        return {"bytes": self.bytes, "poses": self.poses, "seen": sorted(self._seen)}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`."""
        self.bytes = int(state["bytes"])
        self.poses = int(state["poses"])
        self._seen = {int(u) for u in state["seen"]}

    def step(self, peers: int) -> None:
        """Price the poses new since the last step, each sent to ``peers`` robots."""
        local = self.store.local
        for uid in _new_poses(self.store, self._seen):
            self._seen.add(uid)
            pose = local.poses[uid]
            if not self.merged and pose.merged_from:
                continue
            self.poses += 1
            first = None if self.made is None else self.made.get(uid)
            if first is not None and first is not pose:
                pose = replace(pose, local_map=first.local_map)
            self.bytes += peers * len(encode_pose_message(pose, local.edges_of(uid)))


def encode_pose_message(pose: Pose, edges: Sequence[OdometryEdge]) -> bytes:
    """The body carrying ``pose`` and ``edges``."""
    return pack({"v": VERSION, "pose": encode(pose), "edges": [encode(e) for e in edges]})


@strict_decoder
def decode_pose_message(
    body: bytes, source: int, *, regions: Collection[int] | None = None
) -> tuple[Pose, list[OdometryEdge]]:
    """The pose and edges in ``body`` from robot ``source``.

    Raises
    ------
    ExchangeError
        If the body is not a valid one: bad msgpack or fields, a record that does not
        decode, a pose or edge that is not ``source``'s, a pose outside ``regions``.
    """
    d = unpack(body)
    check_keys(d, ("v", "pose", "edges"), "pose message")
    check_version(d)
    pose: Pose = read_record(d["pose"], Pose, "pose message.pose")
    edges: list[OdometryEdge] = [
        read_record(e, OdometryEdge, f"pose message.edges[{k}]")
        for k, e in enumerate(read_list(d["edges"], "pose message.edges"))
    ]
    if robot_of(pose.uid) != source:
        raise ExchangeError("inconsistent", f"pose {pose.uid} is not robot {source}'s")
    if regions is not None and pose.region not in regions:
        raise ExchangeError("range", f"pose {pose.uid}: region {pose.region} is not on the map")
    for e in edges:
        if robot_of(e.a) != source or robot_of(e.b) != source:
            raise ExchangeError("inconsistent", f"edge {e.a} -> {e.b} is not {source}'s")
    return pose, edges


class NaiveExchanger:
    """One robot's side of the naive baseline, with :class:`~.exchange.Exchanger`'s
    interface (:meth:`step`, ``stats``, ``outstanding``).

    Parameters
    ----------
    store : RobotStore
        The robot's store; only its received layers and closures change.
    transport : Transport
    params : ExchangeParams, optional
        ``mode`` must be ``"naive"`` (the default); ``descriptor_bits`` and ``ternary_maps``
        quantise what is sent; nothing else is read.
    adjacency : mapping of int to collection of int, optional
        The prior map's regions: a received pose in another is rejected.
    on_received : callable, optional
        ``on_received(source, pose) -> closures`` for each pose before it is stored.
    peers : callable, optional
        ``peers() -> robot ids`` reachable now; default as the Exchanger's.

    Attributes
    ----------
    stats : ExchangeStats
        ``poses_sent`` counts a pose once per robot it went to.
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
    ) -> None:
        check_pair(store, transport)
        self.params = params if params is not None else ExchangeParams(mode="naive")
        if self.params.mode != "naive":
            raise ConfigError(f"exchange: NaiveExchanger runs mode 'naive', not {params!r}")
        self.store = store
        self.transport = transport
        self.regions = None if adjacency is None else frozenset(int(r) for r in adjacency)
        self.on_received = on_received
        self.stats = ExchangeStats()
        self._rejects = RejectLog(logger)
        self._peers = peers if peers is not None else default_peers(transport)
        self._now = -math.inf
        self._sent: set[int] = set()

    @property
    def robot(self) -> int:
        return self.store.robot

    @property
    def outstanding(self) -> dict[int, tuple[int, list[tuple[int, int]]]]:
        """Always empty: the baseline never waits for an answer."""
        return {}

    def finish(self) -> None:
        """The mission is over; the baseline holds nothing back, so nothing changes."""

    def step(self, now: float, wanted_regions: Sequence[int] | None = None) -> None:
        """Take every pose received, then send each new local pose to every reachable
        robot. ``wanted_regions`` is ignored (the baseline sends everything)."""
        check_time(now, self._now)
        self._now = float(now)
        for msg in self.transport.poll(0.0):
            self._handle(msg, self._now)
        local = self.store.local
        new = _new_poses(self.store, self._sent)
        if not new:
            return
        peers = sorted(set(self._peers()) - {self.robot})
        # Sent as they are now: the store's fold must not change them afterwards.
        self.store.share(new)
        for uid in new:
            self._sent.add(uid)
            pose = quantise_pose(
                local.poses[uid], self.params.descriptor_bits, self.params.ternary_maps
            )
            body = encode_pose_message(pose, local.edges_of(uid))
            for peer in peers:
                if self._send(peer, body):
                    self.stats.poses_sent += 1

    def _send(self, dst: int, body: bytes) -> bool:
        if not self.transport.send(dst, body, kind=KIND):
            self.stats.refused += 1
            return False
        self.stats.count_sent(KIND, len(body))
        return True

    def _handle(self, msg: Message, now: float) -> None:
        self.stats.messages_received += 1
        self.stats.bytes_received += len(msg.payload)
        try:
            if msg.kind != KIND:
                raise ExchangeError("kind", f"unknown kind {msg.kind!r}")
            if msg.src == self.robot:
                raise ExchangeError("own", "a pose message from ourselves")
            pose, edges = decode_pose_message(msg.payload, msg.src, regions=self.regions)
        except ExchangeError as e:
            self.stats.rejected[e.code] += 1
            self._rejects.warn(
                f"robot {self.robot} rejected a {msg.kind[:16]!r} from robot {msg.src} "
                f"({e.code}): {e.reason}"
            )
            return
        self.stats.poses_received += 1
        layer = self.store.received.get(msg.src)
        if layer is not None and pose.uid in layer.poses:
            return
        closures = [] if self.on_received is None else list(self.on_received(msg.src, pose))
        held = ({pose.uid} if layer is None else set(layer.poses)) | {pose.uid}
        keep = [e for e in edges if e.a in held and e.b in held]
        self.store.add_received_pose(msg.src, pose, keep, closures, now)
        self.stats.poses_added += 1


def make_exchanger(
    store: RobotStore,
    transport: Transport,
    params: ExchangeParams,
    *,
    adjacency: Mapping[int, Collection[int]] | None = None,
    on_received: OnReceived | None = None,
    peers: Callable[[], Iterable[int]] | None = None,
    naive_bytes: Callable[[], float] | None = None,
) -> Exchanger | NaiveExchanger:
    """The exchanger ``params.mode`` names: the thesis's protocols or the baseline
    (``naive_bytes``: the protocols' byte target, ``ExchangeParams.anchor_share``)."""
    if params.mode == "naive":
        return NaiveExchanger(
            store, transport, params, adjacency=adjacency, on_received=on_received, peers=peers
        )
    return Exchanger(
        store,
        transport,
        params,
        adjacency=adjacency,
        on_received=on_received,
        peers=peers,
        naive_bytes=naive_bytes,
    )
