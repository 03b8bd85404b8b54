"""The ROS 2 bag (MCAP) a stream records, read back with rosbags."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from sonarmap.cli import main
from sonarmap.errors import OutputError
from sonarmap.io.record import BagRecorder, robot_poses
from sonarmap.io.rosmap import OCCUPIED, UNKNOWN, read_map
from sonarmap.scenarios import Scenario


def test_robot_poses_invert_the_mounting(doorways: Scenario) -> None:
    """The simulator places each sonar on the robot; undoing the mounting gives the
    trajectory's pose back at each reading."""
    r = doorways.readings
    poses = robot_poses(r, doorways.rig)
    traj = doorways.trajectory
    x = np.interp(r.t, traj.t, traj.x)
    y = np.interp(r.t, traj.t, traj.y)
    th = np.interp(r.t, traj.t, np.unwrap(traj.theta))
    np.testing.assert_allclose(poses[:, 0], x, atol=1e-6)
    np.testing.assert_allclose(poses[:, 1], y, atol=1e-6)
    np.testing.assert_allclose(np.angle(np.exp(1j * (poses[:, 2] - th))), 0, atol=1e-6)


def test_stream_records_a_bag_the_ros_tools_read(
    doorways: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doorways.write(tmp_path / "scene")
    d = tmp_path / "scene"
    out = tmp_path / "out"
    args = ["stream", str(d / "readings.csv"), "--rig", str(d / "rig.yaml")]
    args += ["--like", str(d / "truth.yaml"), "--method", "gradient", "--bag", "-o", str(out)]
    main(args)
    assert "bag/ (" in capsys.readouterr().out
    final = read_map(out / "map.yaml")
    meta = yaml.safe_load((out / "bag" / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["storage_identifier"] == "mcap"
    r = doorways.readings
    with AnyReader([out / "bag"]) as bag:
        counts = {c.topic: c.msgcount for c in bag.connections}
        types = {c.topic: c.msgtype for c in bag.connections}
        sonars = [t for t in counts if t.startswith("/sonar/")]
        assert sorted(sonars) == sorted(f"/sonar/{n}" for n in doorways.rig.names)
        assert sum(counts[t] for t in sonars) == len(r)
        assert types["/map"] == "nav_msgs/msg/OccupancyGrid"
        assert counts["/tf_static"] == 1
        maps: list[Any] = [
            bag.deserialize(raw, c.msgtype)
            for c, _, raw in bag.messages([c for c in bag.connections if c.topic == "/map"])
        ]
        ranges: list[Any] = [
            bag.deserialize(raw, c.msgtype)
            for c, _, raw in bag.messages([c for c in bag.connections if c.topic in sonars])
        ]
    last = maps[-1]
    assert (last.info.width, last.info.height) == (final.grid.cols, final.grid.rows)
    assert last.info.resolution == pytest.approx(final.grid.resolution)
    assert last.info.origin.position.x == pytest.approx(final.grid.origin[0])
    # Rows run up from the origin in ROS; the classes are the written map's.
    data = np.asarray(last.data).reshape(last.info.height, last.info.width)[::-1]
    cls = final.classes()
    np.testing.assert_array_equal(data == 100, cls == OCCUPIED)
    np.testing.assert_array_equal(data == -1, cls == UNKNOWN)
    assert len(maps) >= math.floor(r.t[-1] - r.t[0])  # one a second of log, and the last
    no_echo = [m for m in ranges if math.isinf(m.range)]
    assert len(no_echo) == int(np.sum(r.range >= doorways.rig.sensor.r_max))
    assert all(m.radiation_type == 0 and m.field_of_view > 0 for m in ranges[:10])


def test_recorder_refuses_an_existing_folder(doorways: Scenario, tmp_path: Path) -> None:
    (tmp_path / "bag").mkdir()
    with pytest.raises(OutputError, match="already exists"):
        BagRecorder(tmp_path / "bag", doorways.rig)
