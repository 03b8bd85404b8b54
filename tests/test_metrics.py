"""Scores and passage detection."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.errors import InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.metrics import passage_open, score
from sonarmap.scenarios import Passage, Scenario


def test_truth_scores_perfectly(doorways: Scenario) -> None:
    s = score(doorways.truth, doorways.truth, doorways.passages)
    assert s.accuracy == 1.0
    assert s.f1 == 1.0
    assert s.unknown == 0.0
    assert s.passages_open == s.passages == 4


def test_closed_doorway_is_detected(doorways: Scenario) -> None:
    occ = doorways.truth.occupancy.copy()
    grid = doorways.truth.grid
    p = doorways.passages[0]
    xc, yc = grid.all_centres()
    # A line of cells across the whole opening, one cell beside the jambs' line.
    line = (np.abs(xc - (p.a[0] + 0.075)) < grid.resolution / 2) & (yc > p.a[1]) & (yc < p.b[1])
    occ[line] = 1.0
    closed = OccupancyMap(grid, occ)
    assert not passage_open(closed, p)
    assert all(passage_open(closed, q) for q in doorways.passages[1:])
    # All but one cell of that line: a one-cell gap is still a passage.
    occ[
        np.flatnonzero(line.ravel())[5] // grid.cols, np.flatnonzero(line.ravel())[5] % grid.cols
    ] = 0.0
    assert passage_open(OccupancyMap(grid, occ), p)
    # Unknown cells are not free.
    occ[line] = np.nan
    assert not passage_open(OccupancyMap(grid, occ), p)


def test_diagonal_passage() -> None:
    grid = Grid(0.1, (0.0, 0.0), (30, 30))
    occ = np.zeros(grid.shape, dtype=np.float32)
    xc, yc = grid.all_centres()
    wall = np.abs((xc + yc) - 3.0) < 0.15  # a diagonal wall
    gap = np.abs(xc - yc) < 0.4  # an opening around (1.5, 1.5)
    occ[wall & ~gap] = 1.0
    # Jambs on the wall's mid-line x + y = 3, either side of the opening.
    p = Passage("diag", (1.5 - 0.28, 1.5 + 0.28), (1.5 + 0.28, 1.5 - 0.28), 0.3)
    m = OccupancyMap(grid, occ)
    assert passage_open(m, p)
    occ[wall] = 1.0
    assert not passage_open(OccupancyMap(grid, occ), p)


def test_grids_must_match() -> None:
    a = OccupancyMap(Grid(0.1, (0, 0), (2, 2)), np.zeros((2, 2), np.float32))
    b = OccupancyMap(Grid(0.1, (0, 0), (2, 3)), np.zeros((2, 3), np.float32))
    with pytest.raises(InputError, match="differs from the truth grid"):
        score(a, b)


def test_distances_both_ways() -> None:
    grid = Grid(0.1, (0.0, 0.0), (1, 10))
    truth = OccupancyMap(grid, np.array([[0, 0, 1, 0, 0, 0, 0, 0, 0, 0]], np.float32))
    # One recovered obstacle 0.3 m off, the true one missed; the rest observed free.
    m = OccupancyMap(grid, np.array([[0, 0, 0, 0, 0, 1, 0, 0, 0, np.nan]], np.float32))
    s = score(truth, m)
    assert s.dist_to_truth == pytest.approx(0.3)
    assert s.dist_from_truth == pytest.approx(0.3)
    assert s.recall == 0.0
    assert s.recall_all == 0.0
    assert s.accuracy_all == pytest.approx(0.8)


def test_small_obstacle_size(small_passages: Scenario) -> None:
    from sonarmap.metrics import measure_obstacle

    truth = small_passages.truth
    for o in small_passages.obstacles:
        r = measure_obstacle(truth, o)
        assert r.found
        assert r.size == pytest.approx(o.size)
    # Grow one post by a cell each way: its size error is two cells.
    o = small_passages.obstacles[1]
    occ = truth.occupancy.copy()
    xc, yc = truth.grid.all_centres()
    near = (np.abs(xc - o.centre[0]) <= o.size / 2 + 0.05) & (
        np.abs(yc - o.centre[1]) <= o.size / 2 + 0.05
    )
    occ[near] = 1.0
    grown = measure_obstacle(OccupancyMap(truth.grid, occ), o)
    assert grown.size == pytest.approx(o.size + 0.1)
    empty = OccupancyMap(truth.grid, np.zeros_like(occ))
    assert not measure_obstacle(empty, o).found


def test_annotations_round_trip(tmp_path: Path, small_passages: Scenario) -> None:
    from sonarmap.scenarios import load_annotations

    small_passages.write(tmp_path)
    passages, posts = load_annotations(tmp_path / "annotations.yaml")
    assert [p.name for p in passages] == [p.name for p in small_passages.passages]
    assert passages[0].width == pytest.approx(small_passages.passages[0].width)
    assert posts == small_passages.obstacles
    (tmp_path / "bad.yaml").write_text("passages:\n  - {name: x, a: [0, 0]}\n")
    with pytest.raises(InputError, match=r"bad.yaml, field 'passages\[0\]': bad passage"):
        load_annotations(tmp_path / "bad.yaml")
