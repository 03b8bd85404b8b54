"""Cars that track the wave's path and manoeuvre out of dead ends (patrol.manoeuvre)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from scipy import ndimage

from sonarmap.cli import main as cli_main
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol.fog import Fog, disc_cells, disc_offsets, disc_side
from sonarmap.patrol.giveup import GiveUp
from sonarmap.patrol.manoeuvre import (
    DeadEnds,
    FreshAhead,
    behind_cells,
    carrot,
    clear_goals,
    drop_fresh_behind,
    fresh_behind,
    leads_on,
    plan_manoeuvre,
    route_goals,
    turn_weights,
)
from sonarmap.patrol.maps import street_site, street_territory
from sonarmap.patrol.paths import STEP_UNITS, Wave
from sonarmap.patrol.robots import Car, Holonomic
from sonarmap.patrol.simulation import (
    PatrolConfig,
    halves_discs,
    obstacle_discs,
    run_patrol,
)
from sonarmap.patrol.territory import Territory, move_clear, points_clear


def _corridor_map(res: float = 0.5) -> Territory:
    """A 40 x 30 m room with a 4 m wide dead-end corridor leaving it eastwards."""
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(int(30 / res), int(70 / res)))
    occ = np.ones(g.shape, np.float32)
    occ[:, : int(40 / res)] = 0.0
    occ[int(13 / res) : int(17 / res), : int(65 / res)] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


def _block_site(width: float, west: float, east: float, res: float = 0.5) -> Territory:
    """A ``width`` x 30 m site with one block from x = ``west`` to ``east`` m, 5 m off
    the south and north edges (metres)."""
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(int(30 / res), int(width / res)))
    occ = np.zeros(g.shape, np.float32)
    occ[int(5 / res) : int(25 / res), int(west / res) : int(east / res)] = 1.0
    return Territory.from_map(OccupancyMap(g, occ))


def _ring_map(res: float = 0.5) -> Territory:
    """A 40 x 30 m yard round a 30 x 20 m block: a ring of 5 m streets."""
    return _block_site(40.0, 5.0, 35.0, res)


def _numpy_behind_cells(
    x: float, y: float, heading: float, grid: Grid, radius: float, gap: float
) -> npt.NDArray[np.intp]:
    """The former ``behind_cells`` (main 74e644f), in numpy over the square of cells."""
    k = math.ceil(radius / grid.resolution)
    r0, c0 = (int(v) for v in grid.world_to_cell(x, y))
    dr, dc = np.mgrid[-k : k + 1, -k : k + 1]
    rr, cc = (r0 + dr).ravel(), (c0 + dc).ravel()
    px, py = grid.cell_centres(rr, cc)
    dx, dy = px - x, py - y
    along = dx * math.cos(heading) + dy * math.sin(heading)
    keep = (np.hypot(dx, dy) <= radius) & (along < -gap) & grid.contains(rr, cc)
    keep &= (rr != r0) | (cc != c0)
    return np.column_stack([rr[keep], cc[keep]]).astype(np.intp)


def test_behind_cells_are_the_former_numpy_cells() -> None:
    # Cars anywhere (off the map too), at cell centres heading along the axes and the
    # diagonals (cells exactly on the radius or the gap line), several cell sizes,
    # radii and gaps: the same cells in the same order as the numpy form.
    rng = np.random.default_rng(31)
    for k in range(3000):
        res = float(rng.choice([0.1, 0.05, 0.25, 0.5]))
        shape = (int(rng.integers(5, 120)), int(rng.integers(5, 120)))
        g = Grid(resolution=res, origin=(float(rng.uniform(-5, 5)), 1.0), shape=shape)
        if k % 3 == 0:
            cx, cy = g.cell_centres([int(rng.integers(0, shape[0]))], [0])
            x, y = float(cx[0]) + res * int(rng.integers(0, shape[1])), float(cy[0])
            heading = float(rng.choice([0.0, math.pi / 2, math.pi, -math.pi / 2, math.pi / 4]))
        else:
            x = g.origin[0] + float(rng.uniform(-2.0, shape[1] * res + 2.0))
            y = 1.0 + float(rng.uniform(-2.0, shape[0] * res + 2.0))
            heading = float(rng.uniform(-4.0, 4.0))
        radius = float(rng.choice([4.0, 1.0, 0.5]))
        gap = float(rng.choice([0.5, 0.0, 0.25]))
        got = behind_cells(x, y, heading, g, radius=radius, gap=gap)
        want = _numpy_behind_cells(x, y, heading, g, radius, gap)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_behind_cells_lie_behind_the_car_within_the_radius() -> None:
    t = _corridor_map()
    back = behind_cells(20.2, 15.1, 0.0, t.grid, radius=4.0)
    px, py = t.grid.cell_centres(back[:, 0], back[:, 1])
    assert len(back) > 20
    assert (px - 20.2 < -0.5).all()
    assert (np.hypot(px - 20.2, py - 15.1) <= 4.0).all()
    own = t.grid.world_to_cell(20.2, 15.1)
    assert not ((back[:, 0] == own[0]) & (back[:, 1] == own[1])).any()


def test_the_way_ahead_leads_on_unless_it_is_a_dead_end() -> None:
    t = _corridor_map()
    passable = t.passable(1.0)
    r0, c0 = t.grid.world_to_cell(55.0, 15.0)
    start = (int(r0), int(c0))
    assert passable[start]
    # Facing the corridor's end: ahead is a dead end; facing the room: it leads on.
    assert not leads_on(passable, behind_cells(55.0, 15.0, 0.0, t.grid), start)
    assert leads_on(passable, behind_cells(55.0, 15.0, math.pi, t.grid), start)


def _leads_on_by_labels(
    passable: npt.NDArray[np.bool_],
    closed: npt.NDArray[np.intp],
    start: tuple[int, int],
    share: float = 0.5,
) -> bool:
    # The former leads_on, which labelled the whole map: the reference the flood fill
    # must agree with.
    if not len(closed):
        return True
    open_ = passable.copy()
    open_[closed[:, 0], closed[:, 1]] = False
    open_[start] = True
    labels, _ = ndimage.label(open_, structure=np.ones((3, 3), dtype=bool))
    mine = labels[start]
    return bool(np.count_nonzero(labels == mine) >= share * np.count_nonzero(passable))


def test_leads_on_answers_as_labelling_the_whole_map_does() -> None:
    rng = np.random.default_rng(36)
    answers = set()
    for trial in range(400):
        rows, cols = int(rng.integers(1, 30)), int(rng.integers(1, 30))
        passable = rng.random((rows, cols)) < rng.uniform(0.3, 0.95)
        k = int(rng.integers(0, rows * cols // 2 + 2))
        closed = np.column_stack([rng.integers(0, rows, k), rng.integers(0, cols, k)]).astype(
            np.intp
        )
        start = (int(rng.integers(0, rows)), int(rng.integers(0, cols)))
        if trial % 3 == 0 and len(closed):
            closed[0] = start  # the start stays open even when closed
        share = float(rng.choice([0.0, 0.1, 0.5, 0.9, 1.0]))
        want = _leads_on_by_labels(passable, closed, start, share)
        assert leads_on(passable, closed, start, share) == want
        ends = DeadEnds(passable)
        assert ends.leads_on(closed, start, share) == want
        assert ends.leads_on(closed, start, share) == want  # its scratch left clean
        answers.add(want)
    assert answers == {True, False}


def test_the_dead_end_test_reads_indices_as_numpy_does() -> None:
    rng = np.random.default_rng(7)
    passable = rng.random((20, 37)) < 0.7
    ends = DeadEnds(passable)
    rows, cols = passable.shape
    # Negative rows and columns count from the end, in the closed cells and the start.
    for _ in range(50):
        k = int(rng.integers(1, 60))
        closed = np.column_stack(
            [rng.integers(-rows, rows, k), rng.integers(-cols, cols, k)]
        ).astype(np.intp)
        start = (int(rng.integers(-rows, rows)), int(rng.integers(-cols, cols)))
        want = _leads_on_by_labels(passable, closed, start)
        assert ends.leads_on(closed, start) == want
        assert leads_on(passable, closed, start, n_passable=12345) == want  # ignored
    # Outside the map: IndexError, as numpy's indexing raised, and the scratch left clean.
    inside = np.array([[3, 4]], dtype=np.intp)
    for cell in ([rows, 0], [0, cols], [-rows - 1, 0], [0, -cols - 1], [rows + 40, cols + 9]):
        with pytest.raises(IndexError, match="outside the 20 x 37 map"):
            ends.leads_on(np.array([[1, 1], cell], dtype=np.intp), (5, 5))
        # The first cell off the map is named, before a start off it too.
        two = np.array([[1, 1], cell, [rows + 1, 1]], dtype=np.intp)
        with pytest.raises(IndexError, match=rf"cell \({cell[0]}, {cell[1]}\) is outside"):
            ends.leads_on(two, (5, 5))
        with pytest.raises(IndexError, match=rf"cell \({cell[0]}, {cell[1]}\) is outside"):
            ends.leads_on(two, (rows, 5))
    for start in ((rows, 2), (2, cols), (-rows - 1, 2), (2, -cols - 1)):
        with pytest.raises(IndexError, match="outside"):
            ends.leads_on(inside, start)
        with pytest.raises(IndexError, match="outside"):
            leads_on(passable, inside, start)
    assert ends.leads_on(inside, (5, 5)) == _leads_on_by_labels(passable, inside, (5, 5))


def test_the_dead_end_test_refuses_closed_cells_not_k_by_2() -> None:
    passable = np.ones((20, 37), dtype=bool)
    ends = DeadEnds(passable)
    for closed in (
        np.array([[3], [4]], dtype=np.intp),
        np.array([3, 4], dtype=np.intp),
        np.empty(0, dtype=np.intp),
        np.zeros((2, 3), dtype=np.intp),
        np.zeros((1, 2, 2), dtype=np.intp),
    ):
        shape = re.escape(str(closed.shape))
        with pytest.raises(ValueError, match=rf"shape \(K, 2\).*got {shape}"):
            ends.leads_on(closed, (5, 5))
        with pytest.raises(ValueError, match=rf"shape \(K, 2\).*got {shape}"):
            leads_on(passable, closed, (5, 5))
    assert ends.leads_on(np.empty((0, 2), dtype=np.intp), (5, 5))


def test_one_dead_end_test_answers_many_questions_of_a_map_as_labelling_does() -> None:
    # Corridors and rooms, as the cars' maps are, and the cars' closed sets: a half disc
    # behind a cell, sometimes with discs round other cars; one DeadEnds for every call.
    rng = np.random.default_rng(3636)
    for _ in range(6):
        rows, cols = int(rng.integers(20, 60)), int(rng.integers(20, 60))
        passable = np.zeros((rows, cols), dtype=bool)
        for _ in range(int(rng.integers(2, 8))):  # corridors
            if rng.random() < 0.5:
                r = int(rng.integers(0, rows - 2))
                passable[r : r + int(rng.integers(1, 4)), int(rng.integers(0, cols)) :] = True
            else:
                c = int(rng.integers(0, cols - 2))
                passable[: int(rng.integers(1, rows)), c : c + int(rng.integers(1, 4))] = True
        passable[rng.random((rows, cols)) < 0.03] = False  # speckle
        ends = DeadEnds(passable)
        # Blocks smaller than these maps too: floods through many blocks' pieces.
        small = _SmallBlocks(passable)
        rr, cc = np.nonzero(passable)
        dr, dc = np.mgrid[-4:5, -4:5]
        for _ in range(60):
            k = int(rng.integers(0, len(rr)))
            start = (int(rr[k]), int(cc[k]))
            h = rng.uniform(-math.pi, math.pi)
            half = (dr * math.cos(h) + dc * math.sin(h) < 0) & (dr**2 + dc**2 <= 16)
            closed = np.column_stack([dr[half] + start[0], dc[half] + start[1]])
            if rng.random() < 0.3:
                other = (int(rng.integers(0, rows)), int(rng.integers(0, cols)))
                closed = np.concatenate([closed, np.column_stack([dr.ravel(), dc.ravel()]) + other])
            inside = (closed[:, 0] >= 0) & (closed[:, 0] < rows)
            inside &= (closed[:, 1] >= 0) & (closed[:, 1] < cols)
            closed = closed[inside].astype(np.intp)
            for share in (0.05, 0.3, 0.5):
                want = _leads_on_by_labels(passable, closed, start, share)
                assert ends.leads_on(closed, start, share) == want
                assert small.leads_on(closed, start, share) == want
        _assert_clean(ends)
        _assert_clean(small)


class _SmallBlocks(DeadEnds):
    BLOCK = 4


def test_the_dead_end_tests_blocks_are_a_power_of_two() -> None:
    class Odd(DeadEnds):
        BLOCK = 12

    with pytest.raises(ValueError, match="power of two"):
        Odd(np.ones((10, 10), dtype=bool))


def _assert_clean(ends: DeadEnds) -> None:
    """The dead-end test left its scratch as it found it."""
    assert not ends.mark.any()
    assert not ends.seen.any()
    assert not ends.touched.any()


def _plus_map(south: bool = True) -> npt.NDArray[np.bool_]:
    """A plus of 3-cell corridors: arms of 10 (west), 20 (east), 30 (north) and 40
    (south) cells from a 3 x 3 centre at rows and columns 40-42: 9 + 3 x 100 cells;
    without the ``south`` arm a T of 189."""
    passable = np.zeros((83, 83), dtype=bool)
    passable[40:43, 30:63] = True  # west 10, centre 3, east 20
    passable[10 : 83 if south else 43, 40:43] = True  # north 30, centre 3, south 40
    return passable


def _cut(rows: range, cols: range) -> npt.NDArray[np.intp]:
    return np.array([(r, c) for r in rows for c in cols], dtype=np.intp)


# The centre and a cell of each arm round it: 8-connected, the arms touch diagonally.
CENTRE = _cut(range(39, 44), range(39, 44))


@pytest.mark.parametrize(
    ("south", "closed", "start", "piece"),
    [
        # None: the closed cells cut nothing off (the end of the west arm).
        (True, _cut(range(40, 43), range(30, 31)), (41, 41), 306),
        # In two: the west arm cut off at its root; the car in it, or in the rest.
        (True, _cut(range(40, 43), range(39, 40)), (41, 35), 27),
        (True, _cut(range(40, 43), range(39, 40)), (41, 50), 279),
        # In three (the T's centre closed) and four (the plus's): the car in an arm.
        (False, CENTRE, (41, 50), 57),
        (False, CENTRE, (30, 41), 87),
        (False, CENTRE, (41, 35), 27),
        (True, CENTRE, (41, 50), 57),
        (True, CENTRE, (60, 41), 117),
        # The car on the closed set's border, and inside it (it stays open: alone, or
        # joined to the cells west of the closed ones).
        (True, _cut(range(40, 43), range(36, 39)), (41, 39), 282),
        (True, _cut(range(40, 43), range(36, 39)), (41, 37), 1),
        (True, _cut(range(40, 43), range(36, 39)), (41, 36), 19),
    ],
)
def test_dead_end_pieces_are_counted_exactly(
    south: bool, closed: npt.NDArray[np.intp], start: tuple[int, int], piece: int
) -> None:
    passable = _plus_map(south)
    n = int(passable.sum())
    assert n == (309 if south else 189)
    ends = DeadEnds(passable)
    # The start's piece holds ``piece`` cells: at the share it leads on (the largest
    # share of n at most ``piece`` cells in float64, ``piece`` exactly when there is
    # one), just above it it does not.
    at = _share(piece, n)
    above = float(np.nextafter(at, 1.0))
    assert at * n <= piece < above * n
    assert ends.leads_on(closed, start, at)
    assert not ends.leads_on(closed, start, above)
    assert _leads_on_by_labels(passable, closed, start, at)
    assert not _leads_on_by_labels(passable, closed, start, above)
    _assert_clean(ends)


def _share(cells: int, n: int) -> float:
    """The largest float64 share whose product with ``n`` is at most ``cells``."""
    share = cells / n
    while share * n > cells:
        share = float(np.nextafter(share, 0.0))
    while float(np.nextafter(share, 1.0)) * n <= cells:
        share = float(np.nextafter(share, 1.0))
    return share


def test_dead_end_test_from_a_cell_off_the_passable_ones() -> None:
    # A start off ``passable`` joins what touches it; a second component elsewhere.
    passable = _plus_map()
    passable[0:5, 0:5] = True  # 25 cells apart
    passable[41, 28] = True  # joined to the west arm only through the start (41, 29)
    assert not passable[41, 29]
    ends = DeadEnds(passable)
    n = int(passable.sum())
    closed = _cut(range(40, 43), range(39, 40))
    for share in (1 / n, 2 / n, 29 / n, 30 / n, 0.5):
        want = _leads_on_by_labels(passable, closed, (41, 29), share)
        assert ends.leads_on(closed, (41, 29), share) == want
    # The start, (41, 28) and the 27 cells of the west arm west of the closed ones.
    assert ends.leads_on(closed, (41, 29), _share(29, n))
    assert not ends.leads_on(closed, (41, 29), float(np.nextafter(_share(29, n), 1.0)))
    assert ends.leads_on(closed, (2, 2), _share(25, n))
    assert not ends.leads_on(closed, (2, 2), float(np.nextafter(_share(25, n), 1.0)))
    _assert_clean(ends)


def test_a_forward_wave_reaches_a_place_behind_around_the_block() -> None:
    t = _ring_map()
    passable = t.passable(1.0)
    g = t.grid
    start = (int(g.world_to_cell(20.0, 2.5)[0]), int(g.world_to_cell(20.0, 2.5)[1]))
    place = (int(g.world_to_cell(12.0, 2.5)[0]), int(g.world_to_cell(12.0, 2.5)[1]))
    target = np.zeros(passable.shape, dtype=bool)
    target[place] = True
    wave = Wave(passable.shape)
    wave(passable, start, g.resolution, target)
    direct = float(wave.dist[place])
    assert STEP_UNITS[int(wave.first[place]), 0] < 0  # straight back west
    back = behind_cells(20.0, 2.5, 0.0, g)  # facing east
    assert leads_on(passable, back, start)
    wave(passable, start, g.resolution, target, None, back)
    assert STEP_UNITS[int(wave.first[place]), 0] > 0  # leaves east, round the block
    assert float(wave.dist[place]) > direct + 60.0


def test_car_planner_finds_a_reversing_manoeuvre_in_a_dead_end() -> None:
    t = _corridor_map()
    passable = t.passable(1.0)
    route = np.column_stack([np.linspace(62.0, 30.0, 65), np.full(65, 15.0)])
    plan = plan_manoeuvre((62.0, 15.0, 0.0), route_goals(route), passable, t.grid, 3.5)
    assert plan is not None
    assert plan.reverses
    assert plan.arcs
    assert all(abs(k) <= 1 / 3.5 + 1e-12 for _, k in plan.arcs)
    # Nothing clear: no manoeuvre.
    assert (
        plan_manoeuvre((62.0, 15.0, 0.0), route_goals(route), passable & False, t.grid, 3.5) is None
    )


def test_clear_goals_lie_on_passable_cells_within_reach_and_clear_of_the_others() -> None:
    t = _crossroads()
    passable = t.passable(1.0)
    away = np.array([[16.15, 16.06]])
    goals = clear_goals(13.87, 16.07, away, passable, t.grid, clear=5.5, reach=6.0)
    assert len(goals) > 0
    assert np.isnan(goals[:, 2]).all()
    r, c = t.grid.world_to_cell(goals[:, 0], goals[:, 1])
    assert passable[r, c].all()
    assert (np.hypot(goals[:, 0] - 13.87, goals[:, 1] - 16.07) <= 6.0).all()
    assert (np.hypot(goals[:, 0] - 16.15, goals[:, 1] - 16.06) >= 5.5).all()
    assert clear_goals(13.87, 16.07, away, passable, t.grid, clear=20.0).shape == (0, 3)


def test_carrot_lies_lookahead_along_the_route() -> None:
    route = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 4.0]])
    assert carrot(route, 0.0, 0.0, 3.0) == pytest.approx((2.0, 1.0))
    assert carrot(route, 0.0, 0.0, 50.0) == pytest.approx((2.0, 4.0))
    goals = route_goals(np.array([[0.0, 0.0], [1.0, 0.0]]))
    assert goals.shape == (1, 3)
    assert math.isnan(goals[0, 2])


def test_a_tracking_car_gets_out_of_a_dead_end_street_within_a_minute() -> None:
    t = _corridor_map()
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    # Near the end of the corridor facing its end wall; the path leads back west.
    car = Car(
        np.array([62.0]), np.array([15.0]), np.array([0.0]), clearance=t.clearance, planner="track"
    )
    escaped = False
    for _ in range(120):  # 60 s at 0.5 s a step
        x0, y0 = float(car.x[0]), float(car.y[0])
        xs = np.linspace(x0, 20.0, max(2, int((x0 - 20.0) / 0.5)))
        route = np.column_stack([xs, np.full(len(xs), 15.0)])
        route[0] = x0, y0
        car.routes[0] = route
        p = carrot(route, x0, y0, 3.0)
        d = (p[0] - x0, p[1] - y0)
        n = math.hypot(*d)
        car.step([(d[0] / n, d[1] / n)], passable, t.grid, 0.5, rng, [p])
        assert move_clear(x0, y0, float(car.x[0]), float(car.y[0]), passable, t.grid)
        if car.x[0] < 38.0:
            escaped = True
            break
    assert escaped, "the car never left the dead end"
    assert abs(math.remainder(car.heading[0] - math.pi, 2 * math.pi)) < 0.6  # facing west


@pytest.mark.slow
def test_street_sites_are_seeded_and_tracking_cars_never_drive_through_walls() -> None:
    assert street_site(3).ops == street_site(3).ops
    assert street_site(3).ops != street_site(4).ops
    t = street_territory(0)
    passable = t.passable(1.0)
    last: dict[int, tuple[float, float]] = {}

    def check(time: float, team: object, fog: Fog) -> None:
        assert isinstance(team, Car)
        for i in range(len(team)):
            x, y = float(team.x[i]), float(team.y[i])
            r, c = t.grid.world_to_cell(x, y)
            assert passable[int(r), int(c)]
            if i in last:
                # A step is at most 2.1 m (15 km/h): the chord stays within the arc's
                # sweep to within a cell, so a clear chord means no wall crossed.
                assert move_clear(*last[i], x, y, passable, t.grid)
            last[i] = (x, y)

    cfg = PatrolConfig(model="car", refine=True, duration=90.0)
    res = run_patrol(t, cfg, robots=2, seed=0, on_step=check)
    assert len(res.t) == 180


@pytest.mark.slow
def test_tracking_car_dvt_on_a_training_street_site_is_low() -> None:
    # Measured 2026-12-06 on training site 0, 1 car, 600 s, refinement, seed 0: DVT
    # 5.8 % with the forward wave, 12.8 % without (the thesis's planner on the held-out
    # sites: 73-85 %); 9 still fails without the forward wave, which is why this test
    # turns it on (it is off by default). Since the cars-unstuck work it gives 8.92 %:
    # the margin went to the manoeuvre search's finer arc check alone (64 points a metre
    # instead of 16: 5.75 -> 8.92 % with the old +x start heading; the stall watch never
    # fires here); the new start heading alone gives 11.00 % (16 points), both 8.92 %
    # (benchmarks.patrol_car_margin, 2026-12-07 cars-unstuck page). One car's 600 s
    # moves by 3-5 points with any small change of its path; the bar stays 9.
    t = street_territory(0)
    track = run_patrol(
        t,
        PatrolConfig(model="car", refine=True, duration=600.0, forward_wave=True),
        robots=1,
        seed=0,
    ).summary()
    assert track["dvt"] < 9.0


def test_cars_give_up_a_never_seen_place_at_the_limit_and_take_it_back_once_seen() -> None:
    g = Grid(resolution=0.5, origin=(0.0, 0.0), shape=(20, 20))
    watched = np.ones(g.shape, dtype=bool)
    fog = Fog(g, watched)
    fog.advance(1.0)  # at time 0 a place seen is a place never seen
    fog.observe(np.array([2]), np.array([2]), disc_offsets(1.0, 0.5))  # seen: 2 m round
    quit_ = GiveUp(watched, 2, disc_offsets(1.0, 0.5))
    assert quit_.targets(fog) is watched
    assert not quit_.tried((2, 2), fog)  # seen places are never given up
    assert not quit_.tried((2, 2), fog)
    assert not quit_.tried((15, 15), fog)
    assert quit_.targets(fog) is watched
    assert quit_.tried((15, 15), fog)  # the second try on the way to it
    targets = quit_.targets(fog)
    assert not targets[15, 15]
    assert not targets[15, 17]  # never seen, within 1 m
    assert targets[15, 18]  # 1.5 m off
    assert int((~targets).sum()) == len(disc_offsets(1.0, 0.5))
    fog.advance(1.0)
    fog.observe(np.array([15]), np.array([17]), disc_offsets(0.0, 0.5))
    targets = quit_.targets(fog)
    assert targets[15, 17]  # seen at last: a target again
    assert not targets[15, 15]
    assert targets is quit_.targets(fog)  # unchanged: the same array


def test_turn_weights_damp_only_the_steps_behind_the_heading() -> None:
    w = turn_weights(0.0, 1.75, 10.0)
    angle = np.degrees(np.arctan2(STEP_UNITS[:, 1], STEP_UNITS[:, 0]))
    behind = np.abs(angle) > np.degrees(1.75)
    assert behind.sum() == 3  # 135, 180 and -135 deg off a car heading east
    assert np.all(w[behind] == pytest.approx(math.exp(-10.0)))
    assert np.all(w[~behind] == 1.0)
    # Heading north: the steps south are the ones behind.
    w = turn_weights(math.pi / 2, 1.75, 10.0)
    assert np.all((w < 1) == (STEP_UNITS[:, 1] < -0.5))
    assert np.all(turn_weights(1.0, 1.75, 0.0) == 1.0)


@pytest.mark.slow
def test_a_tracking_car_does_not_swing_at_a_one_cell_street_for_the_rest_of_the_run() -> None:
    # Training site 0, 3 cars, 600 s, seed 0, places in sight not pulling, no turn
    # penalty: a car at the mouth of a street whose passable cells are one wide (x
    # 16.5-17 m) swung between two poses from t = 410 s on, one step of the thesis's
    # escape and one of pursuit (333 of its 1,200 steps on the fallback); run until
    # aligned with the street, the fallback takes 10.
    t = street_territory(0)
    last: list[Car] = []

    def keep(_t: float, team: object, _fog: Fog) -> None:
        assert isinstance(team, Car)
        last[:] = [team]

    cfg = PatrolConfig(
        model="car",
        refine=True,
        crowding="obstacles",
        duration=600.0,
        turn_penalty=0.0,
        out_of_sight=True,
    )
    run_patrol(t, cfg, robots=3, seed=0, on_step=keep)
    assert int(last[0].escape_causes["fallback"].max()) < 60


@pytest.mark.xfail(strict=True, reason="a car beside a one-cell street's mouth finds no way in")
def test_a_tracking_car_beside_a_one_cell_street_gets_in() -> None:
    # The limit: aligned but 0.6 m beside the street's one passable column, the car
    # needs to back into the cross street and come down again, and the hybrid A*
    # (1.37 m arcs, 3,000 expansions) finds no such manoeuvre; it swings on.
    t = street_territory(0)
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    car = Car(
        np.array([17.22]),
        np.array([67.54]),
        np.array([math.radians(-111.0)]),
        clearance=t.clearance,
        planner="track",
    )
    lowest = 67.54
    for _ in range(120):  # 60 s at 0.5 s a step
        x0, y0 = float(car.x[0]), float(car.y[0])
        ys = np.arange(min(y0, 67.25), 56.0, -0.5)
        route = np.column_stack([np.full(len(ys) + 1, 16.75), np.concatenate([[y0], ys])])
        route[0] = x0, y0
        car.routes[0] = route
        p = carrot(route, x0, y0, 3.0)
        d = (p[0] - x0, p[1] - y0)
        n = math.hypot(*d)
        car.step([(d[0] / n, d[1] / n)], passable, t.grid, 0.5, rng, [p])
        r, c = t.grid.world_to_cell(float(car.x[0]), float(car.y[0]))
        assert passable[int(r), int(c)]
        lowest = min(lowest, float(car.y[0]))
    assert lowest < 60.0, f"the car got no further than y = {lowest:.1f} m"


@pytest.mark.slow
def test_tracking_cars_do_not_manoeuvre_for_places_in_sight() -> None:
    # Training site 0, 3 cars, 1,200 s, seed 0: of the 162 reversing manoeuvres for a
    # path behind, 114 went for a place under 1 m from the car (one it was looking
    # at) while every place pulled; 1 of 43 with only places out of sight pulling
    # (300 s here, as below).
    t = street_territory(0)

    def near_turns(out_of_sight: bool) -> tuple[int, int]:
        seen: dict[int, int] = {}
        counts = [0, 0]

        def watch(_t: float, team: object, _fog: Fog) -> None:
            assert isinstance(team, Car)
            for i, plan in enumerate(team.plans):
                if plan is None or seen.get(i) == id(plan):
                    continue
                seen[i] = id(plan)
                route = team.routes[i]
                if plan.reverses and route is not None:
                    counts[0] += 1
                    length = float(np.hypot(*np.diff(route, axis=0).T).sum())
                    counts[1] += length < 1.0

        cfg = PatrolConfig(
            model="car",
            refine=True,
            crowding="obstacles",
            duration=300.0,
            turn_penalty=0.0,
            out_of_sight=out_of_sight,
            # Measured before turn_time and round_block: the pulls alone.
            turn_time=0.0,
            round_block=0.0,
        )
        run_patrol(t, cfg, robots=3, seed=0, on_step=watch)
        return counts[0], counts[1]

    _, every_near = near_turns(False)
    _, out_near = near_turns(True)
    assert every_near >= 4  # measured 6 of 39
    assert out_near <= 1


def _yard_and_block_map(res: float = 0.5) -> Territory:
    """A 60 x 30 m site: a 25 m yard on the west, then a 30 x 20 m block with 5 m
    streets round it (narrower than a car's 7 m turning circle)."""
    return _block_site(60.0, 25.0, 55.0, res)


def test_a_car_drives_round_the_block_rather_than_turn_round_when_allowed() -> None:
    # A car in the south street facing east, the unseen yard 7 m behind it: it turns
    # round on the 5 m street (reversing), or with round_block drives on, east and
    # up the east street, round the block.
    t = _yard_and_block_map()

    def run(round_block: float) -> tuple[int, float, float]:
        track: list[tuple[float, float]] = []
        reverse = [0]

        def keep(_t: float, team: object, _fog: Fog) -> None:
            assert isinstance(team, Car)
            track.append((float(team.x[0]), float(team.y[0])))
            reverse[0] = int(sum(int(v.sum()) for v in team.escape_causes.values()))

        cfg = PatrolConfig(
            model="car",
            duration=40.0,
            vision=5.0,
            turn_penalty=0.0,
            out_of_sight=True,
            round_block=round_block,
        )
        run_patrol(t, cfg, starts=np.array([[32.0, 2.5, 0.0]]), seed=0, on_step=keep)
        xs = [x for x, _ in track]
        return reverse[0], min(xs), max(xs)

    turned, west, _ = run(0.0)
    looped, _, east = run(150.0)
    assert west < 20.0  # turned round towards the yard (measured: 9.9 m)
    assert turned >= 10  # steps reversing (measured: 20)
    assert east > 54.0  # on round the block (measured: 56.8 m)
    assert looped <= turned // 2  # the first step's turn only (measured: 4)


def test_fresh_behind_is_what_was_just_seen_behind_the_car() -> None:
    # A car at (20, 15) heading east on the 40 x 30 m room's grid; every cell seen
    # 5 s ago but a column of cells 10 m behind it seen 100 s ago and the corridor,
    # never watched.
    t = _corridor_map()
    g = t.grid
    last = np.full(g.shape, 95.0)
    rr, cc = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
    px, py = g.cell_centres(rr, cc)
    last[np.abs(px - 10.25) < 0.3] = 0.0
    last[px > 40.0] = np.inf
    fresh = fresh_behind(last, 100.0, 20.0, 15.0, 0.0, g, 1.75, 30.0)
    off = np.abs(np.arctan2(py - 15.0, px - 20.0))
    assert fresh.any()
    # Just seen and more than 1.75 rad off the heading: all of them, and only them.
    assert np.array_equal(fresh, (off > 1.75) & (last == 95.0))
    assert not fresh[np.abs(px - 10.25) < 0.3].any()  # seen too long ago
    assert not fresh[px > 20.0].any()  # ahead
    # Seen 5 s ago counts as fresh for a turn of 10 s, not of 5 s.
    assert not fresh_behind(last, 100.0, 20.0, 15.0, 0.0, g, 1.75, 5.0).any()


@pytest.mark.parametrize("start", [0.0, 20.0])
def test_drop_fresh_behind_drops_what_fresh_behind_names(start: float) -> None:
    # Random looks on a fog with a block grid cut short at the edges; cars anywhere,
    # at cell centres and heading along the axes too (cells exactly on the line of
    # ``behind`` = pi / 2 go to numpy), young fogs (never-seen cells look fresh) and
    # old ones.
    rng = np.random.default_rng(int(start) + 5)
    shape = (83, 70)
    g = Grid(resolution=0.25, origin=(-3.0, 1.5), shape=shape)
    watched = rng.random(shape) > 0.2
    fog = Fog(g, watched, start)
    disc = disc_offsets(2.0, 0.25)
    dropped = 0
    for k in range(50):
        fog.advance(1.0)
        fog.observe(rng.integers(0, shape[0], 2), rng.integers(0, shape[1], 2), disc)
        for heading, behind in ((rng.uniform(-4, 4), 1.75), (0.0, math.pi / 2), (-math.pi, 1.75)):
            if k % 2:
                x, y = (float(v[0]) for v in g.cell_centres([rng.integers(0, 83)], [40]))
            else:
                x, y = rng.uniform(-3.0, 14.5), rng.uniform(1.5, 22.25)
            mask = (rng.random(shape) > 0.3) & watched
            want = mask & ~fresh_behind(
                fog.last, fog.t, x, y, heading, g, behind, 10.0, fog.never_seen()
            )
            got = mask.copy()
            n = drop_fresh_behind(got, fog, x, y, heading, g, behind, 10.0)
            np.testing.assert_array_equal(got, want)
            assert n == int(mask.sum() - want.sum())
            dropped += n
    assert dropped > 1000


@pytest.mark.parametrize("behind", [1.75, math.pi / 2 + 1e-5, 2.2, 2.9])
def test_drop_fresh_behind_on_blocks_wholly_behind(behind: float) -> None:
    # A fog of many blocks (32 cells a side) seen in long sweeps, cars inside and
    # outside it and at block corners: many blocks lie wholly behind the car, whose
    # cells the kernel drops without an angle each (down to a cone just past a right
    # angle, whose blocks near the car it must leave to the angle).
    rng = np.random.default_rng(round(behind * 1000))
    shape = (200, 180)
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=shape)
    watched = rng.random(shape) > 0.1
    fog = Fog(g, watched, 0.0)
    disc = disc_offsets(6.0, 0.25)
    fog.advance(1.0)
    fog.observe(np.arange(0, 200, 8), np.full(25, 90), disc)
    dropped = 0
    for k in range(12):
        fog.advance(1.0)
        fog.observe(rng.integers(0, shape[0], 6), rng.integers(0, shape[1], 6), disc)
        for heading in (rng.uniform(-4, 4), 0.0, math.pi / 2, -3 * math.pi / 4):
            if k % 3 == 0:
                x, y = 8.0 * int(rng.integers(0, 6)), 8.0 * int(rng.integers(0, 7))  # corners
            elif k % 3 == 1:
                x, y = (float(v[0]) for v in g.cell_centres([rng.integers(0, 200)], [90]))
            else:
                x, y = float(rng.uniform(-20.0, 65.0)), float(rng.uniform(-20.0, 70.0))
            mask = (rng.random(shape) > 0.2) & watched
            want = mask & ~fresh_behind(
                fog.last, fog.t, x, y, heading, g, behind, 10.0, fog.never_seen()
            )
            got = mask.copy()
            n = drop_fresh_behind(got, fog, x, y, heading, g, behind, 10.0)
            np.testing.assert_array_equal(got, want)
            assert n == int(mask.sum() - want.sum())
            dropped += n
    assert dropped > 20000


