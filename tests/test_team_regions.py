"""Which regions of the prior map touch (the limited-network exchange asks for adjacent
patches together)."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.team.regions import cut_regions, region_adjacency


def test_two_rooms_joined_by_a_door_are_adjacent_and_nothing_else() -> None:
    free = np.ones((40, 120), dtype=bool)
    free[:, 39:41] = False
    free[18:22, 39:41] = True  # a 0.4 m door between the left and middle rooms
    free[:, 79:81] = False  # a closed wall: the right room touches nobody
    labels = cut_regions(free, 0.1, min_area=1.0)
    assert int(labels.max()) + 1 == 3
    left, middle, right = (int(labels[5, c]) for c in (5, 60, 110))
    adj = region_adjacency(labels)
    assert adj == {left: {middle}, middle: {left}, right: set()}


def test_corner_contacts_do_not_count_and_the_result_is_symmetric() -> None:
    labels = np.array(
        [
            [0, 0, -1, 1],
            [0, 0, 1, 1],
            [-1, 2, -1, -1],
            [3, 2, 2, -1],
        ],
        dtype=np.int32,
    )
    adj = region_adjacency(labels)
    # 0 and 1 share the side at (1, 1)-(1, 2); 0 and 2 at (1, 1)-(2, 1); 1 and 2 touch
    # only by a corner; 3 and 2 share a side.
    assert adj == {0: {1, 2}, 1: {0}, 2: {0, 3}, 3: {2}}
    for r, ns in adj.items():
        assert all(r in adj[n] for n in ns)


def test_region_adjacency_wants_a_2d_integer_grid() -> None:
    with pytest.raises(ValueError, match="2-D integer array"):
        region_adjacency(np.zeros((2, 2, 2), dtype=np.int32))
    with pytest.raises(ValueError, match="2-D integer array"):
        region_adjacency(np.zeros((2, 2)))  # type: ignore[arg-type]
    assert region_adjacency(np.full((3, 3), -1, dtype=np.int32)) == {}


def test_mission_regions_leave_out_free_space_no_robot_reaches() -> None:
    # An 8 x 8 m room with a shelf drawn as a 1-cell outline (free inside, as a SLAM map
    # draws it) and a 0.3 m strip of free outside the east wall.
    from sonarmap.floorplan import FloorPlan
    from sonarmap.team.regions import mission_regions

    plan = FloorPlan((0.0, 0.0, 8.4, 8.0))
    plan.border(0.1)
    plan.clear(8.1, 0.1, 8.4, 7.9)
    plan.box(8.0, 0.0, 8.1, 8.0)
    for x0, y0, x1, y1 in ((3, 3, 5, 3.1), (3, 4.9, 5, 5), (3, 3, 3.1, 5), (4.9, 3, 5, 5)):
        plan.box(x0, y0, x1, y1)
    m = plan.render(plan.grid(0.1))
    free = m.classes() == 0
    every = cut_regions(free, 0.1)
    mine = mission_regions(m)
    inside_shelf = m.grid.world_to_cell(4.0, 4.0)
    strip = m.grid.world_to_cell(8.25, 4.0)
    room = m.grid.world_to_cell(1.5, 1.5)
    for cell in (inside_shelf, strip):
        assert every[cell] >= 0
        assert mine[cell] == -1
    assert mine[room] >= 0
    assert ((mine >= 0) <= free).all()
