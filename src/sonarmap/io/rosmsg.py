"""ROS 2 messages that the ROS tools draw natively, built with rosbags' typestore.

The recorders (:mod:`.record`) and the live server (:mod:`.live`) publish these: grids
as ``nav_msgs/msg/OccupancyGrid``, poses in ``tf2_msgs/msg/TFMessage`` and
``nav_msgs/msg/Path``, links, areas and pose graphs as
``visualization_msgs/msg/MarkerArray``, figures as ``std_msgs/msg/Float64``. Every
message is stamped in the run's own (simulated or log) time, in seconds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.typesys import Stores, get_typestore

from ..grid import Grid

__all__ = [
    "CUBE_LIST",
    "CYLINDER",
    "FLOAT",
    "GRID",
    "LINE_LIST",
    "LINE_STRIP",
    "MARKERS",
    "PATH",
    "SPHERE_LIST",
    "TF",
    "TYPESTORE",
    "Trails",
    "float_message",
    "grid_message",
    "header",
    "marker",
    "markers_message",
    "msgdef",
    "path_message",
    "serialize",
    "stamp",
    "tf_message",
    "transform",
]

#: The ROS 2 Humble type definitions every message is serialised with (CDR).
TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
_T = TYPESTORE.types
GRID = "nav_msgs/msg/OccupancyGrid"
TF = "tf2_msgs/msg/TFMessage"
PATH = "nav_msgs/msg/Path"
MARKERS = "visualization_msgs/msg/MarkerArray"
FLOAT = "std_msgs/msg/Float64"

#: visualization_msgs/Marker types used here.
LINE_STRIP, LINE_LIST, CUBE_LIST, SPHERE_LIST, CYLINDER = 4, 5, 6, 7, 3
_ADD, _DELETEALL = 0, 3


def serialize(msg: Any, msgtype: str) -> bytes:
    """The message as CDR bytes (what a bag stores and the live server sends)."""
    return bytes(TYPESTORE.serialize_cdr(msg, msgtype))


def msgdef(msgtype: str) -> str:
    """The type's ``ros2msg`` definition with its dependencies (an MCAP schema)."""
    text, _ = TYPESTORE.generate_msgdef(msgtype, ros_version=2)
    return str(text)


def stamp(t: float) -> Any:
    """``builtin_interfaces/Time`` of ``t`` seconds."""
    sec = math.floor(t)
    nsec = min(round((t - sec) * 1e9), 999_999_999)
    return _T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def header(t: float, frame: str) -> Any:
    return _T["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame)


def _quaternion(yaw: float) -> Any:
    return _T["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
    )


def transform(t: float, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    """``geometry_msgs/TransformStamped``: ``child`` at (x, y) metres, heading ``yaw``
    radians, in ``parent``."""
    tr = _T["geometry_msgs/msg/Transform"](
        translation=_T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=0.0),
        rotation=_quaternion(float(yaw)),
    )
    return _T["geometry_msgs/msg/TransformStamped"](
        header=header(t, parent), child_frame_id=child, transform=tr
    )


def tf_message(transforms: Sequence[Any]) -> Any:
    """A ``tf2_msgs/TFMessage`` of :func:`transform` results."""
    return _T[TF](transforms=list(transforms))


def grid_message(grid: Grid, t: float, values: npt.NDArray[np.int8], frame: str = "map") -> Any:
    """``nav_msgs/OccupancyGrid`` of ``values`` (rows from the top, as sonarmap's arrays;
    0-100, -1 unknown) on ``grid``."""
    ox, oy = grid.origin
    info = _T["nav_msgs/msg/MapMetaData"](
        map_load_time=stamp(t),
        resolution=float(grid.resolution),
        width=grid.cols,
        height=grid.rows,
        origin=_T["geometry_msgs/msg/Pose"](
            position=_T["geometry_msgs/msg/Point"](x=float(ox), y=float(oy), z=0.0),
            orientation=_quaternion(0.0),
        ),
    )
    # ROS grids start at the origin (bottom-left) and run along x; ours start at the top.
    data = np.ascontiguousarray(np.asarray(values, dtype=np.int8)[::-1]).reshape(-1)
    return _T[GRID](header=header(t, frame), info=info, data=data)


def path_message(t: float, poses: npt.ArrayLike, frame: str = "map") -> Any:
    """``nav_msgs/Path`` through ``poses`` (K, 4): time, x, y, heading."""
    rows = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
    stamped = [
        _T["geometry_msgs/msg/PoseStamped"](
            header=header(float(ti), frame),
            pose=_T["geometry_msgs/msg/Pose"](
                position=_T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                orientation=_quaternion(float(th)),
            ),
        )
        for ti, x, y, th in rows.tolist()
    ]
    return _T[PATH](header=header(t, frame), poses=stamped)


def float_message(value: float) -> Any:
    """``std_msgs/Float64`` (a plot-able figure)."""
    return _T[FLOAT](data=float(value))


def _point(x: float, y: float, z: float = 0.0) -> Any:
    return _T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z))


