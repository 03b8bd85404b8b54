"""Robots moving with the thesis's collision rule: holonomic robots and cars.

Every robot is a disc (radius 1 m). A move is possible when every point of its path
over the step keeps the disc clear of obstacles and inside the map (the territory's
passable cells). Robots must keep ``min_separation`` (2 m) between centres: if the
chosen moves of several robots make a collision possible on a step, the moves of all
of those robots are cancelled for that step (repeated until no possible collision is
left, since a cancelled robot stays where another may be heading). With ``give_way``
(not the thesis's) of two robots whose moves collide only one stops, so that one of
two robots meeting in a corridor keeps its way (:func:`cancel_collisions`).

- :class:`Holonomic`: stands or moves at full speed (4.4 m/s) in a straight line along
  its chosen direction, turning at once. While blocked (its move cancelled), each step
  it goes in a random direction instead with probability ``p_random`` (10 %).
- :class:`Car`: a car-like robot (turning radius 3.5 m forward and reverse, speed by the
  nearest obstacle, the dead-end escape instead of random moves).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..grid import Grid
from .manoeuvre import Manoeuvre, carrot, clear_goals, plan_manoeuvre, route_goals
from .paths import STEPS, nearest_step
from .territory import move_clear, points_clear

__all__ = [
    "SPEED_BANDS",
    "STALL_WAIT_CAP",
    "UNSTALL_SEARCH",
    "Car",
    "FineSearch",
    "Holonomic",
    "Team",
    "arc",
    "band_speed",
    "cancel_collisions",
    "close_pairs",
    "wrap_angle",
]

F64 = npt.NDArray[np.float64]

#: Why a tracking car manoeuvres: held by the collision rule (``traffic``), its path
#: behind it (``behind``), no clear forward arc along it (``ahead``), or no manoeuvre
#: found, the thesis's escape (``fallback``).
CAUSES = ("traffic", "behind", "ahead", "fallback")
#: Track: the most steps a fallback on the thesis's escape runs before the car plans
#: again (10 s at 0.5 s a step); it ends once the car is aligned.
ESCAPE_STEPS = 20


@dataclass(frozen=True)
class FineSearch:
    """The finer manoeuvre search of a stalled car (:meth:`Car.unstall`): the keywords
    of :func:`~sonarmap.patrol.manoeuvre.plan_manoeuvre` it changes.

    Parameters
    ----------
    headings : int
        Heading bins; each arc turns by one (a 64th of the turning circle: 0.34 m at
        3.5 m). Default 64.
    bin_size : float
        Side of the position bins, metres; default 0.25.
    budget : int
        Expansions at most; default 6,000.
    """

    headings: int = 64
    bin_size: float = 0.25
    budget: int = 6000


#: Track: the finer search of a stalled car: short arcs and small bins, so that a car
#: askew in a street whose passable cells are one wide (where the ordinary search's
#: 1.4 m arcs leave the cells at once) can straighten up by short shunts.
UNSTALL_SEARCH = FineSearch()
#: Track: after each failed search of a stalled car (:meth:`Car.unstall`) its wait
#: before the next doubles, up to this many times ``stall_steps`` (160 s at the
#: defaults): a car no search frees does not run one every 10 s for the whole run.
STALL_WAIT_CAP = 16


@dataclass
class Team:
    """What every team has: positions, headings and who was blocked or is escaping.

    Attributes
    ----------
    x, y, heading : ndarray of float64
        Positions (metres) and headings (radians) of the robots.
    blocked : ndarray of bool
        Whose move was cancelled on the last step.
    escaping : ndarray of bool
        Who is in the dead-end escape mode (cars only).
    """

    x: F64
    y: F64
    heading: F64
    radius: float = 1.0
    min_separation: float = 2.0
    p_random: float = 0.1
    #: Collisions cancel the later robot's move first (:func:`cancel_collisions`).
    give_way: bool = False
    blocked: npt.NDArray[np.bool_] = field(init=False)
    escaping: npt.NDArray[np.bool_] = field(init=False)

    def __post_init__(self) -> None:
        for name in ("radius", "min_separation"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"robot {name} must be > 0, got {v}")
        if not (0.0 <= self.p_random <= 1.0):
            raise ConfigError(f"p_random must be in [0, 1], got {self.p_random}")
        self.blocked = np.zeros(len(self.x), dtype=bool)
        self.escaping = np.zeros(len(self.x), dtype=bool)

    def __len__(self) -> int:
        return len(self.x)

    def step(
        self,
        directions: list[tuple[float, float] | None],
        passable: npt.NDArray[np.bool_],
        grid: Grid,
        dt: float,
        rng: np.random.Generator,
        goals: list[tuple[float, float] | None] | None = None,
    ) -> npt.NDArray[np.bool_]:
        """Move every robot one step; returns who moved."""
        raise NotImplementedError


@dataclass
class Holonomic(Team):
    """Holonomic robots: full ``speed`` (4.4 m/s) along the chosen direction, or stand."""

    speed: float = 4.4

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ConfigError(f"robot speed must be > 0, got {self.speed}")

    def step(
        self,
        directions: list[tuple[float, float] | None],
        passable: npt.NDArray[np.bool_],
        grid: Grid,
        dt: float,
        rng: np.random.Generator,
        goals: list[tuple[float, float] | None] | None = None,
    ) -> npt.NDArray[np.bool_]:
        """Move every robot one step; returns who moved. A robot with a point in
        ``goals`` (path motion) goes straight to it instead of a full step along its
        direction."""
        n = len(self)
        want = np.zeros(n, dtype=bool)
        dx = np.zeros(n)
        dy = np.zeros(n)
        goal: list[tuple[float, float] | None] = list(goals) if goals is not None else [None] * n
        for i, d in enumerate(directions):
            if self.blocked[i] and rng.random() < self.p_random:
                a = rng.uniform(-math.pi, math.pi)
                d = (math.cos(a), math.sin(a))
                goal[i] = None
            if d is None:
                continue
            want[i] = True
            dx[i], dy[i] = d
        step = self.speed * dt
        nx = self.x + want * dx * step
        ny = self.y + want * dy * step
        for i, p in enumerate(goal):
            if p is not None and want[i]:
                vx, vy = p[0] - self.x[i], p[1] - self.y[i]
                length = math.hypot(vx, vy)
                if length > 1e-9:
                    nx[i], ny[i] = p
                    dx[i], dy[i] = vx / length, vy / length
        clear = want.copy()
        for i in np.flatnonzero(want).tolist():
            if move_clear(self.x[i], self.y[i], nx[i], ny[i], passable, grid):
                continue
            # Cells are coarser than the thesis's 10 cm, so a robot may stray up to half
            # a cell off the centre line of its path and clip a wall a centred robot
            # would pass: then it heads for the centre of the next cell that way.
            alt = _towards_next_cell(self.x[i], self.y[i], dx[i], dy[i], grid)
            if alt is not None:
                ax, ay = alt
                ex, ey = self.x[i] + ax * step, self.y[i] + ay * step
                if move_clear(self.x[i], self.y[i], ex, ey, passable, grid):
                    nx[i], ny[i], dx[i], dy[i] = ex, ey, ax, ay
                    continue
            clear[i] = False
        moving = cancel_collisions(
            self.x, self.y, nx, ny, clear, self.min_separation, self.give_way
        )
        self.blocked = want & ~moving
        self.x = np.where(moving, nx, self.x)
        self.y = np.where(moving, ny, self.y)
        self.heading = np.where(moving, np.arctan2(dy, dx), self.heading)
        return moving


def _towards_next_cell(
    x: float, y: float, dx: float, dy: float, grid: Grid
) -> tuple[float, float] | None:
    """The unit vector from (x, y) to the centre of the neighbouring cell, of the 8,
    that lies in direction (dx, dy)."""
    r, c = grid.world_to_cell(x, y)
    dr, dc = (int(v) for v in STEPS[nearest_step(dx, dy)])
    cx, cy = grid.cell_centres(np.array([int(r) + dr]), np.array([int(c) + dc]))
    vx, vy = float(cx[0]) - x, float(cy[0]) - y
    n = math.hypot(vx, vy)
    return (vx / n, vy / n) if n > 1e-9 else None


def cancel_collisions(
    x: F64,
    y: F64,
    nx: F64,
    ny: F64,
    moving: npt.NDArray[np.bool_],
    sep: float,
    give_way: bool = False,
    first: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.bool_]:
    """Who still moves once the moves of robots in a possible collision (ending closer
    than ``sep`` to another robot) are cancelled; repeated until none is left, since a
    cancelled robot stays where another may be heading.

    By default (the thesis's rule) every moving robot of a pair loses its move. With
    ``give_way``, of a pair where both move only one does when that parts them: the
    later robot (the higher index), unless the earlier one would still run into it
    where it stands, and the later one could move on (as when it backs off before the
    earlier one). Of two robots meeting in a corridor one keeps its way. Under either
    rule, of a moving pair where one robot is marked in ``first`` (default none) and
    the other is not, the marked one keeps its move unless that move alone still ends
    too close to the other where it stands and the other's move alone does not (the
    give-way test with the marked robot as the earlier one).
    """
    moving = moving.copy()
    while True:
        px = np.where(moving, nx, x)
        py = np.where(moving, ny, y)
        pairs = close_pairs(px, py, sep)
        culprits: set[int] = set()
        for i, j in pairs:
            if first is not None and moving[i] and moving[j] and first[i] != first[j]:
                m, u = (i, j) if first[i] else (j, i)
                culprits.add(_yielder(m, u, x, y, nx, ny, sep))
            elif give_way and moving[i] and moving[j]:
                culprits.add(_yielder(i, j, x, y, nx, ny, sep))
            else:
                culprits.update(k for k in (i, j) if moving[k])
        if not culprits:
            return moving
        moving[sorted(culprits)] = False


def _yielder(i: int, j: int, x: F64, y: F64, nx: F64, ny: F64, sep: float) -> int:
    """Which of robots i and j (i the one with the right of way: the earlier, or the
    one marked first), both moving and ending too close, loses its move: j, unless i's
    move alone still ends too close to j and j's alone does not."""
    i_alone = math.hypot(nx[i] - x[j], ny[i] - y[j]) >= sep - 1e-9
    j_alone = math.hypot(nx[j] - x[i], ny[j] - y[i]) >= sep - 1e-9
    return i if j_alone and not i_alone else j


