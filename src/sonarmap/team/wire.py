"""The exchange's wire format (thesis 002, section 2.4): the bodies of the good- and
limited-network protocols (:mod:`.exchange`) and of the naive baseline (:mod:`.naive`),
encoded and decoded strictly.

Three kinds of message, each a msgpack map (never pickle), compressed as one zstd frame
with a preset dictionary (:data:`PRESET_DICTIONARY`), in a transport envelope (a pose's
local map is mostly unknown cells and shrinks about eight times; its landmarks'
descriptors hardly shrink):

``"advert"``
    The sender's table of patch stamps: ``(source, region) -> (stamp, held)`` for every
    patch it holds (its own local patches and its received ones), ``held`` the number of
    poses it has of that patch. Sent to every peer each ``advert_every`` seconds, so the
    others know who is newest: whole every ``full_advert_every`` seconds and to a peer
    newly in reach; in between, a *delta* (the key ``gone`` present) carries only the
    rows that changed since the last whole table sent to that peer (``base``, its send
    time ``t``) and the patches dropped since. Deltas are cumulative, so a lost one is
    made good by the next; an advert older than one already heard is ignored.
``"request"``
    A set of one-patch requests ``(source, region, requester's stamp, short list, edge
    fingerprints)``; in the limited mode also the requester's full list, and all
    patches of one request belong to one source and are adjacent regions. The edge
    fingerprints (:func:`edge_fingerprints`, 4 bytes an edge) are of the odometry edges
    the requester holds that touch its poses of the patch.
``"answer"``
    Per requested patch: the answerer's stamp, its short (good mode) or full (limited
    mode) list when it is newer, the poses sent and the odometry edges attached, poses
    and edges as their records' own msgpack encodings (:func:`.records.encode`); and,
    only when the answerer sends closures (``ExchangeParams.send_closures``), the key
    ``c``: its closures touching the poses sent, in :mod:`.peerclosures`' compact form.

Every body is decoded strictly: every field type- and range-checked, UIDs checked to be
the source's, poses to lie in their patch's region; a bad body raises
:class:`ExchangeError` (its ``code`` the short reason) and nothing of it is used.
"""

from __future__ import annotations

import functools
import hashlib
import math
import struct
import threading
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ParamSpec, TypeVar

import msgpack
import numpy as np
import zstandard

from ..errors import InputError
from .peerclosures import PeerClosureError, decode_closures, encode_closures
from .records import (
    ClosureEdge,
    Landmarks,
    LocalMap,
    OdometryEdge,
    Pose,
    RecordError,
    UnpackError,
    decode,
    encode,
    make_uid,
    robot_of,
    unpack_strict,
)
from .transport import ROBOT_LIMIT

__all__ = [
    "ENVELOPE_SLACK",
    "FINGERPRINT_BYTES",
    "KINDS",
    "MAX_INFLATED",
    "MODES",
    "PRESET_DICTIONARY",
    "VERSION",
    "ZSTD_LEVEL",
    "Advert",
    "AdvertEntry",
    "Answer",
    "ExchangeError",
    "PatchAnswer",
    "PatchKey",
    "PatchRequest",
    "Request",
    "answer_row",
    "bare",
    "check_keys",
    "check_version",
    "decode_advert",
    "decode_answer",
    "decode_request",
    "delta_advert",
    "edge_fingerprint",
    "edge_fingerprints",
    "encode_advert",
    "encode_answer",
    "encode_request",
    "inflate",
    "pack",
    "read_list",
    "read_record",
    "sorted_ids",
    "split_fingerprints",
    "stamp_or_none",
    "strict_decoder",
    "unpack",
]

#: Message kinds, the transport envelope's ``kind``.
KINDS = ("advert", "request", "answer")
#: The two protocols (the modes messages may carry).
MODES = ("good", "limited")
#: The bodies' version, field ``v`` (2: requests carry an edge digest per patch; 3: bodies
#: are deflated; 4: edge fingerprints instead of the digest; 5: delta adverts, adverts
#: stamped with their send time, odometry edges in float32, a preset deflate dictionary;
#: 6: zstd instead of deflate, with the same dictionary; 7: answer entries may carry
#: closures, key ``c``).
VERSION = 7
#: Bytes a body may expand to at most; a compressed body that would grow past it (a
#: decompression bomb) is refused before it is expanded.
MAX_INFLATED = 64 << 20
#: Bytes of an edge's fingerprint (:func:`edge_fingerprints`).
FINGERPRINT_BYTES = 4
#: Edges one patch request may name at most.
_MAX_EDGES = 1 << 20
_UID_LIMIT = 2**63
_REGION_LIMIT = 2**31
_ID_LIMIT = 2**63
#: Patches one request may name at most (whatever the sender's ``max_patches``).
_MAX_PATCHES = 4096
#: Bytes of a transport's envelope around a body, at most (map keys, ints, kind).
ENVELOPE_SLACK = 128

