"""The fog of war: time since each place was last seen, and the metrics on it.

TB(x) is the time in seconds since any robot last had cell x within its vision radius
(a disc, as the thesis draws it). The watched domain is the territory's free cells.
MTB(t) = max of TB over the free cells; the thesis's criterion is its time average.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..grid import Grid

__all__ = ["Fog", "dilate", "disc_offsets"]


def disc_offsets(radius: float, resolution: float) -> npt.NDArray[np.int64]:
    """(row, column) offsets of the cells whose centres lie within ``radius`` metres of
    a cell's centre."""
    k = int(np.floor(radius / resolution))
    dr, dc = np.mgrid[-k : k + 1, -k : k + 1]
    inside = (dr * resolution) ** 2 + (dc * resolution) ** 2 <= radius**2 + 1e-12
    return np.column_stack([dr[inside], dc[inside]]).astype(np.int64)


def dilate(tb: npt.NDArray[np.float64], wing: int) -> npt.NDArray[np.float64]:
    """TB(x) <- max of TB over the square of half-side ``wing`` cells around x (the
    thesis's fog dilation, so small long-unseen places are not ignored)."""
    if wing <= 0:
        return tb
    out: npt.NDArray[np.float64] = ndimage.grey_dilation(
        tb, size=(2 * wing + 1, 2 * wing + 1), mode="nearest"
    )
    return out


class Fog:
    """TB over a grid; cells outside ``watched`` stay at 0 and never count.

    Parameters
    ----------
    grid : Grid
    watched : ndarray of bool
        The cells whose TB is kept (the territory's free cells).
    start : float
        TB of every watched cell at time 0 (the thesis's START_FOG, not given; 0 means
        the patrol starts from a territory just seen).
    """

    def __init__(self, grid: Grid, watched: npt.NDArray[np.bool_], start: float = 0.0) -> None:
        self.grid = grid
        self.watched = watched
        self.tb = np.where(watched, float(start), 0.0)

    def advance(self, dt: float) -> None:
        """Time passes: every watched cell's TB grows by ``dt``."""
        self.tb[self.watched] += dt

    def observe(
        self, rows: npt.ArrayLike, cols: npt.ArrayLike, disc: npt.NDArray[np.int64]
    ) -> None:
        """Robots at cells (rows, cols) see every cell of ``disc`` around them."""
        nr, nc = self.tb.shape
        for r, c in zip(np.atleast_1d(rows).tolist(), np.atleast_1d(cols).tolist(), strict=True):
            rr = disc[:, 0] + r
            cc = disc[:, 1] + c
            ok = (rr >= 0) & (rr < nr) & (cc >= 0) & (cc < nc)
            self.tb[rr[ok], cc[ok]] = 0.0

    def mtb(self) -> float:
        """Max of TB over the watched cells."""
        return float(self.tb[self.watched].max())

    def mean_tb(self) -> float:
        """Mean of TB over the watched cells."""
        return float(self.tb[self.watched].mean())
