"""The patrol's step loop and what a run measured.

Each step of ``dt`` seconds (0.5), every robot finds the path length L and first
direction to every watched cell (the wave, or straight lines), weighs every cell by
f(TB_n) g(L), chooses a direction (mode or vector sum) and the team moves by the
collision rule; then time passes and every robot sees the cells within its vision
radius. Each robot keeps its own fog, built from the positions it hears of
(:mod:`.network`); with the full network every robot's fog is the true fog. The metric
is always the true fog.

The run's pieces live by concept: its settings in :mod:`.settings`
(:class:`~sonarmap.patrol.settings.PatrolConfig`), its starts and team in :mod:`.launch`,
the cells a robot closes round the others in :mod:`.crowding`, the place it goes for in
:mod:`.goals` and its way there in :mod:`.steering`, what it measured in :mod:`.result`
(:class:`~sonarmap.patrol.result.PatrolResult`). Their public names are importable from
here too, as they always were.

Decisions where the thesis is silent (docs/patrol.md marks them UNCLEAR):

- the start fog is 0 (the territory just seen) and the reported MTB is the time average
  of MTB(t) over the steps after a warm-up of ``warmup`` seconds (default a fifth of the
  run); the average over every step is reported too;
- robots start facing +x unless a start file gives headings;
- paths and fog are on cells of ``cell`` metres (0.5, or half the robot's radius when
  smaller) rather than the thesis's 0.1 m: the wave per robot and step is then 25 times
  smaller; ``cell=0.1`` is the thesis's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from .claims import Claims
from .coarse import CoarseChoice
from .crowding import ONCOMING_NEAR, earlier_near, give_way, halves_discs, obstacle_discs
from .fog import Fog, Vision, dilate, disc_cells, disc_offsets
from .forces import sector_pulls, step_direction
from .giveup import GiveUp
from .goals import aim, goal_index, nearest_leftover, stale, wave_anchors
from .graph import PatrolGraph
from .launch import build_team, car_starts, check_given_starts, place_robots
from .manoeuvre import DeadEnds, FreshAhead, behind_cells, turn_weights
from .monitor import Monitor
from .network import components
from .oneway import one_way
from .paths import STEP_UNITS, Wave, shadows, straight_paths
from .policies import choose, goal_pulls, reactive_pick
from .reach import Reach
from .refine import obstacle_penalty, refine_direction, sector_weakening
from .result import PatrolResult
from .robots import Car, Holonomic, Team
from .semaphores import Semaphores
from .settings import (
    CAR_DEFAULTS,
    CAR_PLANNERS,
    CROWDING,
    FINDERS,
    FOLLOW_TIME,
    GIVE_UP_RADIUS,
    GIVE_WAY_TIME,
    MAX_STEPS,
    MODELS,
    MOTIONS,
    PATH_POLICIES,
    PATHS,
    PLAIN_DEFAULTS,
    REACH_FIELDS,
    SIGHT_MARGIN,
    TRAFFIC,
    PatrolConfig,
)
from .starts import StartSource
from .steering import car_carrot, follow_tour, held_goal, path_goal, unit_towards, walk_step
from .stubs import stand_points, stub_places
from .territory import Territory
from .tour import plan_tour
from .walkers import WALKERS, GraphWalkers

# The settings' names live in :mod:`.settings`; they are named here too, where callers
# have always imported them from.
__all__ = [
    "CAR_DEFAULTS",
    "CAR_PLANNERS",
    "CROWDING",
    "MAX_STEPS",
    "MODELS",
    "MOTIONS",
    "ONCOMING_NEAR",
    "PATHS",
    "PATH_POLICIES",
    "PLAIN_DEFAULTS",
    "REACH_FIELDS",
    "SIGHT_MARGIN",
    "TRAFFIC",
    "PatrolConfig",
    "PatrolResult",
    "car_starts",
    "check_given_starts",
    "halves_discs",
    "obstacle_discs",
    "run_patrol",
]

F64 = npt.NDArray[np.float64]
#: A place chosen on blocks (:class:`~sonarmap.patrol.coarse.CoarseChoice`) is refused,
#: and the fine choice made instead, when its fine path is longer than this factor times
#: the blocks' path plus these metres (the blocks' 8-connected paths run up to a block
#: off the cells' at either end).
COARSE_SLACK = (1.25, 2.0)


#: A direction (a unit vector) or a point (world metres), or None for none.
Way = tuple[float, float] | None


def run_patrol(
    territory: Territory,
    config: PatrolConfig,
    *,
    starts: F64 | None = None,
    robots: int | None = None,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
    on_step: Callable[[float, Team, Fog], None] | None = None,
    semaphores: list[npt.NDArray[np.bool_]] | None = None,
    region: npt.NDArray[np.bool_] | None = None,
    graph: bool = False,
    start_source: StartSource | None = None,
) -> PatrolResult:
    """Patrol ``territory`` for ``config.duration`` seconds.

    Parameters
    ----------
    starts : ndarray (N, 3), optional
        World (x, y, heading) per robot; otherwise ``robots`` starts spread over the
        reachable territory (:func:`~sonarmap.patrol.starts.spread_starts`, seeded).
    on_step : callable, optional
        Called after every step with the time, the robots and the fog (for pictures).
    semaphores : list of ndarray of bool, optional
        The semaphores' cells (:func:`~sonarmap.patrol.semaphores.read_semaphores`);
        needed by ``crowding="semaphores"``.
    region : ndarray of bool, optional
        The user's territory mask on the territory's grid (:mod:`.region`): nothing
        outside it is entered or watched.
    graph : bool
        Also measure patrolling_sim's metrics (:class:`~sonarmap.patrol.monitor.Monitor`)
        on the patrol graph of the reachable territory
        (:meth:`~sonarmap.patrol.graph.PatrolGraph.from_territory`, vertices spaced by
        the vision radius), every step; default False.
    start_source : StartSource, optional
        Where ``starts`` came from (a start file's path and lines), named when one is
        refused (:func:`check_given_starts`); default: world poses.

    Raises
    ------
    InputError
        A start outside the map, the region, or too near an obstacle or another robot;
        a territory with nothing to patrol (:func:`~sonarmap.patrol.reach.reach`).
    """
    if seed < 0:
        raise ConfigError(f"seed must be >= 0, got {seed}")
    if config.crowding == "semaphores" and not semaphores:
        raise ConfigError("crowding 'semaphores' needs a semaphore file (--semaphores)")
    config.check_reach(territory.grid)
    if starts is not None or robots is not None:
        config = config.for_team(len(starts) if starts is not None else int(robots or 0))
    sems = Semaphores(semaphores or [])
    starts, where = place_robots(
        territory, config, starts, robots, seed, region=region, start_source=start_source
    )
    run = _Run(territory, config, where, build_team(starts, territory, config), sems, seed, graph)
    steps = len(run.t_out)
    for k in range(steps):
        run.step(k)
        if on_step is not None:
            on_step(float(run.t_out[k]), run.team, run.fog)
        if progress is not None:
            progress(k + 1, steps)
    return run.result(starts)


class _Run:
    """One patrol run: its state, built once from the robots placed, and its step.

    Each step (:meth:`step`) every robot decides where to head (:meth:`decide`), the
    team moves (:meth:`move`), time passes and the robots look (:meth:`look`); the
    true fog's metrics are recorded per step. It lives inside one :func:`run_patrol`
    call and is never saved or resumed, so it has no ``state()``/``restore()``.
    """

    def __init__(
        self,
        territory: Territory,
        config: PatrolConfig,
        where: Reach,
        team: Team,
        sems: Semaphores,
        seed: int,
        graph: bool,
    ) -> None:
        self.territory, self.config, self.where, self.team = territory, config, where, team
        self.sems = sems
        self.passable = where.passable
        self.g = g = territory.grid
        self.watched = watched = where.watched
        self.fog = Fog(g, watched, config.start_fog)  # the true fog: the metric
        # Each robot's own fog; with the full network they are all the true fog.
        self.shared = config.network == "full"
        self.own = (
            [self.fog] if self.shared else [Fog(g, watched, config.start_fog) for _ in team.x]
        )
        self.disc = Vision(
            config.vision, g.resolution, territory.free if config.line_of_sight else None
        )
        self.rng = np.random.default_rng(seed)
        self.cx, self.cy = g.all_centres()
        steps = round(config.duration / config.dt)
        self.t_out = np.empty(steps)
        self.mtb = np.empty(steps)
        self.mean_tb = np.empty(steps)
        self.blocked = np.zeros(len(team), dtype=np.int64)
        self.escapes = np.zeros(len(team), dtype=np.int64)
        self.dvt = np.empty(steps)
        self._crowding_state()
        self.look()
        self.wall0 = time.perf_counter()
        self._baselines(graph)
        self._paths()
        self._choice_state()

    def _crowding_state(self) -> None:
        """What :meth:`closed_cells` reads: the discs, the forward waves' state, who
        hears whom and who gives way."""
        config, team, g = self.config, self.team, self.g
        self.obst = disc_offsets(config.r_obst, g.resolution)
        self.halve = halves_discs(config)
        self.forward = config.forward_wave and isinstance(team, Car) and team.planner == "track"
        # The map does not change during a run: the dead-end test labels it once.
        self.dead_ends = DeadEnds(self.passable) if self.forward else None
        # Forward waves: from which step other robots have shut each car's way ahead.
        self.shut = np.full(len(team), -1, dtype=np.int64)
        # Forward waves: whether each fog's stalest place lifts them this step
        # (``config.forward_stale``).
        self.lifted = np.zeros(len(self.own), dtype=np.bool_)
        self.follow_steps = round(FOLLOW_TIME / config.dt)
        self.penalty = (
            obstacle_penalty(self.territory.free, g.resolution, config.refine_window)
            if config.refine
            else None
        )
        self.label = np.zeros(len(team), dtype=np.int64)
        # give-way: until which step each robot plans around the earlier robots near it.
        self.yielding = np.full(len(team), -1, dtype=np.int64)
        self.yield_steps = max(1, round(GIVE_WAY_TIME / config.dt))
        self.yield_disc = disc_offsets(config.min_separation, g.resolution)
        self.yield_range = config.min_separation + config.speed * GIVE_WAY_TIME

    def _baselines(self, graph: bool) -> None:
        """The patrol graph's monitor and walkers, the static path-finder and the tour."""
        config, team, g, passable = self.config, self.team, self.g, self.passable
        self.monitor: Monitor | None = None
        self.walkers: GraphWalkers | None = None
        if graph or config.policy in WALKERS:
            r0, c0 = g.world_to_cell(team.x, team.y)
            cells0 = np.column_stack([np.asarray(r0), np.asarray(c0)])
            patrol_graph = PatrolGraph.from_territory(
                self.territory,
                passable,
                config.vision,
                starts=[tuple(rc) for rc in cells0.tolist()],
            )
            if config.policy in WALKERS:
                self.walkers = GraphWalkers(patrol_graph, config.policy, cells0, speed=config.speed)
            if graph:
                self.monitor = Monitor(
                    patrol_graph, start_idleness=config.start_fog, robot_radius=config.radius
                )
                self.monitor.update(0.0, team.x, team.y)
        self.finder = (
            FINDERS[config.paths].build(passable, g.resolution) if config.paths in FINDERS else None
        )
        r0, c0 = g.world_to_cell(team.x, team.y)
        self.tour = np.empty((0, 2), dtype=np.int64)
        self.target = np.zeros(len(team), dtype=np.int64)
        if config.policy == "cycle":
            self.tour, _ = plan_tour(
                self.territory, passable, config.vision, (int(r0[0]), int(c0[0]))
            )
            # Robots spread evenly along the tour: robot k joins it at the k-th share.
            self.target = (np.arange(len(team)) * len(self.tour)) // len(team)

    def _paths(self) -> None:
        """The wave (on one-way streets when driven), the stubs' stand points and the
        places pulling as if seen later, the shadows."""
        config, g, passable, watched = self.config, self.g, self.passable, self.watched
        streets = (
            one_way(
                passable,
                self.territory.clearance,
                g.resolution,
                config.turn_radius,
                orient=config.one_way_orient if config.one_way else "dfs",
            )
            if config.one_way or config.stub_sight or config.stub_delay > 0
            else None
        )
        self.waver = Wave(
            passable.shape, streets.steps if streets is not None and config.one_way else None
        )
        stands = (
            stand_points(passable, watched, streets, g.resolution, config.vision - SIGHT_MARGIN)
            if streets is not None and (config.stub_sight or config.stub_delay > 0)
            else None
        )
        self.stand = stands if config.stub_sight else None
        # The places a car must drive into a stub to see, pulling as if seen later.
        deep = (
            stub_places(passable, watched, streets) & (stands < 0)
            if streets is not None and stands is not None and config.stub_delay > 0
            else None
        )
        if deep is not None and not deep.any():
            deep = None  # nothing delayed: no per-step copies of the fogs
        self.deep = deep
        self.n_watched = int(watched.sum())
        # Wall-side cells no wave reaches pull from the nearest cell one does, so that no
        # place of the territory is left without a pull (on real maps a fifth of the cells
        # may be such). Only with the path motion: the thesis's straight-motion robots and
        # cars keep the thesis's pulls, so its experiments are unchanged.
        self.shade = (
            shadows(passable, watched, g.resolution)
            if config.policy == "potential"
            and config.motion == "path"
            and config.paths == "wave"
            and config.reach == "reachable"
            else None
        )
        self.watched_rc = np.nonzero(watched)

    def _choice_state(self) -> None:
        """How the robots choose (the switches settled by the configuration) and what
        they keep between steps: the places they go for, the places given up, the
        tracking cars' masks."""
        config, team, g, passable, watched = (
            self.config,
            self.team,
            self.g,
            self.passable,
            self.watched,
        )
        # The potential field's pulls summed per wave step in one pass with the wave give
        # its direction at once, unless the path motion or other sectors need every place.
        # Tracking cars follow the path to a place: they need every place too.
        self.tracking = tracking = isinstance(team, Car) and team.planner == "track"
        self.direct = (
            config.policy == "potential"
            and config.motion == "straight"
            and (config.sectors == 8 or config.direction == "vector")
            and not tracking
        )
        self.along_path = along_path = config.motion == "path"
        # A potential-field robot on its way to a kept goal needs only the path there: the
        # field's direction (always some step while the goal is unseen) is overridden by
        # the goal, and only consulted when the path gives no clear step -- then, and when
        # the goal is seen or cut off, the full field is worked out as before.
        # Its choice of step and of the place it goes for along it are settled once the
        # places left could change neither: the wave stops there.
        # Tracking cars choose their place the same way.
        self.certify_goal = certify_goal = (
            (along_path or tracking) and config.sectors == 8 and config.policy == "potential"
        )
        # Then the mode's step and that step's strongest place come straight from the
        # pulls summed with the wave, as the straight motion's direction does.
        self.direct_path = direct_path = along_path and certify_goal and config.direction == "mode"
        self.places = np.full((8, 2), -1, dtype=np.int64)
        self.hold_fast = hold_fast = (
            ((along_path and self.penalty is None and isinstance(team, Holonomic)) or tracking)
            and config.keep_goal
            and config.policy == "potential"
            and config.direction == "mode"
            and config.paths == "wave"
        )
        # A new choice of place on blocks of cells, then the fine wave only as far as it.
        self.coarse = (
            CoarseChoice.build(
                passable, watched, g.resolution, config.choice_cell, fine_shadows=self.shade
            )
            if direct_path and hold_fast and config.choice_cell > 0 and not config.line_of_sight
            else None
        )
        # Places the other robots go for pull a robot's new choice as if seen (claim).
        self.claims = (
            Claims(config.claim, g.resolution)
            if config.claim > 0 and self.shared and along_path
            else None
        )
        # Path motion: the place each robot goes for, and when it chose it.
        self.aims: list[tuple[int, int] | None] = [None] * len(team)
        self.aimed_at = np.zeros(len(team))
        # Leftovers (``config.leftover``): when each car's place was last seen before it
        # chose it, and the cell its wave goes to for a leftover no wave reaches.
        self.aim_last = np.full(len(team), -np.inf)
        self.via: list[tuple[int, int] | None] = [None] * len(team)
        # The place each car chose (not a leftover): leftovers are looked for round it
        # only.
        self.chosen: list[tuple[int, int] | None] = [None] * len(team)
        self.anchors = (
            wave_anchors(passable, watched)
            if tracking and hold_fast and config.leftover > 0
            else None
        )
        # The places the robots go for: the watched ones but those the cars gave up.
        self.targets = watched
        self.giving_up = tracking and config.give_up > 0
        self.quitter = GiveUp(
            watched, max(1, config.give_up), disc_offsets(GIVE_UP_RADIUS, g.resolution)
        )
        self.turns = team.turns.copy() if isinstance(team, Car) else np.zeros(0, dtype=np.int64)
        # How many places ``targets`` holds (counted again when it is another array).
        self.counted, self.n_targets = watched, self.n_watched
        # Tracking cars' masks, in buffers kept for the run (a fresh map-sized array per
        # car and step cost more than filling it): per fog the places out of sight and the
        # step they were made on, and the places ahead of the car being decided for.
        pulls_masks = tracking and (config.out_of_sight or config.turn_time > 0)
        self.unseen_of = [np.empty_like(watched) for _ in self.own] if pulls_masks else []
        self.n_unseen = np.zeros(len(self.own), dtype=np.int64)
        self.unseen_step = np.full(len(self.own), -1, dtype=np.int64)
        self.ahead_buffer = FreshAhead(watched.shape) if pulls_masks else None

    def look(self) -> None:
        """Every robot sees the cells within its vision: the true fog, then (unless
        shared) each robot's own fog from the robots it hears of."""
        config, team, g = self.config, self.team, self.g
        r, c = g.world_to_cell(team.x, team.y)
        self.fog.observe(r, c, self.disc)
        self.label = label = components(
            config.network, team.x, team.y, clear=self.territory.free, grid=g, r_max=config.r_max
        )
        if self.shared:
            return
        for i, f in enumerate(self.own):
            heard = label == label[i]
            f.observe(r[heard], c[heard], self.disc)

    def closed_cells(
        self,
        i: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        now: int,
        following: bool = False,
        open_behind: bool = False,
    ) -> tuple[npt.NDArray[np.intp] | None, bool]:
        """Cells closed on robot i's path-finding map, as (row, column) pairs (None:
        none), and whether they hold the cells behind the car because the way ahead
        leads on.

        The crowding rule closes the active semaphores it does not hold, or discs
        around the other robots it hears of; a robot giving way closes discs around
        the earlier robots near it (its own cell stays open); a tracking car's forward
        wave closes the cells behind it while the way ahead leads on
        (``config.forward_wave``; the flag is True then) or, for
        :data:`FOLLOW_TIME`, while only other robots shut the way ahead (the flag
        stays False: those cells are the robots', not a forward wave's choice).
        ``following``: for a car driving on rather than turning round
        (``config.round_block``): no disc round the robots ahead of it going its way
        (they clear the street as it follows) nor round those ahead farther than
        :data:`ONCOMING_NEAR` (they may turn off before they meet it), and no forward
        wave. ``open_behind``: no forward wave either, nor any change to when other
        robots shut the car's way (the rerun of a wave whose closed cells behind left
        the car nothing to go for, in the choice below); the flag is then False."""
        config, team, g, passable = self.config, self.team, self.g, self.passable
        shut = self.shut
        heard = self.label == self.label[i]
        parts: list[npt.NDArray[np.intp]] = []
        if self.yielding[i] >= now:
            near = earlier_near(team, i, self.yield_range)
            parts = [
                np.column_stack(disc_cells(self.yield_disc, int(r[j]), int(c[j]), passable.shape))
                for j in np.flatnonzero(near & heard[:i]).tolist()
            ]
        if config.crowding == "semaphores":
            parts.append(self.sems.closed_cells(i, heard))
        if config.crowding == "obstacles" and len(team) > 1:
            rc = np.column_stack([np.asarray(r), np.asarray(c)])
            parts += obstacle_discs(
                team,
                i,
                rc,
                self.obst,
                passable.shape,
                halve=self.halve,
                following=following,
                heard=heard,
            )
        behind = False
        if (
            self.dead_ends is not None
            and not following
            and not self.lifted[0 if self.shared else i]
            and not open_behind
        ):
            back = behind_cells(float(team.x[i]), float(team.y[i]), float(team.heading[i]), g)
            start = (int(r[i]), int(c[i]))
            if self.dead_ends.leads_on(np.concatenate([back, *parts]), start):
                parts.append(back)
                behind = True
                shut[i] = -1
            elif self.dead_ends.leads_on(back, start):
                # Only other robots shut the way ahead: they are often on their way, so
                # follow them for FOLLOW_TIME before turning round (nose to nose, a car
                # turns round after that).
                shut[i] = now if shut[i] < 0 else shut[i]
                if now - shut[i] < self.follow_steps:
                    parts.append(back)
            else:
                shut[i] = -1  # a dead end: the way out lies behind
        return (np.concatenate(parts) if parts else None), behind

    def closed_only(
        self,
        i: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        now: int,
        following: bool = False,
    ) -> npt.NDArray[np.intp] | None:
        """:meth:`closed_cells`'s cells alone, for the callers that take a cell list."""
        return self.closed_cells(i, r, c, now, following)[0]

    def tb_of(
        self,
        i: int,
        rr: npt.NDArray[np.intp],
        cc: npt.NDArray[np.intp],
        dilated: list[F64] | None,
    ) -> F64:
        """Robot i's TB of cells (rows, cols), from its dilated fog when there is one."""
        j = 0 if self.shared else i
        return dilated[j][rr, cc] if dilated is not None else self.own[j].tb_at(rr, cc)

    def step(self, k: int) -> None:
        """Step ``k``: every robot decides, the team moves, time passes, the robots
        look, and the true fog's metrics are recorded."""
        config, team, g, own = self.config, self.team, self.g, self.own
        directions: list[Way] = []
        goals: list[Way] = []
        r, c = g.world_to_cell(team.x, team.y)
        # Each fog dilated once a step (with the full network, one for the whole team).
        dilated = [dilate(f.tb, config.dilation) for f in own] if config.dilation else None
        if self.deep is not None:
            dilated = [
                np.where(self.deep, np.maximum(tb - config.stub_delay, 0.0), tb)
                for tb in (dilated if dilated is not None else [f.tb for f in own])
            ]
        tops = [f.mtb() for f in own]
        if self.forward and config.forward_stale > 0:
            for j, f in enumerate(own):
                self.lifted[j] = stale(tops[j], config.forward_stale, f)
        if self.targets is not self.counted:
            self.counted, self.n_targets = self.targets, int(np.count_nonzero(self.targets))
        for i in range(len(team)):
            direction, goal = self.decide(i, k, r, c, dilated, tops[0 if self.shared else i])
            directions.append(direction)
            goals.append(goal)
        self.move(k, directions, goals)
        self.record(k)

    def decide(
        self,
        i: int,
        k: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        dilated: list[F64] | None,
        top: float,
    ) -> tuple[Way, Way]:
        """Robot i's direction and the point it heads for (None: none) on step ``k``.

        ``r``, ``c``: every robot's cell; ``dilated``: each fog's TB as the choice reads
        it (None: the fogs' own); ``top``: robot i's fog's MTB."""
        config, team, g, passable = self.config, self.team, self.g, self.passable
        own, waver, aims, aimed_at = self.own, self.waver, self.aims, self.aimed_at
        held = self._leftover(i)
        kept = self._keep_going(i, k, r, c, held)
        if kept is not None:
            return kept
        weights = self._weights(i)
        step: npt.NDArray[np.int8] | None = None
        pulling, n_pulling, unmasked, n_unmasked = self._pulling(i, k)
        if config.policy == "random":
            tbv = lengths = ux = uy = np.empty(0)
            rr = cc = np.empty(0, dtype=np.intp)  # no place: the random walk has no goal
        elif config.paths == "wave" or config.policy == "cycle" or self.walkers is not None:
            start = (int(r[i]), int(c[i]))
            closed, behind = self.closed_cells(i, r, c, k)
            j = 0 if self.shared else i
            if (
                self.coarse is not None
                and closed is None
                and self.targets is self.watched
                and (held is None or own[j].last[held] >= aimed_at[i])
            ):
                decided = self._coarse(i, start, top, weights, dilated)
                if decided is not None:
                    return decided
            if config.policy == "potential":
                # When only places just seen behind the car are within its reach (a
                # car nose to nose with another), they pull as before, or it would
                # stand until they age.
                tries = (
                    [(pulling, n_pulling)]
                    if unmasked is None
                    else [(pulling, n_pulling), (unmasked, n_unmasked)]
                )
                strength, pulling = self._pulls(
                    i, k, r, c, start, closed, behind, weights, tries, dilated, top
                )
                if self.direct:
                    return step_direction(strength, config.direction, weights), None
                if self.direct_path:
                    way = step_direction(strength, "mode", weights)
                    goal_cell = aim(i, way, self.places, waver, own[j], aims, aimed_at, config)
                    return way, path_goal(team, i, goal_cell, waver, g, passable, config)
            else:
                waver(passable, start, g.resolution, pulling, None, closed)
            rr, cc, step, lengths = waver.reached_in(pulling)
            tbv = self.tb_of(i, rr, cc, dilated)
            ux = STEP_UNITS[step, 0]
            uy = STEP_UNITS[step, 1]
        elif config.paths == "straight":
            rr, cc = self.watched_rc
            tbv = self.tb_of(i, rr, cc, dilated)
            lengths, ux, uy = straight_paths(team.x[i], team.y[i], self.cx[rr, cc], self.cy[rr, cc])
        else:
            assert self.finder is not None
            dist, gx, gy = self.finder.paths((int(r[i]), int(c[i])), self.watched)
            rr, cc = np.nonzero(self.watched & np.isfinite(dist))
            tbv = self.tb_of(i, rr, cc, dilated)
            lengths, ux, uy = dist[rr, cc], gx[rr, cc], gy[rr, cc]
        if self.walkers is not None:
            direction = walk_step(
                i,
                self.walkers,
                waver,
                own[0 if self.shared else i],
                config,
                self.label == self.label[i],
                bool(team.blocked[i]) and self.yielding[i] >= k,
            )
            return direction, (
                path_goal(team, i, self.walkers.goal_cell(i), waver, g, passable, config)
                if self.along_path
                else None
            )
        if config.policy == "cycle":
            direction = follow_tour(i, self.tour, self.target, waver.dist, waver.first, config)
            way_cell = (int(self.tour[self.target[i], 0]), int(self.tour[self.target[i], 1]))
            return direction, (
                path_goal(team, i, way_cell, waver, g, passable, config)
                if self.along_path
                else None
            )
        direction = choose(
            config.policy,
            force=config.force,
            method=config.direction,
            sectors=config.sectors,
            tb=tbv,
            lengths=lengths,
            ux=ux,
            uy=uy,
            heading=float(team.heading[i]),
            blocked=bool(team.blocked[i]),
            rng=self.rng,
            weights=weights,
            top=top,
            steps=step,
        )
        goal = self._goal(i, direction, step, tbv, lengths, rr, cc, top)
        if self.tracking:
            return self._pursue(i, k, r, c, direction, goal, pulling)
        return direction, path_goal(team, i, goal, waver, g, passable, config)

    def _coarse(
        self,
        i: int,
        start: tuple[int, int],
        top: float,
        weights: F64 | None,
        dilated: list[F64] | None,
    ) -> tuple[Way, Way] | None:
        """Robot i's new place chosen on blocks of cells (``choice_cell``) and its step
        towards it, the fine wave run only as far as it; None when the blocks give no
        place the fine wave reaches within :data:`COARSE_SLACK`."""
        config, own, waver, g = self.config, self.own, self.waver, self.g
        assert self.coarse is not None
        j = 0 if self.shared else i
        with self._claimed(i, j):
            way, place, length = self.coarse.choose(
                start,
                config.force,
                top,
                weights=weights,
                **(
                    {"tb": dilated[j]}
                    if dilated is not None
                    else {"last_seen": own[j].last, "now": own[j].t}
                ),
            )
        # The fine path to it; a place the fine wave cannot reach, or only by a path
        # much longer than the blocks' (the blocks join what the cells do not; a
        # shadow's anchor behind a wall), falls back on the fine choice.
        if place is None or not np.isfinite(
            waver.to(
                self.passable,
                start,
                place,
                g.resolution,
                self.targets,
                limit=COARSE_SLACK[0] * length + COARSE_SLACK[1],
            )
        ):
            return None
        self.aims[i], self.aimed_at[i] = place, own[j].t
        self.aim_last[i], self.via[i], self.chosen[i] = own[j].last[place], None, place
        return way, path_goal(self.team, i, place, waver, g, self.passable, config)

    def _pulls(
        self,
        i: int,
        k: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        start: tuple[int, int],
        closed: npt.NDArray[np.intp] | None,
        behind: bool,
        weights: F64 | None,
        tries: list[tuple[npt.NDArray[np.bool_], int]],
        dilated: list[F64] | None,
        top: float,
    ) -> tuple[F64, npt.NDArray[np.bool_]]:
        """The potential field's pulls on robot i per wave step
        (:func:`~sonarmap.patrol.forces.sector_pulls`), from the first of the places
        ``tries`` (the places pulling and how many) that pull at all, the cells behind
        a car opened when none does; and the places that pulled."""
        config, own, waver, g = self.config, self.own, self.waver, self.g
        # Only the places near the robot can change its choice (see Force.pull_limit):
        # the wave stops there unless told not to.
        j = 0 if self.shared else i
        pull_args: dict[str, Any] = {
            "closed": closed,
            "prune": config.prune,
            "certify": config.direction == "mode" and (self.direct or self.certify_goal),
            "weights": weights,
            "goal": self.certify_goal,
            "places": self.places,
            "shadows": self.shade,
            **(
                {"tb": dilated[j]}
                if dilated is not None
                else {"last_seen": own[j].last, "now": own[j].t}
            ),
        }
        # The dead-end test floods the passable cells, not the wave's allowed steps: a
        # car facing the wrong way into a one-way street passes it while its forward
        # wave, keeping to the one-way steps, reaches only a pocket of places in sight.
        # Then nothing pulls and it would stand for good, so its wave runs in every
        # direction.
        with self._claimed(i, j):
            for _ in range(2):
                for pulling, n_pulling in tries:
                    strength = sector_pulls(
                        waver,
                        self.passable,
                        start,
                        g.resolution,
                        pulling,
                        config.force,
                        top,
                        n_watched=n_pulling,
                        **pull_args,
                    )
                    if strength.any():
                        break
                if strength.any() or not behind:
                    break
                pull_args["closed"], behind = self.closed_cells(i, r, c, k, open_behind=True)
        return strength, pulling

    def _claimed(self, i: int, j: int) -> AbstractContextManager[None]:
        """While the block runs, the places round the others' aims count as just seen in
        fog j for robot i's choice (``config.claim``); nothing without claims."""
        if self.claims is None:
            return nullcontext()
        last, now = self.own[j].last, self.own[j].t
        return self.claims.held(last, now, self.claims.others(i, self.aims, self.aimed_at, last))

    def _leftover(self, i: int) -> tuple[int, int] | None:
        """Robot i's place, after a car whose place was seen takes the nearest leftover
        round it (``config.leftover``) as its next."""
        held = self.aims[i]
        mine_fog = self.own[0 if self.shared else i]
        anchors = self.anchors
        if anchors is not None and held is not None and mine_fog.last[held] >= self.aimed_at[i]:
            left = nearest_leftover(
                mine_fog,
                self.targets,
                self.chosen[i] or held,
                float(self.aim_last[i]),
                self.config.leftover,
                anchors[2],
            )
            if left is not None:
                # aim_last and the centre stay the chosen place's: the leftovers
                # along a street's wall-side cells (none of which a wave reaches)
                # would otherwise lead a car on from one to the next.
                self.aims[i], self.aimed_at[i], held = left, mine_fog.t, left
                self.via[i] = (int(anchors[0][left]), int(anchors[1][left]))
        return held

    def _keep_going(
        self,
        i: int,
        k: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        held: tuple[int, int] | None,
    ) -> tuple[Way, Way] | None:
        """Robot i's direction and point on the way to the place it keeps (``hold_fast``:
        not seen since chosen, or held for ``min_hold``), from a wave run only as far as
        it; None when it keeps none or the place gives no point."""
        config, team = self.config, self.team
        mine_fog = self.own[0 if self.shared else i]
        if not (
            self.hold_fast
            and held is not None
            and (
                mine_fog.last[held] < self.aimed_at[i]
                or (self.along_path and mine_fog.t - self.aimed_at[i] < config.min_hold - 1e-9)
            )
        ):
            return None
        start = (int(r[i]), int(c[i]))
        closed = self.closed_only(i, r, c, k)
        towards = held_goal(
            team,
            i,
            start,
            self.via[i] or held,
            self.waver,
            self.g,
            self.passable,
            self.targets,
            closed,
            config,
            partial(
                car_carrot,
                targets=self.targets,
                closed=partial(self.closed_only, i, r, c, k, True),
                stand=self.stand,
            )
            if self.tracking
            else path_goal,
        )
        if towards is None:
            return None
        return unit_towards(team, i, towards), towards

    def _weights(self, i: int) -> F64 | None:
        """Robot i's sector weights: the weakening (``weaken``) times a tracking car's
        turn penalty (``turn_penalty``); None for none."""
        config, team = self.config, self.team
        weights = (
            sector_weakening(
                float(team.x[i]),
                float(team.y[i]),
                self.territory.free,
                self.g,
                config.sectors,
                config.weaken_r0,
            )
            if config.weaken
            else None
        )
        if self.tracking and config.turn_penalty > 0:
            assert isinstance(team, Car)
            turn = turn_weights(float(team.heading[i]), team.behind, config.turn_penalty)
            weights = turn if weights is None else weights * turn
        return weights

    def _pulling(
        self, i: int, k: int
    ) -> tuple[npt.NDArray[np.bool_], int, npt.NDArray[np.bool_] | None, int]:
        """The places robot i's choice weighs and how many they are, and those pulling
        before the turn-time rule took the fresh ones behind out (None: it took none)
        and how many; a tracking car's ``out_of_sight`` and ``turn_time`` masks."""
        config, team, own, waver = self.config, self.team, self.own, self.waver
        pulling = self.targets
        n_pulling = self.n_targets
        if self.tracking and config.out_of_sight:
            j = 0 if self.shared else i
            if self.unseen_step[j] != k:
                # targets & (last < t): the places its fog saw at the last look out;
                # the same for every car sharing the fog, so once a step per fog.
                np.copyto(self.unseen_of[j], self.targets)
                self.n_unseen[j] = self.n_targets - own[j].clear_just_seen(self.unseen_of[j])
                waver.forget_targets()
                self.unseen_step[j] = k
            if self.n_unseen[j]:
                pulling, n_pulling = self.unseen_of[j], int(self.n_unseen[j])
        unmasked: npt.NDArray[np.bool_] | None = None
        n_unmasked = 0
        if self.tracking and config.turn_time > 0:
            assert isinstance(team, Car)
            mine_fog = own[0 if self.shared else i]
            # pulling & ~fresh_behind(...), without a pass over the whole map. The
            # places pulling change only between steps (out of sight: once a step).
            assert self.ahead_buffer is not None
            ahead, n_dropped = self.ahead_buffer.make(
                pulling,
                k,
                mine_fog,
                float(team.x[i]),
                float(team.y[i]),
                float(team.heading[i]),
                self.g,
                team.behind,
                config.turn_time,
            )
            waver.forget_targets()
            if n_dropped and n_pulling > n_dropped:
                unmasked, n_unmasked = pulling, n_pulling
                pulling, n_pulling = ahead, n_pulling - n_dropped
        return pulling, n_pulling, unmasked, n_unmasked

    def _goal(
        self,
        i: int,
        direction: Way,
        step: npt.NDArray[np.int8] | None,
        tbv: F64,
        lengths: F64,
        rr: npt.NDArray[np.intp],
        cc: npt.NDArray[np.intp],
        top: float,
    ) -> tuple[int, int] | None:
        """The place robot i goes for after choosing ``direction`` by the field (path
        motion and tracking cars): the one it keeps while unseen since chosen, else the
        strongest along its step (the reactive agent's place); None for none."""
        config = self.config
        goal: tuple[int, int] | None = None
        held = self.aims[i]
        mine = self.own[0 if self.shared else i]
        seek = self.along_path or self.tracking
        if (
            seek
            and config.keep_goal
            and held is not None
            and np.isfinite(self.waver.dist[held])
            and mine.last[held] < self.aimed_at[i]
        ):
            goal = held  # not seen since chosen: still worth the trip
        elif seek and step is not None:
            pick = (
                reactive_pick(tbv, lengths)
                if config.policy == "reactive"
                else goal_index(
                    direction,
                    step,
                    goal_pulls(config.policy, config.force, tbv, lengths, top),
                )
            )
            goal = None if pick is None else (int(rr[pick]), int(cc[pick]))
            self.aims[i], self.aimed_at[i] = goal, mine.t
            self.aim_last[i] = mine.last[goal] if goal is not None else -np.inf
            self.via[i], self.chosen[i] = None, goal
        return goal

    def _pursue(
        self,
        i: int,
        k: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        direction: Way,
        goal: tuple[int, int] | None,
        pulling: npt.NDArray[np.bool_],
    ) -> tuple[Way, Way]:
        """A tracking car's direction and pure-pursuit point on the way to ``goal``."""
        team = self.team
        point = car_carrot(
            team,
            i,
            goal,
            self.waver,
            self.g,
            self.passable,
            self.config,
            targets=pulling,
            closed=partial(self.closed_only, i, r, c, k, True),
            stand=self.stand,
        )
        if point is not None:
            # Steer for the point ahead on the path (refinement then moves it).
            px, py = point
            vx, vy = px - float(team.x[i]), py - float(team.y[i])
            norm = math.hypot(vx, vy)
            if norm > 1e-9:
                direction = (vx / norm, vy / norm)
        return direction, point

    def move(self, k: int, directions: list[Way], goals: list[Way]) -> None:
        """The team moves on step ``k`` (directions refined first with ``refine``); the
        robots blocked give way, and tracking cars give up places."""
        config, team, g, passable = self.config, self.team, self.g, self.passable
        if self.penalty is not None:
            penalty = self.penalty
            directions = [
                d
                if d is None
                else refine_direction(
                    float(team.x[i]),
                    float(team.y[i]),
                    d,
                    penalty,
                    passable,
                    g,
                    r_goal=config.refine_goal,
                    side=config.refine_side,
                )
                for i, d in enumerate(directions)
            ]
        team.step(
            directions,
            passable,
            g,
            config.dt,
            self.rng,
            goals if self.along_path or self.tracking else None,
        )
        if team.give_way:
            give_way(
                team,
                self.yielding,
                k + self.yield_steps,
                config.min_separation + 2 * config.speed * config.dt,
            )
        if self.giving_up:
            self._give_up()

    def _give_up(self) -> None:
        """The places tracking cars gave up after a reversing manoeuvre on the way to
        them; every robot going for one chooses again."""
        team, aims = self.team, self.aims
        assert isinstance(team, Car)
        for i in np.flatnonzero(team.turns > self.turns).tolist():
            held = aims[i]
            if held is not None and self.quitter.tried(held, self.own[0 if self.shared else i]):
                aims[i] = None
        self.turns = team.turns.copy()
        self.targets = targets = self.quitter.targets(self.fog)
        # Every robot going for a place given up chooses again.
        for j, a in enumerate(aims):
            if a is not None and not targets[a]:
                aims[j] = None

    def record(self, k: int) -> None:
        """After the move of step ``k``: time passes, the robots look, and the step's
        metrics are recorded."""
        config, team, g, fog = self.config, self.team, self.g, self.fog
        self.blocked += team.blocked
        self.escapes += team.escaping
        self.dvt[k] = 100.0 * self.escapes.mean() / (k + 1)
        moved_r, moved_c = g.world_to_cell(team.x, team.y)
        self.sems.update(np.asarray(moved_r), np.asarray(moved_c))
        fog.advance(config.dt)
        if not self.shared:
            for f in self.own:
                f.advance(config.dt)
        self.look()
        self.t_out[k] = (k + 1) * config.dt
        if self.monitor is not None:
            self.monitor.update(float(self.t_out[k]), team.x, team.y)
        self.mtb[k] = fog.mtb()
        self.mean_tb[k] = fog.mean_tb()

    def result(self, starts: F64) -> PatrolResult:
        """What the run measured, from the ``starts`` it began at."""
        team, fog, watched = self.team, self.fog, self.watched
        never = fog.never_seen()
        stall_team = team if isinstance(team, Car) and team.planner == "track" else None
        return PatrolResult(
            self.t_out,
            self.mtb,
            self.mean_tb,
            np.column_stack([team.x, team.y, team.heading]),
            self.config,
            time.perf_counter() - self.wall0,
            self.blocked,
            fog.tb.copy(),
            self.escapes,
            self.dvt,
            watched,
            float(never[watched].mean()),
            reach=self.where,
            starts=np.array(starts, dtype=np.float64),
            never_seen=never,
            monitor=self.monitor,
            given_up=float(self.quitter.given[watched].mean()),
            stalls=stall_team.stalls.copy() if stall_team is not None else None,
            stall_watch=(stall_team.stall_radius, stall_team.stall_steps)
            if stall_team is not None
            else None,
        )
