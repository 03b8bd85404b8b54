"""The patrol's step loop and what a run measured.

Each step of ``dt`` seconds (0.5), every robot finds the path length L and first
direction to every watched cell (the wave, or straight lines), weighs every cell by
f(TB_n) g(L), chooses a direction (mode or vector sum) and the team moves by the
collision rule; then time passes and every robot sees the cells within its vision
radius. Each robot keeps its own fog, built from the positions it hears of
(:mod:`.network`); with the full network every robot's fog is the true fog. The metric
is always the true fog.

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
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..grid import Grid
from .claims import Claims
from .coarse import CoarseChoice
from .finders import PathFinder
from .fog import Fog, Vision, dilate, disc_cells, disc_offsets, disc_side
from .forces import Force, sector_pulls, step_direction
from .giveup import GiveUp
from .graph import PatrolGraph
from .manoeuvre import DeadEnds, FreshAhead, behind_cells, carrot, turn_weights
from .marching import Marching
from .monitor import Monitor
from .network import NETWORKS, components
from .oneway import ORIENTS, one_way
from .paths import STEP_UNITS, Wave, nearest_step, path_to, shadows, straight_paths
from .policies import POLICIES, choose, goal_pulls, reactive_pick
from .reach import MODES as REACH_MODES
from .reach import Reach, reach
from .refine import obstacle_penalty, refine_direction, sector_weakening
from .regions import Regions
from .robots import SPEED_BANDS, Car, Holonomic, Team
from .semaphores import Semaphores
from .starts import CarStarts, StartSource, check_starts, format_starts, spread_starts
from .stubs import stand_points, stub_places
from .territory import Territory, move_clear
from .tour import plan_tour
from .walkers import WALKERS, GraphWalkers

__all__ = [
    "CAR_DEFAULTS",
    "CROWDING",
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

#: Anti-crowding rules: none; artificial obstacles (each robot blocks, on its own
#: path-finding map, a disc of ``r_obst`` around every robot it hears of); semaphores
#: (:mod:`.semaphores`).
CROWDING = ("none", "obstacles", "semaphores")
#: Robot models: holonomic, or car-like (:class:`~sonarmap.patrol.robots.Car`).
MODELS = ("holonomic", "car")
#: How cars plan: ``track`` (pure pursuit along the wave's path to the place chosen,
#: hybrid-A* manoeuvres out of dead ends; :mod:`.manoeuvre`) or ``thesis`` (turn
#: towards the chosen direction, the thesis's reversing escape).
CAR_PLANNERS = ("track", "thesis")
#: How a holonomic robot moves: a full step straight along its chosen direction (the
#: thesis's), or a step along the wave's shortest path towards the place it goes for
#: (``path``: the strongest pull in the chosen direction, the reactive agent's place,
#: the tour's waypoint; no overshooting the narrow bands of door-ways, no jamming on
#: corners); ``auto`` is ``path`` where it applies (holonomic robots, the wave, a
#: policy with a place to go for, no refinement) and ``straight`` elsewhere.
MOTIONS = ("auto", "straight", "path")
#: What robots do when their moves would collide: ``thesis`` (both moves are cancelled)
#: or ``give-way`` (the later robot's move is cancelled first, and a robot so blocked
#: plans around the earlier robots near it for ``GIVE_WAY_TIME``, so that of two robots
#: meeting in a corridor one backs off and the other passes); ``auto`` is ``give-way``
#: with the path motion and ``thesis`` elsewhere.
TRAFFIC = ("auto", "thesis", "give-way")
#: Seconds a robot that gave way keeps planning around the robots it gave way to.
GIVE_WAY_TIME = 5.0
#: Seconds a tracking car with a forward wave whose way ahead only other robots shut
#: keeps its wave forwards before it may turn round (training street sites 0 and 1,
#: 3 and 5 cars, 600 s: the DVT of turning round for another robot fell from 3-10 % to
#: 1-7 % against none; 20 s was no better).
FOLLOW_TIME = 10.0
#: Metres within which a robot coming the other way ahead of a car driving on round
#: the block (``round_block``) shuts its way: one farther off may turn off before they
#: meet, so the car keeps on rather than turn round for it (chosen on training street
#: sites, docs/results/2026-12-06-cars.md).
ONCOMING_NEAR = 10.0
#: Metres around a place the cars give up within which the never-seen places go too.
GIVE_UP_RADIUS = 2.0
#: Metres short of the vision radius within which a place in a stub must lie of its
#: stand point (``stub_sight``): a car passing a cell beside that point still sees it.
SIGHT_MARGIN = 1.0
#: Policies the path motion can follow.
PATH_POLICIES = ("potential", "reactive", "gravity", "cycle", *WALKERS)
#: Path-finders built once per run for the static map (:mod:`.regions`, :mod:`.marching`).
FINDERS: dict[str, type[PathFinder]] = {"regions": Regions, "marching": Marching}
#: Every path-finding: the wave, straight lines (open space) and the static finders.
PATHS = ("wave", "straight", *FINDERS)
#: A tracking car's defaults on the potential field's wave paths (``car_planner``
#: 'track', ``policy`` 'potential', ``paths`` 'wave'): the setting chosen on the
#: training street sites (docs/results/2026-12-07-cars-defaults.md). A field left unset
#: (NaN, or None for a switch) takes its value here for such a car and its
#: :data:`PLAIN_DEFAULTS` value (the thesis's) for every other robot.
CAR_DEFAULTS: dict[str, float | bool] = {
    "forward_wave": True,
    "forward_stale": 10.0,
    "turn_penalty": 10.0,
    "turn_time": 30.0,
    "out_of_sight": True,
    "round_block": 60.0,
    # For a team of more than one car (:meth:`PatrolConfig.for_team`); a lone car
    # drives every street both ways.
    "one_way": True,
}
#: The values of :data:`CAR_DEFAULTS`'s fields for every other robot: the thesis's
#: pulls and shortest paths.
PLAIN_DEFAULTS: dict[str, float | bool] = {
    "forward_wave": False,
    "forward_stale": 0.0,
    "turn_penalty": 0.0,
    "turn_time": 0.0,
    "out_of_sight": False,
    "round_block": 0.0,
    "one_way": False,
}

F64 = npt.NDArray[np.float64]
#: A place chosen on blocks (:class:`~sonarmap.patrol.coarse.CoarseChoice`) is refused,
#: and the fine choice made instead, when its fine path is longer than this factor times
#: the blocks' path plus these metres (the blocks' 8-connected paths run up to a block
#: off the cells' at either end).
COARSE_SLACK = (1.25, 2.0)
#: The most steps one run may take (about 58 days at 0.5 s): more is a typo.
MAX_STEPS = 10_000_000


#: PatrolConfig's lengths in metres that size a window, a search, a ray or a block:
#: :meth:`PatrolConfig.check_reach` refuses them past the map's diagonal.
REACH_FIELDS = ("choice_cell", "refine_window", "refine_side", "refine_goal", "weaken_r0", "r_obst")


@dataclass(frozen=True)
class PatrolConfig:
    """Every number of a patrol run, with the thesis's defaults.

    The fields left unset (NaN, or None for a switch) are settled once, at
    construction: the lengths by the robot's ``radius``, ``motion`` and ``traffic``
    ('auto') by the robots and paths, and :data:`CAR_DEFAULTS`'s fields by
    :attr:`car_tuned` (``one_way`` alone waits for :meth:`for_team`). A copy made with
    :func:`dataclasses.replace` does not settle them again: it passes on the settled
    values as if given, so ``replace(PatrolConfig(model="car"), forward_wave=False)``
    is refused (``forward_stale`` 10 without a forward wave) and
    ``replace(PatrolConfig(motion="straight"), model="car")`` keeps the plain values
    though :attr:`car_tuned` is then True (all but ``one_way``, still unset, which
    :meth:`for_team` settles for a car). To change the robot, policy, paths or one of
    :data:`CAR_DEFAULTS`'s fields, build a new configuration from the fields given
    (or set every dependent field in the ``replace`` call).
    """

    policy: str = "potential"
    model: str = "holonomic"
    motion: str = "auto"
    force: Force = field(default_factory=Force)
    direction: str = "mode"
    sectors: int = 8
    paths: str = "wave"
    network: str = "full"
    r_max: float = 70.0
    dilation: int = 0
    crowding: str = "none"
    traffic: str = "auto"
    #: Path motion: a robot keeps the place it goes for until it (or, with the full
    #: network, any robot) has seen it, or it cannot be reached; False chooses again
    #: every step (two places whose paths leave in opposite directions can then hold
    #: a robot swinging between two cells).
    keep_goal: bool = True
    #: Path motion with ``keep_goal``: a holonomic robot keeps the place it goes for at
    #: least this long after choosing it (seconds), even once it has been seen, while
    #: the place can be reached and is more than a step away: each choice runs a wave
    #: over the places that could change it, and a place chosen just beyond the vision
    #: radius is seen a step or two later. 0: choose again as soon as it is seen.
    min_hold: float = 0.0
    #: Path motion (potential field, the mode's 8 steps, holonomic robots): the side,
    #: in metres, of the blocks a new choice of place is made on
    #: (:class:`~sonarmap.patrol.coarse.CoarseChoice`; the nearest whole number of
    #: cells); the fine wave then runs only as far as the place chosen. 0, or under two
    #: cells (as with the default 0.5 m cells), or with ``line_of_sight`` (the block's
    #: place stands for cells it may not see): the choice's wave runs on the fog's own
    #: cells.
    choice_cell: float = 0.3
    #: Path motion (holonomic robots on the wave's paths; read by no other motion) with
    #: the potential field and the full network: while a robot makes
    #: a new choice of place, the watched places within this many metres of a place
    #: another robot goes for (not seen since that robot chose it) pull as if just
    #: seen, so that two robots do not go for the same stale place
    #: (:mod:`~sonarmap.patrol.claims`). 0: every robot chooses from the fog alone, as
    #: the thesis has it.
    claim: float = 0.0
    #: Artificial obstacles' radius; NaN: three times the robot's radius (3 m).
    r_obst: float = math.nan
    refine: bool = False
    weaken: bool = False
    weaken_r0: float = 5.5
    refine_window: float = 10.0
    refine_goal: float = 2.5
    refine_side: float = 2.0
    radius: float = 1.0
    speed: float = 4.4
    #: Least distance between centres; NaN: twice the robot's radius (2 m).
    min_separation: float = math.nan
    p_random: float = 0.1
    turn_radius: float = 3.5
    #: How cars plan (:data:`CAR_PLANNERS`).
    car_planner: str = "track"
    #: Track: how far along the path the car's pure-pursuit point lies, metres.
    lookahead: float = 3.0
    #: Track: a car's wave leaves forwards (the cells up to 4 m behind it closed,
    #: :func:`~sonarmap.patrol.manoeuvre.behind_cells`) unless the way ahead is a dead
    #: end; False runs it from the car's cell in every direction. Its dead-end test
    #: floods the map from the car every step, up to half of it. None (the default):
    #: True for a tracking car on the potential field's wave paths
    #: (:data:`CAR_DEFAULTS`), else False.
    forward_wave: bool | None = None
    #: Track with ``forward_wave``: on a step when the worst time since seen of the
    #: watched places in a car's fog exceeds this many times the mean time since seen
    #: over those seen at least once, the car's wave runs in every direction (the
    #: forward wave lifted), so that a place the driving-on paths never lead to is still
    #: gone for. A place never seen counts in the worst (its time since the start, plus
    #: ``start_fog``) but not in the mean; the places given up (``give_up``) count as
    #: every watched place does, so one given up and never seen keeps the wave lifted
    #: once it is stale enough. The test reads the fog as the step's choice does, as
    #: the robots saw at the end of the step before: a lift ends one step after the
    #: stale place is seen. 0: never lifted. NaN (the default): 10 for a tracking car
    #: on the potential field's wave paths with ``forward_wave`` (:data:`CAR_DEFAULTS`),
    #: else 0.
    forward_stale: float = math.nan
    #: Track: reversing manoeuvres on the way to a never-seen place after which the cars
    #: stop going for it and the never-seen places within :data:`GIVE_UP_RADIUS` (until
    #: one is seen; they still count in every metric); 0: never give up.
    give_up: int = 3
    #: Track: the lead in log pull (the potential field's, e^(a TB_n) e^(-L^2/b^2)) a
    #: place whose path leaves more than the car's ``behind`` angle off its heading
    #: needs over the places ahead (:func:`~sonarmap.patrol.manoeuvre.turn_weights`):
    #: turning round takes a reversing manoeuvre on streets narrower than a car's
    #: turning circle. 0: every place pulls as the thesis has it. NaN (the default):
    #: 10 for a tracking car on the potential field's wave paths (:data:`CAR_DEFAULTS`),
    #: else 0.
    turn_penalty: float = math.nan
    #: Track: seconds a car's turning round costs. The places its fog saw less than
    #: this long ago (the team's sight when the fog is shared; never the places never
    #: seen) that lie more than its ``behind`` angle off its heading
    #: (:func:`~sonarmap.patrol.manoeuvre.fresh_behind`) do not pull on it: going for
    #: one it turns round, a reversing manoeuvre on streets narrower than its turning
    #: circle, and sees it about that much later than it was last seen, gaining
    #: nothing. A car that has everything ahead in its team's sight (a car coming the
    #: other way, the street ahead just driven) otherwise goes for the nearest place
    #: out of sight, just behind its own vision's edge. When no other place pulls,
    #: they pull as before. 0: every place pulls, as the thesis has it. NaN (the
    #: default): 30 for a tracking car on the potential field's wave paths
    #: (:data:`CAR_DEFAULTS`), else 0.
    turn_time: float = math.nan
    #: Track: only the places out of a car's sight (not seen on this step) pull on it
    #: (all do when every place is in sight); False: every watched place does, as the
    #: thesis has it. A place in sight pulls (f(0) = 1 under f3), and by the mass of
    #: such places near the car the mode can name a place the car is looking at: going
    #: for it a car turns on the spot, which on streets narrower than its turning circle
    #: is a reversing manoeuvre. None (the default): True for a tracking car on the
    #: potential field's wave paths (:data:`CAR_DEFAULTS`), else False.
    out_of_sight: bool | None = None
    #: Track: metres of extra path a car accepts to drive on and round the block
    #: rather than turn round: when its path leaves more than its ``behind`` angle off
    #: its heading, it takes instead the shortest path that leaves forwards (the cells
    #: up to 4 m behind it closed, :func:`~sonarmap.patrol.manoeuvre.behind_cells`) if
    #: that is at most this much longer. On a street grid a loop round a block has no
    #: reversing, where turning round on a street narrower than the turning circle
    #: does. 0: the shortest path, as the thesis's wave has it. NaN (the default): 60
    #: for a tracking car on the potential field's wave paths (:data:`CAR_DEFAULTS`),
    #: else 0.
    round_block: float = math.nan
    #: Track: one-way streets (:mod:`.oneway`): every street narrower than the cars'
    #: turning circle that is no bridge of the street graph (dead-end stubs are) gets a
    #: direction, so that every place can still be reached from every other, and the
    #: cars' waves take its cells only that way: two cars never meet head-on in such a
    #: street, and a place behind is reached round the block. Every car derives the
    #: same system from the map. Needs ``paths`` 'wave' (the only path-finding that
    #: keeps to the allowed steps). False: every street two-way. None (the default):
    #: True for a team of more than one tracking car on the potential field's wave
    #: paths (:data:`CAR_DEFAULTS`), else False, settled by :meth:`for_team`
    #: (:func:`run_patrol` does) once the number of robots is known: until then it
    #: stays None, on the configuration and in :meth:`as_dict` (a run's summary holds
    #: the settled value, its configuration having been through :meth:`for_team`).
    one_way: bool | None = None
    #: Track: the directions of the one-way streets (``one_way``), each strongly
    #: connected (:data:`~sonarmap.patrol.oneway.ORIENTS`): 'dfs' (the default), a
    #: depth-first search's, with no regard to detours; 'short', that one improved by a
    #: local search that shortens the paths between the streets
    #: (:func:`~sonarmap.patrol.oneway.one_way`), whose cost at the run's start grows
    #: about with the cube of the number of one-way streets. Read only when
    #: ``one_way`` is on.
    one_way_orient: str = "dfs"
    #: Track: a car does not drive into a dead-end stub (narrower than the turning
    #: circle, :attr:`~sonarmap.patrol.oneway.OneWay.stubs`) for a place it can see from
    #: the junction the stub opens on: its route to a place in a stub within ``vision``
    #: less :data:`SIGHT_MARGIN` of that junction's skeleton cell ends there
    #: (:func:`~sonarmap.patrol.stubs.stand_points`).
    #: Needs ``line_of_sight`` False (a place within the disc is then in sight). False
    #: (the default): the route runs to the place.
    stub_sight: bool = False
    #: Track: seconds later than it was that a place in a dead-end stub a car must enter
    #: to see (one without a stand point, :func:`~sonarmap.patrol.stubs.stand_points`)
    #: pulls as if seen: backing out of a stub is a reversing manoeuvre, so such places
    #: are gone for less often. 0 (the default): they pull as any place; at most
    #: ``duration``. Needs ``line_of_sight`` False; with it or ``stub_sight``, ``vision``
    #: must be at least :data:`SIGHT_MARGIN`.
    stub_delay: float = 0.0
    #: Track: metres round the place a car chose within which, once that place is
    #: seen, the places no wave reaches (beyond the last cell a car's centre may be on
    #: and the step past it) that its looks missed and that had been seen no later than
    #: the chosen place had when chosen (never seen, or as stale) are its next places,
    #: the nearest first, until none is left; then it chooses afresh. The car's wave
    #: goes for such a place's anchor, the nearest cell a wave ends at; a leftover whose
    #: anchor cannot be reached on a step is dropped for a fresh choice. Leftovers are
    #: looked for round the chosen place only, never round a leftover. 0 (the default):
    #: none, the car chooses afresh once its place is seen. Needs ``model`` 'car',
    #: ``car_planner`` 'track', ``keep_goal``, ``policy`` 'potential', ``direction``
    #: 'mode' and ``paths`` 'wave'.
    leftover: float = 0.0
    #: The car's speed rule: (nearest obstacle closer than metres, km/h), in order.
    speed_bands: tuple[tuple[float, float], ...] = SPEED_BANDS
    vision: float = 10.0
    line_of_sight: bool = False
    dt: float = 0.5
    duration: float = 3600.0
    warmup: float | None = None
    start_fog: float = 0.0
    #: Cell of fog and paths; NaN: 0.5 m, or half the robot's radius when smaller (a
    #: coarse cell would close doors a small robot passes).
    cell: float = math.nan
    #: Stop each robot's wave where farther places can no longer change its choice
    #: (:func:`~sonarmap.patrol.forces.sector_pulls`: their pulls together fall below
    #: float64 precision, or, for the mode's choice, below the lead of the strongest
    #: step); False runs every wave over the whole map. The runs are the same either way.
    prune: bool = True
    #: The places watched: ``reachable`` (what the robots can get to from the starts,
    #: :mod:`.reach`) or ``free`` (every free cell, the thesis's reading).
    reach: str = "reachable"

    def __post_init__(self) -> None:
        # Lengths left unset follow the robot's size, as the thesis's do (1 m robots,
        # 2 m apart); a frozen dataclass sets them once, here.
        if math.isnan(self.min_separation):
            object.__setattr__(self, "min_separation", 2.0 * self.radius)
        if math.isnan(self.r_obst):
            object.__setattr__(self, "r_obst", 3.0 * self.radius)
        if math.isnan(self.cell):
            object.__setattr__(self, "cell", min(0.5, self.radius / 2))
        defaults = CAR_DEFAULTS if self.car_tuned else PLAIN_DEFAULTS
        for name, value in defaults.items():
            now = getattr(self, name)
            if name == "one_way" or not (
                now is None or (isinstance(now, float) and math.isnan(now))
            ):
                continue  # one_way waits for the team (for_team); a value given wins
            if name == "forward_stale" and not self.forward_wave:
                value = PLAIN_DEFAULTS[name]
            object.__setattr__(self, name, value)
        if self.direction not in ("mode", "vector"):
            raise ConfigError(
                f"unknown direction {self.direction!r}; valid: mode, vector", field="direction"
            )
        if self.model not in MODELS:
            raise ConfigError(
                f"unknown robot model {self.model!r}; valid: {', '.join(MODELS)}", field="model"
            )
        if self.car_planner not in CAR_PLANNERS:
            raise ConfigError(
                f"unknown car planner {self.car_planner!r}; valid: {', '.join(CAR_PLANNERS)}",
                field="car_planner",
            )
        if self.motion not in MOTIONS:
            raise ConfigError(
                f"unknown motion {self.motion!r}; valid: {', '.join(MOTIONS)}", field="motion"
            )
        fits_path = (
            self.model == "holonomic" and self.paths == "wave" and self.policy in PATH_POLICIES
        )
        if self.motion == "auto":
            chosen = "path" if fits_path and not self.refine else "straight"
            object.__setattr__(self, "motion", chosen)
        if self.traffic not in TRAFFIC:
            raise ConfigError(
                f"unknown traffic rule {self.traffic!r}; valid: {', '.join(TRAFFIC)}",
                field="traffic",
            )
        if self.traffic == "auto":
            rule = "give-way" if self.motion == "path" else "thesis"
            object.__setattr__(self, "traffic", rule)
        if self.motion == "path" and not fits_path:
            raise ConfigError(
                "motion 'path' follows the wave's paths with holonomic robots (--model "
                f"holonomic --paths wave --policy {'/'.join(PATH_POLICIES)})",
                field="motion",
            )
        if self.motion == "path" and self.refine:
            raise ConfigError(
                "motion 'path' already keeps to the path: drop --refine", field="refine"
            )
        if self.paths not in PATHS:
            raise ConfigError(
                f"unknown path-finding {self.paths!r}; valid: {', '.join(PATHS)}", field="paths"
            )
        if self.paths in FINDERS and self.crowding != "none":
            # Both crowding rules edit each robot's map every step; only the wave follows.
            raise ConfigError(
                f"path-finding {self.paths!r} is built once for a static map and cannot "
                f"follow the map edits of crowding {self.crowding!r}; use the wave",
                field="paths",
            )
        if self.reach not in REACH_MODES:
            raise ConfigError(
                f"unknown territory mode {self.reach!r}; valid: {', '.join(REACH_MODES)}",
                field="reach",
            )
        if self.policy not in POLICIES:
            raise ConfigError(
                f"unknown policy {self.policy!r}; valid: {', '.join(POLICIES)}", field="policy"
            )
        if self.network not in NETWORKS:
            raise ConfigError(
                f"unknown network {self.network!r}; valid: {', '.join(NETWORKS)}", field="network"
            )
        if not (self.r_max >= 0):
            raise ConfigError(f"r_max must be >= 0 metres, got {self.r_max}", field="r_max")
        for name in (
            "radius",
            "speed",
            "vision",
            "dt",
            "duration",
            "cell",
            "turn_radius",
            "lookahead",
            "min_separation",
            "weaken_r0",
            "refine_window",
            "refine_goal",
            "refine_side",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be > 0, got {v}", field=name)
        if not (math.isfinite(self.turn_penalty) and self.turn_penalty >= 0):
            raise ConfigError(
                f"turn_penalty must be >= 0, got {self.turn_penalty}", field="turn_penalty"
            )
        if not (math.isfinite(self.turn_time) and self.turn_time >= 0):
            raise ConfigError(
                f"turn_time must be >= 0 seconds, got {self.turn_time}", field="turn_time"
            )
        if self.turn_time > 0 and (self.policy != "potential" or self.paths != "wave"):
            raise ConfigError(
                "turn_time > 0 needs policy 'potential' and paths 'wave', got "
                f"{self.policy!r} and {self.paths!r}",
                field="turn_time",
            )
        if not (math.isfinite(self.forward_stale) and self.forward_stale >= 0):
            raise ConfigError(
                f"forward_stale must be >= 0, got {self.forward_stale}", field="forward_stale"
            )
        if self.forward_stale > 0 and not self.forward_wave:
            raise ConfigError("forward_stale needs forward_wave", field="forward_stale")
        if not (math.isfinite(self.round_block) and self.round_block >= 0):
            raise ConfigError(
                f"round_block must be >= 0 metres, got {self.round_block}", field="round_block"
            )
        if self.one_way_orient not in ORIENTS:
            raise ConfigError(
                f"unknown one_way_orient {self.one_way_orient!r}; valid: {', '.join(ORIENTS)}",
                field="one_way_orient",
            )
        if self.one_way and not (self.model == "car" and self.car_planner == "track"):
            raise ConfigError(
                "one_way applies to tracking cars only (model 'car', car_planner 'track')",
                field="one_way",
            )
        if self.stub_sight and not (self.model == "car" and self.car_planner == "track"):
            raise ConfigError(
                "stub_sight applies to tracking cars only (model 'car', car_planner 'track')",
                field="stub_sight",
            )
        if not (math.isfinite(self.stub_delay) and self.stub_delay >= 0):
            raise ConfigError(
                f"stub_delay must be >= 0 seconds, got {self.stub_delay}", field="stub_delay"
            )
        if self.stub_delay > 0 and not (
            self.model == "car" and self.car_planner == "track" and not self.line_of_sight
        ):
            raise ConfigError(
                "stub_delay applies to tracking cars seeing a disc (model 'car', "
                "car_planner 'track', line_of_sight False)",
                field="stub_delay",
            )
        if not (math.isfinite(self.leftover) and self.leftover >= 0):
            raise ConfigError(
                f"leftover must be >= 0 metres, got {self.leftover}", field="leftover"
            )
        if self.leftover > 0 and not (
            self.model == "car"
            and self.car_planner == "track"
            and self.keep_goal
            and self.policy == "potential"
            and self.direction == "mode"
            and self.paths == "wave"
        ):
            # Leftovers are the next places a car keeps going for: without a kept goal
            # on the mode's wave paths there is nothing to act on.
            raise ConfigError(
                "leftover applies to tracking cars keeping their goal (model 'car', "
                "car_planner 'track', keep_goal True, policy 'potential', direction 'mode', "
                "paths 'wave')",
                field="leftover",
            )
        if self.stub_delay > self.duration:
            # A delay past the mission's end never wears off: the place never pulls.
            raise ConfigError(
                f"stub_delay must be at most duration ({self.duration} s), got {self.stub_delay}",
                field="stub_delay",
            )
        if (self.stub_sight or self.stub_delay > 0) and self.vision < SIGHT_MARGIN:
            # Stand points lie within vision less SIGHT_MARGIN of a place.
            raise ConfigError(
                f"vision must be >= {SIGHT_MARGIN} m with stub_sight or stub_delay "
                f"(stand points within vision less {SIGHT_MARGIN} m), got {self.vision}",
                field="vision",
            )
        if self.stub_sight and self.line_of_sight:
            # Behind a wall a place within the disc is not in sight: a car standing at
            # the junction might never see it.
            raise ConfigError("stub_sight needs line_of_sight False", field="stub_sight")
        if self.one_way and self.paths != "wave":
            # Only the wave keeps to the allowed steps: straight and marching paths
            # would drive against the streets.
            raise ConfigError(
                f"one_way needs paths 'wave', got paths {self.paths!r}", field="one_way"
            )
        if not (0 <= self.give_up <= 1000):
            raise ConfigError(f"give_up must be in 0..1000, got {self.give_up}", field="give_up")
        if self.crowding not in CROWDING:
            raise ConfigError(
                f"unknown crowding rule {self.crowding!r}; valid: {', '.join(CROWDING)}",
                field="crowding",
            )
        if not (math.isfinite(self.r_obst) and self.r_obst > 0):
            raise ConfigError(f"r_obst must be > 0 metres, got {self.r_obst}", field="r_obst")
        if not (0.0 <= self.p_random <= 1.0):
            raise ConfigError(f"p_random must be in [0, 1], got {self.p_random}", field="p_random")
        if not (math.isfinite(self.start_fog) and self.start_fog >= 0):
            raise ConfigError(
                f"start_fog must be >= 0 seconds, got {self.start_fog}", field="start_fog"
            )
        # Upper bounds: each step's cost grows with the sectors and with the square of
        # the dilation, so absurd values would run for days rather than fail.
        from .config import MAX_DILATION, MAX_SECTORS

        if not (1 <= self.sectors <= MAX_SECTORS):
            raise ConfigError(
                f"sectors must be in 1..{MAX_SECTORS}, got {self.sectors}", field="sectors"
            )
        if not (0 <= self.dilation <= MAX_DILATION):
            raise ConfigError(
                f"dilation must be in 0..{MAX_DILATION} cells, got {self.dilation}",
                field="dilation",
            )
        if round(self.duration / self.dt) < 1:
            raise ConfigError(
                f"duration {self.duration:g} s is shorter than one step of {self.dt:g} s",
                field="duration",
            )
        if self.duration / self.dt > MAX_STEPS:
            raise ConfigError(
                f"duration {self.duration:g} s is {self.duration / self.dt:.3g} steps of "
                f"{self.dt:g} s; at most {MAX_STEPS:,} steps",
                field="duration",
            )
        if not (math.isfinite(self.min_hold) and self.min_hold >= 0):
            raise ConfigError(
                f"min_hold must be >= 0 seconds, got {self.min_hold}", field="min_hold"
            )
        if not (math.isfinite(self.claim) and self.claim >= 0):
            raise ConfigError(f"claim must be >= 0 metres, got {self.claim}", field="claim")
        if self.claim > 0 and self.network != "full":
            # A robot knows where the others go only when it hears them all.
            raise ConfigError(f"claim needs network 'full', got {self.network!r}", field="claim")
        if not (math.isfinite(self.choice_cell) and self.choice_cell >= 0):
            raise ConfigError(
                f"choice_cell must be >= 0 metres, got {self.choice_cell}", field="choice_cell"
            )
        if self.warmup is not None and not (0 <= self.warmup < self.duration):
            raise ConfigError(f"warmup must be in [0, duration), got {self.warmup}", field="warmup")

    @property
    def car_tuned(self) -> bool:
        """Whether the fields left unset take :data:`CAR_DEFAULTS` (a tracking car on
        the potential field's wave paths) rather than :data:`PLAIN_DEFAULTS`."""
        return (
            self.model == "car"
            and self.car_planner == "track"
            and self.policy == "potential"
            and self.paths == "wave"
        )

    def for_team(self, robots: int) -> PatrolConfig:
        """This configuration for a team of ``robots``, ``one_way`` settled when left
        unset (None): :data:`CAR_DEFAULTS`'s for more than one tracking car on the
        potential field's wave paths, else False.

        Parameters
        ----------
        robots : int
            The number of robots.

        Returns
        -------
        PatrolConfig
            This one when ``one_way`` is set, else a copy with it set.
        """
        if self.one_way is not None:
            return self
        on = self.car_tuned and robots > 1 and bool(CAR_DEFAULTS["one_way"])
        return replace(self, one_way=on)

    def check_reach(self, grid: Grid) -> None:
        """Refuse a length in metres (:data:`REACH_FIELDS`) longer than ``grid``'s
        diagonal and than the field's default (which a small map keeps).

        Past the diagonal a window, search, ray or choice block means nothing more,
        and it allocated (or searched) that many cells: 1e9 m ran out of memory.

        Raises
        ------
        ConfigError
            Naming the first such field.
        """
        diagonal = math.hypot(grid.rows, grid.cols) * grid.resolution
        defaults = PatrolConfig()
        for name in REACH_FIELDS:
            value, default = float(getattr(self, name)), float(getattr(defaults, name))
            limit = max(diagonal, default) if math.isfinite(default) else diagonal
            if math.isfinite(value) and value > limit:
                raise ConfigError(
                    f"{name} {value:g} m: at most the map's diagonal, {diagonal:.3g} m",
                    field=name,
                )

    @property
    def warmup_s(self) -> float:
        return self.duration / 5 if self.warmup is None else self.warmup

    def as_dict(self) -> dict[str, Any]:
        """The fields as plain values, the force as its name and parameters and
        ``warmup`` in seconds; ``one_way`` is None until :meth:`for_team` settles it."""
        d = asdict(self)
        d["force"] = self.force.name
        d["force_a"], d["force_b_dm"] = self.force.a, self.force.b
        d["warmup"] = self.warmup_s
        return d


@dataclass
class PatrolResult:
    """Per step: time, MTB(t), mean TB(t); and the robots' final state."""

    t: F64
    mtb: F64
    mean_tb: F64
    positions: F64
    config: PatrolConfig
    wall_seconds: float
    blocked_steps: npt.NDArray[np.int64]
    #: TB of every cell at the end.
    final_tb: F64
    #: Steps each robot spent in the dead-end escape mode (cars only).
    escape_steps: npt.NDArray[np.int64]
    #: The team's mean DVT so far, in %, after each step.
    dvt: F64
    #: The cells the metric watches (:attr:`Reach.watched`).
    watched: npt.NDArray[np.bool_]
    #: Share of the watched cells no robot ever saw.
    unseen: float = 0.0
    #: What the team patrolled and what was left out (:mod:`.reach`).
    reach: Reach | None = None
    #: World (x, y, heading) of every robot at the start.
    starts: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    #: Watched cells no robot ever saw.
    never_seen: npt.NDArray[np.bool_] | None = None
    #: patrolling_sim's metrics on the patrol graph (``run_patrol(graph=True)``).
    monitor: Monitor | None = None
    #: Share of the watched cells the cars had given up at the end (:mod:`.giveup`).
    given_up: float = 0.0
    #: Tracking cars: the stalls each car was found in (:meth:`.robots.Car.unstall`);
    #: None for other robots.
    stalls: npt.NDArray[np.int64] | None = None
    #: Tracking cars: the stall watch's ``stall_radius`` (m) and ``stall_steps``,
    #: recorded in ``summary.json``'s params; None for other robots.
    stall_watch: tuple[float, int] | None = None

    def dvt_per_robot(self) -> F64:
        """Share of the run each robot spent escaping dead ends, in %."""
        return 100.0 * self.escape_steps / max(1, len(self.t))

    def summary(self) -> dict[str, Any]:
        after = self.t > self.config.warmup_s
        return {
            "mean_mtb": float(self.mtb[after].mean()) if after.any() else math.nan,
            "mean_mtb_all_steps": float(self.mtb.mean()),
            "worst_idleness": float(self.mtb.max()),
            "mean_idleness": float(self.mean_tb[after].mean()) if after.any() else math.nan,
            # Holonomic robots never enter the dead-end escape mode: 0 for them.
            "dvt": float(self.dvt_per_robot().mean()),
            "dvt_per_robot": [round(float(v), 3) for v in self.dvt_per_robot()],
            "blocked_share": float(self.blocked_steps.sum() / (len(self.t) * len(self.positions))),
            # Places no robot has seen yet: while any is left, MTB(t) is the time itself
            # and the mean MTB says only that the run was too short.
            "never_seen": self.unseen,
            # Never-seen places tracking cars stopped going for (they still count above).
            "given_up": self.given_up,
            **(self.reach.summary() if self.reach is not None else {}),
            "steps": len(self.t),
            "sim_seconds": float(self.t[-1]) if len(self.t) else 0.0,
            "wall_seconds": round(self.wall_seconds, 3),
            "robots": len(self.positions),
            **({"graph": self.monitor.summary()} if self.monitor is not None else {}),
            **(
                {"stalls": int(self.stalls.sum()), "stalls_per_robot": self.stalls.tolist()}
                if self.stalls is not None
                else {}
            ),
        }

    def metrics_csv(self) -> str:
        """``metrics.csv``: per step its number (from 1), time (s), MTB (s), mean TB (s)
        and the team's mean DVT so far (%)."""
        import csv
        import io

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["step", "t", "mtb", "mean_tb", "dvt"])
        for k in range(len(self.t)):
            w.writerow(
                [
                    k + 1,
                    f"{self.t[k]:g}",
                    f"{self.mtb[k]:g}",
                    f"{self.mean_tb[k]:.4g}",
                    f"{self.dvt[k]:.4g}",
                ]
            )
        return buf.getvalue()

    def batch_output(self, period: int = 1) -> str:
        """The thesis's batch output: ``step MTB DVT`` every ``period`` steps."""
        period = max(1, int(period))
        rows = [
            f"{k + 1} {self.mtb[k]:g} {self.dvt[k]:.4g}"
            for k in range(len(self.t))
            if (k + 1) % period == 0
        ]
        return "\n".join(rows) + "\n"

    def write(
        self,
        folder: str | Path,
        territory: Territory,
        *,
        seed: int,
        source: str = "",
        batch: tuple[str, int] | None = None,
        animation: Any = None,
    ) -> list[Path]:
        """Write the run's results into ``folder``, all or none (atomically).

        Parameters
        ----------
        folder : str or path-like
            The output folder, created (or replaced) whole.
        territory : Territory
            The territory patrolled (for ``fog.png`` and the cell size).
        seed : int
            The run's seed, recorded in ``summary.json``.
        source : str
            The map's name or file, recorded in ``summary.json``.
        batch : (str, int), optional
            The thesis's batch output: a file name (in ``folder``) and its period in
            steps (``setup.json``'s ``output_file`` and ``log_period_steps``).
        animation : sonarmap.plot.FogAnimation, optional
            Frames recorded during the run, saved as ``patrol.gif``.

        Returns
        -------
        list of Path
            The files written: ``metrics.csv``, ``summary.json``, ``fog.png``,
            ``starts.txt`` (the starts used, in the start-file format); with the patrol
            graph's monitor ``idleness.csv`` (the idleness of its vertices over time),
            ``vertices.csv`` (per vertex) and ``idleness.png``; then the batch output
            and ``patrol.gif`` when asked for.
        """
        # Imported here: the plotting stack is only needed to write.
        from ..files import atomic_folder, atomic_write_text, json_dumps
        from ..plot import save_fog_picture, save_idleness_plot

        out = Path(folder)
        robots = self.summary()["robots"]
        names = ["metrics.csv", "summary.json", "fog.png", "starts.txt"]
        with atomic_folder(out) as tmp:
            atomic_write_text(tmp / "starts.txt", format_starts(self.starts, territory))
            if animation is not None:
                animation.title = f"{self.config.policy}, {robots} robots"
                animation.save(tmp / "patrol.gif")
            atomic_write_text(tmp / "metrics.csv", self.metrics_csv())
            if batch is not None:
                name = Path(batch[0]).name
                atomic_write_text(tmp / name, self.batch_output(batch[1]))
                names.append(name)
            summary: dict[str, Any] = {
                **self.summary(),
                "map": source,
                "cell_m": territory.grid.resolution,  # the cell used (whole map pixels)
                "seed": seed,
                "params": {
                    **self.config.as_dict(),
                    **(
                        {"stall_radius": self.stall_watch[0], "stall_steps": self.stall_watch[1]}
                        if self.stall_watch is not None
                        else {}
                    ),
                },
            }
            atomic_write_text(tmp / "summary.json", json_dumps(summary) + "\n")
            if self.monitor is not None:
                atomic_write_text(tmp / "idleness.csv", self.monitor.idleness_csv())
                atomic_write_text(tmp / "vertices.csv", self.monitor.per_vertex_csv())
                save_idleness_plot(
                    self.monitor.idleness_series(),
                    tmp / "idleness.png",
                    title=f"{robots} robots, {len(self.monitor.graph)} patrol-graph vertices",
                )
                names += ["idleness.csv", "vertices.csv", "idleness.png"]
            save_fog_picture(
                territory.grid,
                territory.free,
                self.final_tb,
                self.positions,
                tmp / "fog.png",
                radius=self.config.radius,
                title=f"{robots} robots, t = {self.t[-1]:.0f} s",
                outside=territory.free & ~self.watched,
                unknown=territory.unknown,
                never_seen=self.never_seen,
            )
        if animation is not None:
            names.append("patrol.gif")
        return [out / n for n in names]


