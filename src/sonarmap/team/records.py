"""What a robot stores about its mission (thesis 002, chapter 2): poses with their
landmarks and local occupancy maps, odometry edges and loop-closure edges, and their
compact binary encoding.

Conventions (shared by every module of :mod:`sonarmap.team`):

- A 2-D transform is ``(x, y, theta)``: metres, metres, radians. The transform of
  pose B *in the frame of* pose A maps B's local coordinates into A's:
  ``p_A = R(theta) p_B + (x, y)``.
- A pose's local frame is the robot's body frame where the pose was made: x forward,
  y to the left, z up; landmarks are 3-D points in that frame.
- A pose UID is ``robot << 40 | counter`` (:func:`make_uid`): unique in the team with
  no coordination, and the robot that made a pose is read back from its UID.
- A covariance of a transform (3 x 3 over x, y, theta) is expressed in the frame of
  the transform's end (pose B's frame): the tangent space gtsam's ``Pose2`` uses.
- A local occupancy map is stored as int8 log-odds (scaled by :data:`LOGODDS_SCALE`),
  0 unknown, on a square grid centred on the pose's origin, in the pose's frame.

The encoding is msgpack (never pickle): every record is a map of plain values, numpy
arrays as ``{"dtype", "shape", "data"}`` triples. The byte size of the encoding is the
memory figure of the stores and what the exchange sends. Decoding checks every field and
raises :class:`RecordError` naming it, so a peer's bad message is rejected, not obeyed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import msgpack
import numpy as np
import numpy.typing as npt

__all__ = [
    "LOGODDS_SCALE",
    "ClosureEdge",
    "Landmarks",
    "LocalMap",
    "OdometryEdge",
    "Pose",
    "RecordError",
    "UnpackError",
    "adjoint",
    "compose",
    "compose_covariance",
    "counter_of",
    "decode",
    "decode_as",
    "encode",
    "invert",
    "invert_covariance",
    "make_uid",
    "robot_of",
    "size_of",
    "unpack_strict",
]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

#: int8 log-odds of a local map = round(log-odds x LOGODDS_SCALE), clipped to +-127.
LOGODDS_SCALE = 16.0
_UID_SHIFT = 40
#: Dimensions an encoded array may have at most (a record's have two).
_MAX_DIMS = 4
#: The encoding's version, first field of every message.
VERSION = 1


class RecordError(ValueError):
    """A record that cannot be decoded or is inconsistent; the message names the field."""


class UnpackError(ValueError):
    """Bytes that are not one whole msgpack object; ``reason`` is ``"trailing"``,
    ``"truncated"`` or ``"msgpack"``."""

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(detail)


def unpack_strict(data: bytes, *, max_bin: int, max_str: int, max_array: int, max_map: int) -> Any:
    """One msgpack object from ``data``, nothing before or after it, with no length
    field claiming more than the given limits (so a forged length cannot allocate
    beyond the message); :class:`UnpackError` otherwise. Extension types are refused."""
    try:
        return msgpack.unpackb(
            data,
            raw=False,
            strict_map_key=True,
            use_list=True,
            max_bin_len=max_bin,
            max_str_len=max_str,
            max_array_len=max_array,
            max_map_len=max_map,
            max_ext_len=0,
        )
    except msgpack.ExtraData:
        raise UnpackError("trailing", "bytes after the object") from None
    except msgpack.OutOfData:
        raise UnpackError("truncated", "the data end early") from None
    except (ValueError, TypeError, msgpack.UnpackException) as e:
        # msgpack's C unpacker reports short data as a plain ValueError.
        if "incomplete" in str(e):
            raise UnpackError("truncated", "the data end early") from None
        # A nest too deep raises StackError with no text: its name says what happened.
        raise UnpackError("msgpack", f"not msgpack: {str(e) or type(e).__name__}") from None


def make_uid(robot: int, counter: int) -> int:
    """The UID of a robot's ``counter``-th pose."""
    if not (0 <= robot < 2**23 and 0 <= counter < 2**_UID_SHIFT):
        raise ValueError(f"robot {robot} or counter {counter} out of range")
    return (robot << _UID_SHIFT) | counter


