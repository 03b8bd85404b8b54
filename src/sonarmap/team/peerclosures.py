"""Loop closures that travel with the poses they touch (a deviation from thesis 002,
which keeps each robot's closure store private; the factor exchange of multi-robot
systems such as Swarm-SLAM).

An answer's patch entry may carry, beside its poses and odometry edges, the answerer's
closures that touch a pose it sends there (:func:`closures_to_send`). A receiver adds
each one whose two poses it holds, unless a closure already joins the same two poses
in either direction (:meth:`.store.RobotStore.add_peer_closures`): a closure received
twice, found by the receiver itself or coming back from a peer it was sent to is one
factor in the receiver's graph.

The wire form is compact: ``[a, b, x, y, theta, covariance, inliers]``, ``x`` and
``y`` in whole :data:`XY_STEP` (1 mm), ``theta`` in whole :data:`TURN_STEP`
(1e-4 rad), the covariance's upper triangle (xx, xy, xt, yy, yt, tt) as six
little-endian float32 (24 bytes). Feature matches and the fit's error do not travel (a
receiver's graph uses neither): a received closure has no matches and error 0.

Every closure is checked on receipt (:func:`decode_closures`): types, UIDs, one end a
pose of the entry, no pair twice, the translation within :data:`MAX_REACH` metres, the
covariance finite and symmetric with variances at most :data:`MAX_VARIANCE` and every
eigenvalue at least :data:`MIN_VARIANCE`, at most :data:`MAX_PER_POSE` closures per
pose of the entry. A bad one raises :class:`PeerClosureError` naming the field. The
sender applies the same rules (:func:`closures_to_send` checks each closure's wire form
with the decoder's own check), so an honest answer is never refused for its closures.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Collection, Iterable, Sequence
from typing import Any, NamedTuple

import numpy as np

from .records import ClosureEdge

__all__ = [
    "MAX_PER_POSE",
    "MAX_REACH",
    "MAX_VARIANCE",
    "MIN_VARIANCE",
    "TURN_STEP",
    "XY_STEP",
    "PeerClosureError",
    "Selection",
    "closures_to_send",
    "decode_closures",
    "encode_closure",
    "encode_closures",
    "pair_of",
]

#: Metres of one unit of a closure's travelling x and y.
XY_STEP = 1e-3
#: Radians of one unit of a closure's travelling theta.
TURN_STEP = 1e-4
#: Metres a closure's translation may span at most: two poses that see the same
#: landmarks are a few sonar or camera ranges apart (8 m each by default), so anything
#: past this is a forged or broken closure, not a loop.
MAX_REACH = 100.0
#: Smallest eigenvalue (m^2 or rad^2) a travelling covariance may have: below it one
#: forged closure would outweigh every other factor along some direction. Association
#: adds 0.01 m to x and y and 0.002 rad to theta of every closure
#: (``AssociationParams.min_sigma_xy``, ``min_sigma_theta``), so an honest one has
#: eigenvalues of 4e-6 or more; the floor leaves room for fused or carried closures.
MIN_VARIANCE = 1e-6
#: Largest variance a travelling covariance's diagonal may hold: above it the closure
#: says nothing.
MAX_VARIANCE = 1e4
#: Closures one entry may carry per pose it sends.
MAX_PER_POSE = 64
_UID_LIMIT = 2**63
_INLIER_LIMIT = 2**16
_COV = struct.Struct("<6f")
_XY_LIMIT = round(MAX_REACH / XY_STEP)
_TURN_LIMIT = math.ceil(math.pi / TURN_STEP)


class PeerClosureError(ValueError):
    """A travelling closure that is not valid; ``code`` is the short reason."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


def pair_of(c: ClosureEdge) -> frozenset[int]:
    """The two poses a closure joins, in either direction (:attr:`ClosureEdge.pair`)."""
    return c.pair


