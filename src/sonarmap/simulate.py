"""Simulated sonar readings from a floor plan.

Two models of the sonar (``model=``):

- :class:`~sonarmap.acoustics.AcousticModel` (the default): rays through a geometry at
  least five times finer than the maps, a piston transducer's beam pattern, mirror-like
  walls, corners and edges, range noise and scale errors (see :mod:`sonarmap.acoustics`).
  None of it is a mapper's model, so maps judged on these readings are not judged on
  their own assumptions.
- :class:`~sonarmap.sensors.Noise`: Thrun's model as the research simulated it
  (methods.md section 3; thesis 000, 4.1), on the map's own cells, for reproducing the
  papers. The mappers' forward models are this model: maps judged on its readings
  are judged on the data they assume.

Thrun's model: for each pose and sonar, with probability ``p_rand`` the reading is uniform on
``[r_min, r_max]``; otherwise the occupied cells inside the beam are tried nearest
first, each reflecting with probability ``p_hit``, and the reading is the distance to
the first that reflects plus Gaussian noise; if none reflects the reading is ``r_max``
(no echo). Readings are clipped to ``[r_min, r_max]``.

Trying cells in turn until one reflects is the same as drawing the number of
misses ``k ~ Geometric(p_hit) - 1`` and taking the (k+1)-th nearest occupied cell,
which is how it is computed here: three vectorised draws per reading.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numba as nb
import numpy as np
import numpy.typing as npt

from .acoustics import AcousticModel, beam_pattern, first_echoes, surfaces
from .errors import ConfigError, InputError
from .io.rosmap import OccupancyMap
from .raster import beam_cells
from .readings import Readings, Trajectory
from .rig import Rig
from .sensors import Noise

__all__ = ["MODEL_KINDS", "AcousticModel", "PoseNoise", "SonarModel", "make_model", "simulate"]

#: A sonar model the simulator runs.
SonarModel = AcousticModel | Noise

Progress = Callable[[int, int], None]


#: The simulator's sonar models by name.
MODEL_KINDS = ("acoustic", "thrun")


def make_model(
    kind: str = "acoustic",
    *,
    p_rand: float | None = None,
    p_hit: float | None = None,
    sigma: float | None = None,
    base: Noise | None = None,
    params: Mapping[str, str | float] | None = None,
) -> SonarModel:
    """A sonar model by name, with the usual noise settings and the model's own.

    Parameters
    ----------
    kind : {"acoustic", "thrun"}
    p_rand, sigma : float, optional
        Spurious-reading probability and range noise (metres), for either model.
    p_hit : float, optional
        Thrun's reflection probability per occupied cell.
    base : Noise, optional
        Thrun's model's values for what is not given (default: no noise).
    params : mapping, optional
        Further :class:`~sonarmap.acoustics.AcousticModel` parameters, numbers or their
        text (``"none"`` for ``null_deg``).

    Examples
    --------
    >>> make_model("thrun", p_rand=0.05)
    Noise(p_rand=0.05, p_hit=1.0, sigma=0.0)
    >>> make_model("acoustic", sigma=0.02, params={"specular_deg": "12"}).specular_deg
    12.0
    """
    extra = dict(params or {})
    if kind == "thrun":
        if extra:
            raise ConfigError(
                f"parameter(s) {sorted(extra)} belong to the acoustic model, not 'thrun'"
            )
        b = base if base is not None else Noise()
        return Noise(
            b.p_rand if p_rand is None else p_rand,
            b.p_hit if p_hit is None else p_hit,
            b.sigma if sigma is None else sigma,
        )
    if kind != "acoustic":
        raise ConfigError(f"sonar model must be one of {', '.join(MODEL_KINDS)}, got {kind!r}")
    if p_hit is not None:
        raise ConfigError("p_hit belongs to Thrun's model ('thrun'), not 'acoustic'")
    values: dict[str, float | None] = {}
    for key, v in extra.items():
        if isinstance(v, str):
            if key == "null_deg" and v.strip().lower() in ("none", ""):
                values[key] = None
                continue
            try:
                values[key] = float(v)
            except ValueError:
                raise ConfigError(f"acoustic model: {key} expects a number, got {v!r}") from None
        else:
            values[key] = float(v)
    if p_rand is not None:
        values["p_rand"] = p_rand
    if sigma is not None:
        values["sigma"] = sigma
    return AcousticModel.from_dict(values)


@dataclass(frozen=True)
class PoseNoise:
    """Localisation error added to the *recorded* poses (readings use the true ones).

    Parameters
    ----------
    sigma_xy : float
        Standard deviation of x and y, metres.
    sigma_theta : float
        Standard deviation of the heading, radians.
    """

    sigma_xy: float = 0.0
    sigma_theta: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_xy) and self.sigma_xy >= 0):
            raise ConfigError(f"pose sigma_xy must be >= 0 metres, got {self.sigma_xy}")
        if not (np.isfinite(self.sigma_theta) and self.sigma_theta >= 0):
            raise ConfigError(f"pose sigma_theta must be >= 0 radians, got {self.sigma_theta}")


@nb.njit(cache=True)
def _kth_occupied(
    offsets: npt.NDArray[np.int64],
    cells: npt.NDArray[np.int32],
    distance: npt.NDArray[np.float32],
    occupied: npt.NDArray[np.bool_],
    k: npt.NDArray[np.int64],
) -> npt.NDArray[np.int64]:
    """Per reading, the cell of the (k+1)-th nearest occupied beam cell, or -1."""
    n = offsets.shape[0] - 1
    out = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        a = offsets[i]
        b = offsets[i + 1]
        m = 0
        for j in range(a, b):
            if occupied[cells[j]]:
                m += 1
        if k[i] >= m:
            continue
        idx = np.empty(m, dtype=np.int64)
        m = 0
        for j in range(a, b):
            if occupied[cells[j]]:
                idx[m] = j
                m += 1
        order = np.argsort(distance[idx], kind="mergesort")
        out[i] = cells[idx[order[k[i]]]]
    return out


_STAGES = (0.25, 0.5, 1.0)


def simulate(
    world: OccupancyMap,
    rig: Rig,
    trajectory: Trajectory,
    *,
    model: SonarModel | None = None,
    pose_noise: PoseNoise | None = None,
    seed: int = 0,
    chunk_size: int = 20_000,
    progress: Progress | None = None,
) -> Readings:
    """Simulate one reading per sonar of ``rig`` at each pose of ``trajectory``.

    Parameters
    ----------
    world : OccupancyMap
        Floor plan; cells classed occupied are obstacles (unknown cells are not). The
        acoustic model casts its rays through it, subdivided to ``model.max_cell``; give
        the finest plan there is (scenarios pass one at 1 cm).
    rig : Rig
        Sonars on the robot: their nominal beam, range limits and resolution.
    trajectory : Trajectory
        Robot poses; every sonar fires at every pose, in rig order.
    model : AcousticModel or Noise, optional
        The sonar's physics; default :class:`~sonarmap.acoustics.AcousticModel` ``()``.
        A :class:`~sonarmap.sensors.Noise` runs Thrun's model on the map's cells.
    pose_noise : PoseNoise, optional
        Error added to the recorded poses.
    seed : int
        Seed of the random generator; equal seeds give equal readings.
    chunk_size : int
        Poses simulated at once (bounds memory).
    progress : callable, optional
        Called as ``progress(done, total)`` with numbers of readings.

    Returns
    -------
    Readings
        Sensor world poses as recorded (with pose noise) and ranges.
    """
    if len(trajectory) == 0:
        raise InputError("trajectory is empty")
    if chunk_size < 1:
        raise ConfigError(f"chunk_size must be >= 1, got {chunk_size}")
    model = AcousticModel() if model is None else model
    pn = PoseNoise() if pose_noise is None else pose_noise
    rng = np.random.default_rng(seed)
    n_pose = len(trajectory)
    n_mount = len(rig.mounts)
    tx, ty, tt = (
        a.reshape(-1) for a in rig.sensor_poses(trajectory.x, trajectory.y, trajectory.theta)
    )
    if isinstance(model, Noise):
        ranges, rng = _thrun(world, rig, tx, ty, tt, model, rng, n_mount, chunk_size, progress)
    else:
        ranges = _acoustic(world, rig, tx, ty, tt, model, rng, n_mount, chunk_size, progress)
    rx = trajectory.x + pn.sigma_xy * rng.standard_normal(n_pose)
    ry = trajectory.y + pn.sigma_xy * rng.standard_normal(n_pose)
    rt = trajectory.theta + pn.sigma_theta * rng.standard_normal(n_pose)
    sx, sy, st = (v.reshape(-1) for v in rig.sensor_poses(rx, ry, rt))
    return Readings(
        t=np.repeat(trajectory.t, n_mount),
        sensor=np.tile(np.arange(n_mount, dtype=np.int32), n_pose),
        x=sx,
        y=sy,
        theta=st,
        range=ranges,
        names=rig.names,
    )


F64 = npt.NDArray[np.float64]


def _thrun(
    truth: OccupancyMap,
    rig: Rig,
    tx: F64,
    ty: F64,
    tt: F64,
    nz: Noise,
    rng: np.random.Generator,
    n_mount: int,
    chunk_size: int,
    progress: Progress | None,
) -> tuple[F64, np.random.Generator]:
    """Thrun's model on the map's cells; returns the ranges and the generator to draw
    the pose noise from (in the order the readings of earlier versions used)."""
    sensor = rig.sensor
    total = len(tx)
    # Every random number is drawn up front so results do not depend on chunking.
    u = rng.random(total)
    misses = rng.geometric(nz.p_hit, size=total).astype(np.int64) - 1
    gauss = rng.standard_normal(total)
    outlier = sensor.r_min + rng.random(total) * (sensor.r_max - sensor.r_min)
    occupied = np.ascontiguousarray((truth.classes() == 1).ravel())
    ranges = np.empty(total)
    step = max(1, chunk_size) * n_mount
    for a in range(0, total, step):
        b = min(a + step, total)
        hit = np.full(b - a, -1, dtype=np.int64)
        todo = np.arange(b - a)
        # A beam's cost grows with the square of its reach, and most echoes are short:
        # look for the hit within a quarter, then half, then all of r_max. Cells nearer
        # than a stage's reach are the same in every stage, so the k-th occupied one,
        # when found, is the full beam's.
        for frac in _STAGES:
            cs = beam_cells(
                truth.grid,
                sensor,
                tx[a:b][todo],
                ty[a:b][todo],
                tt[a:b][todo],
                max_range=sensor.r_max * frac,
            )
            found = _kth_occupied(cs.offsets, cs.cells, cs.distance, occupied, misses[a:b][todo])
            hit[todo] = found
            todo = todo[found < 0]
            if len(todo) == 0:
                break
        got = hit >= 0
        cx, cy = truth.grid.cell_centres(*truth.grid.unravel(hit[got]))
        dist = np.full(b - a, sensor.r_max)
        # Recomputed in float64: the rasteriser stores distances as float32.
        dist[got] = np.hypot(cx - tx[a:b][got], cy - ty[a:b][got]) + nz.sigma * gauss[a:b][got]
        dist = np.where(u[a:b] < nz.p_rand, outlier[a:b], dist)
        ranges[a:b] = np.clip(dist, sensor.r_min, sensor.r_max)
        if progress is not None:
            progress(b, total)
    return ranges, rng


def _acoustic(
    world: OccupancyMap,
    rig: Rig,
    tx: F64,
    ty: F64,
    tt: F64,
    model: AcousticModel,
    rng: np.random.Generator,
    n_mount: int,
    chunk_size: int,
    progress: Progress | None,
) -> F64:
    """The acoustic model (:mod:`sonarmap.acoustics`)."""
    sensor = rig.sensor
    total = len(tx)
    # Every random number is drawn up front so results do not depend on chunking.
    scale = 1.0 + model.scale_sigma * rng.standard_normal(n_mount)
    gauss = rng.standard_normal(total)
    u = rng.random(total)
    outlier = sensor.r_min + rng.random(total) * (sensor.r_max - sensor.r_min)
    geo = surfaces(world, model.max_cell)
    phi, amp = beam_pattern(model, sensor)
    alpha = np.linspace(0.0, np.pi / 2, 1025)
    spec = np.exp(-((alpha / np.radians(model.specular_deg)) ** 2))
    ox, oy = geo.grid.origin
    ranges = np.empty(total)
    step = max(1, chunk_size) * n_mount
    per_reading = np.tile(scale, total // n_mount)
    for a in range(0, total, step):
        b = min(a + step, total)
        d = first_echoes(
            geo.occupied,
            geo.kind,
            geo.nx,
            geo.ny,
            ox,
            oy,
            geo.grid.resolution,
            tx[a:b],
            ty[a:b],
            tt[a:b],
            phi,
            amp,
            model.reach * sensor.r_max,
            sensor.r_max,
            spec,
            model.roughness,
            model.edge_gain,
            model.corner_gain,
        )
        echo = d < sensor.r_max
        noisy = d * per_reading[a:b] + (model.sigma + model.sigma_rel * d) * gauss[a:b]
        q = sensor.range_resolution
        noisy = np.round(noisy / q) * q
        r = np.where(echo, np.clip(noisy, sensor.r_min, np.nextafter(sensor.r_max, 0)), d)
        r = np.where(u[a:b] < model.p_rand, outlier[a:b], r)
        ranges[a:b] = np.clip(r, sensor.r_min, sensor.r_max)
        if progress is not None:
            progress(b, total)
    return ranges
