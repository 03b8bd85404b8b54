"""The placement benchmark's byte count of a closure sent as a record, the form an
answer carries odometry edges in."""

from __future__ import annotations

from benchmarks.team_placement import closure_wire_bytes

from sonarmap.team.records import ClosureEdge, OdometryEdge, encode, make_uid

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
