"""Dead-end stubs seen from the street (patrol.stubs) and cars that look down them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.oneway import one_way
from sonarmap.patrol.robots import Car
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.stubs import stand_points, stub_cells, stub_places
from sonarmap.patrol.territory import Territory

RES = 0.5


def _drawn(
    w: float,
    h: float,
    boxes: list[tuple[float, float, float, float, float]],
    *,
    background: float,
    walled: bool,
) -> Territory:
    """A ``w`` x ``h`` m map at ``RES`` of occupancy ``background``, walled round if
    ``walled``, with each box ``(x0, y0, x1, y1, v)`` (m, y up) set to ``v`` in order."""
    g = Grid(resolution=RES, origin=(0.0, 0.0), shape=(int(h / RES), int(w / RES)))
    occ = np.full(g.shape, background, np.float32)
    if walled:
        occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    for x0, y0, x1, y1, v in boxes:
        occ[int((h - y1) / RES) : int((h - y0) / RES), int(x0 / RES) : int(x1 / RES)] = v
    return Territory.from_map(OccupancyMap(g, occ))


def _ring_with_stubs() -> Territory:
    """5 m streets round a 50 x 20 m block (walled round, 60 x 30 m), with two 4 m wide
    dead-end stubs cut into the block from the south street: a short one (6 m deep,
    x 10-14 m) and a deep one (17 m, x 40-44 m)."""
    return _drawn(
        60.0,
        30.0,
        [
            (5.0, 5.0, 55.0, 25.0, 1.0),
            (10.0, 5.0, 14.0, 11.0, 0.0),
            (40.0, 5.0, 44.0, 22.0, 0.0),
        ],
        background=0.0,
        walled=True,
    )


def _stands(t: Territory, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    return (
        passable,
        stub_cells(passable, streets),
        stand_points(passable, t.free, streets, RES, reach),
    )


def test_places_in_a_short_stub_are_seen_from_its_junction_a_deep_stubs_far_end_not() -> None:
    t = _ring_with_stubs()
    g = t.grid
    passable, stub, stand = _stands(t, 9.0)
    # Both stubs are bridges of the street graph; the ring's streets are not.
    assert stub[g.world_to_cell(12.0, 9.0)]
    assert stub[g.world_to_cell(42.0, 18.0)]
    assert not stub[g.world_to_cell(30.0, 2.5)]
    # The short stub's end (6 m in, 8.5 m from the south street's middle) has a stand
    # point on the south street, in front of the stub; the deep stub's end has none.
    end = g.world_to_cell(12.0, 10.5)
    assert stand[end] >= 0
    sr, sc = divmod(int(stand[end]), passable.shape[1])
    x, y = g.cell_centres(sr, sc)
    assert passable[sr, sc]
    assert not stub[sr, sc]
    assert abs(float(x) - 12.0) <= 2.0
    assert float(y) < 5.0
    assert np.hypot(sr - end[0], sc - end[1]) * RES <= 9.0
    assert stand[g.world_to_cell(42.0, 21.0)] == -1
    # Only places in stubs have one.
    assert (stand[~stub & passable] == -1).all()
    # No reach, no stand points.
    assert (_stands(t, 0.0)[2] == -1).all()


def test_stub_places_include_the_wall_side_places_of_a_stub() -> None:
    t = _ring_with_stubs()
    g = t.grid
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    places = stub_places(passable, t.free, streets)
    stub = stub_cells(passable, streets)
    # Every passable stub cell, and free cells beside the stub's walls no car's centre
    # reaches (the robot's radius is 1 m); nothing on the ring.
    assert (places[stub]).all()
    assert (places & ~passable).any()
    assert places[g.world_to_cell(42.0, 21.5)]
    assert not places[g.world_to_cell(30.0, 2.5)]


def test_stand_points_check_their_inputs() -> None:
    t = _ring_with_stubs()
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    with pytest.raises(ValueError, match="watched"):
        stand_points(passable, t.free[1:], streets, RES, 9.0)
    with pytest.raises(ValueError, match="reach"):
        stand_points(passable, t.free, streets, RES, float("nan"))


def _ring_with_a_t_shaped_stub() -> Territory:
    """5 m streets round a 50 x 20 m block (walled round, 60 x 30 m), with a 4 m wide
    dead end cut north into the block from the south street's middle (x 28-32 m, 10 m
    deep) that ends in a 4 m wide bar from x = 20 to 40 m: a T the street graph gives a
    junction of its own, beyond the stub."""
    return _drawn(
        60.0,
        30.0,
        [
            (5.0, 5.0, 55.0, 25.0, 1.0),
            (28.0, 5.0, 32.0, 15.0, 0.0),
            (20.0, 15.0, 40.0, 19.0, 0.0),
        ],
        background=0.0,
        walled=True,
    )


def test_a_junction_beyond_a_stub_belongs_to_the_stub() -> None:
    # Training sites 5, 7, 9 and 11 have such junctions (a dead end that bends or
    # branches): their cells belonged to no street, so to no stub, and the places there
    # were neither looked at from the mouth nor delayed.
    t = _ring_with_a_t_shaped_stub()
    g = t.grid
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    stub = stub_cells(passable, streets)
    tee = g.world_to_cell(30.0, 17.0)
    assert streets.street[tee] == -1  # a junction of the street graph
    assert streets.stub_ends[tee]
    # Every passable cell of the T and of the stub leading to it is a stub cell.
    r0, c0 = g.world_to_cell(20.0, 19.0)
    r1, c1 = g.world_to_cell(40.0, 7.5)
    box = np.zeros_like(passable)
    box[r0 : r1 + 1, c0 : c1 + 1] = True
    assert stub[box & passable].all()
    # The junction where the stub opens on the south street is no stub's.
    mouth = g.world_to_cell(30.0, 2.5)
    assert streets.street[mouth] == -1
    assert not stub[mouth]
    assert not streets.stub_ends[mouth]
    # The bar's far end has no stand point; the stub's near part still has one.
    stand = stand_points(passable, t.free, streets, RES, 9.0)
    assert stand[g.world_to_cell(21.0, 17.0)] == -1
    assert stand[g.world_to_cell(30.0, 9.0)] >= 0


def _ring_with_a_stub_to_a_wide_dead_end() -> Territory:
    """5 m streets round a 50 x 20 m block (walled round, 60 x 30 m), with a 4 m wide
    stub cut north into the block from the south street (x 28-32 m, 9 m deep) that ends
    in a T: a 4 m wide bar west to x = 18 m and an 8 m wide dead end east to x = 50 m,
    wider than a 3.5 m turning circle (a car turns round in it), so no stub."""
    return _drawn(
        60.0,
        30.0,
        [
            (5.0, 5.0, 55.0, 25.0, 1.0),
            (28.0, 5.0, 32.0, 14.0, 0.0),
            (18.0, 14.0, 32.0, 18.0, 0.0),
            (32.0, 12.0, 50.0, 20.0, 0.0),
        ],
        background=0.0,
        walled=True,
    )


def test_a_junction_beyond_a_stub_with_a_wide_street_is_no_stub_end() -> None:
    # Both junctions of the T lie beyond the stub from the south street; the one where
    # the wide dead end begins has a street that is no stub, so it is no stub end.
    t = _ring_with_a_stub_to_a_wide_dead_end()
    g = t.grid
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    wide = streets.street[g.world_to_cell(42.0, 16.0)]
    assert wide >= 0
    assert streets.widths[wide] >= 2.0 * 3.5
    assert not streets.stubs[wide]
    assert streets.stubs[streets.street[g.world_to_cell(30.0, 9.0)]]
    opening = g.world_to_cell(35.5, 15.5)
    assert passable[opening]
    assert streets.street[opening] == -1  # a junction of the street graph
    assert not streets.stub_ends[opening]
    assert not stub_cells(passable, streets)[opening]
    # The junction where the stub meets the narrow bar is all stubs: a stub end.
    corner = g.world_to_cell(30.5, 15.0)
    assert streets.street[corner] == -1
    assert streets.stub_ends[corner]


def test_a_ring_of_streets_has_no_stub_ends() -> None:
    t = _ring_with_stubs()
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    assert not streets.stub_ends.any()


def _thin_ring_with_a_stub() -> Territory:
    """5 m streets round a 40 x 3 m block (walled round, 60 x 26 m): from the north
    street a car sees the south street across the block but not the far end of a 4 m
    wide, 6 m deep dead-end stub cut south from the south street's middle (x 28-32 m)."""
    return _drawn(
        60.0,
        26.0,
        [
            (5.0, 9.0, 55.0, 22.0, 0.0),
            (10.0, 14.0, 50.0, 17.0, 1.0),
            (28.0, 3.0, 32.0, 9.0, 0.0),
        ],
        background=1.0,
        walled=False,
    )


