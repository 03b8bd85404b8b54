"""The store's regions are cut inside the mission's territory: a drawn plan's free
outside is in no region, on the mission (run alone or in a team) and through
``team run``; a SLAM-like map (its outside unknown, so no default territory) keeps the
regions of its whole prior."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import building_cells, drawn_building
from sonarmap.cli import main
from sonarmap.io.rosmap import FREE, OccupancyMap, read_map, write_map
from sonarmap.team.config import MissionConfig
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import RobotAgent
from sonarmap.team.node import state_fingerprint
from sonarmap.team.regions import mission_regions
from sonarmap.team.territory import default_territory, mask_on


def _regions(labels: np.ndarray) -> int:
    return int(labels.max()) + 1


def test_a_drawn_plans_outside_is_in_no_region() -> None:
    plan = drawn_building(outside=0.0)
    terr = default_territory(plan)
    assert terr is not None
    whole = mission_regions(plan)
    inside = mission_regions(plan, region=terr.region)
    building = building_cells(plan)
    # The whole prior's cut sizes the outside (about 240 m^2 of free) in regions.
    assert (whole[~building] >= 0).sum() * 0.01 > 200
    assert ((inside >= 0) <= terr.region).all()
    assert (inside[~building] >= 0).sum() * 0.01 < 1.0  # the entrance's notch at most
    assert _regions(inside) < _regions(whole)
    # Both rooms keep their regions.
    for x in (2.0, 6.0):
        r, c = plan.grid.world_to_cell(x, 3.0)
        assert inside[r, c] >= 0
        assert inside[r, c] != inside[plan.grid.world_to_cell(8.0 - x, 3.0)]


def test_the_mission_cuts_its_regions_inside_the_territory_it_is_given() -> None:
    plan = drawn_building(outside=0.0)
    terr = default_territory(plan)
    assert terr is not None
    cfg = MissionConfig(duration=10.0, seed=0)
    masked = RobotAgent(plan, cfg, territory=terr.region)
    np.testing.assert_array_equal(masked.labels, mission_regions(plan, region=terr.region))
    assert len(masked.region_areas) == _regions(masked.labels)
    whole = RobotAgent(plan, cfg)
    np.testing.assert_array_equal(whole.labels, mission_regions(plan))


def test_a_slam_like_maps_regions_are_unchanged() -> None:
    plan = drawn_building(outside=0.5)
    assert default_territory(plan) is None
    free = plan.classes() == FREE
    assert not (free & ~building_cells(plan)).any()
    agent = RobotAgent(plan, MissionConfig(duration=10.0, seed=0))
    np.testing.assert_array_equal(agent.labels, mission_regions(plan))
    # A mask over the whole map cuts what no mask cuts.
    whole = np.ones(plan.grid.shape, dtype=bool)
    np.testing.assert_array_equal(mission_regions(plan, region=whole), mission_regions(plan))


@pytest.mark.parametrize("robots", [1, 2])
def test_team_run_counts_only_the_territorys_regions(tmp_path: Path, robots: int) -> None:
    plan = drawn_building(outside=0.0)
    write_map(plan, tmp_path / "plan")
    terr = default_territory(plan)
    assert terr is not None
    counts = {}
    for name, extra in (("default", []), ("none", ["--territory", "none"])):
        out = tmp_path / name
        main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--duration", "8",
              "--robots", str(robots), "-o", str(out), *extra])  # fmt: skip
        rows = json.loads((out / "summary.json").read_text())["robots"]
        counts[name] = {row["regions"] for row in rows}
    assert counts["default"] == {_regions(mission_regions(plan, region=terr.region))}
    assert counts["none"] == {_regions(mission_regions(plan))}
    assert counts["default"] != counts["none"]


def test_a_mask_of_another_shape_is_refused() -> None:
    plan = drawn_building(outside=0.0)
    with pytest.raises(ValueError, match="territory mask"):
        mission_regions(plan, region=np.ones((3, 3), dtype=bool))


#: ``state_fingerprint`` of the test's inputs without a mask, and with the building's
#: cells as the mask, computed at 185bcdf (before the regions were cut inside the
#: territory) from a scratch ``git archive`` of that commit.
BASE_PRINT = "81b02f87d03e3c05da851cb7527a79e7653eb3ea2d2240ae251edfdd71681915"
BASE_PRINT_MASKED = "60ecafbb889cc5f11cc7ec533d2ffa73a9a6f526cd78c0995a8fb2a1a7939de5"


def test_a_node_states_fingerprint_changes_only_with_a_mask() -> None:
    """States saved without a mask resume as before; those saved with one before the
    regions were cut inside it are another mission's."""
    plan = drawn_building()
    route = np.array([[0.0, 2.0, 3.0, 0.0], [1.0, 2.5, 3.0, 0.0]])
    cfg = MissionConfig(duration=5.0, seed=1)
    args = (plan, cfg, 0, [0], ExchangeParams(), [route])
    assert state_fingerprint(*args) == BASE_PRINT
    masked = state_fingerprint(*args, region=building_cells(plan))
    assert masked not in (BASE_PRINT, BASE_PRINT_MASKED)


