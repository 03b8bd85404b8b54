"""Scores, passages and false openings, on maps built to fool them."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.annotations import Passage
from sonarmap.errors import InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap, read_map, write_map
from sonarmap.metrics import (
    FalseOpening,
    false_openings,
    measure_passage,
    passage_f1,
    passage_open,
    score,
    width_tolerance,
)
from sonarmap.scenarios import Scenario

F32 = npt.NDArray[np.float32]


def wall_cells(scene: Scenario, p: Passage, reach: float) -> npt.NDArray[np.bool_]:
    """Truth wall cells within ``reach`` metres of passage ``p``'s opening."""
    xc, yc = scene.truth.grid.all_centres()
    lo, hi = sorted((p.a[1], p.b[1]))
    near = (np.abs(xc - p.a[0]) <= p.depth / 2 + 1e-9) & (yc > lo - reach) & (yc < hi + reach)
    return near & (scene.truth.occupancy > 0.5)


def erase_beside_gaps(scene: Scenario) -> F32:
    occ = scene.truth.occupancy.copy()
    for p in scene.passages:
        occ[wall_cells(scene, p, 0.3)] = 0.0
    return occ


def punch_holes(scene: Scenario, width: float = 0.2) -> tuple[F32, list[tuple[float, float]]]:
    """A hole of ``width`` through the wall halfway between each pair of passages."""
    occ = scene.truth.occupancy.copy()
    xc, yc = scene.truth.grid.all_centres()
    where = []
    ps = sorted(scene.passages, key=lambda p: (p.a[0], p.a[1]))
    for p, q in itertools.pairwise(ps):
        if p.a[0] != q.a[0]:
            continue  # not the same wall
        y = (max(p.a[1], p.b[1]) + min(q.a[1], q.b[1])) / 2
        hole = (np.abs(xc - p.a[0]) <= p.depth / 2 + 1e-9) & (np.abs(yc - y) < width / 2)
        occ[hole] = 0.0
        where.append((p.a[0], y))
    return occ, where


ADVERSARIAL: dict[str, Callable[[Scenario], F32]] = {
    "all free": lambda s: np.zeros_like(s.truth.occupancy),
    "all occupied": lambda s: np.ones_like(s.truth.occupancy),
    "all unknown": lambda s: np.full_like(s.truth.occupancy, np.nan),
    "all even odds": lambda s: np.full_like(s.truth.occupancy, 0.5),
    "speckle 5 %": lambda s: (np.random.default_rng(1).random(s.truth.grid.shape) < 0.05).astype(
        np.float32
    ),
    "speckle 10 %": lambda s: (np.random.default_rng(2).random(s.truth.grid.shape) < 0.1).astype(
        np.float32
    ),
    "walls erased beside the gaps": erase_beside_gaps,
}


@pytest.mark.parametrize("scene_name", ["doorways", "small_passages"])
@pytest.mark.parametrize("kind", list(ADVERSARIAL))
def test_broken_maps_open_and_detect_nothing(
    kind: str, scene_name: str, request: pytest.FixtureRequest
) -> None:
    scene: Scenario = request.getfixturevalue(scene_name)
    m = OccupancyMap(scene.truth.grid, ADVERSARIAL[kind](scene))
    s = score(scene.truth, m, scene.passages)
    assert s.passages_open == 0
    assert s.passages_detected == 0
    assert not s.passage_f1 > 0  # 0, or NaN
    if kind in ("all free", "speckle 5 %", "speckle 10 %", "walls erased beside the gaps"):
        assert s.false_openings > 0
    if kind in ("all unknown", "all even odds"):
        # Unknown is unknown: neither a wall nor a hole, and no wall found.
        assert s.false_openings == 0
        assert s.f1_all == 0.0
        assert s.unknown == 1.0
    if kind != "walls erased beside the gaps":
        assert not s.f1_all > 0.3


