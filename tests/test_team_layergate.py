"""Tests of sonarmap.team.layergate: a received pose matched in repeated structure."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.team.association import AssociationParams, associate
from sonarmap.team.layergate import (
    MIN_SUPPORT,
    LayerPlacement,
    closure_residual,
    gate_closures,
    layer_placements,
)
from sonarmap.team.records import ClosureEdge, Landmarks, Pose, compose, invert, make_uid

F64 = npt.NDArray[np.float64]

#: Where the received layer's frame (its source's believed start) lies in ours.
FRAME = np.array([3.0, -2.0, 0.3])
#: The repeated structure's period along the corridor (m).
PERIOD = 5.0
SIGMA = (0.03, 0.03, 0.01)


def _closure(a: int, b: int, at_a: F64, at_b: F64, rng: np.random.Generator) -> ClosureEdge:
    x, y, t = (float(v) for v in compose(invert(at_a), at_b) + rng.normal(0.0, SIGMA))
    cov = np.diag(np.square(SIGMA))
    return ClosureEdge(a, b, (x, y, t), tuple(float(v) for v in cov.ravel()), 20, 0.01)


def _corridor(rng: np.random.Generator) -> tuple[dict[int, F64], dict[int, F64], list[ClosureEdge]]:
    """Own poses along a corridor at their true places, a received layer's poses beside
    them in its source's frame, and closures between the two from the truth."""
    own = {make_uid(0, i): np.array([float(i), 0.0, 0.0]) for i in range(21)}
    truth_l = {make_uid(1, i): np.array([i + 0.5, 0.2, 0.05]) for i in range(21)}
    layer = {u: compose(invert(FRAME), x) for u, x in truth_l.items()}
    closures = [
        _closure(make_uid(0, i), make_uid(1, i), own[make_uid(0, i)], truth_l[make_uid(1, i)], rng)
        for i in range(0, 21, 2)
    ]
    return own, layer, closures


def test_placement_recovers_the_layer_frame() -> None:
    own, layer, closures = _corridor(np.random.default_rng(0))
    placed = layer_placements(own, {1: layer}, closures)
    assert set(placed) == {1}
    at = placed[1]
    assert len(at.proposals) == len(closures)
    u = make_uid(1, 7)
    where, cov = at.place(layer[u])
    np.testing.assert_allclose(where[:2], compose(FRAME, layer[u])[:2], atol=0.1)
    # The spread is measured from the residuals: of the closures' noise's order.
    assert 0.0 < cov[0, 0] < 0.2**2
    assert 0.0 < cov[2, 2] < 0.05**2


def test_placement_spread_grows_away_from_its_closures() -> None:
    own, layer, closures = _corridor(np.random.default_rng(2))
    at = layer_placements(own, {1: layer}, closures)[1]
    near = at.place(layer[make_uid(1, 10)])[1]
    far = at.place(compose(invert(FRAME), np.array([60.0, 0.2, 0.05])))[1]
    assert far[0, 0] > 4 * near[0, 0]


def test_a_layer_with_too_few_closures_is_not_placed() -> None:
    own, layer, closures = _corridor(np.random.default_rng(1))
    assert layer_placements(own, {1: layer}, closures[: MIN_SUPPORT - 1]) == {}


def test_residual_is_zero_for_an_exact_closure() -> None:
    a, b = np.array([1.0, 2.0, 0.4]), np.array([3.0, 1.0, -0.2])
    np.testing.assert_allclose(
        closure_residual(a, b, compose(invert(a), b).tolist()), 0.0, atol=1e-12
    )


def _scene(rng: np.random.Generator, n: int) -> tuple[F64, F64]:
    """Landmarks ahead of a pose (its frame) and SIFT-like descriptors."""
    pts = np.column_stack(
        [rng.uniform(1.5, 6.0, n), rng.uniform(-3.0, 3.0, n), rng.uniform(0.1, 2.0, n)]
    )
    g = rng.gamma(0.5, size=(n, 128))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    return pts, np.clip(np.rint(np.minimum(g, 0.2) * 2500), 0, 255)


