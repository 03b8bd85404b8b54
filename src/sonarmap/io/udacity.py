"""The two-file text log of a small 8-sonar robot (``measurement.txt`` + ``poses.txt``).

``measurement.txt``: ``timestamp r_1 .. r_8`` per row, ranges in millimetres, 5110 = no
echo. ``poses.txt``: ``timestamp x y theta`` per row, x and y in millimetres, theta in
tenths of a degree; rows match by timestamp. The sonar headings are not recorded: the
``udacity-8`` rig (headings -90, -37.5, -22.5, -7.5, 7.5, 22.5, 37.5, 90 degrees, a
20-degree beam) is the mounting assumed by the teaching material that uses the log.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..files import need_file
from ..readings import Readings
from ..rig import Mount, Rig
from ..sensors import Region, SensorModel

__all__ = ["UNITS", "read_udacity", "udacity_rig"]

#: Length units the files may be in, as metres per unit.
UNITS = {"mm": 0.001, "cm": 0.01, "m": 1.0}
NO_ECHO_MM = 5110.0


def udacity_rig() -> Rig:
    """Eight sonars at the assumed headings, a 20-degree cone up to 5.11 m."""
    sensor = SensorModel("udacity-sonar", Region.cone(20.0, 5.11), 0.0, 5.11, 0.01)
    yaws = (-90.0, -37.5, -22.5, -7.5, 7.5, 22.5, 37.5, 90.0)
    return Rig(sensor, tuple(Mount(f"s{i}", 0.0, 0.0, y) for i, y in enumerate(yaws)))


def _table(path: Path, columns: int, what: str) -> npt.NDArray[np.float64]:
    need_file(path, "udacity log file")
    rows = []
    with path.open(encoding="utf-8", errors="strict") as f:
        for line, text in enumerate(f, start=1):
            tokens = text.split()
            if not tokens:
                continue
            if len(tokens) != columns:
                raise InputError(
                    f"expected {columns} fields ({what}), got {len(tokens)}", path=path, line=line
                )
            try:
                vals = [float(t) for t in tokens]
            except ValueError:
                bad = next(t for t in tokens if not _num(t))
                raise InputError(f"not a number ({bad!r})", path=path, line=line) from None
            if not all(math.isfinite(v) for v in vals):
                raise InputError("non-finite value", path=path, line=line)
            rows.append(vals)
    if not rows:
        raise InputError("file holds no rows", path=path)
    return np.asarray(rows)


def _num(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def read_udacity(
    measurements: str | Path,
    poses: str | Path,
    *,
    rig: Rig | None = None,
    units: str = "mm",
) -> tuple[Readings, Rig]:
    """Readings of the log; ``units`` is the length unit of ranges and positions."""
    if units not in UNITS:
        raise InputError(f"unknown units '{units}'; valid: {', '.join(UNITS)}")
    scale = UNITS[units]
    r = rig if rig is not None else udacity_rig()
    n = len(r.mounts)
    mp, pp = Path(measurements), Path(poses)
    meas = _table(mp, 1 + n, f"timestamp and {n} ranges")
    pose = _table(pp, 4, "timestamp x y theta")
    if len(meas) != len(pose):
        raise InputError(f"{len(meas)} measurement rows but {len(pose)} pose rows", path=pp)
    off = np.flatnonzero(meas[:, 0] != pose[:, 0])
    if len(off):
        raise InputError(
            f"timestamp {pose[off[0], 0]:.0f} does not match the measurement's "
            f"{meas[off[0], 0]:.0f}",
            path=pp,
            line=int(off[0]) + 1,
        )
    ranges_raw = meas[:, 1:]
    neg = np.argwhere(ranges_raw < 0)
    if len(neg):
        raise InputError(
            f"negative range ({ranges_raw[tuple(neg[0])]})", path=mp, line=int(neg[0][0]) + 1
        )
    no_echo = ranges_raw >= NO_ECHO_MM * 0.001 / scale
    ranges = np.where(no_echo, r.sensor.r_max, ranges_raw * scale)
    t = (meas[:, 0] - meas[0, 0]) * 0.001  # the timestamps count milliseconds
    x, y = pose[:, 1] * scale, pose[:, 2] * scale
    theta = np.radians(pose[:, 3] / 10.0)
    sx, sy, st = r.sensor_poses(x, y, theta)
    readings = Readings(
        np.repeat(t, n),
        np.tile(np.arange(n, dtype=np.int32), len(t)),
        sx.ravel(),
        sy.ravel(),
        st.ravel(),
        ranges.ravel(),
        r.names,
    )
    return readings, r
