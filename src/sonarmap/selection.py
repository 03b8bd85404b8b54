"""Which readings stay in play while streaming (methods.md section 5).

A forward-model map is the optimum of an objective over readings; run in real time, the
objective holds a bounded set of them. A strategy sees each reading as it is admitted
(by its slot in the mapper's store) and names the readings that leave:

``last:N``
    a sliding window of the last N readings;
``cell:N``
    per cell, the N freshest readings whose beam holds it; a reading leaves when it is
    no longer among the N freshest of any of its cells. This bounds the cost of a step
    at a cell by N readings;
``pose:N[:XY[:DEG]][:median]``
    a grid over sensor pose -- x and y in bins of XY m (0.5), heading in bins of DEG
    degrees (30) -- keeping the N freshest readings per bin, at a scale that does not
    depend on the map's; with ``median``, the "filtered readings" variant of thesis 000
    (section 2.3, which leaves the filter open): per bin, the N readings whose ranges
    lie nearest the median range of the bin's last 3N readings, so that a lone
    spurious range leaves first and readings from one pose cannot all repeat it;
``all``
    every reading stays (only for methods that keep no readings, such as ``inverse``).

Memory: ``last`` holds N readings; ``cell`` at most N per cell of the grid, plus an
N-slot ring per cell; ``pose`` N per pose bin visited, which the floor area bounds.
None of them grows with the length of the log.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque

import numba as nb
import numpy as np
import numpy.typing as npt

from .errors import ConfigError, quote
from .readings import Readings

__all__ = [
    "FreshestPerCell",
    "KeepAll",
    "LastN",
    "PoseGrid",
    "Strategy",
    "parse_strategy",
]

I64 = npt.NDArray[np.int64]


class Strategy(ABC):
    """Chooses the readings in play. Call :meth:`start` before the first :meth:`admit`."""

    #: Whether readings ever leave (``all`` keeps everything).
    bounded: bool = True

    def start(self, n_cells: int) -> None:  # noqa: B027 -- most strategies need no setup
        """Reset for a grid of ``n_cells`` cells."""

    @abstractmethod
    def admit(
        self,
        slots: I64,
        readings: Readings,
        cell_start: I64,
        cell_len: I64,
        cells: npt.NDArray[np.int32],
    ) -> I64:
        """Take new readings; return the slots of the readings that leave.

        Parameters
        ----------
        slots : ndarray of int64
            Slot of each new reading (slots are reused after a reading leaves).
        readings : Readings
            The new readings, aligned with ``slots``.
        cell_start, cell_len : ndarray of int64
            Per slot (indexed by slot), where its cells are in ``cells``.
        cells : ndarray of int32
            The store's cell arena.
        """

    @abstractmethod
    def spec(self) -> str:
        """The strategy as text that :func:`parse_strategy` reads back."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.spec()!r})"


class KeepAll(Strategy):
    """Every reading stays in play."""

    bounded = False

    def admit(
        self,
        slots: I64,
        readings: Readings,
        cell_start: I64,
        cell_len: I64,
        cells: npt.NDArray[np.int32],
    ) -> I64:
        return np.empty(0, np.int64)

    def spec(self) -> str:
        return "all"


class LastN(Strategy):
    """A sliding window of the last ``n`` readings."""

    def __init__(self, n: int) -> None:
        _positive_int("last", n)
        self.n = n
        self._queue: deque[int] = deque()

    def start(self, n_cells: int) -> None:
        self._queue = deque()

    def admit(
        self,
        slots: I64,
        readings: Readings,
        cell_start: I64,
        cell_len: I64,
        cells: npt.NDArray[np.int32],
    ) -> I64:
        self._queue.extend(slots.tolist())
        out = [self._queue.popleft() for _ in range(max(0, len(self._queue) - self.n))]
        return np.asarray(out, dtype=np.int64)

    def spec(self) -> str:
        return f"last:{self.n}"


