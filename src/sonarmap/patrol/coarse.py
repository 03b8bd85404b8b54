"""The path motion's choice of a place, made on a coarser grid than the fog's.

A path-motion robot chooses a new place about every second step (the place it goes for
is seen soon after it is chosen), and each choice's wave runs over every place that
could change it: on 0.1 m cells, some 20,000 cells. On blocks of k x k cells the same
wave covers about k^2 times fewer. Here the choice's wave runs on the blocks
(:func:`~sonarmap.patrol.forces.sector_pulls` with ``block``), the block chosen names
one fog cell, and the fine wave then runs only as far as that cell, for the path.

The coarse grid, from the fine one:

- a block is passable where the robot's centre may be on some of its cells (so a door
  the robot passes stays open however it lies across the blocks);
- a block is watched where some of its cells are;
- a block pulls as its watched cells together (the sum of their f(TB_n)), at the
  coarse wave's length;
- watched blocks no coarse wave reaches pull from their anchors, as the fine
  :func:`~sonarmap.patrol.paths.shadows` do.

The place a chosen block names is its oldest watched cell a fine wave reaches (with a
vision disc, any cell of the block sees the others; not so with line of sight, and the
patrol does not choose on blocks then); when it has none, the anchor of its
oldest cell (a fine shadow), from which the fine choice pulls it too. That anchor may lie
behind a wall: :meth:`CoarseChoice.choose` also gives the coarse path's length, and a
caller can refuse a place whose fine path is much longer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .forces import Force, sector_pulls, step_direction
from .paths import Shadows, Wave, nearest_step, shadows

__all__ = ["CoarseChoice", "any_in_blocks"]

F64 = npt.NDArray[np.float64]


def any_in_blocks(mask: npt.NDArray[np.bool_], block: int) -> npt.NDArray[np.bool_]:
    """Whether each ``block`` x ``block`` block of ``mask`` has a True cell; blocks cut
    by the grid's far edges count their cells inside. Shape: the grid's divided by
    ``block``, rounded up."""
    if block < 1:
        raise ValueError(f"block: a side of >= 1 cells, got {block}")
    rows, cols = mask.shape
    # A block past the grid's size is one block, the grid's: without the cap a choice
    # cell of 1e9 m padded the mask to 2e9 x 2e9 cells.
    block = min(block, max(rows, cols, 1))
    padded = np.zeros((-(-rows // block) * block, -(-cols // block) * block), dtype=bool)
    padded[:rows, :cols] = mask
    out = padded.reshape(padded.shape[0] // block, block, -1, block).any(axis=(1, 3))
    return np.asarray(out, dtype=np.bool_)


@dataclass(frozen=True, eq=False)
class CoarseChoice:
    """The choice's wave on blocks of ``block`` x ``block`` fog cells.

    Attributes
    ----------
    block : int
        Side of a block, in fog cells (>= 2).
    resolution : float
        Side of a fog cell, metres.
    passable, watched : ndarray of bool
        The fog grid's cells the robot's centre may be on, and the places watched.
    coarse_passable, coarse_watched : ndarray of bool
        The same on the blocks (see the module's notes).
    coarse_shadows : Shadows or None
        Watched blocks no coarse wave reaches, tied to their anchors; None: they do not
        pull (as the fine choice without shadows).
    anchor : ndarray of int64
        Per fog cell (row-major), the flat index of the anchor of a fine shadow, -1 for
        every other cell.
    """

    block: int
    resolution: float
    passable: npt.NDArray[np.bool_]
    watched: npt.NDArray[np.bool_]
    coarse_passable: npt.NDArray[np.bool_]
    coarse_watched: npt.NDArray[np.bool_]
    coarse_shadows: Shadows | None
    anchor: npt.NDArray[np.int64]
    wave: Wave

    @classmethod
    def build(
        cls,
        passable: npt.NDArray[np.bool_],
        watched: npt.NDArray[np.bool_],
        resolution: float,
        cell: float,
        *,
        fine_shadows: Shadows | None = None,
    ) -> CoarseChoice | None:
        """The choice on blocks about ``cell`` metres wide (a whole number of fog cells
        ``resolution`` metres wide, the nearest); None when that is under two cells
        (the fog's own grid chooses). ``fine_shadows``
        (:func:`~sonarmap.patrol.paths.shadows` of ``passable`` and ``watched``): the
        fine choice's shadows; with them the blocks no coarse wave reaches pull from
        their anchors too, without them they do not pull."""
        if not (math.isfinite(cell) and cell >= 0):
            raise ValueError(f"the choice's cell must be >= 0 metres, got {cell}")
        if passable.shape != watched.shape:
            raise ValueError(f"passable cells of {passable.shape}, watched of {watched.shape}")
        block = round(cell / resolution)
        if block < 2:
            return None
        cp = any_in_blocks(passable, block)
        cw = any_in_blocks(watched, block) | cp
        anchor = np.full(passable.size, -1, dtype=np.int64)
        if fine_shadows is not None and len(fine_shadows):
            if len(fine_shadows.ptr) != passable.size + 1:
                raise ValueError(
                    f"shadows of {len(fine_shadows.ptr) - 1} cells for a map of {passable.size}"
                )
            owner = np.repeat(np.arange(passable.size), np.diff(fine_shadows.ptr))
            anchor[fine_shadows.rows * passable.shape[1] + fine_shadows.cols] = owner
        return cls(
            block,
            float(resolution),
            passable,
            watched,
            cp,
            cw,
            shadows(cp, cw, resolution * block) if fine_shadows is not None else None,
            anchor,
            Wave(cp.shape),
        )

    def choose(
        self,
        start: tuple[int, int],
        force: Force,
        top: float,
        *,
        tb: F64 | None = None,
        last_seen: F64 | None = None,
        now: float = 0.0,
        weights: F64 | None = None,
    ) -> tuple[tuple[float, float] | None, tuple[int, int] | None, float]:
        """The mode's step for a robot on fog cell ``start``, the fog cell it goes for
        and the coarse wave's path length to that cell's block (metres): (unit (x, y)
        or None, (row, column) or None, length) -- None and inf when nothing pulls.

        The step and the block are those the fine choice
        (:func:`~sonarmap.patrol.forces.sector_pulls` with ``certify`` and ``goal``)
        makes on the blocks; the fog (``tb``, or ``last_seen`` and ``now``), ``top``
        (the robot's MTB) and ``weights`` are as there, on the fog's grid.
        """
        k = self.block
        coarse_start = (int(start[0]) // k, int(start[1]) // k)
        places = np.full((8, 2), -1, dtype=np.int64)
        fog: dict[str, F64 | float] = (
            {"tb": tb} if tb is not None else {"last_seen": last_seen, "now": now}  # type: ignore[dict-item]
        )
        strength = sector_pulls(
            self.wave,
            self.coarse_passable,
            coarse_start,
            self.resolution * k,
            self.coarse_watched,
            force,
            top,
            certify=True,
            goal=True,
            weights=weights,
            places=places,
            shadows=self.coarse_shadows,
            block=k,
            fog_watched=self.watched,
            **fog,  # type: ignore[arg-type]
        )
        way = step_direction(strength, "mode", weights)
        if way is None:
            return None, None, math.inf
        br, bc = places[nearest_step(*way)]
        if br < 0:
            return way, None, math.inf
        length = float(self.wave.dist[br, bc])
        return way, self.place_in(int(br), int(bc), tb=tb, last_seen=last_seen), length

    def place_in(
        self, br: int, bc: int, *, tb: F64 | None = None, last_seen: F64 | None = None
    ) -> tuple[int, int] | None:
        """The fog cell block (br, bc) names (see the module's notes; the first in row
        order among equally old cells); None when it has no watched cell."""
        if (tb is None) == (last_seen is None):
            raise ValueError("give either tb or last_seen")
        k = self.block
        rows = slice(br * k, (br + 1) * k)
        cols = slice(bc * k, (bc + 1) * k)
        # Oldest: the largest TB, or the earliest last-seen time.
        age = tb[rows, cols] if tb is not None else -last_seen[rows, cols]  # type: ignore[index]
        watched = self.watched[rows, cols]
        width = self.passable.shape[1]
        flat = (np.arange(br * k, br * k + watched.shape[0])[:, None] * width) + np.arange(
            bc * k, bc * k + watched.shape[1]
        )
        anchor = self.anchor[flat]
        shadow = anchor >= 0
        for mask in (watched & ~shadow, watched):
            if mask.any():
                pick = np.unravel_index(int(np.argmax(np.where(mask, age, -np.inf))), mask.shape)
                r, c = divmod(int(anchor[pick]) if shadow[pick] else int(flat[pick]), width)
                return r, c
        return None