@pytest.fixture
def counted_sqrt(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """For the test's length, ``patrol.manoeuvre``'s ``math`` is a copy whose
    ``sqrt`` adds one to the returned list's only entry at each call: what the Python
    twin (``py_func``) of its kernel calls (compiled code still calls the real one)."""
    import types

    import sonarmap.patrol.manoeuvre as manoeuvre

    calls = [0]

    def sqrt(v: float) -> float:
        calls[0] += 1
        return math.sqrt(v)

    fake = types.SimpleNamespace(
        **{k: getattr(math, k) for k in dir(math) if not k.startswith("_")}
    )
    fake.sqrt = sqrt
    # The compiled helper the twin calls is compiled now, with the real math: numba
    # cannot compile it against the copy (as it would on a cold cache).
    manoeuvre._off_cone(manoeuvre._cone_sides(0.0, 1.75), 0.0, 0.0, 0.25, 4, 0.0, 0.0, 0, 1, 0, 1)
    monkeypatch.setattr(manoeuvre, "math", fake)
    return calls


@pytest.mark.parametrize("behind", [1.75, 2.9])
def test_drop_fresh_behind_takes_a_block_wholly_behind_without_an_angle_per_cell(
    counted_sqrt: list[int], behind: float
) -> None:
    # One block (32 x 32 cells, the top-left one) seen 5 s ago, the rest long ago; the
    # car 22 m east of it heading east: the block lies wholly behind it. The kernel's
    # Python twin, with math.sqrt counted, drops all 1024 cells after working out only
    # the block's 4 corner distances, where the per-cell path would need one a cell:
    # it fails if the whole-block path is removed or never taken.
    import sonarmap.patrol.manoeuvre as manoeuvre

    shape = (64, 64)
    last = np.zeros(shape)
    last[:32, :32] = 95.0
    latest = np.array([[95.0, 0.0], [0.0, 0.0]])
    mask = np.ones(shape, dtype=np.bool_)
    unsure = np.empty(16, dtype=np.int64)
    n, k = manoeuvre._drop_fresh_behind.py_func(
        mask, last, latest, 32, 100.0, 10.0, -1.0, 30.0, 12.0, 1.0, 0.0,
        math.cos(behind), manoeuvre._cone_sides(0.0, behind), 0.0, 0.0, 0.25, unsure,
        np.empty(0, dtype=np.int64),
    )  # fmt: skip
    assert (n, k) == (1024, 0)
    assert not mask[:32, :32].any()
    assert mask.sum() == 64 * 64 - 1024
    assert counted_sqrt[0] == 4
    # The same cells as fresh_behind names.
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=shape)
    want = ~fresh_behind(last, 100.0, 30.0, 12.0, 0.0, g, behind, 10.0)
    np.testing.assert_array_equal(mask, want)