def close_pairs(x: F64, y: F64, sep: float) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of points nearer than ``sep`` to each other."""
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    i, j = np.nonzero(np.triu(d < sep - 1e-9, k=1))
    return list(zip(i.tolist(), j.tolist(), strict=True))


#: The thesis's speed rule for car-like robots: (nearest obstacle closer than this many
#: metres, speed in km/h), checked in order.
SPEED_BANDS: tuple[tuple[float, float], ...] = (
    (2.0, 3.0),
    (5.0, 6.0),
    (7.5, 9.0),
    (math.inf, 15.0),
)


def band_speed(distance: float, bands: tuple[tuple[float, float], ...] = SPEED_BANDS) -> float:
    """The speed (m/s) the rule gives at ``distance`` metres from the nearest obstacle."""
    for upper, kmh in bands:
        if distance < upper:
            return kmh / 3.6
    return bands[-1][1] / 3.6


def parse_speed_bands(text: str) -> tuple[tuple[float, float], ...]:
    """``"2:3,5:6,7.5:9,inf:15"`` -> ((2, 3), (5, 6), (7.5, 9), (inf, 15)): a speed in km/h
    below each distance in metres, distances increasing, speeds > 0."""
    bands: list[tuple[float, float]] = []
    for part in text.split(","):
        try:
            d, v = (float(x) for x in part.split(":"))
        except ValueError:
            raise ConfigError(
                f"expected 'METRES:KMH' in the speed rule, got {part.strip()!r}"
            ) from None
        if not (v > 0 and math.isfinite(v)) or not d > 0:
            raise ConfigError(f"speed rule: distances and speeds must be > 0, got {part.strip()!r}")
        if bands and d <= bands[-1][0]:
            raise ConfigError(f"speed rule: distances must increase, got {text!r}")
        bands.append((d, v))
    return tuple(bands)


def arc(
    x: float, y: float, heading: float, length: float, curvature: float, n: int
) -> tuple[F64, F64, float]:
    """``n`` points along the arc of signed ``length`` (negative: in reverse) and
    ``curvature`` (1/m, positive turns left when going forward) from (x, y, heading);
    returns the points (the first is the start, the last the end) and the end heading."""
    u = np.linspace(0.0, length, max(2, n))
    turn = curvature * u
    if abs(curvature * length) < 1e-12:
        return x + u * math.cos(heading), y + u * math.sin(heading), heading
    px = x + (np.sin(heading + turn) - math.sin(heading)) / curvature
    py = y - (np.cos(heading + turn) - math.cos(heading)) / curvature
    return px, py, heading + curvature * length


def wrap_angle(a: float) -> float:
    """The angle ``a`` (radians) in [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


@dataclass
class Car(Team):
    """Car-like robots: forward and reverse along arcs no tighter than ``turn_radius``
    (3.5 m), at the speed the rule gives for the distance to the nearest obstacle, with
    the thesis's dead-end escape.

    A step drives forward along the arc that turns towards the chosen direction as fast
    as the turning radius allows; if that arc is not clear, the other forward arcs are
    tried from the nearest curvature out. When no forward arc is clear, or the collision
    rule cancels the car's move, the car is in a dead end and escapes: it fixes the
    target heading (the chosen direction of that step), reverses while steering to
    reduce the heading error; if reversing hits an obstacle it drives forward steering
    to reduce the error the other way round (a three-point turn), and reverses again
    when forward is impossible; once the heading is within ``align`` radians of the
    target the escape ends. A car cancelled by the collision rule while escaping
    switches gear, and with probability ``p_random`` a step takes a random target
    heading instead (two cars facing each other in a corridor would otherwise meet
    again and again). DVT is the share of steps a car spends escaping.

    With ``planner="track"`` (a car-like planner, not the thesis's; :mod:`.manoeuvre`)
    the car instead follows the wave's path to the place it goes for (``routes``, set
    before each step, world points) by pure pursuit: the chosen direction points at a
    point on that path, and the car drives the forward arc through it (clipped to the
    turning radius) if that arc stays clear ``horizon`` metres on. When no such forward
    arc is clear, the path lies behind the car
    (``behind`` radians off its heading), or the collision rule has held it for
    ``patience`` steps, it plans a manoeuvre (hybrid A* with forward and reverse arcs
    to a pose on the path 3-10 m ahead, clear of the map and the other robots) and
    drives it arc by arc; with no manoeuvre found it takes the pursuit arc if only the
    step is clear, else falls back on the thesis's escape, aiming for the direction of
    its route 1-3 m on (or the opposite one, whichever is nearer its heading), until
    aligned with it or for at most :data:`ESCAPE_STEPS`, and then searches again. DVT
    then counts the steps of manoeuvres that reverse and of the fallback: the car's
    dead-end escapes.

    The body is the same disc as the holonomic robot's (the thesis gives no body for
    the car); the speed rule reads the distance from the car's centre to the nearest
    cell that is not free, as the territory's clearance has it.
    """

    clearance: F64 = field(default_factory=lambda: np.zeros((0, 0)))
    turn_radius: float = 3.5
    bands: tuple[tuple[float, float], ...] = SPEED_BANDS
    align: float = 0.1
    #: ``thesis`` (turn towards the chosen direction, the thesis's escape) or ``track``.
    planner: str = "thesis"
    #: Track: the path off the heading (radians) beyond which the car manoeuvres.
    behind: float = 1.75
    #: Track: metres the pursuit arc must be clear ahead, or the car manoeuvres (3 m:
    #: on training street sites one car's DVT fell from 18 % with none to 13 %).
    horizon: float = 3.0
    #: Track: steps held by the collision rule before the car manoeuvres around.
    patience: int = 4
    escaping: npt.NDArray[np.bool_] = field(init=False)
    goal: F64 = field(init=False)
    gear: npt.NDArray[np.int64] = field(init=False)
    #: Track: each car's path (K, 2 world points) or None, set before each step.
    routes: list[F64 | None] = field(init=False)
    #: Track: each car's manoeuvre being driven (arcs left), or None.
    plans: list[Manoeuvre | None] = field(init=False)
    #: Track: steps each car has been held in a row.
    held: npt.NDArray[np.int64] = field(init=False)
    #: Track: steps before a car whose search failed searches again.
    rest: npt.NDArray[np.int64] = field(init=False)
    #: Track: why each car's manoeuvre was planned (one of :data:`CAUSES`).
    cause: list[str] = field(init=False)
    #: Track: per cause, each car's steps counted by the DVT.
    escape_causes: dict[str, npt.NDArray[np.int64]] = field(init=False)
    #: Track: reversing manoeuvres (and falls back on the thesis's escape) each car began.
    turns: npt.NDArray[np.int64] = field(init=False)
    #: Track: steps each car's fallback on the thesis's escape may still run.
    stuck: npt.NDArray[np.int64] = field(init=False)
    #: Track: metres a car with a route must get from where it stood
    #: (:attr:`anchor`) for its time there not to count as a stall.
    stall_radius: float = 1.0
    #: Track: steps (10 s at 0.5 s a step) a car with a route may stay within
    #: ``stall_radius`` of one spot, not held by the collision rule nor driving a
    #: manoeuvre, before it searches
    #: for a way out with the finer manoeuvre search (:data:`UNSTALL_SEARCH`); after
    #: each failed search its wait doubles (:data:`STALL_WAIT_CAP`).
    stall_steps: int = 20
    #: Track: where each car's current stay began (K, 2 world metres).
    anchor: F64 = field(init=False)
    #: Track: steps each car has stayed within ``stall_radius`` of its anchor.
    still: npt.NDArray[np.int64] = field(init=False)
    #: Track: stalls each car was found in (its :attr:`wait` reached).
    stalls: npt.NDArray[np.int64] = field(init=False)
    #: Track: steps each car stays before it searches (``stall_steps``, doubled after
    #: each failed search up to :data:`STALL_WAIT_CAP` times it; back to ``stall_steps``
    #: once the car gets ``stall_radius`` away or a search finds a way).
    wait: npt.NDArray[np.int64] = field(init=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.turn_radius) and self.turn_radius > 0):
            raise ConfigError(f"turning radius must be > 0 metres, got {self.turn_radius}")
        if not all(kmh > 0 for _, kmh in self.bands):
            raise ConfigError("every speed of the speed rule must be > 0")
        if self.planner not in ("thesis", "track"):
            raise ConfigError(f"unknown car planner {self.planner!r}; valid: thesis, track")
        self.escaping = np.zeros(len(self.x), dtype=bool)
        self.goal = np.zeros(len(self.x))
        self.gear = -np.ones(len(self.x), dtype=np.int64)
        self.routes = [None] * len(self.x)
        self.plans = [None] * len(self.x)
        self.held = np.zeros(len(self.x), dtype=np.int64)
        self.rest = np.zeros(len(self.x), dtype=np.int64)
        self.cause = [""] * len(self.x)
        self.escape_causes = {c: np.zeros(len(self.x), dtype=np.int64) for c in CAUSES}
        self.turns = np.zeros(len(self.x), dtype=np.int64)
        self.stuck = np.zeros(len(self.x), dtype=np.int64)
        if self.stall_steps < 1 or not self.stall_radius > 0:
            raise ConfigError(
                f"stall_steps must be >= 1 and stall_radius > 0, got {self.stall_steps}, "
                f"{self.stall_radius}"
            )
        self.anchor = np.column_stack([self.x, self.y]).astype(np.float64)
        self.still = np.zeros(len(self.x), dtype=np.int64)
        self.stalls = np.zeros(len(self.x), dtype=np.int64)
        self.wait = np.full(len(self.x), self.stall_steps, dtype=np.int64)

    def state(self) -> dict[str, Any]:
        """Everything the cars' next steps depend on, copied.

        Returns
        -------
        dict
            Per car: the pose, the escape's and the planner's state, the stall watch's
            and the counts, by attribute name (:meth:`restore` takes it back).
        """
        return {
            "x": self.x.copy(),
            "y": self.y.copy(),
            "heading": self.heading.copy(),
            "blocked": self.blocked.copy(),
            "escaping": self.escaping.copy(),
            "goal": self.goal.copy(),
            "gear": self.gear.copy(),
            "routes": [None if r is None else r.copy() for r in self.routes],
            "plans": [None if p is None else Manoeuvre(list(p.arcs)) for p in self.plans],
            "held": self.held.copy(),
            "rest": self.rest.copy(),
            "cause": list(self.cause),
            "escape_causes": {k: v.copy() for k, v in self.escape_causes.items()},
            "turns": self.turns.copy(),
            "stuck": self.stuck.copy(),
            "anchor": self.anchor.copy(),
            "still": self.still.copy(),
            "stalls": self.stalls.copy(),
            "wait": self.wait.copy(),
        }

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`, copied again.

        Parameters
        ----------
        state : mapping
            A :meth:`state` of a team of as many cars, with exactly its keys.

        Raises
        ------
        ConfigError
            A state with other keys (of another version or kind of team) or of another
            number of cars.
        """
        want = set(self.state())
        if set(state) != want:
            missing, extra = sorted(want - set(state)), sorted(set(state) - want)
            raise ConfigError(f"not a car team's state: missing {missing}, unknown {extra}")
        if len(state["x"]) != len(self):
            raise ConfigError(f"a state of {len(state['x'])} cars for a team of {len(self)}")
        fresh = dict(state)
        fresh["routes"] = [None if r is None else np.array(r) for r in state["routes"]]
        fresh["plans"] = [None if p is None else Manoeuvre(list(p.arcs)) for p in state["plans"]]
        fresh["cause"] = list(state["cause"])
        fresh["escape_causes"] = {k: np.array(v) for k, v in state["escape_causes"].items()}
        for name, value in fresh.items():
            if isinstance(value, np.ndarray):
                value = value.copy()
            setattr(self, name, value)

    def speed_of(self, i: int, grid: Grid) -> float:
        r, c = grid.world_to_cell(self.x[i], self.y[i])
        if not grid.contains(r, c):
            return band_speed(0.0, self.bands)
        return band_speed(float(self.clearance[int(r), int(c)]), self.bands)

    def _try(
        self,
        i: int,
        length: float,
        curvatures: list[float],
        passable: npt.NDArray[np.bool_],
        grid: Grid,
    ) -> tuple[float, float, float] | None:
        """The end (x, y, heading) of the first clear arc of ``curvatures``."""
        n = math.ceil(abs(length) / (grid.resolution * 0.25)) + 1
        for k in curvatures:
            px, py, h = arc(
                float(self.x[i]), float(self.y[i]), float(self.heading[i]), length, k, n
            )
            if points_clear(px, py, passable, grid):
                return float(px[-1]), float(py[-1]), h
        return None

    def _steer(self, error: float, length: float) -> float:
        """The curvature that turns by ``error`` over ``length`` metres as far as the
        turning radius allows (``length`` negative in reverse)."""
        kmax = 1.0 / self.turn_radius
        return max(-kmax, min(kmax, error / length))

    def _arcs(self, error: float, length: float) -> list[float]:
        """The arc that steers towards ``error`` first, then the others from the nearest
        curvature out (a car takes another arc before giving up a gear)."""
        kmax = 1.0 / self.turn_radius
        best = self._steer(error, length)
        others = [kmax * f for f in (-1.0, -0.5, 0.0, 0.5, 1.0)]
        return [best, *sorted(others, key=lambda k: abs(k - best))]

    def step(
        self,
        directions: list[tuple[float, float] | None],
        passable: npt.NDArray[np.bool_],
        grid: Grid,
        dt: float,
        rng: np.random.Generator,
        goals: list[tuple[float, float] | None] | None = None,
    ) -> npt.NDArray[np.bool_]:
        """Move every car one step; returns who moved. With the ``track`` planner,
        ``goals`` holds each car's pure-pursuit point (None: ``directions`` alone)."""
        if self.planner == "track":
            return self._track(directions, passable, grid, dt, rng, goals)
        n = len(self)
        want = np.zeros(n, dtype=bool)
        boxed: list[int] = []
        end = np.column_stack([self.x, self.y, self.heading]).astype(np.float64)
        for i, d in enumerate(directions):
            if self.escaping[i] and abs(wrap_angle(self.goal[i] - self.heading[i])) <= self.align:
                self.escaping[i] = False
            if self.escaping[i] and self.blocked[i] and rng.random() < self.p_random:
                self.goal[i] = rng.uniform(-math.pi, math.pi)
            if not self.escaping[i] and d is None:
                continue
            s = self.speed_of(i, grid) * dt
            want[i] = True
            if not self.escaping[i]:
                assert d is not None
                error = wrap_angle(math.atan2(d[1], d[0]) - float(self.heading[i]))
                move = self._try(i, s, self._arcs(error, s), passable, grid)
                if move is not None:
                    end[i] = move
                    continue
                self.escaping[i] = True  # a dead end: forward motion is impossible
                self.goal[i] = math.atan2(d[1], d[0])
                self.gear[i] = -1
            error = wrap_angle(float(self.goal[i] - self.heading[i]))
            move = None
            for _ in range(2):
                length = s * float(self.gear[i])
                move = self._try(i, length, self._arcs(error, length), passable, grid)
                if move is not None:
                    break
                self.gear[i] = -self.gear[i]
            if move is None:
                boxed.append(i)  # boxed in both ways: stand, still escaping
            else:
                end[i] = move
        moving = cancel_collisions(
            self.x, self.y, end[:, 0], end[:, 1], want, self.min_separation, self.give_way
        )
        for i in boxed:
            moving[i] = False
        # A boxed-in car counts as blocked, so that its random re-targeting can free it.
        self.blocked = want & ~moving
        for i in np.flatnonzero(self.blocked).tolist():
            if self.escaping[i]:
                self.gear[i] = -self.gear[i]
            else:
                self.escaping[i] = True
                d = directions[i]
                self.goal[i] = math.atan2(d[1], d[0]) if d is not None else self.heading[i]
                self.gear[i] = -1
        self.x = np.where(moving, end[:, 0], self.x)
        self.y = np.where(moving, end[:, 1], self.y)
        self.heading = np.where(
            moving, (end[:, 2] + math.pi) % (2 * math.pi) - math.pi, self.heading
        )
        return moving

    def _watch_stalls(self) -> None:
        """Count, per car, the steps it has stayed within ``stall_radius`` of where its
        stay began; a car held by the collision rule (traffic's to settle), without a
        route (nowhere to go) or driving a manoeuvre (a turn round in a few shunts
        stays within a metre for a while) starts a new stay where it is."""
        xy = np.column_stack([self.x, self.y])
        away = np.hypot(*(xy - self.anchor).T) > self.stall_radius
        self.wait[away] = self.stall_steps
        idle = np.array([r is None or len(r) < 2 for r in self.routes])
        planned = np.array([p is not None for p in self.plans])
        fresh = away | self.blocked | idle | planned
        self.anchor[fresh] = xy[fresh]
        self.still = np.where(fresh, 0, self.still + 1)

    def unstall(self, i: int, passable: npt.NDArray[np.bool_], grid: Grid) -> bool:
        """Search car i a way out of a stall.

        Car i has stayed within ``stall_radius`` of one spot for its :attr:`wait`,
        not held by another car: a lock no ordinary step gets it out of (as a car askew
        in a street whose passable cells are one wide, swinging between two poses). It
        searches for a manoeuvre onto its route with the finer search
        (:data:`UNSTALL_SEARCH`), whatever its rest, and drives it as a ``fallback``
        (its steps in reverse count as dead-end escape); its stay starts anew either
        way. A failed search doubles its wait, up to :data:`STALL_WAIT_CAP` times
        ``stall_steps``; a found one sets it back to ``stall_steps``.

        Parameters
        ----------
        i : int
            The car.
        passable : ndarray of bool
            Cells a car's centre may be on.
        grid : Grid
            The map's grid.

        Returns
        -------
        bool
            True when a manoeuvre was found.
        """
        self.stalls[i] += 1
        self.still[i] = 0
        self.anchor[i] = (float(self.x[i]), float(self.y[i]))
        route = self.routes[i]
        if route is None or len(route) < 2:
            return False
        # Doubled now, set back below if a way is found.
        self.wait[i] = min(2 * int(self.wait[i]), STALL_WAIT_CAP * self.stall_steps)
        plan, _ = self._search(i, route, passable, grid, UNSTALL_SEARCH)
        if plan is None or not plan.arcs:
            return False
        self.plans[i] = plan
        self.cause[i] = "fallback"
        self.turns[i] += plan.reverses
        self.stuck[i] = 0
        self.rest[i] = 0
        self.wait[i] = self.stall_steps
        return True

    def _escape_move(
        self, i: int, s: float, passable: npt.NDArray[np.bool_], grid: Grid
    ) -> tuple[float, float, float] | None:
        """One step of the thesis's escape: reverse (or forward, once reverse is
        blocked) steering towards the target heading ``goal[i]``."""
        error = wrap_angle(float(self.goal[i] - self.heading[i]))
        for _ in range(2):
            length = s * float(self.gear[i])
            move = self._try(i, length, self._arcs(error, length), passable, grid)
            if move is not None:
                return move
            self.gear[i] = -self.gear[i]
        return None

    def _drive_plan(
        self, i: int, s: float, passable: npt.NDArray[np.bool_], grid: Grid
    ) -> tuple[float, float, float] | None:
        """Up to ``s`` metres along the first arc of car i's manoeuvre (the rest of it
        stays for the next step); None, dropping the manoeuvre, if it is not clear."""
        plan = self.plans[i]
        assert plan is not None
        x0, y0, h0 = float(self.x[i]), float(self.y[i]), float(self.heading[i])
        left = s
        gear = math.copysign(1.0, plan.arcs[0][0])
        move: tuple[float, float, float] | None = None
        # Arcs in one gear run on within the step; a change of gear waits for the next.
        while plan.arcs and left > 1e-9 and math.copysign(1.0, plan.arcs[0][0]) == gear:
            length, k = plan.arcs[0]
            part = math.copysign(min(left, abs(length)), length)
            # The search checked the whole arc; checked again on a part of it, other
            # sample points could clip the corner of a cell the search's passed by.
            px, py, h = arc(float(self.x[i]), float(self.y[i]), float(self.heading[i]), part, k, 2)
            r, c = grid.world_to_cell(px[-1], py[-1])
            if not (grid.contains(r, c) and passable[int(r), int(c)]):
                break
            move = (float(px[-1]), float(py[-1]), h)
            self.x[i], self.y[i], self.heading[i] = move
            left -= abs(part)
            rest = length - part
            if abs(rest) > 1e-6:
                plan.arcs[0] = (rest, k)
            else:
                plan.arcs.pop(0)
        # Driven on a copy of the pose: the step is the collision rule's to allow.
        end = (float(self.x[i]), float(self.y[i]), float(self.heading[i]))
        self.x[i], self.y[i], self.heading[i] = x0, y0, h0
        if move is None and left == s:
            # Not even a start: a manoeuvre from here would fail the same way.
            self.plans[i] = None
            self._rest_and_retry(i)
            return None
        if not plan.arcs:
            self.plans[i] = None
        return end

    def is_behind(self, i: int, point: tuple[float, float]) -> bool:
        """Whether the world ``point`` (metres) lies more than ``behind`` radians off
        car i's heading, the angle past which the tracking car manoeuvres rather than
        pursues; a point at the car itself is not behind."""
        dx, dy = point[0] - float(self.x[i]), point[1] - float(self.y[i])
        if math.hypot(dx, dy) <= 1e-9:
            return False
        return abs(wrap_angle(math.atan2(dy, dx) - float(self.heading[i]))) > self.behind

    def _street_axis(self, i: int, towards: float) -> float:
        """The heading car i's fallback aligns with: its route's direction from 1 to
        3 m on, or the opposite one when that is nearer its heading (a car askew in a
        street straightens up before it turns round); ``towards`` when it has no
        route that long."""
        route = self.routes[i]
        if route is None or len(route) < 2:
            return towards
        x, y = float(self.x[i]), float(self.y[i])
        ax, ay = carrot(route, x, y, 1.0)
        bx, by = carrot(route, x, y, 3.0)
        if math.hypot(bx - ax, by - ay) < 1.0:
            return towards
        h = math.atan2(by - ay, bx - ax)
        ahead = abs(wrap_angle(h - float(self.heading[i]))) <= math.pi / 2
        return h if ahead else wrap_angle(h + math.pi)

    def _yielded_to(self, i: int) -> bool:
        """Whether a later car near car i, held too or already manoeuvring round
        traffic, gets out of the way instead of it: of two cars holding each other up
        only one manoeuvres (both would otherwise back off and meet again). A later car
        that found no way out (resting) does not count: were car i to wait for it,
        neither would ever move."""
        near = self._near(i)
        near[: i + 1] = False
        held = (self.held > 0) & (self.rest == 0)
        traffic = np.array(
            [p is not None and c == "traffic" for p, c in zip(self.plans, self.cause, strict=True)]
        )
        return bool((near & (held | traffic)).any())

    def _near(self, i: int) -> npt.NDArray[np.bool_]:
        """The other cars within 2 m of car i's separation: those that can hold it up."""
        near: npt.NDArray[np.bool_] = (
            np.hypot(self.x - self.x[i], self.y - self.y[i]) < self.min_separation + 2.0
        )
        near[i] = False
        return near

    def _back_off(
        self, i: int, passable: npt.NDArray[np.bool_], grid: Grid, others: F64
    ) -> Manoeuvre | None:
        """A manoeuvre taking car i a turning radius beyond the separation from the cars
        near it (:meth:`_near`), wherever that is: two cars that both make for the
        street one of them stands at the mouth of find no manoeuvre onto their routes
        (each sees the other in the way), and would hold each other for good."""
        near = self._near(i)
        if not near.any():
            return None
        x, y = float(self.x[i]), float(self.y[i])
        goals = clear_goals(
            x,
            y,
            np.column_stack([self.x[near], self.y[near]]),
            passable,
            grid,
            clear=self.min_separation + self.turn_radius,
        )
        if not len(goals):
            return None
        return plan_manoeuvre(
            (x, y, float(self.heading[i])),
            goals,
            passable,
            grid,
            self.turn_radius,
            others=others,
            separation=self.min_separation + 0.5,
        )

    def _rest_and_retry(self, i: int) -> None:
        """Car i found no manoeuvre from where it stands (onto its route, nor, held
        for traffic, back off to room within 6 m; :meth:`_plan`), or has one whose
        first step cannot be driven (:meth:`_drive_plan`, which drops it): it rests.
        ``rest`` is set to ``patience`` and counts down at the start of each step, so
        the car skips the search on the next ``patience - 1`` steps and searches again
        on the ``patience``-th, since searching sooner would find none either; while
        resting it plans none (it takes a pursuit arc clear for the step, else the
        fallback on the thesis's escape). A car that held it and yielded to it
        (:meth:`_yielded_to`) does not wait for a resting car: it plans in turn, onto
        its route or backing off itself, so of two cars holding each other the one
        with room makes way. Two with no room either way stand and search by turns.
        In a dead-end corridor this does not settle which car leaves first: the car
        that made way backs off about a turning radius, the other follows it out,
        they meet again, and the one that rested, now with room behind it, backs off
        in turn; the two take turns backing off."""
        self.rest[i] = self.patience

    def _search(
        self,
        i: int,
        route: F64,
        passable: npt.NDArray[np.bool_],
        grid: Grid,
        search: FineSearch | None = None,
    ) -> tuple[Manoeuvre | None, F64]:
        """The manoeuvre search for car i onto ``route``, clear of the other cars.

        Parameters
        ----------
        i : int
            The car.
        route : ndarray (M, 2)
            Its route, world metres.
        passable : ndarray of bool
            Cells a car's centre may be on.
        grid : Grid
            The map's grid.
        search : FineSearch, optional
            The search's bins and budget; default None (:func:`plan_manoeuvre`'s).

        Returns
        -------
        plan : Manoeuvre or None
            The manoeuvre found, None when the search found none.
        others : ndarray (K - 1, 2)
            The other cars' positions, world metres.
        """
        others = np.column_stack([np.delete(self.x, i), np.delete(self.y, i)])
        bins: dict[str, Any] = {} if search is None else asdict(search)
        plan = plan_manoeuvre(
            (float(self.x[i]), float(self.y[i]), float(self.heading[i])),
            route_goals(route),
            passable,
            grid,
            self.turn_radius,
            others=others,
            # Some room to spare: a car that ends its manoeuvre just clear of another
            # is held again at once.
            separation=self.min_separation + 0.5,
            **bins,
        )
        return plan, others

    def _plan(self, i: int, passable: npt.NDArray[np.bool_], grid: Grid, cause: str) -> bool:
        """Plan a manoeuvre for car i onto its route, for ``cause`` (of :data:`CAUSES`);
        True when one was found."""
        route = self.routes[i]
        if route is None or len(route) < 2:
            return False
        plan, others = self._search(i, route, passable, grid)
        if (plan is None or not plan.arcs) and cause == "traffic":
            # No way onto the route past the cars in the way: make way for them instead
            # (only the car :meth:`_yielded_to` picks plans for traffic, so one parts).
            plan = self._back_off(i, passable, grid, others)
        if plan is None or not plan.arcs:
            self._rest_and_retry(i)
            return False
        self.plans[i] = plan
        self.cause[i] = cause
        self.turns[i] += plan.reverses
        return True

    def _track(
        self,
        directions: list[tuple[float, float] | None],
        passable: npt.NDArray[np.bool_],
        grid: Grid,
        dt: float,
        rng: np.random.Generator,
        goals: list[tuple[float, float] | None] | None,
    ) -> npt.NDArray[np.bool_]:
        """The ``track`` planner's step (see the class notes)."""
        n = len(self)
        want = np.zeros(n, dtype=bool)
        end = np.column_stack([self.x, self.y, self.heading]).astype(np.float64)
        kmax = 1.0 / self.turn_radius
        # The manoeuvres as they were, for the cars the collision rule holds back.
        saved: dict[int, list[tuple[float, float]]] = {}
        # Every car's rest counts down before any car plans: :meth:`_yielded_to` reads
        # the later cars' rest, which a count-down inside the loop would leave a step
        # stale (car i would take a later car about to search again for a resting one,
        # and both would back off on the same step).
        self.rest = np.maximum(self.rest - 1, 0)
        for i, d in enumerate(directions):
            s = self.speed_of(i, grid) * dt
            if self.still[i] >= self.wait[i]:
                self.unstall(i, passable, grid)
            if (
                self.plans[i] is None
                and self.held[i] >= self.patience
                and not self.rest[i]
                and not self._yielded_to(i)
            ):
                self._plan(i, passable, grid, "traffic")
            if self.plans[i] is None and self.stuck[i] > 0:
                # The fallback runs until the car is aligned (at most ESCAPE_STEPS):
                # one step of it, then pursuit again, can swing a car between two
                # poses for good in a street whose passable cells are one wide.
                if abs(wrap_angle(float(self.goal[i] - self.heading[i]))) <= self.align:
                    self.stuck[i] = 0
                else:
                    self.stuck[i] -= 1
                    self.escape_causes["fallback"][i] += 1
                    move = self._escape_move(i, s, passable, grid)
                    if move is not None:
                        want[i] = True
                        end[i] = move
                    continue
            if self.plans[i] is None:
                self.escaping[i] = False
            if self.plans[i] is None and d is not None:
                error = wrap_angle(math.atan2(d[1], d[0]) - float(self.heading[i]))
                p = goals[i] if goals is not None else None
                ahead = math.hypot(p[0] - self.x[i], p[1] - self.y[i]) if p is not None else s
                arcs: list[float] = []
                if abs(error) <= self.behind:
                    # Pure pursuit: the arc through the point ahead.
                    k = max(-kmax, min(kmax, 2.0 * math.sin(error) / max(ahead, 1e-6)))
                    others = [kmax * f for f in (-1.0, -0.5, 0.0, 0.5, 1.0)]
                    arcs = [k, *sorted(others, key=lambda v: abs(v - k))][:3]
                    # The arc must stay clear ``horizon`` metres on: a car that would
                    # soon be boxed in plans while it can still turn forwards.
                    far = max(s, self.horizon)
                    clear = [v for v in arcs if self._try(i, far, [v], passable, grid)]
                    move = self._try(i, s, clear[:1], passable, grid)
                    if move is not None:
                        want[i] = True
                        end[i] = move
                        continue
                why = "behind" if abs(error) > self.behind else "ahead"
                if self.rest[i] or not self._plan(i, passable, grid, why):
                    move = self._try(i, s, arcs, passable, grid)
                    if move is not None:
                        want[i] = True
                        end[i] = move
                        continue
                    # No manoeuvre found: the thesis's escape, for this step.
                    if not self.escaping[i]:
                        self.gear[i] = -1
                        self.turns[i] += 1
                    self.escaping[i] = True
                    self.escape_causes["fallback"][i] += 1
                    self.stuck[i] = ESCAPE_STEPS
                    self.goal[i] = self._street_axis(i, math.atan2(d[1], d[0]))
                    move = self._escape_move(i, s, passable, grid)
                    if move is not None:
                        want[i] = True
                        end[i] = move
                    continue
            if self.plans[i] is not None:
                plan = self.plans[i]
                assert plan is not None
                self.escaping[i] = plan.reverses
                if plan.reverses:
                    self.escape_causes[self.cause[i]][i] += 1
                saved[i] = list(plan.arcs)
                move = self._drive_plan(i, s, passable, grid)
                if move is not None:
                    want[i] = True
                    end[i] = move
        # A car manoeuvring round traffic goes first: were the car it got out of the
        # way of to drive on at it, the rule would cancel both moves, step after step.
        traffic = np.array([c == "traffic" and i in saved for i, c in enumerate(self.cause)])
        moving = cancel_collisions(
            self.x,
            self.y,
            end[:, 0],
            end[:, 1],
            want,
            self.min_separation,
            self.give_way,
            first=traffic,
        )
        self.blocked = want & ~moving
        self.held = np.where(self.blocked, self.held + 1, 0)
        for i in np.flatnonzero(self.blocked).tolist():
            # Held too long on a manoeuvre: plan again around the robots in the way.
            held_back = i in saved and self.held[i] < self.patience
            self.plans[i] = Manoeuvre(saved[i]) if held_back else None
        del rng  # the track planner draws nothing at random
        self.x = np.where(moving, end[:, 0], self.x)
        self.y = np.where(moving, end[:, 1], self.y)
        self.heading = np.where(
            moving, (end[:, 2] + math.pi) % (2 * math.pi) - math.pi, self.heading
        )
        self._watch_stalls()
        return moving