@pytest.mark.parametrize("scene_name", ["doorways", "small_passages"])
def test_the_truth_scores_perfectly(scene_name: str, request: pytest.FixtureRequest) -> None:
    scene: Scenario = request.getfixturevalue(scene_name)
    s = score(scene.truth, scene.truth, scene.passages)
    assert (s.accuracy, s.f1, s.f1_all, s.unknown) == (1.0, 1.0, 1.0, 0.0)
    assert s.passages_open == s.passages_detected == s.passages > 0
    assert s.width_error == pytest.approx(0.0, abs=1e-9)
    assert (s.false_openings, s.false_opening_width, s.passage_f1) == (0, 0.0, 1.0)


def test_holes_in_a_wall_are_false_openings(doorways: Scenario) -> None:
    occ, where = punch_holes(doorways, 0.2)
    assert where
    m = OccupancyMap(doorways.truth.grid, occ)
    found = false_openings(doorways.truth, m, doorways.passages)
    assert len(found) == len(where)
    for hole, (x, y) in zip(sorted(found, key=lambda f: f.centre), where, strict=True):
        assert hole.centre == pytest.approx((x, y), abs=0.05)
        assert hole.width == pytest.approx(0.2, abs=1e-6)
    s = score(doorways.truth, m, doorways.passages)
    assert s.false_openings == len(where)
    assert s.false_opening_width == pytest.approx(0.2 * len(where))
    assert s.passage_f1 == pytest.approx(passage_f1(4, 4, len(where)))
    assert s.passage_f1 < 1.0


def test_small_errors_are_not_false_openings(doorways: Scenario) -> None:
    truth = doorways.truth
    occ = truth.occupancy
    # The whole map one cell off: walls are where they were, within a cell.
    shifted = np.zeros_like(occ)
    shifted[:, 1:] = occ[:, :-1]
    # Only the wall's near face recovered, the rest unknown: not see-through.
    face = np.where(occ > 0.5, np.nan, occ).astype(np.float32)
    face[:, :-1][(occ[:, :-1] < 0.5) & (occ[:, 1:] > 0.5)] = 1.0
    # A door one cell wider on one side: a width error, not a new opening.
    wider = occ.copy()
    p = doorways.passages[0]
    xc, yc = truth.grid.all_centres()
    wider[(np.abs(xc - p.a[0]) < 0.06) & (np.abs(yc - (p.a[1] - 0.025)) < 0.01)] = 0.0
    for occ2 in (shifted, face, wider):
        s = score(truth, OccupancyMap(truth.grid, occ2), doorways.passages)
        assert s.false_openings == 0
        assert s.passages_detected == 4


def test_posts_and_unseen_walls_are_not_openings(small_passages: Scenario) -> None:
    truth = small_passages.truth
    occ = truth.occupancy.copy()
    xc, yc = truth.grid.all_centres()
    for o in small_passages.obstacles:
        near = np.maximum(np.abs(xc - o.centre[0]), np.abs(yc - o.centre[1])) <= o.size / 2
        occ[near] = 0.0  # a missed post: free space goes round it
    s = score(truth, OccupancyMap(truth.grid, occ), small_passages.passages)
    assert s.false_openings == 0
    assert s.passages_detected == len(small_passages.passages)


def test_dotted_walls_are_see_through(small_passages: Scenario) -> None:
    occ = small_passages.truth.occupancy.copy()
    occ[::3] = np.where(occ[::3] > 0.5, 0.0, occ[::3])
    m = OccupancyMap(small_passages.truth.grid, occ)
    s = score(small_passages.truth, m, small_passages.passages)
    assert s.false_openings > 5
    # Without the annotations the gaps join both sides of the wall: no wall to check.
    assert score(small_passages.truth, m).false_openings == 0


