"""The coarse near-miss image of the map alignment's multi-resolution search: where it
puts each fine cell (sonarmap.team.globalmap._coarse_near)."""

from __future__ import annotations

import numpy as np

from sonarmap.grid import Grid
from sonarmap.team.globalmap import _coarse_near

# 7 x 10 fine cells of 0.1 m with the lower-left corner at (2, -1): pooled by 3, the
# coarse grid is 3 x 4 cells of 0.3 m padded at the top and the right.
FINE = Grid(0.1, (2.0, -1.0), (7, 10))


def test_a_fine_cell_lands_in_the_coarse_cell_under_its_centre() -> None:
    near = np.zeros(FINE.shape)
    near[1, 9] = 1.0  # the right column's second row, centre (2.95, -0.45)
    near[6, 0] = 0.5  # the bottom-left one, centre (2.05, -0.95)
    pooled, coarse = _coarse_near(near, FINE, 3)
    assert np.isclose(coarse.resolution, 0.3)
    assert coarse.origin == (2.0, -1.0)
    assert coarse.shape == (3, 4)
    expected = np.zeros((3, 4))
    # 0.95 m east of the corner is column 3; 0.55 m north is the middle row (the
    # padding is at the top: pooled from the top it would be the top row).
    expected[1, 3] = 1.0
    expected[2, 0] = 0.5
    np.testing.assert_array_equal(pooled, expected)


def test_each_coarse_cell_is_the_best_fine_value_under_it() -> None:
    rng = np.random.default_rng(4)
    near = rng.random(FINE.shape)
    pooled, coarse = _coarse_near(near, FINE, 3)
    rows, cols = np.indices(FINE.shape)
    x, y = FINE.cell_centres(rows.ravel(), cols.ravel())
    r, c = coarse.world_to_cell(x, y)
    expected = np.zeros(coarse.shape)  # a coarse cell over padding only holds 0
    np.maximum.at(expected, (r, c), near.ravel())
    np.testing.assert_array_equal(pooled, expected)
    # The coarse grid covers the fine one from the same lower-left corner.
    fx0, fx1, fy0, fy1 = FINE.extent
    cx0, cx1, cy0, cy1 = coarse.extent
    assert (cx0, cy0) == (fx0, fy0)
    assert 0 <= cx1 - fx1 < coarse.resolution
    assert 0 <= cy1 - fy1 < coarse.resolution


def test_factor_one_is_the_fine_image() -> None:
    near = np.random.default_rng(5).random(FINE.shape)
    pooled, coarse = _coarse_near(near, FINE, 1)
    assert pooled is near
    assert coarse is FINE