def counter_of(uid: int) -> int:
    """The counter of pose ``uid`` (:func:`make_uid`) among its robot's poses."""
    return uid & ((1 << _UID_SHIFT) - 1)


def robot_of(uid: int) -> int:
    """The robot that made pose ``uid``."""
    return uid >> _UID_SHIFT


def _wrap(t: F64) -> F64:
    """Angles into [-pi, pi], as math.remainder(t, 2 pi) does (ties to even)."""
    return t - 2 * np.pi * np.round(t / (2 * np.pi))


def compose(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """a (+) b: the transform b, given in a's frame, expressed in a's parent frame.

    Each of ``a`` and ``b`` is one transform (3,) or rows of them (N, 3); one
    transform is composed with every row of the other."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            _wrap(a[..., 2] + b[..., 2]),
        ],
        axis=-1,
    )


def invert(a: npt.ArrayLike) -> F64:
    """The inverse transform (of each row): compose(a, invert(a)) is the identity."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x, y = a[..., 0], a[..., 1]
    return np.stack([-(c * x + s * y), s * x - c * y, _wrap(-a[..., 2])], axis=-1)


@dataclass
class Landmarks:
    """A pose's landmarks, one row each.

    Attributes
    ----------
    points : ndarray (n, 3) float32
        In the pose's frame, metres.
    descriptors : ndarray (n, d) uint8
        Appearance (SIFT-like: d = 128 bytes by default).
    reliability : ndarray (n,) float32
        In [0, 1]; 0.5 for a new landmark.
    stamp : ndarray (n,) float64
        Mission time (s) of the last observation by any robot.
    ids : ndarray (n,) int64
        The simulation's identity of the physical landmark, -1 when unknown. Kept only
        to score association; no algorithm reads it.
    """

    points: F32
    descriptors: npt.NDArray[np.uint8]
    reliability: F32
    stamp: F64
    ids: npt.NDArray[np.int64]

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float32).reshape(-1, 3)
        n = len(self.points)
        desc = np.asarray(self.descriptors, dtype=np.uint8)
        # reshape(0, -1) is ambiguous: an empty set keeps its descriptor length.
        dim = desc.shape[-1] if desc.ndim == 2 else (desc.size // n if n else 128)
        self.descriptors = desc.reshape(n, dim)
        self.reliability = np.asarray(self.reliability, dtype=np.float32).reshape(n)
        self.stamp = np.asarray(self.stamp, dtype=np.float64).reshape(n)
        self.ids = np.asarray(self.ids, dtype=np.int64).reshape(n)

    @classmethod
    def empty(cls, dim: int = 128) -> Landmarks:
        return cls(
            np.zeros((0, 3), dtype=np.float32),
            np.zeros((0, dim), dtype=np.uint8),
            np.zeros(0, dtype=np.float32),
            np.zeros(0, dtype=np.float64),
            np.zeros(0, dtype=np.int64),
        )

    def __len__(self) -> int:
        return len(self.points)

    def take(self, keep: npt.NDArray[np.bool_] | npt.NDArray[np.intp]) -> Landmarks:
        """The landmarks selected by a mask or indices."""
        return Landmarks(
            self.points[keep],
            self.descriptors[keep],
            self.reliability[keep],
            self.stamp[keep],
            self.ids[keep],
        )

    @staticmethod
    def concat(parts: list[Landmarks]) -> Landmarks:
        return Landmarks(
            np.concatenate([p.points for p in parts]),
            np.concatenate([p.descriptors for p in parts]),
            np.concatenate([p.reliability for p in parts]),
            np.concatenate([p.stamp for p in parts]),
            np.concatenate([p.ids for p in parts]),
        )


@dataclass
class LocalMap:
    """A pose's local occupancy map: int8 scaled log-odds, row 0 at the top (+y), on a
    square of ``size`` cells of ``resolution`` metres centred on the pose's origin and
    axis-aligned with its frame."""

    logodds: npt.NDArray[np.int8]
    resolution: float

    def __post_init__(self) -> None:
        self.logodds = np.asarray(self.logodds, dtype=np.int8)
        if self.logodds.ndim != 2 or self.logodds.shape[0] != self.logodds.shape[1]:
            raise RecordError(f"local map: a square array expected, got {self.logodds.shape}")
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise RecordError(f"local map: resolution must be > 0, got {self.resolution}")

    @property
    def size(self) -> int:
        return int(self.logodds.shape[0])

    def probability(self) -> F32:
        """Occupancy probability, NaN where unknown (log-odds 0)."""
        lo = self.logodds.astype(np.float32) / LOGODDS_SCALE
        p = 1.0 / (1.0 + np.exp(-lo))
        return np.where(self.logodds == 0, np.float32(np.nan), p).astype(np.float32)

    @classmethod
    def from_logodds(cls, logodds: npt.ArrayLike, resolution: float) -> LocalMap:
        q = np.clip(np.rint(np.asarray(logodds, dtype=np.float64) * LOGODDS_SCALE), -127, 127)
        return cls(q.astype(np.int8), resolution)


@dataclass
class Pose:
    """One pose of a robot's graph.

    Attributes
    ----------
    uid : int
        :func:`make_uid`; a merged pose gets a new one.
    time : float
        Mission time (s) the pose was made.
    region : int
        The prior map's region its origin lay in at creation (never changes).
    estimate : ndarray (3,)
        The pose's frame in the global frame, as the robot currently estimates it.
    landmarks : Landmarks
    local_map : LocalMap or None
    merged_from : tuple of int
        UIDs this pose replaced (empty unless merged).
    """

    uid: int
    time: float
    region: int
    estimate: F64
    landmarks: Landmarks
    local_map: LocalMap | None = None
    merged_from: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        self.estimate = np.asarray(self.estimate, dtype=np.float64).reshape(3)

    @property
    def robot(self) -> int:
        return robot_of(self.uid)

    def with_landmarks(self, landmarks: Landmarks) -> Pose:
        return replace(self, landmarks=landmarks)


#: Magnitudes float32 holds; a value beyond stays float64 (none an odometry edge has).
_F32_MAX = 3.0e38


def _f32_tuple(values: npt.ArrayLike) -> tuple[float, ...]:
    """The values rounded to float32, as Python floats (beyond its range: unchanged)."""
    a = np.asarray(values, dtype=np.float64).ravel()
    with np.errstate(over="ignore", invalid="ignore"):
        r = np.where(np.abs(a) < _F32_MAX, a.astype(np.float32), a)
    return tuple(float(v) for v in r)


@dataclass(frozen=True)
class OdometryEdge:
    """Wheel odometry from pose ``a`` to pose ``b``: ``transform`` of b in a's frame,
    its ``covariance`` (3 x 3, x y theta) and hard bounds: the two poses are at most
    ``max_distance`` metres and ``max_turn`` radians apart (e.g. top speed x time)."""

    a: int
    b: int
    transform: tuple[float, float, float]
    covariance: tuple[float, ...]
    max_distance: float
    max_turn: float = math.pi

    def __post_init__(self) -> None:
        # Held to float32 (odometry is known to far coarser than its 1e-7 relative step):
        # a float64 exact in float32 ends in zero bytes, which compression removes, so an
        # edge travels in about 30 % fewer bytes. Rounding twice changes nothing, so
        # every copy of an edge, and its fingerprint, is the same.
        object.__setattr__(self, "transform", _f32_tuple(self.transform))
        cov = np.asarray(self.covariance, dtype=np.float64)
        if cov.shape == (9,):
            # Entries equal but for float64 rounding must not round apart in float32
            # (the graph checks symmetry); a truly asymmetric one is left to be refused.
            # The test is symmetric in the pair, so both entries of a pair change or neither.
            m = cov.reshape(3, 3)
            with np.errstate(invalid="ignore", over="ignore"):
                near = np.abs(m - m.T) <= 1e-9 * np.maximum(np.abs(m), np.abs(m.T))
                cov = np.where(near, (m + m.T) / 2, m)
        object.__setattr__(self, "covariance", _f32_tuple(cov))

    def cov(self) -> F64:
        return np.array(self.covariance, dtype=np.float64).reshape(3, 3)


@dataclass(frozen=True)
class ClosureEdge:
    """A loop closure from data association: ``transform`` of pose b in a's frame,
    its ``covariance`` (estimated from the RANSAC draws), the inlier count and the
    weighted error E of the chosen transform."""

    a: int
    b: int
    transform: tuple[float, float, float]
    covariance: tuple[float, ...]
    inliers: int
    error: float
    matches: tuple[tuple[int, int], ...] = field(default=())

    def cov(self) -> F64:
        return np.array(self.covariance, dtype=np.float64).reshape(3, 3)

    @property
    def pair(self) -> frozenset[int]:
        """The two poses the closure joins, in either direction: a closure and its
        reverse, found by two robots, join the same pair."""
        return frozenset((self.a, self.b))


# --- encoding ------------------------------------------------------------------------

_DTYPES = ("uint8", "int8", "int64", "float32", "float64")


def adjoint(t: npt.ArrayLike) -> F64:
    """SE(2) adjoint of ``t`` (tangent order x, y, theta, as gtsam's Pose2): a
    perturbation on the right of ``t`` (in its end's frame) as one on the left (at its
    start)."""
    x, y, th = (float(v) for v in np.asarray(t, dtype=np.float64))
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, y], [s, c, -x], [0.0, 0.0, 1.0]])


