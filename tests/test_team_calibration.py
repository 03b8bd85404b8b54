"""The odometry's heading bias, measured on the pose graph and taken out of the edges
(:mod:`sonarmap.team.calibration`), and a robot alone that calibrates itself."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from benchmarks.calibration_gate_null import ar1

from sonarmap.errors import InputError
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.calibration import (
    HEADING_BIAS_PRIOR,
    MIN_BATCHES,
    SIGNIFICANCE,
    BiasFit,
    batches,
    bias_fit,
    calibrated_bias,
    critical_value,
    debias,
    debias_edges,
    gated_bias,
    heading_bias_fit,
    heading_bias_step,
    remaining_bias_sd,
    slope_stderr,
)
from sonarmap.team.mission import BiasSd, MissionConfig, RobotAgent, run_mission
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
    # 159 edges: five batches, the fewest whose fit the gate applies.
    truth = _loop(160)
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
    assert fit.dof == batches(len(lengths)) - 1 == MIN_BATCHES - 1
    assert calibrated_bias(0.0, noisy(0.0), truth) == 0.0
    # A bias of 0.75 the gate's threshold is not applied, one of 1.5 is.
    gate = critical_value(fit.dof) * max(fit.stderr, fit.stderr_iid)
    assert calibrated_bias(0.0, noisy(0.75 * gate), truth) == 0.0
    assert calibrated_bias(0.0, noisy(1.5 * gate), truth) == pytest.approx(1.5 * gate, rel=0.05)
    # The edges corrected by it: the step is 0 and the estimate stays; corrected by it
    # where there is none, the estimate is taken back to 0.
    assert calibrated_bias(1.5 * gate, debias_edges(noisy(1.5 * gate), 1.5 * gate), truth) == (
        pytest.approx(1.5 * gate, rel=0.05)
    )
    assert calibrated_bias(1.5 * gate, debias_edges(noisy(0.0), 1.5 * gate), truth) == 0.0
    # No edge with a length: nothing to fit.
    assert heading_bias_fit([], truth).stderr == math.inf


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def _agent(
    plan: OccupancyMap,
    calibrate: bool,
    run: bool = True,
    sim_bias: float | None = None,
    bias_sd: BiasSd = "prior",
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
        bias_sd=bias_sd,
    )
    if run:
        agent.run()
    return agent


def _stored_bias(agent: RobotAgent) -> float:
    """The heading bias left in the robot's stored odometry edges, against the truth."""
    return heading_bias_fit(agent.store.local.edges, agent.truth).step


def test_a_robot_alone_takes_its_odometrys_bias_out_of_its_edges(plan: OccupancyMap) -> None:
    alone = _agent(plan, calibrate=True, bias_sd="remaining")
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
    # Told to, the new edges' covariance counts what the calibration leaves of the
    # bias, not the robot's prior (which a robot that does not calibrate keeps).
    assert fixed.heading_bias_sd == HEADING_BIAS_PRIOR
    assert 0.0 < alone.heading_bias_sd < HEADING_BIAS_PRIOR / 3, alone.heading_bias_sd
    # The calibration survives a checkpoint, and a robot that does not calibrate does
    # not take it back.
    state = alone.state()
    assert state["heading_bias"] == s["odometry_heading_bias"]
    again = _agent(plan, calibrate=True, run=False, bias_sd="remaining")
    again.restore(state)
    assert again.heading_bias == alone.heading_bias
    assert again.heading_bias_sd == alone.heading_bias_sd
    assert again.calibration_batches == alone.calibration_batches > 0
    other = _agent(plan, calibrate=False, run=False)
    other.restore(state)
    assert other.heading_bias == 0.0


def test_a_calibrating_robot_keeps_the_priors_variance_by_default(plan: OccupancyMap) -> None:
    held = _agent(plan, calibrate=True)
    # The estimate still corrects the edges...
    true_bias = ODOMETRY_NOISE["bias_theta"]
    assert held.heading_bias == pytest.approx(true_bias, rel=0.35), held.heading_bias
    assert held.calibration_batches_applied > 0
    assert abs(_stored_bias(held)) < 0.0008, _stored_bias(held)
    # ...but the new edges' covariance keeps the prior, through a checkpoint too.
    assert held.heading_bias_sd == HEADING_BIAS_PRIOR
    again = _agent(plan, calibrate=True, run=False)
    again.restore(held.state())
    assert again.heading_bias_sd == HEADING_BIAS_PRIOR
    assert again.heading_bias == held.heading_bias
    with pytest.raises(InputError, match="bias_sd"):
        RobotAgent(plan, MissionConfig(duration=60.0, seed=1), bias_sd="both")  # type: ignore[arg-type]


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


