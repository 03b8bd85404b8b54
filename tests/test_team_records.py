"""Team records: transforms, UIDs and the msgpack encoding, which rejects a peer's bad
message field by field."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from sonarmap.team.records import (
    ClosureEdge,
    Landmarks,
    LocalMap,
    OdometryEdge,
    Pose,
    RecordError,
    compose,
    decode,
    encode,
    invert,
    make_uid,
    robot_of,
    size_of,
)


def _pose(n: int = 20, seed: int = 0) -> Pose:
    rng = np.random.default_rng(seed)
    lm = Landmarks(
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.integers(0, 256, (n, 128)).astype(np.uint8),
        rng.uniform(0, 1, n).astype(np.float32),
        rng.uniform(0, 100, n),
        np.arange(n),
    )
    local = LocalMap.from_logodds(rng.normal(size=(40, 40)), 0.1)
    return Pose(make_uid(3, 17), 12.5, 4, np.array([1.0, -2.0, 0.7]), lm, local, (5, 6))


def test_transforms_compose_and_invert() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.uniform(-5, 5, 3)
        b = rng.uniform(-5, 5, 3)
        np.testing.assert_allclose(compose(a, invert(a)), 0.0, atol=1e-12)
        ab = compose(a, b)
        np.testing.assert_allclose(compose(invert(a), ab)[:2], b[:2], atol=1e-12)
        assert math.isclose(
            math.remainder(compose(invert(a), ab)[2] - b[2], 2 * math.pi), 0.0, abs_tol=1e-12
        )
    # A point one metre ahead of a robot at (1, 2) facing +y lies at (1, 3).
    np.testing.assert_allclose(compose((1.0, 2.0, math.pi / 2), (1.0, 0.0, 0.0))[:2], (1.0, 3.0))


def test_uids_name_their_robot() -> None:
    assert robot_of(make_uid(5, 123)) == 5
    assert make_uid(1, 0) != make_uid(0, 1)
    with pytest.raises(ValueError, match="out of range"):
        make_uid(-1, 0)


def test_records_round_trip_and_their_size_is_the_encoding() -> None:
    p = _pose()
    q = decode(encode(p))
    assert isinstance(q, Pose)
    assert (q.uid, q.time, q.region, q.merged_from) == (p.uid, p.time, p.region, p.merged_from)
    np.testing.assert_array_equal(q.estimate, p.estimate)
    for f in ("points", "descriptors", "reliability", "stamp", "ids"):
        np.testing.assert_array_equal(getattr(q.landmarks, f), getattr(p.landmarks, f))
    assert q.local_map is not None
    assert p.local_map is not None
    np.testing.assert_array_equal(q.local_map.logodds, p.local_map.logodds)
    # Bytes grow with the landmarks: about 150 per landmark (128 descriptor + point,
    # reliability, stamp, id).
    per = (size_of(_pose(120)) - size_of(_pose(20))) / 100
    assert 150 <= per <= 170
    odo = OdometryEdge(1, 2, (1.0, 0.5, 0.1), tuple(np.eye(3).ravel() * 0.01), 25.0, 1.0)
    assert decode(encode(odo)) == odo
    cl = ClosureEdge(1, 2, (0.0, 1.0, -0.2), tuple(np.eye(3).ravel()), 12, 0.01, ((0, 3), (2, 5)))
    assert decode(encode(cl)) == cl


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.pop("uid"), "missing field 'uid'"),
        (lambda d: d.update(uid="x"), "pose.uid"),
        (lambda d: d.update(estimate=[1.0, 2.0]), "pose.estimate"),
        (lambda d: d.update(estimate=[1.0, 2.0, float("nan")]), "pose.estimate"),
        (lambda d: d["points"].update(data=b"\0" * 7), "pose.points"),
        (lambda d: d["points"].update(dtype="object"), "not allowed"),
        (
            lambda d: d["reliability"].update(data=np.full(20, 2.0, np.float32).tobytes()),
            "reliability",
        ),
        (lambda d: d["descriptors"].update(shape=[19, 128], data=b"\0" * 19 * 128), "descriptors"),
        (lambda d: d.update(kind="pickle"), "record.kind"),
        (lambda d: d.update(v=99), "record.v"),
    ],
)
def test_bad_messages_are_rejected_by_field(mutate: object, message: str) -> None:
    d = msgpack.unpackb(encode(_pose()), raw=False)
    mutate(d)  # type: ignore[operator]
    with pytest.raises(RecordError, match=message.replace("(", r"\(")):
        decode(msgpack.packb(d, use_bin_type=True))


def test_garbage_is_rejected() -> None:
    for data in (b"", b"\xc1", b"\x92\x01\x02", msgpack.packb([1, 2])):
        with pytest.raises(RecordError):
            decode(data)


def test_an_empty_landmark_set_keeps_its_descriptor_length() -> None:
    e = Landmarks.empty(64)
    assert e.descriptors.shape == (0, 64)
    assert e.take(np.zeros(0, dtype=bool)).descriptors.shape == (0, 64)
    p = _pose()
    q = decode(encode(p.with_landmarks(p.landmarks.take(np.zeros(20, dtype=bool)))))
    assert isinstance(q, Pose)
    assert q.landmarks.descriptors.shape == (0, 128)


def test_odometry_edges_hold_float32_values_and_keep_symmetry() -> None:
    c = np.array([[1e-4, 1e-6, 2e-7], [1e-6 * (1 + 1e-13), 2e-4, 0.0], [2e-7, 0.0, 1e-5]])
    e = OdometryEdge(1, 2, (0.1, -0.2, 3.0), tuple(c.ravel()), 1.0)
    assert all(float(np.float32(v)) == v for v in (*e.transform, *e.covariance))
    assert (e.cov() == e.cov().T).all()  # equal but for float64 rounding: made equal
    assert OdometryEdge(1, 2, e.transform, e.covariance, 1.0) == e  # rounding twice: same
    assert decode(encode(e)) == e
    c[0, 1] = 5e-6  # truly asymmetric: left for the graph to refuse
    m = OdometryEdge(1, 2, (0, 0, 0), tuple(c.ravel()), 1.0).cov()
    assert m[0, 1] != m[1, 0]
    odd = OdometryEdge(1, 2, (math.nan, math.inf, 1e39), (1.0,) * 9, 1.0)
    assert math.isnan(odd.transform[0])
    assert odd.transform[1:] == (math.inf, 1e39)
