"""Graph walkers (CR, HCR, SEBS): which neighbour they choose, and whole runs on a map."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol.graph import PatrolGraph
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory
from sonarmap.patrol.walkers import SEBS_G1, GraphWalkers


def _star() -> PatrolGraph:
    """Vertex 0 in the middle of a row, joined to 1 (left, 2 m) and 2 (right, 6 m)."""
    g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(1, 10))
    cells = np.array([(0, 3), (0, 1), (0, 9)], dtype=np.int64)
    x, y = g.cell_centres(cells[:, 0], cells[:, 1])
    nb = [np.array([1, 2]), np.array([0]), np.array([0])]
    ln = [np.array([2.0, 6.0]), np.array([2.0]), np.array([6.0])]
    region = np.full(g.shape, -1, dtype=np.int64)
    region[0, :3] = 1
    region[0, 3:6] = 0
    region[0, 6:] = 2
    return PatrolGraph(g, cells, np.column_stack([x, y]), nb, ln, 2.0, 1.0, region)


def test_a_walker_starts_for_the_vertex_whose_region_holds_it() -> None:
    w = GraphWalkers(_star(), "cr", [(0, 4), (0, 0)])
    assert w.target.tolist() == [0, 1]
    assert w.goal_cell(1) == (0, 1)
    bad = _star()
    bad.region[0, 0] = -1
    with pytest.raises(ValueError, match="outside"):
        GraphWalkers(bad, "cr", [(0, 0)])
    with pytest.raises(ValueError, match="walker"):
        GraphWalkers(bad, "dtap", [(0, 4)])
    with pytest.raises(ValueError, match="g2"):
        GraphWalkers(_star(), "sebs", [(0, 4)], g2=0.0)


def test_cr_goes_where_it_has_not_been_longest_and_ignores_the_others() -> None:
    w = GraphWalkers(_star(), "cr", [(0, 4)])
    w.reached[0, 1] = 50.0  # it was at vertex 1 lately, never at 2
    # The shared fog says 2 was just seen: CR does not listen.
    assert w.arrive(0, 60.0, np.array([0.0, 0.0, 59.0])) == 2
    assert w.reached[0, 0] == 60.0


def test_hcr_weighs_shared_idleness_against_distance() -> None:
    # Equal idleness: the nearer neighbour wins.
    w = GraphWalkers(_star(), "hcr", [(0, 4)])
    assert w.arrive(0, 60.0, np.array([0.0, 0.0, 0.0])) == 1
    # The far one unseen much longer wins despite its length.
    w = GraphWalkers(_star(), "hcr", [(0, 4)])
    assert w.arrive(0, 60.0, np.array([0.0, 58.0, 0.0])) == 2
    # A walker's state comes back whole.
    again = GraphWalkers(_star(), "hcr", [(0, 4)])
    again.restore(w.state())
    assert again.target.tolist() == w.target.tolist()
    assert np.array_equal(again.reached, w.reached)


def test_sebs_goes_for_the_larger_gain_idleness_over_distance() -> None:
    # Idleness 60 s over 2 m (gain 30) beats 120 s over 6 m (gain 20).
    w = GraphWalkers(_star(), "sebs", [(0, 4)], g2=100.0)
    assert w.arrive(0, 120.0, np.array([0.0, 60.0, 0.0])) == 1
    # 180 s over 6 m (gain 30) beats 40 s over 2 m (gain 20).
    w = GraphWalkers(_star(), "sebs", [(0, 4)], g2=100.0)
    assert w.arrive(0, 180.0, np.array([0.0, 140.0, 0.0])) == 2
    # Both gains past g2: the posteriors saturate at 1 and the larger gain still wins.
    w = GraphWalkers(_star(), "sebs", [(0, 4)], g2=1.0)
    assert w.arrive(0, 180.0, np.array([0.0, 140.0, 0.0])) == 2
    # The default g2: V / (n v) = 3 vertices / (1 robot x 0.5 m/s).
    assert GraphWalkers(_star(), "sebs", [(0, 4)], speed=0.5).g2 == 6.0


def test_sebs_avoids_a_vertex_another_robot_it_hears_intends() -> None:
    # Robot 0 at vertex 0; robot 1 is bound for vertex 1. Gains 30 (vertex 1) and 20
    # (vertex 2), g2 = 100: posteriors 0.1 exp(ln 10 x 0.3) = 0.200 and 0.158; the
    # intention multiplies the first by 2**(2 - 1) / (2**2 - 1) = 2/3: 0.133 < 0.158.
    idle = np.array([0.0, 60.0, 0.0])
    post = [SEBS_G1 * 10 ** (g / 100.0) for g in (30.0, 20.0)]
    assert post[0] * 2 / 3 < post[1] < post[0]
    w = GraphWalkers(_star(), "sebs", [(0, 4), (0, 0)], g2=100.0)
    assert w.target.tolist() == [0, 1]
    assert w.arrive(0, 120.0, idle) == 2
    # Not heard (no network between them): the intention does not count.
    w = GraphWalkers(_star(), "sebs", [(0, 4), (0, 0)], g2=100.0)
    assert w.arrive(0, 120.0, idle, heard=np.array([True, False])) == 1
    # A much larger gain outweighs the intention: 90 s over 2 m (gain 45) against 20.
    w = GraphWalkers(_star(), "sebs", [(0, 4), (0, 0)], g2=100.0)
    assert w.arrive(0, 120.0, np.array([0.0, 30.0, 0.0])) == 1


def test_a_walker_cut_off_from_its_vertex_chooses_another_it_can_reach() -> None:
    w = GraphWalkers(_star(), "cr", [(0, 4)])
    assert w.arrive(0, 10.0, np.zeros(3)) == 1  # both unvisited: the lowest index
    # Vertex 1 is cut off: from vertex 0 (the one it left) it goes to 2 instead.
    assert w.reroute(0, 11.0, np.zeros(3), np.array([True, False, True])) == 2
    # Nothing else within reach: it keeps its target.
    assert w.reroute(0, 12.0, np.zeros(3), np.array([True, False, False])) == 2
    # Where it last was and where it goes come back with its state.
    again = GraphWalkers(_star(), "cr", [(0, 4)])
    again.restore(w.state())
    assert again.left.tolist() == [0]
    assert again.target.tolist() == [2]


def _rooms() -> Territory:
    """20 x 10 m at 0.25 m: two rooms joined by a 2 m door."""
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=(40, 80))
    occ = np.zeros(g.shape, np.float32)
    occ[[0, -1], :] = 1.0
    occ[:, [0, -1]] = 1.0
    occ[:, 40] = 1.0
    occ[16:24, 40] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


@pytest.mark.parametrize("policy", ["cr", "hcr", "sebs"])
def test_walkers_patrol_every_vertex_and_repeat_with_a_seed(policy: str) -> None:
    t = _rooms()
    cfg = PatrolConfig(policy=policy, radius=0.4, speed=1.0, vision=3.0, duration=240.0)
    a = run_patrol(t, cfg, robots=2, seed=3, graph=True)
    s = a.summary()
    assert s["graph"]["never_visited_vertices"] == 0
    assert s["never_seen"] == 0.0
    assert s["graph"]["complete_cycles"] >= 1
    b = run_patrol(t, cfg, robots=2, seed=3, graph=True)
    assert np.array_equal(a.positions, b.positions)
    assert np.array_equal(a.mtb, b.mtb)
