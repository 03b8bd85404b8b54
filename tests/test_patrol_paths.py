"""Path-finders other than the wave: the thesis's regions and fast marching."""

from __future__ import annotations

import math
import time
from functools import cache

import numpy as np
import numpy.typing as npt
import pytest
from scipy import ndimage

from sonarmap.errors import ConfigError, InputError
from sonarmap.patrol.finders import PathFinder
from sonarmap.patrol.maps import BUILTIN_MAPS, RESOLUTION, builtin_map
from sonarmap.patrol.marching import Marching, in_sight
from sonarmap.patrol.paths import STEPS, wave
from sonarmap.patrol.regions import Regions
from sonarmap.patrol.territory import Territory

Mask = npt.NDArray[np.bool_]

FINDERS: list[type[PathFinder]] = [Regions, Marching]


@cache
def _builtin(name: str) -> Territory:
    m = builtin_map(name)
    return Territory.from_map(m.plan.render(m.plan.grid(RESOLUTION)), cell=0.5)


def _blobs(seed: int, shape: tuple[int, int] = (48, 64)) -> tuple[Mask, tuple[int, int]]:
    """A random map of rounded obstacles, and a start in its largest open part."""
    rng = np.random.default_rng(seed)
    passable = ndimage.gaussian_filter(rng.random(shape), 2.5) < 0.52
    labels, _ = ndimage.label(passable)
    biggest = np.argmax(np.bincount(labels.ravel())[1:]) + 1
    cells = np.argwhere(labels == biggest)
    r, c = cells[rng.integers(len(cells))]
    return passable, (int(r), int(c))


def _square() -> Mask:
    """A 60 x 60 field with a 10 x 10 block: rows and columns 25 to 34."""
    passable = np.ones((60, 60), dtype=bool)
    passable[25:35, 25:35] = False
    return passable


def _straight(shape: tuple[int, ...], start: tuple[int, int]) -> npt.NDArray[np.float64]:
    rr, cc = np.indices(shape)
    out: npt.NDArray[np.float64] = np.hypot(rr - start[0], cc - start[1])
    return out


def _segments_clear(passable: Mask, a: npt.NDArray[np.int64], b: npt.NDArray[np.int64]) -> bool:
    """Whether every segment a[i] -> b[i] between cell centres stays on passable cells,
    sampled every 1/8 of a cell."""
    n = int(np.abs(b - a).max(initial=0)) * 8 + 2
    t = np.linspace(0.0, 1.0, n)[None, :, None]
    points = np.rint(a[:, None, :] + t * (b - a)[:, None, :]).astype(np.int64)
    return bool(passable[points[..., 0], points[..., 1]].all())


def _check_regions(passable: Mask, rng: np.random.Generator) -> None:
    regions = Regions.build(passable, 1.0)
    labels = regions.labels
    # Every passable cell is in exactly one region, and only those.
    np.testing.assert_array_equal(labels >= 0, passable)
    for k in range(len(regions.rects)):
        cells = np.argwhere(labels == k)
        # The region's extreme cells (corners, for a rectangle) and random pairs.
        ends = cells[[0, -1]]
        corners = np.array([[ends[0, 0], ends[1, 1]], [ends[1, 0], ends[0, 1]]])
        some = np.concatenate([ends, corners, cells[rng.integers(len(cells), size=12)]])
        i, j = np.triu_indices(len(some), 1)
        assert _segments_clear(passable, some[i], some[j]), f"region {k}"
    # Each door lies on the border of both regions it joins.
    for (r, c), pair in zip(regions.doors, regions.door_regions, strict=True):
        for r0, r1, c0, c1 in regions.rects[pair]:
            assert r0 - 0.5 <= r <= r1 + 0.5
            assert c0 - 0.5 <= c <= c1 + 0.5


@pytest.mark.parametrize("seed", range(4))
def test_regions_are_straight_on_random_maps(seed: int) -> None:
    passable, _ = _blobs(seed)
    _check_regions(passable, np.random.default_rng(seed))


@pytest.mark.parametrize("name", list(BUILTIN_MAPS))
def test_regions_are_straight_on_builtin_maps(name: str) -> None:
    _check_regions(_builtin(name).passable(1.0), np.random.default_rng(0))


@pytest.mark.parametrize("finder", FINDERS)
def test_empty_map_gives_straight_lines(finder: type[PathFinder]) -> None:
    passable = np.ones((30, 40), dtype=bool)
    dist, ux, uy = finder.build(passable, 0.5).paths((12, 7), passable)
    rr, cc = np.indices(passable.shape)
    straight = 0.5 * _straight(passable.shape, (12, 7))
    np.testing.assert_allclose(dist, straight, atol=1e-12)
    away = straight > 0
    # x east is +column, y north is -row.
    np.testing.assert_allclose(ux[away], 0.5 * (cc[away] - 7) / straight[away], atol=1e-12)
    np.testing.assert_allclose(uy[away], -0.5 * (rr[away] - 12) / straight[away], atol=1e-12)
    assert ux[12, 7] == uy[12, 7] == 0.0


