"""Places the cars give up: never-seen places they keep failing to get in sight of.

A car-like robot cannot get everywhere a disc of its size can: the last few never-seen
places of a street site lie at the ends of stubs too narrow for a car to enter, and
their pull grows with the time they stay unseen, so that a tracking car goes for them
again and again and turns round, reversing, at each try. :class:`GiveUp` counts the
reversing manoeuvres begun on the way to each never-seen place; at the limit that place,
and every never-seen place within a small disc of it, is no longer a place the robots go
for. The metrics still count them (they stay never seen); a place given up that any
robot comes to see is a target again.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .fog import Fog, disc_cells

__all__ = ["GiveUp"]


class GiveUp:
    """The watched places the robots go for, less the never-seen ones given up.

    Parameters
    ----------
    watched : ndarray of bool
        The places watched (not copied; never written).
    limit : int
        Reversing manoeuvres on the way to a never-seen place at which it is given up
        (>= 1).
    disc : ndarray of int64, shape (K, 2)
        Cell offsets (:func:`~sonarmap.patrol.fog.disc_offsets`) around a place given
        up within which the never-seen places go too.
    """

    def __init__(
        self, watched: npt.NDArray[np.bool_], limit: int, disc: npt.NDArray[np.int64]
    ) -> None:
        if limit < 1:
            raise ValueError(f"limit must be >= 1, got {limit}")
        self.watched = watched
        self.limit = limit
        self.disc = disc
        self.tries: dict[tuple[int, int], int] = {}
        self.given = np.zeros_like(watched)
        self._targets = watched

    def tried(self, place: tuple[int, int], fog: Fog) -> bool:
        """Count one reversing manoeuvre on the way to ``place`` (row, column); True
        when that gives it up now (it was never seen by ``fog`` and this was the
        ``limit``-th)."""
        never = fog.never_seen()
        if not never[place]:
            return False
        n = self.tries.get(place, 0) + 1
        self.tries[place] = n
        if n < self.limit:
            return False
        rr, cc = disc_cells(self.disc, place[0], place[1], self.watched.shape)
        keep = never[rr, cc]
        self.given[rr[keep], cc[keep]] = True
        self._targets = self.watched & ~self.given
        return True

    def targets(self, fog: Fog) -> npt.NDArray[np.bool_]:
        """The watched places but those given up and still never seen by ``fog`` (the
        same array object while that set is unchanged)."""
        if self.given.any():
            seen = self.given & ~fog.never_seen()
            if seen.any():
                self.given &= ~seen
                self._targets = self.watched & ~self.given
        return self._targets
