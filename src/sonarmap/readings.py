"""Sonar readings and robot trajectories, and their CSV formats.

Readings CSV: ``t,sensor,x,y,theta,range`` -- time (s), sonar name, the sonar's world
pose at the reading (metres, radians) and the range (metres). A range ``>= r_max``
(``inf`` included) means no echo. Trajectory CSV: ``t,x,y,theta`` -- robot poses.

Files are read in chunks (plain, or compressed by gzip, bzip2 or xz, by suffix), so
memory holds the parsed arrays, never the text of a large file. Blank lines, lines of
spaces and ``#`` comment lines are skipped anywhere, the header's head included; errors
name the file's own line.
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import re
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Literal

import numpy as np
import numpy.typing as npt
import pandas as pd

from .errors import InputError, quote
from .files import atomic_write, need_file

__all__ = [
    "READINGS_COLUMNS",
    "REORDER_WINDOW",
    "TRAJECTORY_COLUMNS",
    "Readings",
    "TimeOrder",
    "Trajectory",
    "in_time_order",
    "iter_readings",
    "read_readings",
    "read_trajectory",
    "write_readings",
    "write_readings_stream",
    "write_trajectory",
]

READINGS_COLUMNS = ("t", "sensor", "x", "y", "theta", "range")
TRAJECTORY_COLUMNS = ("t", "x", "y", "theta")
DEFAULT_CHUNK = 500_000
#: Seconds a reading may arrive behind a later one and still be put back in its place:
#: recorded logs interleave sensors' messages by arrival, a few tenths of a second apart.
REORDER_WINDOW = 2.0

F64 = npt.NDArray[np.float64]
#: The file line of each row of a parsed chunk.
Lines = npt.NDArray[np.intp]


@dataclass(frozen=True, eq=False)
class Readings:
    """A batch of sonar readings, one entry per reading.

    Attributes
    ----------
    t : ndarray of float64, shape (N,)
        Time in seconds, non-decreasing.
    sensor : ndarray of int32, shape (N,)
        Index into :attr:`names`.
    x, y, theta : ndarray of float64, shape (N,)
        World pose of the sonar at the reading (metres, radians).
    range : ndarray of float64, shape (N,)
        Measured range in metres; ``>= r_max`` means no echo.
    names : tuple of str
        Sonar names.
    """

    t: F64
    sensor: npt.NDArray[np.int32]
    x: F64
    y: F64
    theta: F64
    range: F64
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in ("sensor", "x", "y", "theta", "range"):
            if len(getattr(self, name)) != n:
                raise InputError(
                    f"readings field '{name}' has {len(getattr(self, name))} entries, expected {n}"
                )

    def __len__(self) -> int:
        return len(self.t)

    def take(self, index: npt.ArrayLike | slice) -> Readings:
        """The readings at ``index`` (a boolean mask, integer indices or a slice)."""
        i = index if isinstance(index, slice) else np.asarray(index)
        return Readings(
            self.t[i],
            self.sensor[i],
            self.x[i],
            self.y[i],
            self.theta[i],
            self.range[i],
            self.names,
        )

    @classmethod
    def concat(cls, parts: Sequence[Readings]) -> Readings:
        """Join batches in order; sonar names are merged."""
        names: list[str] = []
        for p in parts:
            names.extend(n for n in p.names if n not in names)
        if not parts:
            e = np.empty(0)
            return cls(e, np.empty(0, np.int32), e, e, e, e, ())
        lookup = {n: i for i, n in enumerate(names)}
        sensor = np.concatenate(
            [
                np.array([lookup[n] for n in p.names], dtype=np.int32)[p.sensor]
                if len(p)
                else np.empty(0, np.int32)
                for p in parts
            ]
        )
        return cls(
            np.concatenate([p.t for p in parts]),
            sensor,
            np.concatenate([p.x for p in parts]),
            np.concatenate([p.y for p in parts]),
            np.concatenate([p.theta for p in parts]),
            np.concatenate([p.range for p in parts]),
            tuple(names),
        )


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Robot poses over time: ``t`` (s), ``x``, ``y`` (metres), ``theta`` (radians)."""

    t: F64
    x: F64
    y: F64
    theta: F64

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class TimeOrder:
    """What putting a stream of readings back in time order did.

    Attributes
    ----------
    window : float or None
        How late (seconds behind the latest time seen) a reading may be and still be
        put in its place; later ones are dropped. None refuses any reading out of order.
    reordered : int
        Readings that came after a later one and were put back in place.
    dropped : int
        Readings later than ``window``, left out.
    max_lag : float
        The most any out-of-order reading was behind (seconds).
    first : int or None
        Index in the stream (from 0) of the first reading out of order.
    """

    window: float | None = REORDER_WINDOW
    reordered: int = 0
    dropped: int = 0
    max_lag: float = 0.0
    first: int | None = None

    def message(self, first_line: int | None = None) -> str | None:
        """One line saying what was done, or None when the stream was in order.

        ``first_line`` is the line of the stream's first reading (2 for a CSV with a
        header), so the first reading out of order is named by its line; without it,
        by its index.
        """
        if self.first is None:
            return None
        parts = []
        if self.reordered:
            parts.append(f"put {self.reordered} readings back in time order")
        if self.dropped:
            parts.append(f"dropped {self.dropped} readings more than {self.window:g} s late")
        where = (
            f"line {first_line + self.first}"
            if first_line is not None
            else f"reading {self.first} (from 0)"
        )
        return f"{'; '.join(parts)} (at most {self.max_lag:.3g} s late; the first at {where})"


