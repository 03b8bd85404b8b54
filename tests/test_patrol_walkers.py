"""Graph walkers (CR, HCR): which neighbour they choose, and whole runs on a map."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol.graph import PatrolGraph
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory
from sonarmap.patrol.walkers import GraphWalkers


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


def _rooms() -> Territory:
    """20 x 10 m at 0.25 m: two rooms joined by a 2 m door."""
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=(40, 80))
    occ = np.zeros(g.shape, np.float32)
    occ[[0, -1], :] = 1.0
    occ[:, [0, -1]] = 1.0
    occ[:, 40] = 1.0
    occ[16:24, 40] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


@pytest.mark.parametrize("policy", ["cr", "hcr"])
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
