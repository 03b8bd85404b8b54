"""CARMEN log files (plain or gzip), streamed line by line into sonarmap readings.

Messages read (one a line, whitespace separated, ending ``timestamp host
logger_timestamp``):

- ``FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ...``: front laser, n beams
  evenly from -90 to +90 degrees about the robot heading, pose of the robot (the laser
  at its origin).
- ``RLASER``: the same for a rear laser (beams from +90 to +270 degrees).
- ``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n
  r_1..r_n [n_rem rem_1..] laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
  forward_safety side_safety [turn_axis] ...``: beams from ``start_angle`` at
  ``resolution`` about the laser's own pose.
- ``SONAR cone_angle n r_1..r_n x_1 y_1 theta_1 .. x_n y_n theta_n robot_x robot_y
  robot_theta tv rv ...`` (carmen_robot_sonar_message): sonar offsets in the robot frame,
  angles in radians.
- ``ODOM x y theta tv rv accel ...``: checked and counted (the messages above carry
  their own poses).

Other messages (``PARAM``, ``NEFF``, ``SYNC``, ``RAWLASER*``, ...) and ``#`` comments are
skipped and counted. A laser range at or above ``max_range`` means no return and
becomes a no-echo reading.
"""

from __future__ import annotations

import gzip
import math
import zlib
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..files import need_file
from ..readings import Readings
from ..rig import Mount, Rig
from ..sensors import Region, SensorModel

__all__ = ["CarmenScan", "ConvertSummary", "iter_carmen", "iter_carmen_readings", "read_carmen"]

SOURCES = ("FLASER", "RLASER", "ROBOTLASER1", "SONAR")
F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class CarmenScan:
    """One range message: beam angles in the sensor frame, sensor pose, ranges."""

    kind: str
    t: float
    x: F64  # world pose of each beam's sensor, metres / radians
    y: F64
    theta: F64
    ranges: F64
    cone: float  # full opening of each beam, radians (0 for a laser: one resolution step)
    mount_angles: F64  # beam directions in the robot frame (for the rig)
    mount_x: F64
    mount_y: F64
    line: int


@dataclass
class ConvertSummary:
    """What a conversion read, for the user's report."""

    lines: int = 0
    counts: Counter[str] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)
    readings: int = 0


def _open(path: Path) -> Iterator[str]:
    """The log's lines; a corrupt or binary file is an InputError naming the last good line."""
    opener = gzip.open if path.suffix == ".gz" else open
    line = 0
    try:
        with opener(path, "rt", encoding="utf-8", errors="strict") as f:
            for line, text in enumerate(f, start=1):  # noqa: B007 - line is read after the loop
                yield text
    except (EOFError, gzip.BadGzipFile, zlib.error) as err:
        raise InputError(
            f"compressed file is truncated or corrupt after line {line} ({type(err).__name__})",
            path=path,
        ) from err
    except UnicodeDecodeError as err:
        # Text is decoded a block at a time, so the bad byte is after the last whole line.
        where = f"after line {line}" if line else "in its first lines"
        raise InputError(f"not a text log (bytes that are not UTF-8 {where})", path=path) from err
    except OSError as err:
        raise InputError(f"cannot read file ({err.strerror or err})", path=path) from err


