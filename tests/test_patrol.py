"""Patrolling (first part): the wave, forces, the collision rule, fog, runs, the command."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from sonarmap.cli import main
from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.patrol import (
    Fog,
    Force,
    Holonomic,
    PatrolConfig,
    Territory,
    choose_direction,
    parse_force,
    read_starts,
    run_patrol,
    wave,
)
from sonarmap.patrol.experiments import run_experiment
from sonarmap.patrol.fog import Vision, dilate, disc_cells, disc_offsets
from sonarmap.patrol.forces import _top_two, sector_pulls, step_direction
from sonarmap.patrol.paths import STEP_UNITS, STEPS, Wave, nearest_step, shadows
from sonarmap.patrol.robots import SPEED_BANDS, Car, arc, band_speed, parse_speed_bands
from sonarmap.patrol.territory import move_clear


def _graph(passable: np.ndarray) -> coo_matrix:
    """The wave's graph written out edge by edge, for scipy's Dijkstra."""
    rows, cols = passable.shape
    src, dst, w = [], [], []
    for r in range(rows):
        for c in range(cols):
            if not passable[r, c]:
                continue
            for k, (dr, dc) in enumerate(STEPS.tolist()):
                rr, cc = r + dr, c + dc
                if not (0 <= rr < rows and 0 <= cc < cols and passable[rr, cc]):
                    continue
                if k % 2 and not (passable[r, cc] and passable[rr, c]):
                    continue
                src.append(r * cols + c)
                dst.append(rr * cols + cc)
                w.append(math.sqrt(2) if k % 2 else 1.0)
    return coo_matrix((w, (src, dst)), shape=(rows * cols, rows * cols))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.slow
def test_wave_is_dijkstra_and_first_steps_lead_there(seed: int) -> None:
    rng = np.random.default_rng(seed)
    passable = rng.random((30, 40)) > 0.3
    passable[15, 20] = True
    dist, first = wave(passable, (15, 20), 0.1)
    ref = dijkstra(_graph(passable).tocsr(), indices=15 * 40 + 20).reshape(30, 40) * 0.1
    ref[~passable] = np.inf
    np.testing.assert_array_equal(np.isfinite(dist), np.isfinite(ref))
    np.testing.assert_allclose(dist[np.isfinite(ref)], ref[np.isfinite(ref)], atol=1e-9)
    # The first step of a shortest path is a step the source can take, and the rest of
    # the path from there is exactly as long as the remainder.
    from_src = {}
    for k, (dr, dc) in enumerate(STEPS.tolist()):
        rr, cc = 15 + dr, 20 + dc
        if 0 <= rr < 30 and 0 <= cc < 40 and np.isfinite(dist[rr, cc]) and first[rr, cc] == k:
            from_src[k] = wave(passable, (rr, cc), 0.1)[0]
    cells = np.argwhere(np.isfinite(dist) & (first >= 0))
    for r, c in cells[rng.choice(len(cells), 40, replace=False)]:
        k = int(first[r, c])
        step = 0.1 * (math.sqrt(2) if k % 2 else 1.0)
        assert from_src[k][r, c] + step == pytest.approx(dist[r, c])


def test_places_beside_walls_still_pull() -> None:
    """A cell the robot's centre cannot reach is reached by a passable path and one
    last step onto it, never across others like it (a strip along a wall or through a
    gap too narrow for the robot must not pull the robot into the wall); paths between
    passable cells never leave them."""
    free = np.ones((10, 10), dtype=bool)
    passable = free.copy()
    passable[:, :2] = False  # a strip too near the wall for the robot's centre
    dist, _first = wave(passable, (5, 5), 1.0, target=free)
    assert np.isfinite(dist[:, 1]).all()
    assert dist[5, 1] == pytest.approx(4.0)
    assert np.isinf(dist[:, 0]).all()
    alone, _ = wave(passable, (5, 5), 1.0)
    np.testing.assert_array_equal(dist[passable], alone[passable])


def test_forces_and_directions() -> None:
    f = parse_force("f3g4")
    assert (f.f, f.g, f.a, f.b) == ("f3", "g4", 40.0, 65.0)
    # log F = a TB_n - (L / b)^2, L in decimetres.
    lp = f.log_pull(np.array([0.5, 1.0]), np.array([6.5, 13.0]))
    np.testing.assert_allclose(lp, [20.0 - 1.0, 40.0 - 4.0])  # 65 and 130 dm
    with pytest.raises(ConfigError, match="unknown force"):
        parse_force("f6g1")
    with pytest.raises(ConfigError, match="must be > 0"):
        Force("f3", "g4", a=0.0)
    # Three weak pulls east outvote one strong pull north in mode, not in the vector sum.
    lp = np.log(np.array([1.0, 1.0, 1.0, 2.5]))
    ux = np.array([1.0, 1.0, 1.0, 0.0])
    uy = np.array([0.0, 0.0, 0.0, 1.0])
    assert choose_direction(lp, ux, uy, "mode") == pytest.approx((1.0, 0.0))
    vx, vy = choose_direction(lp, ux, uy, "vector")  # type: ignore[misc]
    assert math.atan2(vy, vx) == pytest.approx(math.atan2(2.5, 3.0))
    assert choose_direction(np.full(3, -np.inf), ux[:3], uy[:3]) is None
    assert STEP_UNITS[2] == pytest.approx((0.0, 1.0))  # step 2 is north: one row up


def _open_field(size: float = 30.0, res: float = 0.5) -> Territory:
    n = int(size / res)
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(n, n))
    return Territory.from_map(OccupancyMap(g, np.zeros(g.shape, np.float32)))


def test_collision_rule_cancels_every_move_that_could_collide() -> None:
    t = _open_field()
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    # Head-on: both moves are cancelled; a third robot far away still moves.
    team = Holonomic(np.array([10.0, 14.0, 25.0]), np.array([10.0, 10.0, 25.0]), np.zeros(3))
    moved = team.step([(1.0, 0.0), (-1.0, 0.0), (0.0, -1.0)], passable, t.grid, 0.5, rng)
    assert moved.tolist() == [False, False, True]
    assert team.blocked.tolist() == [True, True, False]
    assert (team.x[0], team.x[1], team.y[2]) == (10.0, 14.0, 25.0 - 2.2)
    # A move into a robot that stands is cancelled too; into a wall or off the map also.
    team = Holonomic(np.array([10.0, 13.5]), np.array([10.0, 10.0]), np.zeros(2))
    moved = team.step([(1.0, 0.0), None], passable, t.grid, 0.5, rng)
    assert moved.tolist() == [False, False]
    team = Holonomic(np.array([2.0]), np.array([10.0]), np.zeros(1))
    assert team.step([(-1.0, 0.0)], passable, t.grid, 0.5, rng).tolist() == [False]


def test_blocked_robots_wander_one_step_in_ten() -> None:
    t = _open_field(60.0)
    passable = t.passable(1.0)
    rng = np.random.default_rng(3)
    wandered = 0
    trials = 2000
    for _ in range(trials):
        team = Holonomic(np.array([30.0]), np.array([30.0]), np.zeros(1))
        team.blocked[:] = True
        team.step([None], passable, t.grid, 0.5, rng)  # no pull: only the 10 % rule moves it
        wandered += int(team.x[0] != 30.0 or team.y[0] != 30.0)
    share = wandered / trials
    assert abs(share - 0.1) < 3 * math.sqrt(0.1 * 0.9 / trials)


def test_fog_bookkeeping_and_dilation() -> None:
    g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(20, 20))
    watched = np.ones(g.shape, dtype=bool)
    watched[0, 0] = False
    fog = Fog(g, watched, start=5.0)
    assert fog.tb[0, 0] == 0.0
    assert fog.mtb() == 5.0
    fog.advance(0.5)
    disc = disc_offsets(3.0, 1.0)
    assert len(disc) == 29  # cells within 3 cells of a centre
    fog.observe([10], [10], disc)
    assert fog.tb[10, 13] == 0.0
    assert fog.tb[10, 14] == 5.5
    assert fog.tb[12, 12] == 0.0  # sqrt(8) m away: inside
    assert fog.tb[12, 13] == 5.5  # sqrt(13) m away: outside
    assert fog.mean_tb() == pytest.approx(5.5 * (399 - 29) / 399)
    rng = np.random.default_rng(0)
    tb = rng.random((15, 12))
    np.testing.assert_array_equal(dilate(tb, 2), ndimage.grey_dilation(tb, size=(5, 5)))
    assert dilate(tb, 0) is tb


@pytest.mark.slow
def test_runs_are_deterministic_and_more_robots_watch_better() -> None:
    t = _open_field(40.0)
    cfg = PatrolConfig(duration=300.0, paths="wave")
    a = run_patrol(t, cfg, robots=2, seed=5)
    b = run_patrol(t, cfg, robots=2, seed=5)
    np.testing.assert_array_equal(a.mtb, b.mtb)
    np.testing.assert_array_equal(a.positions, b.positions)
    # On a field much wider than the vision radius (100 x 88 m, as in Tables 2-3) three
    # robots share the work; on a 40 m field one robot sees nearly all of it already and
    # more robots mostly get in each other's way.
    g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(88, 100))
    field = Territory.from_map(OccupancyMap(g, np.zeros(g.shape, np.float32)))
    wide = PatrolConfig(duration=400.0, cell=1.0)
    for seed in (0, 1):
        one = run_patrol(field, wide, robots=1, seed=seed).summary()["mean_mtb"]
        three = run_patrol(field, wide, robots=3, seed=seed).summary()["mean_mtb"]
        assert three < 0.6 * one
    s = a.summary()
    assert 0 < s["mean_mtb"] < 300
    assert s["worst_idleness"] >= s["mean_mtb"]
    assert s["steps"] == 600


def test_start_files_in_the_thesis_format(tmp_path: Path) -> None:
    t = _open_field(30.0)
    (tmp_path / "s.txt").write_text("2\n100 50 0\n200 250 1.57\n")
    s = read_starts(tmp_path / "s.txt", t)
    np.testing.assert_allclose(s, [[10.0, 25.0, 0.0], [20.0, 5.0, 1.57]])
    (tmp_path / "bad.txt").write_text("2\n100 50 0\n200 x 1.57\n")
    with pytest.raises(InputError, match=r"bad.txt:3: expected 'X Y phi'"):
        read_starts(tmp_path / "bad.txt", t)
    (tmp_path / "short.txt").write_text("4\n100 50 0\n")
    with pytest.raises(InputError, match="says 4 robots but lists 1"):
        read_starts(tmp_path / "short.txt", t)
    with pytest.raises(InputError, match="start closer than 2 m"):
        run_patrol(t, PatrolConfig(duration=1.0), starts=np.array([[10, 10, 0], [11, 10, 0.0]]))
    with pytest.raises(InputError, match="outside the map"):
        run_patrol(t, PatrolConfig(duration=1.0), starts=np.array([[-5, 10, 0.0]]))


def test_patrol_run_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(300, 400))
    occ = np.zeros(g.shape, np.float32)
    occ[140:160, 100:300] = 1.0  # a wall across the middle
    write_map(OccupancyMap(g, occ), tmp_path / "plan")
    (tmp_path / "starts.txt").write_text("2\n50 50 0\n350 250 0\n")
    out = tmp_path / "run"
    main(
        [
            "patrol",
            "run",
            "--map",
            str(tmp_path / "plan.yaml"),
            "--starts",
            str(tmp_path / "starts.txt"),
            "--duration",
            "60",
            "--animate",
            "-o",
            str(out),
        ]
    )
    assert "mean MTB" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 120
    assert summary["params"]["force"] == "f3g4"
    lines = (out / "metrics.csv").read_text().splitlines()
    assert lines[0] == "step,t,mtb,mean_tb,dvt"
    assert len(lines) == 121
    assert (out / "fog.png").stat().st_size > 1000
    with Image.open(out / "patrol.gif") as gif:
        assert getattr(gif, "n_frames", 1) == 120  # a frame a step: fewer than 200 steps
    (tmp_path / "starts.txt").write_text("1\n200 150 0\n")  # inside the wall
    with pytest.raises(SystemExit) as e:
        main(
            [
                "patrol",
                "run",
                "--map",
                str(tmp_path / "plan.yaml"),
                "--starts",
                str(tmp_path / "starts.txt"),
                "-o",
                str(tmp_path / "bad"),
            ]
        )
    assert e.value.code == 2
    # The file, the robot's line and its start in the file's units.
    assert "starts.txt:2: robot 1 at (200, 150) dm is in an obstacle" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_network_components_with_line_of_sight() -> None:
    t = _open_field(100.0, 1.0)
    free = t.free.copy()
    free[:, 50] = False  # a wall down the middle, x = 50..51 m
    free[90:, 50] = True  # with a gap near y = 0..10 m
    x = np.array([10.0, 40.0, 60.0, 45.0, 56.0])
    y = np.array([50.0, 50.0, 50.0, 5.0, 5.0])
    from sonarmap.patrol import components

    lab = components("limited", x, y, clear=free, grid=t.grid, r_max=35.0)
    # 0-1 in range and in sight; 1-2 in range but the wall is between them; 3-4 see each
    # other through the gap; 1-3 in range (45 m? no: 45.3 m > 35) -> not linked.
    assert lab[0] == lab[1]
    assert lab[1] != lab[2]
    assert lab[3] == lab[4]
    assert lab[0] != lab[3]
    assert len(set(components("none", x, y, clear=free, grid=t.grid).tolist())) == 5
    assert len(set(components("full", x, y, clear=free, grid=t.grid).tolist())) == 1


def test_without_a_network_a_robot_knows_only_what_it_saw() -> None:
    t = _open_field(60.0)
    starts = np.array([[10.0, 10.0, 0.0], [50.0, 50.0, 0.0]])
    seen: dict[str, float] = {}
    for net in ("full", "none"):
        res = run_patrol(t, PatrolConfig(duration=200.0, network=net), starts=starts, seed=2)
        seen[net] = res.summary()["mean_mtb"]
    # Robots that cannot tell each other where they are patrol worse (here 2 robots).
    assert seen["none"] > seen["full"]
    with pytest.raises(ConfigError, match="unknown network"):
        PatrolConfig(network="wifi")


@pytest.mark.parametrize("policy", ["random", "reactive", "gravity"])
def test_baselines_run_on_the_same_simulator(policy: str) -> None:
    t = _open_field(40.0)
    starts = np.array([[10.0, 10.0, 0.0], [30.0, 30.0, 0.0]])
    res = run_patrol(t, PatrolConfig(duration=100.0, policy=policy), starts=starts, seed=1)
    s = res.summary()
    assert s["steps"] == 200
    assert 0 < s["mean_mtb"] <= 100
    moved = np.hypot(*(res.positions[:, :2] - starts[:, :2]).T)
    assert (moved > 0).all()  # every robot left its start


def test_artificial_obstacles_change_nothing_for_one_robot() -> None:
    t = _open_field(40.0)
    one = np.array([[20.0, 20.0, 0.0]])
    runs = [
        run_patrol(t, PatrolConfig(duration=60.0, crowding=c), starts=one, seed=4)
        for c in ("none", "obstacles")
    ]
    np.testing.assert_array_equal(runs[0].mtb, runs[1].mtb)
    two = np.array([[15.0, 20.0, 0.0], [25.0, 20.0, 0.0]])
    runs = [
        run_patrol(t, PatrolConfig(duration=60.0, crowding=c), starts=two, seed=4)
        for c in ("none", "obstacles")
    ]
    assert not np.array_equal(runs[0].positions, runs[1].positions)
    with pytest.raises(ConfigError, match="unknown crowding rule"):
        PatrolConfig(crowding="queues")


def test_refinement_penalty_and_direction() -> None:
    from sonarmap.patrol.refine import obstacle_penalty, refine_direction

    free = np.ones((12, 14), dtype=bool)
    free[3, 4] = False
    pen = obstacle_penalty(free, 1.0, window=3.0)
    # By hand at cell (5, 6): the obstacle (d^2 = 4 + 4) and no map edge within 3 cells.
    assert pen[5, 6] == pytest.approx(1 / 8)
    # At a corner the outside of the map counts: every cell of the window off the map.
    brute = sum(
        1.0 / (dr * dr + dc * dc)
        for dr in range(-3, 4)
        for dc in range(-3, 4)
        if (dr or dc) and not (0 <= dr < 12 and 0 <= dc < 14 and free[dr, dc])
    )
    assert pen[0, 0] == pytest.approx(brute)
    # Heading along a wall at 1.5 m, the refined direction turns away from it.
    t = _open_field(40.0)
    passable = t.passable(1.0)
    pen = obstacle_penalty(t.free, t.grid.resolution)
    dx, dy = refine_direction(20.0, 1.6, (1.0, 0.0), pen, passable, t.grid)
    assert dy > 0
    assert dx > 0
    # In the open, far from walls, the direction stays.
    assert refine_direction(20.0, 20.0, (1.0, 0.0), pen, passable, t.grid) == pytest.approx(
        (1.0, 0.0), abs=0.05
    )


def test_semaphores(tmp_path: Path) -> None:
    from sonarmap.patrol.semaphores import Semaphores, read_semaphores

    t = _open_field(40.0, 1.0)
    # A 10 m square in the middle, in dm from the top-left corner (y down).
    (tmp_path / "sem.txt").write_text("150 150;250 150;250 250;150 250\n")
    (area,) = read_semaphores(tmp_path / "sem.txt", t.grid)
    assert area.sum() == 100
    assert area[20, 20]
    assert not area[10, 10]
    (tmp_path / "bad.txt").write_text("150 150;250 150;250 250;150 250\n1 2;3\n")
    with pytest.raises(InputError, match=r"bad.txt:2: a semaphore needs at least 3"):
        read_semaphores(tmp_path / "bad.txt", t.grid)
    sem = Semaphores([area])
    heard = np.ones(3, dtype=bool)
    # Robots 0 and 1 enter on the same step: both own it, robot 2 finds it closed.
    sem.update(np.array([20, 21, 5]), np.array([20, 21, 5]))
    assert sem.owners[0] == {0, 1}
    assert sem.closed_for(0, heard) is None
    closed = sem.closed_for(2, heard)
    assert closed is not None
    assert closed.sum() == 100
    # Not if robot 2 hears of neither owner.
    assert sem.closed_for(2, np.array([False, False, True])) is None
    # Robot 2 cannot join later; when both owners leave, it is free again.
    sem.update(np.array([20, 5, 22]), np.array([20, 5, 22]))
    assert sem.owners[0] == {0}
    sem.update(np.array([5, 5, 5]), np.array([6, 7, 8]))
    assert sem.owners[0] == set()
    # One robot: semaphores change nothing.
    one = np.array([[20.0, 20.0, 0.0]])
    runs = [
        run_patrol(
            t, PatrolConfig(duration=40.0, crowding=c), starts=one, seed=4, semaphores=[area]
        )
        for c in ("none", "semaphores")
    ]
    np.testing.assert_array_equal(runs[0].mtb, runs[1].mtb)
    with pytest.raises(ConfigError, match="needs a semaphore file"):
        run_patrol(t, PatrolConfig(duration=1.0, crowding="semaphores"), starts=one)


def test_settings_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The thesis's setup.json and a YAML of option names; the command line wins."""
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(300, 300))
    write_map(OccupancyMap(g, np.zeros(g.shape, np.float32)), tmp_path / "plan")
    (tmp_path / "starts.txt").write_text("3\n50 50 0\n250 250 0\n50 250 0\n")
    (tmp_path / "setup.json").write_text(
        json.dumps(
            {
                "map": "plan.yaml",
                "robot_starting_position": "starts.txt",
                "robot_number": 2,
                "worsening_window": 1,
                "max_model_time": 40,
                "output_file": "mtb.txt",
                "log_period_steps": 10,
            }
        )
    )
    out = tmp_path / "a"
    main(["patrol", "run", "--config", str(tmp_path / "setup.json"), "-o", str(out)])
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["robots"], summary["steps"], summary["params"]["dilation"]) == (2, 40, 1)
    rows = (out / "mtb.txt").read_text().split("\n")
    assert [r.split()[0] for r in rows if r] == ["10", "20", "30", "40"]
    (tmp_path / "p.yaml").write_text("map: plan.yaml\nrobots: 1\nduration: 30\npolicy: reactive\n")
    out = tmp_path / "b"
    main(
        ["patrol", "run", "--config", str(tmp_path / "p.yaml"), "--duration", "10", "-o", str(out)]
    )
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["steps"], summary["params"]["policy"]) == (20, "reactive")
    capsys.readouterr()
    (tmp_path / "bad.yaml").write_text("map: plan.yaml\ncolour: 2\n")
    with pytest.raises(SystemExit) as e:
        main(["patrol", "run", "--config", str(tmp_path / "bad.yaml"), "-o", str(tmp_path / "c")])
    assert e.value.code == 2
    assert "bad.yaml, field 'colour': unknown option" in capsys.readouterr().err