def _follow_tour(
    i: int,
    tour: npt.NDArray[np.int64],
    target: npt.NDArray[np.int64],
    dist: F64,
    first: npt.NDArray[np.int8],
    config: PatrolConfig,
) -> tuple[float, float] | None:
    """Robot i's step along the tour: towards its waypoint, the next one once there."""
    for _ in range(len(tour)):
        tr, tc = tour[target[i]]
        # Within one step counts as there: a move of a full step along one of 8
        # directions could otherwise circle the waypoint for ever.
        if first[tr, tc] >= 0 and dist[tr, tc] > config.speed * config.dt:
            k = int(first[tr, tc])
            return float(STEP_UNITS[k, 0]), float(STEP_UNITS[k, 1])
        target[i] = (target[i] + 1) % len(tour)
    return None


def _walk(
    i: int,
    walkers: GraphWalkers,
    waver: Wave,
    fog: Fog,
    config: PatrolConfig,
    heard: npt.NDArray[np.bool_],
    stuck: bool,
) -> tuple[float, float] | None:
    """Robot i's step towards its graph vertex, the next one once within a step of it,
    another one when it cannot be reached or ``stuck`` (it gave way and was blocked
    again: two walkers head-on on one edge push against each other for good otherwise);
    None (stand) while no neighbour can be reached. ``heard``: the robots whose
    intentions robot i hears."""
    r, c = walkers.goal_cell(i)
    cells = walkers.graph.cells
    if waver.dist[r, c] <= config.speed * config.dt:
        walkers.arrive(i, fog.t, fog.last[cells[:, 0], cells[:, 1]], heard)
        r, c = walkers.goal_cell(i)
    if stuck or not np.isfinite(waver.dist[r, c]):
        reachable = np.isfinite(waver.dist[cells[:, 0], cells[:, 1]])
        walkers.reroute(i, fog.t, fog.last[cells[:, 0], cells[:, 1]], reachable, heard)
        r, c = walkers.goal_cell(i)
    k = int(waver.first[r, c])
    if k < 0:
        return None
    return float(STEP_UNITS[k, 0]), float(STEP_UNITS[k, 1])


