"""Small scenes shared by the PCM tests (test_team_pcm, test_team_pcm_judged): a
corridor driven by two robots with forged closures, and a noisy lap driven twice."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import numpy.typing as npt

from sonarmap.team.pcm import LayerChain
from sonarmap.team.records import ClosureEdge, OdometryEdge, compose, invert

F64 = npt.NDArray[np.float64]


def t3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


#: An odometry step's covariance (its end's frame): 2 cm and 0.01 rad a metre.
STEP_COV = np.diag([0.02**2, 0.02**2, 0.01**2])
#: A closure's covariance: 3 cm and 0.01 rad.
CLOSURE_COV = np.diag([0.03**2, 0.03**2, 0.01**2])


def layer(source: int, truth: F64, frame: F64) -> tuple[dict[int, F64], list[OdometryEdge]]:
    """Poses ``source * 1000 + k`` at ``truth`` seen from ``frame`` (their layer's
    origin in the world), chained by exact odometry edges."""
    est = {source * 1000 + k: compose(invert(frame), t) for k, t in enumerate(truth)}
    uids = sorted(est)
    edges = [
        OdometryEdge(
            u,
            w,
            t3(compose(invert(est[u]), est[w])),
            tuple(float(v) for v in STEP_COV.ravel()),
            10.0,
        )
        for u, w in itertools.pairwise(uids)
    ]
    return est, edges


def closure(
    a: int,
    b: int,
    ta: F64,
    tb: F64,
    rng: np.random.Generator,
    off: tuple[float, float] = (0.0, 0.0),
) -> ClosureEdge:
    t = compose(invert(ta), tb) + np.r_[rng.normal(0, 0.01, 2), rng.normal(0, 0.003)]
    t[:2] += off
    return ClosureEdge(a, b, t3(t), tuple(float(v) for v in CLOSURE_COV.ravel()), 12, 0.0)


def corridor() -> tuple[
    dict[int, F64], dict[int, int], dict[int, LayerChain], list[ClosureEdge], set[int]
]:
    """Robot 0 and robot 1 drive the same 30 m corridor (1 m steps), robot 1 a metre
    aside, each in its own frame; closures join poses side by side, and five forged ones
    put robot 1's pose 5 m (a shelf's period) along the corridor from where it is."""
    rng = np.random.default_rng(3)
    n = 30
    truth0 = np.array([[float(k), 0.0, 0.0] for k in range(n)])
    truth1 = np.array([[float(k), 1.0, 0.02] for k in range(n)])
    est0, edges0 = layer(0, truth0, np.array([0.0, 0.0, 0.0]))
    est1, edges1 = layer(1, truth1, np.array([3.0, -2.0, 0.7]))
    closures = []
    forged = set()
    for k in range(0, n, 2):
        closures.append(closure(k, 1000 + k, truth0[k], truth1[k], rng))
    for k in (5, 11, 17, 21, 27):
        forged.add(len(closures))
        # Robot 0's pose k matched to robot 1's pose k - 5: 5 m off along the corridor.
        closures.append(closure(k, 1000 + k - 5, truth0[k], truth1[k], rng))
    estimates = {**est0, **est1}
    layer_of = {u: u // 1000 for u in estimates}
    chains = {0: LayerChain(edges0), 1: LayerChain(edges1)}
    return estimates, layer_of, chains, closures, forged


def noisy_lap_twice(rng: np.random.Generator, bias: float = 0.0) -> tuple[F64, list[OdometryEdge]]:
    """A 5 m circle driven twice (62 poses), odometry edges the truth plus their noise,
    and ``bias`` radians per metre driven on every edge's heading (a systematic turn,
    as :func:`~sonarmap.team.world.odometry`'s ``bias_theta``)."""
    lap = [
        [5 * math.cos(a), 5 * math.sin(a), a + math.pi / 2]
        for a in np.linspace(0, 2 * math.pi, 32)[:-1]
    ]
    truth = np.array(lap + lap)
    chol = np.linalg.cholesky(STEP_COV)
    edges = []
    for k in range(len(truth) - 1):
        t = compose(invert(truth[k]), truth[k + 1]) + chol @ rng.normal(size=3)
        t[2] += bias * math.hypot(float(t[0]), float(t[1]))
        edges.append(OdometryEdge(k, k + 1, t3(t), tuple(float(v) for v in STEP_COV.ravel()), 1))
    return truth, edges
