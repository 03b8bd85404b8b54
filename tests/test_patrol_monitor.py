"""The monitor: visit intervals, cycles, interference and idleness on a patrol graph, as
patrolling_sim reports them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import SHARED_DATA
from sonarmap.grid import Grid
from sonarmap.io.rosmap import read_map
from sonarmap.patrol import Fog, PatrolConfig, Territory, run_patrol
from sonarmap.patrol.graph import PatrolGraph
from sonarmap.patrol.monitor import Monitor
from sonarmap.patrol.robots import Team
from sonarmap.patrol.starts import spread_starts

DEPOT = SHARED_DATA / "maps" / "depot.yaml"


def _line_graph(cols: tuple[int, ...] = (5, 15, 25), width: int = 30) -> PatrolGraph:
    """Vertices on one row of 1 m cells, at x = col + 0.5, y = 0.5."""
    g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(1, width))
    cells = np.array([(0, c) for c in cols], dtype=np.int64)
    x, y = g.cell_centres(cells[:, 0], cells[:, 1])
    n = len(cols)
    nb = [np.array([j for j in (i - 1, i + 1) if 0 <= j < n], dtype=np.int64) for i in range(n)]
    ln = [np.abs(x[a] - x[i]).astype(np.float64) for i, a in enumerate(nb)]
    region = np.full(g.shape, -1, dtype=np.int64)
    region[0, list(cols)] = np.arange(n)
    return PatrolGraph(g, cells, np.column_stack([x, y]), nb, ln, 10.0, 2.0, region)


def _walk(mon: Monitor, xs: list[float], t0: float = 0.0, dt: float = 1.0) -> None:
    for k, x in enumerate(xs):
        mon.update(t0 + k * dt, [x], [0.5])


def _there_and_back() -> list[float]:
    """x = 0.5 at t = 0 out to 29.5 at t = 29, then back to 0.5 at t = 58 (1 m/s)."""
    out = [k + 0.5 for k in range(30)]
    return out + out[-2::-1]


def test_one_robot_walking_past_three_vertices() -> None:
    mon = Monitor(_line_graph(), visit_radius=2.0)
    _walk(mon, _there_and_back())
    # Vertex at x = 5.5 is covered while |x - 5.5| <= 2: t in 3..7 out, 51..55 back;
    # 15.5: 13..17, 41..45; 25.5: 23..27, 31..35.
    vert, val = mon.intervals()
    assert vert.tolist() == [0, 1, 2, 2, 1, 0]
    assert val.tolist() == [3.0, 13.0, 23.0, 31.0 - 27.0, 41.0 - 17.0, 51.0 - 7.0]
    s = mon.summary()
    assert s["visits"] == 6
    assert s["avg_idleness"] == pytest.approx(np.mean(val))
    assert s["std_idleness"] == pytest.approx(np.std(val))
    assert s["median_idleness"] == pytest.approx(18.0)
    assert s["worst_idleness_visits"] == 44.0
    # Sampled at the updates: vertex 0 at t = 50 had gone 43 s unseen.
    assert s["worst_instantaneous_idleness"] == 43.0
    assert s["complete_cycles"] == 2
    assert s["last_cycle_time"] == 51.0
    assert s["never_visited_vertices"] == 0
    assert s["interference_events"] == 0
    assert s["monitor_seconds"] == 58.0
    np.testing.assert_array_equal(mon.cycle_times(), [23.0, 51.0])
    np.testing.assert_array_equal(mon.idleness(), [58.0 - 55.0, 58.0 - 45.0, 58.0 - 35.0])
    pv = mon.per_vertex()
    assert pv["visits"].tolist() == [2, 2, 2]
    np.testing.assert_allclose(pv["avg"], [(3 + 44) / 2, (13 + 24) / 2, (23 + 4) / 2])
    np.testing.assert_allclose(pv["median"], pv["avg"])  # two intervals each
    np.testing.assert_allclose(pv["std"], [41 / 2, 11 / 2, 19 / 2])
    np.testing.assert_array_equal(pv["worst"], [44.0, 24.0, 23.0])
    np.testing.assert_array_equal(pv["worst_idleness"], [43.0, 23.0, 23.0])


def test_time_averages_match_a_step_by_step_reference() -> None:
    mon = Monitor(_line_graph(), visit_radius=2.0, start_idleness=5.0)
    xs = _there_and_back()
    vx = np.array([5.5, 15.5, 25.5])
    last = np.full(3, -5.0)
    idle_rows = []
    for k, x in enumerate(xs):
        mon.update(float(k), [x], [0.5])
        last[np.abs(vx - x) <= 2.0] = k
        idle_rows.append(k - last)
    idle = np.array(idle_rows)
    # Each update stands for the step that ends there (the start's weighs nothing).
    ref = idle[1:].mean(axis=0)
    np.testing.assert_allclose(mon.per_vertex()["mean_idleness"], ref)
    s = mon.summary()
    assert s["mean_instantaneous_idleness"] == pytest.approx(idle[1:].mean())
    assert s["mean_max_idleness"] == pytest.approx(idle[1:].max(axis=1).mean())
    assert s["worst_instantaneous_idleness"] == idle.max()
    # The start idleness counts into the first interval of each vertex.
    _, val = mon.intervals()
    assert val[:3].tolist() == [3.0 + 5.0, 13.0 + 5.0, 23.0 + 5.0]


def test_a_vertex_watched_from_the_start_is_visited_there_and_unvisited_ones_reported() -> None:
    mon = Monitor(_line_graph(width=60, cols=(5, 15, 55)), visit_radius=2.0)
    # The robot starts on vertex 0 (just seen at the start: an interval of 0) and walks
    # to vertex 1 and back; vertex 2 is never reached.
    xs = [5.5 + k for k in range(11)] + [15.5 - k for k in range(1, 11)]
    _walk(mon, xs)
    vert, val = mon.intervals()
    assert vert.tolist() == [0, 1, 0]
    assert val.tolist() == [0.0, 8.0, 18.0 - 2.0]
    s = mon.summary()
    assert s["never_visited_vertices"] == 1
    assert s["complete_cycles"] == 0
    assert s["worst_instantaneous_idleness"] == 20.0  # vertex 2: the whole run
    pv = mon.per_vertex()
    assert pv["visits"].tolist() == [2, 1, 0]
    assert math.isnan(pv["avg"][2])
    assert math.isnan(pv["median"][2])
    assert pv["worst_idleness"][2] == 20.0
    rows = mon.per_vertex_csv().splitlines()
    assert rows[0].startswith("vertex,row,col,x,y,degree,visits,avg_interval")
    assert rows[3].split(",")[6:11] == ["0", "", "", "", ""]
    # JSON-ready: plain numbers, NaN where nothing was measured.
    json.dumps(s)


def test_cycles_need_every_vertex_again() -> None:
    mon = Monitor(_line_graph(), visit_radius=2.0)
    # Out to vertex 1 and back twice (vertex 2 never), then all the way out.
    short = [k + 0.5 for k in range(17)] + [16.5 - k for k in range(1, 17)]
    _walk(mon, short + short[1:] + [k + 0.5 for k in range(1, 30)])
    assert mon.summary()["complete_cycles"] == 1
    # The last leg starts at t = 65 and reaches x = 23.5 (vertex 2 in sight) at t = 87.
    np.testing.assert_array_equal(mon.cycle_times(), [87.0])


def test_interference_counts_each_approach_once() -> None:
    g = _line_graph(width=60, cols=(5, 55))
    mon = Monitor(g, visit_radius=2.0, robot_radius=1.0)
    assert mon.interference_distance == 3.0
    # Robot 0 still at x = 20; robot 1 comes to 2 m, stays, leaves to 10 m, comes back.
    gaps = [10, 8, 6, 4, 2, 2, 2.5, 2, 4, 6, 10, 2.9, 2.9, 5, 3.0, 1.0, 3.5]
    for k, d in enumerate(gaps):
        mon.update(float(k), [20.0, 20.0 + d], [0.5, 0.5])
    s = mon.summary()
    assert s["interference_events"] == 3  # from 4 to 2, from 10 to 2.9, from 3.0 to 1
    minutes = (len(gaps) - 1) / 60.0
    assert s["interference_rate_per_robot_min"] == pytest.approx(3 / 2 / minutes)
    # Three robots in a bunch: each close pair counts.
    mon3 = Monitor(g, interference_distance=5.0)
    mon3.update(0.0, [0.0, 30.0, 60.0], [0.5, 0.5, 0.5])
    mon3.update(1.0, [30.0, 31.0, 32.0], [0.5, 0.5, 0.5])
    mon3.update(2.0, [30.0, 31.0, 32.0], [0.5, 0.5, 0.5])
    assert mon3.summary()["interference_events"] == 3


def test_median_and_spread_against_numpy_on_random_walks() -> None:
    rng = np.random.default_rng(7)
    g = _line_graph(cols=tuple(range(2, 60, 6)), width=60)
    mon = Monitor(g, visit_radius=2.5)
    x = np.array([10.0, 40.0, 25.0])
    for k in range(3000):
        x = np.clip(x + rng.normal(0.0, 1.5, 3), 0.0, 59.9)
        mon.update(0.5 * k, x, np.full(3, 0.5))
    vert, val = mon.intervals()
    assert len(val) > 300
    s = mon.summary()
    assert s["median_idleness"] == pytest.approx(np.median(val))
    assert s["std_idleness"] == pytest.approx(np.std(val))
    assert s["avg_idleness"] == pytest.approx(np.mean(val))
    assert s["worst_idleness_visits"] == val.max()
    pv = mon.per_vertex()
    for i in range(len(g)):
        mine = val[vert == i]
        assert pv["visits"][i] == len(mine)
        assert pv["median"][i] == pytest.approx(np.median(mine))
        assert pv["std"][i] == pytest.approx(np.std(mine))
        assert pv["worst"][i] == mine.max()


def test_idleness_series_is_bounded_and_evenly_spaced(tmp_path: Path) -> None:
    mon = Monitor(_line_graph(), visit_radius=2.0, max_rows=100)
    xs = _there_and_back()
    for k in range(5000):
        mon.update(float(k), [xs[k % len(xs)]], [0.5])
    s = mon.idleness_series()
    steps = s["step"].astype(int)
    assert 50 <= len(steps) <= 101
    assert steps[0] == 1
    assert steps[-1] == 5000  # the latest step closes the series
    gaps = np.diff(steps[:-1])
    assert (gaps == gaps[0]).all()
    text = mon.idleness_csv().splitlines()
    assert text[0] == "step,t,mean_idleness,max_idleness"
    assert len(text) == len(steps) + 1
    from sonarmap.plot import save_idleness_plot

    out = save_idleness_plot(s, tmp_path / "idleness.png", title="line")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_state_and_restore_continue_identically() -> None:
    rng = np.random.default_rng(1)
    g = _line_graph(cols=tuple(range(3, 60, 8)), width=60)
    path = np.clip(30.0 + np.cumsum(rng.normal(0.0, 1.0, (800, 2)), axis=0), 0.0, 59.9)
    a = Monitor(g, visit_radius=3.0, max_rows=64)
    for k in range(400):
        a.update(0.5 * k, path[k], [0.5, 0.5])
    saved = json.loads(json.dumps(a.state()))
    b = Monitor(g, visit_radius=3.0, max_rows=64)
    b.restore(saved)
    for k in range(400, 800):
        a.update(0.5 * k, path[k], [0.5, 0.5])
        b.update(0.5 * k, path[k], [0.5, 0.5])
    assert json.dumps(a.summary()) == json.dumps(b.summary())
    assert a.per_vertex_csv() == b.per_vertex_csv()
    assert a.idleness_csv() == b.idleness_csv()
    assert a.summary()["interference_events"] > 0
    with pytest.raises(ValueError, match="vertices"):
        Monitor(_line_graph()).restore(saved)
    with pytest.raises(ValueError, match="set up otherwise"):
        Monitor(g, visit_radius=2.0, max_rows=64).restore(saved)


def test_updates_must_move_forward() -> None:
    mon = Monitor(_line_graph())
    mon.update(0.0, [1.0], [0.5])
    with pytest.raises(ValueError, match="forward"):
        mon.update(0.0, [1.0], [0.5])
    with pytest.raises(ValueError, match="robots"):
        mon.update(1.0, [1.0, 2.0], [0.5, 0.5])


@pytest.mark.skipif(not DEPOT.is_file(), reason="shared data (../shared/data/maps) not present")
def test_vertex_idleness_is_the_fogs_on_a_real_map() -> None:
    t = Territory.from_map(read_map(DEPOT), cell=0.5)
    cfg = PatrolConfig(duration=40.0, vision=4.0, radius=0.5, start_fog=3.0)
    passable = t.passable(cfg.radius)
    starts = spread_starts(2, t, passable, cfg.min_separation, 0)
    r, c = t.grid.world_to_cell(starts[:, 0], starts[:, 1])
    g = PatrolGraph.from_territory(t, passable, cfg.vision, starts=[(int(r[0]), int(c[0]))])
    mon = Monitor(g, start_idleness=cfg.start_fog, robot_radius=cfg.radius)
    mon.update(0.0, starts[:, 0], starts[:, 1])
    worst: list[float] = []

    def on_step(now: float, team: Team, fog: Fog) -> None:
        mon.update(now, team.x, team.y)
        tb = fog.tb_at(g.cells[:, 0], g.cells[:, 1])
        worst.append(float(np.abs(mon.idleness() - tb).max()))

    run_patrol(t, cfg, starts=starts, on_step=on_step)
    assert len(worst) == 80
    assert max(worst) == 0.0
    assert mon.summary()["visits"] > 0


def test_a_run_with_the_graph_reports_and_writes_its_metrics(tmp_path: Path) -> None:
    from sonarmap.cli import main
    from sonarmap.io.rosmap import OccupancyMap, write_map

    g = Grid(resolution=0.5, origin=(0.0, 0.0), shape=(40, 60))  # 30 x 20 m
    occ = np.zeros(g.shape, np.float32)
    occ[[0, -1], :] = occ[:, [0, -1]] = 1.0
    occ[:30, 30] = 1.0  # a wall with a 5 m gap at the top
    write_map(OccupancyMap(g, occ), tmp_path / "hall")
    out = tmp_path / "out"
    main(["patrol", "run", "--map", str(tmp_path / "hall.yaml"), "--robots", "2",
          "--duration", "200", "--vision", "4", "--radius", "0.5", "-o", str(out)])  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    m = s["graph"]
    assert m["graph_vertices"] >= 6
    assert m["graph_connected"]
    assert m["never_visited_vertices"] == 0
    assert m["visits"] >= m["graph_vertices"]
    # Average idleness over visit intervals cannot exceed the worst one, and a vertex's
    # worst interval cannot exceed the run.
    assert 0 < m["avg_idleness"] <= m["worst_idleness_visits"] <= 200.0
    rows = (out / "idleness.csv").read_text().splitlines()
    assert rows[0] == "step,t,mean_idleness,max_idleness"
    assert len(rows) > 10
    vertices = (out / "vertices.csv").read_text().splitlines()
    assert len(vertices) == m["graph_vertices"] + 1
    assert (out / "idleness.png").stat().st_size > 0
    main(["patrol", "run", "--map", str(tmp_path / "hall.yaml"), "--robots", "2",
          "--duration", "20", "--no-graph", "-o", str(tmp_path / "bare")])  # fmt: skip
    assert "graph" not in json.loads((tmp_path / "bare" / "summary.json").read_text())
    assert not (tmp_path / "bare" / "idleness.csv").exists()


def test_fog_knows_its_never_seen_cells() -> None:
    g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(3, 3))
    watched = np.ones(g.shape, dtype=bool)
    watched[0, 0] = False
    fog = Fog(g, watched, start=5.0)
    assert fog.never_seen().sum() == 8
    fog.advance(1.0)
    fog.observe(np.array([2]), np.array([2]), np.zeros((1, 2), dtype=np.int64))
    seen = fog.never_seen()
    assert not seen[2, 2]
    assert not seen[0, 0]
    assert seen.sum() == 7
