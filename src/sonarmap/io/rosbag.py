"""ROS 1 and ROS 2 bags with ``sensor_msgs/Range`` readings, through ``rosbags``.

- Readings: every ``sensor_msgs/Range`` (ultrasound or infrared) message, or those of the
  topics given; its ``header.frame_id`` names the sensor, ``field_of_view``,
  ``min_range`` and ``max_range`` give the beam. Following REP 117, ``+inf`` or a range
  at or above ``max_range`` is no echo, ``-inf`` an object closer than ``min_range``
  (read as ``min_range``); NaN readings are skipped and counted. A reading whose stamp
  is unset takes the time the bag recorded it.
- Robot poses: a ``nav_msgs/Odometry`` topic (the first one, or the one given), or else
  the ``/tf`` transforms from any parent to the base frame (default ``base_link``); the
  pose is interpolated to each reading's stamp (linearly, heading along the shortest
  arc). Readings outside the span of poses are skipped and counted.
- Sensor frames: ``/tf_static`` transforms, composed from the sensor's frame up to the
  base frame; a sensor frame that tf_static does not reach must be a sonar of the rig
  given, by name.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..readings import Readings
from ..rig import Mount, Rig
from ..sensors import Region, SensorModel

__all__ = ["BagSummary", "read_bag"]

RANGE = "sensor_msgs/msg/Range"
ODOM = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"
F64 = npt.NDArray[np.float64]


@dataclass
class BagSummary:
    """Counts of what a conversion read and skipped."""

    topics: Counter[str] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)
    pose_source: str = ""


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _compose(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> tuple[float, float, float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def _mount(
    frame: str, static: dict[str, tuple[str, tuple[float, float, float]]], base: str
) -> tuple[float, float, float] | None:
    """Pose of ``frame`` in ``base`` through tf_static, or None if it does not reach."""
    pose = (0.0, 0.0, 0.0)
    seen = set()
    f = frame
    while f != base:
        if f not in static or f in seen:
            return None
        seen.add(f)
        parent, tr = static[f]
        pose = _compose(tr, pose)
        f = parent
    return pose


def read_bag(
    path: str | Path,
    *,
    topics: Sequence[str] | None = None,
    odom_topic: str | None = None,
    base_frame: str = "base_link",
    rig: Rig | None = None,
    summary: BagSummary | None = None,
) -> tuple[Readings, Rig]:
    """Readings and their rig from a ROS 1 bag (``.bag``) or ROS 2 bag (folder)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    p = Path(path)
    if not p.exists():
        raise InputError("no such bag", path=p)
    s = summary if summary is not None else BagSummary()
    ranges: list[tuple[float, str, float, float, float, float, str]] = []
    poses: list[tuple[float, float, float, float]] = []
    tf_poses: list[tuple[float, float, float, float]] = []
    static: dict[str, tuple[str, tuple[float, float, float]]] = {}
    tf_children: set[str] = set()
    try:
        with AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            conns = reader.connections
            range_conns = [
                c for c in conns if c.msgtype == RANGE and (topics is None or c.topic in topics)
            ]
            if not range_conns:
                found = sorted({c.topic for c in conns if c.msgtype == RANGE})
                raise InputError(
                    "no sensor_msgs/Range messages"
                    + (
                        f" on {', '.join(topics)} (the bag has {', '.join(found) or 'none'})"
                        if topics
                        else ""
                    ),
                    path=p,
                )
            odoms = [
                c
                for c in conns
                if c.msgtype == ODOM and (odom_topic is None or c.topic == odom_topic)
            ]
            if odom_topic is not None and not odoms:
                raise InputError(f"no nav_msgs/Odometry on topic {odom_topic}", path=p)
            odoms = odoms[:1]
            tfs = [c for c in conns if c.msgtype == TF]
            wanted = range_conns + odoms + tfs
            for c in conns:
                if c not in wanted:
                    s.skipped[c.topic] += c.msgcount
            for conn, recorded, raw in reader.messages(connections=wanted):
                msg: Any = reader.deserialize(raw, conn.msgtype)
                s.topics[conn.topic] += 1
                if conn.msgtype == RANGE:
                    ranges.append(
                        (
                            _stamp(msg.header) or recorded * 1e-9,  # unset stamp: the record time
                            msg.header.frame_id,
                            float(msg.range),
                            float(msg.min_range),
                            float(msg.max_range),
                            float(msg.field_of_view),
                            conn.topic,
                        )
                    )
                elif conn.msgtype == ODOM:
                    pp = msg.pose.pose
                    poses.append(
                        (_stamp(msg.header), pp.position.x, pp.position.y, _yaw(pp.orientation))
                    )
                else:
                    for tr in msg.transforms:
                        t3 = (
                            tr.transform.translation.x,
                            tr.transform.translation.y,
                            _yaw(tr.transform.rotation),
                        )
                        child = tr.child_frame_id.lstrip("/")
                        parent = tr.header.frame_id.lstrip("/")
                        if conn.topic.endswith("tf_static"):
                            static[child] = (parent, t3)
                        else:
                            tf_children.add(child)
                            if child == base_frame:
                                tf_poses.append((_stamp(tr.header), *t3))
    except InputError:
        raise
    except Exception as err:  # rosbags signals bad bags with several exception types
        raise InputError(f"cannot read bag ({type(err).__name__}: {err})", path=p) from err
    if poses:
        s.pose_source = f"odometry on {odoms[0].topic}"
    elif tf_poses:
        poses, s.pose_source = tf_poses, f"/tf to {base_frame}"
    else:
        raise InputError(
            f"no robot poses: no nav_msgs/Odometry and no /tf transform to '{base_frame}' "
            f"(/tf has {', '.join(sorted(tf_children)) or 'no frames'}; see --base-frame)",
            path=p,
        )
    return _assemble(p, ranges, poses, static, base_frame, rig, s)


