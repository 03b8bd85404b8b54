"""The placement benchmark: the byte count of a closure sent as a record (the form an
answer carries odometry edges in) and the edges that hold a received layer at its shape."""

from __future__ import annotations

import itertools
import math
from typing import cast

import numpy as np
import numpy.typing as npt
import pytest
from benchmarks.team_placement import (
    closure_wire_bytes,
    placement,
    shape_edges,
    source_closures,
)

from sonarmap.io.rosmap import OccupancyMap
from sonarmap.team.globalmap import optimise_graph
from sonarmap.team.mission import RobotAgent
from sonarmap.team.records import (
    ClosureEdge,
    Landmarks,
    OdometryEdge,
    Pose,
    compose,
    encode,
    invert,
    make_uid,
)

F64 = npt.NDArray[np.float64]

COV = (0.003, 0.001, -0.0008, 0.001, 0.014, -0.002, -0.0008, -0.002, 0.0005)


def test_a_closure_costs_its_records_bytes_without_its_matches() -> None:
    # Robot 1's and robot 3's UIDs exceed 2^32: msgpack's 9-byte unsigned integers.
    a, b = make_uid(1, 5), make_uid(3, 900)
    matches = tuple((i, i + 1) for i in range(16))
    c = ClosureEdge(a, b, (1.25, -0.04, 0.0066), COV, 16, 0.02, matches)
    # A 9-entry map: "v" 6, "kind" "closure", "a" and "b" as uint64, the transform's 3
    # and the covariance's 9 float64, "inliers" 16, "error" a float64, "matches" [].
    header, v, kind, ab = 1, 2 + 1, 5 + 8, 2 * (2 + 9)
    transform, covariance = 10 + 1 + 3 * 9, 11 + 1 + 9 * 9
    inliers, error, no_matches = 8 + 1, 6 + 9, 8 + 1
    expected = header + v + kind + ab + transform + covariance + inliers + error + no_matches
    assert expected == 203
    assert closure_wire_bytes(c) == expected
    # The matches would add 3 bytes a pair (and 2 to the array's header past 15
    # entries); the receiver's graph does not use them.
    assert len(encode(c)) == expected + 16 * 3 + 2


def test_a_closure_costs_about_what_an_odometry_edge_does() -> None:
    a, b = make_uid(1, 5), make_uid(1, 6)
    closure = ClosureEdge(a, b, (1.25, -0.04, 0.0066), COV, 16, 0.02)
    edge = OdometryEdge(a, b, (1.25, -0.04, 0.0066), COV, 2.0, 0.5)
    # The edge's two bounds (2 float64 and their keys) against the closure's inlier
    # count, error and empty matches: 8 bytes apart, not the 3.5 times of a bare array.
    assert len(encode(edge)) - closure_wire_bytes(closure) == 8
    small = ClosureEdge(make_uid(0, 5), make_uid(0, 6), closure.transform, COV, 16, 0.02)
    # Robot 0's first UIDs are one-byte integers: 8 bytes each fewer.
    assert closure_wire_bytes(closure) - closure_wire_bytes(small) == 2 * 8


# --- the shape levers ----------------------------------------------------------------

ODO_COV = tuple(np.diag([0.05**2, 0.05**2, 0.02**2]).ravel().tolist())
CLO_COV = tuple(np.diag([0.05**2, 0.05**2, 0.01**2]).ravel().tolist())


def _pose(uid: int, t: float, est: npt.ArrayLike) -> Pose:
    marks = Landmarks(
        np.zeros((1, 3), dtype=np.float32),
        np.zeros((1, 128), dtype=np.uint8),
        np.full(1, 0.5, dtype=np.float32),
        np.zeros(1),
        np.full(1, -1, dtype=np.int64),
    )
    return Pose(uid, t, 0, np.asarray(est, dtype=np.float64), marks)


def _rms(est: dict[int, F64], truth: dict[int, F64]) -> float:
    d = np.array([est[u][:2] - truth[u][:2] for u in truth])
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def test_shape_edges_join_a_layers_oldest_pose_to_each_other_at_their_estimates() -> None:
    rng = np.random.default_rng(0)
    uids = [make_uid(2, k) for k in range(5)]
    # Made out of order: the oldest (time 1.0) is the third UID.
    layer = {
        u: _pose(u, t, rng.normal(0, 3, 3)) for u, t in zip(uids, (4, 3, 1, 2, 5), strict=True)
    }
    edges = shape_edges(layer, (0.2, 0.3, 0.05))
    root = uids[2]
    assert [e.a for e in edges] == [root] * 4
    assert sorted(e.b for e in edges) == sorted(set(uids) - {root})
    for e in edges:
        # The transform puts b where its estimate is, seen from the root's estimate.
        placed = compose(layer[root].estimate, e.transform)
        assert np.allclose(placed[:2], layer[e.b].estimate[:2], atol=1e-5)
        assert abs(math.remainder(placed[2] - layer[e.b].estimate[2], 2 * math.pi)) < 1e-5
        assert np.allclose(e.cov(), np.diag([0.04, 0.09, 0.0025]), rtol=1e-6)
    assert shape_edges({root: layer[root]}) == []


