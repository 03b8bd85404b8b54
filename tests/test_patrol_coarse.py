"""The path motion's choice of a place on blocks of cells (patrol.coarse)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.floorplan import random_building
from sonarmap.grid import Grid
from sonarmap.patrol.coarse import CoarseChoice, any_in_blocks
from sonarmap.patrol.forces import Force, sector_pulls, step_direction
from sonarmap.patrol.paths import Wave, nearest_step, shadows
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory


def test_a_block_is_set_where_any_of_its_cells_is_and_edge_blocks_count_their_cells() -> None:
    mask = np.zeros((5, 7), dtype=bool)
    mask[0, 0] = True  # block (0, 0)
    mask[4, 6] = True  # the corner block, cut to one cell by the grid's edges
    mask[2, 3] = True  # block (0, 1)
    out = any_in_blocks(mask, 3)
    assert out.shape == (2, 3)
    assert out.tolist() == [[True, True, False], [False, False, True]]
    with pytest.raises(ValueError, match="block"):
        any_in_blocks(mask, 0)


def test_a_choice_cell_under_two_cells_leaves_the_choice_to_the_cells() -> None:
    open_ = np.ones((12, 12), dtype=bool)
    assert CoarseChoice.build(open_, open_, 0.1, 0.0) is None
    assert CoarseChoice.build(open_, open_, 0.1, 0.14) is None
    choice = CoarseChoice.build(open_, open_, 0.1, 0.3)
    assert choice is not None
    assert choice.block == 3
    with pytest.raises(ValueError, match="cell"):
        CoarseChoice.build(open_, open_, 0.1, -0.3)


def _room() -> tuple[np.ndarray, np.ndarray]:
    """A 6 x 9 m room of 0.1 m cells, walled round, the robot's centre kept 0.3 m off."""
    free = np.zeros((60, 90), dtype=bool)
    free[1:-1, 1:-1] = True
    passable = np.zeros_like(free)
    passable[4:-4, 4:-4] = True
    return passable, free


def test_the_blocks_choose_the_old_corner_and_name_its_oldest_cell() -> None:
    passable, free = _room()
    last = np.where(free, 0.0, np.inf)
    # Everything seen at t = 0 but the north-east corner, unseen since t = -50, with its
    # oldest cell at -60.
    last[2:12, 70:88] = -50.0
    last[5, 80] = -60.0
    force, now = Force(), 10.0
    top = now - float(last[free].min())
    choice = CoarseChoice.build(passable, free, 0.1, 0.3)
    assert choice is not None
    start = (45, 10)  # south-west
    way, place, length = choice.choose(start, force, top, last_seen=last, now=now)
    assert way is not None
    assert place == (5, 80)
    # North-east from the south-west corner, as the fine choice goes.
    places = np.full((8, 2), -1, dtype=np.int64)
    fine = sector_pulls(
        Wave(passable.shape),
        passable,
        start,
        0.1,
        free,
        force,
        top,
        last_seen=last,
        now=now,
        certify=True,
        goal=True,
        places=places,
    )
    fine_way = step_direction(fine, "mode")
    assert fine_way is not None
    assert nearest_step(*way) == nearest_step(*fine_way) == 1
    # The blocks' length to the place's block is about the straight way there.
    assert math.isfinite(length)
    assert abs(length - 0.1 * math.hypot(45 - 5, 80 - 10)) < 1.0


def test_a_block_names_its_oldest_reachable_cell_else_its_oldest_shadows_anchor() -> None:
    passable, free = _room()
    passable[:5] = False  # the centre kept 0.5 m off the north wall: rows 1-3 shadows
    sh = shadows(passable, free, 0.1)
    choice = CoarseChoice.build(passable, free, 0.1, 0.3, fine_shadows=sh)
    assert choice is not None
    last = np.where(free, 0.0, np.inf)
    # Block (1, 10): rows 3-5, columns 30-32; row 3 a shadow, row 4 reached in one last
    # step from the passable row 5.
    last[3, 31] = -9.0
    last[4, 32] = -5.0
    assert choice.place_in(1, 10, last_seen=last) == (4, 32)
    # Block (0, 10): rows 0-2, all wall or shadow: the anchor of the oldest, a cell the
    # fine wave reaches.
    last[1, 31] = -20.0
    anchor = choice.place_in(0, 10, last_seen=last)
    assert anchor == (4, 31)
    assert math.isfinite(Wave(passable.shape).to(passable, (30, 45), anchor, 0.1, free))
    # The same with TB in place of last-seen times.
    assert choice.place_in(1, 10, tb=np.where(free, 10.0 - last, 0.0)) == (4, 32)
    with pytest.raises(ValueError, match="either"):
        choice.place_in(0, 10)


