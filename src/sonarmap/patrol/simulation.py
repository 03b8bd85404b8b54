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
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
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
from .refine import obstacle_penalty, refine_direction, sector_weakening
from .result import PatrolResult
from .robots import Car, Holonomic, Team
from .semaphores import Semaphores
from .settings import (
    CAR_DEFAULTS,
    CROWDING,
    FINDERS,
    FOLLOW_TIME,
    GIVE_UP_RADIUS,
    GIVE_WAY_TIME,
    MAX_STEPS,
    MODELS,
    PLAIN_DEFAULTS,
    REACH_FIELDS,
    SIGHT_MARGIN,
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
    "CROWDING",
    "MAX_STEPS",
    "MODELS",
    "ONCOMING_NEAR",
    "PLAIN_DEFAULTS",
    "REACH_FIELDS",
    "SIGHT_MARGIN",
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
    passable = where.passable
    team = build_team(starts, territory, config)
    g = territory.grid
    watched = where.watched
    fog = Fog(g, watched, config.start_fog)  # the true fog: the metric
    # Each robot's own fog; with the full network they are all the true fog.
    shared = config.network == "full"
    own = [fog] if shared else [Fog(g, watched, config.start_fog) for _ in starts]
    disc = Vision(config.vision, g.resolution, territory.free if config.line_of_sight else None)
    rng = np.random.default_rng(seed)
    cx, cy = g.all_centres()
    steps = round(config.duration / config.dt)
    t_out = np.empty(steps)
    mtb = np.empty(steps)
    mean_tb = np.empty(steps)
    blocked = np.zeros(len(team), dtype=np.int64)
    escapes = np.zeros(len(team), dtype=np.int64)
    dvt = np.empty(steps)

    obst = disc_offsets(config.r_obst, g.resolution)
    halve = halves_discs(config)
    forward = config.forward_wave and isinstance(team, Car) and team.planner == "track"
    # The map does not change during a run: the dead-end test labels it once.
    dead_ends = DeadEnds(passable) if forward else None
    # Forward waves: from which step other robots have shut each car's way ahead.
    shut = np.full(len(team), -1, dtype=np.int64)
    # Forward waves: whether each fog's stalest place lifts them this step
    # (``config.forward_stale``).
    lifted = np.zeros(len(own), dtype=np.bool_)
    follow_steps = round(FOLLOW_TIME / config.dt)
    penalty = (
        obstacle_penalty(territory.free, g.resolution, config.refine_window)
        if config.refine
        else None
    )
    label = np.zeros(len(team), dtype=np.int64)
    # give-way: until which step each robot plans around the earlier robots near it.
    yielding = np.full(len(team), -1, dtype=np.int64)
    yield_steps = max(1, round(GIVE_WAY_TIME / config.dt))
    yield_disc = disc_offsets(config.min_separation, g.resolution)
    yield_range = config.min_separation + config.speed * GIVE_WAY_TIME

    def look() -> None:
        nonlocal label
        r, c = g.world_to_cell(team.x, team.y)
        fog.observe(r, c, disc)
        label = components(
            config.network, team.x, team.y, clear=territory.free, grid=g, r_max=config.r_max
        )
        if shared:
            return
        for i, f in enumerate(own):
            heard = label == label[i]
            f.observe(r[heard], c[heard], disc)

    def closed_cells(
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
        heard = label == label[i]
        parts: list[npt.NDArray[np.intp]] = []
        if yielding[i] >= now:
            near = earlier_near(team, i, yield_range)
            parts = [
                np.column_stack(disc_cells(yield_disc, int(r[j]), int(c[j]), passable.shape))
                for j in np.flatnonzero(near & heard[:i]).tolist()
            ]
        if config.crowding == "semaphores":
            parts.append(sems.closed_cells(i, heard))
        if config.crowding == "obstacles" and len(team) > 1:
            rc = np.column_stack([np.asarray(r), np.asarray(c)])
            parts += obstacle_discs(
                team, i, rc, obst, passable.shape, halve=halve, following=following, heard=heard
            )
        behind = False
        if (
            dead_ends is not None
            and not following
            and not lifted[0 if shared else i]
            and not open_behind
        ):
            back = behind_cells(float(team.x[i]), float(team.y[i]), float(team.heading[i]), g)
            start = (int(r[i]), int(c[i]))
            if dead_ends.leads_on(np.concatenate([back, *parts]), start):
                parts.append(back)
                behind = True
                shut[i] = -1
            elif dead_ends.leads_on(back, start):
                # Only other robots shut the way ahead: they are often on their way, so
                # follow them for FOLLOW_TIME before turning round (nose to nose, a car
                # turns round after that).
                shut[i] = now if shut[i] < 0 else shut[i]
                if now - shut[i] < follow_steps:
                    parts.append(back)
            else:
                shut[i] = -1  # a dead end: the way out lies behind
        return (np.concatenate(parts) if parts else None), behind

    def closed_only(
        i: int,
        r: npt.NDArray[np.intp],
        c: npt.NDArray[np.intp],
        now: int,
        following: bool = False,
    ) -> npt.NDArray[np.intp] | None:
        """:func:`closed_cells`'s cells alone, for the callers that take a cell list."""
        return closed_cells(i, r, c, now, following)[0]

    look()
    wall0 = time.perf_counter()
    monitor = None
    walkers = None
    if graph or config.policy in WALKERS:
        r0, c0 = g.world_to_cell(team.x, team.y)
        cells0 = np.column_stack([np.asarray(r0), np.asarray(c0)])
        patrol_graph = PatrolGraph.from_territory(
            territory, passable, config.vision, starts=[tuple(rc) for rc in cells0.tolist()]
        )
        if config.policy in WALKERS:
            walkers = GraphWalkers(patrol_graph, config.policy, cells0, speed=config.speed)
        if graph:
            monitor = Monitor(
                patrol_graph, start_idleness=config.start_fog, robot_radius=config.radius
            )
            monitor.update(0.0, team.x, team.y)
    finder = (
        FINDERS[config.paths].build(passable, g.resolution) if config.paths in FINDERS else None
    )
    r0, c0 = g.world_to_cell(team.x, team.y)
    tour = np.empty((0, 2), dtype=np.int64)
    target = np.zeros(len(team), dtype=np.int64)
    if config.policy == "cycle":
        tour, _ = plan_tour(territory, passable, config.vision, (int(r0[0]), int(c0[0])))
        # Robots spread evenly along the tour: robot k joins it at the k-th share.
        target = (np.arange(len(team)) * len(tour)) // len(team)
    streets = (
        one_way(
            passable,
            territory.clearance,
            g.resolution,
            config.turn_radius,
            orient=config.one_way_orient if config.one_way else "dfs",
        )
        if config.one_way or config.stub_sight or config.stub_delay > 0
        else None
    )
    waver = Wave(passable.shape, streets.steps if streets is not None and config.one_way else None)
    stands = (
        stand_points(passable, watched, streets, g.resolution, config.vision - SIGHT_MARGIN)
        if streets is not None and (config.stub_sight or config.stub_delay > 0)
        else None
    )
    stand = stands if config.stub_sight else None
    # The places a car must drive into a stub to see, pulling as if seen later.
    deep = (
        stub_places(passable, watched, streets) & (stands < 0)
        if streets is not None and stands is not None and config.stub_delay > 0
        else None
    )
    if deep is not None and not deep.any():
        deep = None  # nothing delayed: no per-step copies of the fogs
    n_watched = int(watched.sum())
    # Wall-side cells no wave reaches pull from the nearest cell one does, so that no
    # place of the territory is left without a pull (on real maps a fifth of the cells
    # may be such). Only with the path motion: the thesis's straight-motion robots and
    # cars keep the thesis's pulls, so its experiments are unchanged.
    shade = (
        shadows(passable, watched, g.resolution)
        if config.policy == "potential"
        and config.motion == "path"
        and config.paths == "wave"
        and config.reach == "reachable"
        else None
    )
    watched_rc = np.nonzero(watched)
    # The potential field's pulls summed per wave step in one pass with the wave give
    # its direction at once, unless the path motion or other sectors need every place.
    # Tracking cars follow the path to a place: they need every place too.
    tracking = isinstance(team, Car) and team.planner == "track"
    direct = (
        config.policy == "potential"
        and config.motion == "straight"
        and (config.sectors == 8 or config.direction == "vector")
        and not tracking
    )

    def tb_of(
        i: int, rr: npt.NDArray[np.intp], cc: npt.NDArray[np.intp], dilated: list[F64] | None
    ) -> F64:
        """Robot i's TB of cells (rows, cols), from its dilated fog when there is one."""
        j = 0 if shared else i
        return dilated[j][rr, cc] if dilated is not None else own[j].tb_at(rr, cc)

    along_path = config.motion == "path"
    # A potential-field robot on its way to a kept goal needs only the path there: the
    # field's direction (always some step while the goal is unseen) is overridden by
    # the goal, and only consulted when the path gives no clear step -- then, and when
    # the goal is seen or cut off, the full field is worked out as before.
    # Its choice of step and of the place it goes for along it are settled once the
    # places left could change neither: the wave stops there.
    # Tracking cars choose their place the same way.
    certify_goal = (along_path or tracking) and config.sectors == 8 and config.policy == "potential"
    # Then the mode's step and that step's strongest place come straight from the pulls
    # summed with the wave, as the straight motion's direction does.
    direct_path = along_path and certify_goal and config.direction == "mode"
    places = np.full((8, 2), -1, dtype=np.int64)
    hold_fast = (
        ((along_path and penalty is None and isinstance(team, Holonomic)) or tracking)
        and config.keep_goal
        and config.policy == "potential"
        and config.direction == "mode"
        and config.paths == "wave"
    )
    # A new choice of place on blocks of cells, then the fine wave only as far as it.
    coarse = (
        CoarseChoice.build(passable, watched, g.resolution, config.choice_cell, fine_shadows=shade)
        if direct_path and hold_fast and config.choice_cell > 0 and not config.line_of_sight
        else None
    )
    # Path motion: the place each robot goes for, and when it chose it.
    aims: list[tuple[int, int] | None] = [None] * len(team)
    aimed_at = np.zeros(len(team))
    # Leftovers (``config.leftover``): when each car's place was last seen before it
    # chose it, and the cell its wave goes to for a leftover no wave reaches.
    aim_last = np.full(len(team), -np.inf)
    via: list[tuple[int, int] | None] = [None] * len(team)
    # The place each car chose (not a leftover): leftovers are looked for round it only.
    chosen: list[tuple[int, int] | None] = [None] * len(team)
    anchors = (
        wave_anchors(passable, watched) if tracking and hold_fast and config.leftover > 0 else None
    )
    # The places the robots go for: the watched ones but those the cars gave up.
    targets = watched
    giving_up = tracking and config.give_up > 0
    quitter = GiveUp(watched, max(1, config.give_up), disc_offsets(GIVE_UP_RADIUS, g.resolution))
    turns = team.turns.copy() if isinstance(team, Car) else np.zeros(0, dtype=np.int64)
    # How many places ``targets`` holds (counted again when it is another array).
    counted, n_targets = watched, n_watched
    # Tracking cars' masks, in buffers kept for the run (a fresh map-sized array per
    # car and step cost more than filling it): per fog the places out of sight and the
    # step they were made on, and the places ahead of the car being decided for.
    pulls_masks = tracking and (config.out_of_sight or config.turn_time > 0)
    unseen_of = [np.empty_like(watched) for _ in own] if pulls_masks else []
    n_unseen = np.zeros(len(own), dtype=np.int64)
    unseen_step = np.full(len(own), -1, dtype=np.int64)
    ahead_buffer = FreshAhead(watched.shape) if pulls_masks else None
    for k in range(steps):
        directions: list[tuple[float, float] | None] = []
        goals: list[tuple[float, float] | None] = []
        r, c = g.world_to_cell(team.x, team.y)
        # Each fog dilated once a step (with the full network, one for the whole team).
        dilated = [dilate(f.tb, config.dilation) for f in own] if config.dilation else None
        if deep is not None:
            dilated = [
                np.where(deep, np.maximum(tb - config.stub_delay, 0.0), tb)
                for tb in (dilated if dilated is not None else [f.tb for f in own])
            ]
        tops = [f.mtb() for f in own]
        if forward and config.forward_stale > 0:
            for j, f in enumerate(own):
                lifted[j] = stale(tops[j], config.forward_stale, f)
        if targets is not counted:
            counted, n_targets = targets, int(np.count_nonzero(targets))

        for i in range(len(team)):
            held = aims[i]
            mine_fog = own[0 if shared else i]
            if anchors is not None and held is not None and mine_fog.last[held] >= aimed_at[i]:
                left = nearest_leftover(
                    mine_fog,
                    targets,
                    chosen[i] or held,
                    float(aim_last[i]),
                    config.leftover,
                    anchors[2],
                )
                if left is not None:
                    # aim_last and the centre stay the chosen place's: the leftovers
                    # along a street's wall-side cells (none of which a wave reaches)
                    # would otherwise lead a car on from one to the next.
                    aims[i], aimed_at[i], held = left, mine_fog.t, left
                    via[i] = (int(anchors[0][left]), int(anchors[1][left]))
            closed: npt.NDArray[np.intp] | None = None
            if (
                hold_fast
                and held is not None
                and (
                    mine_fog.last[held] < aimed_at[i]
                    or (along_path and mine_fog.t - aimed_at[i] < config.min_hold - 1e-9)
                )
            ):
                start = (int(r[i]), int(c[i]))
                closed = closed_only(i, r, c, k)
                towards = held_goal(
                    team,
                    i,
                    start,
                    via[i] or held,
                    waver,
                    g,
                    passable,
                    targets,
                    closed,
                    config,
                    partial(
                        car_carrot,
                        targets=targets,
                        closed=partial(closed_only, i, r, c, k, True),
                        stand=stand,
                    )
                    if tracking
                    else path_goal,
                )
                if towards is not None:
                    directions.append(unit_towards(team, i, towards))
                    goals.append(towards)
                    continue
            top = tops[0 if shared else i]
            weights = (
                sector_weakening(
                    float(team.x[i]),
                    float(team.y[i]),
                    territory.free,
                    g,
                    config.sectors,
                    config.weaken_r0,
                )
                if config.weaken
                else None
            )
            if tracking and config.turn_penalty > 0:
                assert isinstance(team, Car)
                turn = turn_weights(float(team.heading[i]), team.behind, config.turn_penalty)
                weights = turn if weights is None else weights * turn
            step: npt.NDArray[np.int8] | None = None
            # The places this robot's choice weighs, and how many they are.
            pulling = targets
            n_pulling = n_targets
            if tracking and config.out_of_sight:
                j = 0 if shared else i
                if unseen_step[j] != k:
                    # targets & (last < t): the places its fog saw at the last look out;
                    # the same for every car sharing the fog, so once a step per fog.
                    np.copyto(unseen_of[j], targets)
                    n_unseen[j] = n_targets - own[j].clear_just_seen(unseen_of[j])
                    waver.forget_targets()
                    unseen_step[j] = k
                if n_unseen[j]:
                    pulling, n_pulling = unseen_of[j], int(n_unseen[j])
            # The places pulling before the turn-time rule took the fresh ones behind
            # out (None: it took none).
            unmasked: npt.NDArray[np.bool_] | None = None
            n_unmasked = 0
            if tracking and config.turn_time > 0:
                assert isinstance(team, Car)
                mine_fog = own[0 if shared else i]
                # pulling & ~fresh_behind(...), without a pass over the whole map. The
                # places pulling change only between steps (out of sight: once a step).
                assert ahead_buffer is not None
                ahead, n_dropped = ahead_buffer.make(
                    pulling,
                    k,
                    mine_fog,
                    float(team.x[i]),
                    float(team.y[i]),
                    float(team.heading[i]),
                    g,
                    team.behind,
                    config.turn_time,
                )
                waver.forget_targets()
                if n_dropped and n_pulling > n_dropped:
                    unmasked, n_unmasked = pulling, n_pulling
                    pulling, n_pulling = ahead, n_pulling - n_dropped
            if config.policy == "random":
                tbv = lengths = ux = uy = np.empty(0)
            elif config.paths == "wave" or config.policy == "cycle" or walkers is not None:
                start = (int(r[i]), int(c[i]))
                closed, behind = closed_cells(i, r, c, k)
                j = 0 if shared else i
                if (
                    coarse is not None
                    and closed is None
                    and targets is watched
                    and (held is None or own[j].last[held] >= aimed_at[i])
                ):
                    way, place, length = coarse.choose(
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
                    # The fine path to it; a place the fine wave cannot reach, or
                    # only by a path much longer than the blocks' (the blocks join what
                    # the cells do not; a shadow's anchor behind a wall), falls back on
                    # the fine choice.
                    if place is not None and np.isfinite(
                        waver.to(
                            passable,
                            start,
                            place,
                            g.resolution,
                            targets,
                            limit=COARSE_SLACK[0] * length + COARSE_SLACK[1],
                        )
                    ):
                        aims[i], aimed_at[i] = place, own[j].t
                        aim_last[i], via[i], chosen[i] = own[j].last[place], None, place
                        directions.append(way)
                        goals.append(path_goal(team, i, place, waver, g, passable, config))
                        continue
                if config.policy == "potential":
                    # Only the places near the robot can change its choice (see
                    # Force.pull_limit): the wave stops there unless told not to.
                    j = 0 if shared else i
                    pull_args: dict[str, Any] = {
                        "closed": closed,
                        "prune": config.prune,
                        "certify": config.direction == "mode" and (direct or certify_goal),
                        "weights": weights,
                        "goal": certify_goal,
                        "places": places,
                        "shadows": shade,
                        **(
                            {"tb": dilated[j]}
                            if dilated is not None
                            else {"last_seen": own[j].last, "now": own[j].t}
                        ),
                    }
                    # When only places just seen behind the car are within its reach (a
                    # car nose to nose with another), they pull as before, or it would
                    # stand until they age.
                    tries = (
                        [(pulling, n_pulling)]
                        if unmasked is None
                        else [(pulling, n_pulling), (unmasked, n_unmasked)]
                    )
                    # The dead-end test floods the passable cells, not the wave's
                    # allowed steps: a car facing the wrong way into a one-way street
                    # passes it while its forward wave, keeping to the one-way steps,
                    # reaches only a pocket of places in sight. Then nothing pulls and
                    # it would stand for good, so its wave runs in every direction.
                    for _ in range(2):
                        for pulling, n_pulling in tries:
                            strength = sector_pulls(
                                waver,
                                passable,
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
                        pull_args["closed"], behind = closed_cells(i, r, c, k, open_behind=True)
                    if direct:
                        directions.append(step_direction(strength, config.direction, weights))
                        goals.append(None)
                        continue
                    if direct_path:
                        way = step_direction(strength, "mode", weights)
                        directions.append(way)
                        goals.append(
                            path_goal(
                                team,
                                i,
                                aim(i, way, places, waver, own[j], aims, aimed_at, config),
                                waver,
                                g,
                                passable,
                                config,
                            )
                        )
                        continue
                else:
                    waver(passable, start, g.resolution, pulling, None, closed)
                rr, cc, step, lengths = waver.reached_in(pulling)
                tbv = tb_of(i, rr, cc, dilated)
                ux = STEP_UNITS[step, 0]
                uy = STEP_UNITS[step, 1]
            elif config.paths == "straight":
                rr, cc = watched_rc
                tbv = tb_of(i, rr, cc, dilated)
                lengths, ux, uy = straight_paths(team.x[i], team.y[i], cx[rr, cc], cy[rr, cc])
            else:
                assert finder is not None
                dist, gx, gy = finder.paths((int(r[i]), int(c[i])), watched)
                rr, cc = np.nonzero(watched & np.isfinite(dist))
                tbv = tb_of(i, rr, cc, dilated)
                lengths, ux, uy = dist[rr, cc], gx[rr, cc], gy[rr, cc]
            if walkers is not None:
                directions.append(
                    walk_step(
                        i,
                        walkers,
                        waver,
                        own[0 if shared else i],
                        config,
                        label == label[i],
                        bool(team.blocked[i]) and yielding[i] >= k,
                    )
                )
                goals.append(
                    path_goal(team, i, walkers.goal_cell(i), waver, g, passable, config)
                    if along_path
                    else None
                )
                continue
            if config.policy == "cycle":
                directions.append(follow_tour(i, tour, target, waver.dist, waver.first, config))
                way = (int(tour[target[i], 0]), int(tour[target[i], 1]))
                goals.append(
                    path_goal(team, i, way, waver, g, passable, config) if along_path else None
                )
                continue
            directions.append(
                choose(
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
                    rng=rng,
                    weights=weights,
                    top=top,
                    steps=step,
                )
            )
            goal: tuple[int, int] | None = None
            held = aims[i]
            mine = own[0 if shared else i]
            seek = along_path or tracking
            if (
                seek
                and config.keep_goal
                and held is not None
                and np.isfinite(waver.dist[held])
                and mine.last[held] < aimed_at[i]
            ):
                goal = held  # not seen since chosen: still worth the trip
            elif seek and step is not None:
                pick = (
                    reactive_pick(tbv, lengths)
                    if config.policy == "reactive"
                    else goal_index(
                        directions[-1],
                        step,
                        goal_pulls(config.policy, config.force, tbv, lengths, top),
                    )
                )
                goal = None if pick is None else (int(rr[pick]), int(cc[pick]))
                aims[i], aimed_at[i] = goal, mine.t
                aim_last[i] = mine.last[goal] if goal is not None else -np.inf
                via[i], chosen[i] = None, goal
            if tracking:
                goals.append(
                    car_carrot(
                        team,
                        i,
                        goal,
                        waver,
                        g,
                        passable,
                        config,
                        targets=pulling,
                        closed=partial(closed_only, i, r, c, k, True),
                        stand=stand,
                    )
                )
                if goals[-1] is not None:
                    # Steer for the point ahead on the path (refinement then moves it).
                    px, py = goals[-1]
                    vx, vy = px - float(team.x[i]), py - float(team.y[i])
                    norm = math.hypot(vx, vy)
                    if norm > 1e-9:
                        directions[-1] = (vx / norm, vy / norm)
                continue
            goals.append(path_goal(team, i, goal, waver, g, passable, config))
        if penalty is not None:
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
            directions, passable, g, config.dt, rng, goals if along_path or tracking else None
        )
        if team.give_way:
            give_way(
                team,
                yielding,
                k + yield_steps,
                config.min_separation + 2 * config.speed * config.dt,
            )
        if giving_up:
            assert isinstance(team, Car)
            for i in np.flatnonzero(team.turns > turns).tolist():
                held = aims[i]
                if held is not None and quitter.tried(held, own[0 if shared else i]):
                    aims[i] = None
            turns = team.turns.copy()
            targets = quitter.targets(fog)
            # Every robot going for a place given up chooses again.
            for j, a in enumerate(aims):
                if a is not None and not targets[a]:
                    aims[j] = None
        blocked += team.blocked
        escapes += team.escaping
        dvt[k] = 100.0 * escapes.mean() / (k + 1)
        moved_r, moved_c = g.world_to_cell(team.x, team.y)
        sems.update(np.asarray(moved_r), np.asarray(moved_c))
        fog.advance(config.dt)
        if not shared:
            for f in own:
                f.advance(config.dt)
        look()
        t_out[k] = (k + 1) * config.dt
        if monitor is not None:
            monitor.update(float(t_out[k]), team.x, team.y)
        mtb[k] = fog.mtb()
        mean_tb[k] = fog.mean_tb()
        if on_step is not None:
            on_step(float(t_out[k]), team, fog)
        if progress is not None:
            progress(k + 1, steps)
    never = fog.never_seen()
    stall_team = team if isinstance(team, Car) and team.planner == "track" else None
    return PatrolResult(
        t_out,
        mtb,
        mean_tb,
        np.column_stack([team.x, team.y, team.heading]),
        config,
        time.perf_counter() - wall0,
        blocked,
        fog.tb.copy(),
        escapes,
        dvt,
        watched,
        float(never[watched].mean()),
        reach=where,
        starts=np.array(starts, dtype=np.float64),
        never_seen=never,
        monitor=monitor,
        given_up=float(quitter.given[watched].mean()),
        stalls=stall_team.stalls.copy() if stall_team is not None else None,
        stall_watch=(stall_team.stall_radius, stall_team.stall_steps)
        if stall_team is not None
        else None,
    )
