"""Virtual sonars from laser scans: real building geometry as a sonar benchmark.

A laser scan with a corrected pose holds the geometry around the robot. A virtual sonar
on the robot reads, to first order, the nearest laser return inside its beam:

- the sonar's world pose follows from the robot pose (recovered from the laser beams'
  poses and the laser rig) and the sonar's mounting;
- every laser return (range below the laser's r_max) whose end point lies inside the
  sonar's beam region (sensor frame, as the rasteriser's membership test) is a
  candidate; the reading is the distance from the sonar to the nearest one, clipped to
  [r_min, r_max]; with none the reading is r_max (no echo);
- a sonar whose beam is not inside the laser's field of view is dropped (its reading
  would claim free space the laser never saw);
- ``p_drop`` optionally turns a reading into no echo, as real sonars miss specular
  surfaces; ``sigma`` adds Gaussian range noise. Both default to 0.

The model ignores the sensitivity diagram (a laser return is a point; its size is not
known), multiple reflections, and the laser's own range noise.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from .errors import InputError
from .readings import Readings
from .rig import Mount, Rig

__all__ = ["laser_fov", "robot_poses", "virtual_sonar"]

F64 = npt.NDArray[np.float64]


def _scans(laser: Readings, rig: Rig) -> int:
    n = len(rig.mounts)
    if n == 0 or len(laser) % n:
        raise InputError(f"{len(laser)} laser readings do not make whole scans of {n} beams")
    expected = np.tile(np.arange(n), len(laser) // n)
    if not np.array_equal(laser.sensor, expected):
        raise InputError("laser readings are not in scan order (beam 0..n-1, scan by scan)")
    return len(laser) // n


def robot_poses(laser: Readings, rig: Rig) -> tuple[F64, F64, F64, F64]:
    """Per scan: time, robot x, y, heading (from the first beam's pose and its mounting)."""
    m = _scans(laser, rig)
    n = len(rig.mounts)
    first = np.arange(m) * n
    mount = rig.mounts[0]
    heading = laser.theta[first] - math.radians(mount.yaw_deg)
    c, s = np.cos(heading), np.sin(heading)
    x = laser.x[first] - (c * mount.x - s * mount.y)
    y = laser.y[first] - (s * mount.x + c * mount.y)
    return laser.t[first], x, y, np.angle(np.exp(1j * heading))


def laser_fov(rig: Rig) -> tuple[float, float]:
    """Smallest and largest beam direction of a laser rig, radians in the robot frame."""
    yaws = np.radians([m.yaw_deg for m in rig.mounts])
    return float(yaws.min()), float(yaws.max())


def virtual_sonar(
    laser: Readings,
    laser_rig: Rig,
    sonar_rig: Rig,
    *,
    p_drop: float = 0.0,
    sigma: float = 0.0,
    seed: int = 0,
) -> tuple[Readings, Rig]:
    """Readings of ``sonar_rig`` derived from laser scans (see the module notes).

    Returns the readings and the rig of the sonars kept (those the laser covers).
    """
    if not (0.0 <= p_drop < 1.0):
        raise InputError(f"p_drop must be in [0, 1), got {p_drop}")
    if not (math.isfinite(sigma) and sigma >= 0):
        raise InputError(f"sigma must be >= 0 metres, got {sigma}")
    lo, hi = laser_fov(laser_rig)
    beam = sonar_rig.sensor.beam
    # The beam's angular extent from its outline (cone or polygon), about the sonar axis.
    ang = np.arctan2(beam.outline[1:, 1], beam.outline[1:, 0])
    half = float(np.max(np.abs(ang)))

    def axis(mt: Mount) -> float:
        return math.radians((mt.yaw_deg + 180.0) % 360.0 - 180.0)

    kept = tuple(
        mt
        for mt in sonar_rig.mounts
        if lo - 1e-9 <= axis(mt) - half and axis(mt) + half <= hi + 1e-9
    )
    if not kept:
        raise InputError(
            "no sonar of the rig has its beam inside the laser's field of view "
            f"({math.degrees(lo):.0f} to {math.degrees(hi):.0f} degrees)"
        )
    rig = Rig(sonar_rig.sensor, kept)
    t, rx, ry, rth = robot_poses(laser, laser_rig)
    n_beams = len(laser_rig.mounts)
    ends_ok = (laser.range < laser_rig.sensor.r_max).reshape(-1, n_beams)
    ex = (laser.x + laser.range * np.cos(laser.theta)).reshape(-1, n_beams)
    ey = (laser.y + laser.range * np.sin(laser.theta)).reshape(-1, n_beams)
    sx, sy, sth = rig.sensor_poses(rx, ry, rth)  # (scans, sonars)
    planes = beam.halfplanes
    sensor = rig.sensor
    out = np.full(sx.shape, sensor.r_max)
    for j in range(len(kept)):
        dx = ex - sx[:, j : j + 1]
        dy = ey - sy[:, j : j + 1]
        c, s = np.cos(sth[:, j : j + 1]), np.sin(sth[:, j : j + 1])
        u, v = c * dx + s * dy, -s * dx + c * dy
        inside = ends_ok.copy()
        for a, b, off in planes:
            inside &= a * u + b * v <= off + 1e-9
        d = np.hypot(u, v)
        inside &= d <= min(beam.radius, sensor.r_max)
        best = np.where(inside, d, np.inf).min(axis=1)
        out[:, j] = np.where(
            np.isfinite(best), np.clip(best, sensor.r_min, sensor.r_max), sensor.r_max
        )
    rng = np.random.default_rng(seed)
    echo = out < sensor.r_max
    if sigma > 0:
        out = np.where(
            echo,
            np.clip(out + sigma * rng.standard_normal(out.shape), sensor.r_min, sensor.r_max),
            out,
        )
    if p_drop > 0:
        out = np.where(rng.random(out.shape) < p_drop, sensor.r_max, out)
    k = len(kept)
    readings = Readings(
        np.repeat(t, k),
        np.tile(np.arange(k, dtype=np.int32), len(t)),
        sx.ravel(),
        sy.ravel(),
        sth.ravel(),
        out.ravel(),
        rig.names,
    )
    return readings, rig


def default_ring() -> Rig:
    """16 Polaroid-type sonars, 22.5 degrees apart, 0.2 m from the robot centre, 5 m range.

    The documented default of ``sonarmap experiment real`` (a Pioneer-like ring limited to
    the range indoor sonars are used at).
    """
    from dataclasses import replace

    from .rig import get_rig
    from .sensors import Region

    ring = get_rig("ring16")
    sensor = replace(ring.sensor, beam=Region.cone(30.0, 5.0), r_max=5.0)
    return Rig(sensor, tuple(Mount(m.name, m.x, m.y, m.yaw_deg) for m in ring.mounts))