def test_a_car_looks_down_a_stub_from_the_junction_instead_of_driving_in() -> None:
    # One car on the north street, 120 s: the stub's far end is the place it most often
    # has out of sight. Without stub_sight its route runs into the stub whenever it goes
    # for that end (measured: on 40 steps of 240); with stub_sight the route ends at the
    # stand point on the south street on every step, the car's centre never enters the
    # stub, and the stub's end is seen all the same.
    t = _thin_ring_with_a_stub()
    g = t.grid
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    stub = stub_cells(passable, streets)
    end = g.world_to_cell(30.0, 3.5)
    assert stub.any()
    assert stand_points(passable, t.free, streets, RES, 9.0)[end] >= 0

    def run(stub_sight: bool) -> tuple[int, int, float, float]:
        inside = [0, 0]
        seen = [0.0]

        def keep(_t: float, team: object, fog: Fog) -> None:
            assert isinstance(team, Car)
            r, c = g.world_to_cell(team.x, team.y)
            inside[0] += int(stub[r, c].sum())
            route = team.routes[0]
            if route is not None:
                er, ec = g.world_to_cell(route[-1, 0], route[-1, 1])
                inside[1] += int(stub[er, ec])
            seen[0] = float(fog.last[end])

        cfg = PatrolConfig(
            model="car",
            duration=120.0,
            turn_penalty=10.0,
            out_of_sight=True,
            stub_sight=stub_sight,
        )
        start = np.array([[30.0, 19.5, 0.0]])
        s = run_patrol(t, cfg, starts=start, seed=0, on_step=keep).summary()
        return inside[0], inside[1], seen[0], float(s["never_seen"])

    centre_in, route_in, seen, never = run(True)
    assert centre_in == 0
    assert route_in == 0
    assert seen > 0.0  # the stub's end was seen from the street
    assert never == 0.0
    _, route_in_before, _, _ = run(False)
    assert route_in_before >= 10