def _goal_index(
    direction: tuple[float, float] | None, step: npt.NDArray[np.int8], lp: F64
) -> int | None:
    """The place with the strongest pull ``lp`` among those whose first step is the
    one nearest ``direction`` (None when there is none)."""
    if direction is None or not len(lp):
        return None
    mine = np.flatnonzero(step == nearest_step(*direction))
    if not len(mine):
        return None
    return int(mine[int(np.argmax(lp[mine]))])


def _earlier_near(team: Team, i: int, near: float) -> npt.NDArray[np.bool_]:
    """Which of robots 0 .. i-1 are within ``near`` metres of robot i."""
    out: npt.NDArray[np.bool_] = np.hypot(team.x[:i] - team.x[i], team.y[:i] - team.y[i]) < near
    return out


def _give_way(team: Team, until: npt.NDArray[np.int64], step: int, near: float) -> None:
    """Robots blocked with an earlier robot within ``near`` metres plan around the
    earlier robots near them until ``step``."""
    for i in np.flatnonzero(team.blocked).tolist():
        if _earlier_near(team, i, near).any():
            until[i] = step


def _path_goal(
    team: Team,
    i: int,
    cell: tuple[int, int] | None,
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    config: PatrolConfig,
) -> tuple[float, float] | None:
    """Where robot i gets to in one step along the wave's shortest path to ``cell``
    (path motion; None when there is no cell or no clear step)."""
    if cell is None or not np.isfinite(waver.dist[cell]) or waver.dist[cell] <= 0:
        return None
    cells = path_to(waver.dist, cell, g.resolution, passable, waver.allowed)
    px, py = g.cell_centres(cells[1:, 0], cells[1:, 1])
    x0, y0 = float(team.x[i]), float(team.y[i])
    x, y = x0, y0
    left = config.speed * config.dt
    # The farthest point a step along the path reaches that the robot can go to in a
    # straight line (a corner of the path may hide the rest).
    reach: tuple[float, float] | None = None
    for qx, qy in zip(px.tolist(), py.tolist(), strict=True):
        d = math.hypot(qx - x, qy - y)
        end = (x + (qx - x) * left / d, y + (qy - y) * left / d) if d >= left else (qx, qy)
        if not move_clear(x0, y0, end[0], end[1], passable, g):
            break
        reach = end
        if d >= left:
            break
        x, y, left = qx, qy, left - d
    return reach


