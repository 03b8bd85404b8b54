"""Pairwise consistency maximisation over closures (sonarmap.team.pcm)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import numpy.typing as npt
import pytest

from pcm_helpers import STEP_COV, closure, corridor, layer, noisy_lap_twice, t3
from sonarmap.team.globalmap import CHI2_99_3DOF
from sonarmap.team.pcm import LayerChain, loop_distance, pcm_gate
from sonarmap.team.records import (
    ClosureEdge,
    OdometryEdge,
    compose,
    compose_covariance,
    invert,
)

F64 = npt.NDArray[np.float64]
Oriented = tuple[int, int, F64, F64]


def test_chain_covariance_is_the_composed_odometry_covariance() -> None:
    rng = np.random.default_rng(1)
    edges = []
    for k in range(20):
        t = t3((rng.uniform(0.5, 1.2), rng.normal(0, 0.1), rng.normal(0, 0.3)))
        q = np.diag([rng.uniform(1e-4, 1e-3), rng.uniform(1e-4, 1e-3), rng.uniform(1e-5, 1e-4)])
        edges.append(OdometryEdge(k, k + 1, t, tuple(q.ravel()), 10.0))
    chain = LayerChain(edges, bias_sd=0.0)  # the edges' own noise only
    x, c = np.zeros(3), np.zeros((3, 3))
    for e in edges[4:17]:
        step = np.asarray(e.transform)
        c = compose_covariance(x, c, step, e.cov())
        x = compose(x, step)
    got = chain.covariance(4, 17)
    assert got is not None
    np.testing.assert_allclose(got, c, rtol=1e-9, atol=1e-12)
    # Two poses on no common chain: untestable.
    assert chain.covariance(4, 99) is None
    assert chain.relative(4, 99) is None
    rel = chain.relative(4, 17)
    assert rel is not None
    np.testing.assert_allclose(rel[0], x, atol=1e-12)
    # Two closures sharing a pose on no chain: the stretch there is empty, not unknown.
    same = chain.relative(99, 99)
    assert same is not None
    assert not same[0].any()


def test_pcm_keeps_the_consistent_closures_and_rejects_the_forged() -> None:
    _, layer_of, chains, closures, forged = corridor()
    result = pcm_gate(closures, layer_of, chains)
    rejected = {i for i, c in enumerate(closures) if any(c is r for r in result.rejected)}
    assert rejected == forged
    assert len(result.kept) == len(closures) - len(forged)
    assert result.judged == len(closures)


def test_a_forged_closure_fails_its_loop_with_a_true_neighbour() -> None:
    _, _, chains, closures, forged = corridor()

    def oriented(c: ClosureEdge) -> Oriented:
        return (c.a, c.b, np.asarray(c.transform), c.cov())

    true_ = [c for i, c in enumerate(closures) if i not in forged]
    bad = [c for i, c in enumerate(closures) if i in forged]
    d_true = loop_distance(oriented(true_[2]), oriented(true_[3]), *chains.values())
    d_bad = loop_distance(oriented(bad[0]), oriented(true_[3]), *chains.values())
    assert d_true is not None
    assert d_true < CHI2_99_3DOF
    assert d_bad is not None
    assert d_bad > CHI2_99_3DOF


def test_pcm_within_one_layer_and_orientation() -> None:
    """A robot's own revisits (a loop driven twice), one closure stored each way, and a
    forged one 4 m off."""
    rng = np.random.default_rng(5)
    lap = [
        [5 * math.cos(a), 5 * math.sin(a), a + math.pi / 2]
        for a in np.linspace(0, 2 * math.pi, 32)[:-1]
    ]
    truth = np.array(lap + lap)
    est, edges = layer(0, truth, np.zeros(3))
    closures = []
    for k in range(0, 31, 3):
        a, b = k, 31 + k
        c = closure(a, b, truth[a], truth[b], rng)
        if k % 2:
            c = ClosureEdge(
                b,
                a,
                t3(invert(np.asarray(c.transform))),
                c.covariance,
                12,
                0.0,
            )
        closures.append(c)
    forged = closure(10, 31 + 10, truth[10], truth[31 + 10], rng, off=(4.0, 0.0))
    closures.insert(5, forged)
    result = pcm_gate(closures, dict.fromkeys(est, 0), {0: LayerChain(edges)})
    assert [c is forged for c in result.rejected] == [True]


def test_only_the_newest_closures_of_a_pair_are_judged() -> None:
    _, layer_of, chains, closures, forged = corridor()
    result = pcm_gate(closures, layer_of, chains, max_per_pair=8)
    assert result.judged == 8
    # The window is the last 8: 3 true closures and the 5 forged ones, which agree with
    # each other (each is the same 5 m period off): the larger set wins, PCM's known
    # limit when repeated structure outnumbers the truth. Nothing older is judged.
    forged_set = {id(closures[i]) for i in forged}
    assert {id(c) for c in result.kept[-5:]} == forged_set
    assert [id(c) for c in result.rejected] == [id(c) for c in closures[-8:-5]]


def test_too_few_to_judge_keeps_all() -> None:
    _, layer_of, chains, closures, _ = corridor()
    assert pcm_gate(closures, layer_of, chains, max_per_pair=1).rejected == []
    assert pcm_gate(closures[:1], layer_of, chains).rejected == []


@pytest.mark.parametrize("max_per_pair", [0, -3])
def test_max_per_pair_below_one_is_refused(max_per_pair: int) -> None:
    _, layer_of, chains, closures, _ = corridor()
    with pytest.raises(ValueError, match="max_per_pair"):
        pcm_gate(closures, layer_of, chains, max_per_pair=max_per_pair)


def test_the_loop_goes_through_the_odometry_not_the_estimates() -> None:
    """A graph pulled by forged closures moves robot 1's later poses 5 m along the
    corridor; a loop through those estimates finds a forged closure consistent with a
    true one, the loop through the odometry does not."""
    estimates, layer_of, chains, closures, forged = corridor()
    first_forged = min(forged)
    c_true = closures[2]  # robot 0's pose 4 with robot 1's pose 1004
    c_bad = closures[first_forged]  # robot 0's pose 5 with robot 1's pose 1000
    assert (c_true.a, c_true.b, c_bad.a, c_bad.b) == (4, 1004, 5, 1000)
    pulled = dict(estimates)
    along = compose(invert(estimates[1000]), estimates[1005])
    for k in range(1000, 1004):  # robot 1's poses 0..3 pulled 5 m forward
        pulled[k] = compose(estimates[k], along)
    # The chain the old code used: the estimates' relative poses, the odometry's noise.
    uids = sorted(u for u in pulled if u >= 1000)
    from_estimates = LayerChain(
        OdometryEdge(
            u,
            w,
            t3(compose(invert(pulled[u]), pulled[w])),
            tuple(float(v) for v in STEP_COV.ravel()),
            10.0,
        )
        for u, w in itertools.pairwise(uids)
    )

    def oriented(c: ClosureEdge) -> Oriented:
        return (c.a, c.b, np.asarray(c.transform), c.cov())

    d_old = loop_distance(oriented(c_true), oriented(c_bad), chains[0], from_estimates)
    d_new = loop_distance(oriented(c_true), oriented(c_bad), chains[0], chains[1])
    assert d_old is not None
    assert d_old < CHI2_99_3DOF
    assert d_new is not None
    assert d_new > CHI2_99_3DOF
    result = pcm_gate([c_true, closures[3], c_bad], layer_of, chains)
    assert [c is c_bad for c in result.rejected] == [True]


def test_a_reversed_true_pair_within_one_layer_passes() -> None:
    """Two true revisits stored one each way, (5 -> 36) and (41 -> 10): the loop's two
    odometry stretches (10..36 and 5..41) overlap, and as one walk the edges walked
    once each way cancel, so the pair fails about as often as the 1 % the quantile
    allows and no loop is untestable, whichever way round the closures are stored."""
    fails = untestable = 0
    runs = 200
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        truth, edges = noisy_lap_twice(rng)
        c1 = closure(5, 36, truth[5], truth[36], rng)
        c2 = closure(41, 10, truth[41], truth[10], rng)
        result = pcm_gate([c1, c2], dict.fromkeys(range(len(truth)), 0), {0: LayerChain(edges)})
        fails += bool(result.rejected)
        untestable += result.loops_untestable
    assert untestable == 0
    assert fails <= 0.05 * runs


def test_the_zmq_nodes_get_the_pcm_setting() -> None:
    from sonarmap.team.config import MissionConfig
    from sonarmap.team.exchange import ExchangeParams
    from sonarmap.team.launcher import node_args
    from sonarmap.team.node import LockstepParams

    on = node_args(MissionConfig(pcm=True), ExchangeParams(), 30.0, None, 120.0, LockstepParams())
    off = node_args(MissionConfig(), ExchangeParams(), 30.0, None, 120.0, LockstepParams())
    assert "--pcm" in on
    assert "--pcm" not in off
    assert "--no-pcm" in off