def compose_covariance(a: npt.ArrayLike, ca: F64, b: npt.ArrayLike, cb: F64) -> F64:
    """First-order covariance of compose(a, b) for independent a and b.

    Every covariance here is in the frame of its transform's end (a perturbation on
    the right, as gtsam's BetweenFactor takes it): a's error reaches the end of b
    through the adjoint of b's inverse.
    """
    j = adjoint(invert(np.asarray(b, dtype=np.float64)))
    return np.asarray(j @ ca @ j.T + cb, dtype=np.float64)


def invert_covariance(a: npt.ArrayLike, ca: F64) -> F64:
    """First-order covariance of invert(a), in the inverse's end frame (a's start)."""
    j = adjoint(a)
    return np.asarray(j @ ca @ j.T, dtype=np.float64)


def _arr(a: npt.NDArray[Any]) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.name, "shape": list(a.shape), "data": a.tobytes()}


def _unarr(d: Any, where: str) -> npt.NDArray[Any]:
    if not isinstance(d, Mapping) or set(d) != {"dtype", "shape", "data"}:
        raise RecordError(f"{where}: an array (dtype, shape, data) expected")
    dtype, shape, data = d["dtype"], d["shape"], d["data"]
    if dtype not in _DTYPES:
        raise RecordError(f"{where}: dtype {dtype!r} not allowed")
    if not (
        isinstance(shape, list)
        and len(shape) <= _MAX_DIMS
        and all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**31 for s in shape)
    ):
        raise RecordError(f"{where}: bad shape {str(shape)[:80]}")
    # Python ints: numpy's product of a forged shape wraps around in int64 (65536**4 is
    # 0), which would let an empty buffer pass for an absurd shape.
    count = 1
    for s in shape:
        count *= s
    if not isinstance(data, bytes) or len(data) != count * np.dtype(dtype).itemsize:
        raise RecordError(f"{where}: data does not fill shape {shape} of {dtype}")
    return np.frombuffer(data, dtype=dtype).reshape(shape).copy()