def in_time_order(chunks: Iterable[Readings], order: TimeOrder | None = None) -> Iterator[Readings]:
    """Readings in non-decreasing time, from chunks that are almost in order.

    A reading behind the latest time seen by at most ``order.window`` seconds is put
    back in its place (ties keep their order in the stream); one later than that is
    dropped, because readings before it may already have been handed on. Memory holds
    one chunk and the last ``window`` seconds of readings. ``order`` collects the counts.
    """
    rep = order if order is not None else TimeOrder()
    window = rep.window
    # Sorted as a whole; kept as separate chunks so that a stream in order is passed on
    # without copying, and merged only when a late reading has to be put in place.
    pending: deque[Readings] = deque()
    latest = -np.inf
    seen = 0
    for chunk in chunks:
        n = len(chunk)
        if n == 0:
            continue
        before = np.maximum.accumulate(np.concatenate([[latest], chunk.t[:-1]]))
        lag = before - chunk.t
        late = lag > 0
        in_order = True
        if late.any():
            i = int(np.flatnonzero(late)[0])
            if window is None:
                raise InputError(
                    f"reading {seen + i}: time goes backwards ({chunk.t[i]} after {before[i]})"
                )
            if rep.first is None:
                rep.first = seen + i
            rep.max_lag = max(rep.max_lag, float(lag[late].max()))
            drop = lag > window
            rep.dropped += int(drop.sum())
            rep.reordered += int((late & ~drop).sum())
            latest = max(latest, float(before[-1]), float(chunk.t[-1]))
            chunk = chunk.take(~drop)
            in_order = not (late & ~drop).any()
        else:
            latest = float(chunk.t[-1])
        seen += n
        if window is None or window == 0:
            yield chunk
            continue
        if len(chunk) == 0:
            continue
        if in_order:
            pending.append(chunk)
        else:
            merged = Readings.concat([*pending, chunk])
            pending = deque([merged.take(np.argsort(merged.t, kind="stable"))])
        watermark = latest - window
        while pending and pending[0].t[-1] <= watermark:
            yield pending.popleft()
        if pending and pending[0].t[0] <= watermark:
            cut = int(np.searchsorted(pending[0].t, watermark, side="right"))
            yield pending[0].take(slice(0, cut))
            pending[0] = pending[0].take(slice(cut, None))
    if pending:
        yield Readings.concat(list(pending))


_TOKENIZE = re.compile(r"Expected (\d+) fields in line (\d+), saw (\d+)")


def _chunks(
    path: Path, columns: Sequence[str], text_columns: Sequence[str], chunk_size: int
) -> Iterator[tuple[Lines, dict[str, npt.NDArray[np.generic]]]]:
    """Parse a CSV file with a header in chunks; yield (file line of each row, columns).

    Blank lines, and comment lines (``#`` first), are skipped anywhere in the file.

    Every value is checked: missing fields, non-numbers and non-finite numbers raise
    :class:`InputError` naming the file, line and field.
    """
    need_file(path, "CSV file")
    try:
        source = _Uncommented(_open_binary(path))
    except OSError as err:
        raise InputError(f"cannot read file ({type(err).__name__}: {err})", path=path) from err
    try:
        reader = pd.read_csv(
            source,
            dtype=str,
            keep_default_na=False,
            # Comment lines are emptied and blank lines dropped after parsing, so that
            # the line numbers of errors stay the file's own.
            skip_blank_lines=False,
            chunksize=chunk_size,
            engine="c",
        )
    except pd.errors.EmptyDataError as err:
        source.close()
        raise InputError(
            f"file is empty; expected a header {','.join(columns)}", path=path
        ) from err
    except (EOFError, OSError, UnicodeDecodeError, lzma.LZMAError) as err:
        source.close()
        raise InputError(f"cannot read file ({type(err).__name__}: {err})", path=path) from err
    with source, reader:
        first = 2 + source.head
        yield from _parse_chunks(path, reader, columns, text_columns, first_line=first)