def _floats(tokens: list[str], path: Path, line: int, what: str) -> F64:
    try:
        out = np.array(tokens, dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise InputError(f"{what}: not a number ({bad!r})", path=path, line=line) from None
    if not np.all(np.isfinite(out)):
        raise InputError(f"{what}: non-finite value", path=path, line=line)
    return out


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def _count(tokens: list[str], i: int, path: Path, line: int, what: str) -> int:
    if i >= len(tokens):
        raise InputError(f"{tokens[0]} message ends before its {what}", path=path, line=line)
    try:
        n = int(tokens[i])
    except ValueError:
        raise InputError(
            f"{what} is not an integer ({tokens[i]!r})", path=path, line=line
        ) from None
    if n < 0:
        raise InputError(f"{what} is negative ({n})", path=path, line=line)
    return n


def _need(tokens: list[str], n: int, path: Path, line: int) -> None:
    if len(tokens) < n:
        raise InputError(
            f"{tokens[0]} message is truncated: {len(tokens)} fields, expected at least {n}",
            path=path,
            line=line,
        )


def _laser(tokens: list[str], path: Path, line: int, rear: bool) -> CarmenScan:
    n = _count(tokens, 1, path, line, "number of readings")
    _need(tokens, 2 + n + 6 + 1, path, line)
    ranges = _floats(tokens[2 : 2 + n], path, line, "range")
    pose = _floats(tokens[2 + n : 2 + n + 3], path, line, "pose")
    t = _floats(tokens[2 + n + 6 : 2 + n + 7], path, line, "timestamp")[0]
    start = math.pi / 2 if rear else -math.pi / 2
    angles = start + np.arange(n, dtype=np.float64) * (math.pi / max(n - 1, 1))
    step = math.pi / max(n - 1, 1)
    return CarmenScan(
        "RLASER" if rear else "FLASER",
        float(t),
        np.full(n, pose[0]),
        np.full(n, pose[1]),
        pose[2] + angles,
        ranges,
        step,
        angles,
        np.zeros(n),
        np.zeros(n),
        line,
    )


def _robotlaser(tokens: list[str], path: Path, line: int) -> CarmenScan:
    _need(tokens, 10, path, line)
    cfg = _floats(tokens[2:7], path, line, "laser configuration")
    start, _fov, res = cfg[0], cfg[1], cfg[2]
    n = _count(tokens, 8, path, line, "number of readings")
    _need(tokens, 9 + n, path, line)
    ranges = _floats(tokens[9 : 9 + n], path, line, "range")
    rest = tokens[9 + n :]
    # Newer logs add "num_remissions rem_1 .." here; tell by what remains: poses (6),
    # tv rv and two safety distances (4), an optional turn axis, and the 3-field trailer.
    if len(rest) not in (13, 14):
        k = _count(rest, 0, path, line, "number of remissions") if rest else 0
        rest = rest[1 + k :]
    if len(rest) not in (13, 14):
        raise InputError(
            f"ROBOTLASER1 message has {len(tokens)} fields, which does not fit {n} readings",
            path=path,
            line=line,
        )
    poses = _floats(rest[:6], path, line, "pose")
    t = _floats(rest[-3:-2], path, line, "timestamp")[0]
    lx, ly, lth, rx, ry, rth = poses
    angles = np.asarray(start + np.arange(n) * res, dtype=np.float64)
    # Beam directions about the robot, for the rig; the world poses use the laser pose.
    c, s = math.cos(-rth), math.sin(-rth)
    mx, my = c * (lx - rx) - s * (ly - ry), s * (lx - rx) + c * (ly - ry)
    return CarmenScan(
        "ROBOTLASER1",
        float(t),
        np.full(n, lx),
        np.full(n, ly),
        lth + angles,
        ranges,
        float(res),
        angles + (lth - rth),
        np.full(n, mx),
        np.full(n, my),
        line,
    )


def _sonar(tokens: list[str], path: Path, line: int) -> CarmenScan:
    _need(tokens, 3, path, line)
    cone = _floats(tokens[1:2], path, line, "cone angle")[0]
    if not 0.0 < cone < math.pi:
        # A sonar's opening is its beam: none, or a half plane or more, is no sonar.
        raise InputError(
            f"SONAR cone angle must be in (0, pi) radians, got {cone:g}", path=path, line=line
        )
    n = _count(tokens, 2, path, line, "number of sonars")
    expected = 3 + n + 3 * n + 3 + 2 + 3
    if len(tokens) != expected:
        raise InputError(
            f"SONAR message has {len(tokens)} fields, expected {expected} for {n} sonars",
            path=path,
            line=line,
        )
    ranges = _floats(tokens[3 : 3 + n], path, line, "range")
    offs = _floats(tokens[3 + n : 3 + 4 * n], path, line, "sonar offset").reshape(n, 3)
    robot = _floats(tokens[3 + 4 * n : 6 + 4 * n], path, line, "robot pose")
    t = _floats(tokens[-3:-2], path, line, "timestamp")[0]
    c, s = math.cos(robot[2]), math.sin(robot[2])
    x = robot[0] + c * offs[:, 0] - s * offs[:, 1]
    y = robot[1] + s * offs[:, 0] + c * offs[:, 1]
    return CarmenScan(
        "SONAR",
        float(t),
        x,
        y,
        robot[2] + offs[:, 2],
        ranges,
        float(cone),
        offs[:, 2].copy(),
        offs[:, 0].copy(),
        offs[:, 1].copy(),
        line,
    )


def iter_carmen(
    path: str | Path,
    summary: ConvertSummary | None = None,
    progress: Callable[[int], None] | None = None,
) -> Iterator[CarmenScan]:
    """Range messages of a CARMEN log, in file order; ``summary`` collects the counts."""
    p = need_file(path, "CARMEN log")
    s = summary if summary is not None else ConvertSummary()
    for line, text in enumerate(_open(p), start=1):
        s.lines = line
        if progress is not None and line % 2000 == 0:
            progress(line)
        tokens = text.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        kind = tokens[0]
        if kind in ("FLASER", "RLASER"):
            s.counts[kind] += 1
            yield _laser(tokens, p, line, rear=kind == "RLASER")
        elif kind == "ROBOTLASER1":
            s.counts[kind] += 1
            yield _robotlaser(tokens, p, line)
        elif kind == "SONAR":
            s.counts[kind] += 1
            yield _sonar(tokens, p, line)
        elif kind == "ODOM":
            _need(tokens, 10, p, line)
            _floats(tokens[1:7], p, line, "odometry")
            s.counts[kind] += 1
        else:
            s.skipped[kind] += 1


def _sensor(kind: str, cone: float, max_range: float) -> SensorModel:
    # A laser beam is a cone one angular step wide; a sonar's is its cone angle.
    aperture = min(max(math.degrees(cone), 0.05), 179.0)
    return SensorModel(
        f"carmen-{kind.lower()}", Region.cone(aperture, max_range), 0.0, max_range, 0.01
    )


def _choose(path: Path, source: str) -> str:
    """The source to convert; ``auto`` looks through the log first (a cheap pass)."""
    if source != "auto":
        if source not in SOURCES:
            raise InputError(f"unknown source '{source}'; valid: auto, {', '.join(SOURCES)}")
        return source
    seen: set[str] = set()
    for text in _open(path):
        head = text[:12].split(maxsplit=1)
        if head and head[0] in SOURCES:
            seen.add(head[0])
            if head[0] == "SONAR":
                break
    for kind in ("SONAR", "FLASER", "ROBOTLASER1", "RLASER"):
        if kind in seen:
            return kind
    raise InputError(f"no range messages ({', '.join(SOURCES)}) in the log", path=path)


def _rig(kind: str, first: CarmenScan, max_range: float) -> Rig:
    n = len(first.ranges)
    prefix = kind.lower()
    mounts = tuple(
        Mount(
            f"{prefix}_{i:03d}",
            float(first.mount_x[i]),
            float(first.mount_y[i]),
            math.degrees(float(first.mount_angles[i])),
        )
        for i in range(n)
    )
    return Rig(_sensor(kind, first.cone, max_range), mounts)


def _scan_readings(sc: CarmenScan, rig: Rig, max_range: float, path: Path) -> Readings:
    n = len(rig.mounts)
    if len(sc.ranges) != n:
        raise InputError(
            f"{sc.kind} message has {len(sc.ranges)} beams, the first had {n}",
            path=path,
            line=sc.line,
        )
    if np.any(sc.ranges < 0):
        raise InputError(f"negative range ({sc.ranges.min()})", path=path, line=sc.line)
    return Readings(
        np.full(n, sc.t),
        np.arange(n, dtype=np.int32),
        sc.x,
        sc.y,
        np.angle(np.exp(1j * sc.theta)),
        np.minimum(sc.ranges, max_range),
        rig.names,
    )


def iter_carmen_readings(
    path: str | Path,
    *,
    source: str = "auto",
    max_range: float = 80.0,
    summary: ConvertSummary | None = None,
    progress: Callable[[int], None] | None = None,
) -> Iterator[tuple[Readings, Rig]]:
    """Readings of one range source of a CARMEN log, one message at a time, with the rig
    that describes the source (the same object every time)."""
    p = Path(path)
    if not (math.isfinite(max_range) and max_range > 0):
        raise InputError(f"max_range must be > 0 metres, got {max_range}")
    need_file(p, "CARMEN log")
    kind = _choose(p, source)
    rig: Rig | None = None
    s = summary if summary is not None else ConvertSummary()
    for sc in iter_carmen(p, s, progress):
        if sc.kind != kind:
            continue
        if rig is None:
            rig, cone = _rig(kind, sc, max_range), sc.cone
        r = _scan_readings(sc, rig, max_range, p)
        if kind == "SONAR" and sc.cone != cone:
            # The rig has one beam: a log whose sonars change theirs has no single rig.
            # A laser's "cone" is its angular step, which a log may round differently
            # from message to message; its beams are thin either way.
            raise InputError(
                f"{kind} cone angle {sc.cone:g} rad, the first message's was {cone:g}",
                path=p,
                line=sc.line,
            )
        s.readings += len(r)
        yield r, rig
    if rig is None:
        raise InputError(f"no {kind} messages in the log", path=p)


def read_carmen(
    path: str | Path,
    *,
    source: str = "auto",
    max_range: float = 80.0,
    summary: ConvertSummary | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[Readings, Rig]:
    """All readings of one range source of a CARMEN log, and a rig describing it.

    Parameters
    ----------
    source : {"auto", "FLASER", "RLASER", "ROBOTLASER1", "SONAR"}
        Which messages to convert; ``auto`` takes SONAR if the log has any, else the
        first laser kind in the order FLASER, ROBOTLASER1, RLASER.
    max_range : float
        Ranges at or above this (metres) are no-return values: no-echo readings.
    """
    parts = list(
        iter_carmen_readings(
            path, source=source, max_range=max_range, summary=summary, progress=progress
        )
    )
    readings = Readings.concat([r for r, _ in parts])
    if np.any(np.diff(readings.t) < 0):
        readings = readings.take(np.argsort(readings.t, kind="stable"))
    return readings, parts[0][1]
