"""Which own poses travel with their landmarks (:attr:`.exchange.ExchangeParams.anchor_every`).

Landmarks are most of a pose's bytes, and a receiver needs them only to find closures.
A pose that travels with them is an *anchor*; the others travel with their estimate,
local map and odometry edges. Two ways of choosing:

- **By the counter** (:func:`is_anchor`): every k-th pose a robot made, and every merged
  pose. Every holder can tell from the UID alone.
- **Where loops close** (:class:`AnchorChooser`, ``loop_anchors``): the same, and also
  every pose that, when it was made, closed a loop the receivers could close too. A
  receiver finds a closure only between two poses that both carry landmarks, so a
  closure the source found counts if its other end travels whole:

  1. *returns*: a closure to one of the source's own anchors (or merged poses) made
     more than ``every`` poses earlier: the loop the source closed, a receiver can
     close too;
  2. *meetings*: a closure to another robot's pose (which reached this robot as an
     anchor): that robot holds its own pose whole and finds the closure, and so does
     any third robot holding both.

  With anchors every k-th pose alone a receiver finds about 1/k of the source's
  closures with its own poses and 1/k^2 of the source's loops. The choice is the
  source's, made once per pose from the closures found when it was made, and kept
  (checkpointed with the exchanger's state); relays forward poses as they received
  them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from .records import ClosureEdge, Pose, counter_of, robot_of
from .store import MERGE_COUNTER_BASE, RobotStore

__all__ = ["AnchorChooser", "is_anchor"]


def is_anchor(pose: Pose, every: int, *, merged_whole: bool = True) -> bool:
    """Whether ``pose`` travels with its landmarks when only every ``every``-th does
    (:attr:`.exchange.ExchangeParams.anchor_every`): merged poses always (a robot's
    densest record of a place it came back to), the others by their UID's counter, so
    that the anchors are spread along the robot's path and every holder agrees on them.

    ``merged_whole=False`` takes merged poses by their counter too: a store that merges
    at every reliable closure (:attr:`.store.StoreParams.merge_on_closure`) makes merged
    poses as often as loops close, and sending each whole would cost about half as much
    again (the team results pages of the docs).

    Examples
    --------
    >>> import numpy as np
    >>> from sonarmap.team.records import Landmarks, make_uid
    >>> def pose(n):
    ...     return Pose(make_uid(1, n), 0.0, 0, np.zeros(3), Landmarks.empty())
    >>> is_anchor(pose(16), 8), is_anchor(pose(17), 8), is_anchor(pose(17), 1)
    (True, False, True)
    """
    if every <= 1:
        return True
    return (merged_whole and bool(pose.merged_from)) or counter_of(pose.uid) % every == 0


class AnchorChooser:
    """One robot's anchors where loops close (module docstring), chosen as its poses
    are made.

    Parameters
    ----------
    robot : int
        The robot whose own poses are chosen from.
    every : int
        k: every k-th pose is an anchor whatever its closures (>= 1).

    Examples
    --------
    Pose 11 closed a loop with anchor 0; pose 12 only with pose 11, made just before:

    >>> import numpy as np
    >>> from sonarmap.team.records import ClosureEdge, make_uid
    >>> def closure(a, b):
    ...     cov = tuple(float(v) for v in np.eye(3).ravel() * 1e-4)
    ...     return ClosureEdge(make_uid(0, a), make_uid(0, b), (1.0, 0, 0), cov, 9, 0.0, ())
    >>> chooser = AnchorChooser(0, every=4)
    >>> chooser.choose([make_uid(0, n) for n in range(13)], [closure(0, 11), closure(11, 12)])
    >>> sorted(counter_of(u) for u in chooser.anchors)
    [0, 4, 8, 11, 12]
    """

    def __init__(self, robot: int, *, every: int) -> None:
        if every < 1:
            raise ValueError(f"anchors: every must be >= 1, got {every}")
        self.robot = robot
        self.every = every
        #: The anchors chosen (UIDs), never forgotten: a pose's choice does not change.
        self.anchors: set[int] = set()
        #: The counter of the last pose decided (-1: none yet).
        self.decided = -1

    def travels_whole(self, pose: Pose) -> bool:
        """Whether an own pose, already decided, travels with its landmarks."""
        return bool(pose.merged_from) or pose.uid in self.anchors

    def pending(self, uids: Iterable[int]) -> list[int]:
        """The UIDs among ``uids`` (own, not merged) not decided yet, in the order made."""
        return sorted(
            u
            for u in uids
            if robot_of(u) == self.robot and self.decided < counter_of(u) < MERGE_COUNTER_BASE
        )

    def update(self, store: RobotStore) -> None:
        """Decide every own pose of ``store`` made since the last call."""
        new = self.pending(store.local.poses)
        if new:
            self.choose(new, store.closures)

    def choose(self, new: list[int], closures: Iterable[ClosureEdge]) -> None:
        """Decide the poses ``new`` (own UIDs in the order made, none decided yet) from
        the closures found when they were made (those whose ``b`` is the new pose)."""
        wanted = set(new)
        found: dict[int, list[int]] = {u: [] for u in new}
        for c in closures:
            if c.b in wanted:
                found[c.b].append(c.a)
        for u in new:
            if counter_of(u) % self.every == 0 or any(self._loop(u, a) for a in found[u]):
                self.anchors.add(u)
            self.decided = counter_of(u)

    def _loop(self, uid: int, a: int) -> bool:
        """Whether a closure from new pose ``uid`` to ``a`` is one a receiver can find
        and that closes a loop."""
        if robot_of(a) != self.robot:
            return True
        n = counter_of(a)
        return n >= MERGE_COUNTER_BASE or (a in self.anchors and n < counter_of(uid) - self.every)

    def state(self) -> dict[str, Any]:
        """What a checkpoint keeps (:meth:`restore` reads it)."""
        return {"anchors": sorted(self.anchors), "decided": self.decided}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`."""
        self.anchors = {int(u) for u in state["anchors"]}
        self.decided = int(state["decided"])