@pytest.mark.parametrize("angle", [1.62, 4.66])
def test_drop_fresh_behind_passes_over_a_block_beside_the_cone_unread(
    counted_sqrt: list[int], angle: float
) -> None:
    # One block (32 x 32 cells of 0.25 m) seen 5 s ago, the rest long ago; the car
    # about 60 m from it, heading east, the block's centre ``angle`` radians from the
    # heading: just past a right angle on either side, so behind the car's side line
    # but short of ``behind`` (1.75): none of its cells is behind. The kernel's Python
    # twin, math.sqrt counted, passes it over after its 4 corner distances (the
    # per-cell path would take one a cell), and drops nothing, as fresh_behind.
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=(512, 512))
    bx, by = (float(v[0]) for v in g.cell_centres([240], [240]))
    x, y = bx - 60.0 * math.cos(angle), by - 60.0 * math.sin(angle)
    n, k, used, mask, want = _one_block_beside(x, y, counted_sqrt)
    assert (n, k) == (0, 0)
    assert mask.all()
    assert used == 4
    assert not want.any()


def _one_block_beside(
    x: float, y: float, counted: list[int]
) -> tuple[int, int, int, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    # The kernel's Python twin on one block (rows and columns 224-255 of 512, 0.25 m)
    # seen 5 s ago, the rest long ago, for a car at (x, y) heading east with behind
    # 1.75: the cells dropped, the unsure ones, math.sqrt's calls, the mask left and
    # fresh_behind's cells.
    import sonarmap.patrol.manoeuvre as manoeuvre

    shape = (512, 512)
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=shape)
    last = np.zeros(shape)
    last[224:256, 224:256] = 95.0
    latest = np.zeros((16, 16))
    latest[7, 7] = 95.0
    mask = np.ones(shape, dtype=np.bool_)
    sides = manoeuvre._cone_sides(0.0, 1.75)
    before = counted[0]
    n, k = manoeuvre._drop_fresh_behind.py_func(
        mask, last, latest, 32, 100.0, 10.0, -1.0, x, y, 1.0, 0.0,
        math.cos(1.75), sides, 0.0, 0.0, 0.25, np.empty(16, dtype=np.int64),
        np.empty(0, dtype=np.int64),
    )  # fmt: skip
    used = counted[0] - before
    return n, k, used, mask, fresh_behind(last, 100.0, x, y, 0.0, g, 1.75, 10.0)


