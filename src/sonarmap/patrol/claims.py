"""Places other robots are going for, pulling one robot's choice as if just seen.

Each potential-field robot chooses the place it goes for from the team's shared fog
alone: two robots near each other see the same pulls and go for the same stale place,
and the second arrives to find it seen (:attr:`PatrolConfig.claim
<sonarmap.patrol.simulation.PatrolConfig.claim>`). With a claim radius, while a robot
chooses, the watched places within that radius of a place another robot goes for (kept
and not seen since that robot chose it) count as seen at that moment: they will be seen
when that robot gets there. The marks are written into the fog's last-seen times for the
choice only and taken out straight after (:meth:`Claims.mark`, :meth:`Claims.restore`),
so the fog, the metric and every other robot's choice are as before.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np
import numpy.typing as npt

from .fog import disc_cells, disc_offsets

__all__ = ["Claims", "Marks"]

F64 = npt.NDArray[np.float64]
#: What :meth:`Claims.mark` changed: per disc marked, its rows, columns and the
#: last-seen times it held, in the order marked.
Marks = list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], F64]]


class Claims:
    """The discs of ``radius`` metres round other robots' places, on a fog of cells
    ``resolution`` metres wide.

    Parameters
    ----------
    radius : float
        Metres round a claimed place whose places count as seen; > 0.
    resolution : float
        Side of a fog cell, metres; > 0.
    """

    def __init__(self, radius: float, resolution: float) -> None:
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"claim radius must be > 0 metres, got {radius}")
        if not (math.isfinite(resolution) and resolution > 0):
            raise ValueError(f"resolution must be > 0 metres, got {resolution}")
        self.radius = float(radius)
        self.disc = disc_offsets(radius, resolution)

    @staticmethod
    def others(
        i: int,
        aims: Sequence[tuple[int, int] | None],
        aimed_at: F64,
        last: F64,
    ) -> list[tuple[int, int]]:
        """The places the robots other than ``i`` go for that were not seen since they
        were chosen (``last`` the fog's last-seen times; ``aimed_at`` when each robot
        chose its place, seconds)."""
        return [
            a
            for j, a in enumerate(aims)
            if j != i and a is not None and float(last[a]) < float(aimed_at[j])
        ]

    def mark(self, last: F64, now: float, places: Sequence[tuple[int, int]]) -> Marks:
        """Set the last-seen time of every cell within the radius of ``places`` to
        ``now`` (cells not watched, whose time is +inf, and any seen later, keep
        theirs), in place; returns what :meth:`restore` needs to undo it."""
        out: Marks = []
        for r, c in places:
            rows, cols = disc_cells(self.disc, int(r), int(c), (last.shape[0], last.shape[1]))
            old = last[rows, cols].copy()
            out.append((rows, cols, old))
            last[rows, cols] = np.maximum(old, now)
        return out

    @staticmethod
    def restore(last: F64, marks: Marks) -> None:
        """Undo :meth:`mark` (discs that overlap are put back last marked first)."""
        for rows, cols, old in reversed(marks):
            last[rows, cols] = old

    @contextmanager
    def held(self, last: F64, now: float, places: Sequence[tuple[int, int]]) -> Iterator[None]:
        """:meth:`mark` for the body of a ``with`` block, then :meth:`restore`, also when
        the body raises: the fog is marked only while a choice reads it."""
        marks = self.mark(last, now, places)
        try:
            yield
        finally:
            self.restore(last, marks)
