"""The patrol graph: vertices that watch every place, edges through doors and never
across walls, lengths of the wave's paths."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from conftest import SHARED_DATA
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap, read_map
from sonarmap.patrol import Territory, wave
from sonarmap.patrol.graph import PatrolGraph, cell_graph, lattice_cells, reachable_cells

DEPOT = SHARED_DATA / "maps" / "depot.yaml"


def _territory(occupied: npt.NDArray[np.bool_], res: float = 0.5) -> Territory:
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=occupied.shape)
    return Territory.from_map(OccupancyMap(g, occupied.astype(np.float32)))


def _two_rooms(door: bool) -> Territory:
    """40 x 20 m, a wall down the middle; with ``door``, a 4 m gap in it near the top."""
    occ = np.zeros((40, 80), dtype=bool)
    occ[:, 39:41] = True
    if door:
        occ[DOOR_ROWS, 39:41] = False
    return _territory(occ)


DOOR_ROWS = slice(2, 10)


def _wave_length(g: PatrolGraph, mask: npt.NDArray[np.bool_], i: int, j: int) -> float:
    d, _ = wave(mask, (int(g.cells[i, 0]), int(g.cells[i, 1])), g.grid.resolution)
    return float(d[g.cells[j, 0], g.cells[j, 1]])


def _check_edges(g: PatrolGraph, mask: npt.NDArray[np.bool_]) -> None:
    ij, lengths = g.edges()
    assert len(ij)
    for (i, j), length in zip(ij.tolist(), lengths.tolist(), strict=True):
        straight = math.dist(g.xy[i], g.xy[j])
        assert length >= straight - 1e-9
        assert length == pytest.approx(_wave_length(g, mask, i, j), abs=1e-9)
    # Both ends list the edge, with one length.
    for i, (nb, ln) in enumerate(zip(g.neighbours, g.lengths, strict=True)):
        assert list(nb) == sorted(set(nb.tolist()))
        assert i not in nb.tolist()
        for j, d in zip(nb.tolist(), ln.tolist(), strict=True):
            back = g.neighbours[j].tolist().index(i)
            assert g.lengths[j][back] == d


def test_two_rooms_with_a_door_are_one_graph_and_edges_go_through_the_door() -> None:
    t = _two_rooms(door=True)
    passable = t.passable(1.0)
    g = PatrolGraph.from_territory(t, passable, 5.0)
    assert g.connected()
    _check_edges(g, passable)
    left = g.xy[:, 0] < 20.0
    ij, lengths = g.edges()
    across = left[ij[:, 0]] != left[ij[:, 1]]
    assert across.any()
    # A path across the wall passes a cell of the door: no edge is shorter than the
    # straight lines through the best one.
    rows = np.arange(40)[DOOR_ROWS]
    dx, dy = t.grid.cell_centres(rows, np.full(len(rows), 39))
    door = np.column_stack([dx, dy])
    for (i, j), length in zip(ij[across].tolist(), lengths[across].tolist(), strict=True):
        via = np.linalg.norm(door - g.xy[i], axis=1) + np.linalg.norm(door - g.xy[j], axis=1)
        assert length >= via.min() - 1e-9
    # Only regions touching at the door are linked across the wall.
    near = np.min(np.linalg.norm(door[:, None] - g.xy[ij[across]].reshape(-1, 2), axis=2), axis=0)
    assert near.max() <= g.spacing
    # Along the graph, the way between two vertices is never shorter than the wave's.
    from scipy.sparse.csgraph import dijkstra

    along = dijkstra(g.to_csgraph(), directed=False)
    for i in range(len(g)):
        d, _ = wave(passable, (int(g.cells[i, 0]), int(g.cells[i, 1])), 0.5)
        assert (along[i] >= d[g.cells[:, 0], g.cells[:, 1]] - 1e-9).all()
    low = np.argsort(g.xy[:, 1] + np.abs(g.xy[:, 0] - 20.0))
    i, j = (int(k) for k in low[left[low]][:1].tolist() + low[~left[low]][:1].tolist())
    assert along[i, j] > math.dist(g.xy[i], g.xy[j]) + 10.0  # round by the door


def test_a_wall_without_a_door_splits_the_graph() -> None:
    t = _two_rooms(door=False)
    passable = t.passable(1.0)
    g = PatrolGraph.from_territory(t, passable, 5.0)
    assert not g.connected()
    comp = g.components()
    left = g.xy[:, 0] < 20.0
    assert set(comp[left].tolist()).isdisjoint(comp[~left].tolist())
    assert len(set(comp.tolist())) == 2
    _check_edges(g, passable)
    # From a start in the left room only the left room's vertices are kept.
    start = (int(g.cells[0, 0]), int(g.cells[0, 1]))
    assert g.xy[0, 0] < 20.0
    h = PatrolGraph.from_territory(t, passable, 5.0, starts=[start])
    assert h.connected()
    assert (h.xy[:, 0] < 20.0).all()
    assert len(h) == int(left.sum())


def test_a_thin_diagonal_wall_is_not_crossed_at_its_corners() -> None:
    # Two triangles split by a wall one cell thick along the diagonal: cells on either
    # side touch at the wall cells' corners only.
    n = 40
    occ = np.eye(n, dtype=bool)
    t = _territory(occ)
    passable = t.free.copy()  # a point robot: every free cell
    g = PatrolGraph.from_territory(t, passable, 3.0)
    comp = g.components()
    upper = g.cells[:, 1] > g.cells[:, 0]
    assert set(comp[upper].tolist()).isdisjoint(comp[~upper].tolist())
    assert not g.connected()
    _check_edges(g, passable)
    # A one-cell hole in the wall joins them.
    occ[20, 20] = False
    t2 = _territory(occ)
    g2 = PatrolGraph.from_territory(t2, t2.free.copy(), 3.0)
    assert g2.connected()


def test_a_corridor_links_only_consecutive_vertices() -> None:
    occ = np.zeros((8, 120), dtype=bool)  # 60 x 4 m
    t = _territory(occ)
    g = PatrolGraph.from_territory(t, t.free.copy(), 5.0)
    order = np.argsort(g.xy[:, 0])
    assert len(g) >= 4
    for k, i in enumerate(order.tolist()):
        want = {int(order[m]) for m in (k - 1, k + 1) if 0 <= m < len(order)}
        assert set(g.neighbours[i].tolist()) == want
    # In open space the wave's length is the straight one, up to its 8 directions.
    ij, lengths = g.edges()
    straight = np.linalg.norm(g.xy[ij[:, 0]] - g.xy[ij[:, 1]], axis=1)
    assert np.all(lengths <= straight * 1.0824 + 1e-9)


def test_regions_and_coverage() -> None:
    t = _two_rooms(door=True)
    passable = t.passable(1.0)
    g = PatrolGraph.from_territory(t, passable, 5.0)
    # Every passable cell belongs to a region, and each vertex to its own.
    assert ((g.region >= 0) == passable).all()
    assert (g.region[g.cells[:, 0], g.cells[:, 1]] == np.arange(len(g))).all()
    assert passable[g.cells[:, 0], g.cells[:, 1]].all()
    x, y = t.grid.cell_centres(*np.nonzero(passable))
    d, _ = cKDTree(g.xy).query(np.column_stack([x, y]))
    assert d.max() <= 5.0 + 1e-9
    # The vertices start with the tour's lattice, in its order.
    lat = lattice_cells(t, passable, 5.0)
    lat = lat[passable[lat[:, 0], lat[:, 1]]]
    np.testing.assert_array_equal(g.cells[: len(lat)], lat)
    assert g.spacing == pytest.approx(math.floor(5.0 * math.sqrt(2) / 0.5) * 0.5)


def test_the_graph_is_deterministic() -> None:
    t = _two_rooms(door=True)
    passable = t.passable(1.0)
    a = PatrolGraph.from_territory(t, passable, 4.0)
    b = PatrolGraph.from_territory(t, passable.copy(), 4.0)
    np.testing.assert_array_equal(a.cells, b.cells)
    np.testing.assert_array_equal(a.region, b.region)
    for na, nb in zip(a.neighbours, b.neighbours, strict=True):
        np.testing.assert_array_equal(na, nb)
    for la, lb in zip(a.lengths, b.lengths, strict=True):
        np.testing.assert_array_equal(la, lb)


def test_cell_graph_is_the_waves_graph() -> None:
    rng = np.random.default_rng(3)
    mask = rng.random((25, 30)) > 0.35
    graph, index = cell_graph(mask, 0.2)
    from scipy.sparse.csgraph import dijkstra

    r, c = np.argwhere(mask)[0]
    ref, _ = wave(mask, (int(r), int(c)), 0.2)
    d = dijkstra(graph, directed=False, indices=int(index[r, c]))
    got = np.full(mask.shape, np.inf)
    got[mask] = d
    np.testing.assert_allclose(got, ref, atol=1e-9)
    reach = reachable_cells(mask, [(int(r), int(c))])
    np.testing.assert_array_equal(reach, np.isfinite(ref))


def _coo_cell_graph(
    mask: npt.NDArray[np.bool_], resolution: float, corners: bool
) -> tuple[Any, npt.NDArray[np.int64]]:
    """The former ``cell_graph`` (main 74e644f): each forward step's edges by array
    slices, both directions as COO, then ``tocsr``."""
    index = np.full(mask.shape, -1, dtype=np.int64)
    n = int(mask.sum())
    index[mask] = np.arange(n)
    rows, cols = mask.shape
    src, dst, w = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r0, r1 = 0, rows - dr
        c0, c1 = max(0, -dc), cols - max(0, dc)
        ok = mask[r0:r1, c0:c1] & mask[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        if dr and dc and not corners:
            ok &= mask[r0:r1, c0 + dc : c1 + dc] & mask[r0 + dr : r1 + dr, c0:c1]
        src.append(index[r0:r1, c0:c1][ok])
        dst.append(index[r0 + dr : r1 + dr, c0 + dc : c1 + dc][ok])
        w.append(np.full(int(ok.sum()), resolution * (math.sqrt(2.0) if dr and dc else 1.0)))
    s, d, ww = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
    pairs = (np.concatenate([s, d]), np.concatenate([d, s]))
    return coo_matrix((np.concatenate([ww, ww]), pairs), shape=(n, n)).tocsr(), index


def test_cell_graph_is_the_former_coo_graph() -> None:
    # Same rows, columns in the same order, step lengths, index types and node numbers
    # as the COO formulation, on random masks of every density (empty ones included),
    # with and without corner cutting.
    rng = np.random.default_rng(5)
    for _ in range(300):
        draw = rng.random((int(rng.integers(0, 25)), int(rng.integers(0, 25))))
        mask = draw < rng.uniform(0.0, 1.0)
        for corners in (False, True):
            got, index = cell_graph(mask, 0.3, corners=corners)
            ref, ref_index = _coo_cell_graph(mask, 0.3, corners)
            assert got.shape == ref.shape
            assert got.indptr.dtype == ref.indptr.dtype
            assert got.indices.dtype == ref.indices.dtype
            np.testing.assert_array_equal(got.indptr, ref.indptr)
            np.testing.assert_array_equal(got.indices, ref.indices)
            np.testing.assert_array_equal(got.data, ref.data)
            np.testing.assert_array_equal(index, ref_index)


@pytest.mark.skipif(not DEPOT.is_file(), reason="shared data (../shared/data/maps) not present")
def test_on_a_real_map_the_graph_is_connected_and_watches_every_reachable_place() -> None:
    t = Territory.from_map(read_map(DEPOT), cell=0.25)
    passable = t.passable(0.25)
    # A start in the largest region a robot can be in.
    sizes = {}
    for r, c in np.argwhere(passable)[::29].tolist():
        sizes[int(reachable_cells(passable, [(r, c)]).sum())] = (r, c)
    start = sizes[max(sizes)]
    dist, _ = wave(passable, start, t.grid.resolution)
    reach = np.isfinite(dist)
    x, y = t.grid.cell_centres(*np.nonzero(reach))
    places = np.column_stack([x, y])
    for vision in (10.0, 2.0):
        g = PatrolGraph.from_territory(t, passable, vision, starts=[start])
        assert g.connected()
        assert ((g.region >= 0) == reach).all()
        d, _ = cKDTree(g.xy).query(places)
        assert d.max() <= vision + 1e-9
        _check_edges(g, reach)
    # Here the lattice alone, moved onto passable cells, leaves places unwatched.
    bare = PatrolGraph.from_territory(t, passable, 2.0, starts=[start], cover=False)
    d, _ = cKDTree(bare.xy).query(places)
    assert d.max() > 2.0
