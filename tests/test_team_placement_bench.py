"""The placement benchmark's byte count of a closure sent as it would travel."""

from __future__ import annotations

import msgpack
import numpy as np
from benchmarks.team_placement import closure_wire_bytes

from sonarmap.team.records import ClosureEdge, make_uid


def test_a_closure_travels_in_41_bytes_and_its_two_uids() -> None:
    cov = np.array([[0.003, 0.001, -0.0008], [0.001, 0.014, -0.002], [-0.0008, -0.002, 0.0005]])
    # Robot numbers near 2^23 give UIDs near 2^63, the largest msgpack integers.
    a, b = make_uid(2**23 - 1, 5), make_uid(2**23 - 2, 900)
    c = ClosureEdge(a, b, (1.25, -0.04, 0.0066), tuple(cov.ravel().tolist()), 16, 0.02)
    # An array header, two 9-byte integers, 12 and 24 bytes of float32 with their
    # 2-byte headers; the inliers, the error and the matches do not travel.
    assert closure_wire_bytes(c) == 1 + 2 * 9 + 14 + 26
    small = ClosureEdge(3, 4, c.transform, c.covariance, 16, 0.02)
    assert closure_wire_bytes(small) == 1 + 2 * 1 + 14 + 26
    body = msgpack.packb(
        [a, b, np.array([1.25, -0.04, 0.0066], dtype=np.float32).tobytes(), b"\0" * 24]
    )
    assert closure_wire_bytes(c) == len(body)