@pytest.mark.parametrize("finder", FINDERS)
@pytest.mark.parametrize("seed", range(3))
def test_paths_are_never_shorter_than_straight(finder: type[PathFinder], seed: int) -> None:
    passable, start = _blobs(seed)
    # Places beside walls too: the free cells are the passable ones grown by two cells.
    free = ndimage.binary_dilation(passable, iterations=2)
    dist, ux, uy = finder.build(passable, 0.25).paths(start, free)
    reached = np.isfinite(dist)
    straight = 0.25 * _straight(passable.shape, start)
    assert (dist[reached] >= straight[reached] - 1e-9).all()
    # What one reaches, the other does, and the wave too (passable cells).
    ref, _ = wave(passable, start, 0.25)
    np.testing.assert_array_equal(reached[passable], np.isfinite(ref)[passable])
    assert not reached[~free].any()
    # A unit first direction everywhere reached but the start, none elsewhere.
    norm = np.hypot(ux, uy)
    reached[start] = False
    np.testing.assert_allclose(norm[reached], 1.0, atol=1e-12)
    assert (norm[~reached] == 0).all()


def _geodesic_round_block(r: int, c: int, start: tuple[int, int]) -> float:
    """The exact shortest length from ``start`` to cell (r, c) round the block of
    :func:`_square`, by hand: straight if in sight, else over the block's corners."""
    lo, hi = 24.5, 34.5  # the block's edges in cell-centre coordinates
    corners = [(lo, lo), (lo, hi), (hi, lo), (hi, hi)]
    nodes = [(float(start[0]), float(start[1])), *corners, (float(r), float(c))]

    def clear(p: tuple[float, float], q: tuple[float, float]) -> bool:
        t = np.linspace(0.0, 1.0, 4001)
        y = p[0] + t * (q[0] - p[0])
        x = p[1] + t * (q[1] - p[1])
        eps = 1e-9
        return not ((y > lo + eps) & (y < hi - eps) & (x > lo + eps) & (x < hi - eps)).any()

    # Dijkstra over six nodes.
    best = [0.0] + [math.inf] * (len(nodes) - 1)
    todo = set(range(len(nodes)))
    while todo:
        u = min(todo, key=lambda i: best[i])
        todo.remove(u)
        for v in todo:
            if clear(nodes[u], nodes[v]):
                best[v] = min(best[v], best[u] + math.dist(nodes[u], nodes[v]))
    return best[-1]


def test_marching_follows_the_geodesic_round_a_block() -> None:
    passable = _square()
    start = (30, 10)
    dist, _, _ = Marching.build(passable, 1.0).paths(start, passable)
    ref, _ = wave(passable, start, 1.0)
    # By hand: the start is 4.5 cells above the block's bottom edge and 5.5 below its
    # top one, so the bottom way is shorter: to the bottom-left corner, along the edge,
    # from the bottom-right corner up to the place.
    by_hand = math.hypot(4.5, 14.5) + 10.0 + math.hypot(4.5, 5.5)
    assert _geodesic_round_block(30, 40, start) == pytest.approx(by_hand)
    assert dist[30, 40] == pytest.approx(by_hand, rel=0.05)
    # Behind the block: the path wraps two corners.
    behind = [(r, c) for r in range(26, 34) for c in range(36, 60, 3)]
    exact = np.array([_geodesic_round_block(r, c, start) for r, c in behind])
    got = np.array([dist[r, c] for r, c in behind])
    err = got / exact - 1
    assert (err > -1e-9).all()
    assert err.max() < 0.05  # about a cell per corner wrapped, at 25 cells and more
    assert err.mean() < 0.025
    # The wave is further off.
    assert (np.array([ref[r, c] for r, c in behind]) / exact - 1).mean() > 0.05
    # Where the block does not hide the place, the length is the straight one.
    seen = in_sight(passable, start)
    np.testing.assert_allclose(dist[seen], _straight(passable.shape, start)[seen], atol=1e-12)
    assert not seen[30, 40]
    assert seen[10, 40]


def _downhill(finder: PathFinder, passable: Mask, start: tuple[int, int]) -> tuple[int, float]:
    """Take one step from ``start`` along each place's first direction (to the nearest of
    the 8 neighbours): how many places were checked, and the least decrease of the path
    length, in steps."""
    dist, ux, uy = finder.paths(start, passable)
    k = np.mod(np.rint(np.arctan2(uy, ux) / (math.pi / 4)).astype(np.int64), 8)
    moving = np.isfinite(dist) & (np.hypot(ux, uy) > 0)
    checked, least = 0, math.inf
    for j, (dr, dc) in enumerate(STEPS.tolist()):
        near = (start[0] + dr, start[1] + dc)
        chosen = moving & (k == j)
        if not chosen.any():
            continue
        # A first direction never points off the passable cells.
        assert passable[near]
        there, _, _ = finder.paths(near, passable)
        step = math.sqrt(2.0) if j % 2 else 1.0
        checked += int(chosen.sum())
        assert np.isfinite(there[chosen]).all()
        least = min(least, float((dist[chosen] - there[chosen]).min()) / step)
    return checked, least


