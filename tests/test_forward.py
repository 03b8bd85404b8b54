"""Forward-model mappers: their objective, solvers, determinism and parameter checks."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.mappers import make_mapper
from sonarmap.mappers._forward import ForwardProblem
from sonarmap.mappers.em import EMMapper
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.mappers.stochastic import StochasticMapper
from sonarmap.readings import Readings
from sonarmap.scenarios import PAPER_NOISE, Scenario, make_scenario


@pytest.fixture(scope="module")
def small() -> Scenario:
    """A short corridor: few readings, fast to solve every way. Read exactly, with the
    papers' model: these tests check the solvers, not how good a method's maps are."""
    return make_scenario(
        "doorways",
        size=4.0,
        corridor_width=1.6,
        door_widths=(0.8,),
        speed=0.5,
        model=PAPER_NOISE["doorways"],
    )


def problem(scene: Scenario) -> ForwardProblem:
    m = GradientMapper().start(scene.truth.grid, scene.rig)
    return m.problem(scene.readings)


def test_objective_pieces(small: Scenario) -> None:
    p = problem(small)
    assert p.n_terms > 0
    assert p.n_cells > 0
    # Normalised rows: every term's weights sum to 1.
    np.testing.assert_allclose(np.asarray(p.W.sum(axis=1)).ravel(), 1.0)
    # P_free(1) = 1 and P_occ(1) = 0 where X0 < 1, as the notes require.
    ok = p.X0 < 1
    vals = p.term_values(np.ones(p.n_terms))
    np.testing.assert_allclose(vals[ok & ~p.is_occ], 1.0)
    np.testing.assert_allclose(vals[ok & p.is_occ], 0.0, atol=1e-12)
    # Continuity at X0.
    below, above = p.slopes()
    x0 = p.X0
    left = p.term_values(x0 - 1e-9)
    right = p.term_values(x0 + 1e-9)
    np.testing.assert_allclose(left, right, atol=1e-6)
    assert np.all(below[~p.is_occ] > 0)
    assert np.all(above[p.is_occ] < 0)


def test_gradient_matches_finite_differences(small: Scenario) -> None:
    p = problem(small)
    rng = np.random.default_rng(0)
    x = rng.uniform(0.05, 0.95, p.n_cells)
    g = p.grad(x)
    for j in rng.choice(p.n_cells, 10, replace=False):
        e = np.zeros(p.n_cells)
        e[j] = 1e-7
        fd = (p.value(x + e) - p.value(x - e)) / 2e-7
        assert g[j] == pytest.approx(fd, rel=1e-3, abs=1e-3)


@pytest.mark.parametrize("solver", ["gd", "pgd", "lbfgs", "ccp"])
def test_every_solver_lowers_the_objective_and_opens_the_door(small: Scenario, solver: str) -> None:
    m = GradientMapper(solver=solver).fit(small.readings, small.truth.grid, small.rig)
    start = problem(small).value(np.full(problem(small).n_cells, 0.5))
    assert m.objective_ < start
    from sonarmap.metrics import passage_open

    assert passage_open(small.truth, m.result(), small.passages[0])


def test_untouched_cells_stay_unknown(small: Scenario) -> None:
    occ = make_mapper("gradient").fit(small.readings, small.truth.grid, small.rig).occupancy_
    p = problem(small)
    known = np.isfinite(occ).ravel()
    assert set(np.flatnonzero(known).tolist()) == set(p.cells.tolist())


def test_em_likelihood_never_decreases(small: Scenario) -> None:
    m = EMMapper(max_iter=40, tol=0.0).fit(small.readings, small.truth.grid, small.rig)
    ll = np.array(m.loglik_)
    assert len(ll) == 40
    assert np.all(np.diff(ll) >= -1e-6 * np.abs(ll[:-1]))
    post = m.occupancy_[np.isfinite(m.occupancy_)]
    assert np.all((post >= 0) & (post <= 1))


def test_stochastic_is_deterministic_with_a_seed(small: Scenario) -> None:
    def run(seed: int) -> np.ndarray:
        m = make_mapper("stochastic", seed=seed, schedule="anneal", sweeps=5)
        return m.fit(small.readings, small.truth.grid, small.rig).occupancy_

    a, b, c = run(1), run(1), run(2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(np.nan_to_num(a), np.nan_to_num(c))


def test_stochastic_presets() -> None:
    assert StochasticMapper().values() == {
        "p_rand": 0.05,
        "p_hit": 0.3,
        "w_occ": 0.0,
        "w_border": -0.005,
    }
    assert StochasticMapper(preset="thesis000").values() == {
        "p_rand": 0.05,
        "p_hit": 0.75,
        "w_occ": -0.05,
        "w_border": -0.005,
    }
    v = StochasticMapper(preset="thesis002", w_occ=-0.1).values()
    assert v == {"p_rand": 0.001, "p_hit": 0.35, "w_occ": -0.1, "w_border": -0.05}


def test_no_echo_readings_only_clear(small: Scenario) -> None:
    r = small.readings
    far = Readings(
        r.t, r.sensor, r.x, r.y, r.theta, np.full(len(r), small.rig.sensor.r_max), r.names
    )
    # EM from the neutral start once left these cells at even odds: the E-step counted a
    # pass as 1 - P(random), which rounds to 0 when chance explains a long beam almost
    # surely, so the M-step never heard that the beam crossed them.
    # The gradient method ignores no-echo readings by default (issue 39): asked to use
    # them, they only clear; by default the map has no evidence at all.
    for method, params in [
        ("gradient", {"no_echo": "free"}),
        ("gradient", {"no_echo": "free", "init": "inverse"}),
        ("stochastic", {}),
        ("em", {}),
        ("em", {"init": "inverse"}),
        ("em-thrun", {}),
    ]:
        occ = make_mapper(method, **params).fit(far, small.truth.grid, small.rig).occupancy_
        assert np.nanmax(occ) < 0.5, method  # no obstacle from readings that saw none
    occ = make_mapper("gradient").fit(far, small.truth.grid, small.rig).occupancy_
    assert not np.any(occ > 0.5)


def test_gradient_starts_from_the_inverse_map_when_asked(small: Scenario) -> None:
    inv = make_mapper("inverse").fit(small.readings, small.truth.grid, small.rig).occupancy_
    known = np.isfinite(inv)
    gaps = {}
    for init in ("uniform", "inverse"):
        # One tiny step, one round: the map is still where it started.
        g = GradientMapper(init=init, max_iter=1, step=1e-4, robust=0.0)
        occ = g.fit(small.readings, small.truth.grid, small.rig).occupancy_
        gaps[init] = float(np.mean(np.abs(np.nan_to_num(occ[known], nan=0.5) - inv[known])))
    assert gaps["inverse"] < gaps["uniform"] / 2


@pytest.mark.parametrize(
    ("method", "params", "match"),
    [
        ("gradient", {"a1": 1.0}, r"parameter 'a1' must be in \(0.0, 1.0\)"),
        ("gradient", {"a2": -0.01}, r"parameter 'a2' must be in \(0.0, 1.0\)"),
        ("gradient", {"c1": -5.0}, r"parameter 'c1' must be in \[0.0, inf\]"),
        ("gradient", {"solver": "adam"}, r"parameter 'solver' must be one of gd, pgd, lbfgs"),
        ("gradient", {"max_iter": 0}, r"parameter 'max_iter' must be >= 1"),
        ("gradient", {"step": 0.0}, r"parameter 'step' must be in \(0.0, inf\]"),
        ("gradient", {"init": "guess"}, r"parameter 'init' must be one of uniform, inverse"),
        ("stochastic", {"p_hit": 1.0}, r"parameter 'p_hit' must be in \(0.0, 1.0\)"),
        ("stochastic", {"p_rand": 1.0}, r"parameter 'p_rand' must be in \[0.0, 1.0\)"),
        ("stochastic", {"preset": "thesis999"}, r"parameter 'preset' must be one of"),
        ("stochastic", {"neighbours": 6}, r"parameter 'neighbours' must be 4 or 8"),
        ("stochastic", {"t_end": 5.0}, r"parameter 't_end' must be in \(0.0, 2.0\]"),
        ("stochastic", {"seed": -1}, r"parameter 'seed' must be >= 0"),
        ("em", {"p_hit": 0.0}, r"parameter 'p_hit' must be in \(0.0, 1.0\)"),
        ("em", {"init": "guess"}, r"parameter 'init' must be one of inverse, uniform"),
        ("em", {"init_value": 0.0}, r"parameter 'init_value' must be in \(0.0, 1.0\]"),
        ("em", {"sigma": -0.1}, r"parameter 'sigma' must be in \(0.0, inf\]"),
    ],
)
def test_parameter_ranges(method: str, params: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make_mapper(method, **params)


def test_readings_that_touch_no_cell(small: Scenario) -> None:
    # Readings whose beam lies entirely off the grid, last in the batch and in between.
    r = small.readings
    off = Readings(
        r.t[:3],
        r.sensor[:3],
        np.full(3, -50.0),
        np.full(3, -50.0),
        r.theta[:3],
        r.range[:3],
        r.names,
    )
    mixed = Readings.concat([r.take(np.arange(20)), off, r.take(np.arange(20, 40)), off])
    for method in ("gradient", "stochastic", "em"):
        occ = make_mapper(method).fit(mixed, small.truth.grid, small.rig).occupancy_
        assert np.isfinite(occ).any(), method
    p = GradientMapper().start(small.truth.grid, small.rig).problem(mixed)
    np.testing.assert_allclose(np.asarray(p.W.sum(axis=1)).ravel(), 1.0)


@pytest.mark.parametrize("method", ["inverse", "counting", "gradient"])
def test_ignored_no_echo_readings_leave_the_map_unknown(small: Scenario, method: str) -> None:
    r = small.readings
    far = Readings(
        r.t, r.sensor, r.x, r.y, r.theta, np.full(len(r), small.rig.sensor.r_max), r.names
    )
    occ = make_mapper(method, no_echo="ignore").fit(far, small.truth.grid, small.rig).occupancy_
    assert np.isnan(occ).all()
    mixed = Readings.concat([r, far])
    a = make_mapper(method, no_echo="ignore").fit(mixed, small.truth.grid, small.rig)
    b = make_mapper(method, no_echo="ignore").fit(r, small.truth.grid, small.rig)
    np.testing.assert_allclose(a.occupancy_, b.occupancy_, equal_nan=True)


def test_p_free_and_p_occ_at_known_values() -> None:
    # One free and one occupied term with X0 = 0.25 and the documents' a1 = 0.05,
    # a2 = 0.01, computed by hand from methods.md section 2:
    #   b1 = (1 - a1 X0) / (1 - X0) = 1.316667,  b2 = (1 - a2 + a2 X0) / X0 = 3.97.
    import scipy.sparse as sp

    from sonarmap.mappers._forward import Penalties

    W = sp.csr_matrix(np.eye(2))
    p = ForwardProblem(
        W,
        W.T.tocsr(),
        np.full(2, 0.25),
        np.array([False, True]),
        np.arange(2),
        Penalties(0.05, 0.01, 5.0, 1.0),
    )
    X = np.array([0.1, 0.25, 0.5, 1.0])
    free = [p.term_values(np.array([x, 0.0]))[0] for x in X]
    occ = [p.term_values(np.array([0.0, x]))[1] for x in X]
    np.testing.assert_allclose(free, [0.005, 0.0125, 0.0125 + 1.316667 * 0.25, 1.0], rtol=1e-6)
    np.testing.assert_allclose(occ, [1 - 0.397, 0.0075, 0.005, 0.0], atol=1e-9)
    # Swapping a1 and a2 changes both pieces: the values above would not hold.
    q = ForwardProblem(p.W, p.WT, p.X0, p.is_occ, p.cells, Penalties(0.01, 0.05, 5.0, 1.0))
    assert q.term_values(np.array([0.1, 0.0]))[0] != pytest.approx(0.005)
    assert q.term_values(np.array([0.0, 0.5]))[1] != pytest.approx(0.005)


def test_stochastic_incremental_score_matches_a_full_recomputation(small: Scenario) -> None:
    from sonarmap.mappers._thrun import apply_flip, flip_delta, init_state
    from sonarmap.mappers._thrun_common import model_sigma

    m = StochasticMapper(sweeps=5.0).fit(small.readings, small.truth.grid, small.rig)
    ix = m.index_
    assert ix is not None
    assert m.local_occupancy_ is not None
    occ = m.local_occupancy_ >= 0.5
    v = m.values()
    sigma = model_sigma(m, m.sigma)
    args = (ix.free_off, ix.free_cell, ix.band_off, ix.band_cell, ix.band_dist, ix.z)
    consts = (v["p_rand"], v["p_hit"], sigma, small.rig.sensor.r_max)
    _, _, ll = init_state(occ, *args, *consts)
    # The log-likelihood the search kept up flip by flip is the map's, recomputed.
    assert m.loglik_ == pytest.approx(float(ll.sum()), rel=1e-9, abs=1e-6)
    # And each flip's predicted change is the change a recomputation sees.
    rng = np.random.default_rng(0)
    n_before, bsum, loglik = init_state(occ, *args, *consts)
    deg = int(np.max(np.diff(ix.cell_off)))
    new_ll, new_bsum = np.empty(deg), np.empty(deg)
    for c in rng.choice(ix.n_cells, 40, replace=False):
        before = float(loglik.sum())
        d = flip_delta(
            int(c), occ, n_before, bsum, loglik, new_ll, new_bsum, ix.cell_off,
            ix.cell_reading, ix.cell_kind, ix.band_off, ix.band_cell, ix.band_dist, ix.z,
            *consts,
        )  # fmt: skip
        apply_flip(
            int(c), occ, n_before, bsum, loglik, new_ll, new_bsum, ix.cell_off,
            ix.cell_reading, ix.cell_kind,
        )  # fmt: skip
        _, _, fresh = init_state(occ, *args, *consts)
        assert float(fresh.sum()) - before == pytest.approx(d, abs=1e-7)
        np.testing.assert_allclose(loglik, fresh, atol=1e-9)


def test_stochastic_border_change_matches_a_recomputation() -> None:
    from sonarmap.mappers.stochastic import _border_delta

    def borders(full: np.ndarray, eight: bool) -> int:
        g = np.pad(full, 1, constant_values=False)
        pad = np.pad(np.ones_like(full), 1, constant_values=False)
        n = np.zeros(full.shape, dtype=np.int64)
        steps = [(-1, 0), (1, 0), (0, -1), (0, 1)]
        if eight:
            steps += [(-1, -1), (-1, 1), (1, -1), (1, 1)]
        rows, cols = full.shape
        for dr, dc in steps:
            nb = g[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
            inside = pad[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
            n += (inside & (nb != full)).astype(np.int64)
        return int((n**2).sum())

    rng = np.random.default_rng(3)
    full = rng.random((7, 9)) < 0.4
    for eight in (False, True):
        for g in rng.choice(full.size, 25, replace=False):
            flat = full.ravel().copy()
            d = _border_delta(int(g), flat, 7, 9, eight)
            after = flat.copy()
            after[g] = not after[g]
            assert d == borders(after.reshape(7, 9), eight) - borders(full, eight)


@pytest.mark.parametrize("method", ["gradient", "stochastic", "em"])
def test_a_problem_too_large_for_memory_is_refused(
    small: Scenario, method: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sonarmap.mappers._base as base

    monkeypatch.setattr(base, "MAX_ENTRIES", 10_000)
    with pytest.raises(
        ConfigError, match=rf"method '{method}': the first [\d,]+ of [\d,]+ readings"
    ):
        make_mapper(method).fit(small.readings, small.truth.grid, small.rig)