def test_a_received_layer_held_at_its_shape_does_not_drift_with_its_odometry() -> None:
    # The received layer (robot 2): 12 poses 1 m apart on a line; its odometry turns
    # 0.03 rad a step too far, its stored estimates are the truth in its source's frame,
    # off ours by `off`. Ours (robot 1): three poses, joined to the layer's first three
    # by closures at their true relative poses.
    off = np.array([3.0, -2.0, 0.7])
    layer = [make_uid(2, k) for k in range(12)]
    truth = {u: np.array([float(k), 1.0, 0.0]) for k, u in enumerate(layer)}
    poses = {u: _pose(u, 100.0 + k, compose(off, truth[u])) for k, u in enumerate(layer)}
    odo = [OdometryEdge(a, b, (1.0, 0.0, 0.03), ODO_COV, 2.0) for a, b in itertools.pairwise(layer)]
    ours = [make_uid(1, k) for k in range(3)]
    our_truth = {u: np.array([float(k), 0.0, 0.0]) for k, u in enumerate(ours)}
    poses.update({u: _pose(u, float(k), our_truth[u]) for k, u in enumerate(ours)})
    odo += [OdometryEdge(a, b, (1.0, 0.0, 0.0), ODO_COV, 2.0) for a, b in itertools.pairwise(ours)]
    links = [
        ClosureEdge(o, r, tuple(compose(invert(our_truth[o]), truth[r])), CLO_COV, 30, 0.1)
        for o, r in zip(ours, layer[:3], strict=True)
    ]
    shape = shape_edges({u: poses[u] for u in layer})
    plain = optimise_graph(poses, odo, links, anchor=ours[0])
    held = optimise_graph(poses, odo + shape, links, anchor=ours[0])
    far = {u: truth[u] for u in layer[6:]}
    assert _rms(held.estimates, far) < 0.1
    assert _rms(plain.estimates, far) > 5 * _rms(held.estimates, far)
    assert _rms(held.estimates, our_truth) < 0.05
    assert held.inconsistent == ()


# --- the closure levers --------------------------------------------------------------


def test_a_sources_closures_are_added_once_per_pair_of_poses_in_either_direction() -> None:
    ours = [make_uid(1, k) for k in range(2)]
    two = [make_uid(2, k) for k in range(3)]
    three = [make_uid(3, k) for k in range(2)]
    times = {ours[0]: 0.0, ours[1]: 50.0, two[0]: 1.0, two[1]: 2.0, two[2]: 90.0}
    times.update({three[0]: 5.0, three[1]: 70.0})
    poses = {u: _pose(u, t, np.zeros(3)) for u, t in times.items()}
    unheld = make_uid(2, 99)

    def closure(a: int, b: int) -> ClosureEdge:
        return ClosureEdge(a, b, (1.0, 0.0, 0.0), CLO_COV, 20, 0.1)

    held = [closure(ours[0], two[0])]
    sources = {
        2: [
            closure(two[0], ours[0]),  # ours, reversed: a duplicate
            closure(ours[0], two[0]),  # ours, the same way round: a duplicate
            closure(two[0], two[2]),  # its revisit: added
            closure(two[2], two[0]),  # the same, reversed: a duplicate
            closure(two[0], two[1]),  # to the pose a second before: added unless revisits
            closure(two[1], unheld),  # to a pose we do not hold: skipped
            closure(three[0], three[1]),  # between robot 3's poses: not robot 2's to send
        ],
        3: [closure(three[1], ours[1])],  # robot 3's to ours: added
    }
    layers = {2: set(two), 3: set(three)}
    added, duplicates, reversed_only = source_closures(held, poses, layers, sources)
    assert [(c.a, c.b) for c in added] == [
        (two[0], two[2]),
        (two[0], two[1]),
        (three[1], ours[1]),
    ]
    assert (duplicates, reversed_only) == (3, 2)
    revisits, duplicates, reversed_only = source_closures(
        held, poses, layers, sources, min_gap=30.0
    )
    assert [(c.a, c.b) for c in revisits] == [(two[0], two[2])]
    # Both duplicates of ours are 1 s apart: not revisits, so not counted either.
    assert (duplicates, reversed_only) == (1, 1)


def test_a_lever_without_the_team_is_refused_before_anything_is_built() -> None:
    plan = cast(OccupancyMap, None)
    agent = cast(RobotAgent, None)  # never reached: the arguments are checked first
    with pytest.raises(ValueError, match=r"source-closures.*with the team"):
        placement(agent, {}, plan, "odometry", lever="source-closures")
    with pytest.raises(ValueError, match="'shape'"):
        placement(agent, {}, plan, "odometry", lever="shape", team={})
