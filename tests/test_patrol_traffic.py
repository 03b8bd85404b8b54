"""Robots meeting one another: the give-way rule, and paths that keep to passable cells."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SHARED_DATA
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol.maps import builtin_territory
from sonarmap.patrol.paths import path_to, wave
from sonarmap.patrol.robots import cancel_collisions
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.starts import starts_from_dm
from sonarmap.patrol.territory import Territory


def _moves(
    ends: list[tuple[float, float]], give_way: bool, starts: list[tuple[float, float]]
) -> list[bool]:
    x, y = (np.array(v, dtype=np.float64) for v in zip(*starts, strict=True))
    nx, ny = (np.array(v, dtype=np.float64) for v in zip(*ends, strict=True))
    moving = cancel_collisions(x, y, nx, ny, np.ones(len(x), dtype=bool), 0.6, give_way)
    return [bool(v) for v in moving]


def test_head_on_the_thesis_stops_both_and_give_way_lets_the_first_pass() -> None:
    starts = [(0.0, 0.0), (1.0, 0.0)]
    ends = [(0.3, 0.0), (0.7, 0.0)]  # 0.4 m apart: too close
    assert _moves(ends, False, starts) == [False, False]
    assert _moves(ends, True, starts) == [True, False]


def test_give_way_lets_a_robot_that_backs_off_move() -> None:
    # Robot 0 alone would still end too close to robot 1 where it stands; robot 1's own
    # move (back and aside) parts them: robot 1 moves, robot 0 waits a step.
    starts = [(0.0, 0.0), (1.0, 0.0)]
    ends = [(0.55, 0.0), (1.0, 0.3)]
    assert _moves(ends, False, starts) == [False, False]
    assert _moves(ends, True, starts) == [False, True]


def test_give_way_still_stops_a_robot_walking_into_one_that_stands() -> None:
    starts = [(0.0, 0.0), (1.0, 0.0)]
    x, y = np.array([0.0, 1.0]), np.array([0.0, 0.0])
    moving = cancel_collisions(
        x, y, np.array([0.6, 1.0]), y.copy(), np.array([True, False]), 0.6, True
    )
    assert moving.tolist() == [False, False]
    assert _moves([(0.0, 0.5), (1.0, 0.5)], True, starts) == [True, True]


def test_a_robot_marked_first_keeps_its_move_under_either_rule() -> None:
    starts = [(0.0, 0.0), (1.0, 0.0)]
    x, y = (np.array(v, dtype=np.float64) for v in zip(*starts, strict=True))
    nx, ny = np.array([0.3, 0.7]), np.zeros(2)  # head on, too close
    both = np.ones(2, dtype=bool)
    for give_way in (False, True):
        moving = cancel_collisions(x, y, nx, ny, both, 0.6, give_way, first=np.array([0, 1], bool))
        assert moving.tolist() == [False, True]
    # Two marked (or two unmarked) robots meet by the rule as before.
    for give_way, want in ((False, [False, False]), (True, [True, False])):
        moving = cancel_collisions(x, y, nx, ny, both, 0.6, give_way, first=np.ones(2, bool))
        assert moving.tolist() == want
    # A marked robot whose move alone would still run into the other, while the other
    # backs off: the other moves, as under give-way, rather than neither.
    back = cancel_collisions(
        x, y, np.array([0.7, 1.2]), ny, both, 0.6, False, first=np.array([1, 0], bool)
    )
    assert back.tolist() == [False, True]


def test_two_cars_on_the_fig_3_4_map_do_not_hold_each_other_for_good() -> None:
    """Two tracking cars met at 543 s and held each other for the rest of the run: the
    later one planned its way round every step, and the earlier one, driving on at it,
    made the collision rule cancel that manoeuvre's first step, every step."""
    cfg = PatrolConfig(model="car", refine=True, duration=700.0)
    territory, starts = builtin_territory("fig3-4", cfg.cell)
    res = run_patrol(territory, cfg, starts=starts_from_dm(starts[:2], territory), seed=0)
    assert res.summary()["blocked_share"] < 0.05


@pytest.mark.parametrize("flip", [False, True])
def test_paths_do_not_cut_through_cells_the_wave_may_only_end_on(flip: bool) -> None:
    # Start at (0, 0); (0, 1) may be reached as a target but not crossed, so the
    # wave's length at (1, 1) ties between (0, 1) and (1, 0). Mirrored, the other
    # neighbour comes first in the steps' order: one of the two would cut through.
    ok = np.ones((4, 4), dtype=bool)
    ok[0, 1] = False
    if flip:
        ok = ok.T.copy()
    dist, _ = wave(ok, (0, 0), 0.1, target=np.ones_like(ok))
    cells = path_to(dist, (3, 3), 0.1, ok)
    assert ok[cells[:, 0], cells[:, 1]].all()
    with pytest.raises(ValueError, match="passable"):
        path_to(dist, (3, 3), 0.1, ok[:3])