def test_a_car_enters_a_deep_stub_less_with_a_stub_delay_and_still_sees_it() -> None:
    # One car on the ring, 600 s: the deep stub (17 m, beyond its sight from the
    # junction) is backed out of on every visit; with its places pulling as if seen
    # 120 s later the car goes in less often, and every place is still seen.
    t = _ring_with_stubs()
    g = t.grid
    passable = t.passable(1.0)
    deep = stub_cells(passable, one_way(passable, t.clearance, RES, 3.5))
    deep[:, : int(30 / RES)] = False  # the deep stub only (x 40-44 m)

    def run(delay: float) -> tuple[int, float, float]:
        inside = [0]

        def keep(_t: float, team: object, _fog: Fog) -> None:
            assert isinstance(team, Car)
            r, c = g.world_to_cell(team.x, team.y)
            inside[0] += int(deep[r, c].sum())

        cfg = PatrolConfig(
            model="car", duration=600.0, turn_penalty=10.0, out_of_sight=True, stub_delay=delay
        )
        s = run_patrol(t, cfg, starts=np.array([[2.5, 2.5, 0.0]]), seed=0, on_step=keep).summary()
        return inside[0], float(s["dvt"]), float(s["never_seen"])

    steps_in, dvt, _ = run(0.0)
    steps_in_delayed, dvt_delayed, never = run(120.0)
    # Measured: 111 -> 47 steps in the deep stub, DVT 11.5 -> 1.9 %.
    assert steps_in_delayed < 0.7 * steps_in
    assert dvt_delayed < dvt
    assert never == 0.0


def test_stub_delay_is_for_tracking_cars_seeing_through_walls() -> None:
    with pytest.raises(ConfigError, match="stub_delay"):
        PatrolConfig(model="car", stub_delay=-1.0)
    with pytest.raises(ConfigError, match="stub_delay"):
        PatrolConfig(model="car", stub_delay=float("nan"))
    with pytest.raises(ConfigError, match="stub_delay"):
        PatrolConfig(model="car", car_planner="thesis", stub_delay=60.0)
    with pytest.raises(ConfigError, match="stub_delay"):
        PatrolConfig(model="car", line_of_sight=True, stub_delay=60.0)


def test_stub_sight_is_for_tracking_cars_seeing_through_walls() -> None:
    with pytest.raises(ConfigError, match="stub_sight"):
        PatrolConfig(model="car", car_planner="thesis", stub_sight=True)
    with pytest.raises(ConfigError, match="stub_sight"):
        PatrolConfig(stub_sight=True)
    with pytest.raises(ConfigError, match="stub_sight"):
        PatrolConfig(model="car", line_of_sight=True, stub_sight=True)


