"""How a mission is judged against the simulation's truth: the trajectory's error after
a rigid fit, whether a closure is right, where a merged pose's frame comes from, and how
the store treats the landmarks that vanished. Nothing here is the robot's: these
functions read the truth, which only the simulator and the evaluator know.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from .association import estimate_planar
from .records import ClosureEdge, Pose, compose, invert
from .store import RobotStore
from .world import World

__all__ = [
    "closure_correct",
    "heirs_of",
    "landmark_changes",
    "origin_of",
    "rigid_ate",
    "same_landmarks",
]

F64 = npt.NDArray[np.float64]


def rigid_ate(est: F64, true: F64) -> float:
    """RMS position error after the best rigid 2-D fit of ``est`` onto ``true``."""
    if len(est) < 2:
        return float("nan")
    tf = estimate_planar(
        np.column_stack([true, np.zeros(len(true))]), np.column_stack([est, np.zeros(len(est))])
    )
    c, s = math.cos(tf[2]), math.sin(tf[2])
    moved = est @ np.array([[c, s], [-s, c]]) + tf[:2]
    return float(np.sqrt(np.mean(np.sum((moved - true) ** 2, axis=1))))


def origin_of(uid: int, truth: Mapping[int, F64], poses: Mapping[int, Pose]) -> int | None:
    """The made pose whose frame a pose has (a merged pose keeps its first pose's)."""
    while uid not in truth:
        p = poses.get(uid)
        if p is None or not p.merged_from:
            return None
        uid = p.merged_from[0]
    return uid


def landmark_changes(
    world: World, store: RobotStore, made: dict[int, Pose], truth: dict[int, F64], now: float
) -> dict[str, float]:
    """How the store treats landmarks that vanished during the mission.

    ``reliability_vanished`` / ``reliability_present``: mean reliability in the final
    store of landmarks whose true landmark had vanished by the end, and of the others.
    ``kept_vanished`` / ``kept_present``: of the landmark observations made at poses
    before the median vanishing time, the share still in the store at the end: lower
    for the vanished ones means they leave first. One window for both, because the
    store keeps recent poses longer: a window running to each landmark's own vanishing
    would credit late-vanishing landmarks with recent observations.
    """
    gone = world.died <= now
    rel: dict[bool, list[float]] = {True: [], False: []}
    kept: set[tuple[int, int]] = set()
    for p in store.local.poses.values():
        ids = p.landmarks.ids
        for i, r in zip(
            ids[ids >= 0].tolist(), p.landmarks.reliability[ids >= 0].tolist(), strict=True
        ):
            rel[bool(gone[i])].append(r)
            kept.add((p.uid, i))
    cut = float(np.median(world.died[gone])) if gone.any() else now
    seen = {True: 0, False: 0}
    still = {True: 0, False: 0}
    heirs = heirs_of(store, made)
    for uid in truth:
        p = made[uid]
        ids = p.landmarks.ids
        for i in ids[ids >= 0].tolist():
            v = bool(gone[i])
            if p.time >= cut:
                continue
            seen[v] += 1
            # A merged pose keeps its landmarks under a new UID: count it by identity.
            still[v] += any((u, i) in kept for u in heirs.get(uid, ()))
    nan = float("nan")
    return {
        "reliability_vanished": float(np.mean(rel[True])) if rel[True] else nan,
        "reliability_present": float(np.mean(rel[False])) if rel[False] else nan,
        "kept_vanished": still[True] / seen[True] if seen[True] else nan,
        "kept_present": still[False] / seen[False] if seen[False] else nan,
    }


def heirs_of(store: RobotStore, made: dict[int, Pose]) -> dict[int, list[int]]:
    """For each pose ever made, the stored poses that hold it: itself, or the merged
    poses it went into (through merges of merges)."""
    out: dict[int, list[int]] = {}
    for p in store.local.poses.values():
        todo = [p.uid]
        while todo:
            u = todo.pop()
            out.setdefault(u, []).append(p.uid)
            q = made.get(u)
            todo += list(q.merged_from) if q is not None else []
    return out


def same_landmarks(c: ClosureEdge, a: Pose | None, b: Pose) -> bool:
    """Whether most of a closure's inliers pair the same true landmark."""
    if a is None or not c.matches:
        return False
    m = np.array(c.matches)
    ia, ib = a.landmarks.ids[m[:, 0]], b.landmarks.ids[m[:, 1]]
    return bool(np.mean((ia == ib) & (ia >= 0)) > 0.5)


def closure_correct(c: ClosureEdge, ta: F64, tb: F64, xy: float, theta: float) -> bool:
    """Whether a closure's transform is within ``xy`` metres and ``theta`` radians of
    the true one between the true poses ``ta`` and ``tb`` (x, y, theta)."""
    true = compose(invert(ta), tb)
    err = np.asarray(c.transform) - true
    return bool(
        math.hypot(err[0], err[1]) <= xy and abs(math.remainder(err[2], 2 * math.pi)) <= theta
    )
