"""Built-in scenarios: floor plan, rig, trajectory and simulated readings.

Each scenario writes ``truth.yaml``/``truth.pgm``/``truth.npy`` (the floor plan on the
mapping grid), ``geometry.yaml``/``geometry.pgm`` (the same plan at 1 cm, what the
simulated sonar saw), ``rig.yaml`` (the sensor's nominal specification: never the
simulation's noise), ``trajectory.csv``, ``readings.csv`` and ``annotations.yaml``
(passages: the two jamb points across each opening; small obstacles) to a folder.

Readings come from the acoustic sonar model by default (:mod:`sonarmap.acoustics`);
``model=Noise(...)`` runs Thrun's model on the map's cells instead, to reproduce the
papers (``PAPER_NOISE`` holds the noise each paper scene used).

Training families (:mod:`sonarmap.splits`), the research's scenes:

- ``doorways``: the synthetic corridor (thesis 000 fig. 4.1, left): a 6 m x 6 m
  territory, a corridor with doorways into rooms on both sides, the robot driving
  straight up the middle with the ``paper-synthetic`` rig.
- ``passages``: a row of blocks separated by gaps of increasing width beside the robot's
  path (thesis 002, figs 4.9-4.10).
- ``room-turn``: a room with a door; the ``paper-real`` rig turns in place at uneven speed,
  with a roughly known sonar mounting (thesis 000 fig. 4.1, right).
- ``boxes``: a corridor between two rows of boxes, in two layouts (thesis 002 section
  4.4.2, the stochastic method's experiment).
- ``hall``: an L-shaped hall with a pillar and a side room, drawn from the seed, walked
  once round by a preset rig (six MaxSonar EZ1s by default): the scene that spans the
  sensor presets in training.
- ``suite``: two to four rooms off a corridor, each with a door, a cabinet and a post,
  drawn from the seed and toured by a preset rig: the training scene shaped like the
  floors users map (the held-out ``office`` is drawn by other rules).

Held-out families, drawn from their seed so that no two are alike:

- ``gaps``: a wall of random thickness with gaps of 0.15 to 0.8 m in shuffled order
  between blocks of random length, off the cell boundaries, a room of random depth
  behind it and posts on the other side; the robot weaves past.
- ``corridor``: a corridor of random width and length with doors of random widths at
  random places on both sides, rooms behind them (some split by walls) with furniture.
- ``office``: a 20 m office floor with eight rooms toured for 10 minutes by a 16-sonar
  ring firing at 20 Hz (192,000 readings): also the streaming benchmark's scene.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .acoustics import AcousticModel
from .annotations import Passage, SmallObstacle, load_annotations, write_annotations
from .checks import numbers_where_floats
from .errors import ConfigError
from .floorplan import FloorPlan
from .io.rosmap import OccupancyMap, write_map
from .readings import Readings, Trajectory, write_readings, write_trajectory
from .rig import RIG_PRESETS, Mount, Rig, get_rig, save_rig
from .sensors import Noise
from .simulate import SonarModel, simulate

__all__ = [
    "PAPER_NOISE",
    "SCENARIOS",
    "Scenario",
    "load_scene",
    "make_scenario",
    "model_from_dict",
    "model_to_dict",
]

Progress = Callable[[int, int], None]

#: Thrun-model noise of the research's scenes, for ``model=PAPER_NOISE[name]``.
PAPER_NOISE: dict[str, Noise] = {
    "doorways": Noise(0.0, 1.0, 0.0),
    "passages": Noise(0.0, 1.0, 0.0),
    "room-turn": Noise(0.05, 0.9, 0.01),
    "office": Noise(0.01, 0.95, 0.01),
    "gaps": Noise(0.0, 1.0, 0.01),
    "corridor": Noise(0.0, 1.0, 0.01),
    # Thesis 002's probabilistic model (set (4.5)); it gives no range noise.
    "boxes": Noise(0.001, 0.35, 0.01),
}

#: Widths of the held-out ``gaps`` scenes (metres), shuffled per seed.
GAP_WIDTHS = (
    0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.9, 1.0, 1.2,
)  # fmt: skip

#: Cell size (metres) of the geometry the acoustic sonar sees.
GEOMETRY_CELL = 0.01


@dataclass(frozen=True, eq=False)
class Scenario:
    """Everything a mapping experiment needs, in memory.

    ``geometry`` is the plan the readings were simulated from (finer than ``truth``),
    when known.
    """

    name: str
    truth: OccupancyMap
    rig: Rig
    trajectory: Trajectory
    readings: Readings
    passages: tuple[Passage, ...] = ()
    params: dict[str, Any] = field(default_factory=dict)
    obstacles: tuple[SmallObstacle, ...] = ()
    geometry: OccupancyMap | None = None

    def write(self, folder: str | Path) -> Path:
        """Write the scenario files into ``folder`` (created if needed)."""
        d = Path(folder)
        d.mkdir(parents=True, exist_ok=True)
        write_map(self.truth, d / "truth")
        if self.geometry is not None:
            write_map(self.geometry, d / "geometry", exact=False)
        save_rig(self.rig, d / "rig.yaml")
        write_trajectory(self.trajectory, d / "trajectory.csv")
        write_readings(self.readings, d / "readings.csv")
        write_annotations(
            d / "annotations.yaml", self.name, self.params, self.passages, self.obstacles
        )
        return d


def model_to_dict(model: SonarModel) -> dict[str, Any]:
    """A sonar model as a plain mapping (``kind`` and its parameters).

    Examples
    --------
    >>> model_to_dict(Noise(0.05, 0.9, 0.01))
    {'kind': 'thrun', 'p_rand': 0.05, 'p_hit': 0.9, 'sigma': 0.01}
    """
    if isinstance(model, Noise):
        return {"kind": "thrun", "p_rand": model.p_rand, "p_hit": model.p_hit, "sigma": model.sigma}
    return {"kind": "acoustic", **model.to_dict()}


def model_from_dict(d: dict[str, Any], where: str = "model") -> SonarModel:
    """The inverse of :func:`model_to_dict`; ``kind`` defaults to ``acoustic``."""
    params = dict(d)
    kind = params.pop("kind", "acoustic")
    if kind == "thrun":
        bad = sorted(set(params) - {"p_rand", "p_hit", "sigma"})
        if bad:
            raise ConfigError(f"{where}: unknown parameter(s) {bad}; valid: p_hit, p_rand, sigma")
        return Noise(
            **numbers_where_floats({"p_rand": 0.0, "p_hit": 1.0, "sigma": 0.0, **params}, Noise)
        )
    if kind == "acoustic":
        return AcousticModel.from_dict(params, where)
    raise ConfigError(f"{where}: kind must be acoustic or thrun, got {kind!r}")


def _check_positive(**values: float) -> None:
    for k, v in values.items():
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"scenario parameter '{k}' must be > 0, got {v}")


def _readings(
    plan: FloorPlan,
    truth: OccupancyMap,
    rig: Rig,
    traj: Trajectory,
    model: SonarModel | None,
    seed: int,
    progress: Progress | None,
    **kwargs: Any,
) -> tuple[Readings, OccupancyMap, SonarModel]:
    """Simulate the readings: the acoustic sonar sees the plan at 1 cm, Thrun's model
    the truth's cells. Returns the readings, the geometry used and the model."""
    model = AcousticModel() if model is None else model
    world = truth if isinstance(model, Noise) else plan.render(plan.grid(GEOMETRY_CELL))
    readings = simulate(world, rig, traj, model=model, seed=seed, progress=progress, **kwargs)
    return readings, world, model