def _mean_seen_tb(fog: Fog) -> float:
    """The mean time since seen over ``fog``'s watched places seen at least once
    (inf when none has been)."""
    seen = fog.watched & ~fog.never_seen()
    if not seen.any():
        return math.inf
    return float(fog.t - fog.last[seen].mean())


def _stale(top: float, ratio: float, fog: Fog) -> bool:
    """Whether ``top`` (the fog's MTB) exceeds ``ratio`` times the mean time since seen
    of the places ``fog`` has seen (:func:`_mean_seen_tb`; ``config.forward_stale``).

    Decided on the fog's running mean (:meth:`~sonarmap.patrol.fog.Fog.mean_seen_tb`)
    unless that is within a millionth of the line, where its last bits could matter:
    then on the mean of the cells, as the rule is stated."""
    mean = fog.mean_seen_tb()
    line = ratio * mean
    if math.isfinite(line) and abs(top - line) <= 1e-6 * max(abs(top), abs(line), 1.0):
        return top > ratio * _mean_seen_tb(fog)
    return top > line


def _wave_anchors(
    passable: npt.NDArray[np.bool_], watched: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.bool_]]:
    """Per cell, the row and column of the nearest watched cell a wave over
    ``passable`` with the watched cells as its targets can end at (a passable cell, or
    a watched one a step from one): where a car's wave goes for a place that no wave
    reaches (a stub's far corner beyond the last cell its centre may be on), and the
    watched cells that are no such end (a wave's places pull for them from their
    anchors)."""
    from scipy import ndimage

    ends = watched & ndimage.binary_dilation(passable, structure=np.ones((3, 3), dtype=bool))
    if not ends.any():
        own: npt.NDArray[np.intp] = np.indices(passable.shape, dtype=np.intp)
        return own[0], own[1], np.zeros_like(watched)
    _, (ar, ac) = ndimage.distance_transform_edt(~ends, return_indices=True)
    return ar.astype(np.intp), ac.astype(np.intp), watched & ~ends