#: Decompressors by file suffix; other files are read as they are.
_OPENERS: dict[str, Callable[[Path, str], Any]] = {
    ".gz": gzip.open,
    ".bz2": bz2.open,
    ".xz": lzma.open,
}
#: A line of spaces or tabs, or a comment (``#`` after them), up to its end; lines end
#: in LF, CRLF or CR alike.
_BLANK_OR_COMMENT = re.compile(rb"(?:(?<=[\r\n])|\A)[ \t]*(?:#[^\r\n]*)?(?=[\r\n]|\Z)")
#: The blank and comment lines before the header, with a byte-order mark.
_HEAD = re.compile(rb"\A(?:\xef\xbb\xbf)?(?:[ \t]*(?:#[^\r\n]*)?(?:\r\n|\r|\n))*")


def _open_binary(path: Path) -> BinaryIO:
    opener = _OPENERS.get(path.suffix.lower())
    if opener is None:
        return open(path, "rb")
    handle: BinaryIO = opener(path, "rb")
    return handle


def _line_ends(text: bytes) -> int:
    crlf = text.count(b"\r\n")
    return text.count(b"\r") + text.count(b"\n") - crlf


class _Uncommented(io.RawIOBase):
    """A binary stream's bytes without the blank and comment lines before the header
    (counted in :attr:`head`) and with later comment lines and lines of spaces emptied,
    their line ends kept, so that the parser's line numbers stay the file's."""

    _BLOCK = 1 << 20

    def __init__(self, source: BinaryIO) -> None:
        self._source = source
        self._ready = b""
        self._tail = b""
        self._done = False
        self._in_head = True
        #: Lines before the header (so far read).
        self.head = 0

    def readable(self) -> bool:
        return True

    def close(self) -> None:
        self._source.close()
        super().close()

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        while not self._ready and not self._done:
            block = self._tail + self._source.read(self._BLOCK)
            if len(block) == len(self._tail):
                self._done, cut = True, len(block)
            else:
                # A line that runs past the block waits for the next one; a CRLF is
                # never split (CR-only files have no LF).
                lf = block.rfind(b"\n")
                cut = lf + 1 if lf >= 0 else block.rfind(b"\r") + 1
            part, self._tail = block[:cut], block[cut:]
            if self._in_head:
                skipped = _HEAD.match(part)
                n = skipped.end() if skipped is not None else 0
                self.head += _line_ends(part[:n])
                part = part[n:]
                self._in_head = not part
            self._ready = _BLANK_OR_COMMENT.sub(b"", part)
        n = min(len(buffer), len(self._ready))
        buffer[:n] = self._ready[:n]
        self._ready = self._ready[n:]
        return n


def _content_rows(frame: pd.DataFrame) -> npt.NDArray[np.intp]:
    """Positions of the rows that are neither blank (every field empty) nor a comment
    (the first field starting with ``#``)."""
    first = frame.iloc[:, 0].astype(str).str.lstrip()
    blank = (frame == "").all(axis=1).to_numpy() | first.str.startswith("#").to_numpy()
    return np.flatnonzero(~blank)