def test_drop_fresh_behind_reads_a_block_across_the_cones_edge(counted_sqrt: list[int]) -> None:
    # The block's centre 60 m from the car 1.7503 rad off its heading, a hair past
    # behind (1.75; exactly on it, that cell would be left to numpy as unsure): the
    # cone's edge cuts the block, so it is neither passed over nor taken whole.
    # Every cell's angle is worked out (4 corners + 1024 cells) and the cells dropped
    # are fresh_behind's, some of the block but not all.
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=(512, 512))
    bx, by = (float(v[0]) for v in g.cell_centres([240], [240]))
    x, y = bx - 60.0 * math.cos(1.7503), by - 60.0 * math.sin(1.7503)
    n, k, used, mask, want = _one_block_beside(x, y, counted_sqrt)
    assert k == 0
    assert used == 4 + 1024
    assert 0 < n < 1024
    assert n == int(want.sum())
    np.testing.assert_array_equal(mask, ~want)


@pytest.mark.parametrize(("gap", "read"), [(5e-5, True), (5e-4, False)])
def test_drop_fresh_behind_passes_over_a_block_only_clear_of_the_margin(
    counted_sqrt: list[int], gap: float, read: bool
) -> None:
    # The block's cell nearest the cone (its bottom-left one, 60 m from the car) lies
    # ``gap`` metres outside the cone's edge, the rest further out: no cell is behind.
    # At 5e-5 m the bound on its cosine test is under OFF_CONE_MARGIN (1e-6; about
    # 2 * 0.7 * gap / 66 m / pi, the far corner about 66 m away), so the block is read
    # cell by cell; at 5e-4 m it is over, so the block is passed over after its four
    # corners. Either way nothing is dropped.
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=(512, 512))
    px, py = (float(v[0]) for v in g.cell_centres([255], [224]))
    a = 1.75 - math.asin(gap / 60.0)
    x, y = px - 60.0 * math.cos(a), py - 60.0 * math.sin(a)
    n, k, used, mask, want = _one_block_beside(x, y, counted_sqrt)
    assert (n, k) == (0, 0)
    assert mask.all()
    assert not want.any()
    assert used == (4 + 1024 if read else 4)