def _leftover(
    fog: Fog,
    targets: npt.NDArray[np.bool_],
    place: tuple[int, int],
    before: float,
    radius: float,
    shade: npt.NDArray[np.bool_],
) -> tuple[int, int] | None:
    """The nearest of the ``targets`` in ``shade`` (the places no wave reaches:
    beyond the last cell a car's centre may be on and the step past it) within
    ``radius`` metres of ``place`` last seen
    no later than ``before`` (the time ``place`` had last been seen when a car chose it;
    never-seen places are last seen before every time), by ``fog``: a place the look
    that saw ``place`` missed and as worth the trip as it was; None when there is none
    (``config.leftover``)."""
    res = fog.grid.resolution
    k = math.floor(radius / res + 1e-9)
    r0, c0 = place
    rows, cols = fog.last.shape
    ra, rb, ca, cb = max(0, r0 - k), min(rows, r0 + k + 1), max(0, c0 - k), min(cols, c0 + k + 1)
    window = (fog.last[ra:rb, ca:cb] <= before) & targets[ra:rb, ca:cb] & fog.watched[ra:rb, ca:cb]
    window &= shade[ra:rb, ca:cb]
    rr, cc = np.nonzero(window)
    if not len(rr):
        return None
    d = np.hypot(rr + ra - r0, cc + ca - c0) * res
    near = d <= radius + 1e-9
    if not near.any():
        return None
    j = int(np.flatnonzero(near)[np.argmin(d[near])])
    return int(rr[j] + ra), int(cc[j] + ca)


