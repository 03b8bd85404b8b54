"""The gradient method's robust form (issue 14, "Outliers"): per-term weights re-estimated
from leave-one-out residuals through the saturating penalty rho(r) = tau r / (tau + r)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers._forward import ForwardProblem, robust_cost, robust_weights
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.metrics import observed_walls, score
from sonarmap.readings import Readings
from sonarmap.rig import get_rig
from sonarmap.scenarios import make_scenario
from sonarmap.sensors import SensorModel

SENSOR: SensorModel = get_rig("paper-synthetic").sensor
#: 3.5 m x 3 m at 5 cm around a sonar at the origin looking along +x (as in
#: tests/test_seed_pieces.py, thesis 002's toy case).
GRID = Grid(resolution=0.05, origin=(-0.5, -1.5), shape=(60, 70))
#: Thesis 002 section 4.6: from one place, ten readings at 2 m and one (the sixth) at 1 m.
TOY = [2.0] * 5 + [1.0] + [2.0] * 5
#: The model's constants when the robust form was tuned (before the band offset): the
#: mechanism below is worked out with them.
BEFORE: dict[str, Any] = {
    "a1": 0.2,
    "a2": 0.03,
    "c2": 0.3,
    "band_offset": 0.0,
    "no_echo": "free",
}


def one_place(ranges: list[float]) -> Readings:
    n = len(ranges)
    z = np.zeros(n)
    return Readings(
        np.arange(n, dtype=np.float64), np.zeros(n, np.int32), z, z, z, np.array(ranges), ("s",)
    )


def near_1m() -> npt.NDArray[np.bool_]:
    xs = GRID.origin[0] + (np.arange(GRID.cols) + 0.5) * GRID.resolution
    ys = GRID.origin[1] + (np.arange(GRID.rows) + 0.5) * GRID.resolution
    x, y = np.meshgrid(xs, ys)
    return np.asarray(np.abs(np.hypot(x, y).ravel() - 1.0) <= 0.1)


def toy_problem() -> ForwardProblem:
    return GradientMapper(**BEFORE).start(GRID, SENSOR).problem(one_place(TOY))


def outlier_row(p: ForwardProblem) -> int:
    return int((~p.is_occ).sum()) + 5


def test_weights_scale_each_term_as_the_formula_says() -> None:
    """S_v(x) = sum_t v_t P_t(W_t x) + R(x), and its subgradient W^T (v P') + R'."""
    p = toy_problem()
    rng = np.random.default_rng(0)
    v = rng.uniform(0.1, 1.0, p.n_terms)
    pv = dataclasses.replace(p, v=v)
    x = rng.uniform(0.05, 0.95, p.n_cells)
    X = p.W @ x
    reg = p.value(x) - float(np.sum(p.term_values(X)))
    assert pv.value(x) == pytest.approx(float(np.sum(v * p.term_values(X))) + reg)
    np.testing.assert_allclose(pv.grad(x), p.WT @ (v * p.term_slopes(X)) + p.reg_grad(x))
    r = np.array([0.0, 0.1, 1.0])
    np.testing.assert_allclose(robust_cost(r, 0.1), [0.0, 0.05, 0.1 / 1.1])


def test_leave_one_out_residual_flags_the_lone_short_reading() -> None:
    """At the plain map every occ term is explained (its own P is under 0.05); the 1 m
    reading's band is seen through by the ten 2 m beams and no other band covers it, so
    its leave-one-out residual is 1 and its weight (tau / (1 + tau))^2; the 2 m bands
    share their cells, so their residual is about 0 and their weight about 1."""
    p = toy_problem()
    m = GradientMapper(robust=0.0, **BEFORE).fit(one_place(TOY), GRID, SENSOR)
    x = np.nan_to_num(m.occupancy_.ravel()[p.cells], nan=0.5).astype(np.float64)
    row = outlier_row(p)
    assert p.term_values(p.W @ x)[row] < 0.05
    tau = 0.3
    v = robust_weights(p, x, tau)
    assert v[row] == pytest.approx((tau / (1 + tau)) ** 2)
    np.testing.assert_allclose(np.delete(v, row), 1.0, atol=1e-3)
    # With free terms too, each keeps tau^2 / (tau + P_free)^2, P_free its own value.
    both = robust_weights(p, x, tau, terms="both")
    free = ~p.is_occ
    want = tau**2 / (tau + p.term_values(p.W @ x)[free]) ** 2
    np.testing.assert_allclose(both[free], want)


def test_a_single_short_outlier_no_longer_plants_an_obstacle() -> None:
    """The plain model explains the 1 m reading with one echo's worth of obstacle area
    (pgd spreads it below 0.5, ccp concentrates it into occupied cells); the robust form
    does not. Explaining it costs the ten free terms 10 a1 X0_free (0.003 here) against
    the outlier's weighted cost v = (tau / (1 + tau))^2 of staying unexplained, so the
    exact solver keeps it for tau = 0.1 (v = 0.008) and drops it for tau = 0.05
    (v = 0.0023), as the formula says."""
    readings = one_place(TOY)
    near = near_1m()
    p = toy_problem()
    row = outlier_row(p)
    x0_free = float(p.X0[~p.is_occ][0])
    assert 10 * 0.2 * x0_free == pytest.approx(0.003, abs=3e-4)

    def echo_share(m: GradientMapper) -> float:
        x = np.nan_to_num(m.occupancy_.ravel()[p.cells], nan=0.5).astype(np.float64)
        return float((p.W @ x)[row] / p.X0[row])

    def occupied(m: GradientMapper) -> int:
        return int(np.sum(np.nan_to_num(m.occupancy_.ravel()[near]) > 0.5))

    def fit(**params: Any) -> GradientMapper:
        return GradientMapper(**{**BEFORE, **params}).fit(readings, GRID, SENSOR)

    plain = fit(robust=0.0)
    robust = fit(robust=0.3)
    default = fit()
    assert echo_share(plain) > 0.95
    assert echo_share(robust) < 0.1
    assert robust.term_weights_[row] < 0.06
    assert echo_share(default) < 0.1
    assert occupied(fit(solver="ccp", robust=0.0)) > 0
    assert occupied(fit(solver="ccp", robust=0.1)) > 0
    assert occupied(fit(solver="ccp", robust=0.05)) == 0
    # The 2 m wall stays in every case.
    assert np.sum(np.nan_to_num(robust.occupancy_) > 0.5) > 0


def test_robust_parameters_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"parameter 'robust' must be in \[0.0, inf\]"):
        GradientMapper(robust=-1.0)
    with pytest.raises(ConfigError, match=r"parameter 'robust_terms' must be one of occ, both"):
        GradientMapper(robust_terms="free")
    with pytest.raises(ConfigError, match=r"parameter 'robust_rounds' must be >= 1"):
        GradientMapper(robust_rounds=0)
    with pytest.raises(ConfigError, match=r"parameter 'robust_support' must be in \[0.0, inf\]"):
        GradientMapper(robust_support=-0.5)


def test_correlated_readings_from_one_pose_count_as_one() -> None:
    """Ten equal readings from one pose each weigh 1 / 10 (Konolige 1997): their terms
    together weigh what one reading's do, ten times less than the lone 1 m reading's;
    the weights are scaled to mean 1 over the readings (11 / 2 here)."""
    readings = one_place(TOY)
    plain = GradientMapper(robust=0.0).start(GRID, SENSOR).problem(readings)
    corr = GradientMapper(robust=0.0, correlated=0.05).start(GRID, SENSOR).problem(readings)
    assert corr.v is not None
    assert corr.reading is not None
    want = np.where(corr.reading == 5, 1.0, 0.1) * 11 / 2
    np.testing.assert_allclose(corr.v, want)
    x = np.random.default_rng(1).uniform(0.0, 1.0, plain.n_cells)
    X = plain.W @ x
    np.testing.assert_allclose(corr.term_values(X), want * plain.term_values(X))
    m = GradientMapper(robust=0.0, correlated=0.05).fit(readings, GRID, SENSOR)
    np.testing.assert_allclose(m.term_weights_, want)
    with pytest.raises(ConfigError, match=r"parameter 'correlated' must be in \[0.0, inf\]"):
        GradientMapper(correlated=-0.1)


def test_at_todays_defaults_the_tent_keeps_pgd_from_the_outlier() -> None:
    """With c2 = 1 (sweeps/band.yaml) the tent's pull, c2 per cell, is more than the lone
    1 m reading's pull on any cell of its band (at most w0 <= 1), so pgd takes the band
    towards 0 before the echo is explained, robust form or not; the exact solver still
    explains it: the optimum keeps the obstacle, the descent does not reach it."""
    readings = one_place(TOY)
    near = near_1m()
    for robust in (0.0, 0.03):
        m = GradientMapper(robust=robust).fit(readings, GRID, SENSOR)
        p = m.problem(readings)
        x = np.nan_to_num(m.occupancy_.ravel()[p.cells], nan=0.5).astype(np.float64)
        assert (p.W @ x)[outlier_row(p)] < 0.3 * p.X0[outlier_row(p)]
        assert np.sum(np.nan_to_num(m.occupancy_.ravel()[near]) > 0.5) == 0
        assert np.sum(np.nan_to_num(m.occupancy_) > 0.5) > 0
    exact = GradientMapper(robust=0.0, solver="ccp").fit(readings, GRID, SENSOR)
    assert np.sum(np.nan_to_num(exact.occupancy_.ravel()[near]) > 0.5) > 0


def scale_claim(band_offset: float | None) -> None:
    """The claim of the tests below: on the training ``doorways`` scene (seed 0, the
    MaxSonar rig) the default tau (0.1) keeps more of the walls the sonars heard than the
    former 0.03 (by more than 0.03 of observed-wall recall) and detects at least as many
    of its doors, both maps with the band ``band_offset`` behind the echo (None: the
    mapper's default)."""
    scene = make_scenario("doorways", seed=0)
    observed = observed_walls(scene.truth, scene.rig, scene.readings)

    def scored(**params: Any) -> tuple[float, float]:
        m = GradientMapper(band_offset=band_offset, **params)
        m.fit(scene.readings, scene.truth.grid, scene.rig)
        s = score(scene.truth, m.result(), scene.passages, scene.obstacles, observed)
        d = s.as_dict()
        return float(d["observed_wall_recall"]), float(d["passage_f1"])

    assert GradientMapper().robust == 0.1
    walls_new, doors_new = scored()
    walls_old, doors_old = scored(robust=0.03)
    assert walls_new > walls_old + 0.03
    assert doors_new >= doors_old


def test_default_scale_keeps_walls_the_former_one_emptied_at_the_band_of_the_time() -> None:
    """Issue 39, sixth pass: 0.904 against 0.841 of the observed walls in
    sweeps/rigs6-robust.yaml, with the band half a cell behind the echo (the default
    then, before 2026-12-07), which both maps here keep. Why was not measured term by
    term; one hypothesis is that a lower tau down-weights a wide beam's wall readings
    whose band the other readings see through."""
    scale_claim(band_offset=0.025)


@pytest.mark.xfail(
    strict=True,
    reason="at the band three quarters of a cell behind the echo (the default since "
    "2026-12-07) tau 0.1 detects fewer of this scene's doors than 0.03 (passage F1 0.5 "
    "against 0.667); tau was not re-chosen at the new band",
)
def test_default_scale_keeps_walls_the_former_one_emptied_at_the_default_band() -> None:
    scale_claim(band_offset=None)
