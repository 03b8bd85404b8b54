"""Every setting of a patrol run (:class:`PatrolConfig`, the thesis's defaults and the
checks that refuse a bad one) and the fixed numbers of the model they name.

A field left unset is settled once, at construction (:class:`PatrolConfig`'s notes);
:data:`CAR_DEFAULTS` and :data:`PLAIN_DEFAULTS` are the values it then takes for a
tracking car and for every other robot. :func:`~sonarmap.patrol.simulation.run_patrol`
runs a configuration.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from ..errors import ConfigError
from ..grid import Grid
from .config import MAX_DILATION, MAX_SECTORS
from .finders import PathFinder
from .forces import Force
from .marching import Marching
from .network import NETWORKS
from .oneway import ORIENTS
from .policies import POLICIES
from .reach import MODES as REACH_MODES
from .regions import Regions
from .robots import SPEED_BANDS
from .walkers import WALKERS

__all__ = [
    "CAR_DEFAULTS",
    "CAR_PLANNERS",
    "CROWDING",
    "FINDERS",
    "FOLLOW_TIME",
    "GIVE_UP_RADIUS",
    "GIVE_WAY_TIME",
    "MAX_STEPS",
    "MODELS",
    "MOTIONS",
    "PATHS",
    "PATH_POLICIES",
    "PLAIN_DEFAULTS",
    "REACH_FIELDS",
    "SIGHT_MARGIN",
    "TRAFFIC",
    "PatrolConfig",
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
    #: Path motion (holonomic robots on the wave's paths) with the potential field (the
    #: mode of 8 steps, no dilation) and the full network, refused with any other
    #: setting: while a robot makes a new choice of place, the watched places within
    #: this many metres of a place another robot goes for (not seen since that robot
    #: chose it) pull as if just seen, so that two robots do not go for the same stale
    #: place (:mod:`~sonarmap.patrol.claims`). 0: every robot chooses from the fog
    #: alone, as the thesis has it.
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
    #: (:func:`~sonarmap.patrol.simulation.run_patrol` does) once the number of robots is
    #: known: until then it stays None, on the configuration and in :meth:`as_dict` (a
    #: run's summary holds the settled value, its configuration having been through
    #: :meth:`for_team`).
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
        if self.claim > 0:
            # Claims act on the potential field's own choice of place from the fog's
            # times (the mode's 8 steps); every other setting chooses from values they
            # never reach, and a claim there would be silently ignored.
            needs: tuple[tuple[str, object, object], ...] = (
                ("motion", self.motion, "path"),
                ("policy", self.policy, "potential"),
                ("direction", self.direction, "mode"),
                ("sectors", self.sectors, 8),
                ("dilation", self.dilation, 0),
            )
            for option, got, wanted in needs:
                if got != wanted:
                    raise ConfigError(f"claim needs {option} {wanted!r}, got {got!r}", field=option)
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
