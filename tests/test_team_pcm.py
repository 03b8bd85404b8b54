"""Pairwise consistency maximisation over closures (sonarmap.team.pcm)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

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


def _t3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


#: An odometry step's covariance (its end's frame): 2 cm and 0.01 rad a metre.
STEP_COV = np.diag([0.02**2, 0.02**2, 0.01**2])
#: A closure's covariance: 3 cm and 0.01 rad.
CLOSURE_COV = np.diag([0.03**2, 0.03**2, 0.01**2])


def _layer(source: int, truth: F64, frame: F64) -> tuple[dict[int, F64], list[OdometryEdge]]:
    """Poses ``source * 1000 + k`` at ``truth`` seen from ``frame`` (their layer's
    origin in the world), chained by exact odometry edges."""
    est = {source * 1000 + k: compose(invert(frame), t) for k, t in enumerate(truth)}
    uids = sorted(est)
    edges = [
        OdometryEdge(
            u,
            w,
            _t3(compose(invert(est[u]), est[w])),
            tuple(float(v) for v in STEP_COV.ravel()),
            10.0,
        )
        for u, w in itertools.pairwise(uids)
    ]
    return est, edges


def _closure(
    a: int,
    b: int,
    ta: F64,
    tb: F64,
    rng: np.random.Generator,
    off: tuple[float, float] = (0.0, 0.0),
) -> ClosureEdge:
    t = compose(invert(ta), tb) + np.r_[rng.normal(0, 0.01, 2), rng.normal(0, 0.003)]
    t[:2] += off
    return ClosureEdge(a, b, _t3(t), tuple(float(v) for v in CLOSURE_COV.ravel()), 12, 0.0)


def _corridor() -> tuple[
    dict[int, F64], dict[int, int], dict[int, LayerChain], list[ClosureEdge], set[int]
]:
    """Robot 0 and robot 1 drive the same 30 m corridor (1 m steps), robot 1 a metre
    aside, each in its own frame; closures join poses side by side, and five forged ones
    put robot 1's pose 5 m (a shelf's period) along the corridor from where it is."""
    rng = np.random.default_rng(3)
    n = 30
    truth0 = np.array([[float(k), 0.0, 0.0] for k in range(n)])
    truth1 = np.array([[float(k), 1.0, 0.02] for k in range(n)])
    est0, edges0 = _layer(0, truth0, np.array([0.0, 0.0, 0.0]))
    est1, edges1 = _layer(1, truth1, np.array([3.0, -2.0, 0.7]))
    closures = []
    forged = set()
    for k in range(0, n, 2):
        closures.append(_closure(k, 1000 + k, truth0[k], truth1[k], rng))
    for k in (5, 11, 17, 21, 27):
        forged.add(len(closures))
        # Robot 0's pose k matched to robot 1's pose k - 5: 5 m off along the corridor.
        closures.append(_closure(k, 1000 + k - 5, truth0[k], truth1[k], rng))
    estimates = {**est0, **est1}
    layer_of = {u: u // 1000 for u in estimates}
    chains = {0: LayerChain(edges0), 1: LayerChain(edges1)}
    return estimates, layer_of, chains, closures, forged


def test_chain_covariance_is_the_composed_odometry_covariance() -> None:
    rng = np.random.default_rng(1)
    edges = []
    for k in range(20):
        t = _t3((rng.uniform(0.5, 1.2), rng.normal(0, 0.1), rng.normal(0, 0.3)))
        q = np.diag([rng.uniform(1e-4, 1e-3), rng.uniform(1e-4, 1e-3), rng.uniform(1e-5, 1e-4)])
        edges.append(OdometryEdge(k, k + 1, t, tuple(q.ravel()), 10.0))
    chain = LayerChain(edges)
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


def test_pcm_keeps_the_consistent_closures_and_rejects_the_forged() -> None:
    estimates, layer_of, chains, closures, forged = _corridor()
    result = pcm_gate(closures, layer_of, estimates.__getitem__, chains)
    rejected = {i for i, c in enumerate(closures) if any(c is r for r in result.rejected)}
    assert rejected == forged
    assert len(result.kept) == len(closures) - len(forged)
    assert result.judged == len(closures)


def test_a_forged_closure_fails_its_loop_with_a_true_neighbour() -> None:
    estimates, _, chains, closures, forged = _corridor()

    def oriented(c: ClosureEdge) -> Oriented:
        return (c.a, c.b, np.asarray(c.transform), c.cov())

    true_ = [c for i, c in enumerate(closures) if i not in forged]
    bad = [c for i, c in enumerate(closures) if i in forged]
    d_true = loop_distance(
        oriented(true_[2]), oriented(true_[3]), estimates.__getitem__, *chains.values()
    )
    d_bad = loop_distance(
        oriented(bad[0]), oriented(true_[3]), estimates.__getitem__, *chains.values()
    )
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
    est, edges = _layer(0, truth, np.zeros(3))
    closures = []
    for k in range(0, 31, 3):
        a, b = k, 31 + k
        c = _closure(a, b, truth[a], truth[b], rng)
        if k % 2:
            c = ClosureEdge(
                b,
                a,
                _t3(invert(np.asarray(c.transform))),
                c.covariance,
                12,
                0.0,
            )
        closures.append(c)
    forged = _closure(10, 31 + 10, truth[10], truth[31 + 10], rng, off=(4.0, 0.0))
    closures.insert(5, forged)
    result = pcm_gate(closures, dict.fromkeys(est, 0), est.__getitem__, {0: LayerChain(edges)})
    assert [c is forged for c in result.rejected] == [True]


def test_only_the_newest_closures_of_a_pair_are_judged() -> None:
    estimates, layer_of, chains, closures, forged = _corridor()
    result = pcm_gate(closures, layer_of, estimates.__getitem__, chains, max_per_pair=8)
    assert result.judged == 8
    # The window is the last 8: 3 true closures and the 5 forged ones, which agree with
    # each other (each is the same 5 m period off): the larger set wins, PCM's known
    # limit when repeated structure outnumbers the truth. Nothing older is judged.
    forged_set = {id(closures[i]) for i in forged}
    assert {id(c) for c in result.kept[-5:]} == forged_set
    assert [id(c) for c in result.rejected] == [id(c) for c in closures[-8:-5]]


@pytest.mark.parametrize("max_per_pair", [1, 0])
def test_too_few_to_judge_keeps_all(max_per_pair: int) -> None:
    estimates, layer_of, chains, closures, _ = _corridor()
    if max_per_pair == 0:
        closures = closures[:1]
        max_per_pair = 40
    result = pcm_gate(closures, layer_of, estimates.__getitem__, chains, max_per_pair=max_per_pair)
    assert result.rejected == []


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
