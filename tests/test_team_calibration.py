"""The odometry's heading bias, measured on the pose graph and taken out of the edges
(:mod:`sonarmap.team.calibration`), and a robot alone that calibrates itself."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sonarmap.io.rosmap import OccupancyMap
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.calibration import (
    calibrated_bias,
    debias,
    debias_edges,
    heading_bias_fit,
    heading_bias_step,
)
from sonarmap.team.mission import MissionConfig, RobotAgent, run_mission
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


def test_the_bias_step_is_taken_only_when_significant() -> None:
    truth = _loop()
    lengths = np.array([math.hypot(*e.transform[:2]) for e in _edges(truth, 0.0)])
    # Heading noise of 0.01 rad per edge, made orthogonal to the lengths: it alone
    # fits a slope of 0 with a standard error above 0.
    noise = np.random.default_rng(5).normal(0.0, 0.01, len(lengths))
    noise -= (noise @ lengths) / (lengths @ lengths) * lengths

    def noisy(bias: float) -> list[OdometryEdge]:
        return [
            replace(e, transform=(e.transform[0], e.transform[1], e.transform[2] + n))
            for e, n in zip(_edges(truth, bias), noise, strict=True)
        ]

    fit = heading_bias_fit(noisy(0.0), truth)
    assert fit.edges == len(lengths)
    assert abs(fit.step) < 1e-6
    assert 0.0 < fit.stderr < 0.01
    assert calibrated_bias(0.0, noisy(0.0), truth) == 0.0
    # A bias of 1.5 standard errors is not applied, one of 3 is.
    se = fit.stderr
    assert calibrated_bias(0.0, noisy(1.5 * se), truth) == 0.0
    assert calibrated_bias(0.0, noisy(3 * se), truth) == pytest.approx(3 * se, rel=0.05)
    # The edges corrected by 3 standard errors: the step is 0 and the estimate stays;
    # corrected by 3 where there is none, the estimate is taken back to 0.
    assert calibrated_bias(3 * se, debias_edges(noisy(3 * se), 3 * se), truth) == (
        pytest.approx(3 * se, rel=0.05)
    )
    assert calibrated_bias(3 * se, debias_edges(noisy(0.0), 3 * se), truth) == 0.0
    # No edge with a length: nothing to fit.
    assert heading_bias_fit([], truth).stderr == math.inf


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def _agent(
    plan: OccupancyMap, calibrate: bool, run: bool = True, sim_bias: float | None = None
) -> RobotAgent:
    cfg = MissionConfig(duration=300.0, seed=1)
    noise = dict(ODOMETRY_NOISE)
    if sim_bias is not None:
        noise["bias_theta"] = sim_bias
    agent = RobotAgent(
        plan,
        cfg,
        route=patrol_route(plan, 300.0, seed=1, style="waypoints"),
        world=make_world(plan, seed=1, duration=300.0, faces="all"),
        calibrate=calibrate,
        odometry_noise=noise,
    )
    if run:
        agent.run()
    return agent


def _stored_bias(agent: RobotAgent) -> float:
    """The heading bias left in the robot's stored odometry edges, against the truth."""
    return heading_bias_fit(agent.store.local.edges, agent.truth).step


def test_a_robot_alone_takes_its_odometrys_bias_out_of_its_edges(plan: OccupancyMap) -> None:
    alone = _agent(plan, calibrate=True)
    fixed = _agent(plan, calibrate=False)
    s, s0 = alone.finish().summary, fixed.finish().summary
    # The simulator turns bias_theta rad per metre; the robot was never told.
    true_bias = ODOMETRY_NOISE["bias_theta"]
    assert s["odometry_heading_bias"] == pytest.approx(true_bias, rel=0.35), s[
        "odometry_heading_bias"
    ]
    assert s["parameters"]["calibrate_odometry"] is True
    assert s0["odometry_heading_bias"] == 0.0
    assert s0["parameters"]["calibrate_odometry"] is False
    # The edges as stored (composed ones included) against the truth: the bias is in
    # the uncalibrated robot's and out of the calibrated one's.
    assert _stored_bias(fixed) > 0.002, _stored_bias(fixed)
    assert abs(_stored_bias(alone)) < 0.0008, _stored_bias(alone)
    # The calibration survives a checkpoint, and a robot that does not calibrate does
    # not take it back.
    state = alone.state()
    assert state["heading_bias"] == s["odometry_heading_bias"]
    again = _agent(plan, calibrate=True, run=False)
    again.restore(state)
    assert again.heading_bias == alone.heading_bias
    other = _agent(plan, calibrate=False, run=False)
    other.restore(state)
    assert other.heading_bias == 0.0


def test_an_odometry_without_the_bias_is_left_as_measured(plan: OccupancyMap) -> None:
    alone = _agent(plan, calibrate=True, sim_bias=0.0)
    assert abs(alone.heading_bias) < 0.001, alone.heading_bias
    # Not significant on the final graph: every edge is the odometry's own again.
    s = alone.finish().summary
    assert s["odometry_heading_bias"] == 0.0, s["odometry_heading_bias"]
    assert abs(_stored_bias(alone)) < 0.0008, _stored_bias(alone)


def test_a_robot_agent_calibrates_only_when_asked_and_run_mission_does(
    plan: OccupancyMap,
) -> None:
    cfg = MissionConfig(duration=60.0, seed=1)
    assert RobotAgent(plan, cfg).calibrate is False
    r = run_mission(plan, cfg)
    assert r.summary["parameters"]["calibrate_odometry"] is True
