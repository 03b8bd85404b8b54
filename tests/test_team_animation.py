"""The team's animation: frames sampled by ``run_team(record=True)``, drawn by
``save_team_animation``, written by ``team run --animate`` (short runs)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image, ImageSequence

from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.animation import TeamFrame, save_team_animation
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams
from sonarmap.team.simulation import TeamResult, run_team

F64 = npt.NDArray[np.float64]
DURATION = 20.0


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def _corridor_routes(*, towards: bool) -> list[F64]:
    """Two robots along the office's corridor (y 9 to 11), a step every 0.5 s: driving
    apart from its middle at 0.4 m/s, or towards each other at 0.5 m/s, meeting at
    t = 14 s (they then map the same walls, which costs association time)."""
    t = np.arange(0.0, DURATION + 0.25, 0.5)
    y0, y1 = np.full_like(t, 10.0), np.full_like(t, 10.2)
    if towards:
        x0, x1, th0 = 3.0 + 0.5 * t, 17.0 - 0.5 * t, 0.0
    else:
        x0, x1, th0 = 9.0 - 0.4 * t, 11.0 + 0.4 * t, np.pi
    return [
        np.column_stack([t, x0, y0, np.full_like(t, th0)]),
        np.column_stack([t, x1, y1, np.full_like(t, np.pi - th0)]),
    ]


def _run(
    plan: OccupancyMap,
    network: NetworkParams,
    *,
    towards: bool = False,
    frame_every: float = 2.0,
    max_frames: int = 300,
    settle: float = 120.0,
) -> TeamResult:
    return run_team(
        plan,
        MissionConfig(duration=DURATION, seed=1),
        2,
        network=network,
        exchange=ExchangeParams(),
        seed=3,
        routes=_corridor_routes(towards=towards),
        record=True,
        frame_every=frame_every,
        max_frames=max_frames,
        settle=settle,
    )


@pytest.fixture(scope="module")
def full_team(plan: OccupancyMap) -> TeamResult:
    return _run(plan, NetworkParams(kind="full"))


def _position_at(route: F64, t: float) -> F64:
    """Where the route puts the robot at ``t``: its last step at or before it."""
    return route[route[:, 0] <= t + 1e-9][-1, 1:3]


def test_team_frames_follow_the_routes_and_the_full_network(full_team: TeamResult) -> None:
    frames = full_team.team_frames
    routes = _corridor_routes(towards=False)
    end = DURATION + full_team.summary["settle_seconds"]
    times = np.array([f.t for f in frames])
    # One frame every 2 s of mission from the first tick on, then the very last tick.
    np.testing.assert_allclose(times[:-1], 2.0 * np.arange(len(frames) - 1))
    assert times[-1] == pytest.approx(end)
    assert len(frames) == int(end // 2.0) + 1 + (end % 2.0 > 0)
    assert [f.driving for f in frames] == [f.t <= DURATION for f in frames]
    for f in frames:
        for i, route in enumerate(routes):
            np.testing.assert_allclose(f.positions[i], _position_at(route, f.t))
        # A full network links the pair at every moment.
        np.testing.assert_array_equal(f.links, [[0, 1]])
        assert (f.held <= f.others).all()
    assert frames[0].bytes_sent <= frames[-1].bytes_sent
    assert all(a.bytes_sent <= b.bytes_sent for a, b in itertools.pairwise(frames))
    assert frames[-1].bytes_sent == sum(e.stats.bytes_sent for e in full_team.exchangers)
    # Once the network is quiet every robot holds the other's poses.
    last = frames[-1]
    assert full_team.summary["identical_maps"] is True
    np.testing.assert_array_equal(last.held, last.others)
    assert (last.others > 0).all()
    assert full_team.robots[0].frames  # the agents' own frames are kept too


def test_a_limited_network_shows_meeting_and_parting_within_the_frame_cap(
    plan: OccupancyMap,
) -> None:
    r_max = 3.0
    team = _run(
        plan,
        NetworkParams(kind="limited", r_max=r_max),
        towards=True,
        frame_every=1.0,
        max_frames=12,
        settle=10,
    )
    frames = team.team_frames
    assert 2 <= len(frames) <= 12
    assert frames[-1].t == pytest.approx(DURATION + team.summary["settle_seconds"])
    linked = []
    for f in frames:
        d = float(np.hypot(*(f.positions[0] - f.positions[1])))
        # The corridor gives a line of sight: a link exactly when in range.
        assert len(f.links) == (d <= r_max)
        linked.append(len(f.links) > 0)
    assert linked[0] is False
    assert any(linked)
    assert linked[-1] is False


def test_the_team_gif_has_every_frame_and_shows_the_robots(
    tmp_path: Path, plan: OccupancyMap, full_team: TeamResult
) -> None:
    frames = full_team.team_frames
    out = save_team_animation(plan, frames, tmp_path / "team.gif", title="test")
    assert out == tmp_path / "team.gif"
    with Image.open(out) as gif:
        pictures = [
            np.asarray(p.convert("RGB"), dtype=np.int64) for p in ImageSequence.Iterator(gif)
        ]
    assert len(pictures) == len(frames)
    first, last = pictures[0], pictures[-1]
    assert first.std() > 20  # not one flat colour
    assert not np.array_equal(first, last)  # the robots moved
    for rgb in ((31, 119, 180), (255, 127, 14)):  # tab10's first two: robots 0 and 1
        near = np.abs(last - np.array(rgb)).sum(axis=2) < 40
        assert near.sum() > 50


def test_save_team_animation_refuses_what_it_cannot_write(
    tmp_path: Path, plan: OccupancyMap
) -> None:
    frame = TeamFrame(
        0.0,
        True,
        np.zeros((2, 2)),
        np.zeros((0, 2), dtype=np.int64),
        np.zeros(2, dtype=np.int64),
        np.zeros(2, dtype=np.int64),
        0,
    )
    with pytest.raises(ConfigError, match=r"must be a \.gif or \.mp4"):
        save_team_animation(plan, [frame], tmp_path / "team.avi")
    with pytest.raises(ConfigError, match="no frames"):
        save_team_animation(plan, [], tmp_path / "team.gif")
    with pytest.raises(ValueError, match="frame_every"):
        _run(plan, NetworkParams(), frame_every=0.0)
    with pytest.raises(ValueError, match="max_frames"):
        _run(plan, NetworkParams(), max_frames=1)
    assert not list(tmp_path.iterdir())


def test_team_run_animate_writes_team_gif(tmp_path: Path, plan: OccupancyMap) -> None:
    write_map(plan, tmp_path / "plan")
    out = tmp_path / "out"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--robots", "2",
          "--duration", "6", "--animate", "-o", str(out)])  # fmt: skip
    with Image.open(out / "team.gif") as gif:
        assert getattr(gif, "n_frames", 1) > 1
    for robot in (0, 1):
        assert (out / f"mission_robot{robot}.gif").stat().st_size > 0
