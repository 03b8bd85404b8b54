"""Which of a robot's own poses its peers see, and in what form: the outgoing-pose policy
of the exchange (:class:`~.exchange.Exchanger`).

Four rules, each off by default (the thesis sends every pose whole, as soon as it is
made):

- **The hold** (``hold``): a new own pose is offered only once it is ``hold`` seconds
  old, so a pose the store deletes or merges within that time never travels. The
  policy keeps a *published* copy of the local layer with the poses old enough and
  the odometry edges between them; the exchanger advertises and answers from it.
- **Anchors** (``anchor_every``, ``loop_anchors``): landmarks travel only with every
  k-th own pose (by the UID's counter), the merged poses, and with ``loop_anchors``
  the poses that closed a loop (:mod:`.anchors`); the others travel bare.
- **The byte target** (``anchor_share``): besides the anchors, an own pose travels
  whole when, the first time it is prepared to travel, the robot has sent less than
  ``anchor_share`` times what the naive baseline would have sent ``hold`` seconds
  before (a held pose is offered that much later). Each pose is decided once, so
  every holder gets the same copy.
- **The end of the mission** (:meth:`OutgoingPolicy.finish`): every own pose is
  offered at once, however young; the last hold's poses, offered in one batch, are
  made whole only as far as their landmarks' bytes to every live peer fit under the
  byte target.

Poses travel quantised as ``descriptor_bits`` and ``ternary_maps`` say
(:func:`.quantise.quantise_pose`); a received pose goes on as its source sent it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

from ..errors import ConfigError
from .anchors import AnchorChooser, is_anchor
from .quantise import quantise_pose
from .records import Pose, encode, robot_of
from .store import Layer, RobotStore
from .wire import bare, pack

__all__ = ["OutgoingPolicy"]


class OutgoingPolicy:
    """One robot's outgoing-pose policy (see the module's notes).

    Parameters
    ----------
    store : RobotStore
        The robot's store, read but for :meth:`~.store.RobotStore.share`: every pose
        offered is marked shared, so that the store's fold never changes it again.
    anchor_every : int
        k: landmarks travel with every k-th own pose; 1: every pose whole.
    loop_anchors : bool
        Also every own pose that closed a loop (:class:`.anchors.AnchorChooser`).
    anchor_share : float
        The byte target, a share of the naive baseline's bytes; 0: off.
    hold : float
        Seconds an own pose waits before it is offered; 0: at once.
    descriptor_bits : int
        Bits each landmark descriptor byte keeps as it travels (8: exact).
    ternary_maps : bool
        Local maps travel as free / occupied / unknown.
    naive_bytes : callable, optional
        ``naive_bytes() -> bytes`` the naive baseline would have sent so far; needed by
        the byte target.
    sent : callable, optional
        ``sent() -> bytes`` this robot has sent so far; needed by the byte target.
    live_peers : callable, optional
        ``live_peers() -> count`` of the peers the robot can reach with a fresh advert;
        needed by the byte target at the end of the mission.
    """

    def __init__(
        self,
        store: RobotStore,
        *,
        anchor_every: int = 1,
        loop_anchors: bool = False,
        anchor_share: float = 0.0,
        hold: float = 0.0,
        descriptor_bits: int = 8,
        ternary_maps: bool = False,
        naive_bytes: Callable[[], float] | None = None,
        sent: Callable[[], int] | None = None,
        live_peers: Callable[[], int] | None = None,
    ) -> None:
        if anchor_share > 0 and (naive_bytes is None or sent is None or live_peers is None):
            raise ConfigError(
                "exchange: anchor_share needs the naive baseline's bytes (naive_bytes)"
            )
        self.store = store
        self.anchor_every = anchor_every
        self.anchor_share = anchor_share
        self.hold = hold
        self.descriptor_bits = descriptor_bits
        self.ternary_maps = ternary_maps
        self._naive_bytes = naive_bytes
        self._sent = sent
        self._live_peers = live_peers
        self._now = -float("inf")
        self._published = Layer(store.robot, own=True) if hold > 0 else None
        self._finished = False
        self._chooser = (
            AnchorChooser(store.robot, every=anchor_every)
            if loop_anchors and anchor_every > 1
            else None
        )
        # Own poses the byte target has decided: whole or not.
        self._by_share: dict[int, bool] = {}
        # (time, naive bytes) over the last ``hold`` seconds: the target follows the
        # baseline that far behind, else every pose of the first minute, when nothing
        # has been offered yet, would go whole.
        self._naive_log: deque[tuple[float, float]] = deque()
        # Bytes the byte target has committed since finish(): the end's poses are decided
        # in a batch before any of them is sent, so each whole one counts at once.
        self._end_spent = 0.0

    @property
    def robot(self) -> int:
        return self.store.robot

    @property
    def finished(self) -> bool:
        """Whether :meth:`finish` was called: the hold is over."""
        return self._finished

    @property
    def chooser(self) -> AnchorChooser | None:
        """The loop anchors' chooser (``loop_anchors``), or None."""
        return self._chooser

    @property
    def end_spent(self) -> float:
        """Bytes the byte target has committed to whole poses since :meth:`finish`."""
        return self._end_spent

    @property
    def offered(self) -> Layer:
        """The local layer as this robot offers it: all of it, or what the hold let out."""
        return self.store.local if self._published is None else self._published

    def finish(self) -> None:
        """The mission is over: from the next :meth:`update` every own pose is offered,
        however young (ends ``hold``). A robot that stops making poses has nothing left
        to wait for, and the team's maps are wanted whole."""
        self._finished = True

    def update(self, now: float) -> None:
        """Catch up with the store at mission time ``now`` (seconds): the loop anchors of
        new poses, the baseline's bytes, and the published layer."""
        self._now = now
        if self._chooser is not None:
            self._chooser.update(self.store)
        if self._naive_bytes is not None and self.anchor_share > 0:
            log = self._naive_log
            log.append((now, self._naive_bytes()))
            while len(log) > 1 and log[1][0] <= now - self.hold:
                log.popleft()
        self._publish(now)
        # What is offered may reach a peer from now on: the store's fold must leave it
        # as it is, or copies of one pose would differ.
        self.store.share(self.offered.poses)

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
            elif self._finished or now - pose.time >= self.hold:
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

    def wire(self, pose: Pose) -> Pose:
        """The pose as it travels: an own pose with its landmarks only if it travels
        whole, quantised. A received pose goes on as its source sent it."""
        if (
            self.anchor_every > 1
            and len(pose.landmarks)
            and robot_of(pose.uid) == self.robot
            and not self.travels_whole(pose)
        ):
            pose = bare(pose)
        return self.quantised(pose)

    def quantised(self, pose: Pose) -> Pose:
        """The pose quantised as it travels (``descriptor_bits``, ``ternary_maps``)."""
        return quantise_pose(pose, self.descriptor_bits, self.ternary_maps)

    def travels_whole(self, pose: Pose) -> bool:
        """Whether an own pose travels with its landmarks (decided once per pose)."""
        chooser = self._chooser
        if chooser is None:
            whole = is_anchor(
                pose,
                self.anchor_every,
                merged_whole=not self.store.params.merge_on_closure,
            )
        else:
            if chooser.pending([pose.uid]):
                chooser.update(self.store)
            whole = chooser.travels_whole(pose)
        if whole or self.anchor_share <= 0:
            return whole
        decided = self._by_share.get(pose.uid)
        if decided is None:
            assert self._sent is not None
            target = self.anchor_share * self._naive_behind()
            decided = self._end_whole(pose, target) if self._finished else self._sent() < target
            self._by_share[pose.uid] = decided
        return decided

    def _end_whole(self, pose: Pose, target: float) -> bool:
        """The byte target after :meth:`finish`: every pose of the last batch would be
        decided against one figure of bytes sent, so each one made whole counts at once,
        its landmarks' bytes times the live peers (the end spends at most the target)."""
        assert self._sent is not None
        assert self._live_peers is not None
        extra = len(pack({"p": encode(self.quantised(pose))})) - len(
            pack({"p": encode(self.quantised(bare(pose)))})
        )
        cost = extra * max(1, self._live_peers())
        if self._sent() + self._end_spent + cost > target:
            return False
        self._end_spent += cost
        return True

    def _naive_behind(self) -> float:
        """The naive baseline's bytes ``hold`` seconds ago (all of them once the hold
        has ended)."""
        assert self._naive_bytes is not None
        if self._finished or self.hold <= 0:
            return self._naive_bytes()
        log = self._naive_log
        return log[0][1] if log and log[0][0] <= self._now - self.hold else 0.0

    def state(self) -> dict[str, Any]:
        """The policy's state as plain msgpack values (:meth:`restore` takes it back)."""
        return {
            "published": None if self._published is None else self._published.state(),
            "finished": self._finished,
            "anchors": None if self._chooser is None else self._chooser.state(),
            "by_share": [[u, w] for u, w in sorted(self._by_share.items())],
            "naive_log": [list(x) for x in self._naive_log],
            "end_spent": self._end_spent,
        }

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`."""
        pub = state.get("published")
        self._published = None if pub is None else Layer.from_state(pub, own=True)
        self._finished = bool(state.get("finished", False))
        if self._chooser is not None and state.get("anchors") is not None:
            self._chooser.restore(state["anchors"])
        self._by_share = {int(u): bool(w) for u, w in state.get("by_share", [])}
        self._naive_log = deque((float(t), float(b)) for t, b in state.get("naive_log", []))
        self._end_spent = float(state.get("end_spent", 0.0))
