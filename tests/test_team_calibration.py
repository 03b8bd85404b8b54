"""The odometry's heading bias, measured on the pose graph and taken out of the edges
(:mod:`sonarmap.team.calibration`), and a robot alone that calibrates itself."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarmap.io.rosmap import OccupancyMap
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.calibration import debias, debias_edges, heading_bias_step
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.records import OdometryEdge, compose, invert
from sonarmap.team.world import ODOMETRY_NOISE, make_world, patrol_route

COV = tuple(np.diag([1e-4, 1e-4, 1e-5]).ravel().tolist())


def _biased(true_step: np.ndarray, bias: float) -> tuple[float, float, float]:
    """What an odometry turning ``bias`` rad per metre measures for a true step: the
    inverse of :func:`debias`."""
    x, y, theta = (float(v) for v in true_step)
    turn = bias * math.hypot(x, y)
    c, s = math.cos(turn / 2), math.sin(turn / 2)
    return (c * x - s * y, s * x + c * y, theta + turn)


def _loop(n: int = 40) -> dict[int, np.ndarray]:
    """True poses about a 6 x 4 m rectangle-ish loop, 0.5-1 m apart."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    x, y = 3.0 * np.cos(t), 2.0 * np.sin(t)
    theta = np.arctan2(np.gradient(y), np.gradient(x)) + rng.normal(0, 0.05, n)
    return {i: np.array([x[i], y[i], theta[i]]) for i in range(n)}


def _edges(truth: dict[int, np.ndarray], bias: float) -> list[OdometryEdge]:
    out = []
    for a in range(len(truth) - 1):
        step = compose(invert(truth[a]), truth[a + 1])
        out.append(OdometryEdge(a, a + 1, _biased(step, bias), COV, 5.0))
    return out


def test_debias_takes_the_turn_per_metre_out_of_a_step() -> None:
    x, y, theta = debias((2.0, 0.0, 0.1), 0.01)
    # 2 m at 0.01 rad per metre: 0.02 rad less turn, the chord turned back by half.
    assert theta == pytest.approx(0.08)
    assert math.hypot(x, y) == pytest.approx(2.0)
    assert math.atan2(y, x) == pytest.approx(-0.01)
    # A turn on the spot has no length, so no bias.
    assert debias((0.0, 0.0, 0.5), 0.01) == (0.0, 0.0, 0.5)


def test_the_bias_step_recovers_a_bias_and_vanishes_once_it_is_taken_out() -> None:
    truth = _loop()
    edges = _edges(truth, 0.004)
    # The estimates are right (closures put them there); the edges are biased.
    assert heading_bias_step(edges, truth) == pytest.approx(0.004, rel=1e-3)
    corrected = debias_edges(edges, 0.004)
    assert abs(heading_bias_step(corrected, truth)) < 1e-6
    # Each corrected edge is the true step again (float32 records).
    for e in corrected:
        true = compose(invert(truth[e.a]), truth[e.b])
        assert np.allclose(e.transform, true, atol=1e-5)
    # A negative bias, and edges naming a pose with no estimate, skipped.
    edges = _edges(truth, -0.002)
    some = {u: p for u, p in truth.items() if u % 2 == 0 or u < 10}
    assert heading_bias_step(edges, some) == pytest.approx(-0.002, rel=1e-3)
    assert heading_bias_step(edges, {}) == 0.0
    assert debias_edges(edges, 0.0) == edges


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def _agent(plan: OccupancyMap, calibrate: bool, run: bool = True) -> RobotAgent:
    cfg = MissionConfig(duration=300.0, seed=1)
    agent = RobotAgent(
        plan,
        cfg,
        route=patrol_route(plan, 300.0, seed=1, style="waypoints"),
        world=make_world(plan, seed=1, duration=300.0, faces="all"),
        calibrate=calibrate,
    )
    if run:
        agent.run()
    return agent


def test_a_robot_alone_finds_its_odometrys_bias_and_the_trajectory_gains(
    plan: OccupancyMap,
) -> None:
    alone = _agent(plan, calibrate=True)
    fixed = _agent(plan, calibrate=False)
    s, s0 = alone.finish().summary, fixed.finish().summary
    # The simulator turns bias_theta rad per metre; the robot was never told.
    true_bias = ODOMETRY_NOISE["bias_theta"]
    assert s["odometry_heading_bias"] == pytest.approx(true_bias, rel=0.35), s[
        "odometry_heading_bias"
    ]
    assert s0["odometry_heading_bias"] == 0.0
    assert s["ate_m"] < s0["ate_m"], (s["ate_m"], s0["ate_m"])
    # The calibration survives a checkpoint.
    state = alone.state()
    assert state["heading_bias"] == s["odometry_heading_bias"]
    again = _agent(plan, calibrate=True, run=False)
    again.restore(state)
    assert again.heading_bias == alone.heading_bias