def test_passage_needs_its_walls_and_a_free_path(doorways: Scenario) -> None:
    truth = doorways.truth
    grid = truth.grid
    p = doorways.passages[0]
    xc, yc = grid.all_centres()
    occ = truth.occupancy.copy()
    r = measure_passage(truth, truth, p)
    assert r.walls == (1.0, 1.0)
    assert r.crossed
    assert r.open
    assert r.detected
    assert r.width == pytest.approx(p.width)
    # A line of occupied cells across the opening closes it.
    line = (np.abs(xc - (p.a[0] + 0.025)) < 0.01) & (yc > p.a[1]) & (yc < p.b[1])
    closed = occ.copy()
    closed[line] = 1.0
    assert not passage_open(truth, OccupancyMap(grid, closed), p)
    assert all(passage_open(truth, OccupancyMap(grid, closed), q) for q in doorways.passages[1:])
    # A one-cell gap in that line is open again, but far too narrow to be this door.
    one = closed.copy()
    idx = np.flatnonzero(line.ravel())[5]
    one.ravel()[idx] = 0.0
    r = measure_passage(truth, OccupancyMap(grid, one), p)
    assert r.open
    assert not r.detected
    assert r.width <= grid.resolution
    # Unknown across the opening: a path may cross it, but the map never saw it free.
    unknown = occ.copy()
    band = (np.abs(xc - p.a[0]) < 0.1) & (yc > p.a[1]) & (yc < p.b[1])
    unknown[band] = np.nan
    r = measure_passage(truth, OccupancyMap(grid, unknown), p)
    assert not r.crossed
    assert not r.open
    # One wall missing next to jamb b: not open, whatever the path.
    lo = wall_cells(doorways, p, 0.3) & (yc > p.b[1])
    half = occ.copy()
    half[lo] = 0.0
    r = measure_passage(truth, OccupancyMap(grid, half), p)
    assert r.walls[0] == 1.0
    assert r.walls[1] == 0.0
    assert r.crossed
    assert not r.open
    assert not r.detected


def test_detection_needs_the_width_within_tolerance(small_passages: Scenario) -> None:
    truth = small_passages.truth
    grid = truth.grid
    h = grid.resolution
    xc, yc = grid.all_centres()
    for p in small_passages.passages:
        tol = width_tolerance(p.width, h)
        assert tol == max(2 * h, 0.25 * p.width)
        # Narrow the gap symmetrically by k cells on each side.
        for k in (1, 2, 3):
            occ = truth.occupancy.copy()
            lo, hi = sorted((p.a[1], p.b[1]))
            grow = (np.abs(xc - p.a[0]) <= p.depth / 2) & (
                ((yc > lo) & (yc < lo + k * h)) | ((yc < hi) & (yc > hi - k * h))
            )
            occ[grow] = 1.0
            r = measure_passage(truth, OccupancyMap(grid, occ), p)
            want = max(p.width - 2 * k * h, 0.0)
            assert r.width == pytest.approx(want, abs=1e-6)
            assert r.detected == (want > 0 and 2 * k * h <= tol + 1e-9)


def test_annotation_without_a_wall_is_refused() -> None:
    grid = Grid(0.1, (0.0, 0.0), (20, 20))
    truth = OccupancyMap(grid, np.zeros(grid.shape, np.float32))
    p = Passage("nowhere", (0.5, 1.0), (1.5, 1.0), 0.1)
    with pytest.raises(InputError, match=r"'nowhere': the truth has no wall next to jamb a"):
        measure_passage(truth, truth, p)


def test_diagonal_passage() -> None:
    grid = Grid(0.1, (0.0, 0.0), (30, 30))
    occ = np.zeros(grid.shape, dtype=np.float32)
    xc, yc = grid.all_centres()
    wall = np.abs((xc + yc) - 3.0) < 0.15  # a diagonal wall
    gap = np.abs(xc - yc) < 0.4  # an opening around (1.5, 1.5)
    occ[wall & ~gap] = 1.0
    truth = OccupancyMap(grid, occ)
    # Jambs on the wall's mid-line x + y = 3, either side of the opening.
    p = Passage("diag", (1.5 - 0.28, 1.5 + 0.28), (1.5 + 0.28, 1.5 - 0.28), 0.3)
    r = measure_passage(truth, truth, p)
    assert r.open
    assert min(r.walls) == 1.0
    shut = occ.copy()
    shut[wall] = 1.0
    assert not passage_open(truth, OccupancyMap(grid, shut), p)
    assert false_openings(truth, truth, [p]) == []
    # Without the annotation the opening is not a wall, so still no false opening.
    assert false_openings(truth, truth) == []


