"""Numba kernel of :mod:`sonarmap.metrics`: straight crossings of the truth's walls."""

from __future__ import annotations

import numba as nb
import numpy as np
import numpy.typing as npt

#: Row and column steps of the four line directions: across, down, and both diagonals.
STEPS = np.array([[0, 1], [1, 0], [1, 1], [1, -1]], dtype=np.int64)


@nb.njit(cache=True)
def crossings(
    wall: npt.NDArray[np.bool_],
    region: npt.NDArray[np.int32],
    cls: npt.NDArray[np.int8],
    max_cells: int,
    steps: npt.NDArray[np.int64],
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Mark the wall cells that straight crossings of the truth's walls pass through.

    A crossing is a run of at most ``max_cells`` wall cells along one of ``steps``
    between two cells of different free regions (``region`` > 0; 0 is not a region). It
    is *see-through* when the map (``cls``: 1 occupied, 0 free, -1 unknown) has no
    occupied cell on the run or at its two ends and a free one on the run.

    Returns
    -------
    crossed, seen : ndarray of bool
        Cells on some crossing; cells on some see-through crossing.
    thickness : ndarray of float64
        Per seen cell, the fewest wall cells of a see-through crossing through it.
    """
    rows, cols = wall.shape
    crossed = np.zeros((rows, cols), dtype=np.bool_)
    seen = np.zeros((rows, cols), dtype=np.bool_)
    thickness = np.full((rows, cols), np.inf)
    for k in range(steps.shape[0]):
        dr = steps[k, 0]
        dc = steps[k, 1]
        for r in range(rows):
            for c in range(cols):
                # A run starts at a free cell followed by a wall cell.
                if region[r, c] <= 0:
                    continue
                r1 = r + dr
                c1 = c + dc
                if not (0 <= r1 < rows and 0 <= c1 < cols) or not wall[r1, c1]:
                    continue
                n = 0
                rr = r1
                cc = c1
                while 0 <= rr < rows and 0 <= cc < cols and wall[rr, cc] and n <= max_cells:
                    n += 1
                    rr += dr
                    cc += dc
                if n > max_cells or not (0 <= rr < rows and 0 <= cc < cols):
                    continue
                end = region[rr, cc]
                if end <= 0 or end == region[r, c]:
                    continue
                blocked = cls[r, c] == 1 or cls[rr, cc] == 1
                free = False
                for j in range(1, n + 1):
                    v = cls[r + j * dr, c + j * dc]
                    if v == 1:
                        blocked = True
                    elif v == 0:
                        free = True
                for j in range(1, n + 1):
                    a = r + j * dr
                    b = c + j * dc
                    crossed[a, b] = True
                    if free and not blocked:
                        seen[a, b] = True
                        if n < thickness[a, b]:
                            thickness[a, b] = n
    return crossed, seen, thickness