def _get(d: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in d:
        raise RecordError(f"{where}: missing field '{key}'")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, kind):
        raise RecordError(f"{where}.{key}: {type(v).__name__} where {kind} expected")
    if isinstance(v, float) and not math.isfinite(v):
        raise RecordError(f"{where}.{key}: not finite")
    return v


def _pose_dict(p: Pose) -> dict[str, Any]:
    lm = p.landmarks
    return {
        "uid": p.uid,
        "time": float(p.time),
        "region": int(p.region),
        "estimate": [float(v) for v in p.estimate],
        "points": _arr(lm.points),
        "descriptors": _arr(lm.descriptors),
        "reliability": _arr(lm.reliability),
        "stamp": _arr(lm.stamp),
        "ids": _arr(lm.ids),
        "map": None
        if p.local_map is None
        else {"logodds": _arr(p.local_map.logodds), "resolution": p.local_map.resolution},
        "merged_from": list(p.merged_from),
    }


def _pose_from(d: Mapping[str, Any], where: str) -> Pose:
    uid = _get(d, "uid", int, where)
    if uid < 0:
        raise RecordError(f"{where}.uid: negative")
    est = _get(d, "estimate", list, where)
    if len(est) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in est):
        raise RecordError(f"{where}.estimate: three finite numbers expected")
    pts = _unarr(d.get("points"), f"{where}.points")
    n = len(pts)
    if pts.dtype != np.float32 or pts.shape != (n, 3) or not np.isfinite(pts).all():
        raise RecordError(f"{where}.points: finite float32 (n, 3) expected")
    desc = _unarr(d.get("descriptors"), f"{where}.descriptors")
    if desc.dtype != np.uint8 or desc.ndim != 2 or len(desc) != n:
        raise RecordError(f"{where}.descriptors: uint8 ({n}, d) expected")
    rel = _unarr(d.get("reliability"), f"{where}.reliability")
    if rel.shape != (n,) or rel.dtype != np.float32 or not ((rel >= 0) & (rel <= 1)).all():
        raise RecordError(f"{where}.reliability: {n} values in [0, 1] expected")
    stamp = _unarr(d.get("stamp"), f"{where}.stamp")
    if stamp.shape != (n,) or stamp.dtype != np.float64 or not np.isfinite(stamp).all():
        raise RecordError(f"{where}.stamp: {n} finite float64 expected")
    ids = _unarr(d.get("ids"), f"{where}.ids")
    if ids.shape != (n,) or ids.dtype != np.int64:
        raise RecordError(f"{where}.ids: {n} int64 expected")
    local: LocalMap | None = None
    m = d.get("map")
    if m is not None:
        if not isinstance(m, Mapping):
            raise RecordError(f"{where}.map: a map expected")
        lo = _unarr(m.get("logodds"), f"{where}.map.logodds")
        if lo.dtype != np.int8:
            raise RecordError(f"{where}.map.logodds: int8 expected")
        local = LocalMap(lo, float(_get(m, "resolution", (int, float), f"{where}.map")))
    merged = _get(d, "merged_from", list, where)
    if not all(isinstance(v, int) and v >= 0 for v in merged):
        raise RecordError(f"{where}.merged_from: UIDs expected")
    return Pose(
        uid,
        float(_get(d, "time", (int, float), where)),
        _get(d, "region", int, where),
        np.array(est, dtype=np.float64),
        Landmarks(pts, desc, rel, stamp, ids),
        local,
        tuple(merged),
    )