def test_drop_fresh_behind_lists_the_cells_it_drops(monkeypatch: pytest.MonkeyPatch) -> None:
    # The flat indices listed are exactly the cells set False: those of the kernel,
    # of the unsure cells numpy decides (cars at cell centres, headings along the
    # axes, behind a right angle) and of the whole-map fallback (UNSURE_CELLS 0).
    import sonarmap.patrol.manoeuvre as manoeuvre

    rng = np.random.default_rng(17)
    shape = (90, 75)
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=shape)
    watched = rng.random(shape) > 0.2
    fog = Fog(g, watched, 0.0)
    disc = disc_offsets(3.0, 0.25)
    for k in range(30):
        if k == 15:
            monkeypatch.setattr(manoeuvre, "UNSURE_CELLS", 0)
        fog.advance(1.0)
        fog.observe(rng.integers(0, shape[0], 3), rng.integers(0, shape[1], 3), disc)
        x, y = (float(v[0]) for v in g.cell_centres([rng.integers(0, 90)], [37]))
        for heading, behind in ((0.0, math.pi / 2), (rng.uniform(-4, 4), 1.75)):
            mask = watched.copy()
            listed = np.full(shape[0] * shape[1], -1, dtype=np.int64)
            n = drop_fresh_behind(mask, fog, x, y, heading, g, behind, 10.0, listed)
            want = np.flatnonzero(watched & ~mask)
            assert n == len(want)
            np.testing.assert_array_equal(np.sort(listed[:n]), want)
            short = np.empty(max(n - 1, 0), dtype=np.int64)
            again = watched.copy()
            assert drop_fresh_behind(again, fog, x, y, heading, g, behind, 10.0, short) == n
            np.testing.assert_array_equal(again, mask)