def _held_goal(
    team: Team,
    i: int,
    start: tuple[int, int],
    held: tuple[int, int],
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    watched: npt.NDArray[np.bool_],
    closed: npt.NDArray[np.intp] | None,
    config: PatrolConfig,
    towards: Callable[..., tuple[float, float] | None],
) -> tuple[float, float] | None:
    """Robot i's point ahead towards the place it keeps going for, from a wave run only
    as far as that place: ``towards`` (:func:`_path_goal` or :func:`_car_carrot`) of
    that wave; None when the place cannot be reached or there is no point off the
    robot."""
    if not np.isfinite(waver.to(passable, start, held, g.resolution, watched, closed)):
        return None
    point: tuple[float, float] | None = towards(team, i, held, waver, g, passable, config)
    if (
        point is None
        or math.hypot(point[0] - float(team.x[i]), point[1] - float(team.y[i])) <= 1e-9
    ):
        return None
    return point


def _aim(
    i: int,
    way: tuple[float, float] | None,
    places: npt.NDArray[np.int64],
    waver: Wave,
    fog: Fog,
    aims: list[tuple[int, int] | None],
    aimed_at: F64,
    config: PatrolConfig,
) -> tuple[int, int] | None:
    """The place robot i goes for on the path motion: the one it keeps while unseen
    since chosen and reachable, else the strongest place along its step ``way``
    (``places`` per step, from :func:`sector_pulls`), noted in ``aims`` and
    ``aimed_at``."""
    held = aims[i]
    if (
        config.keep_goal
        and held is not None
        and np.isfinite(waver.dist[held])
        and fog.last[held] < aimed_at[i]
    ):
        return held
    goal = None
    if way is not None:
        r, c = places[nearest_step(*way)]
        goal = None if r < 0 else (int(r), int(c))
    aims[i], aimed_at[i] = goal, fog.t
    return goal


