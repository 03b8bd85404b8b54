"""Recording a run as ROS 2 messages: into a bag (MCAP storage), to a live viewer, or both.

One publishing interface serves every layer. A :class:`Sink` takes messages
(``publish(topic, msgtype, msg, t)``, ``t`` the run's time in seconds): a
:class:`BagSink` writes them into a ROS 2 bag in MCAP storage with rosbags' Writer
(``metadata.yaml`` included, so ``ros2 bag info`` reads it), a
:class:`~sonarmap.io.live.LiveSink` serves them over the Foxglove WebSocket protocol.
A :class:`Recorder` fans each message out to its sinks and says when a slower topic is
due. The layers' publishers turn a run's state into messages through it:
:class:`MappingPublisher` here (``sonarmap stream``),
:mod:`sonarmap.patrol.publish` and :mod:`sonarmap.team.publish`.

A mapping run's topics (:class:`MappingPublisher`), which open in Foxglove or play into
RViz with ``ros2 bag play``:

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
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
from rosbags.rosbag2 import StoragePlugin, Writer

from ..errors import OutputError
from ..readings import Readings
from ..rig import Rig
from .rosmap import OCCUPIED, UNKNOWN, OccupancyMap, classify
from .rosmsg import (
    GRID,
    TF,
    TYPESTORE,
    grid_message,
    header,
    serialize,
    tf_message,
    transform,
)

__all__ = [
    "BagRecorder",
    "BagSink",
    "MappingPublisher",
    "Recorder",
    "Sink",
    "make_recorder",
    "robot_poses",
    "trinary",
]

_T = TYPESTORE.types
_RANGE = "sensor_msgs/msg/Range"


class Sink(Protocol):
    """Where a run's messages go: a bag, a live server."""

    def publish(self, topic: str, msgtype: str, msg: Any, t: float) -> None:
        """Take one message of ROS 2 type ``msgtype`` (a rosbags message object) on
        ``topic`` at the run's time ``t`` seconds; times never go back on a topic."""

    def declare(self, topic: str, msgtype: str) -> None:
        """Say that ``topic`` will carry ``msgtype`` messages (a live server advertises
        it at once); publishing without declaring is allowed."""

    def close(self) -> None:
        """Finish: the bag closed, the server stopped. Called once."""


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


class BagSink:
    """A ROS 2 bag in MCAP storage, written as messages come (rosbags' Writer).

    Parameters
    ----------
    path : Path
        The bag's folder, which must not exist: ``metadata.yaml`` and the ``.mcap``.

    Raises
    ------
    OutputError
        The folder exists or cannot be written.
    """

    def __init__(self, path: Path) -> None:
        if path.exists():
            raise OutputError("already exists; a bag needs a new folder", path=path)
        self.path = path
        self._writer = Writer(path, version=8, storage_plugin=StoragePlugin.MCAP)
        try:
            self._writer.open()
        except OSError as err:
            raise OutputError(f"cannot write ({err.strerror or err})", path=path) from err
        self._conns: dict[str, Any] = {}
        self.n_messages = 0

    def publish(self, topic: str, msgtype: str, msg: Any, t: float) -> None:
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            self._conns[topic] = conn
        self._writer.write(conn, _ns(t), serialize(msg, msgtype))
        self.n_messages += 1

    def declare(self, topic: str, msgtype: str) -> None:
        """Nothing: a bag lists only the topics that have messages."""

    def close(self) -> None:
        self._writer.close()


class Recorder:
    """Fans each message out to every sink; a context manager that closes them.

    Parameters
    ----------
    sinks : sequence of Sink
        Where the messages go (none: a recorder that drops everything, so a loop can
        publish unconditionally).
    """

    def __init__(self, sinks: Sequence[Sink] = ()) -> None:
        self.sinks = list(sinks)
        #: Where a live viewer connects, when a sink serves live (:func:`make_recorder`).
        self.url: str | None = None
        self.n_messages = 0
        self._due: dict[str, float] = {}
        self._closed = False

    def __bool__(self) -> bool:
        return bool(self.sinks)

    def publish(self, topic: str, msgtype: str, msg: Any, t: float) -> None:
        """Give the message to every sink."""
        for sink in self.sinks:
            sink.publish(topic, msgtype, msg, t)
        self.n_messages += 1

    def declare(self, topics: dict[str, str]) -> None:
        """Declare topics (name to message type) to every sink before they carry
        messages, so that a live viewer is offered them all at once."""
        for topic, msgtype in topics.items():
            for sink in self.sinks:
                sink.declare(topic, msgtype)

    def due(self, key: str, t: float, every: float) -> bool:
        """Whether the slower topic ``key`` is due at time ``t``: True the first time
        and then once ``every`` seconds have passed since it last was (so grids go at a
        lower rate than poses)."""
        if t < self._due.get(key, -math.inf):
            return False
        self._due[key] = t + every
        return True

    def close(self) -> None:
        """Close every sink (once)."""
        if self._closed:
            return
        self._closed = True
        for sink in self.sinks:
            sink.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        err: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def trinary(classes: npt.NDArray[np.int8] | npt.NDArray[np.int64]) -> npt.NDArray[np.int8]:
    """A map's classes as ``map_server`` publishes them: 100 occupied, 0 free, -1
    unknown."""
    out: npt.NDArray[np.int8] = np.where(
        classes == OCCUPIED, 100, np.where(classes == UNKNOWN, -1, 0)
    ).astype(np.int8)
    return out


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


