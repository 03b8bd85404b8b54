"""Places other robots go for, pulling a robot's new choice as if seen (patrol.claims)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.floorplan import random_building
from sonarmap.grid import Grid
from sonarmap.patrol.claims import Claims
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.robots import Team
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory


def test_marks_set_the_discs_watched_cells_to_now_and_restore_puts_every_time_back() -> None:
    last = np.full((30, 30), -5.0)
    last[:, 20:] = np.inf  # not watched
    last[15, 15] = 50.0  # seen later than the mark's time
    before = last.copy()
    claims = Claims(0.5, 0.1)  # discs of radius 5 cells
    marks = claims.mark(last, 10.0, [(10, 10), (12, 12), (15, 18)])  # overlapping discs
    assert last[10, 10] == 10.0
    assert last[10, 15] == 10.0
    assert last[12, 16] == 10.0
    assert last[10, 17] == -5.0  # 7, 5.4 and 5.1 cells from the three places: out of all
    assert np.isinf(last[15, 21])  # not watched, inside the third disc
    assert last[15, 15] == 50.0  # a later sight is kept
    assert last[0, 0] == -5.0
    Claims.restore(last, marks)
    np.testing.assert_array_equal(last, before)


def test_the_others_places_are_those_not_seen_since_chosen_and_never_the_robots_own() -> None:
    last = np.zeros((5, 5))
    last[1, 1] = 3.0  # seen at 3 s
    aims = [(0, 0), (1, 1), None, (2, 2)]
    aimed_at = np.array([1.0, 2.0, 0.0, 1.0])
    # Robot 1's place was seen (3 s) after it chose it (2 s); robot 2 goes for nothing.
    assert Claims.others(0, aims, aimed_at, last) == [(2, 2)]
    assert Claims.others(3, aims, aimed_at, last) == [(0, 0)]


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf])
def test_a_claim_radius_must_be_a_finite_length_of_at_least_zero(bad: float) -> None:
    with pytest.raises(ConfigError, match="claim"):
        PatrolConfig(claim=bad)
    with pytest.raises(ValueError, match="claim"):
        Claims(bad, 0.1)


@pytest.mark.parametrize(
    "setting",
    [
        {"direction": "vector"},
        {"dilation": 1},
        {"policy": "random"},
        {"motion": "straight"},
        {"sectors": 12},
        {"model": "car"},
    ],
)
def test_claims_are_refused_where_the_choice_never_reads_them(setting: dict[str, object]) -> None:
    with pytest.raises(ConfigError, match="claim needs"):
        PatrolConfig(claim=5.0, **setting)  # type: ignore[arg-type]


def test_claims_need_the_full_network() -> None:
    with pytest.raises(ConfigError, match="claim needs network 'full'"):
        PatrolConfig(claim=5.0, network="limited")


def _building() -> Territory:
    plan = random_building(24.0, 16.0, seed=3, max_room=6.0, door=(1.0, 1.5))
    return Territory.from_map(plan.render(Grid.from_bounds(0, 0, 24.0, 16.0, 0.1)), cell=0.1)


def _near_share(t: Territory, cfg: PatrolConfig) -> tuple[float, np.ndarray]:
    near: list[bool] = []

    def on_step(time: float, team: Team, fog: Fog) -> None:
        near.append(bool(math.hypot(team.x[0] - team.x[1], team.y[0] - team.y[1]) < cfg.vision))

    res = run_patrol(t, cfg, robots=2, seed=0, on_step=on_step)
    return float(np.mean(near[len(near) // 5 :])), res.mtb


@pytest.mark.slow
def test_one_robot_runs_the_same_with_claims_and_two_part_company() -> None:
    t = _building()
    cfg = PatrolConfig(radius=0.3, speed=1.0, vision=3.0, duration=300.0, cell=0.1)
    claimed = dataclasses.replace(cfg, claim=3.0)
    # No other robot: nothing is claimed, the run is the same.
    np.testing.assert_array_equal(
        run_patrol(t, cfg, robots=1, seed=0).mtb, run_patrol(t, claimed, robots=1, seed=0).mtb
    )
    # Two robots choosing from the same fog keep close; with claims they go apart, and
    # the marks leave the fog (the metric) as the robots saw it.
    near_base, _ = _near_share(t, cfg)
    near_claim, mtb = _near_share(t, claimed)
    assert near_claim < near_base
    assert np.all(np.isfinite(mtb))


@pytest.mark.slow
def test_the_marks_never_reach_the_fog_the_run_is_measured_on() -> None:
    """A cell the fog says was seen at a step's time was within sight of a robot then:
    marks left in the fog (a claimed place far from every robot) would break this."""
    t = _building()
    cfg = PatrolConfig(radius=0.3, speed=1.0, vision=3.0, duration=120.0, cell=0.1, claim=3.0)
    g = t.grid
    reach = cfg.vision + 2 * g.resolution
    where: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    marked_far: list[int] = []

    def on_step(time: float, team: Team, fog: Fog) -> None:
        where[time] = (team.x.copy(), team.y.copy())
        for seen_at, (x, y) in list(where.items())[-3:]:
            rows, cols = np.nonzero(fog.last == seen_at)
            px, py = g.cell_centres(rows, cols)
            near = np.zeros(len(rows), dtype=bool)
            for xi, yi in zip(x, y, strict=True):
                near |= np.hypot(px - xi, py - yi) <= reach
            marked_far.append(int(np.count_nonzero(~near)))

    run_patrol(t, cfg, robots=3, seed=0, on_step=on_step)
    assert len(marked_far) > 100
    assert max(marked_far) == 0