def _assemble(
    p: Path,
    ranges: list[tuple[float, str, float, float, float, float, str]],
    poses: list[tuple[float, float, float, float]],
    static: dict[str, tuple[str, tuple[float, float, float]]],
    base: str,
    rig: Rig | None,
    s: BagSummary,
) -> tuple[Readings, Rig]:
    ranges.sort(key=lambda r: r[0])
    poses.sort(key=lambda r: r[0])
    fov = {(r[3], r[4], r[5]) for r in ranges}
    if len(fov) > 1:
        raise InputError(
            "Range messages disagree on field_of_view / min_range / max_range "
            f"({sorted(fov)[:2]}); convert one topic at a time (--topic)",
            path=p,
        )
    r_min, r_max, fov_rad = next(iter(fov))
    if not (0 < fov_rad < math.pi and 0 <= r_min < r_max and math.isfinite(r_max)):
        raise InputError(
            f"unusable beam: field_of_view {fov_rad}, min_range {r_min}, max_range {r_max}", path=p
        )
    frames = sorted({r[1] for r in ranges})
    mounts = []
    for f in frames:
        pose = _mount(f, static, base)
        if pose is None:
            if rig is not None and f in rig.names:
                m = rig.mounts[rig.index(f)]
                mounts.append(m)
                continue
            raise InputError(
                f"no transform from sensor frame '{f}' to '{base}' in "
                "/tf_static; give a rig with a sonar named after the frame",
                path=p,
            )
        mounts.append(Mount(f, pose[0], pose[1], math.degrees(pose[2])))
    sensor = SensorModel("ros-range", Region.cone(math.degrees(fov_rad), r_max), r_min, r_max, 0.01)
    out_rig = Rig(sensor, tuple(mounts))
    pt = np.array([q[0] for q in poses])
    px = np.array([q[1] for q in poses])
    py = np.array([q[2] for q in poses])
    pth = np.unwrap(np.array([q[3] for q in poses]))
    t = np.array([r[0] for r in ranges])
    value = np.array([r[2] for r in ranges])
    inside = (t >= pt[0]) & (t <= pt[-1])
    nan = np.isnan(value)
    s.skipped["readings outside the poses' time span"] += int(np.sum(~inside))
    s.skipped["NaN readings"] += int(np.sum(nan & inside))
    keep = inside & ~nan
    value = np.where(value == -np.inf, r_min, np.where(value >= r_max, r_max, value))
    neg = keep & (value < 0)
    if neg.any():
        raise InputError(f"negative range {value[neg][0]} at stamp {t[neg][0]:.9f}", path=p)
    t, value = t[keep], value[keep]
    names = [r[1] for r, k in zip(ranges, keep, strict=True) if k]
    index = {f: i for i, f in enumerate(frames)}
    sensor_idx = np.array([index[n] for n in names], dtype=np.int32)
    rx, ry, rth = np.interp(t, pt, px), np.interp(t, pt, py), np.interp(t, pt, pth)
    mx = np.array([m.x for m in mounts])[sensor_idx]
    my = np.array([m.y for m in mounts])[sensor_idx]
    myaw = np.radians([m.yaw_deg for m in mounts])[sensor_idx]
    c, sn = np.cos(rth), np.sin(rth)
    readings = Readings(
        t - (t[0] if len(t) else 0.0),
        sensor_idx,
        rx + c * mx - sn * my,
        ry + sn * mx + c * my,
        np.angle(np.exp(1j * (rth + myaw))),
        value,
        out_rig.names,
    )
    if len(readings) == 0:
        raise InputError("no Range reading falls within the span of the robot poses", path=p)
    return readings, out_rig
