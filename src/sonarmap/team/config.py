"""The settings of a robot's mission (:class:`MissionConfig`): every number of
:mod:`.mission`, whose notes give the choices where the thesis is silent."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError
from ..parallel import MIN_PROCESS_LIMIT, PROCESSES_PER_CORE, process_limit
from .association import AssociationParams
from .store import StoreParams, pose_floor

__all__ = [
    "MAX_DURATION",
    "MAX_ROBOTS",
    "MissionConfig",
    "check_team_size",
    "team_size_problem",
]

#: Robots in one team at most. The exchange's traffic and the simulated network's
#: pairs grow with the square of the team (64 robots: 4032 links); the thesis's teams
#: have a handful of robots.
MAX_ROBOTS = 64

#: Seconds of one mission at most: a day of simulated time. A route holds two poses a
#: second and each robot's store grows with its route, so a mission of 10^12 s would
#: try to build a route of 2 x 10^12 poses before anything else (the thesis's
#: missions last minutes).
MAX_DURATION = 86_400.0


def team_size_problem(robots: int, *, processes: bool = False) -> str | None:
    """What is wrong with a team of ``robots`` robots, or None.

    Parameters
    ----------
    robots : int
        The team's size.
    processes : bool
        The robots run as local processes (:func:`~.launcher.run_zmq_team`), one each:
        :func:`sonarmap.parallel.process_limit` bounds them too.

    Returns
    -------
    str or None
        The reason without the value, e.g. ``"at most 64 robots in a team"``.
    """
    if isinstance(robots, bool) or not isinstance(robots, int) or robots < 1:
        return "expected an int >= 1"
    if robots > MAX_ROBOTS:
        return f"at most {MAX_ROBOTS} robots in a team"
    limit = process_limit()
    if processes and robots > limit:
        return (
            f"at most {limit} node processes on this machine ({PROCESSES_PER_CORE} per "
            f"core, at least {MIN_PROCESS_LIMIT}); use --transport sim"
        )
    return None


def check_team_size(robots: int, *, processes: bool = False) -> None:
    """Refuse a team too large to run, before any work (:func:`team_size_problem`).

    Raises
    ------
    ConfigError
        With ``field="robots"``.
    """
    problem = team_size_problem(robots, processes=processes)
    if problem is not None:
        raise ConfigError(f"robots {robots!r}: {problem}", field="robots")


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
    #: deviations of 0.15 m (worst direction) and 2.5 degrees, chosen on training plans
    #: (docs/results/2026-12-03-team-code-notes.md).
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
    #: The layer gate (:mod:`~sonarmap.team.layergate`): a closure between two layers
    #: (an own pose and a received one, or two received layers) must agree, by a
    #: chi-square test at 99 %, with where the robot currently places those layers.
    #: Off: on the training warehouse it left out 121 closures, 119 of them right
    #: (docs/results/2026-12-07-team-received-closures.md).
    layer_gate: bool = False
    #: Pairwise consistency (:mod:`~sonarmap.team.pcm`): before each batch's graph,
    #: judge each new closure once by its loops with the other closures of its pair of
    #: layers through the layers' odometry (chi-square at 99 %), and reject it when
    #: two or more of those loops fail.
    pcm: bool = False

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
                raise ConfigError(f"{name} must be > 0, got {v}", field=name)
        if self.duration > MAX_DURATION:
            raise ConfigError(
                f"duration {self.duration:g} s: at most {MAX_DURATION:g} s (a day)",
                field="duration",
            )
        if self.batch < 1:
            raise ConfigError(f"batch must be >= 1, got {self.batch}", field="batch")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}", field="seed")
        n = self.local_cells()
        floor = pose_floor(self.store, n)
        if self.store.pose_limit < floor:
            # Pose compression drops landmarks, never map cells: found here, not mid-run.
            raise ConfigError(
                f"store: pose_limit {self.store.pose_limit} B is below the size of a pose "
                f"with one landmark and its {n} x {n} local map ({floor} B)",
                field="pose_limit",
            )

    def local_cells(self) -> int:
        """Cells along a side of a pose's local map (``local_size`` / ``local_resolution``,
        at least 2)."""
        return max(2, round(self.local_size / self.local_resolution))
