"""Regular 2-D grids: resolution, origin, shape and world <-> cell conversion.

Arrays over a grid are indexed ``[row, col]`` with row 0 at the **top** (largest
world y), the orientation of the map image, of ROS map_server and of the ``.npy``
files sonarmap writes. The origin is the world position of the lower-left
corner of the lower-left cell, as in map_server's ``origin``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .errors import ConfigError

__all__ = ["Grid"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Grid:
    """A rectangular grid of square cells.

    Parameters
    ----------
    resolution : float
        Cell side in metres, > 0.
    origin : tuple of float
        World (x, y) in metres of the lower-left corner of the lower-left cell.
    shape : tuple of int
        ``(rows, cols)``, both >= 1.

    Examples
    --------
    >>> g = Grid(resolution=0.5, origin=(-1.0, 0.0), shape=(2, 4))
    >>> g.world_to_cell(np.array([-0.9]), np.array([0.1]))
    (array([1]), array([0]))
    >>> g.cell_centres(np.array([0]), np.array([3]))
    (array([0.75]), array([0.75]))
    """

    resolution: float
    origin: tuple[float, float]
    shape: tuple[int, int]

    def __post_init__(self) -> None:
        h = float(self.resolution)
        if not (math.isfinite(h) and h > 0):
            raise ConfigError(f"grid resolution must be a positive number of metres, got {h!r}")
        ox, oy = (float(v) for v in self.origin)
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise ConfigError(f"grid origin must be finite, got {self.origin!r}")
        rows, cols = (int(v) for v in self.shape)
        if rows < 1 or cols < 1:
            raise ConfigError(f"grid shape must be at least (1, 1), got {self.shape!r}")
        if rows * cols >= 2**31:
            raise ConfigError(f"grid of {rows} x {cols} cells is too large (limit 2**31 cells)")
        object.__setattr__(self, "resolution", h)
        object.__setattr__(self, "origin", (ox, oy))
        object.__setattr__(self, "shape", (rows, cols))

    @classmethod
    def from_bounds(
        cls, xmin: float, ymin: float, xmax: float, ymax: float, resolution: float
    ) -> Grid:
        """The smallest grid of the given resolution covering a world rectangle.

        Examples
        --------
        >>> Grid.from_bounds(0.0, 0.0, 6.0, 3.0, 0.05).shape
        (60, 120)
        """
        if not (xmax > xmin and ymax > ymin):
            raise ConfigError(
                f"bounds must satisfy xmin < xmax and ymin < ymax, got "
                f"({xmin}, {ymin}, {xmax}, {ymax})"
            )
        if not (math.isfinite(resolution) and resolution > 0):
            raise ConfigError(f"resolution must be a positive number of metres, got {resolution}")
        span = max(xmax - xmin, ymax - ymin) / resolution
        if not math.isfinite(span):
            # Infinite bounds, or a difference of finite ones that overflows.
            raise ConfigError(
                f"bounds ({xmin:g}, {ymin:g}, {xmax:g}, {ymax:g}) span more cells of "
                f"{resolution:g} m than can be counted (limit 2**31 cells)"
            )
        # A tolerance keeps 6.0 / 0.05 from becoming 121 cells through rounding.
        cols = max(1, math.ceil((xmax - xmin) / resolution - 1e-9))
        rows = max(1, math.ceil((ymax - ymin) / resolution - 1e-9))
        return cls(resolution=resolution, origin=(xmin, ymin), shape=(rows, cols))

    @property
    def rows(self) -> int:
        return self.shape[0]

    @property
    def cols(self) -> int:
        return self.shape[1]

    @property
    def size(self) -> int:
        """Number of cells."""
        return self.shape[0] * self.shape[1]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """World bounds ``(xmin, xmax, ymin, ymax)``, the order matplotlib's ``imshow`` wants."""
        ox, oy = self.origin
        return (ox, ox + self.cols * self.resolution, oy, oy + self.rows * self.resolution)

    def world_to_cell(self, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[IntArray, IntArray]:
        """Row and column of the cells containing world points (not clipped).

        Parameters
        ----------
        x, y : array_like of float
            World coordinates in metres.

        Returns
        -------
        rows, cols : ndarray of int64
            May lie outside the grid; see :meth:`contains`.
        """
        ox, oy = self.origin
        col = np.floor((np.asarray(x, dtype=np.float64) - ox) / self.resolution).astype(np.int64)
        iy = np.floor((np.asarray(y, dtype=np.float64) - oy) / self.resolution).astype(np.int64)
        return self.rows - 1 - iy, col

    def cell_centres(
        self, rows: npt.ArrayLike, cols: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """World coordinates (metres) of cell centres."""
        ox, oy = self.origin
        r = np.asarray(rows, dtype=np.float64)
        c = np.asarray(cols, dtype=np.float64)
        x = ox + (c + 0.5) * self.resolution
        y = oy + (self.rows - 1 - r + 0.5) * self.resolution
        return x, y

    def contains(self, rows: npt.ArrayLike, cols: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Whether (row, col) pairs lie inside the grid."""
        r = np.asarray(rows)
        c = np.asarray(cols)
        return (r >= 0) & (r < self.rows) & (c >= 0) & (c < self.cols)

    def flat_index(self, rows: npt.ArrayLike, cols: npt.ArrayLike) -> IntArray:
        """Row-major flat index of cells, as used by the rasteriser's output."""
        return np.asarray(rows, dtype=np.int64) * self.cols + np.asarray(cols, dtype=np.int64)

    def unravel(self, flat: npt.ArrayLike) -> tuple[IntArray, IntArray]:
        """(row, col) of flat cell indices."""
        f = np.asarray(flat, dtype=np.int64)
        return f // self.cols, f % self.cols

    def all_centres(self) -> tuple[FloatArray, FloatArray]:
        """World x and y of every cell centre, each of shape ``self.shape``."""
        rr, cc = np.indices(self.shape)
        return self.cell_centres(rr, cc)
