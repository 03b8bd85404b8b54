"""A team's mission in simulation: N robots (:class:`~.mission.RobotAgent`) driving
their own routes on a common clock, exchanging poses (:class:`~.exchange.Exchanger`)
over a simulated network (:class:`~.network.SimNetwork` through a
:class:`~.transport.SimHub`), each building its global map from all its layers.

Choices where the thesis is silent:

- **One world, own routes.** The robots share the world's landmarks (made from the
  mission seed); robot ``i`` drives the patrol route drawn from ``seed + ROUTE_SEED_STEP i``, or
  the route given to it (``routes``: e.g. the potential-field patroller's,
  :mod:`.patrolling`), and its sensors are seeded alike (as
  :func:`~.mission.run_mission` does for ``robot=i``).
  ``seed`` of :func:`run_team` seeds the network (losses, jitter, capacity).
- **The clock.** Ticks are the union of the routes' time stamps. At each tick every
  robot first processes its route steps up to it (poses made, associated, stored), then
  the hub moves to the tick with the robots' true positions, then each exchanger steps,
  in robot order.
- **Wanted regions.** A robot asks first for the patches of the regions its route
  visits in the next ``lookahead`` seconds (30), in the order of their first visit:
  the patroller knows its next moves (thesis l.1863-1872). Those it asks for as soon
  as a peer has them newer, the others at most every ``exchange.refresh`` seconds;
  in the quiet phase (no route, no wanted regions) every newer patch at once.
- **Quiet network.** After the routes end, the robots stand still and keep exchanging
  until no exchanger has added or deleted a pose for ``quiet`` seconds (default two
  adverts and two request rounds) and none awaits an answer, or ``settle`` seconds
  (120) have passed. ``identical_maps`` is judged then: do all robots hold the same
  pose UIDs (own and received layers together). The global maps built from them still
  differ a little, since each robot found its own closures (the closure store is never
  exchanged): ``map_agreement`` is the least, over pairs of robots, share of cells
  known in either map that both maps give the same class (free, occupied, unknown).
- **Convergence** (``convergence_s``): seconds from the end of the routes to the last
  pose added or deleted, once the network was quiet and, when every pair of robots is
  linked (``full``), every robot held every pose (``identical_maps``); None (JSON
  null) when that never happened within ``settle`` seconds. 0: nothing was left to
  exchange when the routes ended.
- **Protocols**: ``exchange.mode`` ``"good"`` or ``"limited"`` runs the thesis's
  :class:`~.exchange.Exchanger`, ``"naive"`` the baseline
  :class:`~.naive.NaiveExchanger`.
- **Team map** (``map_f1_team``): the mean of the robots' global-map F1. With
  ``central``, ``map_f1_central`` is the upper bound of :func:`~.central.central_map`
  over the same missions' data.
- **Bytes per robot-minute**: message bodies sent during the routes (not the quiet
  phase), over the robots and the routes' minutes.
- **Team frames** (``record``): a :class:`~.animation.TeamFrame` after the tick that
  reaches each multiple of ``frame_every`` seconds (2) from the first tick on, and after
  the last tick, through the routes and the quiet phase, which is short (``settle`` at
  most) and shows the last poses arriving while the robots stand still. The cadence
  widens so that the routes and ``settle`` together give at most ``max_frames`` (300)
  frames: a 600 s mission keeps one about every 2.4 s. Past ``max_frames`` the last
  frame is replaced, so the final state is always kept.
"""

from __future__ import annotations

import math
from collections import ChainMap
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..io.rosmap import OccupancyMap
from .animation import TeamFrame
from .central import CentralResult, central_map
from .config import check_team_size
from .exchange import ExchangeParams, Exchanger
from .lockstep import LockstepClock, quiet_seconds, team_ticks
from .mission import MissionConfig, MissionResult, RobotAgent
from .naive import NaiveExchanger, NaiveMeter, make_exchanger
from .network import NetworkParams, SimNetwork
from .records import Pose
from .regions import region_adjacency
from .store import RobotStore
from .summary import mission_figures, robot_row, team_figures
from .transport import SimHub
from .world import World, make_world