def _run_regions(plan_yaml: Path, out: Path, *extra: str) -> set[int]:
    main(["team", "run", "--map", str(plan_yaml), "--duration", "8", "-o", str(out), *extra])
    rows = json.loads((out / "summary.json").read_text())["robots"]
    return {row["regions"] for row in rows}


def test_a_prior_at_another_resolution_is_cut_inside_the_territory(tmp_path: Path) -> None:
    """``--prior``: the plan's footprint put on the prior's cells is where its regions
    are cut."""
    plan = drawn_building()
    write_map(plan, tmp_path / "plan")
    write_map(drawn_building(res=0.05), tmp_path / "prior")
    prior = read_map(tmp_path / "prior.yaml")
    terr = default_territory(plan)
    assert terr is not None
    inside = mission_regions(prior, region=mask_on(terr.region, plan.grid, prior.grid))
    prior_yaml = str(tmp_path / "prior.yaml")
    got = _run_regions(tmp_path / "plan.yaml", tmp_path / "out", "--prior", prior_yaml)
    assert got == {_regions(inside)}
    assert got != {_regions(mission_regions(prior))}


def test_team_run_on_a_slam_like_map_reports_the_whole_priors_regions(tmp_path: Path) -> None:
    plan = drawn_building(outside=0.5)
    write_map(plan, tmp_path / "plan")
    got = _run_regions(tmp_path / "plan.yaml", tmp_path / "out")
    assert got == {_regions(mission_regions(read_map(tmp_path / "plan.yaml")))}


@pytest.mark.parametrize("command", ["run", "node"])
def test_a_prior_with_no_free_cell_inside_the_territory_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """Its regions could not be cut inside the territory: ``team run`` and ``team node``
    print one line naming --prior, exit 2, write nothing."""
    plan = drawn_building()
    write_map(plan, tmp_path / "plan")
    # Free only outside the building: the prior does not match the plan.
    occ = np.where(building_cells(plan), 1.0, 0.0).astype(np.float32)
    write_map(OccupancyMap(plan.grid, occ), tmp_path / "prior")
    out = tmp_path / "out"
    argv = ["team", command, "--map", str(tmp_path / "plan.yaml"), "-o", str(out)]
    if command == "run":
        argv += ["--duration", "8"]
    else:
        argv += ["--id", "0", "--listen", "tcp://127.0.0.1:0", "--peers", "1=tcp://127.0.0.1:9"]
    with pytest.raises(SystemExit) as e:
        main([*argv, "--prior", str(tmp_path / "prior.yaml")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "--prior" in err, err
    assert "territory" in err, err
    assert len(err.splitlines()) == 1, err
    assert not out.exists()