def _preset_rig(name: str) -> Rig:
    """The preset rig a scenario's ``rig`` parameter names (a ConfigError naming it if none)."""
    if not isinstance(name, str) or name not in RIG_PRESETS:
        raise ConfigError(
            f"scenario parameter 'rig' must be a rig preset ({', '.join(RIG_PRESETS)}), "
            f"got {name!r}"
        )
    return get_rig(name)


def _post(plan: FloorPlan, name: str, cx: float, cy: float, size: float) -> SmallObstacle:
    plan.box(cx - size / 2, cy - size / 2, cx + size / 2, cy + size / 2)
    return SmallObstacle(name, (cx, cy), size)


def _gapped_wall(
    plan: FloorPlan,
    x: float,
    depth: float,
    start: float,
    widths: Sequence[float],
    blocks: Sequence[float],
    length: float,
) -> list[Passage]:
    """A wall ``depth`` thick from x to x + depth along y in [0, length], with gaps of
    ``widths`` between blocks: the first block ends at ``start + blocks[0]``, the last
    runs to ``length``."""
    y = start + blocks[0]
    plan.box(x, 0.0, x + depth, y)
    found = []
    for k, w in enumerate(widths):
        found.append(Passage(f"gap{k + 1}", (x + depth / 2, y), (x + depth / 2, y + w), depth))
        y += w
        end = length if k == len(widths) - 1 else y + blocks[k + 1]
        plan.box(x, y, x + depth, end)
        y += blocks[k + 1]
    return found


def _straight(x: float, y0: float, y1: float, speed: float, rate: float) -> Trajectory:
    n = math.floor((y1 - y0) / speed * rate) + 1
    t = np.arange(n) / rate
    return Trajectory(t, np.full(n, x), y0 + speed * t, np.full(n, math.pi / 2))


def _weaving(
    x: float, y0: float, y1: float, speed: float, rate: float, amplitude: float, period: float
) -> Trajectory:
    """Up the line x = ``x`` from y0 to y1, swaying ``amplitude`` m either side every
    ``period`` m, heading along the path."""
    n = math.floor((y1 - y0) / speed * rate) + 1
    t = np.arange(n) / rate
    y = y0 + speed * t
    k = 2 * math.pi / period
    xs = x + amplitude * np.sin(k * (y - y0))
    heading = np.arctan2(1.0, amplitude * k * np.cos(k * (y - y0)))
    return Trajectory(t, xs, y, heading)


def _record(model: SonarModel, seed: int, **params: Any) -> dict[str, Any]:
    out = {k: (list(v) if isinstance(v, tuple) else v) for k, v in params.items()}
    return {**out, "model": model_to_dict(model), "seed": seed}