def _field_of_view(rig: Rig) -> float:
    """The beam's angular width in radians, from its outline."""
    pts = rig.sensor.beam.outline
    angles = np.arctan2(pts[:, 1], pts[:, 0])
    near = np.hypot(pts[:, 0], pts[:, 1]) > 1e-9
    return float(np.ptp(angles[near])) if near.any() else 0.0


class MappingPublisher:
    """A mapping run's messages (the module's topics) into a :class:`Recorder`.

    Parameters
    ----------
    recorder : Recorder
    rig : Rig
        Names the sonar frames and gives their mounting (``/tf_static``, published at
        once).

    Call :meth:`readings` and :meth:`map` in time order.
    """

    def __init__(self, recorder: Recorder, rig: Rig) -> None:
        self.recorder = recorder
        self.rig = rig
        self._fov = _field_of_view(rig)
        self._last_pose_t = -math.inf
        topics = {"/tf_static": TF, "/tf": TF, "/map": GRID, "/map_occupancy": GRID}
        recorder.declare(topics | {f"/sonar/{m.name}": _RANGE for m in rig.mounts})
        statics = [
            transform(0.0, "base_link", f"sonar_{m.name}", m.x, m.y, math.radians(m.yaw_deg))
            for m in rig.mounts
        ]
        recorder.publish("/tf_static", TF, tf_message(statics), 0.0)

    @property
    def n_messages(self) -> int:
        return self.recorder.n_messages

    def readings(self, batch: Readings) -> None:
        """One ``Range`` per reading, and the robot's pose when its time moves on."""
        if len(batch) == 0:
            return
        rec = self.recorder
        poses = robot_poses(batch, self.rig)
        r_max = self.rig.sensor.r_max
        for i in range(len(batch)):
            t = float(batch.t[i])
            if t > self._last_pose_t:
                x, y, th = poses[i]
                tf = transform(t, "map", "base_link", float(x), float(y), float(th))
                rec.publish("/tf", TF, tf_message([tf]), t)
                self._last_pose_t = t
            name = batch.names[batch.sensor[i]]
            rng = float(batch.range[i])
            msg = _T[_RANGE](
                header=header(t, f"sonar_{name}"),
                radiation_type=0,  # ULTRASOUND
                field_of_view=self._fov,
                min_range=float(self.rig.sensor.r_min),
                max_range=float(r_max),
                range=math.inf if rng >= r_max else rng,
            )
            rec.publish(f"/sonar/{name}", _RANGE, msg, t)

    def map(self, m: OccupancyMap, t: float) -> None:
        """The map at log time ``t``: its classes on ``/map``, its values on
        ``/map_occupancy``."""
        rec = self.recorder
        rec.publish("/map", GRID, grid_message(m.grid, t, trinary(classify(m.occupancy))), t)
        occ = np.asarray(m.occupancy, dtype=np.float64)
        scaled = np.where(np.isnan(occ), -1, np.round(np.clip(occ, 0, 1) * 100)).astype(np.int8)
        rec.publish("/map_occupancy", GRID, grid_message(m.grid, t, scaled), t)


class BagRecorder(MappingPublisher):
    """A mapping run into a ROS 2 bag (MCAP) alone: a :class:`MappingPublisher` over a
    :class:`BagSink`, and a context manager that closes the bag.

    Parameters
    ----------
    path : Path
        The bag's folder (it must not exist).
    rig : Rig
    """

    def __init__(self, path: Path, rig: Rig) -> None:
        self.path = path
        super().__init__(Recorder([BagSink(path)]), rig)

    def __enter__(self) -> BagRecorder:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        err: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.recorder.close()


def make_recorder(
    bag: Path | None = None,
    *,
    live_port: int | None = None,
    live_rate: float | None = 1.0,
    live_host: str = "127.0.0.1",
) -> Recorder:
    """A recorder into a bag, a live server, both or neither.

    Parameters
    ----------
    bag : Path, optional
        The bag's new folder (:class:`BagSink`).
    live_port : int, optional
        Serve live on this port (0: any free one) with a
        :class:`~sonarmap.io.live.LiveSink`.
    live_rate : float or None
        Live: simulated seconds per wall second the run is held to; None, no pacing.
    live_host : str
        Live: the address bound, ``127.0.0.1`` by default.

    The live server starts first; a bag that cannot be opened then stops it again, so
    a failure leaves nothing behind.
    """
    sinks: list[Sink] = []
    url = None
    if live_port is not None:
        from .live import LiveSink

        live = LiveSink(live_port, host=live_host, rate=live_rate)
        sinks.append(live)
        url = live.url
    if bag is not None:
        try:
            sinks.append(BagSink(bag))
        except BaseException:
            for s in sinks:
                s.close()
            raise
    rec = Recorder(sinks)
    rec.url = url
    return rec
