"""Recording a mapping run as a ROS 2 bag in MCAP storage, for the ROS tools.

The bag opens in Foxglove Studio or plays into RViz with ``ros2 bag play``:

- ``/map`` (``nav_msgs/OccupancyGrid``, frame ``map``): the map's classes as
  ``map_server`` publishes a trinary map -- 100 occupied, 0 free, -1 unknown -- so a
  navigation stack sees exactly what the scores and the written ``.pgm`` say;
- ``/map_occupancy`` (the same type): the occupancy itself, 0-100, -1 unknown;
- ``/sonar/NAME`` (``sensor_msgs/Range``, frame ``sonar_NAME``): every reading, a
  no-echo reading as ``+inf`` (REP 117);
- ``/tf``: ``map -> base_link``, the robot's pose at each reading time (recovered from the
  sonar's world pose and its mounting), and ``/tf_static``: ``base_link -> sonar_NAME``
  from the rig.

Messages are serialised with rosbags (CDR, the ROS 2 Humble type definitions).
"""

from __future__ import annotations

import math
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ..errors import OutputError
from ..readings import Readings
from ..rig import Rig
from .rosmap import OCCUPIED, UNKNOWN, OccupancyMap, classify

__all__ = ["BagRecorder", "robot_poses"]

_TS = get_typestore(Stores.ROS2_HUMBLE)
_T = _TS.types
_RANGE = "sensor_msgs/msg/Range"
_GRID = "nav_msgs/msg/OccupancyGrid"
_TF = "tf2_msgs/msg/TFMessage"


def robot_poses(readings: Readings, rig: Rig) -> npt.NDArray[np.float64]:
    """The robot's pose ``(x, y, theta)`` at each reading, from the sonar's world pose
    and where the rig mounts that sonar (the inverse of placing the sonar on the robot).
    """
    mounts = {m.name: m for m in rig.mounts}
    mx = np.array([mounts[n].x for n in readings.names])[readings.sensor]
    my = np.array([mounts[n].y for n in readings.names])[readings.sensor]
    yaw = np.radians(np.array([mounts[n].yaw_deg for n in readings.names]))[readings.sensor]
    th = readings.theta - yaw
    c, s = np.cos(th), np.sin(th)
    return np.column_stack([readings.x - (c * mx - s * my), readings.y - (s * mx + c * my), th])


def _stamp(t: float) -> Any:
    sec = math.floor(t)
    nsec = min(round((t - sec) * 1e9), 999_999_999)
    return _T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


def _header(t: float, frame: str) -> Any:
    return _T["std_msgs/msg/Header"](stamp=_stamp(t), frame_id=frame)


def _transform(t: float, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    tr = _T["geometry_msgs/msg/Transform"](
        translation=_T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
        rotation=_T["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        ),
    )
    return _T["geometry_msgs/msg/TransformStamped"](
        header=_header(t, parent), child_frame_id=child, transform=tr
    )


def _field_of_view(rig: Rig) -> float:
    """The beam's angular width in radians, from its outline."""
    pts = rig.sensor.beam.outline
    angles = np.arctan2(pts[:, 1], pts[:, 0])
    near = np.hypot(pts[:, 0], pts[:, 1]) > 1e-9
    return float(np.ptp(angles[near])) if near.any() else 0.0


def _grid_message(m: OccupancyMap, t: float, values: npt.NDArray[np.int8]) -> Any:
    g = m.grid
    ox, oy = g.origin
    info = _T["nav_msgs/msg/MapMetaData"](
        map_load_time=_stamp(t),
        resolution=float(g.resolution),
        width=g.cols,
        height=g.rows,
        origin=_T["geometry_msgs/msg/Pose"](
            position=_T["geometry_msgs/msg/Point"](x=float(ox), y=float(oy), z=0.0),
            orientation=_T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    # ROS grids start at the origin (bottom-left) and run along x; ours start at the top.
    data = np.ascontiguousarray(values[::-1]).reshape(-1)
    return _T[_GRID](header=_header(t, "map"), info=info, data=data)


class BagRecorder:
    """Write readings, robot poses and maps as they come into a ROS 2 bag (MCAP).

    Parameters
    ----------
    path : Path
        The bag's folder (it must not exist): ``metadata.yaml`` and the ``.mcap`` file.
    rig : Rig
        Names the sonar frames and gives their mounting (``/tf_static``).

    Use as a context manager; :meth:`readings` and :meth:`map` in time order.
    """

    def __init__(self, path: Path, rig: Rig) -> None:
        if path.exists():
            raise OutputError("already exists; a bag needs a new folder", path=path)
        self.path = path
        self.rig = rig
        self._fov = _field_of_view(rig)
        self._writer = Writer(path, version=8, storage_plugin=StoragePlugin.MCAP)
        self._conns: dict[str, Any] = {}
        self._last_pose_t = -math.inf
        self.n_messages = 0

    def __enter__(self) -> BagRecorder:
        try:
            self._writer.open()
        except OSError as err:
            raise OutputError(f"cannot write ({err.strerror or err})", path=self.path) from err
        statics = [
            _transform(0.0, "base_link", f"sonar_{m.name}", m.x, m.y, math.radians(m.yaw_deg))
            for m in self.rig.mounts
        ]
        self._write("/tf_static", _TF, 0.0, _T[_TF](transforms=statics))
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        err: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._writer.close()

    def _write(self, topic: str, msgtype: str, t: float, msg: Any) -> None:
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=_TS)
        self._writer.write(conn, _ns(t), _TS.serialize_cdr(msg, msgtype))
        self.n_messages += 1

    def readings(self, batch: Readings) -> None:
        """One ``Range`` per reading, and the robot's pose when its time moves on."""
        if len(batch) == 0:
            return
        poses = robot_poses(batch, self.rig)
        r_max = self.rig.sensor.r_max
        for i in range(len(batch)):
            t = float(batch.t[i])
            if t > self._last_pose_t:
                x, y, th = poses[i]
                tf = _transform(t, "map", "base_link", float(x), float(y), float(th))
                self._write("/tf", _TF, t, _T[_TF](transforms=[tf]))
                self._last_pose_t = t
            name = batch.names[batch.sensor[i]]
            rng = float(batch.range[i])
            msg = _T[_RANGE](
                header=_header(t, f"sonar_{name}"),
                radiation_type=0,  # ULTRASOUND
                field_of_view=self._fov,
                min_range=float(self.rig.sensor.r_min),
                max_range=float(r_max),
                range=math.inf if rng >= r_max else rng,
            )
            self._write(f"/sonar/{name}", _RANGE, t, msg)

    def map(self, m: OccupancyMap, t: float) -> None:
        """The map at log time ``t``: its classes on ``/map``, its values on
        ``/map_occupancy``."""
        cls = classify(m.occupancy)
        trinary = np.where(cls == OCCUPIED, 100, np.where(cls == UNKNOWN, -1, 0)).astype(np.int8)
        self._write("/map", _GRID, t, _grid_message(m, t, trinary))
        occ = np.asarray(m.occupancy, dtype=np.float64)
        scaled = np.where(np.isnan(occ), -1, np.round(np.clip(occ, 0, 1) * 100)).astype(np.int8)
        self._write("/map_occupancy", _GRID, t, _grid_message(m, t, scaled))