def test_fresh_ahead_is_a_fresh_copy_less_the_fresh_cells_every_time() -> None:
    # Cars one after another on one source and version (cells set back), a new version
    # after the source changed in place (copied again), another source array, and a
    # record too short for what a car drops (copied again): each mask equals the
    # source copied and dropped from afresh, with the same count. Both kinds of
    # second and third car are met: after a car whose dropped cells fit the record
    # (set back) and, with the 50-cell record, after one that dropped more (copied).
    rng = np.random.default_rng(23)
    shape = (70, 90)
    g = Grid(resolution=0.25, origin=(-1.0, 2.0), shape=shape)
    watched = rng.random(shape) > 0.1
    fog = Fog(g, watched, 0.0)
    disc = disc_offsets(4.0, 0.25)
    other = watched & (rng.random(shape) > 0.5)
    for record in (1 << 20, 50):
        ahead = FreshAhead(shape, record=record)
        source = watched.copy()
        set_back = overflowed = last_n = 0
        for step in range(8):
            fog.advance(1.0)
            fog.observe(rng.integers(0, shape[0], 3), rng.integers(0, shape[1], 3), disc)
            source &= rng.random(shape) > 0.05  # changed in place between steps
            for car in range(4):
                src = other if car == 3 else source
                x, y = rng.uniform(-1.0, 21.5), rng.uniform(2.0, 19.5)
                heading = float(rng.uniform(-4, 4))
                want = src.copy()
                n_want = drop_fresh_behind(want, fog, x, y, heading, g, 1.75, 10.0)
                got, n = ahead.make(src, step, fog, x, y, heading, g, 1.75, 10.0)
                np.testing.assert_array_equal(got, want)
                assert n == n_want
                if car in (1, 2):
                    # The car before, on the same source and step, dropped last_n.
                    set_back += 0 < last_n <= record
                    overflowed += last_n > record
                last_n = n_want
        assert set_back > 0
        assert overflowed == 0 if record == 1 << 20 else overflowed > 0


def test_fresh_ahead_sets_cells_back_within_a_version_and_copies_on_a_new_one() -> None:
    # Within one version the source is not read again (its cells are set back): a cell
    # cleared in the source behind FreshAhead's back (which its contract forbids) still
    # shows; a new version copies the source, and the cell is gone.
    shape = (64, 64)
    g = Grid(resolution=0.25, origin=(0.0, 0.0), shape=shape)
    watched = np.ones(shape, dtype=np.bool_)
    fog = Fog(g, watched, 0.0)
    fog.advance(1.0)
    fog.observe(np.array([32]), np.array([20]), disc_offsets(3.0, 0.25))
    source = watched.copy()
    ahead = FreshAhead(shape)
    got, n = ahead.make(source, 0, fog, 8.0, 8.0, 0.0, g, 1.75, 10.0)
    assert n > 0
    source[0, 63] = False
    got, n_again = ahead.make(source, 0, fog, 8.0, 8.0, 0.0, g, 1.75, 10.0)
    assert n_again == n
    assert got[0, 63]
    got, _ = ahead.make(source, 1, fog, 8.0, 8.0, 0.0, g, 1.75, 10.0)
    assert not got[0, 63]


@pytest.mark.parametrize("heading", [math.pi / 2, -2.5])
def test_fresh_behind_follows_the_heading(heading: float) -> None:
    # Every cell of the room seen 5 s ago; a car at (20, 15): the cells more than
    # 1.75 rad off its heading are fresh, those ahead are not, whichever way it faces
    # (a mask pointing 1 rad the wrong way fails here).
    g = _corridor_map().grid
    last = np.full(g.shape, 95.0)
    rr, cc = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
    px, py = g.cell_centres(rr, cc)
    fresh = fresh_behind(last, 100.0, 20.0, 15.0, heading, g, 1.75, 30.0)
    off = np.abs((np.arctan2(py - 15.0, px - 20.0) - heading + math.pi) % (2 * math.pi) - math.pi)
    assert np.array_equal(fresh, off > 1.75)
    # A point 5 m ahead and one 5 m behind.
    hx, hy = math.cos(heading), math.sin(heading)
    ahead = g.world_to_cell(20.0 + 5 * hx, 15.0 + 5 * hy)
    back = g.world_to_cell(20.0 - 5 * hx, 15.0 - 5 * hy)
    assert not fresh[ahead]
    assert fresh[back]
    # Off by 1 rad, the mask differs.
    assert not np.array_equal(
        fresh, fresh_behind(last, 100.0, 20.0, 15.0, heading + 1.0, g, 1.75, 30.0)
    )


def test_fresh_behind_leaves_out_places_never_seen() -> None:
    # A fog at t = 0 (start_fog 0): ``last`` is 0 for every watched place, so all look
    # just seen; none of them has been seen, so none is masked.
    t = _corridor_map()
    fog = Fog(t.grid, t.free)
    never = fog.never_seen()
    assert never.any()
    assert fresh_behind(fog.last, fog.t, 20.0, 15.0, 0.0, t.grid, 1.75, 30.0).any()
    masked = fresh_behind(fog.last, fog.t, 20.0, 15.0, 0.0, t.grid, 1.75, 30.0, never_seen=never)
    assert not masked.any()


def test_turn_time_needs_the_potential_field_on_wave_paths() -> None:
    PatrolConfig(model="car", turn_time=30.0)  # potential, wave: the defaults
    with pytest.raises(ConfigError, match="turn_time"):
        PatrolConfig(model="car", turn_time=30.0, policy="random")
    with pytest.raises(ConfigError, match="turn_time"):
        PatrolConfig(model="car", turn_time=30.0, paths="straight")
    PatrolConfig(model="car", turn_time=0.0, policy="random")


def test_the_cli_refuses_turn_time_off_the_potential_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    args = ["patrol", "run", "--map", "open-field", "--robots", "1", "--model", "car"]
    args += ["--policy", "random", "--turn-time", "30", "-o", str(out)]
    with pytest.raises(SystemExit) as e:
        cli_main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "turn_time" in err, err
    assert not out.exists()


def test_turn_time_must_be_a_duration() -> None:
    with pytest.raises(ConfigError, match="turn_time"):
        PatrolConfig(model="car", turn_time=-1.0)
    with pytest.raises(ConfigError, match="turn_time"):
        PatrolConfig(model="car", turn_time=math.inf)


def _behind_steps(turn_time: float) -> list[int]:
    """Reversing steps each of two tracking cars spends on manoeuvres planned because
    their path lay behind them, in 60 s on the 5 m ring, artificial obstacles: they
    start in the south street 18 m apart, nose to nose."""
    t = _ring_map()
    steps: list[int] = []

    def keep(_t: float, team: object, _fog: Fog) -> None:
        assert isinstance(team, Car)
        steps[:] = team.escape_causes["behind"].tolist()

    cfg = PatrolConfig(
        model="car",
        duration=60.0,
        vision=5.0,
        turn_penalty=10.0,
        out_of_sight=True,
        round_block=60.0,
        crowding="obstacles",
        turn_time=turn_time,
        # Measured before the forward wave and one-way streets were the cars' defaults.
        forward_wave=False,
        one_way=False,
    )
    starts = np.array([[12.0, 2.5, 0.0], [30.0, 2.5, math.pi]])
    run_patrol(t, cfg, starts=starts, seed=0, on_step=keep)
    return steps


def test_turn_time_leaves_the_never_seen_places_behind_nose_to_nose_cars_pulling() -> None:
    # Both cars drive towards each other for 2.5 s and then turn round, with and
    # without turn_time: the street between them is in sight and the other car shuts
    # the way on, so only places behind them, never seen, are left. Not masking those
    # (review fix), turn_time 30 changes nothing in this scene over 60 s (measured:
    # 36 + 32 reversing steps either way; masking them, as the first version did,
    # gave 22 + 22). The scene does not show the rule's own effect.
    before = _behind_steps(0.0)
    after = _behind_steps(30.0)
    assert sum(before) >= 60  # measured: 36 + 32
    assert after == before


def test_round_block_must_be_a_length() -> None:
    with pytest.raises(ConfigError, match="round_block"):
        PatrolConfig(model="car", round_block=-1.0)
    with pytest.raises(ConfigError, match="round_block"):
        PatrolConfig(model="car", round_block=math.inf)


def test_a_car_follows_a_car_ahead_going_its_way_round_the_block() -> None:
    # As above with artificial obstacles and a second car 8 m ahead going east: its
    # disc shuts the 5 m street ahead, but a car driving on round the block follows it
    # instead of turning round (with the disc closed: 18 steps reversing, west to x =
    # 8.8 m, measured).
    t = _yard_and_block_map()
    track: list[float] = []
    reverse = [0]

    def keep(_t: float, team: object, _fog: Fog) -> None:
        assert isinstance(team, Car)
        track.append(float(team.x[0]))
        reverse[0] = int(sum(int(v[0]) for v in team.escape_causes.values()))

    cfg = PatrolConfig(
        model="car",
        duration=40.0,
        vision=5.0,
        turn_penalty=0.0,
        out_of_sight=True,
        crowding="obstacles",
        round_block=150.0,
        # Measured before the forward wave, turn_time and one-way streets were the
        # cars' defaults.
        forward_wave=False,
        turn_time=0.0,
        one_way=False,
    )
    starts = np.array([[32.0, 2.5, 0.0], [40.0, 2.5, 0.0]])
    run_patrol(t, cfg, starts=starts, seed=0, on_step=keep)
    assert min(track) > 30.0
    assert max(track) > 54.0  # measured: 56.8 m
    assert reverse[0] <= 6  # the first step's turn only (measured: 4)