def _edge_dict(e: OdometryEdge | ClosureEdge) -> dict[str, Any]:
    d: dict[str, Any] = {
        "a": e.a,
        "b": e.b,
        "transform": [float(v) for v in e.transform],
        "covariance": [float(v) for v in e.covariance],
    }
    if isinstance(e, OdometryEdge):
        d.update(max_distance=float(e.max_distance), max_turn=float(e.max_turn))
    else:
        d.update(inliers=e.inliers, error=float(e.error), matches=[list(m) for m in e.matches])
    return d


def _numbers(d: Mapping[str, Any], key: str, n: int, where: str) -> tuple[float, ...]:
    v = _get(d, key, list, where)
    if len(v) != n or not all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v
    ):
        raise RecordError(f"{where}.{key}: {n} finite numbers expected")
    return tuple(float(x) for x in v)


def _edge_from(d: Mapping[str, Any], kind: str, where: str) -> OdometryEdge | ClosureEdge:
    a = _get(d, "a", int, where)
    b = _get(d, "b", int, where)
    tf = _numbers(d, "transform", 3, where)
    cov = _numbers(d, "covariance", 9, where)
    if kind == "odometry":
        return OdometryEdge(
            a,
            b,
            (tf[0], tf[1], tf[2]),
            cov,
            float(_get(d, "max_distance", (int, float), where)),
            float(_get(d, "max_turn", (int, float), where)),
        )
    matches = _get(d, "matches", list, where)
    if not all(
        isinstance(m, list) and len(m) == 2 and all(isinstance(i, int) for i in m) for m in matches
    ):
        raise RecordError(f"{where}.matches: index pairs expected")
    return ClosureEdge(
        a,
        b,
        (tf[0], tf[1], tf[2]),
        cov,
        _get(d, "inliers", int, where),
        float(_get(d, "error", (int, float), where)),
        tuple((int(m[0]), int(m[1])) for m in matches),
    )


