"""A mission's world measured on its map (sonarmap.team.survey)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError, InputError
from sonarmap.floorplan import FloorPlan
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.team.regions import cut_regions, mission_regions
from sonarmap.team.survey import KINDS, draw_survey, landmark_kinds, survey
from sonarmap.team.world import make_world, route_from_waypoints, speckle_mask

F64 = npt.NDArray[np.float64]


def two_rooms(door: float) -> OccupancyMap:
    """Two 6 x 6 m rooms, a wall at x = 6 with a door of ``door`` metres at y = 3."""
    plan = FloorPlan((0.0, 0.0, 12.0, 6.0))
    plan.border(0.1)
    plan.box(5.9, 0.0, 6.1, 6.0)
    plan.clear(5.9, 3.0 - door / 2, 6.1, 3.0 + door / 2)
    return plan.render(plan.grid(0.1))


def back_and_forth(plan: OccupancyMap, laps: int) -> F64:
    """A route driving a loop round the left room ``laps`` times, the same way."""
    loop = [(1.0, 1.0), (4.5, 1.0), (4.5, 4.5), (1.0, 4.5)]
    return route_from_waypoints(plan, loop * laps + [loop[0]])


def test_landmarks_behind_a_door_too_narrow_are_unreachable() -> None:
    # A 0.4 m door: a 0.3 m robot stays in the left room.
    plan = two_rooms(door=0.4)
    world = make_world(plan, seed=1, change_share=0.0, move_share=0.0, faces="all")
    route = back_and_forth(plan, 1)
    s = survey(plan, world, route, mission_regions(plan))
    right = world.points[:, 0] > 6.1
    assert (s.kinds[right] == KINDS.index("unreachable")).all()
    inner_left = (world.points[:, 0] < 5.8) & (world.points[:, 0] > 0.2)
    inner_left &= (world.points[:, 1] > 0.2) & (world.points[:, 1] < 5.8)
    assert (s.kinds[inner_left] == KINDS.index("reachable")).all()
    # The right room's faces: about half the wall.
    assert 0.3 < s.figures["landmarks_unreachable_share"] < 0.7
    assert s.figures["landmarks_reachable_share"] + s.figures["landmarks_unreachable_share"] == 1


def test_the_default_world_puts_landmarks_only_where_the_robot_can_see_them() -> None:
    # The same rooms: by default no landmark lies in the room the robot cannot enter
    # (the left room is the largest area, first among equals).
    plan = two_rooms(door=0.4)
    world = make_world(plan, seed=1)
    assert len(world) > 20
    assert (world.points[:, 0] < 5.95).all()
    assert (
        np.isnan(world.moved_to[:, 0]).all()
        or (world.moved_to[:, 0] < 5.95)[np.isfinite(world.moved_to[:, 0])].all()
    )
    s = survey(plan, world, back_and_forth(plan, 1), mission_regions(plan))
    assert s.figures["landmarks_reachable_share"] == 1.0
    # With every face, the right room's walls get their share.
    every = make_world(plan, seed=1, faces="all")
    assert (every.points[:, 0] > 6.1).sum() > 0.3 * len(every)


def test_no_face_to_put_landmarks_on_is_one_line_error() -> None:
    plan = FloorPlan((0.0, 0.0, 6.0, 6.0))
    m = plan.render(plan.grid(0.1))  # all free: no wall at all
    with pytest.raises(InputError, match="no obstacle facing free space"):
        make_world(m)
    with pytest.raises(ConfigError, match="faces"):
        make_world(two_rooms(door=1.0), faces="some")


def test_a_speck_is_speckle_and_a_post_is_not() -> None:
    plan = FloorPlan((0.0, 0.0, 6.0, 6.0))
    plan.border(0.1)
    plan.box(2.0, 2.0, 2.05, 2.05)  # one 5 cm speck at 5 cm cells
    plan.box(4.0, 4.0, 4.2, 4.2)  # a 20 cm post
    m = plan.render(plan.grid(0.05))
    speck = speckle_mask(m)
    r, c = m.grid.world_to_cell(2.02, 2.02)
    assert speck[r, c]
    r, c = m.grid.world_to_cell(4.1, 4.1)
    assert not speck[r, c]
    watched = m.classes() == 0
    xy = np.array([[2.0, 2.02], [4.0, 4.1]])
    kinds = landmark_kinds(m, xy, watched, speck)
    assert [KINDS[k] for k in kinds] == ["speckle", "reachable"]


def test_a_loop_driven_again_revisits_and_one_lap_does_not() -> None:
    plan = two_rooms(door=1.0)
    world = make_world(plan, seed=1)
    labels = mission_regions(plan)
    once = survey(plan, world, back_and_forth(plan, 1), labels)
    # A lap is about 14 m, 28 s at 0.5 m/s: a place counts again from the third lap
    # back (a pass at least 60 s before), so from the fourth lap on.
    five = survey(plan, world, back_and_forth(plan, 5), labels)
    assert once.figures["route_revisits"] == 0
    assert five.figures["route_revisits"] >= 1
    assert 0.2 < five.figures["route_revisit_time_share"] < 0.7
    assert 60.0 <= five.figures["route_revisit_since_median_s"] < 100.0
    assert five.figures["route_on_territory_share"] > 0.9


def test_a_cut_at_a_door_is_at_a_door_and_a_tile_cut_is_not() -> None:
    plan = two_rooms(door=1.0)
    world = make_world(plan, seed=1)
    route = back_and_forth(plan, 1)
    doors = survey(plan, world, route, mission_regions(plan))
    assert doors.figures["regions"] == 2
    assert doors.figures["regions_cuts"] == doors.figures["regions_cuts_at_doors"] == 1
    # An open 12 x 6 m hall tiled into 9 m2 pieces: every cut crosses open floor.
    open_hall = FloorPlan((0.0, 0.0, 12.0, 6.0))
    open_hall.border(0.1)
    hall = open_hall.render(open_hall.grid(0.1))
    tiles = cut_regions(hall.classes() == 0, 0.1, max_area=20.0)
    s = survey(hall, make_world(hall, seed=1), back_and_forth(hall, 1), tiles)
    assert s.figures["regions"] >= 4
    assert s.figures["regions_cuts_at_doors"] == 0


def test_bad_route_and_labels_refused(tmp_path: Path) -> None:
    plan = two_rooms(door=1.0)
    world = make_world(plan, seed=1)
    with pytest.raises(ConfigError, match="route"):
        survey(plan, world, np.zeros((1, 4)), mission_regions(plan))
    with pytest.raises(ConfigError, match="regions"):
        survey(plan, world, back_and_forth(plan, 1), np.zeros((3, 3), dtype=np.int32))


def test_picture_is_written(tmp_path: Path) -> None:
    plan = two_rooms(door=1.0)
    world = make_world(plan, seed=1)
    route = back_and_forth(plan, 2)
    s = survey(plan, world, route, mission_regions(plan))
    p = draw_survey(plan, world, route, s, tmp_path / "s.png", title="two rooms")
    assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_team_world_tour_option_drives_a_route_that_comes_back(tmp_path: Path) -> None:
    from sonarmap.cli import main
    from sonarmap.team.world import load_world

    for flag, name in (([], "plain"), (["--tour"], "tour")):
        main(["team", "world", "--map", "office", "--duration", "600", *flag,
              "-o", str(tmp_path / name)])  # fmt: skip
    shares = {}
    for name in ("plain", "tour"):
        world, route = load_world(tmp_path / name)
        assert route is not None
        s = survey(world.plan, world, route, mission_regions(world.plan))
        shares[name] = s.figures["route_revisit_time_share"]
    assert shares["tour"] > 0.4
    assert shares["tour"] > shares["plain"] + 0.1
