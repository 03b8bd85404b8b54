"""What ``team run`` does, done in a few calls of :mod:`sonarmap.team` (the command line is a
thin layer over them): the run's territory (:mod:`sonarmap.team.inputs`), its prior
(:func:`~sonarmap.team.prior.make_prior`), its world and routes, its outputs
(:func:`~sonarmap.team.outputs.write_run`), and the presets' rules."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conftest import drawn_building
from sonarmap.builtins import builtin_plan
from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.io.rosmap import FREE, read_map, write_map
from sonarmap.team.inputs import (
    check_world_territory,
    draw_world,
    mission_routes,
    run_territory,
)
from sonarmap.team.mission import MissionConfig, run_mission
from sonarmap.team.outputs import write_run
from sonarmap.team.presets import PRESETS, check_preset, default_mode
from sonarmap.team.prior import check_prior_inside, make_prior
from sonarmap.team.sensing import RobotSensing
from sonarmap.team.summary import naive_share_note
from sonarmap.team.territory import NO_TERRITORY, check_route_inside, territory_option
from sonarmap.team.world import make_world, patrol_route

#: Wall-clock figures of a robot's row, which differ from run to run.
TIMED = ("association_ms_median", "association_ms_p99", "global_map_batch_s", "wall_seconds")


def _untimed(summary: dict[str, Any]) -> dict[str, Any]:
    for row in summary["robots"]:
        for key in TIMED:
            assert key in row
            del row[key]
    return summary


def test_a_few_calls_write_what_team_run_writes(tmp_path: Path) -> None:
    plan = builtin_plan("office")
    chosen = run_territory(None, plan)
    prior, prior_record = make_prior(plan, error="scale=0.01", seed=0)
    config = MissionConfig(duration=20.0, seed=0)
    world, routes = draw_world(plan, 20.0, seed=0, robots=1, region=chosen.region)
    result = run_mission(
        plan, config, prior=prior, route=routes[0], world=world, territory=chosen.region
    )
    api = tmp_path / "api"
    written = write_run(
        api,
        plan,
        result,
        prior=prior,
        prior_record=prior_record,
        territory_record=chosen.record,
    )
    cli = tmp_path / "cli"
    args = ["team", "run", "--map", "office", "--duration", "20", "--prior-error", "scale=0.01"]
    main([*args, "-o", str(cli)])
    summary = _untimed(json.loads((api / "summary.json").read_text()))
    assert json.dumps(summary) == json.dumps(
        _untimed(json.loads((cli / "summary.json").read_text()))
    )
    assert summary.keys() == written.keys()
    assert summary["prior"] == written["prior"]
    assert sorted(p.name for p in api.iterdir()) == sorted(p.name for p in cli.iterdir())
    assert (api / "prior.yaml").is_file()
    assert (api / "memory.csv").read_text() == (cli / "memory.csv").read_text()


def test_run_territory_follows_team_runs_rule(tmp_path: Path) -> None:
    plan = drawn_building()
    default = run_territory(None, plan)
    assert default.how == "default"
    assert default.mask is not None
    assert default.record is not None
    assert default.record["default"] == "footprint"
    assert default.node_value() is None
    whole = run_territory(NO_TERRITORY, plan)
    assert (whole.mask, whole.record, whole.how) == (
        None,
        {"file": None, "default": "none"},
        "none",
    )
    assert whole.node_value() == Path(NO_TERRITORY)
    skipped = run_territory(None, plan, route_given=True)
    assert skipped.mask is None
    assert skipped.record is not None
    assert skipped.record["default"] == "skipped"
    assert skipped.record["footprint_would_leave_out_free_area_m2"] > 200


def test_a_mask_file_and_a_world_are_refused_together(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^--world carries its own landmarks"):
        check_world_territory(tmp_path / "mask.txt", tmp_path / "world")
    check_world_territory(NO_TERRITORY, tmp_path / "world")
    with pytest.raises(ConfigError, match=r"^--world carries its own landmarks"):
        run_territory(tmp_path / "mask.txt", drawn_building(), world=tmp_path / "world")


def test_a_bad_mask_file_names_the_option(tmp_path: Path) -> None:
    bad = tmp_path / "mask.txt"
    bad.write_text("1 2\nthree 4\n")
    with pytest.raises(ConfigError, match=rf"^--territory {bad}:2: "):
        territory_option(bad, drawn_building())


def test_a_route_off_the_territory_is_refused() -> None:
    plan = drawn_building()
    mask = territory_option(None, plan)
    assert mask is not None
    route = np.array([[0.0, 2.0, 3.0, 0.0], [0.5, -3.0, -3.0, 0.0]])
    with pytest.raises(ConfigError, match=r"^--route r.csv: pose 2 \(t = 0.5 s\) at \(-3, -3\) m"):
        check_route_inside(plan, mask, route, where="--route r.csv", inside="the mask")
    check_route_inside(plan, mask, route[:1], where="--route r.csv", inside="the mask")


def test_mission_routes_are_the_missions_own_and_keep_the_given_ones() -> None:
    plan = builtin_plan("office")
    mine = patrol_route(plan, 30.0, seed=5)
    routes = mission_routes(plan, 30.0, seed=2, robots=3, given={0: mine, 1: None})
    assert sorted(routes) == [0, 1, 2]
    assert routes[0] is mine
    world = make_world(plan, seed=2, duration=30.0)
    for i in (1, 2):
        # The route robot i's mission draws by itself when given none.
        own = RobotSensing(plan, MissionConfig(duration=30.0, seed=2), world, i).route
        drawn = routes[i][routes[i][:, 0] <= routes[i][0, 0] + 30.0]
        np.testing.assert_array_equal(drawn, own)
        # The rule written out: robot i's seed is the mission's + 7919 i.
        np.testing.assert_array_equal(routes[i], patrol_route(plan, 30.0, seed=2 + 7919 * i))
    assert not np.array_equal(routes[1], routes[2])


def test_draw_world_keeps_every_route_inside_the_territory() -> None:
    plan = drawn_building()
    chosen = run_territory(None, plan)
    region = chosen.region
    assert chosen.how == "default"
    assert region is not None

    def outside(route: np.ndarray) -> int:
        r, c = plan.grid.world_to_cell(route[:, 1], route[:, 2])
        return int((~region[r, c]).sum())

    _, routes = draw_world(plan, 120.0, seed=1, robots=2, region=region)
    assert sorted(routes) == [0, 1]
    for route in routes.values():
        assert outside(route) == 0
    # The mask matters here: on the whole plan the same routes leave the building.
    _, free = draw_world(plan, 120.0, seed=1, robots=2, region=None)
    assert sum(outside(r) for r in free.values()) > 0


def test_draw_world_and_mission_routes_check_the_team_size() -> None:
    plan = builtin_plan("office")
    with pytest.raises(ConfigError, match=r"^robots 65: at most 64 robots in a team$"):
        draw_world(plan, 20.0, seed=0, robots=65)
    with pytest.raises(ConfigError, match=r"^robots 0: expected an int >= 1$"):
        mission_routes(plan, 20.0, seed=0, robots=0)


def test_make_prior(tmp_path: Path) -> None:
    plan = builtin_plan("office")
    assert make_prior(plan) == (None, None)
    with pytest.raises(ConfigError, match=r"^--prior .*nowhere.yaml: no such file$"):
        make_prior(plan, tmp_path / "nowhere.yaml")
    write_map(plan, tmp_path / "prior")
    prior, record = make_prior(plan, tmp_path / "prior.yaml")
    assert prior is not None
    assert record == {"source": str(tmp_path / "prior.yaml")}
    with pytest.raises(ConfigError, match=r"^--prior-error: expected KEY=VALUE"):
        make_prior(plan, error="doors=1")
    # A caller's own names for the two inputs, in the same messages.
    with pytest.raises(ConfigError, match=r"^path .*nowhere.yaml: no such file$"):
        make_prior(plan, tmp_path / "nowhere.yaml", option="path")
    with pytest.raises(ConfigError, match=r"^error: expected KEY=VALUE"):
        make_prior(plan, error="doors=1", error_option="error")


def test_a_prior_with_no_free_cell_inside_the_territory_is_refused() -> None:
    plan = drawn_building()
    inside = np.zeros(plan.grid.shape, dtype=bool)
    inside[:3, :3] = True
    walls = plan.classes() != FREE
    check_prior_inside(plan, plan, inside, "--prior p.yaml")
    check_prior_inside(plan, None, inside, "--prior p.yaml")
    with pytest.raises(ConfigError, match=r"^--prior p.yaml: no free cell of the prior"):
        check_prior_inside(plan, plan, inside & walls, "--prior p.yaml")


def test_the_presets_rules() -> None:
    check_preset(None)
    check_preset("lean")
    with pytest.raises(ConfigError, match=r"^--preset must be one of classic, lean, got 'x'$"):
        check_preset("x")
    assert default_mode(None, "full") == "good"
    assert default_mode(None, "limited") == "limited"
    assert default_mode("naive", "full") == "naive"
    lean = PRESETS["lean"]
    values = lean.values(["hold", "fold"])
    assert "hold" not in values["exchange"]
    assert "fold" not in values["store"]
    assert values["store"]["merge_on_closure"] == lean.store["merge_on_closure"]
    assert set(values["exchange"]) | {"hold"} == set(lean.sets()) - set(lean.store)


def test_the_naive_share_note() -> None:
    s = {"share_of_naive": 0.1234, "exchange": {"mode": "good"}}
    assert naive_share_note(s) == " (12.3 % of the naive baseline's, quiet phase included)"
    assert naive_share_note({**s, "exchange": {"mode": "naive"}}) == ""
    assert naive_share_note({"exchange": {"mode": "good"}}) == ""


@pytest.mark.slow  # two node processes, each importing and compiling: about 50 s wall at load 4
def test_run_zmq_team_into_writes_the_prior_and_the_records(tmp_path: Path) -> None:
    from sonarmap.team.launcher import run_zmq_team_into

    plan = builtin_plan("office")
    chosen = run_territory(NO_TERRITORY, plan)
    prior, prior_record = make_prior(plan, error="scale=0.01", seed=0)
    assert prior is not None
    assert prior_record is not None
    out = tmp_path / "zmq"
    summary = run_zmq_team_into(
        str(out),
        plan,
        MissionConfig(duration=8.0, seed=0),
        2,
        preset=None,
        prior=prior,
        prior_record=prior_record,
        territory=chosen.node_value(),
        territory_record=chosen.record,
        timeout=300.0,
    )
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert summary["prior"] == prior_record
    assert summary["territory"] == {"file": None, "default": "none"}
    assert summary["preset"] is None
    assert (out / "prior.yaml").is_file()
    assert (out / "nodes").is_dir()
    written = read_map(out / "prior.yaml")
    np.testing.assert_array_equal(written.classes(), prior.classes())
