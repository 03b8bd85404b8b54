"""Cars that never stand for good (issue 36): start headings a car can drive from, and
a car locked askew in a street one passable cell wide getting out."""

from __future__ import annotations

import math
import socket
from pathlib import Path

import numpy as np
import pytest

from conftest import walled_site
from sonarmap.cli import main
from sonarmap.errors import ConfigError, InputError
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.patrol.manoeuvre import carrot
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Car
from sonarmap.patrol.simulation import PatrolConfig, car_starts, run_patrol
from sonarmap.patrol.starts import spread_starts
from sonarmap.patrol.territory import Territory

#: The tip of the stub: farthest-point sampling's second start on :func:`_stub_site`.
TIP = (14.75, 38.25)


def _stub_site() -> Territory:
    """30 x 40 m: a 9.5 m street along the bottom and, north from it, a 2.5 m stub
    (x 13.5-16 m) running 29 m to a dead end, one passable cell wide for the 1 m disc
    (site 1027's boxed start, built small)."""
    return walled_site([(0.5, 10.0, 13.5, 39.5), (16.0, 10.0, 29.5, 39.5)], 30.0, 40.0)


def test_a_stub_tip_start_faces_along_the_stub_and_moves() -> None:
    t = _stub_site()
    cfg = PatrolConfig(model="car", duration=20.0)
    where = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision)
    plain = spread_starts(2, t, where.passable, cfg.min_separation, 0)
    assert tuple(plain[1, :2]) == TIP
    cars = car_starts(t, where.passable, cfg)
    # Facing +x, as every start faced before: no arc of a step is clear.
    assert not cars.moves(*TIP, 0.0)
    assert cars.heading(*TIP) == pytest.approx(-math.pi / 2)
    path: list[tuple[float, float]] = []

    def keep(_t: float, team: object, _fog: object) -> None:
        assert isinstance(team, Car)
        path.append((float(team.x[1]), float(team.y[1])))

    res = run_patrol(t, cfg, robots=2, seed=0, on_step=keep)
    assert tuple(res.starts[1, :2]) == TIP
    assert res.starts[1, 2] == pytest.approx(-math.pi / 2)
    assert math.hypot(path[-1][0] - TIP[0], path[-1][1] - TIP[1]) > 10.0


def test_spread_skips_a_cell_no_car_moves_from() -> None:
    t = _stub_site()
    cfg = PatrolConfig(model="car")
    where = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision)
    r, c = (int(v) for v in t.grid.world_to_cell(*TIP))
    starts = spread_starts(
        2, t, where.passable, cfg.min_separation, 0, fits=lambda rr, cc: (rr, cc) != (r, c)
    )
    # The next farthest cell: the one below the tip.
    assert tuple(starts[1, :2]) == (TIP[0], TIP[1] - 0.5)


def test_a_start_file_pose_no_car_moves_from_is_refused() -> None:
    t = _stub_site()
    cfg = PatrolConfig(model="car", duration=5.0)
    starts = np.array([[17.25, 2.75, 0.0], [TIP[0], TIP[1], 0.0]])
    with pytest.raises(InputError, match=r"robot 2 .* move neither .* heading -1\.571 rad"):
        run_patrol(t, cfg, starts=starts)
    # Facing down the stub, the same place is a start.
    starts[1, 2] = -math.pi / 2
    run_patrol(t, cfg, starts=starts)


#: Training site 4's lock (the fallback page): a car askew at the two-way end of a
#: 2.5 m street one passable cell wide (x 27.25 m), just below its junction; its route
#: runs north and turns east.
LOCK = (27.26991489503502, 44.022203400780704, math.radians(56.35908116844356))
ROUTE = np.array(
    [(27.25, 44.75), (27.25, 45.25), (27.25, 45.75), (27.25, 46.25), (27.75, 46.25)]
    + [(x, 46.75) for x in np.arange(28.25, 38.0, 0.5)]
)


def _drive(car: Car, steps: int) -> float:
    """Drive the lone car ``steps`` steps along :data:`ROUTE` (pure pursuit's point 3 m
    on, as the simulation gives it); returns the farthest it got from where it began."""
    t = street_territory(4)
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    x0, y0 = float(car.x[0]), float(car.y[0])
    far = 0.0
    for _ in range(steps):
        x, y = float(car.x[0]), float(car.y[0])
        j = int(np.argmin(np.hypot(ROUTE[:, 0] - x, ROUTE[:, 1] - y)))
        route = np.vstack([[x, y], ROUTE[j:]])
        car.routes = [route]
        px, py = carrot(route, x, y, 3.0)
        n = math.hypot(px - x, py - y)
        car.step([((px - x) / n, (py - y) / n)], passable, t.grid, 0.5, rng, [(px, py)])
        far = max(far, math.hypot(float(car.x[0]) - x0, float(car.y[0]) - y0))
    return far


def _locked_car(stall_steps: int) -> Car:
    t = street_territory(4)
    x, y, h = LOCK
    return Car(
        np.array([x]),
        np.array([y]),
        np.array([h]),
        clearance=t.clearance,
        planner="track",
        stall_steps=stall_steps,
    )