def _unit_towards(team: Team, i: int, point: tuple[float, float]) -> tuple[float, float]:
    """The unit vector from robot i to ``point`` (not at the robot)."""
    dx, dy = point[0] - float(team.x[i]), point[1] - float(team.y[i])
    n = math.hypot(dx, dy)
    return dx / n, dy / n


def _car_carrot(
    team: Team,
    i: int,
    cell: tuple[int, int] | None,
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    config: PatrolConfig,
    targets: npt.NDArray[np.bool_] | None = None,
    closed: Callable[[], npt.NDArray[np.intp] | None] | None = None,
    stand: npt.NDArray[np.int64] | None = None,
) -> tuple[float, float] | None:
    """Car i's route (the wave's shortest path to ``cell``, set on the car) and its
    pure-pursuit point ``config.lookahead`` metres along it; None when there is none.

    ``stand`` (:func:`~sonarmap.patrol.stubs.stand_points`): a place in a stub with a
    stand point the wave has reached (not the car's own cell) is gone for by the route
    to that point instead, from which the car sees it.

    With ``config.round_block`` a route whose pursuit point lies behind the car is
    replaced by the shortest one that leaves forwards (:func:`_forward_route`), when
    that is at most ``round_block`` metres longer: ``targets`` are the wave's targets
    and ``closed()`` the cells closed on it (without the discs round the cars ahead
    going the car's way, which it follows). ``waver`` may then hold that wave."""
    assert isinstance(team, Car)
    team.routes[i] = None
    if stand is not None and cell is not None and stand[cell] >= 0:
        at = (int(stand[cell]) // stand.shape[1], int(stand[cell]) % stand.shape[1])
        if np.isfinite(waver.dist[at]) and waver.dist[at] > 0:
            cell = at
    if cell is None or not np.isfinite(waver.dist[cell]) or waver.dist[cell] <= 0:
        return None
    x, y = float(team.x[i]), float(team.y[i])
    route = _route(team, i, path_to(waver.dist, cell, g.resolution, passable, waver.allowed), g)
    point = carrot(route, x, y, config.lookahead)
    if config.round_block > 0 and team.is_behind(i, point):
        shut = closed() if closed is not None else None
        forward = _forward_route(team, i, cell, waver, g, passable, config, targets, shut)
        if forward is not None:
            route = forward
            point = carrot(route, x, y, config.lookahead)
    team.routes[i] = route
    return point


def _followed(team: Team, i: int, near: float = ONCOMING_NEAR) -> npt.NDArray[np.bool_]:
    """Which robots ahead of robot i (in front of it along its heading) it may follow
    rather than turn round for: those heading within 90 deg of its heading, and any
    farther than ``near`` metres."""
    h = float(team.heading[i])
    along = (team.x - team.x[i]) * math.cos(h) + (team.y - team.y[i]) * math.sin(h)
    far = np.hypot(team.x - team.x[i], team.y - team.y[i]) > near
    out: npt.NDArray[np.bool_] = (along > 0) & ((np.cos(team.heading - h) > 0) | far)
    out[i] = False
    return out


def halves_discs(config: PatrolConfig) -> bool:
    """Whether a robot's artificial obstacles are only the other robot's side of each
    disc (:func:`obstacle_discs`): tracking cars. A whole disc round each of two of
    them nearer than ``2 r_obst`` shuts every cell about both, and neither has a path
    or a direction: both stand for good. The thesis's car escapes at random instead,
    and keeps the thesis's whole discs."""
    return config.model == "car" and config.car_planner == "track"


def obstacle_discs(
    team: Team,
    i: int,
    cells: npt.NDArray[np.intp],
    disc: npt.NDArray[np.int64],
    shape: tuple[int, int],
    *,
    halve: bool,
    following: bool = False,
    near: float = ONCOMING_NEAR,
    heard: npt.NDArray[np.bool_] | None = None,
) -> list[npt.NDArray[np.intp]]:
    """The cells robot i closes round the other robots with artificial obstacles.

    Parameters
    ----------
    team : Team
        The robots (positions and headings, world metres and radians).
    i : int
        The robot planning.
    cells : ndarray of int, shape (N, 2)
        Every robot's (row, column) cell.
    disc : ndarray of int, shape (K, 2)
        The disc's cell offsets (:func:`~sonarmap.patrol.fog.disc_offsets` of ``r_obst``).
    shape : tuple of int
        The map's (rows, columns); cells off it are dropped.
    halve : bool
        Keep only each disc's cells nearer the other robot than robot i
        (:func:`halves_discs`).
    following : bool
        For a car driving on rather than turning round (``round_block``): no disc
        round the robots ahead of it going its way, nor round those ahead farther than
        ``near`` (default False: a disc round every other robot).
    near : float
        Metres beyond which a robot ahead coming the other way is followed too
        (default :data:`ONCOMING_NEAR`; ``inf``: only those going its way).
    heard : ndarray of bool, shape (N,), optional
        The robots robot i hears of (default: all).

    Returns
    -------
    list of ndarray of int, shape (K_j, 2)
        One array of (row, column) pairs per robot closed, in robot order.
    """
    n = len(team)
    ahead = _followed(team, i, near) if following else np.zeros(n, dtype=np.bool_)
    others = np.ones(n, dtype=np.bool_) if heard is None else heard
    mine = (int(cells[i, 0]), int(cells[i, 1]))
    out: list[npt.NDArray[np.intp]] = []
    for j in np.flatnonzero(others & ~ahead).tolist():
        if j == i:
            continue
        # With ``halve``, the disc's cells nearer the other robot than robot i: an
        # artificial obstacle that never shuts the cells about the robot planning, so
        # two robots closer than twice its radius can still part.
        side = disc_side(disc, int(cells[j, 0]), int(cells[j, 1]), shape, mine if halve else None)
        out.append(side.astype(np.intp, copy=False))
    return out


def _route(team: Team, i: int, cells: npt.NDArray[np.int64], g: Grid) -> F64:
    """World points (K, 2) of a path's ``cells``, the first at robot i itself."""
    px, py = g.cell_centres(cells[:, 0], cells[:, 1])
    route = np.column_stack([px, py]).astype(np.float64)
    route[0] = team.x[i], team.y[i]
    return route


def _forward_route(
    team: Car,
    i: int,
    cell: tuple[int, int],
    waver: Wave,
    g: Grid,
    passable: npt.NDArray[np.bool_],
    config: PatrolConfig,
    targets: npt.NDArray[np.bool_] | None,
    closed: npt.NDArray[np.intp] | None,
) -> F64 | None:
    """Car i's shortest route to ``cell`` with the cells up to 4 m behind it closed (it
    drives on and round the block), if that is at most ``config.round_block`` metres
    longer than the shortest (``waver.dist`` on entry); None otherwise, or at a dead
    end (no such route). Runs a wave on ``waver``."""
    r, c = (int(v) for v in g.world_to_cell(team.x[i], team.y[i]))
    back = behind_cells(float(team.x[i]), float(team.y[i]), float(team.heading[i]), g)
    shut = back if closed is None else np.concatenate([closed, back])
    limit = float(waver.dist[cell]) + config.round_block
    length = waver.to(passable, (r, c), cell, g.resolution, targets, shut, limit=limit)
    if not np.isfinite(length):
        return None
    return _route(team, i, path_to(waver.dist, cell, g.resolution, passable, waver.allowed), g)


def car_starts(
    territory: Territory, passable: npt.NDArray[np.bool_], config: PatrolConfig
) -> CarStarts:
    """Where ``config``'s cars can start on ``passable`` and facing where
    (:class:`~sonarmap.patrol.starts.CarStarts`: its turning radius, speed rule and
    step)."""
    return CarStarts(territory, passable, config.turn_radius, config.speed_bands, config.dt)


def check_given_starts(
    starts: F64,
    territory: Territory,
    config: PatrolConfig,
    region: npt.NDArray[np.bool_] | None = None,
    source: StartSource | None = None,
) -> Reach:
    """Refuse given starts the run cannot use; the territory reachable from them.

    Every start inside the map (and ``region``), on a free cell the robot's radius fits,
    ``config.min_separation`` from the others; for cars, a pose some step's arc leaves
    (:meth:`~sonarmap.patrol.starts.CarStarts.check`).

    Parameters
    ----------
    starts : ndarray (N, 3)
        World (x, y, heading) per robot.
    territory : Territory
        The map.
    config : PatrolConfig
        The run's configuration (radius, separation, reach, the car's turning).
    region : ndarray of bool, optional
        The user's territory mask on the territory's grid; default None (the whole map).
    source : StartSource, optional
        Where the starts came from, for the message (a start file's path and lines);
        default: world poses.

    Returns
    -------
    Reach
        What the team can patrol from these starts (:func:`~sonarmap.patrol.reach.reach`).

    Raises
    ------
    InputError
        The first start refused, naming the robot and its pose (and file and line).
    """
    inside = territory.passable(config.radius)
    if region is not None:
        inside = inside & region
    check_starts(starts, territory, inside, config.min_separation, source)
    rc = np.column_stack(territory.grid.world_to_cell(starts[:, 0], starts[:, 1]))
    where = reach(
        territory,
        config.radius,
        starts=rc,
        region=region,
        mode=config.reach,
        vision=config.vision,
    )
    if config.model == "car":
        # A car that can never move from its start would waste the run.
        car_starts(territory, where.passable, config).check(starts, source)
    return where


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
    if starts is None:
        if robots is None or robots < 1:
            raise ConfigError("give start positions or a number of robots >= 1")
        where = reach(
            territory, config.radius, region=region, mode=config.reach, vision=config.vision
        )
        if config.model == "car":
            starts = car_starts(territory, where.passable, config).spread(
                robots, config.min_separation, seed
            )
        else:
            starts = spread_starts(robots, territory, where.passable, config.min_separation, seed)
    else:
        where = check_given_starts(starts, territory, config, region, start_source)
    passable = where.passable
    team: Team
    if config.model == "car":
        team = Car(
            starts[:, 0].copy(),
            starts[:, 1].copy(),
            starts[:, 2].copy(),
            radius=config.radius,
            min_separation=config.min_separation,
            p_random=config.p_random,
            give_way=config.traffic == "give-way",
            clearance=territory.clearance,
            turn_radius=config.turn_radius,
            bands=config.speed_bands,
            planner=config.car_planner,
        )
    else:
        team = Holonomic(
            starts[:, 0].copy(),
            starts[:, 1].copy(),
            starts[:, 2].copy(),
            radius=config.radius,
            speed=config.speed,
            min_separation=config.min_separation,
            p_random=config.p_random,
            give_way=config.traffic == "give-way",
        )
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
            near = _earlier_near(team, i, yield_range)
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
    # Places the other robots go for pull a robot's new choice as if seen (claim).
    claims = (
        Claims(config.claim, g.resolution) if config.claim > 0 and shared and along_path else None
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
        _wave_anchors(passable, watched) if tracking and hold_fast and config.leftover > 0 else None
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
                lifted[j] = _stale(tops[j], config.forward_stale, f)
        if targets is not counted:
            counted, n_targets = targets, int(np.count_nonzero(targets))

        for i in range(len(team)):
            held = aims[i]
            mine_fog = own[0 if shared else i]
            if anchors is not None and held is not None and mine_fog.last[held] >= aimed_at[i]:
                left = _leftover(
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
                towards = _held_goal(
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
                        _car_carrot,
                        targets=targets,
                        closed=partial(closed_only, i, r, c, k, True),
                        stand=stand,
                    )
                    if tracking
                    else _path_goal,
                )
                if towards is not None:
                    directions.append(_unit_towards(team, i, towards))
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
                    marks = (
                        claims.mark(
                            own[j].last, own[j].t, claims.others(i, aims, aimed_at, own[j].last)
                        )
                        if claims is not None
                        else []
                    )
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
                    Claims.restore(own[j].last, marks)
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
                        goals.append(_path_goal(team, i, place, waver, g, passable, config))
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
                    marks = (
                        claims.mark(
                            own[j].last, own[j].t, claims.others(i, aims, aimed_at, own[j].last)
                        )
                        if claims is not None
                        else []
                    )
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
                    Claims.restore(own[j].last, marks)
                    if direct:
                        directions.append(step_direction(strength, config.direction, weights))
                        goals.append(None)
                        continue
                    if direct_path:
                        way = step_direction(strength, "mode", weights)
                        directions.append(way)
                        goals.append(
                            _path_goal(
                                team,
                                i,
                                _aim(i, way, places, waver, own[j], aims, aimed_at, config),
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
                    _walk(
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
                    _path_goal(team, i, walkers.goal_cell(i), waver, g, passable, config)
                    if along_path
                    else None
                )
                continue
            if config.policy == "cycle":
                directions.append(_follow_tour(i, tour, target, waver.dist, waver.first, config))
                way = (int(tour[target[i], 0]), int(tour[target[i], 1]))
                goals.append(
                    _path_goal(team, i, way, waver, g, passable, config) if along_path else None
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
                    else _goal_index(
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
                    _car_carrot(
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
            goals.append(_path_goal(team, i, goal, waver, g, passable, config))
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
            _give_way(
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