def _parse_chunks(
    path: Path,
    reader: Iterator[pd.DataFrame],
    columns: Sequence[str],
    text_columns: Sequence[str],
    first_line: int = 2,
) -> Iterator[tuple[Lines, dict[str, npt.NDArray[np.generic]]]]:
    try:
        line = first_line
        for k, frame in enumerate(reader):
            frame.columns = [str(c).strip() for c in frame.columns]
            if k == 0:
                _check_columns(path, list(frame.columns), columns, header_line=first_line - 1)
            keep = _content_rows(frame)
            # File line of each kept row, for the messages.
            lines = line + keep
            rows = frame.iloc[keep]
            out: dict[str, npt.NDArray[np.generic]] = {}
            for col in columns:
                raw = rows[col]
                if col in text_columns:
                    values = raw.to_numpy(dtype=str)
                    bad = np.flatnonzero(values == "")
                    if len(bad):
                        raise InputError(
                            "missing value", path=path, line=int(lines[bad[0]]), field=col
                        )
                    out[col] = values
                    continue
                num = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=np.float64)
                bad_mask = np.isnan(num) | np.isneginf(num)
                if col != "range":
                    bad_mask |= ~np.isfinite(num)
                if bad_mask.any():
                    i = int(np.flatnonzero(bad_mask)[0])
                    text = str(raw.iloc[i]).strip()
                    why = "missing value" if text == "" else f"not a finite number ({quote(text)})"
                    raise InputError(why, path=path, line=int(lines[i]), field=col)
                out[col] = num
            if len(keep):
                yield lines, out
            line += len(frame)
    except pd.errors.EmptyDataError as err:
        raise InputError(
            f"file is empty; expected a header {','.join(columns)}", path=path
        ) from err
    except pd.errors.ParserError as err:
        m = _TOKENIZE.search(str(err))
        if m:
            raise InputError(
                f"expected {m.group(1)} fields, saw {m.group(3)}", path=path, line=int(m.group(2))
            ) from err
        raise InputError(f"malformed CSV ({str(err).strip().splitlines()[-1]})", path=path) from err
    except (EOFError, OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read file ({type(err).__name__}: {err})", path=path) from err


def _check_columns(
    path: Path, found: list[str], expected: Sequence[str], header_line: int = 1
) -> None:
    stripped = [c.strip() for c in found]
    missing = [c for c in expected if c not in stripped]
    extra = [c for c in stripped if c not in expected]
    if missing or extra or len(stripped) != len(expected):
        parts = []
        if missing:
            parts.append(f"missing column(s) {', '.join(missing)}")
        if extra:
            parts.append(f"unexpected column(s) {', '.join(extra)}")
        if not parts:
            parts.append("duplicate columns")
        raise InputError(
            f"{'; '.join(parts)}; expected header {','.join(expected)}",
            path=path,
            line=header_line,
        )


def _check_time(path: Path, t: F64, lines: Lines, previous: float) -> None:
    prev = np.concatenate([[previous], t[:-1]])
    back = np.flatnonzero(t < prev)
    if len(back):
        i = int(back[0])
        raise InputError(
            f"time goes backwards ({t[i]} after {prev[i]})",
            path=path,
            line=int(lines[i]),
            field="t",
        )


def iter_readings(
    path: str | Path,
    *,
    names: Sequence[str] | None = None,
    chunk_size: int = DEFAULT_CHUNK,
    order: TimeOrder | None = None,
) -> Iterator[Readings]:
    """Read a readings CSV chunk by chunk, in time order.

    Parameters
    ----------
    path : str or Path
        CSV file, optionally gzip-compressed.
    names : sequence of str, optional
        Valid sonar names (a rig's); any other name is an error. Indices in the
        returned batches refer to this list. Without it, names are numbered in the
        order they first appear.
    chunk_size : int
        Rows per chunk.
    order : TimeOrder, optional
        How readings out of time order are handled, and where the counts go (see
        :func:`in_time_order`): by default a reading up to :data:`REORDER_WINDOW`
        seconds late is put in place and a later one dropped. ``TimeOrder(None)``
        refuses the file at the first reading out of order, naming its line.
    """
    rep = order if order is not None else TimeOrder()
    raw = _parse_readings(Path(path), names, chunk_size)
    if rep.window is not None:
        yield from in_time_order((r for _, r in raw), rep)
        return
    last_t = -np.inf
    for lines, r in raw:
        _check_time(Path(path), r.t, lines, last_t)
        last_t = float(r.t[-1]) if len(r) else last_t
        yield r


def _parse_readings(
    p: Path, names: Sequence[str] | None, chunk_size: int
) -> Iterator[tuple[Lines, Readings]]:
    known: list[str] = list(names) if names is not None else []
    lookup = {n: i for i, n in enumerate(known)}
    for lines, cols in _chunks(p, READINGS_COLUMNS, ("sensor",), chunk_size):
        labels = np.char.strip(cols["sensor"].astype(str))
        uniq, inverse = np.unique(labels, return_inverse=True)
        if names is not None:
            unknown = np.array([u not in lookup for u in uniq.tolist()], dtype=bool)
            if unknown.any():
                i = int(np.flatnonzero(unknown[inverse])[0])
                raise InputError(
                    f"unknown sensor '{labels[i]}'; the rig has {', '.join(known)}",
                    path=p,
                    line=int(lines[i]),
                    field="sensor",
                )
        codes = np.empty(len(uniq), dtype=np.int32)
        # New names are numbered in order of first appearance, not alphabetically.
        first = np.full(len(uniq), len(labels))
        np.minimum.at(first, inverse, np.arange(len(labels)))
        for j in np.argsort(first, kind="stable").tolist():
            name = str(uniq[j])
            if name not in lookup:
                lookup[name] = len(known)
                known.append(name)
            codes[j] = lookup[name]
        rng = cols["range"].astype(np.float64)
        neg = np.flatnonzero(rng < 0)
        if len(neg):
            i = int(neg[0])
            raise InputError(
                f"range is negative ({rng[i]})", path=p, line=int(lines[i]), field="range"
            )
        yield (
            lines,
            Readings(
                cols["t"].astype(np.float64),
                codes[inverse].astype(np.int32),
                cols["x"].astype(np.float64),
                cols["y"].astype(np.float64),
                cols["theta"].astype(np.float64),
                rng,
                tuple(known),
            ),
        )


def read_readings(
    path: str | Path,
    *,
    names: Sequence[str] | None = None,
    chunk_size: int = DEFAULT_CHUNK,
    order: TimeOrder | None = None,
) -> Readings:
    """Read a whole readings CSV, in time order (see :func:`iter_readings`)."""
    parts = list(iter_readings(path, names=names, chunk_size=chunk_size, order=order))
    if sum(len(p) for p in parts) == 0:
        raise InputError("no readings (the file has a header only)", path=path)
    return Readings.concat(parts)


def read_trajectory(path: str | Path, *, chunk_size: int = DEFAULT_CHUNK) -> Trajectory:
    """Read a trajectory CSV ``t,x,y,theta``; it must hold at least one pose."""
    p = Path(path)
    cols: dict[str, list[F64]] = {c: [] for c in TRAJECTORY_COLUMNS}
    last_t = -np.inf
    for lines, chunk in _chunks(p, TRAJECTORY_COLUMNS, (), chunk_size):
        t = chunk["t"].astype(np.float64)
        _check_time(p, t, lines, last_t)
        last_t = float(t[-1]) if len(t) else last_t
        for c in TRAJECTORY_COLUMNS:
            cols[c].append(chunk[c].astype(np.float64))
    if not cols["t"] or sum(len(a) for a in cols["t"]) == 0:
        raise InputError("trajectory is empty (no poses after the header)", path=p)
    t, x, y, th = (np.concatenate(cols[c]) for c in TRAJECTORY_COLUMNS)
    return Trajectory(t, x, y, th)


def write_readings(readings: Readings, path: str | Path) -> None:
    """Write readings as CSV (atomically; gzip when the name ends in ``.gz``)."""
    write_readings_stream([readings], path)


def write_readings_stream(chunks: Iterable[Readings], path: str | Path, batch: int = 50_000) -> int:
    """Write readings arriving in chunks as one CSV (atomically); return how many.

    Memory holds one batch of rows at a time, whatever the length of the stream.
    """
    p = Path(path)
    compression: Literal["gzip"] | None = "gzip" if p.suffix == ".gz" else None
    total = 0

    def frame(parts: list[Readings]) -> pd.DataFrame:
        r = Readings.concat(parts)
        return pd.DataFrame(
            {
                "t": r.t,
                "sensor": np.asarray(r.names, dtype=object)[r.sensor],
                "x": r.x,
                "y": r.y,
                "theta": r.theta,
                "range": r.range,
            }
        )

    def write(tmp: Path) -> None:
        nonlocal total
        opener = gzip.open if compression else open
        with opener(tmp, "wt", newline="") as f:
            f.write(",".join(READINGS_COLUMNS) + "\n")
            pending: list[Readings] = []
            size = 0
            for chunk in chunks:
                pending.append(chunk)
                size += len(chunk)
                if size >= batch:
                    frame(pending).to_csv(f, header=False, index=False, float_format="%.9g")
                    total += size
                    pending, size = [], 0
            if pending:
                frame(pending).to_csv(f, header=False, index=False, float_format="%.9g")
                total += size

    atomic_write(p, write)
    return total


def write_trajectory(traj: Trajectory, path: str | Path) -> None:
    """Write a trajectory as CSV (atomically)."""
    frame = pd.DataFrame({"t": traj.t, "x": traj.x, "y": traj.y, "theta": traj.theta})
    atomic_write(Path(path), lambda tmp: frame.to_csv(tmp, index=False, float_format="%.9g"))