def _corridor() -> Territory:
    """Two 5 x 6 m rooms joined by a 20 m corridor 1 m wide, at 0.1 m: two 0.6 m robots
    cannot pass each other in it."""
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(60, 300))
    occ = np.ones(g.shape, np.float32)
    occ[1:-1, 1:50] = 0.0
    occ[1:-1, 250:-1] = 0.0
    occ[25:35, 50:250] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


def test_in_a_corridor_one_robot_gives_way_and_neither_jams() -> None:
    # Short sight makes the corridor's far end the place to go for each robot in turn,
    # so reactive robots (each for the longest-unseen place) keep meeting in it. Under
    # the thesis's rule they block each other.
    t = _corridor()
    starts = np.array([[6.0, 3.0, 0.0], [24.0, 3.0, np.pi]])
    share = {}
    for rule in ("thesis", "give-way"):
        cfg = PatrolConfig(
            policy="reactive",
            radius=0.3,
            speed=1.0,
            vision=2.0,
            duration=300.0,
            cell=0.1,
            traffic=rule,
        )
        s = run_patrol(t, cfg, starts=starts, seed=0).summary()
        assert s["never_seen"] == 0.0
        share[rule] = s["blocked_share"]
    assert share["thesis"] > 0.1
    assert share["give-way"] < 0.05


def test_traffic_rule_follows_the_motion_and_is_checked() -> None:
    assert PatrolConfig(radius=0.3).traffic == "give-way"  # path motion
    assert PatrolConfig(motion="straight").traffic == "thesis"
    assert PatrolConfig(model="car").traffic == "thesis"
    with pytest.raises(ConfigError, match="traffic"):
        PatrolConfig(traffic="polite")


@pytest.mark.skipif(not (SHARED_DATA / "maps").is_dir(), reason="needs ../shared/data/maps")
def test_two_indoor_robots_do_not_jam_on_the_depot_map() -> None:
    from sonarmap.io.rosmap import read_map

    t = Territory.from_map(read_map(SHARED_DATA / "maps" / "depot.yaml"), cell=0.1)
    cfg = PatrolConfig(radius=0.3, speed=1.0, vision=5.0, duration=300.0, cell=0.1)
    s = run_patrol(t, cfg, robots=2, seed=1).summary()
    assert s["blocked_share"] < 0.05
    assert s["never_seen"] == 0.0


@pytest.mark.skipif(not (SHARED_DATA / "maps").is_dir(), reason="needs ../shared/data/maps")
def test_a_robot_keeps_its_goal_instead_of_swinging_at_a_corner() -> None:
    # On the warehouse map, from seed 0's start, a robot choosing again every step
    # swings between two cells at a wall's corner (two places whose paths leave in
    # opposite directions) and sees a sixth of the building in 200 s.
    from sonarmap.io.rosmap import read_map

    t = Territory.from_map(read_map(SHARED_DATA / "maps" / "warehouse.yaml"), cell=0.1)
    unseen = {}
    for keep in (False, True):
        cfg = PatrolConfig(
            radius=0.3, speed=1.0, vision=5.0, duration=200.0, cell=0.1, keep_goal=keep
        )
        unseen[keep] = run_patrol(t, cfg, robots=1, seed=0).summary()["never_seen"]
    assert unseen[True] < 0.4
    assert unseen[False] > unseen[True] + 0.2


def test_a_minimum_hold_means_fewer_choices_and_still_every_place_seen(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Each choice of the potential field runs one wave with the pulls summed
    # (sector_pulls); a robot keeping its place for 2 s once chosen chooses less often,
    # and on a small building still sees every place.
    from sonarmap.floorplan import random_building
    from sonarmap.patrol.forces import sector_pulls

    plan = random_building(16.0, 12.0, seed=3, max_room=6.0, door=(1.0, 1.5))
    t = Territory.from_map(plan.render(Grid.from_bounds(0, 0, 16.0, 12.0, 0.1)), cell=0.1)
    calls = {"n": 0}

    def counted(*args: object, **kwargs: object) -> object:
        calls["n"] += 1
        return sector_pulls(*args, **kwargs)  # type: ignore[arg-type]

    # The simulation calls it by the name it imported.
    monkeypatch.setattr("sonarmap.patrol.simulation.sector_pulls", counted)
    choices, unseen = {}, {}
    for hold in (0.0, 2.0):
        calls["n"] = 0
        # The choice on the cells, whose calls are counted (not on blocks).
        cfg = PatrolConfig(
            radius=0.3,
            speed=1.0,
            vision=3.0,
            duration=150.0,
            cell=0.1,
            min_hold=hold,
            choice_cell=0.0,
        )
        unseen[hold] = run_patrol(t, cfg, robots=1, seed=0).summary()["never_seen"]
        choices[hold] = calls["n"]
    assert choices[2.0] < 0.6 * choices[0.0]
    assert unseen[0.0] == unseen[2.0] == 0.0


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf")])
def test_a_minimum_hold_must_be_a_finite_time_of_at_least_zero(bad: float) -> None:
    with pytest.raises(ConfigError, match="min_hold"):
        PatrolConfig(min_hold=bad)