def _steps_moving(round_block: float) -> int:
    """Steps of 60 (30 s) on which either of two tracking cars 2.2 m apart in an open
    room, with artificial obstacles, moved."""
    t = _corridor_map()
    poses: list[npt.NDArray[np.float64]] = []

    def keep(_t: float, team: object, _fog: Fog) -> None:
        assert isinstance(team, Car)
        poses.append(np.concatenate([team.x, team.y]))

    cfg = PatrolConfig(
        model="car",
        duration=30.0,
        crowding="obstacles",
        turn_penalty=10.0,
        out_of_sight=True,
        round_block=round_block,
    )
    starts = np.array([[20.0, 10.0, 0.0], [22.2, 10.0, 0.0]])
    run_patrol(t, cfg, starts=starts, seed=0, on_step=keep)
    return int((np.abs(np.diff(np.array(poses), axis=0)).sum(axis=1) > 1e-9).sum())


def test_two_cars_closer_than_their_obstacles_part_when_driving_on() -> None:
    # Each car's disc (3 m) round the other shut every cell about it: both stood for
    # good (held-out site 1005, 3 cars, 3,600 s: from about t = 1,200 s to the end).
    # Only the other's side of the disc is closed now.
    assert _steps_moving(60.0) >= 50  # measured: 59 of 59


def test_two_cars_closer_than_their_obstacles_part_by_default() -> None:
    # Without round_block (the library's default) the whole discs shut both cars in
    # (0 of 59 steps moving); tracking cars now always close only the other's side.
    assert _steps_moving(0.0) >= 50  # measured: 59 of 59


def _disc_team() -> tuple[Holonomic, npt.NDArray[np.intp]]:
    """Robot 0 at (10, 20) heading east (cells: row y, column x at 1 m), with one
    robot ahead going its way (1), one ahead coming the other way 20 m off (2) and
    4 m off (3), and one behind it (4)."""
    x = np.array([10.0, 15.0, 30.0, 14.0, 5.0])
    y = np.array([20.0, 20.0, 20.0, 20.0, 20.0])
    heading = np.array([0.0, 0.0, math.pi, math.pi, 0.0])
    cells = np.column_stack([y, x]).astype(np.intp)
    return Holonomic(x, y, heading), cells


def _centres(discs: list[npt.NDArray[np.intp]]) -> list[tuple[int, int]]:
    return [(round(d[:, 0].mean()), round(d[:, 1].mean())) for d in discs]


def test_obstacle_discs_leave_open_the_robots_a_car_driving_on_follows() -> None:
    team, cells = _disc_team()
    disc = disc_offsets(3.0, 1.0)
    shape = (40, 40)

    def closed(
        following: bool = False, near: float = 10.0, heard: npt.NDArray[np.bool_] | None = None
    ) -> list[tuple[int, int]]:
        discs = obstacle_discs(
            team, 0, cells, disc, shape, halve=False, following=following, near=near, heard=heard
        )
        return _centres(discs)

    assert closed() == [(20, 15), (20, 30), (20, 14), (20, 5)]
    # Driving on: not the one ahead going its way, nor the one coming 20 m off.
    assert closed(following=True) == [(20, 14), (20, 5)]
    assert closed(following=True, near=math.inf) == [(20, 30), (20, 14), (20, 5)]
    assert closed(following=True, near=3.0) == [(20, 5)]
    heard = np.array([True, False, True, True, False])
    assert closed(heard=heard) == [(20, 30), (20, 14)]


def test_obstacle_discs_halved_keep_the_cells_nearer_the_other_robot() -> None:
    team, cells = _disc_team()
    disc = disc_offsets(6.0, 1.0)
    whole = obstacle_discs(team, 0, cells, disc, (40, 40), halve=False)
    half = obstacle_discs(team, 0, cells, disc, (40, 40), halve=True)
    me = cells[0]
    for j, w, h in zip([1, 2, 3, 4], whole, half, strict=True):
        to_them = np.hypot(*(h - cells[j]).T)
        to_me = np.hypot(*(h - me).T)
        assert (to_them < to_me).all()
        # Robot 2 is 20 m off: all its disc is nearer it.
        assert len(h) == len(w) if j == 2 else 0 < len(h) < len(w)
    # Robot 1, 5 m off, has robot 0's cell inside its whole disc but not its half.
    assert (whole[0] == me).all(axis=1).any()
    assert not (half[0] == me).all(axis=1).any()
    assert halves_discs(PatrolConfig(model="car"))
    assert not halves_discs(PatrolConfig(model="car", car_planner="thesis"))


def test_disc_side_is_numpys_disc_and_half() -> None:
    # Discs cut by the grid's edges, the planning robot's cell anywhere (inside the
    # disc, far off, on its centre, on lattice points equidistant from both): the
    # kernel's cells and their order are numpy's disc_cells and hypot comparison.
    rng = np.random.default_rng(11)
    shape = (120, 90)
    halves = 0
    for k in range(400):
        disc = disc_offsets(float(rng.uniform(0.5, 40.0)), 1.0)
        r, c = int(rng.integers(-5, 125)), int(rng.integers(-5, 95))
        if k % 4 == 0:
            mine = (r, c)
        elif k % 4 == 1:
            mine = (r + int(rng.integers(-3, 4)) * 2, c + int(rng.integers(-3, 4)) * 2)
        else:
            mine = (int(rng.integers(-3000, 3000)), int(rng.integers(-3000, 3000)))
        cells = np.column_stack(disc_cells(disc, r, c, shape))
        np.testing.assert_array_equal(disc_side(disc, r, c, shape), cells)
        near_me = np.hypot(cells[:, 0] - mine[0], cells[:, 1] - mine[1])
        near_them = np.hypot(cells[:, 0] - r, cells[:, 1] - c)
        want = cells[near_them < near_me]
        got = disc_side(disc, r, c, shape, mine)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, want)
        halves += 0 < len(want) < len(cells)
    assert halves > 50
    assert not halves_discs(PatrolConfig())


def test_disc_side_far_planning_robot_is_numpys_half() -> None:
    # The planning robot's cell so far off that the squared offsets pass 2**40: the
    # kernel keeps numpy's cells there. Both of its branches would keep the same cells
    # for these cells (no square wraps), so this checks the answer, not which branch
    # gave it.
    disc = disc_offsets(12.0, 1.0)
    shape = (60, 60)
    for mine in [(2**20 + 3, 7), (-(2**21), 2**20), (30, 2**22), (2**19, 2**19)]:
        cells = np.column_stack(disc_cells(disc, 30, 30, shape))
        near_me = np.hypot(cells[:, 0] - mine[0], cells[:, 1] - mine[1])
        want = cells[np.hypot(cells[:, 0] - 30, cells[:, 1] - 30) < near_me]
        np.testing.assert_array_equal(disc_side(disc, 30, 30, shape, mine), want)
    # Lattice points at equal squared distances from both cells by different offsets
    # ((5, 0) and (3, 4), (7, 1) and (5, 5)): the hypots decide, as numpy's do.
    for mine in [(35, 30), (33, 34), (37, 31), (35, 35), (30, 30)]:
        cells = np.column_stack(disc_cells(disc, 30, 30, shape))
        near_me = np.hypot(cells[:, 0] - mine[0], cells[:, 1] - mine[1])
        want = cells[np.hypot(cells[:, 0] - 30, cells[:, 1] - 30) < near_me]
        np.testing.assert_array_equal(disc_side(disc, 30, 30, shape, mine), want)


def test_disc_side_wrapping_squares_is_numpys_half() -> None:
    # The planning robot's cell about 2**32 cells off: the int64 squares of its offsets
    # wrap (2**32 squares to 0), so an integer comparison would keep the wrong cells.
    disc = disc_offsets(12.0, 1.0)
    shape = (60, 60)
    cells = np.column_stack(disc_cells(disc, 30, 30, shape))
    for mine in [(30 + 2**32, 30), (30 + 2**32 + 3, 27), (30, 30 - 2**32), (2**32, 2**32 + 5)]:
        near_me = np.hypot(cells[:, 0] - mine[0], cells[:, 1] - mine[1])
        want = cells[np.hypot(cells[:, 0] - 30, cells[:, 1] - 30) < near_me]
        assert len(want) == len(cells)  # so far off, every cell is nearer (30, 30)
        np.testing.assert_array_equal(disc_side(disc, 30, 30, shape, mine), want)


