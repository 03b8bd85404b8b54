"""benchmarks.patrol_oneway_mtb: the one-way distances it measures with."""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks.patrol_oneway_mtb import allowed_graph, detour, main, streak
from scipy.sparse.csgraph import dijkstra

from sonarmap.patrol.graph import cell_graph


def test_allowed_graph_keeps_only_the_steps_a_cell_allows() -> None:
    passable = np.ones((1, 5), dtype=bool)
    two, index = cell_graph(passable, 0.5)
    east_only = np.full(passable.shape, 1, dtype=np.uint8)  # bit 0: step (0, +1)
    one = allowed_graph(two, index, east_only)
    d = dijkstra(one, directed=True, indices=[0, 4])
    assert d[0, 4] == pytest.approx(2.0)  # four steps of 0.5 m east
    assert np.isinf(d[1, 0])  # never west
    every = allowed_graph(two, index, np.full(passable.shape, 255, dtype=np.uint8))
    assert (every != two).nnz == 0


def test_detour_is_one_when_every_step_is_allowed_and_grows_when_not() -> None:
    ring = np.ones((5, 5), dtype=bool)
    ring[1:4, 1:4] = False
    two, index = cell_graph(ring, 1.0)
    n = int(ring.sum())
    same = detour(two, two, n)
    assert same["summed"] == pytest.approx(1.0)
    assert same["mean_ratio"] == pytest.approx(1.0)
    assert same["twice_share"] == 0.0
    # Clockwise only round the ring (rows grow downwards): east on the top row,
    # south on the right column, west on the bottom row, north on the left column.
    steps = np.zeros(ring.shape, dtype=np.uint8)
    steps[0, :4] = 1 << 0
    steps[:4, 4] = 1 << 6
    steps[4, 1:] = 1 << 4
    steps[1:, 0] = 1 << 2
    one = allowed_graph(two, index, steps)
    loop = detour(two, one, n)
    assert loop["summed"] > 1.5
    # Close pairs behind each other weigh as much as far ones in the mean of ratios.
    assert loop["mean_ratio"] > loop["summed"]
    assert loop["twice_share"] > 0.0


def test_a_bad_leftover_is_refused_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--leftover=-1"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "--leftover" in err, err


def test_streak_chains_nearby_places_but_the_anchored_stay_does_not_drift() -> None:
    # A place drifting 5 m a sample (each within 9 m of the last, the fourth 15 m from
    # the first), then a jump, then two samples at one place.
    xy = [(0.0, 0.0), (5.0, 0.0), (10.0, 0.0), (15.0, 0.0), (100.0, 0.0), (100.0, 1.0)]
    assert streak(xy, 9.0, 10.0) == (30.0, 0, 3)
    assert streak(xy, 9.0, 10.0, anchored=True) == (10.0, 0, 1)
    assert streak(xy[:1], 9.0, 10.0) == (0.0, 0, 0)
    assert streak([(0.0, 0.0), (50.0, 0.0)], 9.0, 10.0) == (0.0, 0, 0)
