"""The default territory of a team mission: on a drawn plan whose outside is free, the
building's footprint leaves the outside out even through an open entrance; a SLAM-like
map (its outside unknown), a map whose walls reach the image's edge and a drawing with
its walls in pieces are left whole."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from conftest import building_cells, drawn_building
from sonarmap.cli import main
from sonarmap.io.rosmap import FREE, OccupancyMap, write_map
from sonarmap.team.launcher import node_territory
from sonarmap.team.territory import default_territory, footprint, read_territory, territory_of
from sonarmap.team.world import make_world, patrol_route, world_territory


def test_the_entrance_joins_inside_and_outside() -> None:
    """Why a flood fill from the border is not enough: every free cell reaches it."""
    free = drawn_building().classes() == FREE
    _, n = ndimage.label(free, structure=np.ones((3, 3), dtype=bool))
    assert n == 1


def test_the_footprint_leaves_out_a_drawn_outside_through_an_open_entrance() -> None:
    plan = drawn_building()
    fp = footprint(plan)
    assert fp.drawn, fp.why
    free, inside = plan.classes() == FREE, building_cells(plan)
    left = free & ~fp.region
    assert (left & ~inside).sum() / (free & ~inside).sum() > 0.99
    # At most the notch at the entrance: under 1 % of the inside's free area.
    assert (left & inside).sum() / (free & inside).sum() < 0.01
    mask = default_territory(plan)
    assert mask is not None
    assert mask.record["default"] == "footprint"
    assert mask.record["left_out_free_area_m2"] > 200
    # The robot's route and the world's landmarks are inside, both rooms reached.
    route = patrol_route(plan, 120.0, seed=3, region=mask.region)
    x, y = route[:, 1], route[:, 2]
    assert ((x > 0.3) & (x < 7.7) & (y > 0.3) & (y < 5.7)).all()
    assert (x < 4.0).any()
    assert (x > 4.1).any()
    world = make_world(plan, seed=0, duration=60.0, region=mask.region)
    lx, ly = world.points[:, 0], world.points[:, 1]
    # Inner faces only, but for the entrance's jambs and its outer face beside it.
    near = (np.abs(ly) < 0.9) & (lx > 4.5) & (lx < 7.5)
    assert ((lx > 0.05) & (lx < 7.95) & (ly > 0.05) & (ly < 5.95) | near).all()


def _walled_border() -> OccupancyMap:
    """The plan with walls on the image's edge: no free margin all round."""
    occ = np.asarray(drawn_building().occupancy).copy()
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    return OccupancyMap(drawn_building().grid, occ)


@pytest.mark.parametrize(
    ("plan", "why"), [(drawn_building(outside=0.5), "unknown cells"), (_walled_border(), "border")]
)
def test_maps_that_are_not_drawn_plans_are_left_whole(plan: OccupancyMap, why: str) -> None:
    fp = footprint(plan)
    assert not fp.drawn
    assert why in fp.why
    assert default_territory(plan) is None


def test_a_drawing_with_its_walls_in_pieces_is_left_whole() -> None:
    plan = drawn_building()
    occ = np.asarray(plan.occupancy).copy()
    # 0.3 m posts over the outside north of the building, 2 m apart (farther than a
    # door): not one building.
    for r in range(5, 45, 20):
        for c in range(5, 175, 20):
            occ[r : r + 3, c : c + 3] = 1.0
    fp = footprint(OccupancyMap(plan.grid, occ))
    assert not fp.drawn
    assert "pieces" in fp.why