def _colour(rgba: tuple[float, float, float, float]) -> Any:
    r, g, b, a = rgba
    return _T["std_msgs/msg/ColorRGBA"](r=r, g=g, b=b, a=a)


def marker(
    t: float,
    ns: str,
    kind: int,
    points: npt.ArrayLike,
    *,
    ident: int = 0,
    scale: float = 0.1,
    height: float | None = None,
    rgba: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0),
    at: tuple[float, float] = (0.0, 0.0),
    frame: str = "map",
    action: int = _ADD,
) -> Any:
    """One ``visualization_msgs/Marker``.

    Parameters
    ----------
    t : float
        Stamp, seconds.
    ns : str
        The marker's namespace (a display can show or hide each).
    kind : int
        ``LINE_LIST`` (``points`` pairs of ends), ``LINE_STRIP``, ``CUBE_LIST`` or
        ``SPHERE_LIST`` (``points`` (K, 2) metres), or ``CYLINDER`` (a disc of diameter
        ``scale`` at ``at``; ``points`` ignored).
    scale : float
        Line width, or the side or diameter of each cube, sphere or cylinder, metres.
    height : float, optional
        Cubes' and cylinders' height (default ``scale``).
    rgba : tuple of float
        Colour, each in [0, 1].
    """
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    h = scale if height is None else height
    pose = _T["geometry_msgs/msg/Pose"](position=_point(*at), orientation=_quaternion(0.0))
    return _T["visualization_msgs/msg/Marker"](
        header=header(t, frame),
        ns=ns,
        id=ident,
        type=kind,
        action=action,
        pose=pose,
        scale=_T["geometry_msgs/msg/Vector3"](x=scale, y=scale, z=h),
        color=_colour(rgba),
        lifetime=_T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        frame_locked=False,
        points=[_point(x, y) for x, y in xy.tolist()] if kind != CYLINDER else [],
        colors=[],
        texture_resource="",
        texture=_T["sensor_msgs/msg/CompressedImage"](
            header=header(t, frame), format="", data=np.zeros(0, dtype=np.uint8)
        ),
        uv_coordinates=[],
        text="",
        mesh_resource="",
        mesh_file=_T["visualization_msgs/msg/MeshFile"](
            filename="", data=np.zeros(0, dtype=np.uint8)
        ),
        mesh_use_embedded_materials=False,
    )


def markers_message(t: float, markers: Sequence[Any], frame: str = "map") -> Any:
    """``visualization_msgs/MarkerArray``: a DELETEALL first, so each array replaces the
    last one whole (a link that went down disappears)."""
    clear = marker(t, "", LINE_LIST, [], frame=frame, action=_DELETEALL)
    return _T[MARKERS](markers=[clear, *markers])


class Trails:
    """Each robot's poses over the last ``seconds`` (time, x, y, heading), for the
    ``nav_msgs/Path`` of its trail (:func:`path_message`)."""

    def __init__(self, robots: int, seconds: float) -> None:
        self.seconds = float(seconds)
        self._poses: list[deque[tuple[float, float, float, float]]] = [
            deque() for _ in range(robots)
        ]

    def add(self, k: int, t: float, x: float, y: float, heading: float) -> Any:
        """Add robot ``k``'s pose at time ``t``, drop what is older than the window, and
        return the path message of what is left."""
        trail = self._poses[k]
        trail.append((t, x, y, heading))
        while trail and trail[0][0] < t - self.seconds:
            trail.popleft()
        return path_message(t, list(trail))