def test_points_clear_is_the_grid_lookup() -> None:
    # Random points on and off a map with its origin off zero, many on cell edges:
    # points_clear is world_to_cell, contains and the clear lookup, all().
    rng = np.random.default_rng(5)
    g = Grid(resolution=0.1, origin=(-1.3, 2.7), shape=(40, 30))
    trues = 0
    for k in range(2000):
        clear = rng.random(g.shape) < (0.5 if k % 2 else 0.995)
        n = int(rng.integers(0, 12))
        x = rng.uniform(-1.6, 1.9, n)
        y = rng.uniform(2.4, 7.0, n)
        if k % 3 == 0:
            # Cell edges exactly, as a car's arc rarely but may land.
            x = -1.3 + 0.1 * rng.integers(-2, 33, n).astype(np.float64)
            y = 2.7 + 0.1 * rng.integers(-2, 43, n).astype(np.float64)
        r, c = g.world_to_cell(x, y)
        inside = g.contains(r, c)
        want = bool(inside.all() and clear[r[inside], c[inside]].all())
        assert points_clear(x, y, clear, g) is want
        trues += want
    assert 100 < trues < 1900
    clear = np.ones(g.shape, dtype=bool)
    assert points_clear(np.array([np.nan]), np.array([3.0]), clear, g) is False
    assert points_clear(np.empty(0), np.empty(0), clear, g) is True


def test_points_clear_refuses_mismatched_inputs() -> None:
    # A y shorter than x would be read past its end; a clear of another shape would be
    # looked up with the grid's cells.
    g = Grid(resolution=0.1, origin=(-1.3, 2.7), shape=(40, 30))
    clear = np.ones(g.shape, dtype=bool)
    with pytest.raises(ValueError, match="x has 3 points, y has 2"):
        points_clear(np.zeros(3), np.full(2, 3.0), clear, g)
    with pytest.raises(ValueError, match=r"clear has shape \(30, 40\)"):
        points_clear(np.zeros(1), np.full(1, 3.0), np.ones((30, 40), dtype=bool), g)
    with pytest.raises(ValueError, match=r"clear has shape \(1200,\)"):
        points_clear(np.zeros(1), np.full(1, 3.0), clear.reshape(-1), g)


def _crossroads(res: float = 0.5) -> Territory:
    """A 30 x 30 m site: a 5.5 m street west to east (y 12.5-18 m) crossed by a 3 m one
    south to north (x 13.5-16.5 m), whose passable cells are two wide."""
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(int(30 / res), int(30 / res)))
    occ = np.ones(g.shape, np.float32)
    occ[int(12.5 / res) : int(18.0 / res), :] = 0.0
    occ[:, int(13.5 / res) : int(16.5 / res)] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


def _route_north(x0: float, y0: float, lane: float, side: float) -> npt.NDArray[np.float64]:
    """The wave's path from (x0, y0) into the north street along x = ``lane`` (m),
    turning in from ``side`` (+0.5: the east, -0.5: the west), as on site 1001."""
    head = np.array([[lane + side, 16.25], [lane + side, 16.75], [lane, 17.25]])
    ys = np.arange(17.75, 28.0, 0.5)
    full = np.vstack([head, np.column_stack([np.full(len(ys), lane), ys])])
    d = np.hypot(full[:, 0] - x0, full[:, 1] - y0)
    k = int(np.argmin(d)) + int(d.min() < 0.3)
    return np.vstack([[x0, y0], full[k:]])


def _two_cars_at_the_mouth(t: Territory) -> Car:
    """The two cars at the mouth of the north street of :func:`_crossroads`, at held-out
    site 1001's poses (its cells shifted by -39.5 m and -25.5 m)."""
    return Car(
        np.array([16.15, 13.87]),
        np.array([16.06, 16.07]),
        np.radians([126.0, 54.0]),
        clearance=t.clearance,
        planner="track",
    )


def _step_into_the_north_street(
    car: Car, t: Territory, passable: npt.NDArray[np.bool_], rng: np.random.Generator
) -> None:
    """One 0.5 s step of both cars of :func:`_two_cars_at_the_mouth`, each tracking the
    wave's path into the north street from its own side (car 0 from the east)."""
    directions: list[tuple[float, float] | None] = []
    points: list[tuple[float, float] | None] = []
    for i, (lane, side) in enumerate(((15.25, 0.5), (14.75, -0.5))):
        x0, y0 = float(car.x[i]), float(car.y[i])
        route = _route_north(x0, y0, lane, side)
        car.routes[i] = route
        p = carrot(route, x0, y0, 3.0)
        n = math.hypot(p[0] - x0, p[1] - y0)
        directions.append(((p[0] - x0) / n, (p[1] - y0) / n) if n > 1e-9 else None)
        points.append(p)
    car.step(directions, passable, t.grid, 0.5, rng, points)


def test_two_cars_at_the_mouth_of_the_street_both_go_for_part() -> None:
    # Held-out site 1001, five cars, 3,600 s, --one-way teams --stub-sight --stub-delay
    # 120: from t = 1,663 s to the end two cars, one from the east and one from the
    # west, stood 2.3 m apart at the mouth of a street both went for. Each car's
    # manoeuvre onto its route found the other in the way; the later car searched, found
    # none and rested, the earlier one then searched, and so on for good. The same poses
    # here (the site's cells shifted by -39.5 m and -25.5 m).
    t = _crossroads()
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    car = _two_cars_at_the_mouth(t)
    furthest = 16.07
    for _ in range(120):  # 60 s at 0.5 s a step
        _step_into_the_north_street(car, t, passable, rng)
        r, c = t.grid.world_to_cell(car.x, car.y)
        assert passable[r, c].all()
        assert math.hypot(car.x[0] - car.x[1], car.y[0] - car.y[1]) >= car.min_separation - 1e-9
        furthest = max(furthest, float(car.y.max()))
        if furthest > 24.0:
            break
    assert furthest > 24.0, f"no car got further than y = {furthest:.1f} m"


def test_of_two_cars_held_at_the_mouth_only_one_backs_off() -> None:
    # The same two cars. Both rest after their first search (each found no manoeuvre
    # onto its route); the earlier car used to read the later one's rest before the
    # later one counted it down, took it for resting, and both planned for traffic on
    # the same step: both backed off, side by side, for 5 steps.
    t = _crossroads()
    passable = t.passable(1.0)
    rng = np.random.default_rng(0)
    car = _two_cars_at_the_mouth(t)
    both = 0
    traffic = np.zeros(2, dtype=np.int64)
    for _ in range(60):  # 30 s at 0.5 s a step
        _step_into_the_north_street(car, t, passable, rng)
        driving = [
            p is not None and c == "traffic" for p, c in zip(car.plans, car.cause, strict=True)
        ]
        both += all(driving)
        traffic += np.array(driving)
    assert traffic.sum() > 0, "neither car planned for traffic: the scene does not test the rule"
    assert both == 0, f"both cars drove a traffic manoeuvre on {both} steps"
    # The later car is the one that makes way.
    assert traffic[0] == 0 < traffic[1]


def _dead_end_corridor(res: float = 0.5) -> Territory:
    """A 15 x 30 m yard (x < 15 m) with a 3.5 m wide corridor east from it to a dead
    end at x = 35 m (y 13-16.5 m), in a 40 x 30 m map."""
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(int(30 / res), int(40 / res)))
    occ = np.ones(g.shape, np.float32)
    occ[:, : int(15 / res)] = 0.0
    occ[int(13 / res) : int(16.5 / res), : int(35 / res)] = 0.0
    return Territory.from_map(OccupancyMap(g, occ))


def test_a_held_car_with_no_room_to_back_off_rests_and_the_other_makes_way() -> None:
    # Car 1 (the later, the one the traffic rule picks) has its back to the dead end:
    # no cell within 6 m of it lies 5.5 m from car 0, so it can neither get past nor
    # back off. It rests and searches again later; car 0, which went for the dead end,
    # must not wait for it but back off itself.
    t = _dead_end_corridor()
    g = t.grid
    passable = t.passable(1.0)
    y = 14.75
    car = Car(
        np.array([30.0, 32.3]),
        np.array([y, y]),
        np.array([0.0, math.pi]),
        clearance=t.clearance,
        planner="track",
    )
    assert not len(clear_goals(32.3, y, np.array([[30.0, y]]), passable, g, 5.5))
    assert len(clear_goals(30.0, y, np.array([[32.3, y]]), passable, g, 5.5))
    rng = np.random.default_rng(0)
    rested = False
    backed: list[float] = []
    for _ in range(2 * car.patience + 2):
        routes = [
            np.array([[car.x[0], car.y[0]], [33.5, y]]),
            np.array([[car.x[1], car.y[1]], [5.0, y], [5.0, 5.0]]),
        ]
        directions: list[tuple[float, float] | None] = []
        points: list[tuple[float, float] | None] = []
        for i, route in enumerate(routes):
            x0, y0 = float(car.x[i]), float(car.y[i])
            car.routes[i] = route
            p = carrot(route, x0, y0, 3.0)
            n = math.hypot(p[0] - x0, p[1] - y0)
            directions.append(((p[0] - x0) / n, (p[1] - y0) / n) if n > 1e-9 else None)
            points.append(p)
        x_before = float(car.x[0])
        car.step(directions, passable, g, 0.5, rng, points)
        rested |= bool(car.rest[1] > 0)
        assert car.plans[1] is None or car.cause[1] != "traffic"
        plan = car.plans[0]
        if plan is not None and car.cause[0] == "traffic":
            backed.append(x_before - float(car.x[0]))
    assert rested
    assert backed, "car 0 waited for the resting car"
    assert sum(backed) > 1.0  # reversing west, away from the dead end