def test_team_run_takes_the_footprint_by_default_and_none_turns_it_off(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_map(drawn_building(), tmp_path / "plan")
    out = tmp_path / "run"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--duration", "8",
          "-o", str(out)])  # fmt: skip
    said = capsys.readouterr().out
    assert "territory: a drawn plan" in said
    assert "--territory none" in said
    t = json.loads((out / "summary.json").read_text())["territory"]
    assert t["default"] == "footprint"
    assert t["file"] is None
    assert 40 < t["free_area_inside_m2"] < 47
    assert t["left_out_free_area_m2"] > 200
    assert t["plan_unknown_share"] == 0.0
    assert t["margin_share"] == 1.0
    off = tmp_path / "off"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--duration", "8",
          "--territory", "none", "-o", str(off)])  # fmt: skip
    assert "territory: a drawn plan" not in capsys.readouterr().out
    t = json.loads((off / "summary.json").read_text())["territory"]
    assert t == {"file": None, "default": "none"}


def test_a_users_route_skips_the_default_and_says_so(tmp_path: Path) -> None:
    plan = drawn_building()
    write_map(plan, tmp_path / "plan")
    route = patrol_route(plan, 8.0, seed=0)
    path = tmp_path / "route.csv"
    lines = ["t,x,y,theta", *(",".join(f"{v:.6f}" for v in row) for row in route)]
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "run"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--duration", "8",
          "--route", str(path), "-o", str(out)])  # fmt: skip
    t = json.loads((out / "summary.json").read_text())["territory"]
    assert t["default"] == "skipped"
    assert "--route" in t["why"]
    assert t["footprint_would_leave_out_free_area_m2"] > 200


def test_a_world_made_inside_the_footprint_keeps_it_in_team_run(tmp_path: Path) -> None:
    """'team world' applies the default; 'team run --world' reuses the mask it wrote."""
    plan = drawn_building()
    write_map(plan, tmp_path / "plan")
    world = tmp_path / "world"
    main(["team", "world", "--map", str(tmp_path / "plan.yaml"), "--duration", "8",
          "-o", str(world)])  # fmt: skip
    saved = world_territory(world)
    assert saved is not None
    mask, source = saved
    assert source == "footprint"
    default = default_territory(plan)
    assert default is not None
    assert np.array_equal(read_territory(mask, plan), default.region)
    out = tmp_path / "run"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--duration", "8",
          "--world", str(world), "-o", str(out)])  # fmt: skip
    t = json.loads((out / "summary.json").read_text())["territory"]
    assert t["default"] == "world"
    assert t["world_territory_from"] == "footprint"
    assert t["free_area_inside_m2"] == default.record["free_area_inside_m2"]


def test_the_launchers_node_arguments_give_the_nodes_its_mask(tmp_path: Path) -> None:
    """The mask the launcher draws routes in is the one its nodes' --territory (as
    'team node' reads it) gives, for no option, 'none' and a file."""
    plan = drawn_building()
    outline = tmp_path / "inside.txt"
    outline.write_text("0 0\n8 0\n8 6\n0 6\n")
    for value in (None, "none", outline):
        region, args = node_territory(value, plan)
        given = args[args.index("--territory") + 1] if "--territory" in args else None
        node = territory_of(given, plan)
        assert (region is None) == (node is None), value
        if region is not None and node is not None:
            assert np.array_equal(region, node.region), value
    assert node_territory(None, plan)[0] is not None
    assert node_territory("none", plan) == (None, ["--territory", "none"])


@pytest.mark.parametrize("width", [2.0, 3.0])
def test_an_entrance_wider_than_a_door_leaves_the_plan_whole(width: float) -> None:
    """The door-wide disc does not bridge it, so its footprint would leave the rooms
    behind out with the outside; the 4 m disc's footprint keeps them, and the two
    disagree."""
    plan = drawn_building(width=width)
    fp = footprint(plan)
    free, inside = plan.classes() == FREE, building_cells(plan)
    # What the footprint alone would cut: over a third of the inside's free area.
    assert (free & inside & ~fp.region).sum() / (free & inside).sum() > 0.3
    assert not fp.drawn
    assert "4 m disc" in fp.why
    assert default_territory(plan) is None


def test_a_door_wide_entrance_is_still_cut() -> None:
    fp = footprint(drawn_building(width=1.2))
    assert fp.drawn, fp.why
    assert fp.disagreement < 0.01
    assert fp.reach is not None