Record = Pose | OdometryEdge | ClosureEdge
_R = TypeVar("_R", Pose, OdometryEdge, ClosureEdge)


def encode(record: Record) -> bytes:
    """The record's msgpack bytes."""
    if isinstance(record, Pose):
        body: dict[str, Any] = {"kind": "pose", **_pose_dict(record)}
    elif isinstance(record, OdometryEdge):
        body = {"kind": "odometry", **_edge_dict(record)}
    elif isinstance(record, ClosureEdge):
        body = {"kind": "closure", **_edge_dict(record)}
    else:
        raise TypeError(f"not a record: {type(record).__name__}")
    return bytes(msgpack.packb({"v": VERSION, **body}, use_bin_type=True))


def decode(data: bytes) -> Record:
    """The record in ``data``; :class:`RecordError` naming the field if it is not one."""
    try:
        d = msgpack.unpackb(data, raw=False, strict_map_key=True, max_bin_len=2**28)
    except (ValueError, TypeError, msgpack.UnpackException) as e:
        raise RecordError(f"not a msgpack record: {e}") from None
    if not isinstance(d, Mapping):
        raise RecordError("record: a map expected")
    if d.get("v") != VERSION:
        raise RecordError(f"record.v: version {d.get('v')!r}, expected {VERSION}")
    kind = d.get("kind")
    try:
        if kind == "pose":
            return _pose_from(d, "pose")
        if kind in ("odometry", "closure"):
            return _edge_from(d, kind, kind)
    except RecordError:
        raise
    except Exception as e:
        # The bytes are a peer's: whatever the records' constructors raise on them
        # (ValueError, TypeError, OverflowError...) means a bad record, not a bug here.
        raise RecordError(f"{kind}: {type(e).__name__}: {str(e)[:120]}") from None
    raise RecordError(f"record.kind: {str(kind)[:40]!r} is not pose, odometry or closure")


def decode_as(data: object, kind: type[_R]) -> _R:
    """The record in ``data``, which must be bytes of a ``kind`` record; else
    :class:`RecordError`."""
    if not isinstance(data, bytes):
        raise RecordError("a record's bytes expected")
    rec = decode(data)
    if not isinstance(rec, kind):
        raise RecordError(f"a {kind.__name__} expected, got {type(rec).__name__}")
    return rec


def size_of(record: Record) -> int:
    """Bytes the record takes: the length of its encoding (the memory figure)."""
    return len(encode(record))
