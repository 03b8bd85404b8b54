"""The evaluator of a robot's mission: it watches the robot through the robot's observer
hooks (a pose made, a pose associated, a received pose associated, closures the graph
dropped) and scores what the robot did against the simulation's truth, which the robot
never sees (:class:`~.sensing.RobotSensing` holds it).

The scores are those of :mod:`.mission`'s notes: association precision and recall
(overall, per stage, before and after the world changed), the trajectory's error after a
rigid fit (:func:`~.scoring.rigid_ate`), the global map's wall F1 beside the maps built
from the same readings at the true and at the odometry poses, and the alignment's error.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from ..api import build_map
from ..io.rosmap import OccupancyMap
from ..metrics import score
from ..readings import Readings
from .association import AssociationStats
from .config import MissionConfig
from .globalmap import Alignment, GraphResult, fuse_local_maps
from .records import ClosureEdge, Pose, compose, invert
from .scoring import closure_correct, landmark_changes, origin_of, rigid_ate, same_landmarks
from .sensing import RobotSensing
from .store import RobotStore
from .world import World

__all__ = ["HALVES", "PCM_LOOP_KEYS", "STAGES", "MissionEvaluator"]

#: What :attr:`MissionEvaluator.pcm_loops` sums over pairwise consistency passes: the
#: closures judged, the pairs of them whose loop was tested and those whose loop could
#: not be (:class:`~.pcm.PcmResult`).
PCM_LOOP_KEYS = ("judged", "loops_tested", "loops_untestable")

F64 = npt.NDArray[np.float64]

#: The two halves of a mission association is scored on apart: before and after the
#: median time of the world's changes.
HALVES = ("before", "after")
#: The stages of association, then the graph's consistency check, as reported.
STAGES = ("votes", "bounds", "ransac", "accepted", "graph")


class MissionEvaluator:
    """Scores one robot's mission as it goes (see the module's notes).

    Parameters
    ----------
    sensing : RobotSensing
        The robot's sensors and the truth behind them.
    config : MissionConfig
    world : World
        The landmarks (their changes split association into two halves).
    made : callable
        ``made() -> {uid: Pose}``: every pose the robot made or merged, as it is now.

    Attributes
    ----------
    truth : dict of int to ndarray
        The true pose (x, y, theta) of each pose the robot made, by UID.
    odo_poses : dict of int to ndarray
        Each pose's dead-reckoning estimate from the believed start.
    peers_truth, peers_made : mapping
        Where the scoring looks up other robots' poses; default the robot's own (a team
        passes views over every robot's).
    received_closures, received_correct : int
        Closures found for received poses, and how many were right.
    inter_closures, inter_correct : int
        Of the closures found for own poses, those to another robot's pose, and how
        many were right.
    gate_rejected : dict of str to list of int
        Closures the layer gate left out (:mod:`~sonarmap.team.layergate`), for own
        poses (``"own"``) and received ones (``"received"``): ``[left out, right]``.
    pcm_rejected : dict of str to list of int
        Closures pairwise consistency left out (:mod:`~sonarmap.team.pcm`), both ends
        own poses (``"own_layer"``) or not (``"not_own"``: between two layers or within a
        received one), each closure once: ``[left out, right]``.
    """

    #: Attributes kept as plain msgpack values in :meth:`state`.
    PLAIN_STATE = (
        "n_true_pairs",
        "n_correct",
        "n_closures",
        "n_found",
        "n_same_place",
        "received_closures",
        "received_correct",
        "inter_closures",
        "inter_correct",
        "gate_rejected",
        "wrong",
        "stage_removed",
        "stages",
        "by_half",
    )

    def __init__(
        self,
        sensing: RobotSensing,
        config: MissionConfig,
        world: World,
        made: Callable[[], Mapping[int, Pose]],
    ) -> None:
        self.sensing = sensing
        self.cfg = config
        self.world = world
        self._made = made
        self.truth: dict[int, F64] = {}
        self.odo_poses: dict[int, F64] = {}
        self.peers_truth: Mapping[int, F64] = self.truth
        self.peers_made: Mapping[int, Pose] | None = None
        self.n_true_pairs = 0
        self.n_correct = 0
        self.n_closures = 0
        self.n_found = 0
        self.n_same_place = 0
        self.received_closures = 0
        self.received_correct = 0
        self.inter_closures = 0
        self.inter_correct = 0
        self.gate_rejected: dict[str, list[int]] = {"own": [0, 0], "received": [0, 0]}
        self.pcm_rejected: dict[str, list[int]] = {"own_layer": [0, 0], "not_own": [0, 0]}
        #: Summed over PCM passes: closures judged, loops tested, loops untestable.
        self.pcm_loops: dict[str, int] = dict.fromkeys(PCM_LOOP_KEYS, 0)
        self.wrong: list[dict[str, Any]] = []
        self.stage_removed: dict[str, list[int]] = {}
        self.stages = {
            s: {"in": 0, "removed": 0, "removed_true": 0, "kept_false": 0} for s in STAGES
        }
        self.graph_dropped: dict[tuple[int, int], bool] = {}
        # Association before and after the world changed: split at the median time of
        # the changes (vanishing, appearing, moving) that happen during the mission.
        self.end = float(sensing.route[-1, 0])
        events = np.concatenate([world.died, world.moved_at, world.born[world.born > 0]])
        events = events[events <= self.end]
        self.t_change = float(np.median(events)) if len(events) else self.end
        self.by_half = {
            h: {"closures": 0, "correct": 0, "true_pairs": 0, "found": 0} for h in HALVES
        }

    # --- truth lookups -------------------------------------------------------------------

    def _origin_any(self, uid: int) -> int | None:
        made = self._made()
        o = origin_of(uid, self.truth, made)
        if o is None and self.peers_truth is not self.truth:
            o = origin_of(
                uid, self.peers_truth, made if self.peers_made is None else self.peers_made
            )
        return o

    def _true_of(self, uid: int) -> F64:
        return self.truth[uid] if uid in self.truth else self.peers_truth[uid]

    def scored(self, c: ClosureEdge) -> bool:
        """Whether both of a closure's poses have a known true pose (a peer's merged pose
        whose merge chain the robot lacks has none), so :meth:`correct` can judge it."""
        return self._origin_any(c.a) is not None and self._origin_any(c.b) is not None

    def correct(self, c: ClosureEdge) -> bool:
        """Whether a closure's transform is within the tolerance of the true one."""
        oa, ob = self._origin_any(c.a), self._origin_any(c.b)
        return (
            oa is not None
            and ob is not None
            and closure_correct(
                c, self._true_of(oa), self._true_of(ob), self.cfg.correct_xy, self.cfg.correct_theta
            )
        )

    # --- the robot's hooks ---------------------------------------------------------------

    def pose_made(self, k: int, pose: Pose, dead_reckoning: F64) -> None:
        """The robot made ``pose`` at route step ``k``."""
        self.truth[pose.uid] = self.sensing.true_pose(k)
        self.odo_poses[pose.uid] = dead_reckoning

    def associated(
        self,
        pose: Pose,
        stored: Sequence[Pose],
        closures: Sequence[ClosureEdge],
        stats: AssociationStats,
        t: float,
    ) -> None:
        """The robot associated its new ``pose`` with the ``stored`` poses at time ``t``."""
        cfg, uid, landmarks = self.cfg, pose.uid, pose.landmarks
        for stage, (_, matches) in stats.removed().items():
            self.stage_removed.setdefault(stage, []).append(matches)
        ids = set(landmarks.ids[landmarks.ids >= 0].tolist())
        overlapping = {
            p.uid
            for p in stored
            if len(ids & set(p.landmarks.ids[p.landmarks.ids >= 0].tolist()))
            >= cfg.association.n_min
        }
        self.n_true_pairs += len(overlapping)
        half = self.by_half[HALVES[int(t >= self.t_change)]]
        half["true_pairs"] += len(overlapping)
        before = {p.uid for p in stored if p.uid != uid}
        for stage in STAGES[:-1]:
            after = set(stats.kept[stage])
            row = self.stages[stage]
            row["in"] += len(before)
            row["removed"] += len(before - after)
            row["removed_true"] += len((before - after) & overlapping)
            row["kept_false"] += len(after - overlapping)
            before = after
        by_uid: dict[int, Pose] = {}
        for p in stored:
            by_uid.setdefault(p.uid, p)
        made = self._made()
        for c in closures:
            self.n_same_place += same_landmarks(c, by_uid.get(c.a), pose)
            right = self.correct(c)
            if c.a not in made:
                self.inter_closures += 1
                self.inter_correct += right
            oa = self._origin_any(c.a)
            if not right and oa is not None:
                err = np.asarray(c.transform) - compose(invert(self._true_of(oa)), self.truth[uid])
                self.wrong.append(
                    {
                        "a": c.a,
                        "b": c.b,
                        "inliers": c.inliers,
                        "error_m": round(math.hypot(err[0], err[1]), 3),
                        "error_deg": round(
                            math.degrees(abs(math.remainder(err[2], 2 * math.pi))), 2
                        ),
                    }
                )
            self.n_closures += 1
            self.n_correct += right
            self.n_found += right and c.a in overlapping
            half["closures"] += 1
            half["correct"] += right
            half["found"] += right and c.a in overlapping

    def received(self, pose: Pose, closures: Sequence[ClosureEdge]) -> None:
        """The robot associated a pose another robot sent it."""
        self.received_closures += len(closures)
        self.received_correct += sum(self.correct(c) for c in closures)

    def gated(self, closures: Sequence[ClosureEdge], *, own: bool) -> None:
        """The layer gate left these closures of an own (``own``) or received pose out."""
        row = self.gate_rejected["own" if own else "received"]
        row[0] += len(closures)
        row[1] += sum(self.correct(c) for c in closures)

    def pcm(
        self,
        closures: Sequence[ClosureEdge],
        own: Collection[int],
        loops: Mapping[str, int] | None = None,
    ) -> None:
        """Pairwise consistency (:mod:`.pcm`) left these closures out; ``own`` holds the
        robot's own poses (a closure with both ends there is its own layer's). ``loops``
        adds a pass's counts (keys :data:`PCM_LOOP_KEYS`) to :attr:`pcm_loops`."""
        for k, v in (loops or {}).items():
            self.pcm_loops[k] += int(v)
        for c in closures:
            row = self.pcm_rejected["own_layer" if c.a in own and c.b in own else "not_own"]
            row[0] += 1
            row[1] += self.correct(c)

    def dropped(self, closures: Sequence[ClosureEdge]) -> None:
        """The robot's graph found these closures inconsistent and dropped them."""
        for c in closures:
            self.graph_dropped[(c.a, c.b)] = self.correct(c)

    # --- the scores ----------------------------------------------------------------------

    def scores(
        self,
        plan: OccupancyMap,
        store: RobotStore,
        graph: GraphResult,
        alignment: Alignment,
        global_map: OccupancyMap,
    ) -> dict[str, Any]:
        """The mission's scores once the robot has built and aligned its global map:
        association (with its stages and halves), ATE, the maps' F1 and the alignment's
        error, and how the store treated the landmarks that changed."""
        cfg, truth, sensing = self.cfg, self.truth, self.sensing
        made = self._made()
        stages = self.stages
        stages["graph"] = {
            "in": self.n_closures,
            "removed": len(self.graph_dropped),
            "removed_true": sum(self.graph_dropped.values()),
            # A closure with a pose of unknown origin is neither right nor wrong here.
            "kept_false": sum(self.scored(c) and not self.correct(c) for c in store.closures),
            "kept_unscored": sum(not self.scored(c) for c in store.closures),
        }
        a = np.asarray(alignment.transform, dtype=np.float64)
        a_true = sensing.a_true
        kept = {u: origin_of(u, truth, made) for u in store.local.poses}
        uids = [u for u, o in kept.items() if o is not None]
        est = np.array([graph.estimates[u] for u in uids])
        tru = np.array([truth[kept[u]] for u in uids])  # type: ignore[index]
        odo_est = np.array([self.odo_poses[kept[u]] for u in uids])  # type: ignore[index]
        # How far the found alignment puts the robot's poses from where the true one would.
        placed = compose(a, est)
        should = compose(a_true, est)
        align_m = float(np.mean(np.hypot(*(placed[:, :2] - should[:, :2]).T)))
        align_deg = math.degrees(abs(math.remainder(a[2] - a_true[2], 2 * math.pi)))
        # The same readings mapped at the true poses and at the odometry poses (given the
        # true start): the bounds of the global map.
        readings, rig, odo = sensing.readings, sensing.rig, sensing.odo
        true_posed = build_map(readings, rig, plan.grid, cfg.mapper, cfg.mapper_params)
        odo_world = compose(
            a_true,
            compose(
                sensing.start_believed,
                compose(invert(odo[0, 1:4]), odo[sensing.step_of, 1:4]),
            ),
        )
        odo_sonar = compose(odo_world, sensing.mounts)
        odo_posed = build_map(
            Readings(
                readings.t,
                readings.sensor,
                odo_sonar[:, 0],
                odo_sonar[:, 1],
                odo_sonar[:, 2],
                readings.range,
                readings.names,
            ),
            rig,
            plan.grid,
            cfg.mapper,
            cfg.mapper_params,
        )
        held_f1, held_n = self._held_at_truth(plan, store)
        changes: dict[str, Any] = dict(
            landmark_changes(self.world, store, dict(made), truth, self.end)
        )
        changes["change_time_s"] = self.t_change
        for h, row in self.by_half.items():
            changes[f"association_{h}"] = {
                "closures": row["closures"],
                "precision": row["correct"] / row["closures"] if row["closures"] else math.nan,
                "recall": row["found"] / row["true_pairs"] if row["true_pairs"] else math.nan,
            }
        n = self.n_closures
        return {
            "association_precision": self.n_correct / n if n else math.nan,
            "association_recall": self.n_found / self.n_true_pairs
            if self.n_true_pairs
            else math.nan,
            "association_precision_landmarks": self.n_same_place / n if n else math.nan,
            "closures_found": n,
            "closures_correct": self.n_correct,
            "closures_wrong": self.wrong,
            # The own poses' closures split by the other end's layer: ours, or a peer's.
            "closures_inter_robot": self.inter_closures,
            "closures_inter_robot_correct": self.inter_correct,
            "association_precision_own_layer": (self.n_correct - self.inter_correct)
            / (n - self.inter_closures)
            if n > self.inter_closures
            else math.nan,
            "association_precision_inter_robot": self.inter_correct / self.inter_closures
            if self.inter_closures
            else math.nan,
            "layer_gate_rejected": {
                k: {"closures": v[0], "correct": v[1]} for k, v in self.gate_rejected.items()
            },
            "pcm_rejected": {
                k: {"closures": v[0], "correct": v[1]} for k, v in self.pcm_rejected.items()
            },
            "pcm_loops": dict(self.pcm_loops),
            "true_pairs": self.n_true_pairs,
            "association_removed_matches": {k: int(sum(v)) for k, v in self.stage_removed.items()},
            "association_stages": stages,
            "changing_landmarks": changes,
            "closures_rejected_by_graph": len(graph.inconsistent),
            "ate_m": rigid_ate(est[:, :2], tru[:, :2]),
            "ate_odometry_m": rigid_ate(odo_est[:, :2], tru[:, :2]),
            "map_f1": score(plan, global_map).f1_all,
            "map_f1_true_poses": score(plan, true_posed).f1_all,
            "map_f1_odometry_poses": score(plan, odo_posed).f1_all,
            "map_f1_held_true_poses": held_f1,
            "map_poses_held": held_n,
            "alignment_error_m": align_m,
            "alignment_error_deg": align_deg,
        }

    def _held_at_truth(self, plan: OccupancyMap, store: RobotStore) -> tuple[float, int]:
        """The wall F1 of the map fused, as the global map is, from the local maps of
        every pose the store holds (own and received), each at its true pose, and how
        many poses that is: the global map's bound given what the store kept."""
        held: dict[int, Pose] = dict(store.local.poses)
        for source in sorted(store.received):
            held.update(store.received[source].poses)
        at: dict[int, F64] = {}
        for uid in held:
            o = self._origin_any(uid)
            if o is not None:
                at[uid] = self._true_of(o)
        fused = fuse_local_maps({u: held[u] for u in at}, at, plan.grid)
        return score(plan, fused).f1_all, len(at)

    # --- state ---------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """The evaluator's counters and truth as plain msgpack values (:meth:`restore`)."""
        d: dict[str, Any] = {name: getattr(self, name) for name in self.PLAIN_STATE}
        d["truth"] = [[u, [float(v) for v in x]] for u, x in self.truth.items()]
        d["odo_poses"] = [[u, [float(v) for v in x]] for u, x in self.odo_poses.items()]
        d["graph_dropped"] = [[k[0], k[1], v] for k, v in self.graph_dropped.items()]
        d["pcm_rejected"] = {k: list(v) for k, v in self.pcm_rejected.items()}
        d["pcm_loops"] = dict(self.pcm_loops)
        return d

    def restore(self, d: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`. :attr:`truth` becomes a new dict: views over it
        (``peers_truth``) must be renewed."""
        for name in self.PLAIN_STATE:
            setattr(self, name, d[name])
        self.truth = {int(u): np.array(x, dtype=np.float64) for u, x in d["truth"]}
        self.odo_poses = {int(u): np.array(x, dtype=np.float64) for u, x in d["odo_poses"]}
        self.graph_dropped = {(int(x), int(y)): bool(v) for x, y, v in d["graph_dropped"]}
        # A state saved before pairwise consistency existed has none rejected; one saved
        # before the row's rename calls "not_own" "between_layers".
        pcm = dict(d.get("pcm_rejected", {}))
        if "between_layers" in pcm:
            pcm.setdefault("not_own", pcm.pop("between_layers"))
        self.pcm_rejected = {
            k: [int(x) for x in pcm.get(k, (0, 0))] for k in ("own_layer", "not_own")
        }
        loops = d.get("pcm_loops", {})
        self.pcm_loops = {k: int(loops.get(k, 0)) for k in PCM_LOOP_KEYS}
