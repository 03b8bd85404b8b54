"""ROS bags with sensor_msgs/Range, written here with rosbags itself."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from sonarmap.errors import InputError
from sonarmap.io.rosbag import BagSummary, read_bag

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types


def stamp(t: float) -> Any:
    sec = math.floor(t)
    return T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9))


def header(t: float, frame: str) -> Any:
    return T["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame)


def quat(yaw: float) -> Any:
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def vec(x: float, y: float) -> Any:
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0)


def tf(t: float, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    tr = T["geometry_msgs/msg/Transform"](translation=vec(x, y), rotation=quat(yaw))
    return T["geometry_msgs/msg/TransformStamped"](
        header=header(t, parent), child_frame_id=child, transform=tr
    )


def odom(t: float, x: float, y: float, yaw: float) -> Any:
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quat(yaw)
    )
    twist = T["geometry_msgs/msg/Twist"](linear=vec(0, 0), angular=vec(0, 0))
    return T["nav_msgs/msg/Odometry"](
        header=header(t, "odom"),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def rng(t: float, frame: str, r: float) -> Any:
    return T["sensor_msgs/msg/Range"](
        header=header(t, frame),
        radiation_type=0,
        field_of_view=0.5,
        min_range=0.1,
        max_range=4.0,
        range=r,
    )


def write_bag(path: Path, ros1: bool, use_tf: bool) -> None:
    msgs: list[tuple[str, str, float, Any]] = []
    statics = [
        tf(0.0, "base_link", "sonar_front", 0.2, 0.0, 0.0),
        tf(0.0, "base_link", "mount", 0.0, 0.1, 0.0),
        tf(0.0, "mount", "sonar_left", 0.0, 0.05, math.pi / 2),
    ]
    msgs.append(
        (
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            0.0,
            T["tf2_msgs/msg/TFMessage"](transforms=statics),
        )
    )
    for k in range(11):  # the robot drives 1 m along x in 1 s, turning 0.5 rad
        t = k * 0.1
        if use_tf:
            msgs.append(
                (
                    "/tf",
                    "tf2_msgs/msg/TFMessage",
                    t,
                    T["tf2_msgs/msg/TFMessage"](
                        transforms=[tf(t, "odom", "base_link", t, 0.0, 0.5 * t)]
                    ),
                )
            )
        else:
            msgs.append(("/odom", "nav_msgs/msg/Odometry", t, odom(t, t, 0.0, 0.5 * t)))
    values = [1.0, math.inf, -math.inf, math.nan, 2.5]
    for k, v in enumerate(values):
        t = 0.05 + 0.2 * k
        msgs.append(("/sonar/front", "sensor_msgs/msg/Range", t, rng(t, "sonar_front", v)))
        msgs.append(("/sonar/left", "sensor_msgs/msg/Range", t, rng(t, "sonar_left", 3.0)))
    msgs.append(("/sonar/front", "sensor_msgs/msg/Range", 5.0, rng(5.0, "sonar_front", 1.0)))
    msgs.append(("/chatter", "std_msgs/msg/String", 0.3, T["std_msgs/msg/String"](data="hi")))
    msgs.sort(key=lambda m: m[2])
    if ros1:
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.typesys import get_types_from_msg

        ts1 = get_typestore(Stores.ROS1_NOETIC)
        ts1.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
        with Writer1(path) as w:
            conns: dict[str, Any] = {}
            for topic, mtype, t, msg in msgs:
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, mtype, typestore=ts1)
                w.write(
                    conns[topic],
                    int((t + 1) * 1e9),
                    ts1.serialize_ros1(_to(ts1, msg, mtype), mtype),
                )
    else:
        from rosbags.rosbag2 import Writer as Writer2

        with Writer2(path, version=8) as w2:
            conns2: dict[str, Any] = {}
            for topic, mtype, t, msg in msgs:
                if topic not in conns2:
                    conns2[topic] = w2.add_connection(topic, mtype, typestore=TS)
                w2.write(conns2[topic], int((t + 1) * 1e9), TS.serialize_cdr(msg, mtype))


def _to(ts1: Any, msg: Any, mtype: str) -> Any:
    """The same message in the ROS 1 typestore (headers there carry a seq field)."""
    cls = ts1.types[mtype]
    kwargs = {}
    for name in cls.__dataclass_fields__:
        if name == "__msgtype__":
            continue
        if name == "seq":
            kwargs[name] = 0
            continue
        v = getattr(msg, name)
        if hasattr(v, "__msgtype__"):
            v = _to(ts1, v, v.__msgtype__)
        elif isinstance(v, list):
            v = [_to(ts1, x, x.__msgtype__) if hasattr(x, "__msgtype__") else x for x in v]
        kwargs[name] = v
    return cls(**kwargs)


@pytest.mark.parametrize(("ros1", "use_tf"), [(False, False), (True, True)])
def test_bag_readings(tmp_path: Path, ros1: bool, use_tf: bool) -> None:
    path = tmp_path / ("run.bag" if ros1 else "run")
    write_bag(path, ros1, use_tf)
    s = BagSummary()
    r, rig = read_bag(path, summary=s)
    assert rig.names == ("sonar_front", "sonar_left")
    left = rig.mounts[1]
    assert (left.x, left.y, left.yaw_deg) == pytest.approx((0.0, 0.15, 90.0))
    assert rig.sensor.r_max == 4.0
    assert rig.sensor.r_min == pytest.approx(0.1)  # float32 in the message
    assert ("/tf" if use_tf else "odometry") in s.pose_source
    assert s.skipped["NaN readings"] == 1
    assert s.skipped["readings outside the poses' time span"] == 1
    assert s.skipped["/chatter"] == 1
    assert len(r) == 9
    front = r.take(r.sensor == 0)
    assert front.range.tolist() == pytest.approx([1.0, 4.0, 0.1, 2.5])  # inf, -inf mapped
    # First front reading at t = 0.05: robot at (0.05, 0), heading 0.025; sonar 0.2 ahead.
    assert front.x[0] == pytest.approx(0.05 + 0.2 * math.cos(0.025))
    assert front.theta[0] == pytest.approx(0.025)
    leftr = r.take(r.sensor == 1)
    assert leftr.theta[0] == pytest.approx(0.025 + math.pi / 2)


def test_bag_errors(tmp_path: Path) -> None:
    path = tmp_path / "run"
    write_bag(path, ros1=False, use_tf=False)
    with pytest.raises(
        InputError,
        match=r"no sensor_msgs/Range messages on /nope \(the bag "
        r"has /sonar/front, /sonar/left\)",
    ):
        read_bag(path, topics=["/nope"])
    with pytest.raises(InputError, match="no nav_msgs/Odometry on topic /odom2"):
        read_bag(path, odom_topic="/odom2")
    with pytest.raises(InputError, match="no such bag"):
        read_bag(tmp_path / "missing")
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\nnot really")
    with pytest.raises(InputError, match=r"junk.bag: cannot read bag"):
        read_bag(tmp_path / "junk.bag")


def test_convert_a_ros2_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from sonarmap.cli import main
    from sonarmap.readings import read_readings
    from sonarmap.rig import load_rig

    write_bag(tmp_path / "bag", ros1=False, use_tf=False)
    main(["convert", str(tmp_path / "bag"), "-o", str(tmp_path / "r.csv")])
    out = " ".join(capsys.readouterr().out.split())  # rich wraps long lines
    assert "poses from odometry on /odom" in out
    rig = load_rig(tmp_path / "r.rig.yaml")
    assert len(read_readings(tmp_path / "r.csv", names=rig.names)) == 9
    with pytest.raises(SystemExit):
        main(["convert", str(tmp_path / "bag"), "--topic", "/x", "-o", str(tmp_path / "x.csv")])
    assert "no sensor_msgs/Range messages on /x" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_tf_to_another_base_frame(tmp_path: Path) -> None:
    path = tmp_path / "run.bag"
    write_bag(path, ros1=True, use_tf=True)
    with pytest.raises(
        InputError,
        match=r"no /tf transform to 'base_footprint' \(/tf has "
        r"base_link; see --base-frame\)",
    ):
        read_bag(path, base_frame="base_footprint")
