"""Built-in scenarios: floor plan, rig, trajectory and simulated readings.

Each scenario writes ``truth.yaml``/``truth.pgm``/``truth.npy``, ``rig.yaml``,
``trajectory.csv``, ``readings.csv`` and ``annotations.yaml`` (passages: the two jamb
points across each opening and its true width) to a folder.

- ``doorways``: the research's synthetic corridor (thesis 000 fig. 4.1, left): a 6 m x 6 m
  territory, a corridor with doorways into rooms on both sides, the robot driving
  straight up the middle with the ``paper-synthetic`` rig, exact readings.
- ``passages``: a row of blocks separated by gaps of increasing width beside the robot's
  path (thesis 002, figs 4.9-4.10).
- ``office``: a 20 m office floor with eight rooms toured for 10 minutes by a 16-sonar
  ring firing at 20 Hz (192,000 readings): the streaming benchmark's scene.
- ``room-turn``: a room with a door; the ``paper-real`` rig turns in place at uneven speed,
  with outliers and a roughly known sonar mounting (thesis 000 fig. 4.1, right).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import ConfigError
from .grid import Grid
from .io._atomic import atomic_write_text
from .io.rosmap import OccupancyMap, write_map
from .readings import Readings, Trajectory, write_readings, write_trajectory
from .rig import Mount, Rig, get_rig, save_rig
from .sensors import Noise
from .simulate import simulate

__all__ = [
    "SCENARIOS",
    "Passage",
    "Scenario",
    "SmallObstacle",
    "load_annotations",
    "load_scene",
    "make_scenario",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Passage:
    """An opening in the floor plan.

    ``a`` and ``b`` are the jamb points (world, metres) on the mid-line of the obstacle
    the opening goes through, ``depth`` that obstacle's thickness across the opening.
    """

    name: str
    a: tuple[float, float]
    b: tuple[float, float]
    depth: float = 0.1

    @property
    def width(self) -> float:
        return math.dist(self.a, self.b)


@dataclass(frozen=True)
class SmallObstacle:
    """A small square obstacle: ``centre`` (world, metres) and side ``size`` (metres)."""

    name: str
    centre: tuple[float, float]
    size: float


@dataclass(frozen=True, eq=False)
class Scenario:
    """Everything a mapping experiment needs, in memory."""

    name: str
    truth: OccupancyMap
    rig: Rig
    trajectory: Trajectory
    readings: Readings
    passages: tuple[Passage, ...] = ()
    params: dict[str, Any] = field(default_factory=dict)
    obstacles: tuple[SmallObstacle, ...] = ()

    def write(self, folder: str | Path) -> Path:
        """Write the scenario files into ``folder`` (created if needed)."""
        d = Path(folder)
        d.mkdir(parents=True, exist_ok=True)
        write_map(self.truth, d / "truth")
        save_rig(self.rig, d / "rig.yaml")
        write_trajectory(self.trajectory, d / "trajectory.csv")
        write_readings(self.readings, d / "readings.csv")
        ann = {
            "scenario": self.name,
            "params": self.params,
            "passages": [
                {
                    "name": p.name,
                    "a": list(p.a),
                    "b": list(p.b),
                    "depth": p.depth,
                    "width": round(p.width, 6),
                }
                for p in self.passages
            ],
            "small_obstacles": [
                {"name": o.name, "centre": list(o.centre), "size": o.size} for o in self.obstacles
            ],
        }
        atomic_write_text(d / "annotations.yaml", yaml.safe_dump(ann, sort_keys=False))
        return d


class _Plan:
    """A floor plan being drawn: rectangles of obstacle on an empty grid."""

    def __init__(self, grid: Grid) -> None:
        self.grid = grid
        self.occ = np.zeros(grid.shape, dtype=np.float32)

    def _cells(self, x0: float, y0: float, x1: float, y1: float) -> tuple[slice, slice]:
        # Edges snap to the nearest cell boundary, so a 0.8 m gap at 5 cm is 16 cells
        # whatever the rounding of its coordinates.
        g = self.grid
        c0 = max(0, round((x0 - g.origin[0]) / g.resolution))
        c1 = min(g.cols, round((x1 - g.origin[0]) / g.resolution))
        i0 = max(0, round((y0 - g.origin[1]) / g.resolution))
        i1 = min(g.rows, round((y1 - g.origin[1]) / g.resolution))
        return slice(g.rows - i1, g.rows - i0), slice(c0, c1)

    def box(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.occ[self._cells(x0, y0, x1, y1)] = 1.0

    def post(self, name: str, cx: float, cy: float, size: float) -> SmallObstacle:
        """A square post about (cx, cy), annotated with the cells actually drawn."""
        rows, cols = self._cells(cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2)
        self.occ[rows, cols] = 1.0
        g = self.grid
        x0 = g.origin[0] + cols.start * g.resolution
        x1 = g.origin[0] + cols.stop * g.resolution
        y1 = g.origin[1] + (g.rows - rows.start) * g.resolution
        y0 = g.origin[1] + (g.rows - rows.stop) * g.resolution
        return SmallObstacle(name, ((x0 + x1) / 2, (y0 + y1) / 2), max(x1 - x0, y1 - y0))

    def clear(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.occ[self._cells(x0, y0, x1, y1)] = 0.0

    def border(self, t: float) -> None:
        xmin, xmax, ymin, ymax = self.grid.extent
        self.box(xmin, ymin, xmax, ymin + t)
        self.box(xmin, ymax - t, xmax, ymax)
        self.box(xmin, ymin, xmin + t, ymax)
        self.box(xmax - t, ymin, xmax, ymax)

    def done(self) -> OccupancyMap:
        return OccupancyMap(self.grid, self.occ)


def _check_positive(**values: float) -> None:
    for k, v in values.items():
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"scenario parameter '{k}' must be > 0, got {v}")


def _with_noise(rig: Rig, noise: Noise) -> Rig:
    """The rig with its sensor model stating the simulation's noise, as a calibrated
    sensor file would: mappers take their default band and model noise from it."""
    return replace(rig, sensor=replace(rig.sensor, noise=noise))


def _straight(x: float, y0: float, y1: float, speed: float, rate: float) -> Trajectory:
    n = math.floor((y1 - y0) / speed * rate) + 1
    t = np.arange(n) / rate
    return Trajectory(t, np.full(n, x), y0 + speed * t, np.full(n, math.pi / 2))


def doorways(
    *,
    size: float = 6.0,
    resolution: float = 0.05,
    corridor_width: float = 2.0,
    wall: float = 0.1,
    door_widths: Sequence[float] = (1.0, 0.8, 0.9, 0.7),
    speed: float = 0.25,
    rate: float = 10.0,
    noise: Noise | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """The research's corridor with doorways.

    Defaults: a ``size`` x ``size`` m territory at ``resolution`` m (6 m, 5 cm), walls
    ``wall`` m thick around it and along a corridor of ``corridor_width`` m (2 m) centred
    on x = size / 2; doorways of ``door_widths`` m (1.0, 0.8, 0.9, 0.7) alternate between
    the left and right corridor walls, evenly spaced along the corridor. The robot drives up
    the corridor centre from y = 0.5 to size - 0.5 at ``speed`` m/s (0.25), all six
    ``paper-synthetic`` sonars firing at ``rate`` Hz (10). Readings are exact by default
    (p_rand = 0, p_hit = 1, sigma = 0), as in the research.
    """
    _check_positive(
        size=size,
        resolution=resolution,
        corridor_width=corridor_width,
        wall=wall,
        speed=speed,
        rate=rate,
    )
    if not door_widths or any(w <= 0 for w in door_widths):
        raise ConfigError("scenario parameter 'door_widths' must be positive widths")
    grid = Grid.from_bounds(0.0, 0.0, size, size, resolution)
    plan = _Plan(grid)
    plan.border(wall)
    cx = size / 2
    xl, xr = cx - corridor_width / 2, cx + corridor_width / 2
    plan.box(xl - wall, 0, xl, size)
    plan.box(xr, 0, xr + wall, size)
    passages = []
    n = len(door_widths)
    span = size - 2.0
    for k, w in enumerate(door_widths):
        yc = 1.0 + span * (k + 0.5) / n
        # Doors alternate sides, so doors on one wall are two spacings apart.
        if w > min(2 * span / n, span) - 0.2:
            raise ConfigError(f"door width {w} m does not fit {n} doors in a {size} m corridor")
        left = k % 2 == 0
        x0, x1 = (xl - wall, xl) if left else (xr, xr + wall)
        plan.clear(x0, yc - w / 2, x1, yc + w / 2)
        xm = (x0 + x1) / 2
        passages.append(
            Passage(
                f"door{k + 1}-{'left' if left else 'right'}",
                (xm, yc - w / 2),
                (xm, yc + w / 2),
                wall,
            )
        )
    truth = plan.done()
    nz = noise if noise is not None else Noise(0.0, 1.0, 0.0)
    rig = _with_noise(get_rig("paper-synthetic"), nz)
    traj = _straight(cx, 0.5, size - 0.5, speed, rate)
    readings = simulate(truth, rig, traj, noise=nz, seed=seed, progress=progress)
    params = {
        "size": size,
        "resolution": resolution,
        "corridor_width": corridor_width,
        "wall": wall,
        "door_widths": list(door_widths),
        "speed": speed,
        "rate": rate,
        "p_rand": nz.p_rand,
        "p_hit": nz.p_hit,
        "sigma": nz.sigma,
        "seed": seed,
    }
    return Scenario("doorways", truth, rig, traj, readings, tuple(passages), params)


def passages(
    *,
    widths: Sequence[float] = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.2),
    resolution: float = 0.05,
    block: float = 0.6,
    depth: float = 0.1,
    offset: float = 1.0,
    room: float = 2.0,
    posts: Sequence[float] = (0.05, 0.1, 0.2, 0.3),
    speed: float = 0.25,
    rate: float = 10.0,
    noise: Noise | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """Wall segments separated by gaps of increasing width, the robot passing alongside.

    Defaults: gaps of ``widths`` m (0.2 to 1.0 in 0.1 steps, and 1.2) between segments
    ``block`` m long (0.6) and ``depth`` m thick (0.1), in a row parallel to the robot's
    path at ``offset`` m (1.0) to its left, with a room ``room`` m deep (2.0) behind it
    that the sonars can see into through the gaps, and a wall the same distance to the
    right with square posts of ``posts`` m (0.05, 0.1, 0.2, 0.3) standing 0.6 m to the right
    of the path, evenly spread along it (annotated as small obstacles). The robot drives
    past the whole row at ``speed`` m/s (0.25) with the ``paper-synthetic`` rig at ``rate``
    Hz (10). Exact readings by default.

    A gap seen from one side only cannot be confirmed free beyond the near face by a
    wide beam (it always hits a corner first); a room behind it is what lets the oblique
    sonars look through, as in the research's corridor.
    """
    _check_positive(
        resolution=resolution,
        block=block,
        depth=depth,
        offset=offset,
        room=room,
        speed=speed,
        rate=rate,
    )
    if not widths or any(w <= 0 for w in widths):
        raise ConfigError("scenario parameter 'widths' must be positive widths")
    if any(not (0 < p <= 0.4) for p in posts):
        raise ConfigError("scenario parameter 'posts' must be sizes in (0, 0.4] m")
    wall = 0.1
    length = 1.0 + block + sum(w + block for w in widths) + 1.0
    x_path = wall + offset + 0.2
    x_row = x_path + offset
    width = x_row + depth + room + wall
    grid = Grid.from_bounds(0.0, 0.0, width, length, resolution)
    plan = _Plan(grid)
    plan.border(wall)
    plan.box(wall, 0, x_path - offset, length)
    y = 1.0
    plan.box(x_row, 0, x_row + depth, y + block)
    y += block
    found = []
    for k, w in enumerate(widths):
        found.append(
            Passage(f"gap{k + 1}", (x_row + depth / 2, y), (x_row + depth / 2, y + w), depth)
        )
        y += w
        end = length if k == len(widths) - 1 else y + block
        plan.box(x_row, y, x_row + depth, end)
        y += block
    small = tuple(
        plan.post(f"post{k + 1}", x_path - 0.6, 1.0 + (length - 2.0) * (k + 0.5) / len(posts), p)
        for k, p in enumerate(posts)
    )
    truth = plan.done()
    nz = noise if noise is not None else Noise(0.0, 1.0, 0.0)
    rig = _with_noise(get_rig("paper-synthetic"), nz)
    traj = _straight(x_path, 0.5, length - 0.5, speed, rate)
    readings = simulate(truth, rig, traj, noise=nz, seed=seed, progress=progress)
    params = {
        "widths": list(widths),
        "resolution": resolution,
        "block": block,
        "depth": depth,
        "offset": offset,
        "room": room,
        "posts": list(posts),
        "speed": speed,
        "rate": rate,
        "p_rand": nz.p_rand,
        "p_hit": nz.p_hit,
        "sigma": nz.sigma,
        "seed": seed,
    }
    return Scenario("passages", truth, rig, traj, readings, tuple(found), params, small)


def room_turn(
    *,
    room: float = 4.0,
    resolution: float = 0.05,
    door_width: float = 0.9,
    turns: float = 1.0,
    duration: float = 30.0,
    rate: float = 10.0,
    noise: Noise | None = None,
    mount_yaw_sigma_deg: float = 2.0,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """A room with a door; the ``paper-real`` rig turns in place at uneven speed.

    Defaults: a ``room`` m square room (4 m) inside a 6 m territory, a door ``door_width``
    m wide (0.9) in its upper wall; the robot stands off-centre and makes ``turns`` (1)
    turns in ``duration`` s (30), its angular speed varying by a factor of five, the four
    sonars firing at ``rate`` Hz (10). Noise p_rand = 0.05, p_hit = 0.9, sigma = 1 cm.
    The readings come from sonars whose yaw differs from the written rig by Gaussian
    errors of ``mount_yaw_sigma_deg`` degrees (2): the mounting is known only roughly.
    """
    _check_positive(
        room=room,
        resolution=resolution,
        door_width=door_width,
        turns=turns,
        duration=duration,
        rate=rate,
    )
    if not (math.isfinite(mount_yaw_sigma_deg) and mount_yaw_sigma_deg >= 0):
        raise ConfigError(
            f"scenario parameter 'mount_yaw_sigma_deg' must be >= 0, got {mount_yaw_sigma_deg}"
        )
    if door_width > room - 0.4:
        raise ConfigError(f"door_width {door_width} m does not fit a {room} m room")
    wall = 0.1
    size = room + 2.0
    grid = Grid.from_bounds(0.0, 0.0, size, size, resolution)
    plan = _Plan(grid)
    plan.border(wall)
    lo, hi = 1.0, 1.0 + room
    plan.box(lo - wall, lo - wall, hi + wall, lo)
    plan.box(lo - wall, hi, hi + wall, hi + wall)
    plan.box(lo - wall, lo - wall, lo, hi + wall)
    plan.box(hi, lo - wall, hi + wall, hi + wall)
    dx = lo + room * 0.55
    plan.clear(dx - door_width / 2, hi, dx + door_width / 2, hi + wall)
    truth = plan.done()
    door = Passage(
        "door", (dx - door_width / 2, hi + wall / 2), (dx + door_width / 2, hi + wall / 2), wall
    )

    n = int(duration * rate) + 1
    t = np.arange(n) / rate
    # Angular speed 1 + 0.67 sin(...) varies between 0.33 and 1.67 of its mean.
    phase = 2 * math.pi * t / duration
    angle = 2 * math.pi * turns * (phase - 0.67 * (np.cos(phase * 3) - 1) / 3) / (2 * math.pi)
    traj = Trajectory(
        t, np.full(n, lo + room * 0.45), np.full(n, lo + room * 0.4), np.angle(np.exp(1j * angle))
    )
    nz = noise if noise is not None else Noise(0.05, 0.9, 0.01)
    rig = _with_noise(get_rig("paper-real"), nz)
    rng = np.random.default_rng(seed + 7919)
    actual = replace(
        rig,
        mounts=tuple(
            Mount(m.name, m.x, m.y, m.yaw_deg + mount_yaw_sigma_deg * float(rng.standard_normal()))
            for m in rig.mounts
        ),
    )
    readings = simulate(truth, actual, traj, noise=nz, seed=seed, progress=progress)
    # The recorded poses are those the nominal mounting gives, as a real robot would log.
    sx, sy, st = (a.reshape(-1) for a in rig.sensor_poses(traj.x, traj.y, traj.theta))
    readings = replace(readings, x=sx, y=sy, theta=st)
    params = {
        "room": room,
        "resolution": resolution,
        "door_width": door_width,
        "turns": turns,
        "duration": duration,
        "rate": rate,
        "mount_yaw_sigma_deg": mount_yaw_sigma_deg,
        "p_rand": nz.p_rand,
        "p_hit": nz.p_hit,
        "sigma": nz.sigma,
        "seed": seed,
    }
    return Scenario("room-turn", truth, rig, traj, readings, (door,), params)


def _waypoint_path(
    points: Sequence[tuple[float, float]], speed: float, rate: float, duration: float
) -> Trajectory:
    """Drive a closed polyline at constant speed, heading along it, looping until
    ``duration`` s have passed; poses at ``rate`` Hz."""
    pts = np.asarray([*list(points), points[0]], dtype=float)
    seg = np.diff(pts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = length > 0
    pts0, seg, length = pts[:-1][keep], seg[keep], length[keep]
    start = np.concatenate([[0.0], np.cumsum(length)])
    n = round(duration * rate)
    t = np.arange(n) / rate
    s = (speed * t) % start[-1]
    k = np.minimum(np.searchsorted(start, s, side="right") - 1, len(length) - 1)
    f = (s - start[k]) / length[k]
    x = pts0[k, 0] + f * seg[k, 0]
    y = pts0[k, 1] + f * seg[k, 1]
    return Trajectory(t, x, y, np.arctan2(seg[k, 1], seg[k, 0]))


def office(
    *,
    size: float = 20.0,
    resolution: float = 0.05,
    rooms: int = 4,
    door_widths: Sequence[float] = (1.0, 0.8, 0.9, 1.2, 0.7, 1.0, 0.8, 0.9),
    duration: float = 600.0,
    speed: float = 0.5,
    rate: float = 20.0,
    noise: Noise | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """An office floor toured by a robot with a ring of 16 sonars: the streaming benchmark.

    Defaults: a ``size`` m square floor (20 m) at ``resolution`` m (5 cm); a corridor 2 m
    wide across the middle; ``rooms`` rooms (4) on each side, each with a door of
    ``door_widths`` m onto the corridor (top row left to right, then the bottom row) and
    a cabinet and a post inside. The ``ring16`` rig (Polaroid sonars) fires every sonar
    at ``rate`` Hz (20) while the robot drives the corridor and a loop through every room
    at ``speed`` m/s (0.5) for ``duration`` s (600): 192,000 readings by default.
    Noise p_rand = 0.01, p_hit = 0.95, sigma = 1 cm.
    """
    _check_positive(
        size=size, resolution=resolution, duration=duration, speed=speed, rate=rate, rooms=rooms
    )
    if len(door_widths) != 2 * rooms or any(not (w >= 0.3) for w in door_widths):
        raise ConfigError(f"scenario parameter 'door_widths' must hold {2 * rooms} widths >= 0.3 m")
    wall = 0.1
    room_w = size / rooms
    if size < 10 or room_w < 3.0 or max(door_widths) > room_w - 1.0:
        raise ConfigError(f"{rooms} rooms with doors {list(door_widths)} do not fit {size} m")
    grid = Grid.from_bounds(0.0, 0.0, size, size, resolution)
    plan = _Plan(grid)
    plan.border(wall)
    mid = size / 2
    y_lo, y_hi = mid - 1.0, mid + 1.0
    plan.box(0, y_hi, size, y_hi + wall)
    plan.box(0, y_lo - wall, size, y_lo)
    found: list[Passage] = []
    small: list[SmallObstacle] = []
    centres = [room_w * (i + 0.5) for i in range(rooms)]
    for k in range(1, rooms):
        plan.box(room_w * k - wall / 2, y_hi, room_w * k + wall / 2, size)
        plan.box(room_w * k - wall / 2, 0, room_w * k + wall / 2, y_lo)
    for side, (y_wall, inward) in enumerate(((y_hi, 1.0), (y_lo - wall, -1.0))):
        for i, cx in enumerate(centres):
            w = door_widths[side * rooms + i]
            plan.clear(cx - w / 2, y_wall, cx + w / 2, y_wall + wall)
            found.append(
                Passage(
                    f"door{side * rooms + i + 1}",
                    (cx - w / 2, y_wall + wall / 2),
                    (cx + w / 2, y_wall + wall / 2),
                    wall,
                )
            )
            # A cabinet against the side wall and a post, clear of the robot's loop.
            far = mid + inward * (size / 2 - 1.0)
            x0 = cx - room_w / 2 + wall
            plan.box(x0, min(far, far - inward * 1.2), x0 + 0.5, max(far, far - inward * 1.2))
            small.append(plan.post(f"post{side * rooms + i + 1}", cx + room_w / 2 - 0.6, far, 0.15))
    truth = plan.done()
    depth = min(3.0, size / 2 - 3.0)
    points: list[tuple[float, float]] = [(0.8, mid)]
    for side_sign in (1.0, -1.0):
        xs = centres if side_sign > 0 else centres[::-1]
        for cx in xs:
            y_in = mid + side_sign * (1.0 + 1.0)
            y_far = mid + side_sign * (1.0 + depth)
            points += [
                (cx, mid),
                (cx, y_in),
                (cx - room_w / 2 + 1.0, y_in),
                (cx - room_w / 2 + 1.0, y_far),
                (cx + room_w / 2 - 1.2, y_far),
                (cx + room_w / 2 - 1.2, y_in),
                (cx, y_in),
                (cx, mid),
            ]
        points.append((size - 0.8, mid) if side_sign > 0 else (0.8, mid))
    traj = _waypoint_path(points, speed, rate, duration)
    nz = noise if noise is not None else Noise(0.01, 0.95, 0.01)
    rig = _with_noise(get_rig("ring16"), nz)
    readings = simulate(truth, rig, traj, noise=nz, seed=seed, chunk_size=2_000, progress=progress)
    params = {
        "size": size,
        "resolution": resolution,
        "rooms": rooms,
        "door_widths": list(door_widths),
        "duration": duration,
        "speed": speed,
        "rate": rate,
        "p_rand": nz.p_rand,
        "p_hit": nz.p_hit,
        "sigma": nz.sigma,
        "seed": seed,
    }
    return Scenario("office", truth, rig, traj, readings, tuple(found), params, tuple(small))


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "doorways": doorways,
    "passages": passages,
    "room-turn": room_turn,
    "office": office,
}


def make_scenario(name: str, **params: Any) -> Scenario:
    """Build a scenario by name with keyword parameters (see each scenario's function)."""
    try:
        fn = SCENARIOS[name]
    except KeyError:
        raise ConfigError(f"unknown scenario '{name}'; valid: {', '.join(SCENARIOS)}") from None
    import inspect

    valid = [p for p in inspect.signature(fn).parameters if p != "progress"]
    bad = set(params) - set(valid) - {"progress"}
    if bad:
        raise ConfigError(
            f"unknown parameter(s) {sorted(bad)} for scenario '{name}'; valid: {', '.join(valid)}"
        )
    return fn(**params)


def load_annotations(path: str | Path) -> tuple[tuple[Passage, ...], tuple[SmallObstacle, ...]]:
    """Passages and small obstacles from a scenario's ``annotations.yaml``."""
    from .errors import InputError
    from .io._yaml import read_yaml

    p = Path(path)
    data = read_yaml(p, "annotations")
    if not isinstance(data, dict):
        raise InputError("expected a mapping with 'passages' and 'small_obstacles'", path=p)
    items = data.get("passages") or []
    posts = data.get("small_obstacles") or []
    for key, value in (("passages", items), ("small_obstacles", posts)):
        if not isinstance(value, list):
            raise InputError(f"expected a list under '{key}'", path=p, field=key)
    out = []
    for i, d in enumerate(items):
        try:
            out.append(
                Passage(
                    str(d["name"]),
                    (float(d["a"][0]), float(d["a"][1])),
                    (float(d["b"][0]), float(d["b"][1])),
                    float(d.get("depth", 0.1)),
                )
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(
                f"bad passage entry ({err!r})", path=p, field=f"passages[{i}]"
            ) from err
    small = []
    for i, d in enumerate(posts):
        try:
            small.append(
                SmallObstacle(
                    str(d["name"]), (float(d["centre"][0]), float(d["centre"][1])), float(d["size"])
                )
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(
                f"bad small obstacle entry ({err!r})", path=p, field=f"small_obstacles[{i}]"
            ) from err
    return tuple(out), tuple(small)


def load_scene(folder: str | Path, *, seed: int = 0, noise: Noise | None = None) -> Scenario:
    """A scene from a folder like those :meth:`Scenario.write` makes, or made by hand.

    The folder holds ``truth.yaml`` (map_server), ``rig.yaml``, and ``readings.csv`` or
    ``trajectory.csv`` (or both), optionally ``annotations.yaml``. With a trajectory and
    ``noise`` given, readings are simulated from it with ``seed``; otherwise the
    recorded ``readings.csv`` is used (simulated from the trajectory with the rig's
    noise when there is none).
    """
    from .errors import InputError
    from .io.rosmap import read_map
    from .readings import read_readings, read_trajectory
    from .rig import load_rig

    d = Path(folder)
    if not d.is_dir():
        raise InputError("scene folder not found", path=d)
    for name in ("truth.yaml", "rig.yaml"):
        if not (d / name).is_file():
            raise InputError(f"scene folder lacks {name}", path=d)
    truth = read_map(d / "truth.yaml")
    rig = load_rig(d / "rig.yaml")
    has_traj = (d / "trajectory.csv").is_file()
    has_readings = (d / "readings.csv").is_file()
    if not (has_traj or has_readings):
        raise InputError("scene folder needs readings.csv or trajectory.csv", path=d)
    traj = read_trajectory(d / "trajectory.csv") if has_traj else None
    if traj is not None and (noise is not None or not has_readings):
        nz = noise if noise is not None else rig.sensor.noise
        rig = replace(rig, sensor=replace(rig.sensor, noise=nz))
        readings = simulate(truth, rig, traj, noise=nz, seed=seed)
    else:
        readings = read_readings(d / "readings.csv", names=rig.names)
        traj = (
            traj
            if traj is not None
            else Trajectory(readings.t, readings.x, readings.y, readings.theta)
        )
    passages: tuple[Passage, ...] = ()
    obstacles: tuple[SmallObstacle, ...] = ()
    if (d / "annotations.yaml").is_file():
        passages, obstacles = load_annotations(d / "annotations.yaml")
    return Scenario(d.name, truth, rig, traj, readings, passages, {"folder": str(d)}, obstacles)