__all__ = ["TeamResult", "TeamTick", "held_uids", "map_agreement", "run_team"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class TeamTick:
    """The team after one tick, for an observer (``run_team(on_tick=...)``): read it,
    never change it.

    Attributes
    ----------
    t : float
        Mission time, seconds.
    driving : bool
        Whether the robots still drive their routes (False in the quiet phase).
    agents : sequence of RobotAgent
        The robots, by id.
    links : ndarray of int (K, 2)
        The network's direct links now, pairs (i, j) with i < j.
    bytes_sent : list of int
        Message bodies each robot has sent so far.
    """

    t: float
    driving: bool
    agents: Sequence[RobotAgent]
    links: I64
    bytes_sent: list[int]


@dataclass
class TeamResult:
    """What a team's mission made and measured.

    Attributes
    ----------
    summary : dict
        ``robots`` (one dict per robot: :func:`~.mission.run_mission`'s summary plus
        ``bytes_sent`` (and ``bytes_by_kind``), ``bytes_received``, ``messages``,
        ``messages_received``,
        ``poses_local``, ``poses_received``, ``received_closures``,
        ``received_closures_correct``) and the team's ``duplicate_poses``,
        ``identical_maps``, ``meetings`` and ``partings`` (direct links that came up,
        the first ones included, and went down), ``held_share_at_routes_end`` (the
        mean share of the other robots' poses each robot held when the routes ended:
        what a ``hold`` keeps back), ``convergence_s``, ``bytes_per_robot_minute``
        (message bodies sent while the robots drive), ``bytes_per_robot_minute_all``
        (with the quiet phase's, over the same minutes), ``naive_bytes_per_robot_minute``
        (what the naive baseline would have sent on the same mission,
        :class:`~.naive.NaiveMeter`; a naive run's own bytes when the baseline runs),
        ``share_of_naive`` (``bytes_per_robot_minute_all`` over it), ``map_f1_team``,
        ``map_f1_central`` (None unless asked for), ``settle_seconds``, ``settled``,
        ``robots_n``, ``network`` and ``exchange``.
    robots : list of MissionResult
        Each robot's result, by robot id.
    exchangers : list of Exchanger or NaiveExchanger
    network : SimNetwork
    held : list of set of int
        The pose UIDs each robot held (all layers) once the network was quiet.
    central : CentralResult, optional
        The central upper bound, when asked for.
    team_frames : list of TeamFrame
        The team sampled at a regular cadence of mission time, when recorded.
    agents : list of RobotAgent
        The robots after their routes, by robot id (what :func:`~.central.central_map`
        builds its bound from).
    """

    summary: dict[str, Any]
    robots: list[MissionResult]
    exchangers: list[Exchanger | NaiveExchanger]
    network: SimNetwork
    held: list[set[int]] = field(default_factory=list)
    central: CentralResult | None = None
    team_frames: list[TeamFrame] = field(default_factory=list)
    agents: list[RobotAgent] = field(default_factory=list)


def held_uids(store: RobotStore) -> tuple[set[int], int]:
    """The pose UIDs a store holds in any layer, and how many it holds more than once."""
    seen: set[int] = set()
    twice = 0
    layers = [store.local, *(store.received[s] for s in sorted(store.received))]
    for layer in layers:
        for uid in layer.poses:
            if uid in seen:
                twice += 1
            seen.add(uid)
    return seen, twice


def map_agreement(maps: Sequence[OccupancyMap]) -> float:
    """The least, over pairs of maps on one grid, share of the cells known (free or
    occupied) in either map that both give the same class; 1.0 for fewer than two maps
    or when no cell is known."""
    classes = [m.classes() for m in maps]
    worst = 1.0
    for i in range(len(classes)):
        for j in range(i + 1, len(classes)):
            a, b = classes[i], classes[j]
            known = (a >= 0) | (b >= 0)
            if known.any():
                worst = min(worst, float(np.mean(a[known] == b[known])))
    return worst


def _held_counts(agents: Sequence[RobotAgent]) -> list[tuple[int, int]]:
    """Per robot, how many of the other robots' own poses (as they are now) it holds,
    and how many those are."""
    out = []
    for a in agents:
        others = set().union(*(b.store.local.poses for b in agents if b is not a))
        out.append((len(others & held_uids(a.store)[0]), len(others)))
    return out


def _held_share(agents: Sequence[RobotAgent]) -> float:
    """The mean, over robots, of the share of the other robots' own poses (as they are
    now) that the robot holds: how far behind the team's exchange is (1: not at all)."""
    shares = [held / others for held, others in _held_counts(agents) if others]
    return float(np.mean(shares)) if shares else 1.0


class _Recorder:
    """Samples the team every ``interval`` seconds of mission time from ``t0`` on, at
    most ``limit`` frames (see the module's notes)."""

    def __init__(
        self,
        agents: Sequence[RobotAgent],
        exchangers: Sequence[Exchanger | NaiveExchanger],
        net: SimNetwork,
        t0: float,
        interval: float,
        limit: int,
    ) -> None:
        self.agents = agents
        self.exchangers = exchangers
        self.net = net
        self.t0 = t0
        self.interval = interval
        self.limit = limit
        self.due = t0
        self.frames: list[TeamFrame] = []

    def sample(self, t: float, *, driving: bool, last: bool = False) -> None:
        """Keep the team as it is after the tick at ``t`` if a frame is due, or if
        ``last`` and the frame at ``t`` is not kept yet."""
        if t < self.due and not (last and (not self.frames or self.frames[-1].t < t)):
            return
        # The next multiple of the interval after t: a tick that skips one (ticks
        # sparser than the cadence) does not make the frames bunch up after it.
        self.due = self.t0 + (math.floor((t - self.t0) / self.interval) + 1) * self.interval
        counts = np.array(_held_counts(self.agents), dtype=np.int64).reshape(-1, 2)
        frame = TeamFrame(
            t=t,
            driving=driving,
            positions=np.array([a.position() for a in self.agents], dtype=np.float64),
            links=self.net.links(),
            held=counts[:, 0].copy(),
            others=counts[:, 1].copy(),
            bytes_sent=sum(e.stats.bytes_sent for e in self.exchangers),
        )
        if len(self.frames) >= self.limit:
            self.frames[-1] = frame
        else:
            self.frames.append(frame)


def _bytes_of(meter: NaiveMeter) -> Callable[[], float]:
    """What ``meter`` has priced so far, read when called."""
    return lambda: float(meter.bytes)


def _changes(exchangers: list[Exchanger | NaiveExchanger]) -> int:
    return sum(e.stats.poses_added + e.stats.poses_deleted for e in exchangers)


def run_team(
    plan: OccupancyMap,
    cfg: MissionConfig,
    robots: int,
    *,
    network: NetworkParams,
    exchange: ExchangeParams,
    seed: int,
    progress: Progress | None = None,
    world: World | None = None,
    lookahead: float = 30.0,
    quiet: float | None = None,
    settle: float = 120.0,
    routes: Sequence[F64 | None] | None = None,
    central: bool = False,
    record: bool = False,
    frame_every: float = 2.0,
    max_frames: int = 300,
    phase: Callable[[str], None] | None = None,
    on_tick: Callable[[TeamTick], None] | None = None,
    prior: OccupancyMap | None = None,
    territory: npt.NDArray[np.bool_] | None = None,
) -> TeamResult:
    """Run ``robots`` robots' missions together, exchanging over a simulated network.

    Parameters
    ----------
    plan : OccupancyMap
        The floor (also the prior map unless ``prior`` is given).
    cfg : MissionConfig
        Every robot's mission settings; robot ``i`` seeds its route and sensors from
        ``cfg.seed + ROUTE_SEED_STEP i``.
    robots : int
        Robots in the team (ids 0 .. robots - 1), >= 1.
    network : NetworkParams
    exchange : ExchangeParams
    seed : int
        The network's seed.
    progress : callable, optional
        ``progress(tick, ticks)`` after each tick of the routes.
    world : World, optional
        The landmarks; made from ``cfg.seed`` unless given.
    lookahead : float
        Seconds of its route ahead whose regions a robot asks for first.
    quiet : float, optional
        Seconds without an added or deleted pose after which the network counts as
        quiet; default 2 ``advert_every`` + 2 ``request_every``.
    settle : float
        Seconds of exchange at most after the routes end.
    routes : sequence of ndarray (T, 4) or None, optional
        One per robot: ``t, x, y, theta`` replacing its random-waypoint route (None
        keeps it).
    central : bool
        Also build the central upper bound (:func:`~.central.central_map`; it costs
        about one robot's mission more).
    record : bool
        Each robot keeps a frame per pose made, and the team a
        :class:`~.animation.TeamFrame` every ``frame_every`` seconds of mission time
        (``team_frames``), for animations.
    frame_every : float
        Seconds of mission time between two team frames at least (> 0).
    max_frames : int
        Team frames at most (>= 2); the cadence widens to keep to it.
    phase : callable, optional
        ``phase(name)`` as each phase after the routes begins (``"quiet network"``,
        ``"robots' maps"``, ``"central bound"``), so that a caller can show progress.
    on_tick : callable, optional
        ``on_tick(TeamTick)`` after every tick, the routes' and the quiet phase's (to
        record or serve the run).
    prior : OccupancyMap, optional
        Every robot's prior map (:mod:`.prior`): its regions and the frame its global
        map is aligned to; the plan unless given. The truth stays the plan.
    territory : ndarray of bool, optional
        The mission's territory mask on the plan's cells (:mod:`.territory`): every
        robot cuts the prior's regions inside it (:class:`~.mission.RobotAgent`).
        Default None: the whole prior.

    Returns
    -------
    TeamResult
    """
    check_team_size(robots)
    if routes is not None and len(routes) != robots:
        raise ValueError(f"routes: {len(routes)} given for {robots} robots")
    if not (math.isfinite(frame_every) and frame_every > 0):
        raise ValueError(f"frame_every must be > 0 seconds, got {frame_every}")
    if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 2:
        raise ValueError(f"max_frames must be an int >= 2, got {max_frames!r}")
    world = make_world(plan, seed=cfg.seed, duration=cfg.duration) if world is None else world
    agents = [
        RobotAgent(
            plan,
            cfg,
            prior=prior,
            world=world,
            robot=i,
            route=None if routes is None else routes[i],
            record=record,
            calibrate=False,
            territory=territory,
        )
        for i in range(robots)
    ]
    truth: ChainMap[int, F64] = ChainMap(*(a.truth for a in agents))
    made: ChainMap[int, Pose] = ChainMap(*(a.made for a in agents))
    for a in agents:
        a.peers_truth = truth
        a.peers_made = made
    free = plan.classes() == 0
    net = SimNetwork(network, robots, seed=seed, clear=free, grid=plan.grid)
    times = team_ticks([a.route for a in agents])
    hub = SimHub(net, t0=float(times[0]))
    adjacency = region_adjacency(agents[0].labels)
    # The naive baseline's bytes on the same mission, for the share of them we send (and
    # the byte target of ExchangeParams.anchor_share).
    fold = cfg.store.fold
    meters = (
        [NaiveMeter(a.store, a.made if fold else None) for a in agents]
        if exchange.mode != "naive"
        else []
    )
    exchangers = [
        make_exchanger(
            a.store,
            hub.transport(a.robot),
            exchange,
            adjacency=adjacency,
            on_received=a.receive,
            naive_bytes=_bytes_of(meters[i]) if meters else None,
        )
        for i, a in enumerate(agents)
    ]

    # The routes and the longest quiet phase, shared out among the frames.
    span = float(times[-1] - times[0]) + settle
    recorder = _Recorder(
        agents,
        exchangers,
        net,
        float(times[0]),
        max(frame_every, span / (max_frames - 1)),
        max_frames,
    )

    clock = LockstepClock.for_ticks(
        times,
        quiet=quiet_seconds(exchange.advert_every, exchange.request_every, quiet),
        settle=settle,
        request_every=exchange.request_every,
    )

    def tick(n: int, t: float, driving: bool) -> None:
        if driving:
            for a in agents:
                a.advance_to(t)
        else:
            for e in exchangers:
                e.finish()
        hub.advance(t)
        hub.update(np.array([a.position() for a in agents]))
        for a, e in zip(agents, exchangers, strict=True):
            e.step(t, a.wanted_regions(lookahead) if driving else None)
        for a, m in zip(agents, meters, strict=False):
            m.step(len(set(net.reachable(a.robot)) - {a.robot}))
        if record:
            recorder.sample(t, driving=driving)
        if on_tick is not None:
            sent = [e.stats.bytes_sent for e in exchangers]
            on_tick(TeamTick(t, driving, agents, net.links(), sent))

    def team(n: int) -> tuple[int, bool]:
        return _changes(exchangers), any(e.outstanding for e in exchangers)

    at_end: dict[str, float] = {}

    def routes_end() -> int:
        at_end["held"] = _held_share(agents)
        if phase is not None:
            phase("quiet network")
        return sum(e.stats.bytes_sent for e in exchangers)

    def after(n: int, t: float, driving: bool) -> None:
        if driving and progress is not None:
            progress(n + 1, len(times))

    clock.run(tick, team, routes_end=routes_end, after=after)
    end, t, settled = clock.end, clock.t, clock.settled
    held_at_end = at_end["held"]
    if record:
        recorder.sample(t, driving=t <= end, last=True)

    held = [held_uids(a.store) for a in agents]
    identical = all(h[0] == held[0][0] for h in held)
    converged = settled and (identical or network.kind != "full")
    if phase is not None:
        phase("robots' maps")
    results = [a.finish() for a in agents]
    rows = [
        robot_row(
            r.summary,
            a,
            e.stats,
            (net.stats.links_made[a.robot], net.stats.links_broken[a.robot]),
        )
        for a, e, r in zip(agents, exchangers, results, strict=True)
    ]
    if phase is not None and central:
        phase("central bound")
    bound = central_map(agents, seed=cfg.seed) if central else None
    summary: dict[str, Any] = mission_figures(rows)
    summary.update(
        team_figures(
            rows,
            held=[h[0] for h in held],
            duplicates=sum(h[1] for h in held),
            route_seconds=end - clock.start,
            sent_in_mission=clock.sent,
            naive_bytes=sum(m.bytes for m in meters) if meters else None,
            converged=converged,
            convergence_s=clock.convergence_s,
            settle_seconds=clock.settle_seconds,
            settled=settled,
        )
    )
    summary.update(
        {
            # Each link has two ends, each counted at its robot.
            "meetings": int(net.stats.links_made.sum()) // 2,
            "partings": int(net.stats.links_broken.sum()) // 2,
            "map_agreement": map_agreement([r.global_map for r in results]),
            "held_share_at_routes_end": held_at_end,
            "map_f1_central": None if bound is None else bound.summary["map_f1"],
            "central": None if bound is None else bound.summary,
            "network": asdict(network),
            "exchange": asdict(exchange),
            "seed": seed,
        }
    )
    return TeamResult(
        summary, results, exchangers, net, [h[0] for h in held], bound, recorder.frames, agents
    )
