"""Simulated sonar readings from a floor plan (methods.md section 3; thesis 000, 4.1).

For each pose and sonar: with probability ``p_rand`` the reading is uniform on
``[r_min, r_max]``; otherwise the occupied cells inside the beam are tried nearest
first, each reflecting with probability ``p_hit``, and the reading is the distance to
the first that reflects plus Gaussian noise; if none reflects the reading is ``r_max``
(no echo). Readings are clipped to ``[r_min, r_max]``.

Trying cells in turn until one reflects is the same as drawing the number of
misses ``k ~ Geometric(p_hit) - 1`` and taking the (k+1)-th nearest occupied cell,
which is how it is computed here: three vectorised draws per reading.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba as nb
import numpy as np
import numpy.typing as npt

from .errors import ConfigError, InputError
from .io.rosmap import OccupancyMap
from .raster import beam_cells
from .readings import Readings, Trajectory
from .rig import Rig
from .sensors import Noise

__all__ = ["PoseNoise", "simulate"]

Progress = Callable[[int, int], None]


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
    truth: OccupancyMap,
    rig: Rig,
    trajectory: Trajectory,
    *,
    noise: Noise | None = None,
    pose_noise: PoseNoise | None = None,
    seed: int = 0,
    chunk_size: int = 20_000,
    progress: Progress | None = None,
) -> Readings:
    """Simulate one reading per sonar of ``rig`` at each pose of ``trajectory``.

    Parameters
    ----------
    truth : OccupancyMap
        Floor plan; cells with occupancy >= 0.5 are obstacles (unknown cells are not).
    rig : Rig
        Sonars on the robot.
    trajectory : Trajectory
        Robot poses; every sonar fires at every pose, in rig order.
    noise : Noise, optional
        Sonar noise; default the rig sensor's.
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
    sensor = rig.sensor
    nz = sensor.noise if noise is None else noise
    pn = PoseNoise() if pose_noise is None else pose_noise
    rng = np.random.default_rng(seed)
    n_pose = len(trajectory)
    n_mount = len(rig.mounts)
    total = n_pose * n_mount

    # Every random number is drawn up front so results do not depend on chunking.
    u = rng.random(total)
    misses = rng.geometric(nz.p_hit, size=total).astype(np.int64) - 1
    gauss = rng.standard_normal(total)
    outlier = sensor.r_min + rng.random(total) * (sensor.r_max - sensor.r_min)
    rx = trajectory.x + pn.sigma_xy * rng.standard_normal(n_pose)
    ry = trajectory.y + pn.sigma_xy * rng.standard_normal(n_pose)
    rt = trajectory.theta + pn.sigma_theta * rng.standard_normal(n_pose)

    tx, ty, tt = (
        a.reshape(-1) for a in rig.sensor_poses(trajectory.x, trajectory.y, trajectory.theta)
    )
    occupied = np.ascontiguousarray((np.nan_to_num(truth.occupancy, nan=0.0) >= 0.5).ravel())
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