def test_the_gate_fires_under_twice_its_nominal_level_on_correlated_residuals() -> None:
    rng = np.random.default_rng(11)
    draws, n = 400, 300
    fired = fired_iid = found = 0
    for _ in range(draws):
        d = rng.uniform(0.5, 1.0, n)
        # No bias: heading residuals correlated along the route (lag-one 0.9), as an
        # optimised graph's are.
        fit = bias_fit(d, ar1(rng, n, 0.9))
        fired += gated_bias(0.0, fit) != 0.0
        fired_iid += abs(fit.step) > SIGNIFICANCE * fit.stderr_iid
        # A bias of 0.03 rad per metre in the same noise (about 8 standard errors).
        fit = bias_fit(d, -0.03 * d + ar1(rng, n, 0.9))
        found += gated_bias(0.0, fit) == pytest.approx(0.03, abs=0.015)
    # The gate's nominal level is 4.6 %; at 300 edges (7 batches) it fires more often
    # (6.6 % over 1,500 draws: python -m benchmarks.calibration_gate_null), so the bound
    # is about twice nominal. The error that takes the residuals as independent lets
    # about 60 % through.
    assert fired / draws < 0.09, fired
    assert fired_iid / draws > 0.4, fired_iid
    assert found / draws > 0.9, found
    # The same through the edges: a route whose odometry's heading has that noise.
    truth = _loop(n + 1)
    edges = [
        replace(e, transform=(e.transform[0], e.transform[1], e.transform[2] + v))
        for e, v in zip(_edges(truth, 0.0), ar1(rng, n, 0.9), strict=True)
    ]
    fit = heading_bias_fit(edges, truth)
    lengths = np.array([math.hypot(*e.transform[:2]) for e in edges])
    residuals = np.array([truth[e.b][2] - truth[e.a][2] - e.transform[2] for e in edges])
    again = bias_fit(lengths, np.remainder(residuals + math.pi, 2 * math.pi) - math.pi)
    assert (fit.edges, fit.dof) == (again.edges, again.dof) == (n, batches(n) - 1)
    assert (fit.step, fit.stderr, fit.stderr_iid) == pytest.approx(
        (again.step, again.stderr, again.stderr_iid), rel=1e-4
    )


def _cancelling(rng: np.random.Generator, d: np.ndarray, count: int) -> np.ndarray:
    """Heading noise (0.01 rad) whose scores ``d * e`` sum to 0 within each of ``count``
    batches, as an optimised graph's residuals nearly do over a closure's stretch."""
    e = rng.normal(0.0, 0.01, len(d))
    for part in np.array_split(np.arange(len(d)), count):
        dk = d[part]
        e[part] -= (e[part] @ dk) / (dk @ dk) * dk
    return e


def test_the_gate_does_not_fire_when_the_batch_sums_cancel() -> None:
    rng = np.random.default_rng(7)
    # 74 edges, 4 batches (the 300 s office mission's third batch): whatever the step,
    # the batch-means error is about 0 and the gate must not take the fit.
    d = rng.uniform(0.5, 1.0, 74)
    assert batches(74) == MIN_BATCHES - 1
    fit = bias_fit(d, -0.001 * d + _cancelling(rng, d, 4))
    assert fit.step == pytest.approx(0.001)
    assert fit.stderr < 1e-3 * fit.stderr_iid
    assert abs(fit.step) > 10 * critical_value(fit.dof) * fit.stderr
    assert gated_bias(0.0, fit) == 0.0
    # Too few batches leave an estimate applied earlier as it is.
    assert gated_bias(0.002, fit) == 0.002
    # 300 edges, 7 batches, the sums cancelling again: the ordinary error is the floor.
    d = rng.uniform(0.5, 1.0, 300)
    e = _cancelling(rng, d, batches(300))
    floor = critical_value(batches(300) - 1) * bias_fit(d, e).stderr_iid
    assert bias_fit(d, e).stderr < 1e-3 * bias_fit(d, e).stderr_iid
    assert gated_bias(0.0, bias_fit(d, -0.75 * floor * d + e)) == 0.0
    assert gated_bias(0.0, bias_fit(d, -1.5 * floor * d + e)) == pytest.approx(1.5 * floor)


def test_the_batch_means_error_counts_whole_stretches() -> None:
    d = np.ones(12)
    # Residuals constant over each third: four edges agree, so they count as one.
    e = np.repeat([1.0, -2.0, 1.0], 4) * 1e-3
    # Batch sums 4, -8, 4 (x 1e-3); B / (B - 1) = 1.5; sum d^2 = 12.
    assert slope_stderr(d, e, 3) == pytest.approx(math.sqrt(1.5 * 96e-6) / 12)
    assert slope_stderr(d, e, 1) == math.inf
    assert critical_value(10_000) == pytest.approx(2.0, abs=0.01)
    assert critical_value(2) > 4.0
    assert critical_value(0) == math.inf


def test_the_edges_covariance_counts_what_the_calibration_leaves() -> None:
    fit = BiasFit(step=0.001, stderr=0.0002, edges=100, dof=4)
    # Applied: only its error is left; not applied: the estimate counts in full.
    assert remaining_bias_sd(0.002, fit, 0.003) == pytest.approx(0.0002)
    assert remaining_bias_sd(0.002, fit, 0.0) == pytest.approx(math.hypot(0.003, 0.0002))
    # Before any fit with an error, the prior.
    assert remaining_bias_sd(0.0, BiasFit(0.0, math.inf, 0), 0.0) == HEADING_BIAS_PRIOR