def encode_closure(c: ClosureEdge) -> list[Any]:
    """A closure's wire form (the module's layout)."""
    x, y, t = c.transform
    m = np.asarray(c.covariance, dtype=np.float64).reshape(3, 3)
    cov = _COV.pack(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
    return [
        int(c.a),
        int(c.b),
        round(x / XY_STEP),
        round(y / XY_STEP),
        round(math.remainder(t, 2 * math.pi) / TURN_STEP),
        cov,
        int(min(max(c.inliers, 0), _INLIER_LIMIT - 1)),
    ]


class Selection(NamedTuple):
    """The closures an answer entry carries and how many it could not."""

    #: The closures to send, sorted by (a, b).
    closures: list[ClosureEdge]
    #: Closures that would go but break a receiver's rule (:func:`decode_closures`) or
    #: exceed :data:`MAX_PER_POSE` per pose sent.
    dropped: int


def closures_to_send(
    closures: Iterable[ClosureEdge],
    sent: Collection[int],
    may_hold: Callable[[int], bool],
    skip: Collection[frozenset[int]] = (),
) -> Selection:
    """The closures that go with the poses ``sent`` in one answer entry: those with an
    end in ``sent`` whose other end is sent too or one the requester may hold
    (``may_hold(uid)``), each pair once and none in ``skip``, each one whose wire form
    passes the receiver's check (:func:`decode_closures`); of those at most
    :data:`MAX_PER_POSE` per pose sent, the ones with most inliers.

    Parameters
    ----------
    closures : iterable of ClosureEdge
        The answerer's closure store.
    sent : collection of int
        The UIDs the entry carries.
    may_hold : callable
        ``may_hold(uid) -> bool`` for a pose not sent: False when the answerer knows the
        requester lacks it (a pose of the same patch missing from its short list, an
        own pose not yet offered).
    skip : collection of frozenset of int
        Pairs (:func:`pair_of`) already carried by another entry of the same answer
        (default none).

    Returns
    -------
    Selection
        The closures, sorted by (a, b), and the count dropped for breaking a rule or the
        cap.
    """
    out: dict[frozenset[int], ClosureEdge] = {}
    dropped = 0
    for c in closures:
        if c.a == c.b or (c.a not in sent and c.b not in sent):
            continue
        other = c.b if c.a in sent else c.a
        if other not in sent and not may_hold(other):
            continue
        pair = pair_of(c)
        if pair in skip or pair in out:
            continue
        try:
            _decode_row(encode_closure(c), sent, "c")
        except (PeerClosureError, ValueError, OverflowError):  # a non-finite transform
            dropped += 1
            continue
        out[pair] = c
    kept = sorted(out.values(), key=lambda c: (-c.inliers, c.a, c.b))
    cap = MAX_PER_POSE * max(1, len(sent))
    dropped += max(0, len(kept) - cap)
    return Selection(sorted(kept[:cap], key=lambda c: (c.a, c.b)), dropped)


def _int(v: Any, where: str, low: int, high: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise PeerClosureError("type", f"{where}: {type(v).__name__} where int expected")
    if not low <= v <= high:
        raise PeerClosureError("range", f"{where}: {v} not in [{low}, {high}]")
    return v


def _covariance(v: Any, where: str) -> tuple[float, ...]:
    if not isinstance(v, bytes):
        raise PeerClosureError("type", f"{where}: {type(v).__name__} where bytes expected")
    if len(v) != _COV.size:
        raise PeerClosureError("range", f"{where}: {len(v)} bytes, {_COV.size} expected")
    xx, xy, xt, yy, yt, tt = (float(u) for u in _COV.unpack(v))
    m = np.array([[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]])
    if not np.isfinite(m).all():
        raise PeerClosureError("range", f"{where}: not finite")
    if (np.diag(m) > MAX_VARIANCE).any():
        raise PeerClosureError("range", f"{where}: a variance above {MAX_VARIANCE:g}")
    # The diagonal alone does not bound the information: a nearly singular matrix has
    # large variances yet almost none along one direction.
    low = float(np.linalg.eigvalsh(m)[0])
    if not low >= MIN_VARIANCE:
        raise PeerClosureError(
            "range", f"{where}: smallest eigenvalue {low:.3g} below {MIN_VARIANCE:g}"
        )
    return tuple(float(u) for u in m.ravel())


def _uid(v: Any, where: str) -> int:
    return _int(v, where, 0, _UID_LIMIT - 1)


def decode_closures(rows: Any, sent: Collection[int], where: str) -> tuple[ClosureEdge, ...]:
    """The closures of an entry's wire list ``rows``, each checked (the module's rules).

    Parameters
    ----------
    rows : Any
        The entry's ``c`` as received: a list of ``[a, b, x, y, theta, covariance,
        inliers]``.
    sent : collection of int
        The UIDs of the poses the entry carries; an entry with none carries no closure.
    where : str
        The message's position, for the error (``answer.patches[3].c``).

    Returns
    -------
    tuple of ClosureEdge
        In the order sent, without matches and with error 0.

    Raises
    ------
    PeerClosureError
        On the first bad closure, naming it (``where[k].field``).
    """
    if not isinstance(rows, list):
        raise PeerClosureError("type", f"{where}: {type(rows).__name__} where list expected")
    if not sent:
        raise PeerClosureError("inconsistent", f"{where}: closures on an entry with no poses")
    if len(rows) > MAX_PER_POSE * len(sent):
        raise PeerClosureError(
            "oversized",
            f"{where}: {len(rows)} closures for {len(sent)} poses, at most {MAX_PER_POSE} a pose",
        )
    out: list[ClosureEdge] = []
    pairs: set[frozenset[int]] = set()
    for k, row in enumerate(rows):
        at = f"{where}[{k}]"
        c = _decode_row(row, sent, at)
        pair = pair_of(c)
        if pair in pairs:
            raise PeerClosureError("duplicate", f"{at}: poses {c.a} and {c.b} are joined twice")
        pairs.add(pair)
        out.append(c)
    return tuple(out)


def _decode_row(row: Any, sent: Collection[int], at: str) -> ClosureEdge:
    """One checked closure of wire form ``row`` (the module's rules but the count and
    pair ones, which need the whole entry)."""
    if not isinstance(row, list) or len(row) != 7:
        raise PeerClosureError("type", f"{at}: [a, b, x, y, theta, covariance, inliers] expected")
    a, b = _uid(row[0], f"{at}.a"), _uid(row[1], f"{at}.b")
    if a == b:
        raise PeerClosureError("inconsistent", f"{at}: joins pose {a} to itself")
    if a not in sent and b not in sent:
        raise PeerClosureError("inconsistent", f"{at}: touches no pose of the entry")
    x = _int(row[2], f"{at}.x", -_XY_LIMIT, _XY_LIMIT) * XY_STEP
    y = _int(row[3], f"{at}.y", -_XY_LIMIT, _XY_LIMIT) * XY_STEP
    if math.hypot(x, y) > MAX_REACH:
        raise PeerClosureError("range", f"{at}: spans {math.hypot(x, y):.0f} m > {MAX_REACH}")
    t = _int(row[4], f"{at}.theta", -_TURN_LIMIT, _TURN_LIMIT) * TURN_STEP
    cov = _covariance(row[5], f"{at}.covariance")
    inliers = _int(row[6], f"{at}.inliers", 0, _INLIER_LIMIT - 1)
    return ClosureEdge(a, b, (x, y, math.remainder(t, 2 * math.pi)), cov, inliers, 0.0)


def encode_closures(closures: Sequence[ClosureEdge]) -> list[list[Any]]:
    """:func:`encode_closure` of each."""
    return [encode_closure(c) for c in closures]
