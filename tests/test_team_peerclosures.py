"""Closures as they travel with poses (:mod:`sonarmap.team.peerclosures`): the compact
form's round trip and precision, its size against the record's, and which closures an
answer entry carries. Hostile closures in whole answers: tests/test_team_exchange.py."""

from __future__ import annotations

import dataclasses
import math
import struct

import msgpack
import numpy as np
import pytest

from sonarmap.team.peerclosures import (
    MAX_PER_POSE,
    MAX_REACH,
    MIN_VARIANCE,
    TURN_STEP,
    XY_STEP,
    PeerClosureError,
    closures_to_send,
    decode_closures,
    encode_closure,
    encode_closures,
)
from sonarmap.team.records import ClosureEdge, encode, make_uid

A, B, C = make_uid(1, 4), make_uid(1, 9), make_uid(2, 3)


def closure(a: int = A, b: int = B, seed: int = 0) -> ClosureEdge:
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(3, 3)) * 0.01
    cov = m @ m.T + np.diag([1e-4, 1e-4, 1e-5])
    tf = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)), float(rng.uniform(-3, 3)))
    matches = ((0, 1), (2, 3))
    return ClosureEdge(a, b, tf, tuple(cov.ravel().tolist()), 17, 0.3, matches)


def test_a_closure_comes_back_within_its_quantisation_without_matches() -> None:
    cs = [closure(A, make_uid(3, s), seed=s) for s in range(20)]
    back = decode_closures(encode_closures(cs), {A}, "c")
    for c, d in zip(cs, back, strict=True):
        assert (d.a, d.b, d.inliers, d.matches, d.error) == (c.a, c.b, 17, (), 0.0)
        assert abs(d.transform[0] - c.transform[0]) <= XY_STEP / 2 + 1e-12
        assert abs(d.transform[1] - c.transform[1]) <= XY_STEP / 2 + 1e-12
        turn = math.remainder(d.transform[2] - c.transform[2], 2 * math.pi)
        assert abs(turn) <= TURN_STEP / 2 + 1e-12
        assert d.cov() == pytest.approx(c.cov(), rel=1e-6)
        assert np.array_equal(d.cov(), d.cov().T)


def test_the_compact_form_is_a_quarter_of_the_record_without_matches() -> None:
    c = closure()
    compact = len(msgpack.packb(encode_closure(c), use_bin_type=True))
    record = len(encode(ClosureEdge(c.a, c.b, c.transform, c.covariance, c.inliers, c.error)))
    assert compact <= 60
    assert compact * 3 < record


def test_an_entry_carries_its_poses_closures_each_pair_once_and_none_the_requester_lacks() -> None:
    sent = {A}
    lacking = {C}
    cs = [
        closure(A, B),
        closure(B, A, seed=1),  # the same pair the other way round: once
        closure(C, A, seed=2),  # the other end is one the requester lacks
        closure(B, C, seed=3),  # no end sent
    ]
    out = closures_to_send(cs, sent, lambda u: u not in lacking)
    assert [(c.a, c.b) for c in out.closures] == [(A, B)]
    assert out.dropped == 0
    # Both ends sent: it goes whatever the requester holds.
    assert closures_to_send(cs, {A, C}, lambda u: False).closures == [cs[2]]
    # A pair another entry of the answer carries does not go again.
    assert closures_to_send(cs, {A, C}, lambda u: False, {frozenset((A, C))}).closures == []


def test_too_many_closures_for_the_poses_sent_are_refused() -> None:
    rows = encode_closures([closure(A, make_uid(3, k)) for k in range(MAX_PER_POSE + 1)])
    with pytest.raises(PeerClosureError, match="at most") as err:
        decode_closures(rows, {A}, "c")
    assert err.value.code == "oversized"
    assert len(decode_closures(rows[:MAX_PER_POSE], {A}, "c")) == MAX_PER_POSE


def _row_with(cov: tuple[float, ...] | None = None, **at: object) -> list[object]:
    row = encode_closure(closure())
    if cov is not None:
        row[5] = struct.pack("<6f", *cov)
    for k, v in at.items():
        row[["a", "b", "x", "y", "theta", "covariance", "inliers"].index(k)] = v
    return row


@pytest.mark.parametrize(
    ("row", "field", "code"),
    [
        # Variances of 1e-4 on the diagonal, but x and y almost the same direction: an
        # eigenvalue of about 2e-11 would pin that direction.
        (_row_with((1e-4, 1e-4 * (1 - 2e-7), 0.0, 1e-4, 0.0, 1e-4)), "covariance", "range"),
        (_row_with((math.inf, 0.0, 0.0, 1e-4, 0.0, 1e-4)), "covariance", "range"),
        (_row_with((1e-4, 0.0, 0.0, 1e-4, 0.0, math.nan)), "covariance", "range"),
        (_row_with(a=-1), "a", "range"),
        (_row_with(inliers=65_536), "inliers", "range"),
    ],
)
def test_a_bad_closure_is_refused_naming_its_field(
    row: list[object], field: str, code: str
) -> None:
    with pytest.raises(PeerClosureError, match=rf"c\[0\]\.{field}") as err:
        decode_closures([row], {A}, "c")
    assert err.value.code == code


def test_closures_on_an_entry_with_no_poses_are_refused() -> None:
    with pytest.raises(PeerClosureError, match="no poses") as err:
        decode_closures(encode_closures([closure()]), set(), "c")
    assert err.value.code == "inconsistent"
    assert decode_closures(encode_closures([closure()]), {A}, "c")


def _forged(a: int, b: int, **changes: object) -> ClosureEdge:
    c = closure(a, b)
    return dataclasses.replace(c, **changes)  # type: ignore[arg-type]


def test_the_sender_keeps_only_closures_the_receiver_accepts() -> None:
    near_singular = (1e-4, 1e-4 * (1 - 2e-7), 0.0, 1e-4 * (1 - 2e-7), 1e-4, 0.0, 0.0, 0.0, 1e-4)
    bad = [
        _forged(A, make_uid(3, 1), covariance=near_singular),
        _forged(A, make_uid(3, 2), transform=(MAX_REACH + 1.0, 0.0, 0.0)),
        _forged(A, make_uid(3, 3), covariance=tuple((np.eye(3) * MIN_VARIANCE / 10).ravel())),
    ]
    good = [closure(A, make_uid(4, k), seed=k) for k in range(3)]
    out = closures_to_send([*bad, *good], {A}, lambda u: True)
    assert out.closures == sorted(good, key=lambda c: (c.a, c.b))
    assert out.dropped == len(bad)
    # What it sends, the receiver takes whole.
    assert len(decode_closures(encode_closures(out.closures), {A}, "c")) == len(good)


def test_the_sender_caps_closures_per_pose_keeping_the_most_inliers() -> None:
    cs = [
        dataclasses.replace(closure(A, make_uid(3, k), seed=k), inliers=10 + k)
        for k in range(MAX_PER_POSE + 5)
    ]
    out = closures_to_send(cs, {A}, lambda u: True)
    assert len(out.closures) == MAX_PER_POSE
    assert out.dropped == 5
    assert min(c.inliers for c in out.closures) == 15
    assert len(decode_closures(encode_closures(out.closures), {A}, "c")) == MAX_PER_POSE
