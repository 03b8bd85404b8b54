"""The prior map's regions and the simulated team mission (sonarmap.team.regions, .world)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from scipy import ndimage

from sonarmap.errors import ConfigError, InputError
from sonarmap.floorplan import FloorPlan
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.regions import cut_regions, mission_regions, region_of, region_sizes
from sonarmap.team.survey import survey
from sonarmap.team.world import (
    World,
    load_world,
    make_world,
    observe,
    odometry,
    patrol_route,
    read_route,
    route_from_waypoints,
    save_world,
    sonar_readings,
)

F64 = npt.NDArray[np.float64]


def two_rooms(door: float | None = 1.0, res: float = 0.1) -> OccupancyMap:
    """Two 6 x 6 m rooms side by side; the wall between at x = 6, with a door of
    ``door`` metres centred at y = 3 (none if None)."""
    plan = FloorPlan((0.0, 0.0, 12.0, 6.0))
    plan.border(0.1)
    plan.box(5.9, 0.0, 6.1, 6.0)
    if door is not None:
        plan.clear(5.9, 3.0 - door / 2, 6.1, 3.0 + door / 2)
    return plan.render(plan.grid(res))


@pytest.fixture(scope="module")
def office_plan() -> OccupancyMap:
    # Only the floor plan is wanted: a one-second, one-pose tour with Thrun's model.
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def free_of(m: OccupancyMap) -> npt.NDArray[np.bool_]:
    return np.asarray(m.classes() == 0)


# --- regions ----------------------------------------------------------------------------


def test_two_rooms_split_at_the_door() -> None:
    m = two_rooms(door=1.0)
    labels = cut_regions(free_of(m), m.grid.resolution)
    assert int(labels.max()) + 1 == 2
    x, _ = m.grid.all_centres()
    free = free_of(m)
    left = np.unique(labels[free & (x < 5.9)])
    right = np.unique(labels[free & (x > 6.1)])
    assert len(left) == 1
    assert len(right) == 1
    assert left[0] != right[0]
    assert (labels[~free] == -1).all()


def test_wide_opening_does_not_split() -> None:
    # A 4 m opening is no door: the two halves are one space.
    m = two_rooms(door=4.0)
    labels = cut_regions(free_of(m), m.grid.resolution)
    assert int(labels.max()) + 1 == 1


def test_same_map_same_labels_numbered_by_first_cell(office_plan: OccupancyMap) -> None:
    free = free_of(office_plan)
    a = cut_regions(free, office_plan.grid.resolution)
    b = cut_regions(free.copy(), office_plan.grid.resolution)
    assert np.array_equal(a, b)
    flat = a.ravel()
    first = [int(np.flatnonzero(flat == k)[0]) for k in range(int(a.max()) + 1)]
    assert first == sorted(first)


def test_corridor_with_rooms_gives_one_region_per_room(office_plan: OccupancyMap) -> None:
    grid = office_plan.grid
    labels = cut_regions(free_of(office_plan), grid.resolution)
    # The default office: a 20 m square, a corridor y in [9, 11], four 5 m rooms a side.
    rooms = [(2.5 + 5 * i, y) for i in range(4) for y in (5.0, 15.0)]
    room_labels = {region_of(labels, grid, x, y) for x, y in rooms}
    corridor = {region_of(labels, grid, x, 10.0) for x in np.arange(0.5, 20.0, 0.5)}
    assert len(room_labels) == 8
    assert len(corridor) == 1
    assert corridor.isdisjoint(room_labels)
    assert int(labels.max()) + 1 == 9
    # Each room is whole: every free cell of a room's box carries that room's label.
    x, y = grid.all_centres()
    for cx, cy in rooms:
        inside = (abs(x - cx) < 2.3) & (abs(y - cy) < 3.8) & (labels >= 0)
        assert len(np.unique(labels[inside])) == 1


def test_huge_open_area_is_tiled() -> None:
    free = np.ones((300, 300), dtype=bool)  # 30 x 30 m at 0.1 m
    labels = cut_regions(free, 0.1, max_area=200.0)
    sizes = region_sizes(labels, 0.1)
    assert len(sizes) >= 5
    assert sizes.max() <= 200.0 + 4.0
    assert sizes.sum() == pytest.approx(900.0)


def test_small_closet_merges_into_its_room() -> None:
    plan = FloorPlan((0.0, 0.0, 8.0, 6.0))
    plan.border(0.1)
    # A 1.5 x 1.5 m closet in a corner behind a 0.8 m door.
    plan.box(0.0, 1.6, 1.6, 1.7)
    plan.box(1.6, 0.0, 1.7, 1.7)
    plan.clear(1.6, 0.5, 1.7, 1.3)
    m = plan.render(plan.grid(0.1))
    free = free_of(m)
    separate = cut_regions(free, 0.1, min_area=1.0, door_width=0.9)
    merged = cut_regions(free, 0.1, min_area=4.0, door_width=0.9)
    assert int(separate.max()) + 1 == 2
    assert int(merged.max()) + 1 == 1


def test_region_of_a_point_on_an_obstacle_is_the_nearest_free_cells() -> None:
    m = two_rooms(door=1.0)
    labels = cut_regions(free_of(m), m.grid.resolution)
    left = region_of(labels, m.grid, 3.0, 1.0)
    right = region_of(labels, m.grid, 9.0, 1.0)
    assert region_of(labels, m.grid, 5.93, 1.0) == left  # in the wall, nearer the left room
    assert region_of(labels, m.grid, 6.08, 1.0) == right
    assert region_of(labels, m.grid, 50.0, 1.0) == right  # off the map


# --- landmarks --------------------------------------------------------------------------


def test_landmarks_lie_on_obstacle_surfaces(office_plan: OccupancyMap) -> None:
    w = make_world(office_plan, seed=3)
    grid = office_plan.grid
    occ = office_plan.classes() == 1
    # Cells from the nearest occupied cell, at each landmark's cell.
    dist = ndimage.distance_transform_edt(~occ)
    moved = np.isfinite(w.moved_at)
    xy = np.concatenate([w.points[:, :2], w.moved_to[moved]])
    r, c = grid.world_to_cell(xy[:, 0], xy[:, 1])
    assert grid.contains(r, c).all()
    assert (dist[r, c] <= 1.0).all()
    assert ((w.points[:, 2] >= 0.2) & (w.points[:, 2] <= 2.0)).all()
    moved_by = np.hypot(*(w.moved_to[moved] - w.points[moved, :2]).T)
    assert moved.sum() > 0
    assert ((moved_by > 0.4) & (moved_by < 2.2)).all()
    # Spacing: about one landmark per 0.5 m of wall, plus the appearing tenth.
    assert len(w) > 200


def test_repeated_textures_look_alike_in_different_places(office_plan: OccupancyMap) -> None:
    w = make_world(office_plan, seed=5, texture_share=0.2, texture_groups=4)
    d = w.descriptors.astype(np.float64)
    assert (w.group >= 0).sum() == round(0.2 * len(w))
    unique = np.flatnonzero(w.group < 0)[:50]
    far_apart = np.linalg.norm(d[unique[0]] - d[unique[1:]], axis=1).min()
    for g in range(4):
        m = np.flatnonzero(w.group == g)
        assert len(m) >= 2
        within = np.linalg.norm(d[m[0]] - d[m[1:]], axis=1).max()
        assert within < 0.2 * far_apart
        spread = np.hypot(*(w.points[m, :2] - w.points[m[0], :2]).T).max()
        assert spread > 3.0


def test_changes_have_times_in_the_mission(office_plan: OccupancyMap) -> None:
    w = make_world(office_plan, seed=1, change_share=0.1, duration=300.0)
    n_gone = int(np.isfinite(w.died).sum())
    n_new = int((w.born > 0).sum())
    assert n_gone == n_new > 0
    assert (w.died[np.isfinite(w.died)] <= 300.0).all()
    assert (w.born <= 300.0).all()
    assert not w.alive(0.0)[w.born > 0].any()
    assert w.alive(299.99)[w.born > 0].all()


def test_same_seed_same_world(office_plan: OccupancyMap) -> None:
    a, b = make_world(office_plan, seed=9), make_world(office_plan, seed=9)
    c = make_world(office_plan, seed=10)
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.descriptors, b.descriptors)
    assert not np.array_equal(a.points[:10], c.points[:10])


# --- observations -----------------------------------------------------------------------


def to_body(pose: tuple[float, float, float], xy: F64) -> tuple[F64, F64]:
    x, y, th = pose
    dx, dy = xy[:, 0] - x, xy[:, 1] - y
    c, s = math.cos(th), math.sin(th)
    return c * dx + s * dy, -s * dx + c * dy


def test_observe_respects_walls_fov_and_range() -> None:
    m = two_rooms(door=None)
    # Every face: the closed room's landmarks are what the wall must hide.
    w = make_world(m, seed=2, change_share=0.0, move_share=0.0, faces="all")
    pose = (4.0, 3.0, 0.0)  # facing the wall between the rooms
    obs = observe(w, pose, 0.0, max_range=8.0, fov_deg=90.0)
    assert len(obs) > 5
    seen = w.points[obs.ids]
    assert (seen[:, 0] < 6.0).all()  # nothing of the other room
    bx, by = to_body(pose, seen[:, :2])
    assert (np.hypot(bx, by) <= 8.0).all()
    assert (np.hypot(bx, by) >= 0.5).all()
    assert (np.abs(np.arctan2(by, bx)) <= math.pi / 4 + 1e-9).all()
    # The other room has landmarks the camera would see but for the wall.
    bx_all, by_all = to_body(pose, w.points[:, :2])
    would = (
        (w.points[:, 0] > 6.1)
        & (np.hypot(bx_all, by_all) <= 8.0)
        & (np.abs(np.arctan2(by_all, bx_all)) <= math.pi / 4)
    )
    assert would.sum() > 5
    # With a door the other room shows through it.
    wd = make_world(two_rooms(door=1.0), seed=2, change_share=0.0, move_share=0.0)
    through = observe(wd, pose, 0.0)
    assert (wd.points[through.ids, 0] > 6.1).any()


def test_observe_sees_only_living_landmarks() -> None:
    m = two_rooms(door=1.0)
    w = make_world(m, seed=4, change_share=0.0, move_share=0.0)
    pose = (3.0, 3.0, math.pi)
    everything = observe(w, pose, 10.0)
    assert len(everything) > 10
    ids = everything.ids
    w.born[ids[::3]] = 50.0  # not yet there at t = 10
    w.died[ids[1::3]] = 5.0  # gone by t = 10
    now = observe(w, pose, 10.0)
    assert set(now.ids.tolist()) == set(ids[2::3].tolist())
    later = observe(w, pose, 60.0)
    assert set(ids[::3].tolist()) <= set(later.ids.tolist())


def test_observe_gives_stereo_points_in_the_robot_frame() -> None:
    m = two_rooms(door=1.0)
    w = make_world(m, seed=6)
    pose = (3.0, 2.0, 0.7)
    obs = observe(w, pose, 1.0, seed=1)
    true = w.positions(1.0)[obs.ids]
    bx, by = to_body(pose, true[:, :2])
    depth = obs.points[:, 0].astype(np.float64)
    # Depth error of a stereo pair grows as X^2 sigma_d / (f B): 4 sigma allowed.
    sigma = bx**2 * 0.3 * math.sqrt(2) / (500.0 * 0.12)
    assert (np.abs(depth - bx) <= 4 * sigma + 1e-3).all()
    assert np.corrcoef(obs.points[:, 1], by)[0, 1] > 0.99
    assert (obs.reliability == 0.5).all()
    assert (obs.stamp == 1.0).all()
    noise = obs.descriptors.astype(float) - w.descriptors[obs.ids]
    assert 5.0 < noise.std() < 11.0
    again = observe(w, pose, 1.0, seed=1)
    assert np.array_equal(again.points, obs.points)


# --- routes and odometry ----------------------------------------------------------------


def test_route_from_waypoints_stays_free_and_reaches_them() -> None:
    m = two_rooms(door=1.0)
    route = route_from_waypoints(m, [(2.0, 1.5), (10.0, 4.5)], speed=0.5, rate=2.0)
    assert route.shape[1] == 4
    assert np.allclose(np.diff(route[:, 0]), 0.5)
    r, c = m.grid.world_to_cell(route[:, 1], route[:, 2])
    assert (m.classes()[r, c] == 0).all()
    assert np.hypot(route[0, 1] - 2.0, route[0, 2] - 1.5) < 0.2
    assert np.hypot(route[-1, 1] - 10.0, route[-1, 2] - 4.5) < 0.2
    # It passes the door, and the heading follows the motion.
    near_door = np.hypot(route[:, 1] - 6.0, route[:, 2] - 3.0).min()
    assert near_door < 0.5
    step = np.diff(route[:, 1:3], axis=0)
    moving = np.hypot(*step.T) > 0.1
    heading = np.arctan2(step[moving, 1], step[moving, 0])
    err = np.angle(np.exp(1j * (heading - route[:-1][moving, 3])))
    assert np.abs(err).max() < 0.5


def test_patrol_route_lasts_and_is_deterministic(office_plan: OccupancyMap) -> None:
    a = patrol_route(office_plan, 120.0, seed=3)
    b = patrol_route(office_plan, 120.0, seed=3)
    c = patrol_route(office_plan, 120.0, seed=4)
    assert a.shape == (240, 4)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    r, cc = office_plan.grid.world_to_cell(a[:, 1], a[:, 2])
    assert (office_plan.classes()[r, cc] == 0).all()
    speed = np.hypot(*np.diff(a[:, 1:3], axis=0).T) * 2.0
    assert speed.max() <= 0.5 + 1e-6


def test_patrol_route_tour_passes_places_again_the_same_way(office_plan: OccupancyMap) -> None:
    # 600 s: three laps of at most 100 m each; random waypoints rarely pass a place the
    # same way twice.
    tour = patrol_route(office_plan, 600.0, seed=3, style="tour")
    rand = patrol_route(office_plan, 600.0, seed=3)
    assert tour.shape == rand.shape == (1200, 4)
    labels = mission_regions(office_plan)
    world = make_world(office_plan, seed=3)
    st = survey(office_plan, world, tour, labels).figures
    sr = survey(office_plan, world, rand, labels).figures
    assert st["route_revisit_time_share"] > 0.6
    assert st["route_revisit_time_share"] > sr["route_revisit_time_share"] + 0.2
    assert st["route_on_territory_share"] > 0.95
    # The tour is the seed's start, then the same loop: two seeds share the loop.
    other = patrol_route(office_plan, 600.0, seed=4, style="tour")
    end_a = {tuple(np.round(p, 1)) for p in tour[-400:, 1:3]}
    end_b = {tuple(np.round(p, 1)) for p in other[-400:, 1:3]}
    assert len(end_a & end_b) > 0.5 * len(end_a)


def test_patrol_route_refuses_a_bad_style(office_plan: OccupancyMap) -> None:
    with pytest.raises(ConfigError, match="style"):
        patrol_route(office_plan, 60.0, style="zigzag")
    with pytest.raises(ConfigError, match="laps"):
        patrol_route(office_plan, 60.0, laps=0.0)


def final_error(route: F64, seed: int) -> float:
    odo, _ = odometry(route, seed=seed)
    return float(np.hypot(*(odo[-1, 1:3] - route[-1, 1:3])))


def test_odometry_drifts_with_distance_and_is_deterministic(office_plan: OccupancyMap) -> None:
    long = patrol_route(office_plan, 600.0, seed=1)
    short = long[:60]
    long_err = np.mean([final_error(long, s) for s in range(5)])
    short_err = np.mean([final_error(short, s) for s in range(5)])
    assert long_err > 0.5
    assert long_err > 5 * short_err
    a, sa = odometry(long, seed=7)
    b, sb = odometry(long, seed=7)
    assert np.array_equal(a, b)
    assert np.array_equal(sa, sb)
    assert sa.shape == (len(long) - 1, 3)
    assert not np.array_equal(a, odometry(long, seed=8)[0])
    assert np.array_equal(a[:, 0], long[:, 0])
    assert np.allclose(a[0], long[0])


def test_odometry_without_noise_reproduces_the_route(office_plan: OccupancyMap) -> None:
    route = patrol_route(office_plan, 60.0, seed=2)
    odo, _ = odometry(route, sigma_xy=0, sigma_theta=0, sigma_theta_dist=0, bias_theta=0)
    assert np.allclose(odo[:, 1:3], route[:, 1:3], atol=1e-9)


def test_sonar_readings_ring(office_plan: OccupancyMap) -> None:
    route = patrol_route(office_plan, 5.0, seed=0)
    rd = sonar_readings(office_plan, route, model=Noise(), seed=1)
    assert len(rd.range) == 16 * len(route)
    assert np.isfinite(rd.range).all()
    assert (rd.range < 10.7).any()  # walls are seen


# --- files ------------------------------------------------------------------------------


def same_world(a: World, b: World) -> None:
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.descriptors, b.descriptors)
    assert np.array_equal(a.born, b.born)
    assert np.array_equal(a.died, b.died)
    assert np.array_equal(a.moved_at, b.moved_at, equal_nan=True)
    assert np.array_equal(a.moved_to, b.moved_to, equal_nan=True)
    assert np.array_equal(a.group, b.group)
    assert a.params == b.params
    assert np.array_equal(a.plan.classes(), b.plan.classes())
    assert a.plan.grid == b.plan.grid


def test_save_load_round_trip(tmp_path: Path, office_plan: OccupancyMap) -> None:
    w = make_world(office_plan, seed=11, duration=60.0)
    route = patrol_route(office_plan, 60.0, seed=1)
    save_world(w, route, tmp_path / "mission")
    w2, r2 = load_world(tmp_path / "mission")
    same_world(w, w2)
    assert r2 is not None
    assert np.array_equal(route, r2)
    assert np.isfinite(w2.moved_at).any()
    # Saved again (the plan now comes from a file), it still loads the same.
    save_world(w2, None, tmp_path / "again")
    w3, r3 = load_world(tmp_path / "again")
    same_world(w, w3)
    assert r3 is None


def write_route(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join(["t,x,y,theta", *rows]) + "\n")
    return path


def test_read_route_names_the_broken_line(tmp_path: Path) -> None:
    good = write_route(tmp_path / "good.csv", ["0,1,2,0", "0.5,1.2,2,0.1"])
    assert read_route(good).shape == (2, 4)
    bad = write_route(tmp_path / "bad.csv", ["0,1,2,0", "0.5,oops,2,0.1"])
    with pytest.raises(InputError, match=r"bad\.csv:3, field 'x': not a number") as err:
        read_route(bad)
    assert err.value.line == 3
    short = write_route(tmp_path / "short.csv", ["0,1,2,0", "0.5,1.2,2"])
    with pytest.raises(InputError, match=r"short\.csv:3: 3 fields, expected 4"):
        read_route(short)
    back = write_route(tmp_path / "back.csv", ["1,1,2,0", "0.5,1.2,2,0"])
    with pytest.raises(InputError, match=r"back\.csv:3, field 't': time 0.5 does not follow"):
        read_route(back)
    header = tmp_path / "header.csv"
    header.write_text("time,x,y\n0,1,2\n")
    with pytest.raises(InputError, match=r"header\.csv:1: header must be 't,x,y,theta'"):
        read_route(header)
    with pytest.raises(InputError, match="no such file"):
        read_route(tmp_path / "missing.csv")


def test_broken_landmark_file_names_line_and_field(tmp_path: Path) -> None:
    m = two_rooms(door=1.0)
    save_world(make_world(m, seed=0), None, tmp_path / "w")
    csv_path = tmp_path / "w" / "landmarks.csv"
    lines = csv_path.read_text().splitlines()
    cells = lines[4].split(",")
    cells[-1] = cells[-1][:-2]  # one descriptor byte short
    lines[4] = ",".join(cells)
    csv_path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"landmarks\.csv:5, field 'descriptor_hex'"):
        load_world(tmp_path / "w")
