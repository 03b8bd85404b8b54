"""One robot's mission, end to end: drive a route through the simulated world, make a
pose every metre or so (stereo landmarks and a local sonar map), associate it with the
store, keep the store under its memory bounds, optimise the pose graph in batches, fuse
and align the global map, and score every estimate against the simulation's truth.

Decisions where the thesis is silent:

- **Frames.** The robot knows its start in the prior map only roughly (``start_error``:
  1 m and 10 degrees, drawn with the seed); its global frame is its odometry frame
  started there. The alignment to the prior map must find the rest; its guess is that
  belief, weighed about the believed start (:meth:`RobotAgent.align`).
- **When a pose is made**: after ``pose_every`` metres (1.0) or ``pose_turn`` radians
  (0.5) of odometry since the last pose.
- **The local map** of a pose is built by a sonarmap mapper (``mapper``: the inverse
  model) from the sonar readings taken since the previous pose, placed in the pose's
  frame by odometry, on a square of ``local_size`` metres (6) at ``local_resolution``
  (0.1 m). Only readings up to ``mapping_range`` (3 m) are used, and the inverse model
  takes ``mapper_params`` (p_occ 0.6, p_free 0.45, a 20-degree fall-off, a 5 cm band
  centred on the echo); the band lies 0.75 cell behind
  the echo, the inverse mapper's default (a cell counts as wall when its centre is
  inside one). Chosen on four training buildings
  (docs/results/2026-12-03-team-code-notes.md).
- **Odometry edges** carry the odometry model's covariance and the hard bound top
  speed x elapsed time (``max_speed``, 1.0 m/s: twice the route's speed).
- **Odometry calibration.** A robot alone (:func:`run_mission`) estimates its
  odometry's heading bias (rad per metre) on each batch's graph, applies it only when
  it is significant, and stores its edges corrected by it (:mod:`.calibration`). A
  :class:`RobotAgent` does not unless asked (``calibrate=True``): a team's robots must
  not change edges they have offered. The edges' covariance counts the bias the robot
  does not know as noise (:func:`~.world.odometry_covariance`): its prior
  (:data:`~.calibration.HEADING_BIAS_PRIOR`) by default, calibrating or not, since it
  also covers heading errors the calibration does not model; ``bias_sd="remaining"``
  counts, once a batch has measured the bias, the uncertainty the calibration leaves.
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
  and the wrong closures left in the store at the end (``kept_false``) and those it
  cannot judge, a pose's true origin unknown (``kept_unscored``: a peer's merged pose
  whose merge chain the robot was not sent).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from ..api import build_map
from ..errors import InputError
from ..grid import Grid
from ..io.rosmap import OccupancyMap
from ..readings import Readings
from ..rig import Rig
from .animation import Frame
from .association import (
    Prior,
    associate,
)
from .calibration import (
    HEADING_BIAS_PRIOR,
    debias,
    debias_edges,
    gated_bias,
    heading_bias_fit,
    remaining_bias_sd,
)
from .config import MissionConfig
from .evaluation import MissionEvaluator
from .globalmap import (
    Alignment,
    GraphResult,
    align_to_prior,
    fuse_local_maps,
    grid_around,
    optimise_graph,
)
from .layergate import LayerPlacement, gate_closures, layer_placements
from .pcm import LayerChain, pcm_gate
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
from .regions import mission_regions, region_of, region_sizes
from .sensing import RobotSensing
from .store import RobotStore, local_bound, region_limits
from .territory import mask_on
from .world import (
    ODOMETRY_MODEL,
    World,
    make_world,
    odometry_covariance,
)

__all__ = [
    "BIAS_SD_CHOICES",
    "GUESS_SIGMAS",
    "BiasSd",
    "MissionConfig",
    "MissionResult",
    "RobotAgent",
    "run_mission",
]

#: The heading-bias standard deviation a calibrating robot's odometry edges carry
#: (:class:`RobotAgent`'s ``bias_sd``).
BiasSd = Literal["remaining", "prior"]
BIAS_SD_CHOICES: tuple[BiasSd, ...] = ("prior", "remaining")

F64 = npt.NDArray[np.float64]
Progress = Callable[[int, int], None]

#: The alignment's guess weighs places by a Gaussian this many standard deviations of
#: the start's error wide (3 m and 30 degrees by default): wide enough that a start
#: two deviations off still weighs 0.8 (the guess only breaks ties between alike
#: places), narrow enough that an alike room a building away does not tie.
GUESS_SIGMAS = 3.0


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
    n = config.local_cells()
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


def _optimise(store: RobotStore) -> tuple[GraphResult, list[ClosureEdge]]:
    """One batch of the global map: optimise, move every pose's estimate, drop the
    closures the result finds inconsistent (returned)."""
    if not store.received:
        # Started from the current estimates, which closures keep near the truth:
        # chained odometry drifts metres over an hour, and from there GNC rejected
        # hundreds of correct closures on a long mission.
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
    """One simulated robot on its mission, one route step at a time: the robot, the
    world simulator of its sensors (:class:`~.sensing.RobotSensing`, :attr:`sensing`)
    and the evaluator that scores it (:class:`~.evaluation.MissionEvaluator`,
    :attr:`evaluator`), which the robot tells what it did through its observer hooks
    and never asks.

    The robot makes its poses (:meth:`step`) from odometry, associates each one with
    every pose its store holds (its own and those received from other robots),
    optimises the pose graph every ``batch`` poses, associates the poses other robots
    send it (:meth:`receive`, an :class:`~sonarmap.team.exchange.Exchanger`'s
    ``on_received``) and, at the end, fuses and aligns the global map (:meth:`finish`,
    which also has it scored).

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
    calibrate : bool
        Calibrate the odometry's heading bias from the pose graph (:meth:`batch`,
        :mod:`.calibration`; False). Only for a robot that offers its edges to no other:
        a team's robots keep False, since an edge offered must stay the copy the others
        hold. :func:`run_mission` passes True.
    odometry_noise : mapping of str to float, optional
        The simulator's odometry noise (:func:`~.world.odometry`'s keywords; default
        :data:`~.world.ODOMETRY_NOISE`). The robot's own model of it, for the edges'
        covariance, stays :data:`~.world.ODOMETRY_MODEL` and :attr:`heading_bias_sd`:
        to test the calibration against an odometry it does not expect.
    bias_sd : {"prior", "remaining"}
        The heading-bias standard deviation a calibrating robot's new odometry edges
        carry after its first batch (:attr:`heading_bias_sd`): ``"prior"`` (default) the
        prior :data:`~.calibration.HEADING_BIAS_PRIOR` throughout, whose larger variance
        also covers heading errors the calibration does not model (wheel base, per
        turn); ``"remaining"`` what the calibration leaves
        (:func:`~.calibration.remaining_bias_sd`). The bias estimate corrects the edges
        either way.
    territory : ndarray of bool, optional
        The mission's territory mask on the plan's cells (:mod:`.territory`): the
        prior's regions are cut inside it (:func:`~.regions.mission_regions`; on the
        prior's cells by :func:`~.territory.mask_on`). Default None: the whole prior.

    Attributes
    ----------
    store : RobotStore
    made : dict of int to Pose
        Every pose the robot made or merged, by UID.
    route : ndarray (T, 4)
        The route (the patroller's plan; the simulator drives it truly).
    region_of_step : ndarray of int (T,)
        The prior map's region of each route step.
    k : int
        The next route step :meth:`step` processes.
    heading_bias : float
        The odometry's heading bias as estimated so far, rad per metre (0 until a batch
        measures it): every own odometry edge in the store, and each new one, is
        corrected by it.
    heading_bias_sd : float
        The robot's uncertainty about the heading bias left in a new odometry edge, rad
        per metre, which its covariance counts (:func:`~.world.odometry_covariance`):
        the prior :data:`~.calibration.HEADING_BIAS_PRIOR`, or with
        ``bias_sd="remaining"``, once a calibrating batch has measured it, what the
        calibration leaves (:func:`~.calibration.remaining_bias_sd`). Edges already
        stored keep theirs.
    calibration_batches : int
        The batches whose graph the calibration fitted (0 unless ``calibrate``).
    calibration_batches_applied : int
        Of those, the batches that ended with a nonzero :attr:`heading_bias`: a batch
        counts whenever a bias is applied after it, whether its own fit passed the
        significance gate or it kept one applied earlier (too few batches to fit), so
        one early firing that is never taken back counts in every later batch; not the
        number of times the gate fired.
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
        calibrate: bool = False,
        odometry_noise: Mapping[str, float] | None = None,
        bias_sd: BiasSd = "prior",
        territory: npt.NDArray[np.bool_] | None = None,
    ) -> None:
        if bias_sd not in BIAS_SD_CHOICES:
            raise InputError(
                f"bias_sd {bias_sd!r} is not one of {', '.join(BIAS_SD_CHOICES)}", field="bias_sd"
            )
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
        self.calibrate = calibrate
        self.bias_sd: BiasSd = bias_sd
        world = make_world(plan, seed=cfg.seed, duration=cfg.duration) if world is None else world
        self.world = world
        self.sensing = sensing = RobotSensing(
            plan, cfg, world, robot, route, odometry_noise=odometry_noise
        )
        self.seed = sensing.seed
        self.route = sensing.route
        self.odo = sensing.odometry()
        self.rig = sensing.rig
        self.start_believed = sensing.start_believed
        inside = None if territory is None else mask_on(territory, plan.grid, prior.grid)
        self.labels = mission_regions(prior, region=inside)
        self.region_of_step: npt.NDArray[np.intp] = np.array(
            [region_of(self.labels, prior.grid, float(x), float(y)) for x, y in self.route[:, 1:3]],
            dtype=np.intp,
        ).reshape(-1)

        self.region_areas = region_sizes(self.labels, prior.grid.resolution).tolist()
        self.store = RobotStore(robot, cfg.store, self.region_areas)
        self.made: dict[int, Pose] = {}
        self.evaluator = MissionEvaluator(sensing, cfg, world, lambda: self.made)
        self.bytes_per_pose: list[int] = []
        self.local_bytes_per_pose: list[int] = []
        self.frames: list[Frame] = []
        self.assoc_seconds: list[float] = []
        self.graph: GraphResult | None = None
        self.drift = np.zeros((3, 3))
        #: The drift each stored own pose was made with (3 x 3, by UID).
        self.drift_of: dict[int, F64] = {}
        #: Where each received layer lies in our frame, as of the last batch (by source).
        self.placements: dict[int, LayerPlacement] = {}
        self.prev_k: int | None = None
        self.prev_uid: int | None = None
        self.heading_bias = 0.0
        self.heading_bias_sd = HEADING_BIAS_PRIOR
        self.calibration_batches = 0
        self.calibration_batches_applied = 0
        self.counter = 0
        self.k = 0

    # --- the evaluator's views -----------------------------------------------------------

    @property
    def truth(self) -> dict[int, F64]:
        """The true pose (x, y, theta) of each pose the robot made, by UID (the
        evaluator's)."""
        return self.evaluator.truth

    @property
    def odo_poses(self) -> dict[int, F64]:
        """Each pose's dead-reckoning estimate (the evaluator's)."""
        return self.evaluator.odo_poses

    @property
    def peers_truth(self) -> Mapping[int, F64]:
        """Where the scoring looks up other robots' true poses (a team passes a view
        over every robot's)."""
        return self.evaluator.peers_truth

    @peers_truth.setter
    def peers_truth(self, view: Mapping[int, F64]) -> None:
        self.evaluator.peers_truth = view

    @property
    def peers_made(self) -> Mapping[int, Pose]:
        """Where the scoring looks up other robots' poses as made."""
        view = self.evaluator.peers_made
        return self.made if view is None else view

    @peers_made.setter
    def peers_made(self, view: Mapping[int, Pose]) -> None:
        self.evaluator.peers_made = view

    @property
    def received_closures(self) -> int:
        """Closures found for received poses."""
        return self.evaluator.received_closures

    @property
    def received_correct(self) -> int:
        """Of :attr:`received_closures`, the right ones."""
        return self.evaluator.received_correct

    def correct(self, c: ClosureEdge) -> bool:
        """Whether a closure's transform is within the tolerance of the true one."""
        return self.evaluator.correct(c)

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

    def align(
        self, built: OccupancyMap, *, seed: int | None = None, coarse_resolution: float = 0.1
    ) -> Alignment:
        """The map ``built`` (in this robot's global frame) aligned to its prior map,
        the guess being the robot's belief: its frame is the prior's, its start where it
        believes it.

        The guess's weight is :data:`GUESS_SIGMAS` standard deviations of the start's
        error (``MissionConfig.start_error``) wide, about the believed start: a start
        heading off by ``d`` moves the expected map by ``d`` times its distance from
        the start (:func:`~.globalmap.align_to_prior`'s ``guess_start``).

        Parameters
        ----------
        built : OccupancyMap
            The fused map, in this robot's global frame.
        seed : int, optional
            The alignment's; default the mission's.
        coarse_resolution : float
            Metres: the correlation's cell (0.1).

        Returns
        -------
        Alignment
        """
        cfg = self.cfg
        start = (float(self.start_believed[0]), float(self.start_believed[1]))
        return align_to_prior(
            built,
            self.prior,
            seed=cfg.seed if seed is None else seed,
            guess=(0.0, 0.0, 0.0),
            guess_sigma=(GUESS_SIGMAS * cfg.start_error[0], GUESS_SIGMAS * cfg.start_error[1]),
            guess_start=start,
            coarse_resolution=coarse_resolution,
        )

    # --- the robot -----------------------------------------------------------------------

    def batch(self) -> GraphResult:
        """One batch of the global map (every layer's poses, our oldest the anchor); the
        closures the graph drops are told to the evaluator. With ``MissionConfig.pcm``
        the closures go through pairwise consistency first (:meth:`_pcm`)."""
        if self.cfg.pcm:
            self._pcm()
        graph, dropped = _optimise(self.store)
        self.evaluator.dropped(dropped)
        self.graph = graph
        if self.calibrate:
            self._calibrate(graph)
        if self.cfg.layer_gate and self.store.received:
            self.placements = layer_placements(
                {u: p.estimate for u, p in self.store.local.poses.items()},
                {
                    s: {u: p.estimate for u, p in layer.poses.items()}
                    for s, layer in self.store.received.items()
                },
                self.store.closures,
            )
        return graph

    def _pcm(self) -> None:
        """Leave out the closures pairwise consistency rejects (:func:`~.pcm.pcm_gate`,
        every layer's loops through its own odometry, each closure judged once), remember
        them in the store so that no peer brings them back
        (:meth:`~.store.RobotStore.reject_closures`) and those kept so that they are not
        judged again (:meth:`~.store.RobotStore.keep_judged`), and tell the evaluator
        those rejected for the first time."""
        store = self.store
        layers = {self.robot: store.local, **store.received}
        layer_of = {u: s for s, layer in layers.items() for u in layer.poses}
        result = pcm_gate(
            store.closures,
            layer_of,
            {s: LayerChain(layer.edges) for s, layer in layers.items()},
            frozen=store.judged_pairs,
        )
        new: list[ClosureEdge] = []
        if result.rejected:
            store.closures = result.kept
            new = store.reject_closures(result.rejected)
        store.keep_judged(result.newly_kept)
        loops = {
            "judged": result.judged,
            "loops_tested": result.loops_tested,
            "loops_untestable": result.loops_untestable,
        }
        self.evaluator.pcm(new, store.local.poses.keys(), loops)

    def _calibrate(self, graph: GraphResult) -> None:
        """Add the heading bias the optimised ``graph`` still shows on the own odometry
        edges (:func:`~.calibration.heading_bias_fit`) to :attr:`heading_bias`, or set
        it to 0 when the total is not significant, or leave it when the fit has too few
        batches (:func:`~.calibration.gated_bias`), and correct every stored edge by the
        change, so that every edge carries the same calibration (compression composes
        them)."""
        layer = self.store.local
        fit = heading_bias_fit(layer.edges, graph.estimates)
        new = gated_bias(self.heading_bias, fit)
        if self.bias_sd == "remaining":
            self.heading_bias_sd = remaining_bias_sd(self.heading_bias, fit, new)
        # Records are replaced, not edited: the layer re-measures their bytes.
        layer.edges = debias_edges(layer.edges, new - self.heading_bias)
        self.heading_bias = new
        self.calibration_batches += 1
        self.calibration_batches_applied += new != 0.0

    def _gate(
        self, closures: list[ClosureEdge], new: Pose, source: int | None, drift: F64 | None
    ) -> list[ClosureEdge]:
        """The closures of pose ``new`` (of layer ``source``, None for our own) that
        pass the layer gate; those between two layers that disagree with where the robot
        places the layers are told to the evaluator and left out. ``drift`` is the
        covariance of an own new pose's estimate (None: a stored pose's, whose spread the
        placements already hold)."""
        if not self.cfg.layer_gate or not self.placements:
            return closures
        store = self.store
        placed: dict[int, tuple[F64, F64]] = {}

        def place(uid: int, layer: int | None, estimate: F64, extra: F64 | None) -> None:
            if layer is None:
                placed[uid] = (estimate, np.zeros((3, 3)) if extra is None else extra)
            elif layer in self.placements:
                placed[uid] = self.placements[layer].place(estimate)

        place(new.uid, source, new.estimate, drift)
        inter = []
        for c in closures:
            if c.a in store.local.poses:
                layer = None
                if source is None:
                    continue
                place(c.a, layer, store.local.poses[c.a].estimate, None)
            else:
                held = next((s for s, x in store.received.items() if c.a in x.poses), None)
                if held is None or held == source:
                    continue
                place(c.a, held, store.received[held].poses[c.a].estimate, None)
            inter.append(c)
        _, rejected = gate_closures(inter, placed)
        if not rejected:
            return closures
        gone = {id(c) for c in rejected}
        self.evaluator.gated(rejected, own=source is None)
        return [c for c in closures if id(c) not in gone]

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
        cfg, odo, route, store = self.cfg, self.odo, self.route, self.store
        prev_k, prev_uid = self.prev_k, self.prev_uid
        if prev_k is not None:
            d = odo[k, 1:3] - odo[prev_k, 1:3]
            turn = abs(math.remainder(odo[k, 3] - odo[prev_k, 3], 2 * math.pi))
            if (
                math.hypot(d[0], d[1]) < cfg.pose_every
                and turn < cfg.pose_turn
                and k < len(route) - 1
            ):
                return None
        t = float(route[k, 0])
        uid = make_uid(self.robot, self.counter)
        self.counter += 1
        # The odometry since the previous pose, which the store keeps until this one.
        step: F64 | None = None
        estimate = self.believed(k)
        if prev_uid is not None and prev_uid in store.local.poses:
            assert prev_k is not None
            # The store composes edges and carries closures through them when it
            # deletes a pose, so a bias left in for the graph to fix would stay there.
            measured = compose(invert(odo[prev_k, 1:4]), odo[k, 1:4])
            step = np.array(debias(measured, self.heading_bias), dtype=np.float64)
            estimate = compose(store.local.poses[prev_uid].estimate, step)
        readings, mounts, steps = self.sensing.readings_up_to(-1 if prev_k is None else prev_k, k)
        local = _local_map(
            _sonar_in_pose_frame(readings, mounts, steps, odo[:, 1:4], k), self.rig, cfg
        )
        landmarks = self.sensing.landmarks_at(k)
        region = region_of(self.labels, self.prior.grid, float(estimate[0]), float(estimate[1]))
        pose = Pose(uid, t, region, estimate, landmarks, local)
        self.evaluator.pose_made(k, pose, self.believed(k))
        self.made[uid] = pose

        edge = None
        if step is not None:
            assert prev_k is not None
            assert prev_uid is not None
            cov = odometry_covariance(odo, prev_k, k, ODOMETRY_MODEL, bias_sd=self.heading_bias_sd)
            edge = OdometryEdge(
                prev_uid,
                uid,
                (float(step[0]), float(step[1]), float(step[2])),
                tuple(float(v) for v in cov.ravel()),
                cfg.max_speed * (t - float(route[prev_k, 0])) + 0.05,
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
            # The candidate's own drift since the closure before it, not a fresh start:
            # a closure to the pose made a second ago (most closures are) says nothing
            # of the drift since the last revisit, and a reset to CANDIDATE_COV let the
            # gate refuse the true revisit closures that came after.
            held = self.drift_of.get(best.a, np.zeros((3, 3)))
            via = compose_covariance(
                store.local.poses[best.a].estimate,
                held,
                best.transform,
                best.cov() + CANDIDATE_COV,
            )
            if np.trace(via) < np.trace(self.drift):
                self.drift = via
        # Closures to received poses have no odometry prior: the layer gate judges them.
        closures = self._gate(closures, pose, None, self.drift)
        self.assoc_seconds.append(time.perf_counter() - t0)
        self.evaluator.associated(pose, stored, closures, stats, t)
        store.add_own_pose(pose, edge, closures, t)
        self.drift_of[uid] = self.drift.copy()
        for gone in set(self.drift_of) - set(store.local.poses):
            del self.drift_of[gone]
        for p in store.local.poses.values():
            self.made.setdefault(p.uid, p)
        self.bytes_per_pose.append(store.bytes())
        self.local_bytes_per_pose.append(store.local.bytes())
        if self.record:
            self.frames.append(
                _frame(
                    store,
                    t,
                    self.sensing.true_pose(k)[:2],
                    self.believed(k)[:2],
                    self.bytes_per_pose[-1],
                )
            )
        self.prev_k, self.prev_uid = k, uid
        if self.counter % cfg.batch == 0:
            self.batch()
        return pose

    def receive(self, source: int, pose: Pose) -> list[ClosureEdge]:
        """Associate a pose received from robot ``source`` with every pose the store
        holds, without priors (its estimate is in its source's frame, with no odometry
        link to ours). The closures are returned for the store to keep with the pose
        (:meth:`RobotStore.add_received_pose`); the caller adds it. The evaluator counts
        them apart from the own poses' scores."""
        stored = [p for p in self._candidates() if p.uid != pose.uid]
        closures, _ = associate(pose, stored, None, self.cfg.association)
        closures = self._gate(closures, pose, source, None)
        self.evaluator.received(pose, closures)
        return closures

    # --- state ---------------------------------------------------------------------------

    #: Attributes kept as plain msgpack values in :meth:`state`.
    PLAIN_STATE = ("bytes_per_pose", "assoc_seconds", "prev_k", "prev_uid", "counter", "k")

    def state(self) -> dict[str, Any]:
        """Where the robot is on its route, what it made, and the evaluator's counters,
        as plain msgpack values (:meth:`restore`); the store has its own
        (:meth:`RobotStore.state`)."""
        d: dict[str, Any] = {name: getattr(self, name) for name in self.PLAIN_STATE}
        d["made"] = [encode(p) for p in self.made.values()]
        d["drift"] = [float(v) for v in np.asarray(self.drift).ravel()]
        d["heading_bias"] = float(self.heading_bias)
        d["heading_bias_sd"] = float(self.heading_bias_sd)
        d["calibration_batches"] = [self.calibration_batches, self.calibration_batches_applied]
        d["drift_of"] = [[u, [float(v) for v in m.ravel()]] for u, m in self.drift_of.items()]
        # The layers' placements as of the last batch: a restarted node must gate as the
        # robot did, not as a batch at restart would.
        d["placements"] = [
            [s, at.at.ravel().tolist(), at.proposals.ravel().tolist(), at.support]
            for s, at in self.placements.items()
        ]
        d.update(self.evaluator.state())
        return d

    def restore(self, d: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`. :attr:`made` and :attr:`truth` become new dicts:
        views over them (``peers_made``, ``peers_truth``, a
        :class:`~.naive.NaiveMeter`'s ``made``) must be renewed."""
        for name in self.PLAIN_STATE:
            setattr(self, name, d[name])
        made = [decode_as(b, Pose) for b in d["made"]]
        self.made = {p.uid: p for p in made}
        self.drift = np.array(d["drift"], dtype=np.float64).reshape(3, 3)
        # A state saved while calibrating, taken back by a robot that is not, must not
        # correct its edges.
        self.heading_bias = float(d.get("heading_bias", 0.0)) if self.calibrate else 0.0
        self.heading_bias_sd = (
            float(d.get("heading_bias_sd", HEADING_BIAS_PRIOR))
            if self.calibrate
            else HEADING_BIAS_PRIOR
        )
        batches, applied = d.get("calibration_batches", (0, 0)) if self.calibrate else (0, 0)
        self.calibration_batches, self.calibration_batches_applied = int(batches), int(applied)
        self.drift_of = {
            int(u): np.array(m, dtype=np.float64).reshape(3, 3) for u, m in d.get("drift_of", [])
        }
        self.placements = {
            int(s): LayerPlacement(np.array(a, dtype=np.float64), np.array(p), int(n))
            for s, a, p, n in d.get("placements", [])
        }
        self.evaluator.restore(d)

    def run(
        self,
        progress: Progress | None = None,
        on_step: Callable[[float, RobotAgent], None] | None = None,
    ) -> None:
        """Process the rest of the route, alone; ``on_step(t, self)`` after each route
        step, ``t`` its mission time (to record or serve the run)."""
        n = len(self.route)
        while not self.done:
            if progress is not None:
                progress(self.k + 1, n)
            self.step()
            if on_step is not None:
                on_step(self.time_of(self.k - 1), self)

    # --- the end -------------------------------------------------------------------------

    def finish(self) -> MissionResult:
        """The last batch, the global map from every layer and its alignment to the
        prior (the robot's), then the evaluator's scores: :func:`run_mission`'s
        summary."""
        cfg, store, plan = self.cfg, self.store, self.plan
        t_batch = time.perf_counter()
        graph = self.batch()
        poses = self.all_poses()
        built = fuse_local_maps(
            poses,
            graph.estimates,
            grid_around(graph.estimates, cfg.local_size / 2, cfg.map_resolution, margin=1.0),
        )
        batch_seconds = time.perf_counter() - t_batch
        alignment = self.align(built)
        a = np.asarray(alignment.transform, dtype=np.float64)
        # The map in the plan's frame, by the found alignment.
        in_prior = {u: compose(a, graph.estimates[u]) for u in poses if u in graph.estimates}
        global_map = fuse_local_maps(poses, in_prior, plan.grid)
        scores = self.evaluator.scores(plan, store, graph, alignment, global_map)
        assoc = np.array(self.assoc_seconds)
        counter, labels = self.counter, self.labels
        regions = int(labels.max()) + 1
        bound = local_bound(store.params, self.region_areas)
        limits = region_limits(store.params, self.region_areas)
        summary: dict[str, Any] = {
            "robot": self.robot,
            "store_bytes_peak": int(store.peak_bytes),
            "store_bytes_final": int(store.bytes()),
            "local_bytes_peak": int(store.peak_local_bytes),
            # The configured bound of the local layer (store.local_bound): every region
            # of the prior full or the store's budget, plus the newest pose.
            "local_bytes_bound": bound,
            "local_bytes_bound_by": "regions"
            if store.params.store_limit <= 0 or sum(limits) <= store.params.store_limit
            else "store_limit",
            "local_bytes_within_bound": bool(store.peak_local_bytes <= bound),
            # M_r of each region (StoreParams.region_density x its area, at least
            # region_limit): the terms of the regions' bound.
            "region_bytes_limits": limits,
            "closure_bytes_final": int(store.closure_bytes()),
            "poses": len(store.local.poses),
            "poses_made": counter,
            "landmarks": int(sum(len(p.landmarks) for p in store.local.poses.values())),
            "closures": len(store.closures),
            "regions": regions,
            "regions_used": len({p.region for p in store.local.poses.values()}),
            **scores,
            "alignment_score_m": float(alignment.score),
            # The odometry calibration's estimate at the end, rad per metre (0 when the
            # robot does not calibrate: parameters.calibrate_odometry tells which).
            "odometry_heading_bias": float(self.heading_bias),
            "association_ms_median": float(np.median(assoc) * 1e3) if len(assoc) else math.nan,
            "association_ms_p99": float(np.percentile(assoc, 99) * 1e3) if len(assoc) else math.nan,
            "pose_interval_s": float(cfg.duration / max(counter, 1)),
            "global_map_batch_s": batch_seconds,
            "sim_seconds": float(self.route[-1, 0] - self.route[0, 0]),
            "wall_seconds": time.perf_counter() - self.wall0,
            "seed": cfg.seed,
            "parameters": {**_parameters(cfg), "calibrate_odometry": self.calibrate},
        }
        return MissionResult(
            cfg,
            summary,
            global_map,
            store,
            graph,
            alignment,
            self.truth,
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
    on_step: Callable[[float, RobotAgent], None] | None = None,
    territory: npt.NDArray[np.bool_] | None = None,
) -> MissionResult:
    """Run robot ``robot``'s mission on the floor ``plan``.

    The prior map is the plan unless ``prior`` is given; ``world`` (landmarks) is made
    from the seed unless given; ``route`` (T, 4: t, x, y, theta) replaces the patrol
    route (random waypoints drawn from the seed and the robot's number). ``record``
    keeps a :class:`~sonarmap.team.animation.Frame` per pose made, for an animation;
    ``on_step(t, agent)`` is called after each route step (:meth:`RobotAgent.run`).
    ``territory`` (a mask on the plan's cells) is where the prior's regions are cut
    (:class:`RobotAgent`; None: the whole prior). A thin loop over a
    :class:`RobotAgent` that calibrates its odometry (alone, it offers its edges to no
    one).
    """
    agent = RobotAgent(
        plan,
        config,
        prior=prior,
        route=route,
        world=world,
        robot=robot,
        record=record,
        calibrate=True,
        territory=territory,
    )
    agent.run(progress, on_step)
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