def test_builtin_maps_are_usable(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from sonarmap.io.rosmap import read_map
    from sonarmap.patrol.maps import BUILTIN_MAPS
    from sonarmap.patrol.semaphores import read_semaphores

    main(["patrol", "maps", "-o", str(tmp_path / "maps")])
    d = tmp_path / "maps"
    sizes = {
        "open-field": (100, 88),
        "fig3-2": (100, 88),
        "fig3-4": (118, 118),
        "fig3-10": (240, 159),
    }
    for name in BUILTIN_MAPS:
        m = read_map(d / f"{name}.yaml")
        assert (m.grid.cols * m.grid.resolution, m.grid.rows * m.grid.resolution) == pytest.approx(
            sizes[name]
        )
        t = Territory.from_map(m, cell=0.5)
        starts = read_starts(d / f"{name}.starts.txt", t)
        # Every start is valid for the default robot: one step runs.
        res = run_patrol(t, PatrolConfig(duration=0.5), starts=starts)
        assert res.summary()["robots"] == len(starts)
    areas = read_semaphores(
        d / "fig3-10.semaphores.txt", Territory.from_map(read_map(d / "fig3-10.yaml")).grid
    )
    assert len(areas) >= 5


def test_line_of_sight_vision() -> None:

    clear = np.ones((21, 21), dtype=bool)
    clear[5:16, 13] = False  # a wall 3 cells east of the robot at (10, 10)
    disc = Vision(8.0, 1.0)
    los = Vision(8.0, 1.0, clear)
    seen_disc = set(zip(*(v.tolist() for v in disc.seen(10, 10, (21, 21))), strict=True))
    seen_los = set(zip(*(v.tolist() for v in los.seen(10, 10, (21, 21))), strict=True))
    assert (10, 16) in seen_disc  # behind the wall: the thesis's disc sees through
    assert (10, 16) not in seen_los
    assert (10, 13) in seen_los  # the wall's face is seen
    assert (10, 5) in seen_los  # nothing in the way
    assert (2, 10) in seen_los
    assert seen_los < seen_disc
    t = _open_field(40.0)
    res = run_patrol(t, PatrolConfig(duration=30.0, line_of_sight=True), robots=2, seed=1)
    assert res.summary()["steps"] == 60


def test_direction_weakening() -> None:
    from sonarmap.patrol.refine import sector_weakening

    t = _open_field(40.0, 0.5)
    # 2 m from the west edge: the west sector is weakened to 2 / 5.5, the east is not.
    w = sector_weakening(2.0, 20.0, t.free, t.grid)
    assert w[4] == pytest.approx(2.0 / 5.5, abs=0.26 / 5.5)
    assert w[0] == 1.0
    # Weakening turns the choice away from a strong pull into the wall.
    lp = np.log(np.array([1.0, 0.6]))
    ux, uy = np.array([-1.0, 1.0]), np.array([0.0, 0.0])
    assert choose_direction(lp, ux, uy, "mode") == pytest.approx((-1.0, 0.0))
    assert choose_direction(lp, ux, uy, "mode", weights=w) == pytest.approx((1.0, 0.0))
    res = run_patrol(t, PatrolConfig(duration=20.0, weaken=True), robots=2, seed=1)
    assert res.summary()["steps"] == 40


def test_offline_tour_sees_everything_and_cycles() -> None:
    from sonarmap.patrol.tour import plan_tour

    t = _open_field(60.0, 0.5)
    passable = t.passable(1.0)
    tour, length = plan_tour(t, passable, 10.0, (60, 60))
    cx, cy = t.grid.all_centres()
    wx, wy = t.grid.cell_centres(tour[:, 0], tour[:, 1])
    near = np.min(np.hypot(cx[..., None] - wx, cy[..., None] - wy), axis=-1)
    assert (near[t.free] <= 10.0).all()  # every place within sight of a waypoint
    assert length > 0
    res = run_patrol(t, PatrolConfig(duration=400.0, policy="cycle"), robots=2, seed=0)
    s = res.summary()
    # Once round, nothing stays unseen for the whole run.
    assert s["worst_idleness"] < 400.0


# --- car-like robots -------------------------------------------------------------


def test_speed_rule_bands() -> None:
    kmh = [band_speed(d) * 3.6 for d in (0.0, 1.99, 2.0, 4.9, 5.0, 7.49, 7.5, 100.0)]
    assert kmh == pytest.approx([3, 3, 6, 6, 9, 9, 15, 15])
    assert parse_speed_bands("2:3,5:6,7.5:9,inf:15") == SPEED_BANDS
    for bad in ("2:3,1:6", "2:0", "2-3", "x:3"):
        with pytest.raises(ConfigError, match="speed rule"):
            parse_speed_bands(bad)


def test_arc_turns_by_length_over_radius() -> None:
    px, py, h = arc(0.0, 0.0, 0.0, math.pi * 3.5 / 2, 1 / 3.5, 50)
    assert h == pytest.approx(math.pi / 2)  # a quarter circle of radius 3.5 m
    assert (px[-1], py[-1]) == pytest.approx((3.5, 3.5))
    np.testing.assert_allclose(np.hypot(px, py - 3.5), 3.5)
    px, py, h = arc(0.0, 0.0, 0.0, -2.0, 0.0, 5)  # straight back
    assert (px[-1], py[-1], h) == pytest.approx((-2.0, 0.0, 0.0))


def _corridor_map(res: float = 0.25) -> Territory:
    """A 40 x 30 m room with a 4 m wide dead-end corridor leaving it eastwards."""
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(int(30 / res), int(70 / res)))
    occ = np.ones(g.shape, np.float32)
    occ[:, : int(40 / res)] = 0.0
    occ[int(13 / res) : int(17 / res), : int(65 / res)] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


