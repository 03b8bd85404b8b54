"""Seeded floor plans: the training and held-out buildings."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from sonarmap.floorplan import random_building


@pytest.mark.parametrize("seed", range(8))
def test_a_random_building_is_one_connected_floor_of_several_rooms(seed: int) -> None:
    plan = random_building(seed=seed)
    occ = plan.render(plan.grid(0.1)).occupancy
    _, parts = ndimage.label(occ == 0)
    assert parts == 1
    walls = [op for op in plan.ops if op[4] == 1.0]
    assert len(walls) >= 4 + 3  # the border and at least three inner walls
    again = random_building(seed=seed).render(plan.grid(0.1)).occupancy
    assert np.array_equal(occ, again)
    other = random_building(seed=seed + 100).render(plan.grid(0.1)).occupancy
    assert not np.array_equal(occ, other)


def test_a_building_too_small_for_its_rooms_is_refused() -> None:
    with pytest.raises(ValueError, match="cannot hold"):
        random_building(4.0, 4.0, min_room=3.0)