def _seen_from(
    uid: int,
    where: F64,
    scene_at: F64,
    scene: tuple[F64, F64],
    ids: npt.NDArray[np.int64],
    estimate: F64,
    rng: np.random.Generator,
) -> Pose:
    """A pose at ``where`` (world) seeing the scene laid out ahead of ``scene_at``."""
    pts, desc = scene
    rel = compose(invert(where), scene_at)
    c, s = math.cos(rel[2]), math.sin(rel[2])
    local = pts.copy()
    local[:, 0] = c * pts[:, 0] - s * pts[:, 1] + rel[0]
    local[:, 1] = s * pts[:, 0] + c * pts[:, 1] + rel[1]
    local += rng.normal(0.0, 0.02, local.shape)
    n = len(pts)
    lm = Landmarks(
        local.astype(np.float32),
        np.clip(np.rint(desc + rng.normal(0.0, 6.0, desc.shape)), 0, 255).astype(np.uint8),
        np.full(n, 0.5),
        np.zeros(n),
        ids,
    )
    return Pose(uid, 0.0, 0, estimate, lm)


def test_a_repeated_structure_match_is_rejected_and_the_true_one_kept() -> None:
    rng = np.random.default_rng(7)
    own, layer, closures = _corridor(rng)
    placements = layer_placements(own, {1: layer}, closures)
    # The same shelf twice along the corridor, PERIOD apart: own pose A sees the first,
    # own pose W the second; the received pose R stands beside A and sees the first.
    scene = _scene(rng, 40)
    ids_first = np.arange(40, dtype=np.int64)
    ids_second = ids_first + 1000
    at_a = np.array([10.0, 0.0, 0.0])
    at_w = at_a + np.array([PERIOD, 0.0, 0.0])
    at_r = np.array([10.3, 0.2, 0.05])
    a = _seen_from(make_uid(0, 100), at_a, at_a, scene, ids_first, at_a, rng)
    w = _seen_from(make_uid(0, 101), at_w, at_w, scene, ids_second, at_w, rng)
    r_uid = make_uid(1, 100)
    r = _seen_from(r_uid, at_r, at_a, scene, ids_first, compose(invert(FRAME), at_r), rng)
    found, _ = associate(r, [a, w], None, AssociationParams())
    # Without a gate both are closures: the repeated one fits its landmarks as well.
    assert {c.a for c in found} == {a.uid, w.uid}
    wrong = next(c for c in found if c.a == w.uid)
    truly = compose(invert(at_w), at_r)
    assert math.hypot(*(np.asarray(wrong.transform[:2]) - truly[:2])) > PERIOD - 1.0

    placed = {
        a.uid: (a.estimate, np.zeros((3, 3))),
        w.uid: (w.estimate, np.zeros((3, 3))),
        r_uid: placements[1].place(r.estimate),
    }
    kept, rejected = gate_closures(found, placed)
    assert [c.a for c in kept] == [a.uid]
    assert [c.a for c in rejected] == [w.uid]


def test_an_unplaced_pose_passes_untested() -> None:
    c = ClosureEdge(1, 2, (100.0, 0.0, 0.0), tuple(np.eye(3).ravel() * 1e-4), 20, 0.01)
    kept, rejected = gate_closures([c], {1: (np.zeros(3), np.zeros((3, 3)))})
    assert kept == [c]
    assert rejected == []


@pytest.mark.parametrize("shift", [0.0, 0.5])
def test_gate_scales_with_the_placement_spread(shift: float) -> None:
    """A closure off by 0.5 m fails against a tight placement and passes a loose one."""
    cov = tuple(float(v) for v in np.diag([0.01**2, 0.01**2, 0.002**2]).ravel())
    c = ClosureEdge(1, 2, (1.0 + shift, 0.0, 0.0), cov, 20, 0.01)
    b = np.array([1.0, 0.0, 0.0])
    tight = {1: (np.zeros(3), np.zeros((3, 3))), 2: (b, np.diag([0.02**2, 0.02**2, 0.01**2]))}
    loose = {1: (np.zeros(3), np.zeros((3, 3))), 2: (b, np.diag([0.5**2, 0.5**2, 0.05**2]))}
    assert len(gate_closures([c], tight)[0]) == (1 if shift == 0.0 else 0)
    assert len(gate_closures([c], loose)[0]) == 1


def test_a_placement_without_proposals_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one"):
        LayerPlacement(np.zeros((0, 2)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="one proposal per supporting pose"):
        LayerPlacement(np.zeros((2, 2)), np.zeros((1, 3)))