def doorways(
    *,
    size: float = 6.0,
    resolution: float = 0.05,
    corridor_width: float = 2.0,
    wall: float = 0.1,
    door_widths: Sequence[float] = (1.0, 0.8, 0.9, 0.7),
    speed: float = 0.25,
    rate: float = 10.0,
    rig: str = "paper-synthetic",
    model: SonarModel | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """The research's corridor with doorways.

    Defaults: a ``size`` x ``size`` m territory at ``resolution`` m (6 m, 5 cm), walls
    ``wall`` m thick around it and along a corridor of ``corridor_width`` m (2 m) centred
    on x = size / 2; doorways of ``door_widths`` m (1.0, 0.8, 0.9, 0.7) alternate between
    the left and right corridor walls, evenly spaced along the corridor. The robot drives up
    the corridor centre from y = 0.5 to size - 0.5 at ``speed`` m/s (0.25), every sonar
    of the preset ``rig`` (``paper-synthetic``: six MaxSonar EZ1s) firing at ``rate`` Hz
    (10). The research's readings were exact: ``model=PAPER_NOISE["doorways"]``.
    """
    scene_rig = _preset_rig(rig)
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
    plan = FloorPlan((0.0, 0.0, size, size))
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
    truth = plan.render(plan.grid(resolution))
    traj = _straight(cx, 0.5, size - 0.5, speed, rate)
    readings, world, used = _readings(plan, truth, scene_rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        size=size,
        resolution=resolution,
        corridor_width=corridor_width,
        wall=wall,
        door_widths=door_widths,
        speed=speed,
        rate=rate,
        rig=rig,
    )
    return Scenario(
        "doorways", truth, scene_rig, traj, readings, tuple(passages), params, geometry=world
    )


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
    model: SonarModel | None = None,
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
    Hz (10).

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
    plan = FloorPlan((0.0, 0.0, width, length))
    plan.border(wall)
    plan.box(wall, 0, x_path - offset, length)
    found = _gapped_wall(plan, x_row, depth, 1.0, widths, [block] * (len(widths) + 1), length)
    small = tuple(
        _post(plan, f"post{k + 1}", x_path - 0.6, 1.0 + (length - 2.0) * (k + 0.5) / len(posts), p)
        for k, p in enumerate(posts)
    )
    truth = plan.render(plan.grid(resolution))
    rig = get_rig("paper-synthetic")
    traj = _straight(x_path, 0.5, length - 0.5, speed, rate)
    readings, world, used = _readings(plan, truth, rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        widths=widths,
        resolution=resolution,
        block=block,
        depth=depth,
        offset=offset,
        room=room,
        posts=posts,
        speed=speed,
        rate=rate,
    )
    return Scenario(
        "passages", truth, rig, traj, readings, tuple(found), params, small, geometry=world
    )


def room_turn(
    *,
    room: float = 4.0,
    resolution: float = 0.05,
    door_width: float = 0.9,
    turns: float = 1.0,
    duration: float = 30.0,
    rate: float = 10.0,
    model: SonarModel | None = None,
    mount_yaw_sigma_deg: float = 2.0,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """A room with a door; the ``paper-real`` rig turns in place at uneven speed.

    Defaults: a ``room`` m square room (4 m) inside a 6 m territory, a door ``door_width``
    m wide (0.9) in its upper wall; the robot stands off-centre and makes ``turns`` (1)
    turns in ``duration`` s (30), its angular speed varying by a factor of five, the four
    sonars firing at ``rate`` Hz (10). The readings come from sonars whose yaw differs
    from the written rig by Gaussian errors of ``mount_yaw_sigma_deg`` degrees (2): the
    mounting is known only roughly.
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
    plan = FloorPlan((0.0, 0.0, size, size))
    plan.border(wall)
    lo, hi = 1.0, 1.0 + room
    plan.box(lo - wall, lo - wall, hi + wall, lo)
    plan.box(lo - wall, hi, hi + wall, hi + wall)
    plan.box(lo - wall, lo - wall, lo, hi + wall)
    plan.box(hi, lo - wall, hi + wall, hi + wall)
    dx = lo + room * 0.55
    plan.clear(dx - door_width / 2, hi, dx + door_width / 2, hi + wall)
    truth = plan.render(plan.grid(resolution))
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
    rig = get_rig("paper-real")
    rng = np.random.default_rng(seed + 7919)
    actual = replace(
        rig,
        mounts=tuple(
            Mount(m.name, m.x, m.y, m.yaw_deg + mount_yaw_sigma_deg * float(rng.standard_normal()))
            for m in rig.mounts
        ),
    )
    readings, world, used = _readings(plan, truth, actual, traj, model, seed, progress)
    # The recorded poses are those the nominal mounting gives, as a real robot would log.
    sx, sy, st = (a.reshape(-1) for a in rig.sensor_poses(traj.x, traj.y, traj.theta))
    readings = replace(readings, x=sx, y=sy, theta=st)
    params = _record(
        used,
        seed,
        room=room,
        resolution=resolution,
        door_width=door_width,
        turns=turns,
        duration=duration,
        rate=rate,
        mount_yaw_sigma_deg=mount_yaw_sigma_deg,
    )
    return Scenario("room-turn", truth, rig, traj, readings, (door,), params, geometry=world)


def gaps(
    *,
    widths: Sequence[float] = GAP_WIDTHS,
    resolution: float = 0.05,
    posts: int = 4,
    rate: float = 10.0,
    model: SonarModel | None = None,
    seed: int = 1000,
    progress: Progress | None = None,
) -> Scenario:
    """A held-out passages scene drawn from its seed.

    A wall 6 to 14 cm thick runs beside the robot's path, 0.8 to 1.3 m to one side,
    with gaps of ``widths`` m (0.15 to 0.8 in 5 cm steps, 0.9, 1.0 and 1.2) **in
    shuffled order** between blocks 0.4 to 0.9 m long; every coordinate is continuous,
    so walls and gaps fall anywhere relative to the cells. Behind the wall a room 1.5 to
    2.5 m deep; on the other side, a wall 0.8 to 1.3 m away with ``posts`` posts of 0.1
    to 0.3 m standing off it. The ``paper-synthetic`` rig drives past at 0.2 to 0.3
    m/s, weaving up to 5 cm either side, firing at ``rate`` Hz.
    """
    _check_positive(resolution=resolution, rate=rate)
    if not widths or any(not (0 < w <= 2.0) for w in widths):
        raise ConfigError("scenario parameter 'widths' must be widths in (0, 2] m")
    if posts < 0:
        raise ConfigError(f"scenario parameter 'posts' must be >= 0, got {posts}")
    rng = np.random.default_rng([seed, 0x6A95])
    order = [float(w) for w in rng.permutation(np.asarray(widths, dtype=float))]
    depth = float(rng.uniform(0.06, 0.14))
    offset = float(rng.uniform(0.8, 1.3))
    right = float(rng.uniform(0.8, 1.3))
    room = float(rng.uniform(1.5, 2.5))
    speed = float(rng.uniform(0.2, 0.3))
    blocks = rng.uniform(0.4, 0.9, len(order) + 1)
    wall = 0.1
    start = float(rng.uniform(0.8, 1.2))
    length = start + float(blocks.sum()) + sum(order) + 1.0
    x_right = wall + float(rng.uniform(0.0, 0.2))
    x_path = x_right + right
    x_row = x_path + offset
    width = x_row + depth + room + wall
    plan = FloorPlan((0.0, 0.0, width, length))
    plan.border(wall)
    plan.box(0.0, 0.0, x_right, length)
    found = _gapped_wall(plan, x_row, depth, start, order, [float(b) for b in blocks], length)
    small = tuple(
        _post(
            plan,
            f"post{k + 1}",
            x_right + float(rng.uniform(0.25, 0.4)),
            1.0 + (length - 2.0) * (k + float(rng.uniform(0.3, 0.7))) / max(posts, 1),
            round(float(rng.uniform(0.1, 0.3)), 3),
        )
        for k in range(posts)
    )
    truth = plan.render(plan.grid(resolution))
    rig = get_rig("paper-synthetic")
    traj = _weaving(x_path, 0.5, length - 0.5, speed, rate, float(rng.uniform(0.0, 0.05)), 2.0)
    readings, world, used = _readings(plan, truth, rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        widths=order,
        resolution=resolution,
        depth=round(depth, 4),
        offset=round(offset, 4),
        room=round(room, 4),
        speed=round(speed, 4),
        rate=rate,
    )
    return Scenario("gaps", truth, rig, traj, readings, tuple(found), params, small, geometry=world)


def corridor(
    *,
    resolution: float = 0.05,
    rate: float = 10.0,
    rig: str = "paper-synthetic",
    model: SonarModel | None = None,
    seed: int = 1000,
    progress: Progress | None = None,
) -> Scenario:
    """A held-out corridor scene drawn from its seed.

    A corridor 1.6 to 2.4 m wide and 6 to 9 m long with walls 8 to 15 cm thick; two or
    three doors 0.5 to 1.2 m wide at random places in each wall, rooms 1.5 to 2.5 m
    deep behind them, split by walls between the doors half of the time, with one or
    two pieces of furniture (boxes of 0.3 to 0.8 m) in each room away from the doors.
    The preset ``rig`` (``paper-synthetic``) drives up the corridor at 0.2 to 0.35 m/s,
    weaving up to 15 cm either side, firing at ``rate`` Hz.
    """
    scene_rig = _preset_rig(rig)
    _check_positive(resolution=resolution, rate=rate)
    rng = np.random.default_rng([seed, 0xC0DE])
    width = float(rng.uniform(1.6, 2.4))
    length = float(rng.uniform(6.0, 9.0))
    wall = float(rng.uniform(0.08, 0.15))
    depth_l, depth_r = (float(v) for v in rng.uniform(1.5, 2.5, 2))
    border = 0.1
    x_l = border + depth_l + wall  # the corridor's left wall face
    x_r = x_l + width
    total_w = x_r + wall + depth_r + border
    plan = FloorPlan((0.0, 0.0, total_w, length))
    plan.border(border)
    plan.box(x_l - wall, 0.0, x_l, length)
    plan.box(x_r, 0.0, x_r + wall, length)
    found: list[Passage] = []
    for side, (x0, x1, x_far) in enumerate(
        ((x_l - wall, x_l, border), (x_r, x_r + wall, total_w - border))
    ):
        n = int(rng.integers(2, 4))
        widths = rng.uniform(0.5, 1.2, n)
        # Doors spread along the wall with at least 0.5 m of wall between them.
        free = length - 1.6 - float(widths.sum()) - 0.5 * (n - 1)
        if free < 0:
            widths *= (length - 1.6 - 0.5 * (n - 1)) / float(widths.sum())
            free = 0.0
        cuts = np.sort(rng.uniform(0.0, free, n))
        y = 0.8
        spans = []
        for k in range(n):
            y0 = y + (cuts[k] - (cuts[k - 1] if k else 0.0))
            y1 = y0 + float(widths[k])
            plan.clear(x0, y0, x1, y1)
            xm = (x0 + x1) / 2
            found.append(Passage(f"door{len(found) + 1}", (xm, y0), (xm, y1), wall))
            spans.append((y0, y1))
            y = y1 + 0.5
        # Walls between the rooms, halfway between doors, half of the time.
        lo, hi = (x_far, x0) if side == 0 else (x1, x_far)
        for (_, a1), (b0, _) in itertools.pairwise(spans):
            if rng.random() < 0.5:
                ym = (a1 + b0) / 2
                plan.box(lo, ym - wall / 2, hi, ym + wall / 2)
        # Furniture away from the doors: against the far wall.
        for _ in range(int(rng.integers(1, 3))):
            size_x, size_y = (float(v) for v in rng.uniform(0.3, 0.8, 2))
            yc = float(rng.uniform(0.8, length - 0.8))
            if side == 0:
                plan.box(lo + 0.05, yc - size_y / 2, lo + 0.05 + size_x, yc + size_y / 2)
            else:
                plan.box(hi - 0.05 - size_x, yc - size_y / 2, hi - 0.05, yc + size_y / 2)
    truth = plan.render(plan.grid(resolution))
    speed = float(rng.uniform(0.2, 0.35))
    traj = _weaving(
        (x_l + x_r) / 2, 0.5, length - 0.5, speed, rate, float(rng.uniform(0.0, 0.15)), 3.0
    )
    readings, world, used = _readings(plan, truth, scene_rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        resolution=resolution,
        width=round(width, 4),
        length=round(length, 4),
        wall=round(wall, 4),
        door_widths=[round(p.width, 4) for p in found],
        speed=round(speed, 4),
        rate=rate,
        rig=rig,
    )
    return Scenario(
        "corridor", truth, scene_rig, traj, readings, tuple(found), params, geometry=world
    )


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
    rig: str = "ring16",
    model: SonarModel | None = None,
    seed: int = 1000,
    progress: Progress | None = None,
) -> Scenario:
    """An office floor toured by a robot with a ring of 16 sonars: the streaming benchmark.

    Defaults: a ``size`` m square floor (20 m) at ``resolution`` m (5 cm); a corridor 2 m
    wide across the middle; ``rooms`` rooms (4) on each side, each with a door of
    ``door_widths`` m onto the corridor (top row left to right, then the bottom row) and
    a cabinet and a post inside. The preset ``rig`` (``ring16``: 16 Polaroid sonars)
    fires every sonar at ``rate`` Hz (20) while the robot drives the corridor and a loop
    through every room at ``speed`` m/s (0.5) for ``duration`` s (600): 192,000 readings
    by default.
    """
    scene_rig = _preset_rig(rig)
    _check_positive(
        size=size, resolution=resolution, duration=duration, speed=speed, rate=rate, rooms=rooms
    )
    if len(door_widths) != 2 * rooms or any(not (w >= 0.3) for w in door_widths):
        raise ConfigError(f"scenario parameter 'door_widths' must hold {2 * rooms} widths >= 0.3 m")
    wall = 0.1
    room_w = size / rooms
    if size < 10 or room_w < 3.0 or max(door_widths) > room_w - 1.0:
        raise ConfigError(f"{rooms} rooms with doors {list(door_widths)} do not fit {size} m")
    plan = FloorPlan((0.0, 0.0, size, size))
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
            name = f"post{side * rooms + i + 1}"
            small.append(_post(plan, name, cx + room_w / 2 - 0.6, far, 0.15))
    truth = plan.render(plan.grid(resolution))
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
    readings, world, used = _readings(
        plan, truth, scene_rig, traj, model, seed, progress, chunk_size=2_000
    )
    params = _record(
        used,
        seed,
        size=size,
        resolution=resolution,
        rooms=rooms,
        door_widths=door_widths,
        duration=duration,
        speed=speed,
        rate=rate,
        rig=rig,
    )
    return Scenario(
        "office",
        truth,
        scene_rig,
        traj,
        readings,
        tuple(found),
        params,
        tuple(small),
        geometry=world,
    )


#: The two box layouts of :func:`boxes`: per row (left, right) the boxes as (length
#: along the corridor, depth across it) in metres, with the gaps between them.
BOX_LAYOUTS: dict[int, dict[str, tuple[tuple[tuple[float, float], ...], tuple[float, ...]]]] = {
    # Equal boxes evenly spaced, the rows facing each other.
    1: {
        "left": (((0.6, 0.6),) * 6, (0.5,) * 5),
        "right": (((0.6, 0.6),) * 6, (0.5,) * 5),
    },
    # Boxes of several sizes and gaps, the rows out of step.
    2: {
        "left": (
            ((0.4, 0.4), (0.8, 0.5), (0.5, 0.8), (0.3, 0.3), (0.7, 0.6), (0.6, 0.4)),
            (0.6, 0.35, 0.8, 0.45, 0.5),
        ),
        "right": (
            ((0.7, 0.7), (0.4, 0.6), (0.9, 0.4), (0.5, 0.5), (0.3, 0.8)),
            (0.4, 0.7, 0.3, 0.9),
        ),
    },
}


def boxes(
    *,
    layout: int = 1,
    resolution: float = 0.1,
    corridor: float = 2.0,
    room: float = 1.2,
    speed: float = 0.25,
    rate: float = 10.0,
    model: SonarModel | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """A corridor between two rows of boxes (thesis 002, section 4.4.2, fig. 4.4).

    The thesis tested its stochastic method on two synthetic maps whose readings came
    from its probabilistic sonar model, the robot driving along a corridor between
    series of boxes with three sonars on each side; it does not give their sizes. Here
    ``layout`` 1 has two facing rows of six 0.6 m boxes 0.5 m apart, ``layout`` 2 rows of
    boxes of different sizes (0.3 to 0.9 m) and gaps (0.3 to 0.9 m), out of step
    (:data:`BOX_LAYOUTS`). The rows' inner faces are ``corridor`` m apart (2.0), with
    ``room`` m (1.2) of floor behind each before the outer wall; cells of ``resolution``
    m (0.1, the stochastic method's cell in thesis 000). The ``paper-synthetic`` robot
    drives up the middle at ``speed`` m/s (0.25), firing at ``rate`` Hz (10). The gaps
    between neighbouring boxes are annotated as passages; ``PAPER_NOISE["boxes"]`` is
    thesis 002's model (p_rand 0.001, p_hit 0.35) with 1 cm of range noise.
    """
    _check_positive(resolution=resolution, corridor=corridor, room=room, speed=speed, rate=rate)
    if layout not in BOX_LAYOUTS:
        raise ConfigError(
            f"scenario parameter 'layout' must be one of {', '.join(map(str, BOX_LAYOUTS))}, "
            f"got {layout!r}"
        )
    wall = 0.1
    rows = BOX_LAYOUTS[layout]
    deepest = max(d for sizes, _ in rows.values() for _, d in sizes)
    runs = [sum(a for a, _ in sizes) + sum(gaps) for sizes, gaps in rows.values()]
    length = max(runs) + 2.0
    width = 2 * (wall + room + deepest) + corridor
    cx = width / 2
    plan = FloorPlan((0.0, 0.0, width, length))
    plan.border(wall)
    found = []
    for side, (sizes, gaps) in rows.items():
        sign = -1.0 if side == "left" else 1.0
        face = cx + sign * corridor / 2
        # The right row starts half a gap later, so in layout 2 the rows are out of step.
        y = 1.0 if side == "left" else 1.0 + 0.5 * (gaps[0] if layout == 2 else 0.0)
        for k, (along, depth) in enumerate(sizes):
            plan.box(min(face, face + sign * depth), y, max(face, face + sign * depth), y + along)
            y += along
            if k < len(gaps):
                # The jambs on the mid-line of the shallower neighbour.
                d = min(depth, sizes[k + 1][1])
                xm = face + sign * d / 2
                found.append(Passage(f"{side}-gap{k + 1}", (xm, y), (xm, y + gaps[k]), d))
                y += gaps[k]
    truth = plan.render(plan.grid(resolution))
    rig = get_rig("paper-synthetic")
    traj = _straight(cx, 0.5, length - 0.5, speed, rate)
    readings, world, used = _readings(plan, truth, rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        layout=layout,
        resolution=resolution,
        corridor=corridor,
        room=room,
        speed=speed,
        rate=rate,
    )
    return Scenario("boxes", truth, rig, traj, readings, tuple(found), params, geometry=world)


def hall(
    *,
    rig: str = "ez1-six",
    resolution: float = 0.05,
    speed: float = 0.3,
    rate: float = 10.0,
    model: SonarModel | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """A training scene: an L-shaped hall with a pillar, walked by a preset rig.

    Drawn from the seed: a hall 6.5 to 7.5 m by 4.6 to 5.4 m whose far corner is solid
    (2.6 to 3.4 m by 2.0 to 2.6 m), which leaves an L; a square pillar of 0.25 to 0.4 m
    in its wide arm; and along its upper wall a side room 1.6 m deep behind a door of
    0.7 to 1.1 m (the scene's passage). The preset ``rig`` (``ez1-six``: six MaxSonar
    EZ1s, front, +-45 degrees, sides and back) walks once round the L, 1 m off the walls,
    at ``speed`` m/s (0.3), every sonar firing at ``rate`` Hz (10).
    """
    scene_rig = _preset_rig(rig)
    _check_positive(resolution=resolution, speed=speed, rate=rate)
    rng = np.random.default_rng([seed, 0x4A11])
    length = float(rng.uniform(6.5, 7.5))
    width = float(rng.uniform(4.6, 5.4))
    cut_x = float(rng.uniform(2.6, 3.4))
    cut_y = float(rng.uniform(2.0, 2.6))
    pillar = float(rng.uniform(0.25, 0.4))
    door = float(rng.uniform(0.7, 1.1))
    wall = 0.1
    side_room = 1.6
    top = wall + width  # the hall's upper wall starts here
    plan = FloorPlan((0.0, 0.0, length + 2 * wall, top + wall + side_room + wall))
    plan.border(wall)
    x_cut = wall + length - cut_x
    plan.box(x_cut, top - cut_y, wall + length, top)
    plan.box(0.0, top, wall + length + wall, top + wall)
    # The door opens from the wide arm into the side room, clear of the hall's corners.
    x_door = float(rng.uniform(wall + 0.6, x_cut - 0.6 - door))
    plan.clear(x_door, top, x_door + door, top + wall)
    passage = Passage("door", (x_door, top + wall / 2), (x_door + door, top + wall / 2), wall)
    inner_x0, inner_y0 = wall + 1.0, wall + 1.0
    inner_x1, inner_y1 = wall + length - 1.0, top - 1.0
    x_mid, y_mid = x_cut - 1.0, top - cut_y - 1.0
    # The pillar stands in the wide arm, halfway between the loop's legs.
    px = (inner_x0 + x_mid) / 2
    py = (y_mid + inner_y1) / 2
    small = (_post(plan, "pillar", px, py, round(pillar, 3)),)
    truth = plan.render(plan.grid(resolution))
    loop = [
        (inner_x0, inner_y0),
        (inner_x1, inner_y0),
        (inner_x1, y_mid),
        (x_mid, y_mid),
        (x_mid, inner_y1),
        (inner_x0, inner_y1),
    ]
    perimeter = sum(math.dist(a, b) for a, b in itertools.pairwise([*loop, loop[0]]))
    traj = _waypoint_path(loop, speed, rate, perimeter / speed)
    readings, world, used = _readings(plan, truth, scene_rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        rig=rig,
        resolution=resolution,
        length=round(length, 4),
        width=round(width, 4),
        cut=[round(cut_x, 4), round(cut_y, 4)],
        door_width=round(door, 4),
        speed=speed,
        rate=rate,
    )
    return Scenario(
        "hall", truth, scene_rig, traj, readings, (passage,), params, small, geometry=world
    )


def _room_visit(
    door_x: float, y_door: float, y_in: float, y_far: float, x0: float, x1: float
) -> list[tuple[float, float]]:
    """Waypoints from the corridor point before a door round a room and back: in to
    ``y_in``, along to the room's ``x0`` side, to ``y_far``, across to ``x1``, back."""
    return [
        (door_x, y_door),
        (door_x, y_in),
        (x0, y_in),
        (x0, y_far),
        (x1, y_far),
        (x1, y_in),
        (door_x, y_in),
        (door_x, y_door),
    ]


def suite(
    *,
    rig: str = "ez1-six",
    resolution: float = 0.05,
    speed: float = 0.5,
    rate: float = 5.0,
    model: SonarModel | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> Scenario:
    """A training scene: rooms off a corridor, drawn from the seed, toured by a preset rig.

    The shape users map (the held-out ``office`` is one), drawn by other rules: a floor
    7 to 9 m long; a corridor 1.5 to 2.2 m wide along it, off its centre by up to 0.4 m;
    two rooms on one side split at 40-60 % of the length and one or two on the other
    (rooms 2.6 to 3.4 m deep); each room with a door of 0.7 to 1.1 m at a random place
    in its corridor wall (the scene's passages), a cabinet against its back wall and a
    0.15 m post by its side wall. The preset ``rig`` (``ez1-six``) drives the corridor and
    a loop 1 m off the walls of every room at ``speed`` m/s (0.5), every sonar firing
    at ``rate`` Hz (5).
    """
    scene_rig = _preset_rig(rig)
    _check_positive(resolution=resolution, speed=speed, rate=rate)
    rng = np.random.default_rng([seed, 0x5017E])
    wall = 0.1
    length = float(rng.uniform(7.0, 9.0))
    corridor_w = float(rng.uniform(1.5, 2.2))
    depth_top = float(rng.uniform(2.6, 3.4))
    depth_bottom = float(rng.uniform(2.6, 3.4))
    y_lo = wall + depth_bottom + wall  # the corridor's lower face
    y_hi = y_lo + corridor_w
    x_end = wall + length
    height = y_hi + wall + depth_top + wall
    plan = FloorPlan((0.0, 0.0, x_end + wall, height))
    plan.border(wall)
    plan.box(0.0, y_lo - wall, x_end + wall, y_lo)
    plan.box(0.0, y_hi, x_end + wall, y_hi + wall)
    # The rooms' spans along x on each side; a side of one room spans the floor.
    split = wall + length * float(rng.uniform(0.4, 0.6))
    n_bottom = int(rng.integers(1, 3))
    spans = {
        "top": [(wall, split), (split, x_end)],
        "bottom": [(wall, x_end)]
        if n_bottom == 1
        else [(wall, wall + length - (split - wall)), (wall + length - (split - wall), x_end)],
    }
    found: list[Passage] = []
    small: list[SmallObstacle] = []
    visits: dict[str, list[list[tuple[float, float]]]] = {"top": [], "bottom": []}
    for side, rooms in spans.items():
        inward = 1.0 if side == "top" else -1.0
        y_wall = y_hi if side == "top" else y_lo - wall  # the corridor wall's lower edge
        face = y_hi + wall if side == "top" else y_lo - wall  # the room's side of it
        back = height - wall if side == "top" else wall
        for k, (a, b) in enumerate(rooms):
            if k > 0:
                plan.box(a - wall / 2, min(face, back), a + wall / 2, max(face, back))
            lo, hi = a + (wall / 2 if k > 0 else 0.0), b - (wall / 2 if k < len(rooms) - 1 else 0.0)
            door = float(rng.uniform(0.7, 1.1))
            dx = float(rng.uniform(lo + 0.4 + door / 2, hi - 0.4 - door / 2))
            plan.clear(dx - door / 2, y_wall, dx + door / 2, y_wall + wall)
            name = f"door{len(found) + 1}"
            found.append(
                Passage(
                    name,
                    (dx - door / 2, y_wall + wall / 2),
                    (dx + door / 2, y_wall + wall / 2),
                    wall,
                )
            )
            # A cabinet 0.4-0.5 m deep against the back wall, a post by the far side wall.
            c_len = float(rng.uniform(0.8, 1.4))
            c_dep = float(rng.uniform(0.4, 0.5))
            cx0 = float(rng.uniform(lo, hi - c_len))
            plan.box(
                cx0, min(back, back - inward * c_dep), cx0 + c_len, max(back, back - inward * c_dep)
            )
            mid_y = (face + back) / 2
            small.append(_post(plan, f"post{len(small) + 1}", hi - 0.5, mid_y, 0.15))
            y_mid = (y_lo + y_hi) / 2
            visits[side].append(
                _room_visit(dx, y_mid, face + inward * 1.0, back - inward * 1.0, lo + 1.0, hi - 1.0)
            )
    truth = plan.render(plan.grid(resolution))
    y_mid = (y_lo + y_hi) / 2
    points: list[tuple[float, float]] = [(wall + 0.8, y_mid)]
    for visit in visits["top"]:
        points += visit
    points.append((x_end - 0.8, y_mid))
    for visit in visits["bottom"][::-1]:
        points += visit
    perimeter = sum(math.dist(a, b) for a, b in itertools.pairwise([*points, points[0]]))
    traj = _waypoint_path(points, speed, rate, perimeter / speed)
    readings, world, used = _readings(plan, truth, scene_rig, traj, model, seed, progress)
    params = _record(
        used,
        seed,
        rig=rig,
        resolution=resolution,
        length=round(length, 4),
        corridor=round(corridor_w, 4),
        depths=[round(depth_bottom, 4), round(depth_top, 4)],
        door_widths=[round(p.width, 4) for p in found],
        speed=speed,
        rate=rate,
    )
    return Scenario(
        "suite",
        truth,
        scene_rig,
        traj,
        readings,
        tuple(found),
        params,
        tuple(small),
        geometry=world,
    )


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "doorways": doorways,
    "passages": passages,
    "room-turn": room_turn,
    "gaps": gaps,
    "corridor": corridor,
    "office": office,
    "boxes": boxes,
    "hall": hall,
    "suite": suite,
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
    return fn(**numbers_where_floats(params, fn))


def load_scene(
    folder: str | Path,
    *,
    seed: int = 0,
    model: SonarModel | None = None,
    resolution: float | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
) -> Scenario:
    """A scene from a folder like those :meth:`Scenario.write` makes, or made by hand.

    The folder holds ``truth.yaml`` (map_server) or a bare black-and-white image
    ``truth.png`` (or another image suffix) placed by ``resolution`` (metres per pixel)
    and ``origin`` (its lower-left corner, metres), ``rig.yaml``, and ``readings.csv``
    or ``trajectory.csv`` (or both), optionally ``geometry.yaml`` (a finer plan for the
    simulated sonar) and ``annotations.yaml``. With a trajectory and ``model`` given,
    readings are simulated from it with ``seed`` (through ``geometry.yaml`` when there
    is one, else the truth); otherwise the recorded ``readings.csv`` is used (simulated
    with the acoustic model when there is none).
    """
    from .errors import InputError
    from .io.rosmap import IMAGE_SUFFIXES, read_map
    from .readings import read_readings, read_trajectory
    from .rig import load_rig

    d = Path(folder)
    if not d.is_dir():
        raise InputError("scene folder not found", path=d)
    images = [d / f"truth{suffix}" for suffix in IMAGE_SUFFIXES if (d / f"truth{suffix}").is_file()]
    if not (d / "truth.yaml").is_file() and not images:
        raise InputError("scene folder lacks truth.yaml (or a bare image truth.png)", path=d)
    if not (d / "rig.yaml").is_file():
        raise InputError("scene folder lacks rig.yaml", path=d)
    if (d / "truth.yaml").is_file():
        truth = read_map(d / "truth.yaml")
    else:
        truth = read_map(images[0], resolution=resolution, origin=origin)
    rig = load_rig(d / "rig.yaml")
    has_traj = (d / "trajectory.csv").is_file()
    has_readings = (d / "readings.csv").is_file()
    if not (has_traj or has_readings):
        raise InputError("scene folder needs readings.csv or trajectory.csv", path=d)
    traj = read_trajectory(d / "trajectory.csv") if has_traj else None
    geometry = read_map(d / "geometry.yaml") if (d / "geometry.yaml").is_file() else None
    if traj is not None and (model is not None or not has_readings):
        used = AcousticModel() if model is None else model
        world = truth if isinstance(used, Noise) or geometry is None else geometry
        readings = simulate(world, rig, traj, model=used, seed=seed)
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
    return Scenario(
        d.name,
        truth,
        rig,
        traj,
        readings,
        passages,
        {"folder": str(d)},
        obstacles,
        geometry=geometry,
    )