def test_cars_never_turn_tighter_than_their_radius_and_keep_the_speed_rule() -> None:
    t = _corridor_map()
    cfg = PatrolConfig(model="car", duration=400.0, cell=0.25)
    seen: list[tuple[float, np.ndarray, np.ndarray]] = []

    def keep(time: float, team: object, fog: Fog) -> None:
        assert isinstance(team, Car)
        seen.append((time, np.column_stack([team.x, team.y, team.heading]), team.escaping.copy()))

    res = run_patrol(t, cfg, robots=2, seed=1, on_step=keep)
    for (_, a, _), (_, b, _) in itertools.pairwise(seen):
        for i in range(len(a)):
            turn = abs(math.remainder(b[i, 2] - a[i, 2], 2 * math.pi))
            chord = math.hypot(b[i, 0] - a[i, 0], b[i, 1] - a[i, 1])
            # An arc of radius R >= 3.5 m turning by `turn` has chord 2 R sin(turn / 2).
            assert chord >= 2 * 3.5 * math.sin(turn / 2) - 1e-6
            rr, cc = t.grid.world_to_cell(a[i, 0], a[i, 1])
            limit = band_speed(float(t.clearance[int(rr), int(cc)])) * 0.5
            # Never faster than the rule allows there, to a micrometre: the arcs'
            # trigonometry leaves a step a few nanometres off its length.
            assert chord <= limit + 1e-6
    s = res.summary()
    assert s["dvt"] > 0  # the dead-end corridor forces escapes
    assert len(s["dvt_per_robot"]) == 2
    assert res.dvt[-1] == pytest.approx(s["dvt"])
    assert s["mean_mtb"] < 400


