"""PCM's loop over one walk of a layer's odometry, its odometry forest, and closures
judged once (sonarmap.team.pcm, RobotStore.keep_judged)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from pcm_helpers import corridor, noisy_lap_twice, t3
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.globalmap import CHI2_99_3DOF
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.pcm import LayerChain, loop_distance, loop_residual, pcm_gate
from sonarmap.team.records import (
    ClosureEdge,
    OdometryEdge,
    compose,
    compose_covariance,
    invert,
    invert_covariance,
)
from sonarmap.team.store import RobotStore

F64 = npt.NDArray[np.float64]

#: A closure's covariance here: 3 cm and 0.01 rad, as its noise is drawn.
CLOSURE_COV = np.diag([0.03**2, 0.03**2, 0.01**2])


def _drawn(a: int, b: int, truth: F64, rng: np.random.Generator) -> tuple[int, int, F64, F64]:
    """A true closure ``a -> b`` with noise drawn from its own covariance (isotropic
    in x and y, so the same on either side of the transform)."""
    t = compose(invert(truth[a]), truth[b]) + np.linalg.cholesky(CLOSURE_COV) @ rng.normal(size=3)
    return a, b, np.asarray(t), CLOSURE_COV.copy()


def _reversed(c: tuple[int, int, F64, F64]) -> tuple[int, int, F64, F64]:
    a, b, t, _ = c
    # Isotropic in x and y: the inverse's covariance is the same matrix.
    return b, a, np.asarray(invert(t)), CLOSURE_COV.copy()


# Pairs of true revisits on the lap driven twice (pose k and k + 31 are one place):
# in a row (the two stretches share edges 20..25, walked once each way), interleaved,
# nested, and one whose loop walks edges 12..36 twice the same way (four times their
# covariance).
PAIRS = {
    "in a row": ((5, 36), (10, 41)),
    "apart": ((5, 36), (25, 56)),
    "nested": ((3, 34), (8, 39)),
    "twice one way": ((5, 36), (43, 12)),
}


@pytest.mark.parametrize("name", sorted(PAIRS))
@pytest.mark.parametrize("stored", ["forward", "reversed"])
def test_the_loop_over_one_walk_has_its_noise_covariance(name: str, stored: str) -> None:
    """Over 300 draws of odometry and closure noise, the loop's squared Mahalanobis
    distance has the chi-square mean (3 for 3 degrees of freedom) and fails about 1 %
    of the time, whichever way round the closures are stored: a covariance that
    counts a shared edge wrongly, or a loop formed with a closure the wrong way round,
    moves the mean far out of the band."""
    (a1, b1), (a2, b2) = PAIRS[name]
    d2 = []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        truth, edges = noisy_lap_twice(rng)
        chain = LayerChain(edges, bias_sd=0.0)  # this odometry has no heading bias
        c1, c2 = _drawn(a1, b1, truth, rng), _drawn(a2, b2, truth, rng)
        if stored == "reversed":
            c1 = _reversed(c1)
        d = loop_distance(c1, c2, chain, chain)
        assert d is not None
        d2.append(d)
    mean = float(np.mean(d2))
    assert 2.4 < mean < 3.6, mean
    assert np.mean(np.array(d2) > CHI2_99_3DOF) <= 0.04


def test_a_loop_over_one_walk_rejects_a_forged_closure() -> None:
    rng = np.random.default_rng(0)
    truth, edges = noisy_lap_twice(rng)
    chain = LayerChain(edges)
    c1 = _drawn(5, 36, truth, rng)
    c2 = _drawn(10, 41, truth, rng)
    forged = (c2[0], c2[1], c2[2] + np.array([0.8, 0.0, 0.0]), c2[3])
    d_true, d_bad = loop_distance(c1, c2, chain, chain), loop_distance(c1, forged, chain, chain)
    assert d_true is not None
    assert d_true < CHI2_99_3DOF
    assert d_bad is not None
    assert d_bad > 5 * CHI2_99_3DOF


def test_the_forest_joins_a_merged_pose_and_a_chain_broken_by_it() -> None:
    """A pose with two edges out (a merge at a closure gives the merged pose both
    poses' edges) no longer breaks the chain: every pose is on one tree, the path
    through the merged pose is the composed odometry, and an edge closing a cycle is
    left out."""
    step = (1.0, 0.0, 0.1)
    cov = tuple(float(v) for v in np.diag([4e-4, 4e-4, 1e-4]).ravel())
    merged = 100
    edges = [
        OdometryEdge(0, 1, step, cov, 10.0),
        OdometryEdge(1, merged, step, cov, 10.0),
        OdometryEdge(merged, 3, step, cov, 10.0),
        OdometryEdge(merged, 7, step, cov, 10.0),  # the other pose's next edge
        OdometryEdge(6, merged, step, cov, 10.0),
        OdometryEdge(3, 7, (0.0, 0.0, 0.0), cov, 10.0),  # closes a cycle: left out
    ]
    chain = LayerChain(edges)
    trees = {u: chain.where[u][0] for u in (0, 1, merged, 3, 6, 7)}
    assert set(trees.values()) == {0}
    rel = chain.relative(0, 3)
    assert rel is not None
    np.testing.assert_allclose(rel[0], compose(compose(step, step), step), atol=1e-12)
    rel6 = chain.relative(6, 3)
    assert rel6 is not None
    np.testing.assert_allclose(rel6[0], compose(step, step), atol=1e-12)
    # Two poses with no edge between any of their trees: untestable.
    assert chain.relative(0, 99) is None
    assert (
        loop_residual((0, 3, np.zeros(3), np.eye(3)), (99, 3, np.zeros(3), np.eye(3)), chain, chain)
        is None
    )


# --- judged once --------------------------------------------------------------------


def _window(result_rejected: list[ClosureEdge], closures: list[ClosureEdge]) -> set[int]:
    return {i for i, c in enumerate(closures) if any(c is r for r in result_rejected)}


def test_judged_once_rejects_the_forged_and_freezes_the_kept() -> None:
    _, layer_of, chains, closures, forged = corridor()
    result = pcm_gate(closures, layer_of, chains, frozen=set())
    assert _window(result.rejected, closures) == forged
    assert [id(c) for c in result.newly_kept] == [
        id(c) for i, c in enumerate(closures) if i not in forged
    ]
    # Judged again with the kept ones frozen: nothing new, nothing judged or tested.
    again = pcm_gate(result.kept, layer_of, chains, frozen={c.pair for c in result.newly_kept})
    assert (again.judged, again.loops_tested, again.rejected, again.newly_kept) == (0, 0, [], [])


def test_frozen_truth_outvotes_repeated_structure_that_arrives_later() -> None:
    """The last 8 closures: 3 true, then the 5 forged ones, which agree with each other.
    Judged afresh, the 5 win (PCM's limit); with the 3 true ones judged and kept in an
    earlier pass, each forged one fails with all 3 and goes, and a frozen closure is
    never rejected."""
    _, layer_of, chains, closures, forged = corridor()
    fresh = pcm_gate(closures, layer_of, chains, max_per_pair=8, frozen=set())
    assert _window(fresh.rejected, closures) == {
        i for i in range(len(closures) - 8, len(closures)) if i not in forged
    }
    truth = {closures[i].pair for i in range(len(closures) - 8, len(closures)) if i not in forged}
    held = pcm_gate(closures, layer_of, chains, max_per_pair=8, frozen=truth)
    assert _window(held.rejected, closures) == forged
    assert held.judged == 5


def _judge(
    store: RobotStore, layer_of: dict[int, int], chains: dict[int, LayerChain]
) -> list[ClosureEdge]:
    """One judged-once pass over the store's closures, kept in the store as the
    mission keeps it; returns the closures rejected for the first time."""
    result = pcm_gate(store.closures, layer_of, chains, frozen=store.judged_pairs)
    store.closures = result.kept
    gone = store.reject_closures(result.rejected)
    store.keep_judged(result.newly_kept)
    return gone


def test_forged_closures_that_arrive_first_do_not_lock_out_the_true_ones() -> None:
    """The reviewer's scenario: one forged closure alone, then a second that agrees
    with it, then the 15 true ones, then the other 3 forged. A closure is frozen only
    once tested against two closures still in, so the first two forged ones are still
    new when the true ones arrive, fail with all 15 and go; every true closure is
    held and none rejected."""
    _, layer_of, chains, closures, forged = corridor()
    bad = [closures[i] for i in sorted(forged)]
    good = [c for i, c in enumerate(closures) if i not in forged]
    store = RobotStore(0)
    rejected: list[ClosureEdge] = []
    for arriving in ([bad[0]], [bad[1]], good, bad[2:]):
        store.closures = store.closures + list(arriving)
        rejected += _judge(store, layer_of, chains)
    held = {c.pair for c in store.closures}
    assert sum(c.pair in held for c in good) == len(good)
    assert sum(c.pair in held for c in bad) == 0
    assert {c.pair for c in rejected} == {c.pair for c in bad}
    assert store.judged_pairs == {c.pair for c in good}


def test_three_agreeing_forged_closures_established_first_reject_the_truth() -> None:
    """The other direction, PCM's limit as the rule stands: three forged closures that
    agree with each other, judged before any true one, are frozen (each tested against
    two still in), and every true closure that arrives later fails with all three."""
    _, layer_of, chains, closures, forged = corridor()
    bad = [closures[i] for i in sorted(forged)]
    good = [c for i, c in enumerate(closures) if i not in forged]
    store = RobotStore(0)
    for arriving in (bad[:3], good):
        store.closures = store.closures + list(arriving)
        _judge(store, layer_of, chains)
    held = {c.pair for c in store.closures}
    assert sum(c.pair in held for c in bad[:3]) == 3
    assert sum(c.pair in held for c in good) == 0


def test_a_closure_alone_or_untested_is_not_frozen() -> None:
    """The first closure of a pair of layers, or one with a single tested partner, is
    kept but not frozen, and not counted as judged; with two partners it is."""
    _, layer_of, chains, closures, forged = corridor()
    good = [c for i, c in enumerate(closures) if i not in forged]
    alone = pcm_gate(good[:1], layer_of, chains, frozen=set())
    assert (alone.judged, alone.newly_kept, alone.rejected) == (0, [], [])
    two = pcm_gate(good[:2], layer_of, chains, frozen=set())
    assert (two.judged, two.newly_kept, two.loops_tested) == (0, [], 1)
    three = pcm_gate(good[:3], layer_of, chains, frozen=set())
    assert three.judged == 3
    assert [c.pair for c in three.newly_kept] == [c.pair for c in good[:3]]


def test_one_failing_loop_does_not_reject_a_closure() -> None:
    """A forged closure with one true partner fails one loop: kept when two failures
    are needed (one is what a true pair shows by chance), rejected when one is."""
    _, layer_of, chains, closures, forged = corridor()
    pair = [closures[0], closures[min(forged)]]
    assert pcm_gate(pair, layer_of, chains, frozen=set()).rejected == []
    assert [
        c is pair[1]
        for c in pcm_gate(pair, layer_of, chains, frozen=set(), min_failures=1).rejected
    ] == [True]
    with pytest.raises(ValueError, match="min_failures"):
        pcm_gate(pair, layer_of, chains, frozen=set(), min_failures=0)


def test_the_store_keeps_the_judged_pairs_through_state_and_restore() -> None:
    store = RobotStore(0)
    cov = tuple(float(v) for v in CLOSURE_COV.ravel())
    c1 = ClosureEdge(1, 2, t3((1.0, 0.0, 0.0)), cov, 12, 0.0)
    c2 = ClosureEdge(3, 4, t3((1.0, 0.0, 0.0)), cov, 12, 0.0)
    gone = ClosureEdge(5, 6, t3((1.0, 0.0, 0.0)), cov, 12, 0.0)
    store.closures = [c1, c2]
    store.keep_judged([c1, gone])  # a pair the store does not hold is not kept
    assert store.judged_pairs == {c1.pair}
    state = store.state()
    other = RobotStore(0)
    other.restore(state)
    assert other.judged_pairs == {c1.pair}
    # Pairs of closures that left the store are forgotten at the next call.
    other.closures = [c2]
    other.keep_judged([c2])
    assert other.judged_pairs == {c2.pair}
    # A state saved before the judged pairs were kept restores with none.
    other.restore({k: v for k, v in state.items() if k != "judged_pairs"})
    assert other.judged_pairs == frozenset()


def test_the_mission_judges_each_closure_once() -> None:
    """MissionConfig.pcm through the robot itself (RobotAgent.batch): a 60 s mission
    alone freezes the closures it kept in its store, and once every closure held has
    been judged, a further batch judges and tests nothing; judged afresh, or with
    nothing frozen, it would judge them all again."""
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    agent = RobotAgent(plan, MissionConfig(duration=60.0, seed=1, pcm=True))
    agent.run()
    agent.batch()  # the closures found after the mission's last batch
    settled = dict(agent.evaluator.pcm_loops)
    frozen = agent.store.judged_pairs
    assert settled["judged"] >= len(frozen) > 10
    assert frozen <= {c.pair for c in agent.store.closures}
    agent.batch()
    assert agent.evaluator.pcm_loops == settled
    assert agent.store.judged_pairs == frozen


# --- the loop's covariance, anisotropic and correlated --------------------------------

#: A noise much larger along one axis than across it, and correlated (x, y).
LOUD = np.array([[2e-3, 4e-4, 1e-6], [4e-4, 1e-4, -1e-6], [1e-6, -1e-6, 4e-6]])
#: A noise small next to :data:`LOUD`, so that the loud one's frame decides the loop's.
QUIET = np.diag([1e-6, 1e-6, 1e-7])


def _perturbed(t: F64, q: F64, rng: np.random.Generator) -> F64:
    """``t`` with noise of covariance ``q`` in its end's frame (what a stored
    covariance means)."""
    return np.asarray(compose(t, np.linalg.cholesky(q) @ rng.normal(size=3)))


def _arc_layer(
    source: int, truth: F64, q: F64, rng: np.random.Generator, reverse: bool
) -> list[OdometryEdge]:
    """Odometry edges between poses ``source * 1000 + k`` along ``truth``, with noise
    drawn from ``q``; ``reverse`` stores each edge from its later pose to its earlier
    one (the inverse, its covariance moved to that end)."""
    edges = []
    for k in range(len(truth) - 1):
        t = _perturbed(compose(invert(truth[k]), truth[k + 1]), q, rng)
        a, b, qk = source * 1000 + k, source * 1000 + k + 1, q
        if reverse:
            a, b, t, qk = b, a, np.asarray(invert(t)), invert_covariance(t, q)
        edges.append(OdometryEdge(a, b, t3(t), tuple(float(v) for v in qk.ravel()), 1))
    return edges


@pytest.mark.parametrize("loud", ["robot 0's odometry", "the closures"])
def test_a_loop_between_two_layers_has_its_noise_covariance(loud: str) -> None:
    """Robot 0 (its edges stored backwards) and robot 1 drive the same arc, 0.5 rad a
    step, each in its own frame; two closures join them two steps apart. One noise is
    loud and anisotropic (robot 0's odometry, or the closures'), the rest quiet, so the
    loop's covariance is as anisotropic as that noise and placed by its frame. Over
    300 draws, the loop's squared Mahalanobis distance has the chi-square mean, 3:
    an edge walked backwards with its covariance left unmoved, closure 2's noise
    entered at closure 1's end, or robot 0's noise moved from the wrong end each move
    it far out of the band."""
    q0, qc = (LOUD, QUIET) if loud == "robot 0's odometry" else (QUIET, LOUD)
    arc = np.array([[2 * math.sin(0.5 * k), 2 - 2 * math.cos(0.5 * k), 0.5 * k] for k in range(8)])
    frame1 = np.array([1.0, -2.0, 0.6])  # robot 1's layer origin in the world
    truth1 = np.array([compose(invert(frame1), p) for p in arc])
    d2 = []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        # This odometry has no heading bias: the edges' own noise only.
        chain0 = LayerChain(_arc_layer(0, arc, q0, rng, reverse=True), bias_sd=0.0)
        chain1 = LayerChain(_arc_layer(1, truth1, QUIET, rng, reverse=False), bias_sd=0.0)
        c1, c2 = (
            (a, 1000 + b, _perturbed(compose(invert(arc[a]), arc[b]), qc, rng), qc)
            for a, b in ((2, 3), (4, 5))
        )
        d = loop_distance(c1, c2, chain0, chain1)
        assert d is not None
        d2.append(d)
    mean = float(np.mean(d2))
    assert 2.5 < mean < 3.5, mean


def test_the_loop_counts_a_heading_bias_shared_by_every_edge() -> None:
    """Odometry turned by a heading bias drawn once per draw (0.003 rad per metre, the
    simulator's, the same on every edge), on the loop that walks 24 edges twice the
    same way: its squared distance has the chi-square mean when the chain counts that
    bias as one unknown (``bias_sd``), and fails far more than 1 % of the time when it
    counts only the edges' own noise (``bias_sd=0``, an independent error per edge:
    the walk's turn grows with its metres, not their square root)."""
    (a1, b1), (a2, b2) = PAIRS["twice one way"]
    with_bias: list[float] = []
    without: list[float] = []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        truth, edges = noisy_lap_twice(rng, bias=0.003 * float(rng.normal()))
        c1, c2 = _drawn(a1, b1, truth, rng), _drawn(a2, b2, truth, rng)
        for d2, bias_sd in ((with_bias, 0.003), (without, 0.0)):
            chain = LayerChain(edges, bias_sd=bias_sd)
            d = loop_distance(c1, c2, chain, chain)
            assert d is not None
            d2.append(d)
    assert 2.4 < float(np.mean(with_bias)) < 3.6, np.mean(with_bias)
    assert np.mean(np.array(with_bias) > CHI2_99_3DOF) <= 0.03
    assert float(np.mean(without)) > 4.5, np.mean(without)
    assert np.mean(np.array(without) > CHI2_99_3DOF) > 0.08


def test_the_shared_bias_keeps_its_sign_on_edges_walked_backwards() -> None:
    """The same bias-turned laps with the poses renamed so that the forest's root (the
    lowest UID) sits mid-route: tree edges are then walked both ways and the walk's
    counts have mixed signs. The chi-square mean still holds; a bias whose sign is
    lost on a backward edge (or counted by the edges' absolute counts) gives a mean
    near 5 and about 9 % failing."""
    (a1, b1), (a2, b2) = PAIRS["twice one way"]

    def uid(k: int) -> int:
        return (k + 31) % 62

    d2: list[float] = []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        truth, edges = noisy_lap_twice(rng, bias=0.003 * float(rng.normal()))
        renamed = [
            OdometryEdge(uid(e.a), uid(e.b), e.transform, e.covariance, e.max_distance)
            for e in edges
        ]
        c1, c2 = _drawn(a1, b1, truth, rng), _drawn(a2, b2, truth, rng)
        c1 = (uid(c1[0]), uid(c1[1]), c1[2], c1[3])
        c2 = (uid(c2[0]), uid(c2[1]), c2[2], c2[3])
        chain = LayerChain(renamed, bias_sd=0.003)
        d = loop_distance(c1, c2, chain, chain)
        assert d is not None
        d2.append(d)
    assert 2.4 < float(np.mean(d2)) < 3.6, np.mean(d2)
    assert np.mean(np.array(d2) > CHI2_99_3DOF) <= 0.03


def test_layer_chain_refuses_a_negative_bias() -> None:
    with pytest.raises(ValueError, match="bias_sd"):
        LayerChain([], bias_sd=-0.001)


def test_the_least_variance_forest_goes_round_a_loud_edge() -> None:
    """A square 0-1-2-3 of quiet edges closed by a loud edge 3-0: breadth first joins
    pose 3 to 0 by the loud edge (one hop), ``forest="least"`` by the quiet three; each
    path's covariance is that edge chain's composed covariance."""
    quiet = np.diag([1e-4, 1e-4, 1e-5])
    loud = np.diag([1e-1, 1e-1, 1e-2])
    steps = [(0, 1, (1.0, 0.0, math.pi / 2), quiet)] + [
        (k, k + 1, (1.0, 0.0, math.pi / 2), quiet) for k in (1, 2)
    ]
    edges = [OdometryEdge(a, b, t, tuple(q.ravel()), 10.0) for a, b, t, q in steps]
    edges.append(OdometryEdge(0, 3, (0.0, 1.0, -math.pi / 2), tuple(loud.ravel()), 10.0))
    hops = LayerChain(edges, bias_sd=0.0)
    least = LayerChain(edges, bias_sd=0.0, forest="least")
    via_loud = hops.covariance(0, 3)
    via_quiet = least.covariance(0, 3)
    assert via_loud is not None
    assert via_quiet is not None
    np.testing.assert_allclose(via_loud, loud, atol=1e-12)
    x, c = np.zeros(3), np.zeros((3, 3))
    for _, _, t, q in steps:
        c = compose_covariance(x, c, np.asarray(t), q)
        x = compose(x, np.asarray(t))
    np.testing.assert_allclose(via_quiet, c, rtol=1e-6, atol=1e-12)  # float32 edges
    with pytest.raises(ValueError, match="forest"):
        LayerChain(edges, forest="widest")