@nb.njit(cache=True)
def _admit_cells(
    slots: I64,
    cell_start: I64,
    cell_len: I64,
    cells: npt.NDArray[np.int32],
    ring: npt.NDArray[np.int32],
    head: npt.NDArray[np.int32],
    votes: npt.NDArray[np.int32],
) -> I64:
    n_max = ring.shape[1]
    out = np.empty(slots.shape[0] * 4 + 16, np.int64)
    k = 0
    for s in slots:
        votes[s] = 0
    for s in slots:
        for j in range(cell_start[s], cell_start[s] + cell_len[s]):
            c = cells[j]
            h = head[c]
            old = ring[c, h]
            if old == s:
                continue
            if old >= 0:
                votes[old] -= 1
                if votes[old] == 0:
                    if k == out.shape[0]:
                        grown = np.empty(2 * k, np.int64)
                        grown[:k] = out
                        out = grown
                    out[k] = old
                    k += 1
            ring[c, h] = s
            votes[s] += 1
            head[c] = (h + 1) % n_max
    return out[:k]


class FreshestPerCell(Strategy):
    """Per cell, the ``n`` freshest readings whose beam holds it."""

    def __init__(self, n: int) -> None:
        _positive_int("cell", n)
        self.n = n
        self._ring = np.empty((0, n), np.int32)
        self._head = np.empty(0, np.int32)
        self._votes = np.empty(0, np.int32)

    def start(self, n_cells: int) -> None:
        self._ring = np.full((n_cells, self.n), -1, np.int32)
        self._head = np.zeros(n_cells, np.int32)
        self._votes = np.zeros(256, np.int32)

    def admit(
        self,
        slots: I64,
        readings: Readings,
        cell_start: I64,
        cell_len: I64,
        cells: npt.NDArray[np.int32],
    ) -> I64:
        if len(slots) and slots.max() >= len(self._votes):
            grown = np.zeros(max(2 * len(self._votes), int(slots.max()) + 1), np.int32)
            grown[: len(self._votes)] = self._votes
            self._votes = grown
        out = _admit_cells(slots, cell_start, cell_len, cells, self._ring, self._head, self._votes)
        # A reading of this batch that lost all its cells to later ones leaves at once;
        # a reading that covers no cell is of no use to any cell.
        empty = slots[cell_len[slots] == 0]
        return np.unique(np.concatenate([out, empty]))

    def spec(self) -> str:
        return f"cell:{self.n}"


#: How a pose bin chooses its readings: the freshest, or those nearest the median range.
POSE_FILTERS = ("freshest", "median")


class PoseGrid(Strategy):
    """``n`` readings per bin of sensor pose (x, y, heading): the freshest, or (with
    ``keep="median"``) those whose ranges agree best with the bin's recent median.

    With ``median`` each bin remembers the ranges of its last ``3 n`` readings. A new
    reading joins those in play; while more than ``n`` are in play, the one farthest
    from the median of the remembered ranges leaves (the older of a tie), and a reading
    older than the last ``3 n`` leaves in any case, so the map follows a change.

    Examples
    --------
    One bin, two readings kept: the 1 m range among 2 m ones is the one that leaves.

    >>> from sonarmap.readings import Readings
    >>> g = PoseGrid(2, keep="median")
    >>> z = np.zeros(4)
    >>> r = Readings(z, np.zeros(4, np.int32), z, z, z, np.array([2.0, 1, 2, 2]), ("s",))
    >>> e = np.zeros(4, np.int64)
    >>> g.admit(np.arange(4), r, e, e, np.zeros(0, np.int32)).tolist()
    [1, 0]
    """

    def __init__(
        self, n: int, xy: float = 0.5, heading_deg: float = 30.0, keep: str = "freshest"
    ) -> None:
        _positive_int("pose", n)
        if not (math.isfinite(xy) and xy > 0):
            raise ConfigError(f"pose bin size must be > 0 m, got {xy}")
        if not (math.isfinite(heading_deg) and 0 < heading_deg <= 360):
            raise ConfigError(f"pose heading bin must be in (0, 360] degrees, got {heading_deg}")
        if keep not in POSE_FILTERS:
            raise ConfigError(f"pose filter must be one of {', '.join(POSE_FILTERS)}, got {keep!r}")
        self.n = n
        self.xy = xy
        self.heading_deg = heading_deg
        self.keep = keep
        self._bins: dict[tuple[int, int, int], deque[int]] = {}
        self._filtered: dict[tuple[int, int, int], _MedianBin] = {}

    def start(self, n_cells: int) -> None:
        self._bins = {}
        self._filtered = {}

    def admit(
        self,
        slots: I64,
        readings: Readings,
        cell_start: I64,
        cell_len: I64,
        cells: npt.NDArray[np.int32],
    ) -> I64:
        ix = np.floor(readings.x / self.xy).astype(np.int64)
        iy = np.floor(readings.y / self.xy).astype(np.int64)
        n_h = max(1, round(360.0 / self.heading_deg))
        ih = np.floor(np.mod(np.degrees(readings.theta), 360.0) / (360.0 / n_h)).astype(np.int64)
        ih = np.minimum(ih, n_h - 1)
        out: list[int] = []
        keys = zip(ix.tolist(), iy.tolist(), ih.tolist(), strict=True)
        if self.keep == "median":
            for key, s, r in zip(keys, slots.tolist(), readings.range.tolist(), strict=True):
                b = self._filtered.get(key)
                if b is None:
                    b = self._filtered[key] = _MedianBin(self.n)
                out.extend(b.add(s, r))
            return np.asarray(out, dtype=np.int64)
        for key, s in zip(keys, slots.tolist(), strict=True):
            q = self._bins.get(key)
            if q is None:
                q = self._bins[key] = deque()
            q.append(s)
            if len(q) > self.n:
                out.append(q.popleft())
        return np.asarray(out, dtype=np.int64)

    @property
    def n_bins(self) -> int:
        return len(self._filtered) if self.keep == "median" else len(self._bins)

    def spec(self) -> str:
        tail = ":median" if self.keep == "median" else ""
        return f"pose:{self.n}:{self.xy:g}:{self.heading_deg:g}{tail}"