def test_stub_delay_is_refused_past_the_mission_and_with_too_little_vision() -> None:
    with pytest.raises(ConfigError, match="stub_delay must be at most duration") as e:
        PatrolConfig(model="car", duration=600.0, stub_delay=1e300)
    assert e.value.field == "stub_delay"
    PatrolConfig(model="car", duration=600.0, stub_delay=600.0)
    for kw in ({"stub_sight": True}, {"stub_delay": 120.0}):
        with pytest.raises(ConfigError, match=r"vision must be >= 1\.0 m") as e:
            PatrolConfig(model="car", vision=0.8, **kw)
        assert e.value.field == "vision"
    # Without stubs a short sight is a car's own business.
    PatrolConfig(model="car", vision=0.8)


def test_the_cli_takes_a_stub_delay_from_the_command_line_and_a_settings_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["patrol", "run", "--map", "open-field", "--model", "car", "--robots", "1"]
    main([*base, "--duration", "2", "--stub-delay", "1.5", "-o", str(tmp_path / "a")])
    params = json.loads((tmp_path / "a" / "summary.json").read_text())["params"]
    assert params["stub_delay"] == 1.5
    (tmp_path / "p.yaml").write_text("duration: 2\nstub_delay: 2\n")
    main([*base, "--config", str(tmp_path / "p.yaml"), "-o", str(tmp_path / "b")])
    params = json.loads((tmp_path / "b" / "summary.json").read_text())["params"]
    assert params["stub_delay"] == 2.0
    capsys.readouterr()
    for extra, field in (
        (["--vision", "0.8", "--stub-sight"], "vision"),
        (["--vision", "0.8", "--stub-delay", "1"], "vision"),
        (["--duration", "2", "--stub-delay", "1e300"], "stub-delay"),
    ):
        with pytest.raises(SystemExit) as ex:
            main([*base, *extra, "-o", str(tmp_path / "bad")])
        assert ex.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1
        assert field in err[0]
        assert not (tmp_path / "bad").exists()


def _corridor() -> Territory:
    """A plain 40 x 4 m corridor, walled round: no junction, no dead end off a street."""
    g = Grid(resolution=RES, origin=(0.0, 0.0), shape=(int(6 / RES), int(42 / RES)))
    occ = np.ones(g.shape, np.float32)
    occ[2:-2, 2:-2] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


def test_a_plain_corridor_has_no_stubs_and_a_wide_dead_end_is_none() -> None:
    t = _corridor()
    passable = t.passable(1.0)
    assert passable.sum() > 50
    streets = one_way(passable, t.clearance, RES, 3.5)
    assert not stub_cells(passable, streets).any()
    assert not stub_places(passable, t.free, streets).any()
    assert (stand_points(passable, t.free, streets, RES, 9.0) == -1).all()
    # The ring's 4 m stubs are stubs for a 3.5 m turning radius, not for a 1.5 m one
    # (a car turns round in them): the same bridges, narrower than neither circle.
    ring = _ring_with_stubs()
    passable = ring.passable(1.0)
    tight, loose = (one_way(passable, ring.clearance, RES, r) for r in (3.5, 1.5))
    assert tight.stubs.sum() == 2
    assert (tight.bridges == loose.bridges).all()
    assert not stub_cells(passable, loose).any()


def test_a_narrow_street_between_two_loops_is_a_bridge_but_no_stub() -> None:
    # Two 5 m ring streets (blocks 18 x 18 m) joined by a 4 m street 12 m long: the
    # joining street is a bridge of the street graph with a loop on either side, so a
    # car that drives in drives out the other end.
    t = _drawn(
        70.0,
        30.0,
        [
            (1.0, 1.0, 29.0, 29.0, 0.0),
            (6.0, 6.0, 24.0, 24.0, 1.0),
            (41.0, 1.0, 69.0, 29.0, 0.0),
            (46.0, 6.0, 64.0, 24.0, 1.0),
            (29.0, 13.0, 41.0, 17.0, 0.0),
        ],
        background=1.0,
        walled=False,
    )
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, 3.5)
    middle = t.grid.world_to_cell(35.0, 15.0)
    assert streets.bridges[streets.street[middle]]
    assert not streets.stubs.any()
    assert not stub_cells(passable, streets).any()
