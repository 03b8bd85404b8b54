"""``--territory`` for team missions: a drawn plan whose outside is free, mapped only
inside the building the user outlines (routes, tours, patrol starts and landmarks), and
the patrol's one-line errors for bad masks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sonarmap.cli import main
from sonarmap.errors import InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.team.launcher import run_zmq_team
from sonarmap.team.mission import MissionConfig
from sonarmap.team.node import load_routes, run_node
from sonarmap.team.patrolling import patrol_routes
from sonarmap.team.regions import mission_regions
from sonarmap.team.territory import mask_on, read_territory
from sonarmap.team.world import make_world, patrol_route

#: The building: 8 x 6 m, one-cell walls, no entrance, drawn at 0.1 m with 5 m of free
#: "outside" all round (24 m^2 of inside against about 260 m^2 of outside).
BUILDING = (0.0, 0.0, 8.0, 6.0)


def _drawn_plan() -> OccupancyMap:
    grid = Grid.from_bounds(-5.0, -5.0, 13.0, 11.0, 0.1)
    occ = np.zeros(grid.shape, dtype=np.float32)
    x, y = grid.all_centres()
    x0, y0, x1, y1 = BUILDING
    ring = (x > x0) & (x < x1) & (y > y0) & (y < y1)
    inner = (x > x0 + 0.1) & (x < x1 - 0.1) & (y > y0 + 0.1) & (y < y1 - 0.1)
    occ[ring & ~inner] = 1.0
    # A wall across the middle with a 1.2 m door, so the inside is two rooms.
    occ[ring & (np.abs(x - 4.05) < 0.05) & ~((y > 2.4) & (y < 3.6))] = 1.0
    return OccupancyMap(grid, occ)


def _inside(xy: np.ndarray, pad: float = 0.0) -> np.ndarray:
    x0, y0, x1, y1 = BUILDING
    x, y = xy[:, 0], xy[:, 1]
    return np.asarray((x >= x0 + pad) & (x <= x1 - pad) & (y >= y0 + pad) & (y <= y1 - pad))


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("drawn")
    write_map(_drawn_plan(), d / "plan")
    x0, y0, x1, y1 = BUILDING
    (d / "inside.txt").write_text(
        f"# the building's outline\n{x0} {y0}\n{x1} {y0}\n{x1} {y1}\n{x0} {y1}\n"
    )
    return d


def test_without_a_mask_the_mission_goes_round_the_outside() -> None:
    """The reason for the option: the largest area a robot fits in is the outside."""
    plan = _drawn_plan()
    route = patrol_route(plan, 60.0, seed=0)
    assert not _inside(route[:, 1:3]).any()


def test_routes_tours_and_landmarks_stay_inside_the_mask(files: Path) -> None:
    plan = _drawn_plan()
    region = read_territory(files / "inside.txt", plan)
    for style in ("waypoints", "tour"):
        route = patrol_route(plan, 120.0, seed=3, style=style, region=region)
        # Inside the walls: the robot's centre keeps its radius from them.
        assert _inside(route[:, 1:3], pad=0.3).all(), style
        # Both rooms: the door joins them into one piece.
        assert (route[:, 1] < 4.0).any(), style
        assert (route[:, 1] > 4.1).any(), style
    world = make_world(plan, seed=0, duration=60.0, region=region)
    xy = world.points[:, :2]
    # On the inner faces of the outer walls (0.1 m in) or on the middle wall: none on
    # the outer faces, which only the outside sees.
    assert _inside(xy, pad=0.05).all()
    assert world.params["territory_cells"] == int(region.sum())
    unmasked = make_world(plan, seed=0, duration=60.0)
    assert not _inside(unmasked.points[:, :2], pad=0.05).any()


@pytest.mark.slow  # the patroller's first call compiles it: about 25 s at load 4
def test_a_patrolling_team_starts_and_patrols_inside_the_mask(files: Path) -> None:
    plan = _drawn_plan()
    region = read_territory(files / "inside.txt", plan)
    routes, _ = patrol_routes(plan, 2, 20.0, seed=1, region=region)
    for r in routes:
        assert _inside(r[:, 1:3], pad=0.2).all()
    free, _ = patrol_routes(plan, 2, 20.0, seed=1)
    assert not any(_inside(r[:, 1:3]).any() for r in free)


def test_a_mask_moves_onto_a_coarser_grid_of_the_same_frame() -> None:
    fine = Grid.from_bounds(0.0, 0.0, 4.0, 2.0, 0.1)
    x, _ = fine.all_centres()
    region = x < 1.0
    coarse = Grid.from_bounds(0.0, 0.0, 4.0, 2.0, 0.5)
    on = mask_on(region, fine, coarse)
    assert on.shape == coarse.shape
    assert on[:, :2].all()
    assert not on[:, 2:].any()
    assert mask_on(region, fine, fine) is region


def test_team_run_records_the_territory_and_team_world_draws_inside_it(files: Path) -> None:
    mask = files / "inside.txt"
    out = files / "run"
    main(["team", "run", "--map", str(files / "plan.yaml"), "--duration", "20",
          "--territory", str(mask), "-o", str(out)])  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    t = s["territory"]
    assert t["file"] == str(mask)
    # The inside's free area (two rooms of about 3.9 x 5.8 m), not the outside's.
    assert 40 < t["free_area_inside_m2"] < 47
    assert 0 < t["reached_area_m2"] <= t["free_area_inside_m2"]
    assert t["outside_region_share"] > 0.8
    world = files / "world"
    main(["team", "world", "--map", str(files / "plan.yaml"), "--duration", "30",
          "--territory", str(mask), "-o", str(world)])  # fmt: skip
    route = np.loadtxt(world / "route.csv", delimiter=",", skiprows=1)
    assert _inside(route[:, 1:3], pad=0.3).all()
    landmarks = np.loadtxt(world / "landmarks.csv", delimiter=",", skiprows=1, usecols=(1, 2))
    assert _inside(landmarks, pad=0.05).all()


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("letters.txt", "0 0\n8 0\nx y\n", "bad.txt:3: expected 'x y'"),
        ("two.txt", "0 0\n8 0\n", "a polygon needs at least 3 vertices"),
        ("away.txt", "50 50\n60 50\n60 60\n", "covers no cell of the map"),
        ("wall.txt", "0 0\n8 0\n8 0.3\n0 0.3\n", "--territory"),
        ("missing", "", "territory file"),
    ],
)
def test_bad_territory_files_are_one_line_and_exit_2(
    files: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    name: str,
    text: str,
    message: str,
) -> None:
    path = tmp_path / "bad.txt"
    if name != "missing":
        path.write_text(text)
    out = tmp_path / "out"
    for cmd in (
        ["team", "run", "--map", str(files / "plan.yaml"), "--duration", "20"],
        ["team", "run", "--map", str(files / "plan.yaml"), "--robots", "2", "--patrol",
         "--duration", "20"],
        ["team", "node", "--map", str(files / "plan.yaml"), "--id", "0",
         "--listen", "tcp://127.0.0.1:1", "--peers", "tcp://127.0.0.1:2"],
    ):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main([*cmd, "--territory", str(path), "-o", str(out)])
        err = capsys.readouterr().err.strip()
        assert e.value.code == 2, cmd
        assert message in err, (cmd, err)
        assert len(err.splitlines()) == 1, err
        assert not out.exists()


def test_a_route_off_the_masks_reach_is_refused_in_one_line(
    files: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A user's --route round the outside with the building's outline: refused before
    any work, naming both options, nothing written."""
    plan = _drawn_plan()
    outside = patrol_route(plan, 20.0, seed=0)
    assert not _inside(outside[:, 1:3]).any()
    path = tmp_path / "route.csv"
    lines = ["t,x,y,theta", *(",".join(f"{v:.6f}" for v in row) for row in outside)]
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as e:
        main(["team", "run", "--map", str(files / "plan.yaml"), "--duration", "20",
              "--route", str(path), "--territory", str(files / "inside.txt"),
              "-o", str(out)])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2
    for part in ("--route", "--territory", "pose 1 "):
        assert part in err, err
    assert len(err.splitlines()) == 1, err
    assert not out.exists()