class _MedianBin:
    """One pose bin of the ``median`` filter (see :class:`PoseGrid`)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.window = 3 * n
        self.ranges: deque[float] = deque(maxlen=self.window)
        #: In play: (slot, range, arrival number in this bin).
        self.live: list[tuple[int, float, int]] = []
        self.count = 0

    def add(self, slot: int, r: float) -> list[int]:
        """Take a reading; return the slots that leave."""
        self.ranges.append(r)
        self.live.append((slot, r, self.count))
        self.count += 1
        oldest = self.count - self.window
        gone = [s for s, _, k in self.live if k < oldest]
        self.live = [e for e in self.live if e[2] >= oldest]
        if len(self.live) > self.n:
            med = float(np.median(np.fromiter(self.ranges, np.float64)))
            # Farthest from the median first; of equals, the oldest.
            self.live.sort(key=lambda e: (-abs(e[1] - med), e[2]))
            gone += [s for s, _, _ in self.live[: len(self.live) - self.n]]
            self.live = self.live[len(self.live) - self.n :]
        return gone


def _positive_int(kind: str, n: int) -> None:
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError(f"strategy '{kind}' needs a count >= 1, got {n!r}")


def parse_strategy(text: str) -> Strategy:
    """A strategy from its text form: ``last:N`` (or just ``N``), ``cell:N``,
    ``pose:N[:XY[:DEG]][:median]``, ``all``.

    Examples
    --------
    >>> parse_strategy("pose:3:0.25")
    PoseGrid('pose:3:0.25:30')
    >>> parse_strategy("pose:3:median")
    PoseGrid('pose:3:0.5:30:median')
    >>> parse_strategy("500")
    LastN('last:500')
    """
    if text.strip().isdigit():
        # A bare count is the sliding window.
        return LastN(int(text.strip()))
    parts = text.strip().split(":")
    kind, args = parts[0], parts[1:]
    usage = "valid: last:N, cell:N, pose:N[:XY_M[:HEADING_DEG]][:median], all"
    try:
        if kind == "all" and not args:
            return KeepAll()
        if kind == "last" and len(args) == 1:
            return LastN(int(args[0]))
        if kind == "cell" and len(args) == 1:
            return FreshestPerCell(int(args[0]))
        if kind == "pose" and len(args) >= 1:
            keep = "freshest"
            if args[-1].strip() in POSE_FILTERS:
                keep = args.pop().strip()
            if 1 <= len(args) <= 3:
                xy = float(args[1]) if len(args) > 1 else 0.5
                heading = float(args[2]) if len(args) > 2 else 30.0
                return PoseGrid(int(args[0]), xy, heading, keep=keep)
    except ConfigError:
        raise  # a number out of its range: the strategy's own message says which
    except ValueError:
        raise ConfigError(
            f"bad strategy {quote(text)}: counts and sizes must be numbers; {usage}"
        ) from None
    raise ConfigError(f"unknown strategy {quote(text)}; {usage}")