def test_false_opening_width_on_a_thick_wall() -> None:
    grid = Grid(0.05, (0.0, 0.0), (40, 40))
    occ = np.zeros(grid.shape, dtype=np.float32)
    occ[:, 18:22] = 1.0  # a wall four cells thick splits the map in two
    truth = OccupancyMap(grid, occ)
    holed = occ.copy()
    holed[10:13, 18:22] = 0.0  # three cells wide
    found = false_openings(truth, OccupancyMap(grid, holed))
    assert found == [FalseOpening(found[0].centre, pytest.approx(0.15), 12)]  # type: ignore[arg-type]
    # A wall thicker than MAX_WALL_THICKNESS is never crossed.
    thick = np.zeros(grid.shape, dtype=np.float32)
    thick[:, 5:35] = 1.0
    assert false_openings(OccupancyMap(grid, thick), OccupancyMap(grid, np.zeros_like(thick))) == []


def test_classes_at_known_values_and_the_written_map() -> None:
    grid = Grid(1.0, (0.0, 0.0), (1, 5))
    m = OccupancyMap(grid, np.array([[0.9, 0.5, 0.2, np.nan, 0.51]], np.float32))
    assert m.classes().tolist() == [[1, -1, 0, -1, 1]]


@pytest.mark.parametrize(
    "method",
    ["inverse", "counting", "gradient", pytest.param("stochastic", marks=pytest.mark.slow), "em"],
)
def test_written_pgm_reads_back_as_the_scored_classes(
    method: str, doorways: Scenario, tmp_path: Path
) -> None:
    from sonarmap.mappers import make_mapper

    m = make_mapper(method).fit(doorways.readings, doorways.truth.grid, doorways.rig).result()
    write_map(m, tmp_path / "m")
    # map_server's rules on the image alone (no .npy): p = (255 - v) / 255, occupied
    # above occupied_thresh, free below free_thresh, unknown between.
    back = read_map(tmp_path / "m.yaml", use_npy=False)
    assert np.array_equal(back.classes(), m.classes())
    assert (m.classes() == 1).sum() > 50
    a = score(doorways.truth, m, doorways.passages)
    b = score(doorways.truth, back, doorways.passages)
    assert a.f1 == b.f1
    assert (a.passages_detected, a.false_openings) == (b.passages_detected, b.false_openings)


def test_scores_count_unknown_apart() -> None:
    grid = Grid(1.0, (0.0, 0.0), (1, 4))
    truth = OccupancyMap(grid, np.array([[1, 0, 0, 1]], np.float32))
    m = OccupancyMap(grid, np.array([[0.9, 0.2, 0.5, np.nan]], np.float32))
    s = score(truth, m)
    assert s.unknown == 0.5
    assert (s.precision, s.recall, s.f1) == (1.0, 1.0, 1.0)
    assert s.recall_all == 0.5
    assert s.f1_all == pytest.approx(2 / 3)
    assert math.isnan(score(truth, OccupancyMap(grid, np.full((1, 4), np.nan, np.float32))).f1)


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
    from sonarmap.annotations import load_annotations

    small_passages.write(tmp_path)
    passages, posts = load_annotations(tmp_path / "annotations.yaml")
    assert [p.name for p in passages] == [p.name for p in small_passages.passages]
    assert passages[0].width == pytest.approx(small_passages.passages[0].width)
    assert posts == small_passages.obstacles
    (tmp_path / "bad.yaml").write_text("passages:\n  - {name: x, a: [0, 0]}\n")
    with pytest.raises(InputError, match=r"bad.yaml, field 'passages\[0\]': bad passage"):
        load_annotations(tmp_path / "bad.yaml")