PatchKey = tuple[int, int]


class ExchangeError(InputError):
    """A message body that is not valid; ``code`` is the short reason (the stats key)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@functools.lru_cache(maxsize=1 << 16)
def _fingerprint(a: int, b: int, transform: tuple[float, float, float]) -> bytes:
    h = hashlib.blake2b(struct.pack("<qq3d", a, b, *transform), digest_size=FINGERPRINT_BYTES)
    return h.digest()


def edge_fingerprint(edge: OdometryEdge) -> bytes:
    """An odometry edge's 4-byte fingerprint (blake2b of its ends and transform; the
    transform is included so that an edge re-made between the same two poses, a source
    chaining across a deleted pose, differs)."""
    return _fingerprint(edge.a, edge.b, edge.transform)


def edge_fingerprints(edges: Iterable[OdometryEdge]) -> bytes:
    """The fingerprints of a set of odometry edges, sorted and concatenated: any order
    of the same edges gives the same bytes.

    Examples
    --------
    >>> e = OdometryEdge(1, 2, (1.0, 0.0, 0.0), (0.0,) * 9, 5.0)
    >>> len(edge_fingerprints([e, e])), edge_fingerprints([]) == b""
    (4, True)
    """
    return b"".join(sorted({edge_fingerprint(e) for e in edges}))


def split_fingerprints(blob: bytes) -> set[bytes]:
    n = FINGERPRINT_BYTES
    return {blob[i : i + n] for i in range(0, len(blob), n)}


# --- messages -----------------------------------------------------------------------------


@dataclass(frozen=True)
class AdvertEntry:
    """One patch its sender holds: its stamp and how many poses of it the sender has."""

    source: int
    region: int
    stamp: float
    held: int


@dataclass(frozen=True)
class Advert:
    """The sender's table of patch stamps, by (source, region): whole, or (``delta``)
    the rows that changed since the whole table the sender sent to this peer at time
    ``base`` and the patches it has dropped since (``gone``). ``t``: when the sender
    sent it (None: unordered, always taken; a delta has both times)."""

    entries: tuple[AdvertEntry, ...]
    delta: bool = False
    gone: tuple[PatchKey, ...] = ()
    t: float | None = None
    base: float | None = None


@dataclass(frozen=True)
class PatchRequest:
    """One patch asked for: the requester's stamp (None if it has none) and short list;
    in the limited mode also its full list (None in the good mode); ``edges``, the
    :func:`edge_fingerprints` of the odometry edges the requester holds touching its
    poses of the patch (default: none)."""

    source: int
    region: int
    stamp: float | None
    short: frozenset[int]
    full: frozenset[int] | None = None
    edges: bytes = b""


@dataclass(frozen=True)
class Request:
    """A request: an id the answer echoes, the protocol, the patches."""

    id: int
    mode: str
    patches: tuple[PatchRequest, ...]


@dataclass(frozen=True)
class PatchAnswer:
    """The answer for one patch.

    Good mode: ``stamp`` and ``short`` (the answerer's short list) when the answerer is
    the source or newer, else all None and no poses. Limited mode: ``stamp`` and
    ``full`` when the answerer is newer, else None; ``short`` is always None. ``poses``
    and ``edges`` are what was sent; ``closures``, the answerer's closures that touch a
    pose sent (:mod:`.peerclosures`; none unless it sends closures).
    """

    source: int
    region: int
    stamp: float | None
    short: frozenset[int] | None
    full: frozenset[int] | None
    poses: tuple[Pose, ...] = ()
    edges: tuple[OdometryEdge, ...] = ()
    closures: tuple[ClosureEdge, ...] = ()


@dataclass(frozen=True)
class Answer:
    """An answer (possibly one of several messages) to request ``id``."""

    id: int
    mode: str
    patches: tuple[PatchAnswer, ...]


def _preset_dictionary() -> bytes:
    """The deflate dictionary every body is compressed with: one message of each kind
    (the naive baseline's too) around a pose with two landmarks, an empty 6 m map and an
    odometry edge, all placeholder values. It holds the field names and the byte runs
    every body repeats, which a small body could not otherwise amortise; it is part of
    the protocol (:data:`VERSION`), so it must never change within a version."""
    n = 2
    landmarks = Landmarks(
        np.zeros((n, 3), np.float32),
        np.zeros((n, 128), np.uint8),
        np.full(n, 0.5, np.float32),
        np.zeros(n),
        np.arange(n),
    )
    uid, nxt = make_uid(1, 1), make_uid(1, 2)
    pose = Pose(uid, 1.0, 1, np.zeros(3), landmarks, LocalMap(np.zeros((60, 60), np.int8), 0.1))
    cov = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-5)
    edge = encode(OdometryEdge(uid, nxt, (0.5, 0.0, 0.1), cov, 1.0))
    patch = {"src": 1, "r": 2, "s": 1.5, "short": [uid], "full": None}
    bodies = [
        {"v": VERSION, "pose": encode(pose), "edges": [edge]},
        {"v": VERSION, "t": 1.0, "base": 0.5, "patches": [[1, 2, 3.5, 4]], "gone": [[1, 3]]},
        {"v": VERSION, "id": 1, "mode": "good", "patches": [{**patch, "edges": bytes(4)}]},
        {
            "v": VERSION,
            "id": 1,
            "mode": "good",
            "patches": [{**patch, "poses": [encode(pose)], "edges": [edge]}],
        },
    ]
    return b"".join(bytes(msgpack.packb(b, use_bin_type=True)) for b in bodies)


#: See :func:`_preset_dictionary`.
PRESET_DICTIONARY = _preset_dictionary()


#: zstd's level for every body (about 1.5 ms a body; how it compares with deflate and
#: lower levels: docs/results/2026-12-03-team-code-notes.md).
ZSTD_LEVEL = 19
_ZSTD_DICT = zstandard.ZstdCompressionDict(
    PRESET_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT
)
# A zstd context must not be shared between threads, and exchangers may run in several
# (a Dask worker's, a caller's).
_codecs = threading.local()


def _compressor() -> zstandard.ZstdCompressor:
    c: zstandard.ZstdCompressor | None = getattr(_codecs, "compressor", None)
    if c is None:
        c = _codecs.compressor = zstandard.ZstdCompressor(
            level=ZSTD_LEVEL, dict_data=_ZSTD_DICT, write_checksum=False
        )
    return c


def _decompressor() -> zstandard.ZstdDecompressor:
    d: zstandard.ZstdDecompressor | None = getattr(_codecs, "decompressor", None)
    if d is None:
        d = _codecs.decompressor = zstandard.ZstdDecompressor(dict_data=_ZSTD_DICT)
    return d


def pack(d: Mapping[str, Any]) -> bytes:
    # The frame states its content size, which inflate checks before expanding it.
    return _compressor().compress(bytes(msgpack.packb(d, use_bin_type=True)))


def bare(pose: Pose) -> Pose:
    """The pose without its landmarks, as a non-anchor travels."""
    return pose.with_landmarks(pose.landmarks.take(np.zeros(0, dtype=np.intp)))


def sorted_ids(s: Collection[int] | None) -> list[int] | None:
    return None if s is None else sorted(int(u) for u in s)


def stamp_or_none(s: float | None) -> float | None:
    return None if s is None else float(s)


def encode_advert(advert: Advert) -> bytes:
    """An advert's body."""
    rows = [[e.source, e.region, float(e.stamp), e.held] for e in advert.entries]
    d: dict[str, Any] = {"v": VERSION, "patches": rows}
    if advert.t is not None:
        d["t"] = float(advert.t)
    if advert.delta:
        if advert.t is None or advert.base is None:
            raise ValueError("a delta advert has its send time and its base's")
        d["base"] = float(advert.base)
        d["gone"] = [[s, r] for s, r in advert.gone]
    elif advert.gone or advert.base is not None:
        raise ValueError("a whole advert has no gone patches and no base")
    return pack(d)


def _request_dict(p: PatchRequest) -> dict[str, Any]:
    return {
        "src": p.source,
        "r": p.region,
        "s": stamp_or_none(p.stamp),
        "short": sorted_ids(p.short),
        "full": sorted_ids(p.full),
        "e": bytes(p.edges),
    }


def encode_request(request: Request) -> bytes:
    """A request's body."""
    return pack(
        {
            "v": VERSION,
            "id": request.id,
            "mode": request.mode,
            "patches": [_request_dict(p) for p in request.patches],
        }
    )


def answer_row(
    p: PatchAnswer, poses: Sequence[bytes] | None = None, edges: Sequence[bytes] | None = None
) -> dict[str, Any]:
    """One patch's entry of an answer as its wire map (``c`` only with closures)."""
    row: dict[str, Any] = {
        "src": p.source,
        "r": p.region,
        "s": stamp_or_none(p.stamp),
        "short": sorted_ids(p.short),
        "full": sorted_ids(p.full),
        "poses": list(poses) if poses is not None else [encode(q) for q in p.poses],
        "edges": list(edges) if edges is not None else [encode(e) for e in p.edges],
    }
    if p.closures:
        row["c"] = encode_closures(p.closures)
    return row


def encode_answer(answer: Answer) -> bytes:
    """An answer's body."""
    return pack(
        {
            "v": VERSION,
            "id": answer.id,
            "mode": answer.mode,
            "patches": [answer_row(p) for p in answer.patches],
        }
    )


# --- strict decoding ----------------------------------------------------------------------

_P = ParamSpec("_P")
_T = TypeVar("_T")


def strict_decoder(decoder: Callable[_P, _T]) -> Callable[_P, _T]:
    """``decoder`` raising nothing but :class:`ExchangeError` on a peer's bytes.

    The checks below mean to catch every bad body by name; this is the net under them:
    whatever else a forged body makes numpy, msgpack or a record's constructor raise
    (ValueError, TypeError, KeyError, OverflowError, MemoryError...) becomes an
    :class:`ExchangeError` "decode", so a receiver rejects it like any other."""

    @functools.wraps(decoder)
    def strict(*args: _P.args, **kwargs: _P.kwargs) -> _T:
        try:
            return decoder(*args, **kwargs)
        except ExchangeError:
            raise
        except Exception as e:
            name = decoder.__name__.removeprefix("decode_")
            raise ExchangeError("decode", f"{name}: {type(e).__name__}: {str(e)[:120]}") from None

    return strict


#: What a body that is not one whole msgpack object is told, by reason.
_BODY_DETAIL = {"trailing": "bytes after the body", "truncated": "the body ends early"}


def inflate(body: bytes) -> bytes:
    """The body expanded: one zstd frame that states its size, nothing after it."""
    try:
        size = zstandard.frame_content_size(body)
    except zstandard.ZstdError as e:
        raise ExchangeError("zstd", f"body: not a zstd frame ({e})") from None
    if size < 0:
        raise ExchangeError("zstd", "body: the zstd frame does not state its size")
    if size > MAX_INFLATED:
        raise ExchangeError("oversized", f"body: expands to {size} bytes, past {MAX_INFLATED}")
    z = _decompressor().decompressobj()
    try:
        # zstd stops, rather than writes, past the size the frame states.
        out = z.decompress(body)
    except zstandard.ZstdError as e:
        raise ExchangeError("zstd", f"body: a bad zstd frame ({e})") from None
    if not z.eof:
        raise ExchangeError("truncated", _BODY_DETAIL["truncated"])
    if z.unused_data:
        raise ExchangeError("trailing", _BODY_DETAIL["trailing"])
    return out


def unpack(body: bytes) -> dict[str, Any]:
    if not isinstance(body, bytes):
        raise ExchangeError("type", f"body: bytes expected, got {type(body).__name__}")
    body = inflate(body)
    n = len(body)
    try:
        # No length field may claim more than the body holds.
        d = unpack_strict(body, max_bin=n, max_str=n, max_array=n, max_map=n)
    except UnpackError as e:
        raise ExchangeError(e.reason, _BODY_DETAIL.get(e.reason, str(e))) from None
    if not isinstance(d, dict):
        raise ExchangeError("not_map", f"body: a map expected, got {type(d).__name__}")
    return d


def check_keys(d: Mapping[str, Any], keys: Collection[str], where: str) -> None:
    if set(d) != set(keys):
        missing, extra = sorted(set(keys) - set(d)), sorted(set(d) - set(keys))
        raise ExchangeError("keys", f"{where}: missing {missing}, unexpected {extra}")


def _int(v: Any, where: str, limit: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ExchangeError("type", f"{where}: {type(v).__name__} where int expected")
    if not 0 <= v < limit:
        raise ExchangeError("range", f"{where}: {v} not in [0, {limit})")
    return v


def _stamp(v: Any, where: str, *, optional: bool) -> float | None:
    if v is None and optional:
        return None
    if not isinstance(v, float):
        raise ExchangeError("type", f"{where}: {type(v).__name__} where float expected")
    if not math.isfinite(v):
        raise ExchangeError("range", f"{where}: {v} is not finite")
    return v


def read_list(v: Any, where: str) -> list[Any]:
    if not isinstance(v, list):
        raise ExchangeError("type", f"{where}: {type(v).__name__} where list expected")
    return v


def _uid_set(v: Any, source: int, where: str, *, optional: bool) -> frozenset[int] | None:
    if v is None and optional:
        return None
    uids = [_int(u, where, _UID_LIMIT) for u in read_list(v, where)]
    out = frozenset(uids)
    if len(out) != len(uids):
        raise ExchangeError("duplicate", f"{where}: a UID is listed twice")
    bad = sorted(u for u in out if robot_of(u) != source)
    if bad:
        raise ExchangeError("inconsistent", f"{where}: pose {bad[0]} is not robot {source}'s")
    return out


def check_version(d: Mapping[str, Any]) -> None:
    v = d["v"]
    if isinstance(v, bool) or not isinstance(v, int) or v != VERSION:
        raise ExchangeError("version", f"version {v!r}, expected {VERSION}")


def _mode(v: Any) -> str:
    if not isinstance(v, str):
        raise ExchangeError("type", f"mode: {type(v).__name__} where str expected")
    if v not in MODES:
        raise ExchangeError("range", f"mode {v!r} is not one of {', '.join(MODES)}")
    return v


def _region(v: Any, where: str, regions: Collection[int] | None) -> int:
    r = _int(v, where, _REGION_LIMIT)
    if regions is not None and r not in regions:
        raise ExchangeError("range", f"{where}: region {r} is not on the prior map")
    return r


def _unique_keys(keys: Sequence[PatchKey], where: str) -> None:
    if len(set(keys)) != len(keys):
        raise ExchangeError("duplicate", f"{where}: a patch is named twice")


@strict_decoder
def decode_advert(body: bytes, *, regions: Collection[int] | None = None) -> Advert:
    """The advert in ``body``; :class:`ExchangeError` if it is not a valid one.

    ``regions``, if given, are the prior map's regions: any other is out of range."""
    d = unpack(body)
    delta = "gone" in d
    if delta:
        check_keys(d, ("v", "t", "base", "patches", "gone"), "advert")
    else:
        check_keys(d, ("v", "t", "patches") if "t" in d else ("v", "patches"), "advert")
    check_version(d)
    t = _stamp(d.get("t"), "advert.t", optional=not delta)
    base = _stamp(d.get("base"), "advert.base", optional=not delta)
    if base is not None and t is not None and base > t:
        raise ExchangeError("inconsistent", f"advert: base {base} after its send time {t}")
    gone: list[PatchKey] = []
    for i, row in enumerate(read_list(d["gone"], "advert.gone") if delta else []):
        where = f"advert.gone[{i}]"
        if not isinstance(row, list) or len(row) != 2:
            raise ExchangeError("type", f"{where}: [source, region] expected")
        gone.append(
            (
                _int(row[0], f"{where}.source", ROBOT_LIMIT),
                _region(row[1], f"{where}.region", regions),
            )
        )
    rows = read_list(d["patches"], "advert.patches")
    entries: list[AdvertEntry] = []
    for i, row in enumerate(rows):
        where = f"advert.patches[{i}]"
        if not isinstance(row, list) or len(row) != 4:
            raise ExchangeError("type", f"{where}: [source, region, stamp, held] expected")
        src = _int(row[0], f"{where}.source", ROBOT_LIMIT)
        region = _region(row[1], f"{where}.region", regions)
        stamp = _stamp(row[2], f"{where}.stamp", optional=False)
        assert stamp is not None
        held = _int(row[3], f"{where}.held", _UID_LIMIT)
        entries.append(AdvertEntry(src, region, stamp, held))
    _unique_keys([(e.source, e.region) for e in entries] + gone, "advert")
    return Advert(tuple(entries), delta, tuple(gone), t, base)


def delta_advert(
    told: tuple[float, Mapping[PatchKey, AdvertEntry]],
    table: Mapping[PatchKey, AdvertEntry],
    now: float,
) -> bytes | None:
    """The delta advert sent at ``now`` from the whole table ``told`` (its send time,
    its rows) to ``table``; None when it would list at least half as many rows as the
    whole table (the whole one then costs little more and refreshes the peer's base)."""
    base, rows = told
    changed = tuple(e for k, e in table.items() if rows.get(k) != e)
    gone = tuple(k for k in rows if k not in table)
    if 2 * (len(changed) + len(gone)) >= max(1, len(table)):
        return None
    return encode_advert(Advert(changed, delta=True, gone=gone, t=now, base=base))


def _connected(regions: Sequence[int], adjacency: Mapping[int, Collection[int]]) -> bool:
    todo, seen = [regions[0]], {regions[0]}
    wanted = set(regions)
    while todo:
        r = todo.pop()
        for n in adjacency.get(r, ()):
            if n in wanted and n not in seen:
                seen.add(n)
                todo.append(n)
    return seen == wanted


@strict_decoder
def decode_request(
    body: bytes,
    *,
    regions: Collection[int] | None = None,
    adjacency: Mapping[int, Collection[int]] | None = None,
) -> Request:
    """The request in ``body``; :class:`ExchangeError` if it is not a valid one.

    Checked besides types and ranges: UIDs are the source's, no patch twice, edge
    fingerprints come in whole 4-byte pieces, the good mode sends no full list and the
    limited mode one including the short list; a limited request names one source and (with
    ``adjacency``) adjacent regions."""
    d = unpack(body)
    check_keys(d, ("v", "id", "mode", "patches"), "request")
    check_version(d)
    rid = _int(d["id"], "request.id", _ID_LIMIT)
    mode = _mode(d["mode"])
    rows = read_list(d["patches"], "request.patches")
    if not 0 < len(rows) <= _MAX_PATCHES:
        raise ExchangeError("range", f"request: {len(rows)} patches, 1..{_MAX_PATCHES} allowed")
    patches: list[PatchRequest] = []
    for i, row in enumerate(rows):
        where = f"request.patches[{i}]"
        if not isinstance(row, dict):
            raise ExchangeError("type", f"{where}: a map expected")
        check_keys(row, ("src", "r", "s", "short", "full", "e"), where)
        src = _int(row["src"], f"{where}.src", ROBOT_LIMIT)
        region = _region(row["r"], f"{where}.r", regions)
        stamp = _stamp(row["s"], f"{where}.s", optional=True)
        short = _uid_set(row["short"], src, f"{where}.short", optional=False)
        assert short is not None
        full = _uid_set(row["full"], src, f"{where}.full", optional=mode == "good")
        if mode == "good" and full is not None:
            raise ExchangeError("inconsistent", f"{where}.full: no full list in the good mode")
        if full is not None and not short <= full:
            raise ExchangeError("inconsistent", f"{where}: the short list is not in the full one")
        prints = row["e"]
        if not isinstance(prints, bytes):
            raise ExchangeError("type", f"{where}.e: {type(prints).__name__} where bytes expected")
        if len(prints) % FINGERPRINT_BYTES or len(prints) > _MAX_EDGES * FINGERPRINT_BYTES:
            raise ExchangeError(
                "range",
                f"{where}.e: {len(prints)} bytes, a multiple of {FINGERPRINT_BYTES} expected "
                f"(at most {_MAX_EDGES} edges)",
            )
        patches.append(PatchRequest(src, region, stamp, short, full, prints))
    _unique_keys([(p.source, p.region) for p in patches], "request")
    if mode == "limited":
        if len({p.source for p in patches}) != 1:
            raise ExchangeError("inconsistent", "request: a limited request names one source")
        if adjacency is not None and not _connected([p.region for p in patches], adjacency):
            raise ExchangeError("adjacency", "request: the regions are not adjacent")
    return Request(rid, mode, tuple(patches))


def read_record(data: Any, kind: type[Pose] | type[OdometryEdge], where: str) -> Any:
    if not isinstance(data, bytes):
        raise ExchangeError("type", f"{where}: {type(data).__name__} where bytes expected")
    try:
        rec = decode(data)
    except RecordError as e:
        raise ExchangeError("record", f"{where}: {e}") from None
    if not isinstance(rec, kind):
        raise ExchangeError("record", f"{where}: a {type(rec).__name__} where {kind.__name__}")
    return rec


def _answer_entry(row: Any, mode: str, where: str, regions: Collection[int] | None) -> PatchAnswer:
    if not isinstance(row, dict):
        raise ExchangeError("type", f"{where}: a map expected")
    keys = ("src", "r", "s", "short", "full", "poses", "edges")
    check_keys(row, (*keys, "c") if "c" in row else keys, where)
    src = _int(row["src"], f"{where}.src", ROBOT_LIMIT)
    region = _region(row["r"], f"{where}.r", regions)
    stamp = _stamp(row["s"], f"{where}.s", optional=True)
    short = _uid_set(row["short"], src, f"{where}.short", optional=True)
    full = _uid_set(row["full"], src, f"{where}.full", optional=True)
    poses: list[Pose] = [
        read_record(p, Pose, f"{where}.poses[{k}]")
        for k, p in enumerate(read_list(row["poses"], f"{where}.poses"))
    ]
    edges: list[OdometryEdge] = [
        read_record(e, OdometryEdge, f"{where}.edges[{k}]")
        for k, e in enumerate(read_list(row["edges"], f"{where}.edges"))
    ]
    for p in poses:
        if robot_of(p.uid) != src or p.region != region:
            raise ExchangeError(
                "inconsistent", f"{where}: pose {p.uid} is not of robot {src} in region {region}"
            )
    for e in edges:
        if robot_of(e.a) != src or robot_of(e.b) != src:
            raise ExchangeError("inconsistent", f"{where}: edge {e.a} -> {e.b} is not {src}'s")
    # What each mode may carry.
    if mode == "good":
        if full is not None or (stamp is None) != (short is None):
            raise ExchangeError("inconsistent", f"{where}: a good answer has stamp and short list")
        listed = short
    else:
        if short is not None or (stamp is None) != (full is None):
            raise ExchangeError(
                "inconsistent", f"{where}: a limited answer has stamp and full list"
            )
        listed = full
    if stamp is None and mode == "good" and (poses or edges):
        raise ExchangeError("inconsistent", f"{where}: poses without a stamp")
    if listed is not None:
        extra = sorted(p.uid for p in poses if p.uid not in listed)
        if extra:
            raise ExchangeError("inconsistent", f"{where}: pose {extra[0]} is not in its list")
    closures: tuple[ClosureEdge, ...] = ()
    if "c" in row:
        try:
            closures = decode_closures(row["c"], {p.uid for p in poses}, f"{where}.c")
        except PeerClosureError as e:
            raise ExchangeError(e.code, str(e)) from None
    return PatchAnswer(src, region, stamp, short, full, tuple(poses), tuple(edges), closures)


@strict_decoder
def decode_answer(body: bytes, *, regions: Collection[int] | None = None) -> Answer:
    """The answer in ``body``; :class:`ExchangeError` if it is not a valid one.

    Checked besides types and ranges: every pose and edge decodes as its record, is the
    patch's source's and (a pose) lies in the patch's region; no pose twice; each mode
    carries what it may (see :class:`PatchAnswer`) and sent poses are in the list sent."""
    d = unpack(body)
    check_keys(d, ("v", "id", "mode", "patches"), "answer")
    check_version(d)
    rid = _int(d["id"], "answer.id", _ID_LIMIT)
    mode = _mode(d["mode"])
    rows = read_list(d["patches"], "answer.patches")
    if len(rows) > _MAX_PATCHES:
        raise ExchangeError("range", f"answer: {len(rows)} patches, at most {_MAX_PATCHES}")
    patches = tuple(
        _answer_entry(row, mode, f"answer.patches[{i}]", regions) for i, row in enumerate(rows)
    )
    _unique_keys([(p.source, p.region) for p in patches], "answer")
    uids = [q.uid for p in patches for q in p.poses]
    if len(set(uids)) != len(uids):
        raise ExchangeError("duplicate", "answer: a pose is sent twice")
    return Answer(rid, mode, patches)