def test_a_car_escapes_a_dead_end() -> None:
    t = _corridor_map()
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    # Near the end of the corridor, facing the end wall, wanting to go back west.
    car = Car(np.array([62.5]), np.array([15.0]), np.array([0.0]), clearance=t.clearance)
    west = (-1.0, 0.0)
    steps = 0
    while steps < 200:
        car.step([west], passable, t.grid, 0.5, rng)
        steps += 1
        if not car.escaping[0] and abs(math.remainder(car.heading[0] - math.pi, 2 * math.pi)) < 0.2:
            break
    assert steps < 200, "the car never turned round"
    # It turned round inside the corridor (4 m wide: a three-point turn, not a U-turn).
    assert 40.0 < car.x[0] < 65.0
    assert 13.0 < car.y[0] < 17.0


def test_holonomic_robots_have_no_dvt_and_one_car_runs_alike_under_all_crowding() -> None:
    t = _corridor_map(0.5)
    runs = [
        run_patrol(t, PatrolConfig(model="car", crowding=c, duration=120.0), robots=1, seed=2)
        for c in ("none", "obstacles")
    ]
    np.testing.assert_array_equal(runs[0].mtb, runs[1].mtb)
    np.testing.assert_array_equal(runs[0].dvt, runs[1].dvt)
    hol = run_patrol(t, PatrolConfig(duration=60.0), robots=2, seed=2)
    assert hol.summary()["dvt"] == 0.0
    with pytest.raises(ConfigError, match="unknown robot model"):
        PatrolConfig(model="tank")
    with pytest.raises(ConfigError, match="turn_radius must be > 0"):
        PatrolConfig(turn_radius=0.0)


