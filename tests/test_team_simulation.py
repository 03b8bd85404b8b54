"""A team's mission in simulation: robots exchanging poses over the simulated network
(short runs)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sonarmap.io.rosmap import OccupancyMap
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams
from sonarmap.team.simulation import TeamResult, held_uids, map_agreement, run_team

#: Summary keys measured on the wall clock: they differ between identical runs.
WALL = {"wall_seconds", "association_ms_median", "association_ms_p99", "global_map_batch_s"}


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def _team(plan: OccupancyMap, robots: int, kind: str, duration: float) -> TeamResult:
    return run_team(
        plan,
        MissionConfig(duration=duration, seed=1),
        robots,
        network=NetworkParams(kind=kind),
        exchange=ExchangeParams(),
        seed=3,
    )


@pytest.fixture(scope="module")
def full(plan: OccupancyMap) -> TeamResult:
    return _team(plan, 3, "full", 30.0)


def _without_wall(s: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in s.items() if k not in WALL and k != "robots"}
    out["robots"] = [{k: v for k, v in r.items() if k not in WALL} for r in s["robots"]]
    return out


def test_a_full_network_gives_every_robot_every_local_store(full: TeamResult) -> None:
    s = full.summary
    stores = [r.store for r in full.robots]
    for i, a in enumerate(stores):
        for j, b in enumerate(stores):
            if i != j:
                assert set(a.received[j].poses) == set(b.local.poses)
    assert s["duplicate_poses"] == 0
    assert s["identical_maps"] is True
    # The same poses, closures found apart: the maps agree on nearly every known cell.
    assert 0.9 <= s["map_agreement"] <= 1.0
    assert s["settled"] is True
    assert s["bytes_per_robot_minute"] > 0
    rows = s["robots"]
    for i, row in enumerate(rows):
        others = sum(r["poses_local"] for j, r in enumerate(rows) if j != i)
        assert row["poses_received"] == others
        assert row["poses_local"] == row["poses"] > 0
        assert row["bytes_sent"] > 0
        assert row["bytes_received"] > 0
        assert row["messages"] > 0
        assert 0.0 < row["map_f1"] <= 1.0
    # Every body one robot sent, another received (no loss on this network).
    assert sum(r["bytes_sent"] for r in rows) == sum(r["bytes_received"] for r in rows)


def test_received_poses_are_associated_and_graphed(full: TeamResult) -> None:
    rows = full.summary["robots"]
    assert sum(r["received_closures"] for r in rows) > 0
    assert all(r["received_closures_correct"] == r["received_closures"] for r in rows)
    # Each robot's graph holds the poses of all its layers.
    for r in full.robots:
        held, twice = held_uids(r.store)
        assert twice == 0
        assert held <= set(r.graph.estimates)


def test_no_network_exchanges_nothing(plan: OccupancyMap) -> None:
    s = _team(plan, 2, "none", 20.0).summary
    for row in s["robots"]:
        assert row["bytes_sent"] == row["bytes_received"] == 0
        assert row["messages"] == 0
        assert row["poses_received"] == 0
        assert row["received_closures"] == 0
    assert s["bytes_per_robot_minute"] == 0
    assert s["duplicate_poses"] == 0
    assert s["identical_maps"] is False
    # Each robot mapped only its own route.
    assert s["map_agreement"] < 0.9


def test_map_agreement_counts_known_cells_only(plan: OccupancyMap) -> None:
    unknown = OccupancyMap(plan.grid, np.full_like(plan.occupancy, np.nan))
    assert map_agreement([plan, plan]) == 1.0
    assert map_agreement([plan]) == 1.0
    assert map_agreement([plan, unknown]) == 0.0
    flipped = OccupancyMap(plan.grid, np.where(plan.classes() == 1, 0.0, plan.occupancy))
    share = np.mean(plan.classes()[plan.classes() >= 0] == 0)
    assert map_agreement([plan, flipped, plan]) == pytest.approx(share)


def test_a_team_is_deterministic(plan: OccupancyMap) -> None:
    a = _team(plan, 2, "full", 20.0).summary
    b = _team(plan, 2, "full", 20.0).summary
    assert _without_wall(a) == _without_wall(b)


def test_robots_must_be_positive(plan: OccupancyMap) -> None:
    with pytest.raises(ValueError, match="robots"):
        _team(plan, 0, "full", 10.0)
