"""One robot's mission, end to end: drive a route through the simulated world, make a
pose every metre or so (stereo landmarks and a local sonar map), associate it with the
store, keep the store under its memory bounds, optimise the pose graph in batches, fuse
and align the global map, and score every estimate against the simulation's truth.

Decisions where the thesis is silent:

- **Frames.** The robot knows its start in the prior map only roughly (``start_error``:
  1 m and 10 degrees, drawn with the seed); its global frame is its odometry frame
  started there. The alignment to the prior map must find the rest.
- **When a pose is made**: after ``pose_every`` metres (1.0) or ``pose_turn`` radians
  (0.5) of odometry since the last pose.
- **The local map** of a pose is built by a sonarmap mapper (``mapper``: the inverse
  model) from the sonar readings taken since the previous pose, placed in the pose's
  frame by odometry, on a square of ``local_size`` metres (6) at ``local_resolution``
  (0.1 m). Only readings up to ``mapping_range`` (3 m) are used, and the inverse model
  takes ``mapper_params`` (p_occ 0.6, p_free 0.45, a 20-degree fall-off, a 5 cm band
  centred on the echo): on four seeded training buildings
  (:func:`~sonarmap.floorplan.random_building` seeds 0-3, 300 s patrols, the 16-sonar
  ring) this scored a mean wall F1 of 0.31 at the true poses, against 0.05 for the
  mapper's own defaults, whose long specular no-echo misses and weak ``p_occ`` erase
  the walls (48 settings of p_occ, p_free and range, and the counting model, tried).
  The band has since moved 0.75 cell (7.5 cm) behind the echo, the inverse mapper's
  default (a cell counts as wall when its centre is inside one, so it lies behind the
  surface heard): on the same four buildings (mission seed 0) the wall F1 at the true
  poses rose from 0.33 to 0.42 on average, and the global map's from 0.28 to 0.32.
- **Odometry edges** carry the odometry model's covariance and the hard bound top
  speed x elapsed time (``max_speed``, 1.0 m/s: twice the route's speed).
- **Association** is tried against every pose in the store. The thesis's hard bound
  (top speed x elapsed time) removes nothing once a minute has passed in a building,
  so each candidate also gets the prior of the current estimates: the new pose's
  estimate carries the odometry's covariance accumulated since the last closure
  (``drift``), and a closure that puts it further off than ``gate_floor`` +
  ``gate_sigmas`` sigmas (the distance to the candidate times the heading sigma
  included) is refused. After a pose's closures are accepted, its estimate moves to
  the one given by its closure with the most inliers, and ``drift`` restarts from
  that closure's covariance, so the gate stays tight between graph batches.
- **Scores.** ATE is the RMS position error over the poses after the best rigid 2-D fit
  to the truth (so it measures the trajectory's shape, not its frame); a closure is
  correct when its transform is within ``correct_xy`` (0.3 m) and ``correct_theta``
  (5 degrees) of the true one (``association_precision``); a closure associates the
  right place when most of its inlier matches pair the same true landmark
  (``association_precision_landmarks``: a right place with a transform off by more
  than the tolerance counts here, not there); recall counts the (new, stored) pairs
  that truly shared at least ``n_min`` landmarks when the new pose was associated.
- **After the world changed** (``changing_landmarks``): association's precision and
  recall on the poses made before and after the median time of the changes
  (``association_before`` / ``association_after``), besides the reliabilities of
  vanished and present landmarks and the share of each still kept.
- **What each stage removes** (``association_stages``): for voting, the odometry
  pre-check, RANSAC and the checks of its refitted transform (``accepted``: the odometry
  bound and the gate, and the certainty limits), the candidate
  poses it was given (``in``), removed, removed although truly overlapping
  (``removed_true``: the stage's cost in recall) and kept although not
  (``kept_false``: what the later stages must still remove). For ``graph``, the closures
  accepted, those the optimised graph found inconsistent, how many of them were correct,
  and the wrong closures left in the store at the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..api import build_map
from ..errors import ConfigError, InputError
from ..grid import Grid
from ..io.rosmap import OccupancyMap
from ..metrics import score
from ..readings import Readings
from ..rig import Rig, get_rig
from .animation import Frame
from .association import (
    AssociationParams,
    AssociationStats,
    Prior,
    associate,
)
from .globalmap import (
    Alignment,
    GraphResult,
    align_to_prior,
    fuse_local_maps,
    grid_around,
    optimise_graph,
)
from .records import (
    ClosureEdge,
    LocalMap,
    OdometryEdge,
    Pose,
    compose,
    compose_covariance,
    decode_as,
    encode,
    invert,
    make_uid,
)
from .regions import cut_regions, region_of
from .scoring import (
    closure_correct,
    landmark_changes,
    origin_of,
    rigid_ate,
    same_landmarks,
)
from .store import RobotStore, StoreParams
from .world import (
    ODOMETRY_NOISE,
    World,
    make_world,
    observe,
    odometry,
    odometry_covariance,
    patrol_route,
    sonar_readings,
)

__all__ = ["MissionConfig", "MissionResult", "RobotAgent", "run_mission"]

F64 = npt.NDArray[np.float64]
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class MissionConfig:
    """Every number of a mission (see the module's notes for the choices)."""

    duration: float = 600.0
    pose_every: float = 1.0
    pose_turn: float = 0.5
    local_size: float = 6.0
    local_resolution: float = 0.1
    map_resolution: float = 0.1
    mapper: str = "inverse"
    mapper_params: dict[str, Any] = field(
        default_factory=lambda: {
            "p_occ": 0.6,
            "p_free": 0.45,
            "falloff_deg": 20.0,
            "dr": 0.05,
            # The inverse mapper's default: its band 0.75 cell behind the echo.
            "band_offset": None,
        }
    )
    mapping_range: float = 3.0
    max_speed: float = 1.0
    start_error: tuple[float, float] = (1.0, math.radians(10.0))
    batch: int = 25
    correct_xy: float = 0.3
    correct_theta: float = math.radians(5.0)
    rig: str = "ring16"
    seed: int = 0
    store: StoreParams = field(default_factory=StoreParams)
    #: Association as :class:`AssociationParams`, but a closure is refused when its
    #: refit puts the new pose less surely than half the scoring tolerance: standard
    #: deviations of 0.15 m (worst direction) and 2.5 degrees. Chosen on training plans
    #: (office and random buildings 0-4, 600 s, mission seed 0): without the limits the
    #: stereo-weighted refit alone gave precision 0.9975-1.0, and the wrong closures had
    #: 0.19-0.38 m and 0.75-4.7 degrees of standard deviation, where 99 % of the right
    #: ones were under 0.15-0.29 m; with them, 0.999-1.0 at recall 0.27-0.49.
    association: AssociationParams = field(
        default_factory=lambda: AssociationParams(
            max_sigma_xy=0.15, max_sigma_theta=math.radians(2.5)
        )
    )
    #: The odometry gate: a candidate's closure must put the new pose within
    #: ``gate_floor`` m + ``gate_sigmas`` standard deviations of where the current
    #: estimates put it (and its heading within ``gate_turn_floor`` rad + as many sigmas),
    #: never beyond the hard bound (top speed x elapsed time).
    gate_floor: float = 0.5
    gate_sigmas: float = 3.0
    gate_turn_floor: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "duration",
            "pose_every",
            "pose_turn",
            "local_size",
            "local_resolution",
            "mapping_range",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be > 0, got {v}")
        if self.batch < 1:
            raise ConfigError(f"batch must be >= 1, got {self.batch}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")


@dataclass
class MissionResult:
    """What a mission made and measured."""

    config: MissionConfig
    summary: dict[str, Any]
    global_map: OccupancyMap
    store: RobotStore
    graph: GraphResult
    alignment: Alignment
    truth: dict[int, F64]
    odometry_poses: dict[int, F64]
    bytes_per_pose: list[int]
    frames: list[Frame] = field(default_factory=list)
    #: The local layer's bytes after each pose (``bytes_per_pose`` is the whole store).
    local_bytes_per_pose: list[int] = field(default_factory=list)


def _sonar_in_pose_frame(
    readings: Readings, mounts: F64, steps: npt.NDArray[np.intp], odo: F64, k: int
) -> Readings:
    """The readings (taken at route steps ``steps``, from sonars at ``mounts`` on the
    robot), their sonar poses put in the frame of the pose made at step ``k`` as the
    robot knows them: at invert(odo_k) (+) odo_i (+) mount."""
    local = compose(compose(invert(odo[k]), odo[steps]), mounts)
    return Readings(
        readings.t,
        readings.sensor,
        local[:, 0],
        local[:, 1],
        local[:, 2],
        readings.range,
        readings.names,
    )


def _local_map(readings: Readings, rig: Rig, config: MissionConfig) -> LocalMap | None:
    """The pose's local map from its readings (in its frame), by the configured mapper."""
    if len(readings) == 0:
        return None
    n = max(2, round(config.local_size / config.local_resolution))
    h = n * config.local_resolution / 2
    grid = Grid(config.local_resolution, (-h, -h), (n, n))
    m = build_map(readings, rig, grid, config.mapper, config.mapper_params)
    p = np.clip(np.nan_to_num(m.occupancy.astype(np.float64), nan=0.5), 0.01, 0.99)
    return LocalMap.from_logodds(np.log(p / (1 - p)), config.local_resolution)


#: What a stored pose's estimate is assumed to be off by, relative to the graph's other
#: poses, when a closure to it resets the drift: (5 cm, 5 cm, 0.01 rad) squared.
CANDIDATE_COV = np.diag([0.05**2, 0.05**2, 0.01**2])


def _priors(
    stored: list[Pose], estimate: F64, t: float, drift: F64, cfg: MissionConfig
) -> dict[int, Prior]:
    """Each candidate's prior: the new pose where the current estimates put it in the
    candidate's frame, within the gate, and never beyond the hard bound."""
    sigma_xy = math.sqrt(max(float(np.linalg.eigvalsh(drift[:2, :2])[-1]), 0.0))
    sigma_t = math.sqrt(max(float(drift[2, 2]), 0.0))
    out = {}
    for p in stored:
        hard = cfg.max_speed * (t - p.time) + 0.05
        pred = compose(invert(p.estimate), estimate)
        d = math.hypot(pred[0], pred[1])
        gate = cfg.gate_floor + cfg.gate_sigmas * (sigma_xy + d * sigma_t)
        turn = min(math.pi, cfg.gate_turn_floor + cfg.gate_sigmas * sigma_t)
        if gate >= hard:
            # The hard bound is about the distance between the poses, not the estimate.
            out[p.uid] = Prior((0.0, 0.0, 0.0), hard)
        else:
            out[p.uid] = Prior((float(pred[0]), float(pred[1]), float(pred[2])), gate, turn)
    return out


#: The two halves of a mission association is scored on apart: before and after the
#: median time of the world's changes.
HALVES = ("before", "after")
#: The stages of association, then the graph's consistency check, as reported.
STAGES = ("votes", "bounds", "ransac", "accepted", "graph")


def _optimise(store: RobotStore) -> tuple[GraphResult, list[ClosureEdge]]:
    """One batch of the global map: optimise, move every pose's estimate, drop the
    closures the result finds inconsistent (returned)."""
    if not store.received:
        # Started from the current estimates, which closures keep near the truth:
        # chained odometry drifts metres over an hour, and from there GNC rejected
        # hundreds of correct closures (building 7, 6000 s: ATE 3.17 m; 0.04 m so).
        graph = optimise_graph(
            store.local.poses, store.local.edges, store.closures, initial="estimates"
        )
    else:
        # Every layer's poses; our oldest pose holds the frame (the default anchor is
        # the oldest of all, which may be another robot's).
        poses = dict(store.local.poses)
        edges = list(store.local.edges)
        for source in sorted(store.received):
            poses.update(store.received[source].poses)
            edges.extend(store.received[source].edges)
        own = store.local.poses.values()
        anchor = min(own, key=lambda p: (p.time, p.uid)).uid if own else None
        graph = optimise_graph(poses, edges, store.closures, anchor=anchor)
    for uid, est in graph.estimates.items():
        # Received poses are not ours to change: only our own estimates move.
        if uid in store.local.poses:
            store.local.poses[uid].estimate = np.asarray(est, dtype=np.float64)
    dropped = [store.closures[i] for i in graph.inconsistent]
    store.closures = graph.consistent_closures(store.closures)
    return graph, dropped


class RobotAgent:
    """One robot's mission, one route step at a time: the robot logic of
    :func:`run_mission`, and the truth bookkeeping that scores it.

    The agent makes its poses (:meth:`step`), associates each one with every pose its
    store holds (its own and those received from other robots), optimises the pose
    graph every ``batch`` poses, associates the poses other robots send it
    (:meth:`receive`, an :class:`~sonarmap.team.exchange.Exchanger`'s ``on_received``)
    and, at the end, fuses, aligns and scores the global map (:meth:`finish`).

    Parameters
    ----------
    plan : OccupancyMap
        The floor the robot drives (the simulation's truth).
    config : MissionConfig, optional
    prior : OccupancyMap, optional
        The prior map; the plan unless given.
    route : ndarray (T, 4), optional
        ``t, x, y, theta``; replaces the patrol route drawn from the seed and ``robot``.
    world : World, optional
        The landmarks; made from the seed unless given.
    robot : int
        The robot's id: its UIDs' source and its seeds.
    record : bool
        Keep a :class:`~sonarmap.team.animation.Frame` per pose made.

    Attributes
    ----------
    store : RobotStore
    truth : dict of int to ndarray
        The true pose (x, y, theta) of each pose the robot made, by UID.
    made : dict of int to Pose
        Every pose the robot made or merged, by UID.
    peers_truth, peers_made : mapping
        Where :meth:`receive` and the scoring look up other robots' poses; default the
        agent's own dicts (a team passes views over every robot's).
    route : ndarray (T, 4)
        The true route, cut to the mission's duration.
    region_of_step : ndarray of int (T,)
        The prior map's region of each route step's true position.
    k : int
        The next route step :meth:`step` processes.
    """

    def __init__(
        self,
        plan: OccupancyMap,
        config: MissionConfig | None = None,
        *,
        prior: OccupancyMap | None = None,
        route: F64 | None = None,
        world: World | None = None,
        robot: int = 0,
        record: bool = False,
    ) -> None:
        cfg = MissionConfig() if config is None else config
        prior = plan if prior is None else prior
        if not (plan.classes() == 0).any() or not (prior.classes() == 0).any():
            raise InputError("the map has no free cell", field="map")
        self.wall0 = time.perf_counter()
        self.cfg = cfg
        self.plan = plan
        self.prior = prior
        self.robot = robot
        self.record = record
        world = make_world(plan, seed=cfg.seed, duration=cfg.duration) if world is None else world
        self.world = world
        self.seed = cfg.seed + 7919 * robot
        seed = self.seed
        true = patrol_route(plan, cfg.duration, seed=seed) if route is None else route
        true = np.asarray(true, dtype=np.float64)
        true = true[true[:, 0] <= true[0, 0] + cfg.duration]
        self.route = true
        odo, _ = odometry(true, seed=seed + 1, **ODOMETRY_NOISE)
        self.odo = odo
        self.rig = get_rig(cfg.rig)
        readings = sonar_readings(plan, true, rig=self.rig, seed=seed + 2)
        readings = readings.take(np.flatnonzero(readings.range <= cfg.mapping_range))
        self.readings = readings
        self.step_of = np.clip(np.searchsorted(true[:, 0], readings.t), 0, len(true) - 1)
        # Each reading's sonar pose on the robot: invert(true robot pose) (+) world sonar pose.
        self.mounts = compose(
            invert(true[self.step_of, 1:4]),
            np.column_stack([readings.x, readings.y, readings.theta]),
        )
        self.labels = cut_regions(prior.classes() == 0, prior.grid.resolution)
        self.region_of_step: npt.NDArray[np.intp] = np.array(
            [region_of(self.labels, prior.grid, float(x), float(y)) for x, y in true[:, 1:3]],
            dtype=np.intp,
        ).reshape(-1)

        # The robot's start as it believes it: the true one off by start_error.
        rng = np.random.default_rng(seed + 3)
        off = np.array([*rng.normal(0, cfg.start_error[0], 2), rng.normal(0, cfg.start_error[1])])
        start_true = true[0, 1:4]
        self.start_believed = start_true + off
        # Prior frame = A_true (+) robot frame.
        self.a_true = compose(start_true, invert(self.start_believed))

        self.store = RobotStore(robot, cfg.store)
        self.truth: dict[int, F64] = {}
        self.odo_poses: dict[int, F64] = {}
        self.made: dict[int, Pose] = {}
        self.peers_truth: Mapping[int, F64] = self.truth
        self.peers_made: Mapping[int, Pose] = self.made
        self.bytes_per_pose: list[int] = []
        self.local_bytes_per_pose: list[int] = []
        self.frames: list[Frame] = []
        self.n_true_pairs = 0
        self.n_correct = 0
        self.n_closures = 0
        self.n_found = 0
        self.n_same_place = 0
        self.received_closures = 0
        self.received_correct = 0
        self.wrong: list[dict[str, Any]] = []
        self.stage_removed: dict[str, list[int]] = {}
        self.stages = {
            s: {"in": 0, "removed": 0, "removed_true": 0, "kept_false": 0} for s in STAGES
        }
        self.graph_dropped: dict[tuple[int, int], bool] = {}

        # Association before and after the world changed: split at the median time of
        # the changes (vanishing, appearing, moving) that happen during the mission.
        self.end = float(true[-1, 0])
        events = np.concatenate([world.died, world.moved_at, world.born[world.born > 0]])
        events = events[events <= self.end]
        self.t_change = float(np.median(events)) if len(events) else self.end
        self.by_half = {
            h: {"closures": 0, "correct": 0, "true_pairs": 0, "found": 0} for h in HALVES
        }
        self.assoc_seconds: list[float] = []
        self.graph: GraphResult | None = None
        self.drift = np.zeros((3, 3))
        self.prev_k: int | None = None
        self.prev_uid: int | None = None
        self.counter = 0
        self.k = 0

    # --- queries -------------------------------------------------------------------------

    @property
    def steps(self) -> int:
        """Route steps of the mission."""
        return len(self.route)

    @property
    def done(self) -> bool:
        """Whether every route step has been processed."""
        return self.k >= len(self.route)

    def time_of(self, k: int) -> float:
        """Mission time of route step ``k`` (clipped to the route)."""
        return float(self.route[min(max(k, 0), len(self.route) - 1), 0])

    def position(self) -> F64:
        """The robot's true (x, y) at its last processed step (its start before any)."""
        return np.asarray(self.route[max(self.k - 1, 0), 1:3], dtype=np.float64)

    def wanted_regions(self, horizon: float) -> list[int]:
        """The regions the route visits in the next ``horizon`` seconds, in the order of
        their first visit, the current one first."""
        k = max(self.k - 1, 0)
        t = self.route[:, 0]
        last = int(np.searchsorted(t, t[k] + horizon, side="right"))
        seen: dict[int, None] = {}
        for r in self.region_of_step[k:last].tolist():
            seen.setdefault(int(r), None)
        return list(seen)

    def stored_pose(self, uid: int) -> Pose | None:
        """The pose ``uid`` from whichever of the store's layers holds it."""
        p = self.store.local.poses.get(uid)
        if p is not None:
            return p
        for layer in self.store.received.values():
            p = layer.poses.get(uid)
            if p is not None:
                return p
        return None

    def all_poses(self) -> dict[int, Pose]:
        """Every pose the store holds: the local layer's, then each received layer's."""
        if not self.store.received:
            return self.store.local.poses
        out = dict(self.store.local.poses)
        for source in sorted(self.store.received):
            out.update(self.store.received[source].poses)
        return out

    def _candidates(self) -> list[Pose]:
        out = list(self.store.local.poses.values())
        for source in sorted(self.store.received):
            out.extend(self.store.received[source].poses.values())
        return out

    def believed(self, k: int | npt.NDArray[np.intp]) -> F64:
        """The robot's belief of route step ``k``'s pose: dead reckoning from its start."""
        return compose(self.start_believed, compose(invert(self.odo[0, 1:4]), self.odo[k, 1:4]))

    def _origin_any(self, uid: int) -> int | None:
        o = origin_of(uid, self.truth, self.made)
        if o is None and self.peers_truth is not self.truth:
            o = origin_of(uid, self.peers_truth, self.peers_made)
        return o

    def _true_of(self, uid: int) -> F64:
        return self.truth[uid] if uid in self.truth else self.peers_truth[uid]

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

    # --- the robot -----------------------------------------------------------------------

    def batch(self) -> GraphResult:
        """One batch of the global map (every layer's poses, our oldest the anchor),
        noting the closures the graph drops."""
        graph, dropped = _optimise(self.store)
        for c in dropped:
            self.graph_dropped[(c.a, c.b)] = self.correct(c)
        self.graph = graph
        return graph

    def advance_to(self, t: float) -> int:
        """Process every route step up to mission time ``t``; the poses made."""
        n = 0
        while not self.done and self.route[self.k, 0] <= t:
            n += self.step() is not None
        return n

    def step(self) -> Pose | None:
        """Process route step :attr:`k` and move on: the pose made there, if one is."""
        k = self.k
        self.k += 1
        cfg, odo, true, store = self.cfg, self.odo, self.route, self.store
        prev_k, prev_uid = self.prev_k, self.prev_uid
        if prev_k is not None:
            d = odo[k, 1:3] - odo[prev_k, 1:3]
            turn = abs(math.remainder(odo[k, 3] - odo[prev_k, 3], 2 * math.pi))
            if (
                math.hypot(d[0], d[1]) < cfg.pose_every
                and turn < cfg.pose_turn
                and k < len(true) - 1
            ):
                return None
        t = float(true[k, 0])
        uid = make_uid(self.robot, self.counter)
        self.counter += 1
        # The odometry since the previous pose, which the store keeps until this one.
        step = None
        estimate = self.believed(k)
        if prev_uid is not None and prev_uid in store.local.poses:
            assert prev_k is not None
            step = compose(invert(odo[prev_k, 1:4]), odo[k, 1:4])
            estimate = compose(store.local.poses[prev_uid].estimate, step)
        lo = -1 if prev_k is None else prev_k
        step_of = self.step_of
        mine = np.flatnonzero((step_of > lo) & (step_of <= k))
        local = _local_map(
            _sonar_in_pose_frame(
                self.readings.take(mine), self.mounts[mine], step_of[mine], odo[:, 1:4], k
            ),
            self.rig,
            cfg,
        )
        landmarks = observe(self.world, true[k, 1:4], t, seed=self.seed)
        region = region_of(self.labels, self.prior.grid, float(estimate[0]), float(estimate[1]))
        pose = Pose(uid, t, region, estimate, landmarks, local)
        self.truth[uid] = true[k, 1:4].copy()
        self.odo_poses[uid] = self.believed(k)
        self.made[uid] = pose

        edge = None
        if step is not None:
            assert prev_k is not None
            assert prev_uid is not None
            cov = odometry_covariance(odo, prev_k, k, ODOMETRY_NOISE)
            edge = OdometryEdge(
                prev_uid,
                uid,
                (float(step[0]), float(step[1]), float(step[2])),
                tuple(float(v) for v in cov.ravel()),
                cfg.max_speed * (t - float(true[prev_k, 0])) + 0.05,
            )
        if edge is not None:
            assert step is not None
            assert prev_uid is not None
            self.drift = compose_covariance(
                store.local.poses[prev_uid].estimate, self.drift, step, edge.cov()
            )
        own = list(store.local.poses.values())
        stored = self._candidates()
        t0 = time.perf_counter()
        # Received poses have no odometry link to ours: no prior, only the hard checks.
        priors = _priors(own, estimate, t, self.drift, cfg)
        closures, stats = associate(pose, stored, priors, cfg.association)
        mine_closures = [c for c in closures if c.a in store.local.poses]
        if mine_closures:
            best = max(mine_closures, key=lambda c: c.inliers)
            pose.estimate = compose(store.local.poses[best.a].estimate, best.transform)
            self.drift = best.cov() + CANDIDATE_COV
        self.assoc_seconds.append(time.perf_counter() - t0)
        self._score_association(pose, stored, closures, stats, t)
        store.add_own_pose(pose, edge, closures, t)
        for p in store.local.poses.values():
            self.made.setdefault(p.uid, p)
        self.bytes_per_pose.append(store.bytes())
        self.local_bytes_per_pose.append(store.local.bytes())
        if self.record:
            self.frames.append(
                _frame(store, t, true[k, 1:3], self.believed(k)[:2], self.bytes_per_pose[-1])
            )
        self.prev_k, self.prev_uid = k, uid
        if self.counter % cfg.batch == 0:
            self.batch()
        return pose

    def _score_association(
        self,
        pose: Pose,
        stored: list[Pose],
        closures: list[ClosureEdge],
        stats: AssociationStats,
        t: float,
    ) -> None:
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
        for c in closures:
            self.n_same_place += same_landmarks(c, self.stored_pose(c.a), pose)
            right = self.correct(c)
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

    def receive(self, source: int, pose: Pose) -> list[ClosureEdge]:
        """Associate a pose received from robot ``source`` with every pose the store
        holds, without priors (its estimate is in its source's frame, with no odometry
        link to ours). The closures are returned for the store to keep with the pose
        (:meth:`RobotStore.add_received_pose`); the caller adds it. Counted in
        ``received_closures`` / ``received_correct``, not in the own poses' scores."""
        stored = [p for p in self._candidates() if p.uid != pose.uid]
        closures, _ = associate(pose, stored, None, self.cfg.association)
        self.received_closures += len(closures)
        self.received_correct += sum(self.correct(c) for c in closures)
        return closures

    # --- state -------------------------------------------------------------------------

    #: Attributes kept as plain msgpack values in :meth:`state`.
    PLAIN_STATE = (
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

    def state(self) -> dict[str, Any]:
        """Where the agent is on its route and what it has counted, as plain msgpack
        values (:meth:`restore`); the store has its own (:meth:`RobotStore.state`)."""
        d: dict[str, Any] = {name: getattr(self, name) for name in self.PLAIN_STATE}
        d["truth"] = [[u, [float(v) for v in x]] for u, x in self.truth.items()]
        d["odo_poses"] = [[u, [float(v) for v in x]] for u, x in self.odo_poses.items()]
        d["made"] = [encode(p) for p in self.made.values()]
        d["graph_dropped"] = [[k[0], k[1], v] for k, v in self.graph_dropped.items()]
        d["drift"] = [float(v) for v in np.asarray(self.drift).ravel()]
        return d

    def restore(self, d: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`. :attr:`made` becomes a new dict: views over it
        (``peers_made``, a :class:`~.naive.NaiveMeter`'s ``made``) must be renewed."""
        for name in self.PLAIN_STATE:
            setattr(self, name, d[name])
        self.truth = {int(u): np.array(x, dtype=np.float64) for u, x in d["truth"]}
        self.odo_poses = {int(u): np.array(x, dtype=np.float64) for u, x in d["odo_poses"]}
        made = [decode_as(b, Pose) for b in d["made"]]
        self.made = {p.uid: p for p in made}
        self.graph_dropped = {(int(x), int(y)): bool(v) for x, y, v in d["graph_dropped"]}
        self.drift = np.array(d["drift"], dtype=np.float64).reshape(3, 3)

    def run(self, progress: Progress | None = None) -> None:
        """Process the rest of the route, alone."""
        n = len(self.route)
        while not self.done:
            if progress is not None:
                progress(self.k + 1, n)
            self.step()

    # --- the end -------------------------------------------------------------------------

    def finish(self) -> MissionResult:
        """The last batch, the global map from every layer, its alignment to the prior,
        and the scores (:func:`run_mission`'s summary)."""
        cfg, store, truth, odo = self.cfg, self.store, self.truth, self.odo
        plan, rig, readings, step_of = self.plan, self.rig, self.readings, self.step_of
        t_batch = time.perf_counter()
        graph = self.batch()
        poses = self.all_poses()
        built = fuse_local_maps(
            poses,
            graph.estimates,
            grid_around(graph.estimates, cfg.local_size / 2, cfg.map_resolution, margin=1.0),
        )
        batch_seconds = time.perf_counter() - t_batch
        stages = self.stages
        stages["graph"] = {
            "in": self.n_closures,
            "removed": len(self.graph_dropped),
            "removed_true": sum(self.graph_dropped.values()),
            "kept_false": sum(not self.correct(c) for c in store.closures),
        }
        # The robot believes its frame is the prior's (it started where it thinks).
        alignment = align_to_prior(built, self.prior, seed=cfg.seed, guess=(0.0, 0.0, 0.0))
        a = np.asarray(alignment.transform, dtype=np.float64)
        a_true = self.a_true

        kept = {u: origin_of(u, truth, self.made) for u in store.local.poses}
        uids = [u for u, o in kept.items() if o is not None]
        est = np.array([graph.estimates[u] for u in uids])
        tru = np.array([truth[kept[u]] for u in uids])  # type: ignore[index]
        odo_est = np.array([self.odo_poses[kept[u]] for u in uids])  # type: ignore[index]
        # How far the found alignment puts the robot's poses from where the true one would.
        placed = compose(a, est)
        should = compose(a_true, est)
        align_m = float(np.mean(np.hypot(*(placed[:, :2] - should[:, :2]).T)))
        align_deg = math.degrees(abs(math.remainder(a[2] - a_true[2], 2 * math.pi)))

        # The map in the plan's frame, by the found alignment, against its bounds: the
        # same readings mapped at the true poses and at the odometry poses (given the
        # true start).
        in_prior = {u: compose(a, graph.estimates[u]) for u in poses if u in graph.estimates}
        global_map = fuse_local_maps(poses, in_prior, plan.grid)
        true_posed = build_map(readings, rig, plan.grid, cfg.mapper, cfg.mapper_params)
        odo_world = compose(
            a_true,
            compose(self.start_believed, compose(invert(odo[0, 1:4]), odo[step_of, 1:4])),
        )
        odo_sonar = compose(odo_world, self.mounts)
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
        assoc = np.array(self.assoc_seconds)
        changes: dict[str, Any] = dict(
            landmark_changes(self.world, store, self.made, truth, self.end)
        )
        changes["change_time_s"] = self.t_change
        for h, row in self.by_half.items():
            changes[f"association_{h}"] = {
                "closures": row["closures"],
                "precision": row["correct"] / row["closures"] if row["closures"] else math.nan,
                "recall": row["found"] / row["true_pairs"] if row["true_pairs"] else math.nan,
            }
        n_closures, counter, labels = self.n_closures, self.counter, self.labels
        summary: dict[str, Any] = {
            "robot": self.robot,
            "store_bytes_peak": int(store.peak_bytes),
            "store_bytes_final": int(store.bytes()),
            "local_bytes_peak": int(store.peak_local_bytes),
            # The configured bound of the local layer: every region of the prior full,
            # plus the newest pose, which region compression never removes.
            "local_bytes_bound": int(
                (int(labels.max()) + 1) * store.params.region_limit + store.params.pose_limit
            ),
            "closure_bytes_final": int(store.closure_bytes()),
            "poses": len(store.local.poses),
            "poses_made": counter,
            "landmarks": int(sum(len(p.landmarks) for p in store.local.poses.values())),
            "closures": len(store.closures),
            "regions": int(labels.max()) + 1,
            "regions_used": len({p.region for p in store.local.poses.values()}),
            "association_precision": self.n_correct / n_closures if n_closures else math.nan,
            "association_recall": self.n_found / self.n_true_pairs
            if self.n_true_pairs
            else math.nan,
            "association_precision_landmarks": self.n_same_place / n_closures
            if n_closures
            else math.nan,
            "closures_found": n_closures,
            "closures_correct": self.n_correct,
            "closures_wrong": self.wrong,
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
            "alignment_error_m": align_m,
            "alignment_error_deg": align_deg,
            "alignment_score_m": float(alignment.score),
            "association_ms_median": float(np.median(assoc) * 1e3) if len(assoc) else math.nan,
            "association_ms_p99": float(np.percentile(assoc, 99) * 1e3) if len(assoc) else math.nan,
            "pose_interval_s": float(cfg.duration / max(counter, 1)),
            "global_map_batch_s": batch_seconds,
            "sim_seconds": float(self.route[-1, 0] - self.route[0, 0]),
            "wall_seconds": time.perf_counter() - self.wall0,
            "seed": cfg.seed,
            "parameters": _parameters(cfg),
        }
        return MissionResult(
            cfg,
            summary,
            global_map,
            store,
            graph,
            alignment,
            truth,
            self.odo_poses,
            self.bytes_per_pose,
            self.frames,
            self.local_bytes_per_pose,
        )


def run_mission(
    plan: OccupancyMap,
    config: MissionConfig | None = None,
    *,
    prior: OccupancyMap | None = None,
    route: F64 | None = None,
    world: World | None = None,
    robot: int = 0,
    progress: Progress | None = None,
    record: bool = False,
) -> MissionResult:
    """Run robot ``robot``'s mission on the floor ``plan``.

    The prior map is the plan unless ``prior`` is given; ``world`` (landmarks) is made
    from the seed unless given; ``route`` (T, 4: t, x, y, theta) replaces the patrol
    route (random waypoints drawn from the seed and the robot's number). ``record``
    keeps a :class:`~sonarmap.team.animation.Frame` per pose made, for an animation.
    A thin loop over a :class:`RobotAgent`.
    """
    agent = RobotAgent(
        plan, config, prior=prior, route=route, world=world, robot=robot, record=record
    )
    agent.run(progress)
    return agent.finish()


def _frame(store: RobotStore, t: float, truth: F64, odometry: F64, size: int) -> Frame:
    poses = store.local.poses
    est = np.array([p.estimate[:2] for p in poses.values()]).reshape(-1, 2)
    seg = [
        (*poses[c.a].estimate[:2], *poses[c.b].estimate[:2])
        for c in store.closures
        if c.a in poses and c.b in poses
    ]
    return Frame(
        t, truth.copy(), odometry.copy(), est, np.array(seg, dtype=np.float64).reshape(-1, 4), size
    )


def _parameters(cfg: MissionConfig) -> dict[str, Any]:
    d = asdict(cfg)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}
