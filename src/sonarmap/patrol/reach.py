"""What a team can patrol: the places its robots can get to from where they start.

A map's free cells are not all a territory. On a real map some free space is never
reachable: the inside of a shelf the SLAM run saw through, a room behind a door
narrower than the robot, the scanned outside of a floor plan. Counting such places as
places to watch makes MTB(t) = t for the whole run, whatever the team does. So the
territory is, by default, what a robot of the given radius can reach from the starts:

1. the *reachable* cells: the 8-connected components of the passable cells (where the
   robot's centre may be, :meth:`~sonarmap.patrol.territory.Territory.passable`) that
   hold a start, or the largest component when no start is given;
2. the *watched* places: the free cells the robot's body can cover from there, those
   within the robot's radius (plus half a cell's diagonal, for the cell's own extent)
   of a reachable cell.

An optional *region* (a user's mask of the inside of a building) bounds both. The free
cells left out -- unreachable, or outside the region -- are reported, never silently
dropped. ``mode="free"`` keeps every free cell, as the thesis does on its own maps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import ConfigError, InputError
from .territory import Territory

__all__ = ["MODES", "Reach", "reach"]

#: How the watched places are chosen: ``reachable`` (the default, above) or ``free``
#: (every free cell, the thesis's reading).
MODES = ("reachable", "free")

#: 8-connectivity, as the wave steps.
_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True, eq=False)
class Reach:
    """The territory a team patrols and what was left out of it.

    Attributes
    ----------
    passable : ndarray of bool
        Where a robot's centre may be on this run: the reachable components (mode
        ``reachable``) or every passable cell inside the region (mode ``free``).
    watched : ndarray of bool
        The places the fog and every metric count.
    left_out : ndarray of bool
        Free cells that are not watched: unreachable, or outside the region.
    outside_region : ndarray of bool
        Free cells outside the user's region (all False without one).
    unreachable_share : float
        Share of the free cells inside the region that are not watched.
    outside_share : float
        Share of all free cells outside the region.
    unknown_share : float
        Share of the map's cells that the map marks unknown.
    """

    passable: npt.NDArray[np.bool_]
    watched: npt.NDArray[np.bool_]
    left_out: npt.NDArray[np.bool_]
    outside_region: npt.NDArray[np.bool_]
    unreachable_share: float
    outside_share: float
    unknown_share: float

    def summary(self) -> dict[str, float | int]:
        """JSON-ready numbers: watched cells and the left-out shares."""
        return {
            "watched_cells": int(self.watched.sum()),
            "unreachable_free_share": round(self.unreachable_share, 6),
            "outside_region_share": round(self.outside_share, 6),
            "unknown_share": round(self.unknown_share, 6),
        }

    def describe(self) -> str:
        """One line for the terminal: what the team patrols and what it does not."""
        parts = [f"{100 * self.unreachable_share:.1f} % of the free space unreachable"]
        if self.outside_share > 0:
            parts.append(f"{100 * self.outside_share:.1f} % outside the territory mask")
        parts.append(f"{100 * self.unknown_share:.1f} % of the map unknown")
        return "territory: " + ", ".join(parts) + " (left out of the metrics)"


def reach(
    territory: Territory,
    radius: float,
    *,
    starts: npt.NDArray[np.intp] | None = None,
    region: npt.NDArray[np.bool_] | None = None,
    mode: str = "reachable",
    vision: float = 0.0,
) -> Reach:
    """The places a team of robots of ``radius`` metres patrols.

    Parameters
    ----------
    territory : Territory
        The map's free cells and their clearance.
    radius : float
        The robots' radius, metres.
    starts : ndarray of int, shape (N, 2), optional
        Rows and columns of the robots' start cells; without them, the largest
        reachable component (the starts are then chosen inside it).
    region : ndarray of bool, optional
        The user's territory mask, on the territory's grid: nothing outside it is
        entered or watched.
    mode : {"reachable", "free"}
        ``reachable`` (default) as the module says; ``free`` watches every free cell
        inside the region.
    vision : float
        The vision radius, metres: a territory smaller than one vision disc is an
        error (default 0: no such check).

    Raises
    ------
    InputError
        When nothing is left to patrol: no passable cell, or a territory smaller than
        one vision disc.
    """
    if mode not in MODES:
        raise ConfigError(f"unknown territory mode {mode!r}; valid: {', '.join(MODES)}")
    free = territory.free
    if region is not None and region.shape != free.shape:
        raise ValueError(f"a region of {region.shape} for a territory of {free.shape}")
    inside = np.ones_like(free) if region is None else region
    passable = territory.passable(radius) & inside
    if not passable.any():
        raise InputError(
            f"no place of the territory has room for a robot of radius {radius:g} m"
            + (" inside the territory mask" if region is not None else "")
        )
    res = territory.grid.resolution
    if mode == "free":
        watched = free & inside
    else:
        labels, n = ndimage.label(passable, structure=_EIGHT)
        if starts is not None and len(starts):
            keep = np.unique(labels[starts[:, 0], starts[:, 1]])
            keep = keep[keep > 0]
        else:
            sizes = np.bincount(labels.ravel(), minlength=n + 1)
            sizes[0] = 0
            keep = np.array([int(np.argmax(sizes))])
        passable = np.isin(labels, keep)
        # The body covers what lies within its radius of a centre it can get to.
        gap = ndimage.distance_transform_edt(~passable) * res
        watched = free & inside & (gap <= radius + res * math.sqrt(0.5))
    n_free = int(free.sum())
    n_inside = int((free & inside).sum())
    area = float(watched.sum()) * res * res
    if vision > 0 and area < math.pi * vision * vision:
        raise InputError(
            f"the territory the robots can reach is {area:.3g} m2, smaller than one vision "
            f"disc ({math.pi * vision * vision:.3g} m2): nothing to patrol"
        )
    unknown = territory.unknown
    return Reach(
        passable=passable,
        watched=watched,
        left_out=free & ~watched,
        outside_region=free & ~inside,
        unreachable_share=1.0 - float(watched.sum()) / max(1, n_inside),
        outside_share=1.0 - n_inside / max(1, n_free),
        unknown_share=float(unknown.mean()) if unknown is not None else 0.0,
    )