# --- experiments -------------------------------------------------------------------


def test_crowding_experiment_writes_its_tables_and_checks_the_one_robot_rule(
    tmp_path: Path,
) -> None:
    out = tmp_path / "crowding"
    report = run_experiment("crowding", out, seeds=1, duration=20.0, cell=1.0, workers=1)
    assert report == out / "report.html"
    runs = pd.read_csv(out / "runs.csv")
    assert len(runs) == 15  # 3 rules x 1-5 robots x 1 seed
    assert set(runs["variant"]) == {"none", "semaphores", "obstacles"}
    assert (runs["dvt"] >= 0).all()
    claims = {c["claim"]: c for c in json.loads((out / "claims.json").read_text())}
    one = claims["one robot runs alike under all three crowding rules"]
    assert one["verdict"] == "confirmed"
    html = report.read_text()
    assert "Table 4" in html
    assert "632.5" in html  # the thesis's figure beside ours
    with pytest.raises(ConfigError, match="unknown experiment"):
        run_experiment("nope", tmp_path / "x")
    assert not (tmp_path / "x").exists()


# --- bad input -----------------------------------------------------------------------


def _bad_input_files(tmp: Path) -> None:
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(200, 300))
    occ = np.zeros(g.shape, np.float32)
    occ[90:110, 100:200] = 1.0
    write_map(OccupancyMap(g, occ), tmp / "plan")
    # A real ROS map of nothing but grey (unknown): nothing to patrol.
    write_map(OccupancyMap(g, np.full(g.shape, 0.5, np.float32)), tmp / "grey")
    (tmp / "broken.yaml").write_text("image: nowhere.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    (tmp / "outside.txt").write_text("1\n5000 50 0\n")
    (tmp / "wall.txt").write_text("1\n150 100 0\n")
    (tmp / "overlap.txt").write_text("2\n50 50 0\n60 50 0\n")
    (tmp / "malformed.txt").write_text("2\n50 50 0\n250 oops 0\n")
    (tmp / "sem.txt").write_text("10 10;20 10;20 20\n10 10;20\n")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--map", "broken.yaml"], "nowhere.pgm: map image not found"),
        (["--map", "grey.yaml", "--robots", "1"], "no free cell"),
        (["--map", "plan.yaml", "--starts", "outside.txt"], "outside the map"),
        (["--map", "plan.yaml", "--starts", "wall.txt"], "is in an obstacle"),
        (["--map", "plan.yaml", "--starts", "overlap.txt"], "start closer than 2 m"),
        (
            ["--map", "plan.yaml", "--starts", "malformed.txt"],
            "malformed.txt:3: expected 'X Y phi'",
        ),
        (
            [
                "--map",
                "plan.yaml",
                "--robots",
                "1",
                "--crowding",
                "semaphores",
                "--semaphores",
                "sem.txt",
            ],
            "sem.txt:2: a semaphore needs at least 3",
        ),
        (["--map", "plan.yaml", "--robots", "1", "--force", "f9g1"], "unknown force"),
        (["--map", "plan.yaml", "--robots", "1", "--radius", "0"], "radius must be > 0"),
        (["--map", "plan.yaml", "--robots", "1", "--vision", "-3"], "vision must be > 0"),
        (["--map", "plan.yaml", "--robots", "1", "--speed", "0"], "speed must be > 0"),
        (["--map", "plan.yaml", "--robots", "1", "--duration", "-1"], "duration must be > 0"),
        (["--map", "plan.yaml", "--robots", "1", "--turn-radius", "0"], "turn_radius must be > 0"),
        (["--map", "plan.yaml", "--robots", "1", "--r-obst", "0"], "r_obst must be > 0"),
        (["--map", "plan.yaml", "--robots", "1", "--model", "tank"], "unknown robot model"),
        (["--map", "plan.yaml", "--robots", "1", "--duration", "0.2"], "shorter than one step"),
        (["--map", "plan.yaml", "--robots", "1", "--seed", "-1"], "seed must be >= 0"),
        (["--map", "plan.yaml", "--starts", "overlap.txt", "--robots", "0"], "robots must be >= 1"),
        (["--map", "plan.yaml", "--robots", "1", "--motion", "path", "--model", "car"], "motion"),
        (["--map", "plan.yaml", "--robots", "1", "--speed-bands", "2:3,1:6"], "speed rule"),
        (
            [
                "--map",
                "plan.yaml",
                "--robots",
                "1",
                "--model",
                "car",
                "--one-way",
                "--paths",
                "straight",
            ],
            "one_way needs paths 'wave'",
        ),
        (
            [
                "--map",
                "plan.yaml",
                "--robots",
                "1",
                "--paths",
                "regions",
                "--crowding",
                "obstacles",
            ],
            "cannot follow the map edits",
        ),
    ],
)
def test_bad_patrol_input_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    _bad_input_files(tmp_path)
    here = [str(tmp_path / a) if a.endswith((".yaml", ".txt")) else a for a in args]
    with pytest.raises(SystemExit) as e:
        # The case's own options come last: they win over the short default duration.
        main(["patrol", "run", "--duration", "5", *here, "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2
    assert message in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_pruned_waves_change_nothing() -> None:
    """Waves cut where far places can no longer change a robot's choice give the very
    same run as waves over the whole map."""
    from sonarmap.patrol.maps import builtin_territory
    from sonarmap.patrol.starts import starts_from_dm

    cars = {"model": "car", "refine": True, "crowding": "obstacles"}
    for name, cell, seconds, n, extra in (
        ("fig3-4", 1.0, 150.0, 3, {}),
        ("fig3-4", 1.0, 150.0, 3, {**cars, "dilation": 1}),
        ("fig3-4", 1.0, 150.0, 3, {"direction": "vector", "weaken": True}),
        # The benchmark's setting, long enough for two steps to tie (at 312 s) after
        # the mode's certified cut had once stopped a wave short.
        ("fig3-10", 0.5, 400.0, 5, cars),
    ):
        t, starts = builtin_territory(name, cell)
        runs = [
            run_patrol(
                t,
                PatrolConfig(duration=seconds, cell=cell, prune=prune, **extra),  # type: ignore[arg-type]
                starts=starts_from_dm(starts[:n], t),
            )
            for prune in (True, False)
        ]
        np.testing.assert_array_equal(runs[0].mtb, runs[1].mtb)
        np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
        np.testing.assert_array_equal(runs[0].dvt, runs[1].dvt)


def test_short_reproduction_of_the_open_field_ordering() -> None:
    """Tables 2-3 in miniature: the adopted f3g4 patrols the open field far better than
    f1g1 (a pull linear in TB_n and 1/L: the thesis's worst, 1476 s against 80.7 s)."""
    from sonarmap.patrol.maps import builtin_territory
    from sonarmap.patrol.starts import starts_from_dm

    t, starts = builtin_territory("open-field", 1.0)
    mtb = {}
    for name in ("f3g4", "f1g1"):
        cfg = PatrolConfig(duration=900.0, cell=1.0, paths="straight", force=parse_force(name))
        mtb[name] = run_patrol(t, cfg, starts=starts_from_dm(starts, t)).summary()["mean_mtb"]
    assert mtb["f3g4"] < 0.5 * mtb["f1g1"]
    assert mtb["f3g4"] < 200.0  # the thesis: 80.7 s by vector sum, 90.0 s by mode


def test_path_motion_keeps_to_paths_and_to_the_speed() -> None:
    """With path motion a robot moves along the wave's path (never farther than a step,
    never into an obstacle); it is refused where there is no wave path to follow."""
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(120, 200))
    occ = np.zeros(g.shape, np.float32)
    occ[58:62, :] = 1.0
    occ[58:62, 95:105] = 0.0  # one 1 m door between two rooms
    t = Territory.from_map(OccupancyMap(g, occ))
    cfg = PatrolConfig(radius=0.25, speed=0.5, vision=3.0, duration=300.0, motion="path")
    seen: list[np.ndarray] = []

    def keep(time: float, team: object, fog: Fog) -> None:
        assert isinstance(team, Holonomic)
        seen.append(np.column_stack([team.x, team.y]))

    res = run_patrol(t, cfg, starts=np.array([[5.0, 3.0, 0.0]]), on_step=keep)
    moves = np.hypot(*np.diff(np.stack(seen)[:, 0, :], axis=0).T)
    assert moves.max() <= 0.5 * 0.5 + 1e-9
    ys = np.stack(seen)[:, 0, 1]
    assert ys.max() > 6.5  # it went through the door into the other room
    assert res.summary()["steps"] == 600
    with pytest.raises(ConfigError, match="motion 'path'"):
        PatrolConfig(motion="path", model="car")
    with pytest.raises(ConfigError, match="motion 'path'"):
        PatrolConfig(motion="path", policy="random")
    with pytest.raises(ConfigError, match="motion 'path'"):
        PatrolConfig(motion="path", refine=True)


@pytest.mark.parametrize("seed", range(6))
def test_pulls_summed_with_the_wave_match_the_whole_map(seed: int) -> None:
    """The one-pass pulls (sector_pulls) against pulls over every place worked out
    apart: the sums cut at Force.pull_limit agree to float64 precision, and the cut
    that only certifies the mode's choice chooses as the whole map does, ties included
    (an even fog on an open field pulls two or four steps alike)."""
    rng = np.random.default_rng(seed)
    rows, cols, res = 121, 141, 0.25
    free = rng.random((rows, cols)) > 0.08 if seed % 3 else np.ones((rows, cols), dtype=bool)
    passable = ndimage.binary_erosion(free, iterations=1) if seed % 3 else free.copy()
    start = (60, 70)
    passable[start] = free[start] = True
    # Seeds 0 and 3: an even fog (ties); the others a fog of random ages with an old patch.
    last = -np.full((rows, cols), 100.0) if seed % 3 == 0 else -rng.uniform(0, 50, (rows, cols))
    last[rng.integers(0, rows), :] -= 100.0 * (seed % 3)
    now, top = 0.0, float((-last[free]).max())
    force = Force("f3", "g4", 40.0, 65.0) if seed < 4 else Force("f2", "g2", 40.0, 65.0)
    whole = Wave(free.shape)
    dist, first = whole(passable, start, res, free)
    rr, cc = np.nonzero(free & (first >= 0))
    lp = force.log_pull((now - last[rr, cc]) / top, dist[rr, cc])
    w = np.exp(lp - lp.max())
    sums = np.bincount(first[rr, cc].astype(np.int64), weights=w, minlength=8).astype(float)
    weights = rng.uniform(0.5, 1.0, 8) if seed % 2 else None
    expected = step_direction(sums, "mode", weights)

    waver = Wave(free.shape)
    kw = {"last_seen": last, "now": now}
    cut = sector_pulls(waver, passable, start, res, free, force, top, **kw)  # type: ignore[arg-type]
    np.testing.assert_allclose(cut, sums, rtol=1e-12, atol=1e-300)
    chosen = sector_pulls(
        waver,
        passable,
        start,
        res,
        free,
        force,
        top,
        certify=True,
        weights=weights,
        **kw,  # type: ignore[arg-type]
    )
    assert step_direction(chosen, "mode", weights) == expected
    assert np.isfinite(waver.dist).sum() <= np.isfinite(dist).sum()
    # With goal: the strongest place whose first step is the chosen one, among the
    # cells the cut wave reached, pulls as hard as the whole map's strongest there.
    aimed = sector_pulls(
        waver,
        passable,
        start,
        res,
        free,
        force,
        top,
        certify=True,
        weights=weights,
        goal=True,
        **kw,  # type: ignore[arg-type]
    )
    way = step_direction(aimed, "mode", weights)
    assert way == expected
    assert way is not None
    k = nearest_step(*way)
    mine = first[rr, cc] == k
    qr, qc = np.nonzero(free & (waver.first == k) & np.isfinite(waver.dist))
    cut_lp = force.log_pull((now - last[qr, qc]) / top, waver.dist[qr, qc])
    assert cut_lp.max() == pytest.approx(lp[mine].max(), rel=1e-12)
    if seed == 0:
        assert expected == pytest.approx((1.0, 0.0))  # four steps tie: the first wins
    with pytest.raises(ValueError, match="either"):
        sector_pulls(waver, passable, start, res, free, force, top)


@pytest.mark.parametrize("shape", [(70, 45), (64, 64), (100, 33)])
def test_the_fogs_mtb_is_the_worst_watched_cell(shape: tuple[int, int]) -> None:
    """Fog.mtb from its block minima equals the plain maximum of TB over the watched
    cells, on grids whose sides are and are not whole numbers of blocks."""
    rng = np.random.default_rng(shape[1])
    watched = rng.random(shape) > 0.2
    fog = Fog(Grid(resolution=0.1, origin=(0.0, 0.0), shape=shape), watched, 3.0)
    vision = Vision(1.0, 0.1)
    for _ in range(60):
        fog.advance(0.5)
        fog.observe(rng.integers(0, shape[0], 3), rng.integers(0, shape[1], 3), vision)
        assert fog.mtb() == fog.tb[watched].max()


def test_the_fog_sees_the_discs_watched_cells_and_keeps_its_mean() -> None:
    """A look with a plain disc marks exactly the watched cells of the disc inside the
    grid (robots at and beyond its edges too), and the mean TB kept as cells are seen
    equals the plain mean over the watched cells."""
    rng = np.random.default_rng(7)
    shape = (57, 80)
    watched = rng.random(shape) > 0.3
    fog = Fog(Grid(resolution=0.1, origin=(0.0, 0.0), shape=shape), watched, 2.0)
    disc = disc_offsets(1.5, 0.1)
    last = np.where(watched, -2.0, np.inf)
    for _ in range(40):
        fog.advance(0.5)
        rows, cols = rng.integers(-5, shape[0] + 5, 2), rng.integers(-5, shape[1] + 5, 2)
        fog.observe(rows, cols, disc)
        for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
            rr, cc = disc_cells(disc, r, c, shape)
            keep = watched[rr, cc]
            last[rr[keep], cc[keep]] = fog.t
        np.testing.assert_array_equal(fog.last, last)
        assert fog.mean_tb() == pytest.approx(float(np.mean(fog.t - last[watched])), rel=1e-12)
        assert fog.mtb() == fog.tb[watched].max()


@pytest.mark.parametrize("start", [0.0, 2.0])
def test_the_fog_keeps_its_latest_blocks_just_seen_cells_and_mean_over_seen_ones(
    start: float,
) -> None:
    """latest_blocks is the latest last-seen time of each block's watched cells;
    clear_just_seen clears exactly the mask's cells seen at the fog's time; the running
    mean over the cells seen at least once equals the plain one (with start 0 a cell
    seen at time 0 counts as never seen, as never_seen says)."""
    rng = np.random.default_rng(int(start) + 11)
    shape = (70, 45)
    watched = rng.random(shape) > 0.3
    fog = Fog(Grid(resolution=0.1, origin=(0.0, 0.0), shape=shape), watched, start)
    disc = disc_offsets(1.0, 0.1)
    b = Fog.BLOCK
    assert fog.mean_seen_tb() == math.inf
    fog.observe(np.array([10]), np.array([10]), disc)  # at time 0
    for k in range(40):
        fog.advance(0.5)
        fog.observe(rng.integers(0, shape[0], 2), rng.integers(0, shape[1], 2), disc)
        padded = np.full((-(-shape[0] // b) * b, -(-shape[1] // b) * b), -np.inf)
        padded[: shape[0], : shape[1]] = np.where(watched, fog.last, -np.inf)
        latest = padded.reshape(padded.shape[0] // b, b, -1, b).max(axis=(1, 3))
        np.testing.assert_array_equal(fog.latest_blocks(), latest)
        mask = (rng.random(shape) > 0.5) & watched  # places: watched cells
        want = mask & (fog.last < fog.t)
        n_cleared = int((mask & ~want).sum())
        assert n_cleared > 0
        assert fog.clear_just_seen(mask) == n_cleared
        np.testing.assert_array_equal(mask, want)
        seen = watched & ~fog.never_seen()
        if k % 10 == 0:
            assert fog.mean_seen_tb() == pytest.approx(
                float(fog.t - fog.last[seen].mean()), rel=1e-12
            )


@pytest.mark.parametrize("start", [0.0, 3.0])
def test_a_restored_fog_answers_as_the_original(start: float) -> None:
    """A fog restored from state() (into a fresh fog of the same grid) answers
    latest_blocks, clear_just_seen, mean_seen_tb, mean_tb and mtb exactly as the
    original, then and after more looks (its derived caches rebuilt from last)."""
    rng = np.random.default_rng(int(start) + 5)
    shape = (75, 50)
    grid = Grid(resolution=0.1, origin=(0.0, 0.0), shape=shape)
    watched = rng.random(shape) > 0.25
    clear = rng.random(shape) > 0.1
    disc = disc_offsets(1.2, 0.1)
    vision = Vision(1.2, 0.1, clear)
    fog = Fog(grid, watched, start)

    def look(f: Fog, k: int, rr: np.ndarray, cc: np.ndarray) -> None:
        f.advance(0.5)
        f.observe(rr, cc, disc if k % 2 else vision)

    def same(a: Fog, b: Fog) -> None:
        np.testing.assert_array_equal(a.latest_blocks(), b.latest_blocks())
        assert a.mean_seen_tb() == b.mean_seen_tb()
        assert a.mean_tb() == b.mean_tb()
        assert a.mtb() == b.mtb()
        np.testing.assert_array_equal(a.never_seen(), b.never_seen())
        mask = rng.random(shape) > 0.4
        mask_b = mask.copy()
        assert a.clear_just_seen(mask) == b.clear_just_seen(mask_b)
        np.testing.assert_array_equal(mask, mask_b)

    for k in range(12):
        look(fog, k, rng.integers(0, shape[0], 2), rng.integers(0, shape[1], 2))
    saved = fog.state()
    back = Fog(grid, watched, 0.0 if start else 7.0)  # restore sets start too
    back.restore(saved)
    assert back.t == fog.t
    assert back.start == fog.start
    same(fog, back)
    assert fog.mean_seen_tb() != math.inf
    assert fog.never_seen().any()
    # The state is a copy: later looks of the original leave it (and the copy) alone.
    for k in range(12, 30):
        rr, cc = rng.integers(0, shape[0], 3), rng.integers(0, shape[1], 3)
        look(fog, k, rr, cc)
        look(back, k, rr, cc)
        same(fog, back)
    again = Fog(grid, watched, start)
    again.restore(saved)
    assert again.t == 6.0
    assert again.mtb() != fog.mtb()
    with pytest.raises(ValueError, match="shape"):
        again.restore({**saved, "last": saved["last"][:-1]})


def test_move_clear_samples_both_ends_and_the_pieces_midpoints() -> None:
    """move_clear is clear exactly when both ends and the midpoints of the quarter-cell
    pieces of the segment lie on clear cells inside the grid (segments leaving the
    grid, on a map with an origin off 0)."""
    rng = np.random.default_rng(11)
    g = Grid(resolution=0.1, origin=(-1.3, 2.2), shape=(40, 60))
    clear = rng.random(g.shape) > 0.05
    agree = {True: 0, False: 0}
    for _ in range(400):
        x0, x1 = rng.uniform(-1.5, 4.9, 2)
        y0, y1 = rng.uniform(2.0, 6.4, 2)
        n = max(1, math.ceil(math.hypot(x1 - x0, y1 - y0) / 0.025))
        t = np.concatenate([[0.0], (np.arange(n) + 0.5) / n, [1.0]])
        r, c = g.world_to_cell(x0 + t * (x1 - x0), y0 + t * (y1 - y0))
        inside = g.contains(r, c)
        want = bool(inside.all() and clear[r[inside], c[inside]].all())
        assert move_clear(float(x0), float(y0), float(x1), float(y1), clear, g) == want
        agree[want] += 1
    assert min(agree.values()) > 20  # both answers were tried


def test_top_two_is_numpys_argmax_and_max_of_the_rest() -> None:
    # The visitor's certification reads the weighted sums without an array: the same
    # index, value and runner-up as numpy's argmax and max, ties (first wins), -inf,
    # zero weights and NaN included.
    rng = np.random.default_rng(3)
    for k in range(3000):
        sums = rng.choice([0.0, 0.5, 1.0, 2.0, -np.inf], 8) if k % 2 else rng.random(8)
        weights = rng.choice([0.0, 0.5, 1.0], 8) if k % 3 else rng.random(8)
        if k % 97 == 0:
            sums[int(rng.integers(8))] = np.nan
        with np.errstate(invalid="ignore"):  # -inf x 0: NaN, as in the kernel
            w = sums * weights
        want_k = int(np.argmax(w))
        top = w[want_k]
        w[want_k] = -np.inf
        got_k, got_top, rest = _top_two(sums, weights)
        assert got_k == want_k
        np.testing.assert_equal(got_top, top)
        np.testing.assert_equal(rest, w.max())


def test_sector_pulls_names_each_steps_strongest_place() -> None:
    """``places``: per step, the place whose pull is the strongest of those the wave
    took with that first step, as worked out apart from the wave's lengths."""
    rng = np.random.default_rng(5)
    free = rng.random((41, 53)) > 0.1
    start = (20, 26)
    free[start] = True
    last = -rng.uniform(0, 60, free.shape)
    top = float((-last[free]).max())
    force = Force()
    waver = Wave(free.shape)
    places = np.zeros((8, 2), dtype=np.int64)
    sector_pulls(waver, free, start, 0.25, free, force, top, last_seen=last, places=places)
    dist, first = waver.dist, waver.first
    for k in range(8):
        rr, cc = np.nonzero(free & (first == k) & np.isfinite(dist))
        if not len(rr):
            assert tuple(places[k]) == (-1, -1)
            continue
        lp = force.log_pull(-last[rr, cc] / top, dist[rr, cc])
        r, c = places[k]
        got = force.log_pull(np.array([-last[r, c] / top]), np.array([dist[r, c]]))[0]
        assert first[r, c] == k
        assert got == pytest.approx(lp.max(), rel=1e-12)
    with pytest.raises(ValueError, match="places"):
        sector_pulls(
            waver,
            free,
            start,
            0.25,
            free,
            force,
            top,
            last_seen=last,
            places=np.zeros((8, 3), dtype=np.int64),
        )


def test_shadows_pull_from_their_anchors() -> None:
    """sector_pulls with shadows: the sums add, to each anchor's step, the pulls of the
    watched cells tied to it at the anchor's length plus their distance, worked out
    apart; a strip cell the wave cannot reach then draws the robot."""
    free = np.ones((24, 36), dtype=bool)
    free[:, 0] = free[:, -1] = free[0, :] = free[-1, :] = False
    passable = ndimage.distance_transform_edt(free) >= 4
    start, res = (12, 18), 0.1
    last = np.zeros(free.shape)
    last[1, 1:6] = -100.0  # a corner of the wall-side strip unseen for long
    top, force = 100.0, Force()
    sh = shadows(passable, free, res)
    waver = Wave(free.shape)
    kw = {"last_seen": last, "now": 0.0, "prune": False}
    plain = sector_pulls(waver, passable, start, res, free, force, top, **kw)  # type: ignore[arg-type]
    places = np.zeros((8, 2), dtype=np.int64)
    shaded = sector_pulls(
        waver,
        passable,
        start,
        res,
        free,
        force,
        top,
        shadows=sh,
        places=places,
        **kw,  # type: ignore[arg-type]
    )
    dist, first = waver.dist, waver.first
    rr, cc = np.nonzero(free & (first >= 0))
    lengths, steps, ages = list(dist[rr, cc]), list(first[rr, cc]), list(-last[rr, cc])
    cols = free.shape[1]
    for k in np.flatnonzero(np.diff(sh.ptr)).tolist():
        ar, ac = divmod(k, cols)
        if first[ar, ac] < 0:
            continue
        for j in range(int(sh.ptr[k]), int(sh.ptr[k + 1])):
            lengths.append(dist[ar, ac] + sh.extra[j])
            steps.append(first[ar, ac])
            ages.append(-last[sh.rows[j], sh.cols[j]])
    lp = force.log_pull(np.array(ages) / top, np.array(lengths))
    w = np.exp(lp - lp.max())
    expected = np.bincount(np.array(steps, dtype=np.int64), weights=w, minlength=8)
    np.testing.assert_allclose(shaded, expected, rtol=1e-9)
    # The old corner pulls only through its shadows: up and to the left.
    way = step_direction(shaded, "mode")
    assert way is not None
    assert way[0] < 0
    assert way[1] > 0
    assert not np.allclose(plain, shaded)
    r, c = places[nearest_step(*way)]
    assert passable[r, c] or np.isfinite(dist[r, c])