def test_a_node_state_belongs_to_its_territory_mask(files: Path, tmp_path: Path) -> None:
    """A one-robot team's node saved with the outline resumes with the same mask and is
    refused with another one or none (its landmarks were drawn inside the mask)."""
    plan = _drawn_plan()
    mask = read_territory(files / "inside.txt", plan)
    left = mask & (plan.grid.all_centres()[0] < 4.0)
    cfg = MissionConfig(duration=5.0, seed=1)
    route = patrol_route(plan, cfg.duration, seed=cfg.seed, region=left)
    state = tmp_path / "state"

    def node(region: np.ndarray | None) -> dict[str, object]:
        return run_node(plan, cfg, 0, "tcp://127.0.0.1:0", {}, out=tmp_path / "out",
                        state_dir=state, routes=[route], region=region,
                        insecure=True)  # fmt: skip

    first = node(mask)
    # The node cuts the prior's regions inside its mask, as the simulated team does.
    row = first["row"]
    assert isinstance(row, dict)
    assert row["regions"] == int(mission_regions(plan, region=mask).max()) + 1
    assert row["regions"] < int(mission_regions(plan).max()) + 1
    for other in (left, None):
        with pytest.raises(InputError, match="territory mask"):
            node(other)
    again = node(mask)
    assert again["local_digest"] == first["local_digest"]
    assert again["held"] == first["held"]


def test_a_saved_world_and_a_mask_are_refused_together(
    files: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as e:
        main(["team", "run", "--map", str(files / "plan.yaml"), "--world", str(tmp_path),
              "--territory", str(files / "inside.txt"), "-o", str(tmp_path / "out")])  # fmt: skip
    assert e.value.code == 2
    assert "--territory" in capsys.readouterr().err


@pytest.mark.slow  # two node processes, each importing and compiling: about 24 s at load 4
def test_the_launcher_hands_every_node_the_mask(files: Path, tmp_path: Path) -> None:
    """The routes the launcher draws stay inside, and every node reads the file it is
    handed (``team node --territory``): its landmarks are drawn inside the same mask."""
    from sonarmap.io.rosmap import read_map

    plan = read_map(files / "plan.yaml")
    mask = files / "inside.txt"
    z = run_zmq_team(
        plan,
        MissionConfig(duration=10.0, seed=1),
        2,
        folder=tmp_path / "zmq",
        territory=mask,
        timeout=300.0,
    )
    region = read_territory(mask, plan)
    for node in z.nodes:
        assert node["territory_cells"] == int(region.sum())
        # The node drew its world inside the mask: without it every landmark lies on the
        # outer faces, which a robot inside never sees (0 landmarks on these routes).
        assert node["row"]["landmarks"] > 0, node["row"]
    for r in load_routes(tmp_path / "zmq" / "routes", 2):
        assert _inside(r[:, 1:3], pad=0.3).all()
    assert z.summary["duplicate_poses"] == 0