@pytest.mark.parametrize("finder", FINDERS)
def test_first_directions_lead_downhill(finder: type[PathFinder]) -> None:
    passable = _square()
    built = finder.build(passable, 1.0)
    for start in [(30, 10), (20, 30), (24, 24), (40, 45)]:
        checked, least = _downhill(built, passable, start)
        assert checked == passable.sum() - 1
        assert least > 0.3
    for seed in range(2):
        blobs, start = _blobs(seed)
        checked, least = _downhill(finder.build(blobs, 1.0), blobs, start)
        assert checked > 100
        assert least > 0


@pytest.mark.parametrize("finder", FINDERS)
def test_unreachable_places_get_no_path(finder: type[PathFinder]) -> None:
    free = np.ones((20, 30), dtype=bool)
    free[:, 15] = False  # a wall from edge to edge
    passable = free.copy()
    passable[:, 16:18] = False  # too near the wall on the far side
    passable[:, 13:15] = False  # and on this side
    dist, ux, uy = finder.build(passable, 1.0).paths((10, 5), free)
    assert np.isinf(dist[:, 15:]).all()
    assert (ux[:, 15:] == 0).all()
    assert (uy[:, 15:] == 0).all()
    # The strip beside the wall on this side is reached over the last passable column.
    assert dist[10, 14] == pytest.approx(9.0)
    assert (ux[10, 14], uy[10, 14]) == pytest.approx((1.0, 0.0))
    assert np.isfinite(dist[:, :15]).all()


@pytest.mark.parametrize("finder", FINDERS)
def test_places_beside_walls_still_pull(finder: type[PathFinder]) -> None:
    free = np.ones((10, 10), dtype=bool)
    passable = free.copy()
    passable[:, :2] = False
    built = finder.build(passable, 1.0)
    dist, ux, uy = built.paths((5, 5), free)
    assert np.isfinite(dist[:, :2]).all()
    assert dist[5, 0] == pytest.approx(5.0)
    assert (ux[5, 0], uy[5, 0]) == pytest.approx((-1.0, 0.0))
    alone, ax, ay = built.paths((5, 5), passable)
    np.testing.assert_array_equal(dist[passable], alone[passable])
    np.testing.assert_array_equal(ux[passable], ax[passable])
    np.testing.assert_array_equal(uy[passable], ay[passable])
    # From the robot's own cell, head straight for the place.
    dist, ux, uy = built.paths((5, 2), free)
    assert (ux[5, 0], uy[5, 0]) == (-1.0, 0.0)
    assert dist[5, 0] == pytest.approx(2.0)
    # Over the nearest passable cell, (4, 2), which leads north.
    assert dist[4, 0] == pytest.approx(3.0)
    assert (ux[4, 0], uy[4, 0]) == pytest.approx((0.0, 1.0))


@pytest.mark.parametrize("finder", FINDERS)
def test_bad_starts_and_settings(finder: type[PathFinder]) -> None:
    passable = np.ones((5, 5), dtype=bool)
    passable[0, 0] = False
    built = finder.build(passable, 1.0)
    with pytest.raises(InputError, match="not a passable cell"):
        built.paths((0, 0), passable)
    with pytest.raises(InputError, match="outside"):
        built.paths((5, 0), passable)
    with pytest.raises(ConfigError, match="resolution"):
        finder.build(passable, 0.0)
    with pytest.raises(ConfigError, match="door spacing"):
        Regions.build(passable, 1.0, door_spacing=-1.0)


def test_on_fig32_against_the_wave() -> None:
    """Both are fast on the fig. 3.2 map, reach what the wave reaches, and are shorter
    than it on average (exact straight lines where the wave zigzags)."""
    t = _builtin("fig3-2")
    passable = t.passable(1.0)
    starts = builtin_map("fig3-2").starts
    top = t.grid.origin[1] + t.grid.rows * t.grid.resolution
    for finder in FINDERS:
        built = finder.build(passable, t.grid.resolution)
        ratios = []
        for x, y, _ in starts:
            r, c = t.cell_of(x / 10, top - y / 10)
            start = (int(r), int(c))
            began = time.perf_counter()
            dist, _, _ = built.paths(start, t.free)
            assert time.perf_counter() - began < 0.5
            ref, _ = wave(passable, start, t.grid.resolution, t.free)
            # Same reach over passable cells; off them the wave takes one last step
            # only, where the finders may go on to any target they can see.
            np.testing.assert_array_equal(np.isfinite(dist)[passable], np.isfinite(ref)[passable])
            assert np.isfinite(dist)[np.isfinite(ref)].all()
            both = passable & (ref > 0) & np.isfinite(ref)
            ratios.append(dist[both] / ref[both])
        ratio = np.concatenate(ratios)
        assert ratio.mean() < 1.0
        # The wave overestimates straight lines by 8 % at most; round corners it can
        # lose a little more, as it passes through cell centres.
        assert ratio.min() > 0.9
        if finder is Marching:
            assert ratio.max() < 1.02