def test_a_car_locked_askew_gets_out() -> None:
    # Without the stall watch (never reached) it swings 0.42 m for a minute.
    car = _locked_car(10**6)
    assert _drive(car, 120) < 0.5
    # With it, out within the same minute: 10 s to notice, then the finer search.
    car = _locked_car(20)
    assert _drive(car, 120) > 8.0
    assert 1 <= int(car.stalls[0]) <= 3


def test_car_state_restores() -> None:
    car = _locked_car(20)
    _drive(car, 15)
    saved = car.state()
    _drive(car, 30)
    after = (car.x.copy(), car.y.copy(), car.heading.copy(), car.stalls.copy())
    car.restore(saved)
    assert int(car.still[0]) == int(saved["still"][0])
    _drive(car, 30)
    assert np.array_equal(car.x, after[0])
    assert np.array_equal(car.y, after[1])
    assert np.array_equal(car.heading, after[2])
    assert np.array_equal(car.stalls, after[3])


def test_a_state_restored_into_a_new_car_drives_on_equal() -> None:
    car = _locked_car(20)
    _drive(car, 25)  # past its first stall: the stall watch's state is not the fresh one
    assert int(car.stalls[0]) >= 1
    twin = _locked_car(20)
    twin.restore(car.state())
    for _ in range(4):
        _drive(car, 10)
        _drive(twin, 10)
        for name, value in car.state().items():
            if isinstance(value, np.ndarray):
                assert np.array_equal(value, twin.state()[name]), name
    assert math.hypot(float(twin.x[0]) - LOCK[0], float(twin.y[0]) - LOCK[1]) > 1.0


def test_a_car_refuses_a_state_not_its_own() -> None:
    car = _locked_car(20)
    state = car.state()
    del state["wait"]
    with pytest.raises(ConfigError, match=r"missing \['wait'\]"):
        car.restore(state)
    with pytest.raises(ConfigError, match=r"unknown \['speed'\]"):
        car.restore({**car.state(), "speed": 1.0})


def test_the_command_line_names_the_start_file_line_and_pose_of_a_boxed_car(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = _stub_site()
    write_map(OccupancyMap(t.grid, (~t.free).astype(np.float32)), tmp_path / "stub")
    # Robot 2 at the stub's tip facing +x: (14.75, 38.25) m is (147.5, 17.5) dm, Y down.
    (tmp_path / "s.txt").write_text("# two cars\n2\n172.5 372.5 0\n147.5 17.5 0\n")
    args = ["patrol", "run", "--map", str(tmp_path / "stub.yaml"), "--model", "car"]
    args += ["--duration", "2", "--starts", str(tmp_path / "s.txt")]
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    live = ["--live", "--live-port", str(port)]
    with pytest.raises(SystemExit) as e:
        main([*args, *live, "-o", str(tmp_path / "a")])
    assert e.value.code == 2
    said = capsys.readouterr()
    # The live server's address is not announced for a run that never starts.
    assert "live:" not in said.out
    err = said.err.strip().splitlines()
    assert len(err) == 1, err
    assert "s.txt:4:" in err[0]
    assert "robot 2 at (147.5, 17.5) dm facing 0 rad" in err[0]
    assert not (tmp_path / "a").exists()
    # --robots 1 runs the file's first car only: the boxed second is not checked.
    main([*args, "--robots", "1", "-o", str(tmp_path / "b")])
    assert (tmp_path / "b" / "summary.json").exists()


def test_a_car_no_search_frees_waits_longer_each_time(monkeypatch: pytest.MonkeyPatch) -> None:
    # Boxed at the stub's tip facing +x (no step's arc is clear), every search failing:
    # it searches after 10 s, then 20, 40, 80 s and at most every 160 s, not every 10 s.
    import sonarmap.patrol.robots as robots

    fine: list[int] = []

    def fail(*_: object, headings: int = 16, **__: object) -> None:
        if headings == robots.UNSTALL_SEARCH.headings:
            fine.append(headings)

    monkeypatch.setattr(robots, "plan_manoeuvre", fail)
    t = _stub_site()
    passable = t.passable(1.0)
    car = Car(
        np.array([TIP[0]]), np.array([TIP[1]]), np.array([0.0]), clearance=t.clearance,
        planner="track",
    )  # fmt: skip
    route = np.array([(TIP[0], TIP[1] - k) for k in range(8)])
    rng = np.random.default_rng(0)
    for _ in range(700):
        car.routes = [route]
        car.step([(0.0, -1.0)], passable, t.grid, 0.5, rng, [(TIP[0], TIP[1] - 3.0)])
    assert math.hypot(float(car.x[0]) - TIP[0], float(car.y[0]) - TIP[1]) < 0.5
    # Searches at steps 20, 60, 140, 300 and 620 (waits 20, 40, 80, 160, 320 = cap).
    assert int(car.stalls[0]) == len(fine) == 5
    assert int(car.wait[0]) == robots.STALL_WAIT_CAP * car.stall_steps


def test_the_straight_run_from_a_cell_not_passable_is_nothing() -> None:
    t = _stub_site()
    cfg = PatrolConfig(model="car")
    where = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision)
    cars = car_starts(t, where.passable, cfg)
    # Inside the block west of the stub, facing east into the stub: 0, not 20 m.
    assert cars.run(12.75, 20.25, 0.0) == 0.0
    # From the stub's tip facing down it: most of its 29 m, capped at 20.
    assert cars.run(*TIP, -math.pi / 2) == pytest.approx(20.0)
