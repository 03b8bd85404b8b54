"""A prior map that is not the truth (:mod:`sonarmap.team.prior`): doorways found, closed
and opened, furniture found and left out, the scale error, prior files matched to the
truth, and ``team run --prior / --prior-error`` with the map's bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from conftest import SHARED_DATA
from sonarmap.cli import main
from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import FREE, OCCUPIED, OccupancyMap, write_map
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.prior import (
    PriorError,
    check_prior,
    degrade_plan,
    find_doors,
    find_furniture,
    find_walls_to_open,
    parse_prior_error,
    scale_plan,
)
from sonarmap.team.regions import mission_regions
from sonarmap.team.world import builtin_plan

H = 0.1  # metres a cell


def _map(occ: np.ndarray, origin: tuple[float, float] = (0.0, 0.0), res: float = H) -> OccupancyMap:
    return OccupancyMap(Grid(res, origin, occ.shape), occ.astype(np.float32))


def _two_rooms(door: bool = True, wall: int = 1) -> OccupancyMap:
    """Two 4 x 4 m rooms side by side (8 x 4 m), a wall ``wall`` cells thick between
    them with a 0.9 m doorway in its middle (``door``)."""
    occ = np.zeros((42, 82))
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    occ[:, 41 : 41 + wall] = 1.0
    if door:
        occ[17:26, 41 : 41 + wall] = 0.0
    return _map(occ)


def _components(m: OccupancyMap) -> int:
    return int(ndimage.label(m.classes() == FREE)[1])


def test_the_doorway_between_two_rooms_is_found_and_closing_it_cuts_them_apart() -> None:
    plan = _two_rooms(wall=2)
    doors = find_doors(plan)
    assert len(doors) == 1
    d = doors[0]
    assert d.rows == (17, 26)
    assert d.cols == (41, 43)
    assert d.width(H) == pytest.approx(0.9)
    prior, report = degrade_plan(plan, PriorError(close_doors=1))
    assert (_components(plan), _components(prior)) == (1, 2)
    assert report.doors_found == 1
    assert len(report.doors_closed) == 1
    x, y = report.doors_closed[0]
    assert x == pytest.approx(4.2, abs=0.1)
    assert y == pytest.approx(2.1, abs=0.1)
    assert report.cells_changed == 9 * 2


def test_a_narrow_corridor_and_a_gap_between_pillars_are_no_doorways() -> None:
    occ = np.zeros((60, 60))
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    # A corridor 0.8 m wide and 3 m long, as narrow at both ends as in the middle.
    occ[5:35, 10] = occ[5:35, 19] = 1.0
    # Two pillars 0.2 m across, 0.8 m apart in open space.
    occ[45:47, 30:32] = occ[45:47, 40:42] = 1.0
    assert find_doors(_map(occ)) == []


def test_a_doorway_is_opened_through_a_thin_wall_and_joins_the_rooms() -> None:
    plan = _two_rooms(door=False)
    walls = find_walls_to_open(plan)
    assert walls  # the middle wall, and the outer walls have no free side outside
    assert all(w.cols == (41, 42) for w in walls)
    prior, report = degrade_plan(plan, PriorError(open_doors=1, seed=3))
    assert (_components(plan), _components(prior)) == (2, 1)
    assert len(report.doors_opened) == 1
    # The cut keeps a jamb of wall on each side.
    assert report.cells_changed == 9
    assert find_doors(prior)  # and it is a doorway by the same rules


def test_furniture_alone_or_against_a_wall_is_found_but_not_specks_or_walls() -> None:
    occ = np.zeros((60, 80))
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    occ[20:30, 20:30] = 1.0  # a 1 m table in the room
    occ[40:46, 1:16] = 1.0  # a 1.5 x 0.6 m cupboard against the left wall
    occ[10, 60] = 1.0  # a speck
    occ[20:50, 70] = 1.0  # a partition wall 3 m long
    plan = _map(occ)
    blobs = find_furniture(plan)
    assert len(blobs) == 2
    assert blobs[0][20:30, 20:30].all()
    assert blobs[0].sum() == 100
    assert blobs[1][40:46, 1:16].all()
    assert not blobs[1][:, 0].any()
    prior, report = degrade_plan(plan, PriorError(drop_furniture=5, seed=1))
    assert report.furniture_found == 2
    assert len(report.furniture_dropped) == 2
    assert (prior.classes()[20:30, 20:30] == FREE).all()
    assert prior.classes()[10, 60] == OCCUPIED
    assert (prior.classes()[20:50, 70] == OCCUPIED).all()


def test_a_pillar_with_an_unknown_inside_counts_as_one_piece_of_furniture() -> None:
    occ = np.zeros((40, 40))
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    occ[15:21, 15:21] = 1.0
    occ[16:20, 16:20] = np.nan
    blobs = find_furniture(_map(occ))
    assert len(blobs) == 1
    assert blobs[0].sum() == 36


def test_the_scale_error_moves_a_wall_in_proportion_and_keeps_thin_walls() -> None:
    occ = np.zeros((50, 100))
    occ[:, 50] = 1.0  # a wall at x = 5.0..5.1 m
    big = scale_plan(_map(occ), 0.1)
    assert big.grid.shape == (55, 110)
    cols = np.flatnonzero((big.classes() == OCCUPIED).all(axis=0))
    x = big.grid.cell_centres(np.zeros_like(cols), cols)[0]
    assert x.min() == pytest.approx(5.5, abs=H)
    assert x.max() == pytest.approx(5.6, abs=H)
    small = scale_plan(_map(occ), -0.3)
    assert small.grid.shape == (35, 70)
    assert (small.classes() == OCCUPIED).all(axis=0).sum() == 1  # a one-cell wall survives
    _, report = degrade_plan(_map(occ), PriorError(scale=0.03))
    assert report.scale_shift_max_m == pytest.approx(0.03 * np.hypot(10.0, 5.0), abs=1e-3)


def test_the_same_seed_draws_the_same_prior_and_another_seed_another() -> None:
    plan = builtin_plan("building:0")
    err = PriorError(close_doors=3, open_doors=2, drop_furniture=2, scale=0.02, seed=5)
    a, ra = degrade_plan(plan, err)
    b, rb = degrade_plan(plan, err)
    np.testing.assert_array_equal(a.classes(), b.classes())
    assert ra.to_dict() == rb.to_dict()
    _, rc = degrade_plan(plan, PriorError(close_doors=3, open_doors=2, seed=6))
    assert (rc.doors_closed, rc.doors_opened) != (ra.doors_closed, ra.doors_opened)
    same, report = degrade_plan(plan, PriorError())
    np.testing.assert_array_equal(same.classes(), plan.classes())
    assert report.cells_changed == 0


def test_prior_error_specs_parse_and_bad_ones_name_the_option() -> None:
    err = parse_prior_error("close-doors=2, furniture=1,scale=-0.04", seed=9)
    assert (err.close_doors, err.open_doors, err.drop_furniture, err.scale, err.seed) == (
        2,
        0,
        1,
        -0.04,
        9,
    )
    assert parse_prior_error("furniture=1,seed=4", seed=9).seed == 4
    for spec, words in [
        ("doors=2", "KEY one of close-doors"),
        ("close-doors=two", "close-doors: an integer expected"),
        ("scale=x", "scale: a number expected"),
        ("furniture=-1", "drop_furniture"),
        ("scale=0.6", "(-0.5, 0.5)"),
        ("scale", "KEY=VALUE"),
        ("seed=-2", "'seed'"),
    ]:
        with pytest.raises(ConfigError, match=r"^--prior-error") as e:
            parse_prior_error(spec)
        assert words in str(e.value)


def test_a_prior_that_cannot_be_matched_to_the_truth_is_refused() -> None:
    truth = _two_rooms()
    check_prior(truth, truth, "p.yaml")  # the truth itself matches
    check_prior(truth, scale_plan(truth, 0.1), "p.yaml")  # so does a plan 10 % too large
    cases = [
        (_map(truth.occupancy, origin=(6.0, 0.0)), "field 'origin'"),  # 8 m map moved 6 m
        (_map(truth.occupancy, res=0.5), "field 'resolution'"),  # 5x the resolution
        (_map(truth.occupancy[:10, :10]), "field 'origin'"),  # a corner of the plan
        (_map(np.ones(truth.grid.shape)), "no free cell"),
    ]
    for prior, words in cases:
        with pytest.raises(InputError, match=r"^p\.yaml") as e:
            check_prior(truth, prior, "p.yaml")
        assert words in str(e.value)


def test_the_robot_cuts_its_regions_from_the_prior_and_is_scored_on_the_truth() -> None:
    plan = builtin_plan("building:0")
    prior, _ = degrade_plan(plan, PriorError(close_doors=4, open_doors=3, seed=2))
    cfg = MissionConfig(duration=20.0, seed=0)
    truthful, given = RobotAgent(plan, cfg), RobotAgent(plan, cfg, prior=prior)
    np.testing.assert_array_equal(given.labels, mission_regions(prior))
    assert not np.array_equal(given.labels, truthful.labels)
    # The simulator drives and senses the truth either way.
    np.testing.assert_array_equal(given.route, truthful.route)
    assert len(given.sensing.readings) == len(truthful.sensing.readings)


def _plan_file(folder: Path, occ: np.ndarray, name: str = "plan", res: float = H) -> Path:
    write_map(_map(occ, res=res), folder / name)
    return folder / f"{name}.yaml"


def _cli_fails(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str]) -> str:
    with pytest.raises(SystemExit) as e:
        main(["team", "run", "--duration", "30", *args, "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()
    return err


def test_a_map_with_no_wall_for_a_landmark_is_one_line_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _plan_file(tmp_path, np.zeros((50, 50)))
    err = _cli_fails(tmp_path, capsys, ["--map", str(path)])
    assert f"--map {path}: the plan has no obstacle facing free space" in err


@pytest.mark.parametrize("side", [4, 7])
def test_a_territory_too_small_for_a_route_is_one_line_naming_the_map(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], side: int
) -> None:
    # A closet 0.4 m (no room for the robot) or 0.7 m across (room to stand, not to go).
    occ = np.ones((40, 40))
    occ[10 : 10 + side, 10 : 10 + side] = 0.0
    path = _plan_file(tmp_path, occ)
    err = _cli_fails(tmp_path, capsys, ["--map", str(path)])
    assert f"--map {path}: " in err
    assert "robot of radius 0.3 m" in err


@pytest.mark.parametrize(
    ("prior", "words"),
    [
        ("moved", "field 'origin'"),
        ("coarse", "field 'resolution'"),
        ("missing", "no such file"),
    ],
)
def test_a_prior_file_that_does_not_match_the_map_is_one_line_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], prior: str, words: str
) -> None:
    occ = _two_rooms().occupancy
    plan = _plan_file(tmp_path, occ)
    if prior == "moved":
        write_map(_map(occ, origin=(20.0, 0.0)), tmp_path / "prior")
    elif prior == "coarse":
        write_map(_map(occ, res=1.0), tmp_path / "prior")
    path = tmp_path / "prior.yaml"
    err = _cli_fails(tmp_path, capsys, ["--map", str(plan), "--prior", str(path)])
    assert err.startswith(f"sonarmap: error: --prior {path}")
    assert words in err


@pytest.mark.parametrize(
    "args",
    [
        ["--prior-error", "doors=1"],
        ["--prior-error", "scale=2"],
        ["--prior-error", "doors=1", "--transport", "zmq", "--robots", "2"],
        # Shrunk to 0.6 of the map, it overlaps it on 36 %: refused under either transport.
        ["--prior-error", "scale=-0.4"],
    ],
)
def test_bad_prior_options_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    err = _cli_fails(tmp_path, capsys, ["--map", "building:0", *args])
    assert "--prior" in err


def test_a_run_with_a_prior_error_records_it_and_scores_against_the_truth(
    tmp_path: Path,
) -> None:
    base = ["team", "run", "--map", "building:0", "--duration", "60"]
    main([*base, "-o", str(tmp_path / "truth")])
    main([*base, "--prior-error", "close-doors=3,scale=0.05", "-o", str(tmp_path / "prior")])
    t = json.loads((tmp_path / "truth" / "summary.json").read_text())
    p = json.loads((tmp_path / "prior" / "summary.json").read_text())
    assert "prior" not in t
    assert not (tmp_path / "truth" / "prior.yaml").exists()
    rec = p["prior"]
    assert rec["source"] == "the map"
    assert rec["error"]["close_doors"] == 3
    assert len(rec["doors_closed"]) == 3
    assert rec["scale_shift_max_m"] == pytest.approx(0.05 * np.hypot(20.0, 16.0), abs=1e-3)
    written = (tmp_path / "prior" / "prior.yaml").read_text()
    assert "resolution: 0.1" in written
    # Same truth, same readings: the bounds of the map do not move with the prior.
    for key in ("map_f1_true_poses", "ate_odometry_m", "poses_made"):
        assert p["robots"][0][key] == t["robots"][0][key]


@pytest.mark.skipif(not (SHARED_DATA / "maps").is_dir(), reason="needs /work/shared/data")
def test_the_shared_depot_offers_doorways_walls_and_furniture() -> None:
    from sonarmap.io.rosmap import read_map

    plan = read_map(SHARED_DATA / "maps" / "depot.yaml")
    err = PriorError()
    assert len(find_doors(plan, err)) >= 2
    assert len(find_walls_to_open(plan, err)) >= 2
    assert len(find_furniture(plan, err)) >= 3


def test_a_users_prior_file_is_what_a_team_cuts_its_regions_from(tmp_path: Path) -> None:
    plan = builtin_plan("building:0")
    # Without its furniture the building cuts into 15 regions, not 17.
    prior, _ = degrade_plan(plan, PriorError(drop_furniture=8))
    write_map(prior, tmp_path / "drawing")
    path = tmp_path / "drawing.yaml"
    out = tmp_path / "team"
    main(["team", "run", "--map", "building:0", "--robots", "2", "--duration", "30",
          "--prior", str(path), "-o", str(out)])  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    assert s["prior"]["source"] == str(path)
    assert "error" not in s["prior"]  # the file as given, nothing drawn on it
    regions = int(mission_regions(prior).max()) + 1
    assert regions != int(mission_regions(plan).max()) + 1
    assert [r["regions"] for r in s["robots"]] == [regions, regions]
    assert (out / "prior.yaml").exists()