def test_a_wave_to_a_goal_beyond_its_limit_gives_inf() -> None:
    passable, free = _room()
    wave = Wave(passable.shape)
    far = wave.to(passable, (10, 10), (10, 80), 0.1, free)
    assert far == pytest.approx(7.0)
    assert wave.to(passable, (10, 10), (10, 80), 0.1, free, limit=6.0) == math.inf
    assert wave.to(passable, (10, 10), (10, 80), 0.1, free, limit=7.5) == pytest.approx(7.0)


def _building() -> Territory:
    plan = random_building(16.0, 12.0, seed=3, max_room=6.0, door=(1.0, 1.5))
    return Territory.from_map(plan.render(Grid.from_bounds(0, 0, 16.0, 12.0, 0.1)), cell=0.1)


def test_a_patrol_choosing_on_blocks_sees_the_building_and_repeats_itself() -> None:
    t = _building()
    cfg = PatrolConfig(radius=0.3, speed=1.0, vision=3.0, duration=120.0, cell=0.1, choice_cell=0.3)
    a = run_patrol(t, cfg, robots=2, seed=0)
    b = run_patrol(t, cfg, robots=2, seed=0)
    np.testing.assert_array_equal(a.mtb, b.mtb)
    np.testing.assert_array_equal(a.positions, b.positions)
    s = a.summary()
    assert s["never_seen"] == 0.0
    assert s["blocked_share"] < 0.05
    # The fine choice's run differs: the blocks did choose.
    fine = run_patrol(t, dataclasses.replace(cfg, choice_cell=0.0), robots=2, seed=0)
    assert not np.array_equal(a.positions, fine.positions)


def test_a_patrol_choosing_on_blocks_calls_the_cells_choice_seldom(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    t = _building()
    calls = {"n": 0}

    def counted(*args: object, **kwargs: object) -> object:
        calls["n"] += 1
        return sector_pulls(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr("sonarmap.patrol.simulation.sector_pulls", counted)
    cfg = PatrolConfig(radius=0.3, speed=1.0, vision=3.0, duration=60.0, cell=0.1, choice_cell=0.0)
    run_patrol(t, cfg, robots=1, seed=0)
    fine = calls["n"]
    calls["n"] = 0
    run_patrol(t, dataclasses.replace(cfg, choice_cell=0.3), robots=1, seed=0)
    assert fine > 20
    assert calls["n"] < 0.2 * fine


@pytest.mark.parametrize("bad", [-0.3, float("nan"), float("inf")])
def test_a_choice_cell_must_be_a_finite_length_of_at_least_zero(bad: float) -> None:
    with pytest.raises(ConfigError, match="choice_cell"):
        PatrolConfig(choice_cell=bad)


def test_with_line_of_sight_the_choice_stays_on_the_cells(monkeypatch: pytest.MonkeyPatch) -> None:
    # A block's place stands for the block's other cells only under a vision disc.
    built: list[object] = []
    real = CoarseChoice.build

    def counted(*args: object, **kwargs: object) -> object:
        built.append(real(*args, **kwargs))  # type: ignore[arg-type]
        return built[-1]

    monkeypatch.setattr(CoarseChoice, "build", counted)
    t = _building()
    seen = PatrolConfig(radius=0.3, speed=1.0, vision=3.0, duration=2.0, cell=0.1)
    run_patrol(t, seen, robots=1, seed=0)
    run_patrol(t, dataclasses.replace(seen, line_of_sight=True), robots=1, seed=0)
    assert len(built) == 1
