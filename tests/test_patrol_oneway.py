"""One-way streets derived from the map (patrol.oneway) and the wave that keeps to them."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from conftest import walled_site
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol import oneway
from sonarmap.patrol.graph import reachable_cells
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.oneway import OneWay, one_way, strong_sets, thin
from sonarmap.patrol.paths import STEPS, Wave, path_to
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Car
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory

RES = 0.5


def _site(blocks: list[tuple[float, float, float, float]], w: float, h: float) -> Territory:
    """A ``w`` x ``h`` m site walled round, with solid blocks (x0, y0, x1, y1) metres."""
    return walled_site(blocks, w, h, RES)


def _cell(g: Grid, x: float, y: float) -> tuple[int, int]:
    r, c = g.world_to_cell(x, y)
    return int(r), int(c)


def _ring() -> Territory:
    """5 m streets round one 30 x 20 m block."""
    return _site([(5.0, 5.0, 35.0, 25.0)], 40.0, 30.0)


def _four_blocks() -> Territory:
    """5 m streets round four blocks: three in a row, the middle one split in two by
    a 4 m street."""
    return _site(
        [
            (5.0, 5.0, 18.0, 25.0),
            (23.0, 5.0, 36.0, 13.0),
            (23.0, 17.0, 36.0, 25.0),
            (41.0, 5.0, 55.0, 25.0),
        ],
        60.0,
        30.0,
    )


def _strongly_connected(passable: npt.NDArray[np.bool_], steps: npt.NDArray[np.uint8]) -> bool:
    """Whether every passable cell reaches every other by the wave's allowed steps."""
    return len(strong_sets(passable, steps)) == 1


def _random_streets(seed: int) -> tuple[npt.NDArray[np.bool_], Territory]:
    """Streets 1.5 to 3 m wide between 7 random points, some diagonal: the passable
    cells of the largest connected part, and the territory."""
    rng = np.random.default_rng(seed)
    occ = np.ones((100, 140), np.float32)
    pts = rng.integers(8, [92, 132], size=(7, 2))
    for a in range(len(pts)):
        for b in range(a + 1, len(pts)):
            if rng.random() < 0.35:
                w = int(rng.integers(3, 7))
                n = int(max(abs(pts[a] - pts[b]))) + 1
                rr = np.round(np.linspace(pts[a][0], pts[b][0], n)).astype(int)
                cc = np.round(np.linspace(pts[a][1], pts[b][1], n)).astype(int)
                for r, c in zip(rr.tolist(), cc.tolist(), strict=True):
                    occ[max(r - w, 1) : r + w, max(c - w, 1) : c + w] = 0.0
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    g = Grid(resolution=RES, origin=(0.0, 0.0), shape=occ.shape)
    t = Territory.from_map(OccupancyMap(g, occ))
    p = t.passable(1.0)
    lab, _ = ndimage.label(p, structure=np.ones((3, 3)))
    big = lab == np.argmax(np.bincount(lab.ravel())[1:]) + 1
    start = np.argwhere(big)[0]
    return reachable_cells(p, [(int(start[0]), int(start[1]))], RES), t


def test_thinning_keeps_a_ring_a_ring_one_cell_wide() -> None:
    passable = _ring().passable(1.0)
    skel = thin(passable)
    assert skel.any()
    assert (skel <= passable).all()
    # One cell wide: no 2 x 2 square of skeleton cells.
    assert not (skel[:-1, :-1] & skel[1:, :-1] & skel[:-1, 1:] & skel[1:, 1:]).any()
    # Still a ring: one component, and the block inside it is a hole.
    k, _ = connected_components(_adjacency(skel), directed=False)
    assert k == 1
    _, holes = ndimage.label(~skel)
    assert holes == 2  # outside and the block


def _adjacency(mask: npt.NDArray[np.bool_]) -> coo_matrix:
    rows, cols = mask.shape
    idx = np.full(mask.shape, -1)
    idx[mask] = np.arange(int(mask.sum()))
    src, dst = [], []
    for dr, dc in STEPS.tolist():
        for r, c in np.argwhere(mask).tolist():
            rr, cc = r + dr, c + dc
            if 0 <= rr < rows and 0 <= cc < cols and mask[rr, cc]:
                src.append(idx[r, c])
                dst.append(idx[rr, cc])
    n = int(mask.sum())
    return coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))


def test_a_ring_of_narrow_streets_is_one_way_and_still_strongly_connected() -> None:
    t = _ring()
    passable = t.passable(1.0)
    ow = one_way(passable, t.clearance, RES, turn_radius=3.5)
    assert ow.one_way.all()
    assert ow.share == 1.0
    assert (ow.steps[passable] != 255).mean() > 0.5
    assert _strongly_connected(passable, ow.steps)
    # A place 6 m behind along the street is reached only round the block (about 100 m).
    g = t.grid
    a = _cell(g, 20.0, 2.5)
    b = _cell(g, 14.0, 2.5)
    two = Wave(passable.shape)
    one = Wave(passable.shape, ow.steps)
    there = one.to(passable, a, b, RES)
    back = one.to(passable, b, a, RES)
    assert two.to(passable, a, b, RES) == pytest.approx(6.0)
    # One of the two ways is the short one, the other goes round the block.
    assert min(there, back) == pytest.approx(6.0)
    assert max(there, back) > 80.0


def test_a_diagonal_only_pinch_leaves_no_place_unreachable() -> None:
    # Seed 47: the skeleton crosses a pinch where two passable cells meet only at a
    # corner, which the wave's steps cannot cut; the street graph saw a cycle through it.
    passable, t = _random_streets(47)
    pinch = (passable[:-1, :-1] & passable[1:, 1:] & ~passable[:-1, 1:] & ~passable[1:, :-1]) | (
        passable[:-1, 1:] & passable[1:, :-1] & ~passable[:-1, :-1] & ~passable[1:, 1:]
    )
    assert pinch.any()
    ow = one_way(passable, t.clearance, RES, turn_radius=3.5)
    assert _strongly_connected(passable, ow.steps)
    w = Wave(passable.shape, ow.steps)
    for start in np.argwhere(passable)[:: max(1, int(passable.sum()) // 10)].tolist():
        dist, _ = w(passable, (start[0], start[1]), RES)
        assert np.isfinite(dist[passable]).all()


def test_strong_sets_follow_the_waves_steps() -> None:
    # Two cells meeting only at a corner: 8-connected, but the wave cannot cut it.
    passable = np.zeros((4, 4), dtype=bool)
    passable[1, 1] = passable[2, 2] = True
    steps = np.full(passable.shape, 255, dtype=np.uint8)
    assert strong_sets(passable, steps).tolist() == [1, 1]
    passable[1, 2] = True
    assert strong_sets(passable, steps).tolist() == [3]
    # Only the step east out of (1, 1): (1, 1) -> (1, 2) but nothing back.
    steps[1, 1] = 1
    steps[1, 2] = 255 & ~(1 << 4) & ~(1 << 5)
    assert sorted(strong_sets(passable, steps).tolist()) == [1, 2]


def test_streets_as_wide_as_the_turning_circle_stay_two_way() -> None:
    t = _ring()
    passable = t.passable(1.0)
    ow = one_way(passable, t.clearance, RES, turn_radius=1.0)
    assert not ow.one_way.any()
    assert (ow.steps == 255).all()


def test_dead_end_stubs_are_bridges_and_stay_two_way() -> None:
    # A ring with a 4 m dead-end street leaving its east side to the east.
    g = Grid(resolution=RES, origin=(0.0, 0.0), shape=(int(30 / RES), int(60 / RES)))
    occ = np.ones(g.shape, np.float32)
    occ[1:-1, 1 : int(40 / RES)] = 0.0
    occ[int(5 / RES) : int(25 / RES), int(5 / RES) : int(35 / RES)] = 1.0
    occ[int(13 / RES) : int(17 / RES), int(40 / RES) : int(58 / RES)] = 0.0
    t = Territory.from_map(OccupancyMap(g, occ))
    passable = t.passable(1.0)
    ow = one_way(passable, t.clearance, RES, turn_radius=3.5)
    assert ow.bridges.any()
    assert ow.one_way.any()
    stub = passable.copy()
    stub[:, : int(45 / RES)] = False
    assert stub.any()
    assert (ow.steps[stub] == 255).all()
    assert _strongly_connected(passable, ow.steps)


def test_the_path_read_back_keeps_to_the_allowed_steps() -> None:
    t = _four_blocks()
    passable = t.passable(1.0)
    ow = one_way(passable, t.clearance, RES, turn_radius=3.5)
    assert _strongly_connected(passable, ow.steps)
    g = t.grid
    w = Wave(passable.shape, ow.steps)
    a = _cell(g, 20.0, 2.5)
    rng = np.random.default_rng(0)
    cells = np.argwhere(passable)
    for r, c in cells[rng.choice(len(cells), 20, replace=False)].tolist():
        dist, _ = w(passable, a, RES)
        path = path_to(dist, (r, c), RES, passable, w.allowed)
        assert tuple(path[0]) == a
        assert tuple(path[-1]) == (r, c)
        for (r0, c0), (r1, c1) in zip(path[:-1].tolist(), path[1:].tolist(), strict=True):
            j = [tuple(s) for s in STEPS.tolist()].index((r1 - r0, c1 - c0))
            assert (ow.steps[r0, c0] >> j) & 1


def test_one_way_is_for_tracking_cars_only() -> None:
    with pytest.raises(ConfigError, match="one_way"):
        PatrolConfig(model="holonomic", one_way=True)
    with pytest.raises(ConfigError, match="one_way"):
        PatrolConfig(model="car", car_planner="thesis", one_way=True)
    for paths in ("straight", "marching"):
        with pytest.raises(ConfigError, match="one_way needs paths 'wave'"):
            PatrolConfig(model="car", one_way=True, paths=paths)


def test_cars_on_a_one_way_ring_do_not_turn_round() -> None:
    # Two cars on the ring of 5 m streets: two-way, the places behind them make them
    # reverse; one-way, they drive round and never meet head-on (measured: 5 and 1).
    t = _ring()

    def turns(one: bool) -> tuple[int, int]:
        out = [0, 0]

        def keep(_t: float, team: object, _fog: object) -> None:
            assert isinstance(team, Car)
            out[:] = [int(team.turns.sum()), int(team.escape_causes["behind"][0])]

        cfg = PatrolConfig(
            model="car",
            duration=120.0,
            vision=5.0,
            crowding="obstacles",
            turn_penalty=10.0,
            out_of_sight=True,
            one_way=one,
        )
        # The second car starts facing against its street (it must turn once).
        starts = np.array([[10.0, 2.5, 0.0], [30.0, 27.5, 0.0]])
        run_patrol(t, cfg, starts=starts, seed=0, on_step=keep)
        return out[0], out[1]

    assert turns(False)[0] >= 3
    assert turns(True) == (1, 0)


@pytest.mark.parametrize("site", [0, 3])
def test_every_one_way_street_restricts_some_step(site: int) -> None:
    # Corner spurs of the thinning (loops of a cell or two back to their junction) lie
    # within the junction's reach, two-way throughout: part of the junction, not streets.
    t = street_territory(site)
    cfg = PatrolConfig(model="car", one_way=True, refine=True)
    passable = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision).passable
    ow = one_way(passable, t.clearance, t.grid.resolution, cfg.turn_radius)
    assert ow.one_way.sum() >= 10
    for s in np.flatnonzero(ow.one_way).tolist():
        assert (ow.steps[ow.street == s] != 255).any(), s


def test_the_two_way_mask_marks_the_unrestricted_cells() -> None:
    t = _four_blocks()
    passable = t.passable(1.0)
    ow = one_way(passable, t.clearance, RES, turn_radius=3.5)
    assert not ow.two_way[~passable].any()
    # Every step between two two-way cells is allowed.
    rows, cols = passable.shape
    for j, (dr, dc) in enumerate(STEPS.tolist()):
        for r, c in np.argwhere(ow.two_way).tolist():
            rr, cc = r + dr, c + dc
            if 0 <= rr < rows and 0 <= cc < cols and ow.two_way[rr, cc]:
                assert (ow.steps[r, c] >> j) & 1
    # Junctions and the ends of one-way streets are two-way, their middles not.
    on = (ow.street >= 0) & ow.one_way[np.maximum(ow.street, 0)]
    assert (ow.two_way & on).any()
    assert (~ow.two_way & on).any()
    assert ow.two_way[passable & (ow.street < 0)].all()
    # Every segment of this map touches one or two junctions: all in the graph.
    assert ow.in_graph.all()
    assert not (ow.bridges & ow.one_way).any()


def test_the_same_map_gives_the_same_system() -> None:
    t = _four_blocks()
    passable = t.passable(1.0)
    before = passable.copy()
    a = one_way(passable, t.clearance, RES, turn_radius=3.5)
    b = one_way(passable.copy(), t.clearance.copy(), RES, turn_radius=3.5)
    assert (passable == before).all()
    for name in ("steps", "street", "one_way", "widths", "bridges", "in_graph", "two_way"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(a.along, b.along, equal_nan=True)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"resolution": 0.0}, "resolution must be > 0"),
        ({"resolution": float("nan")}, "resolution must be > 0"),
        ({"turn_radius": -1.0}, "turn_radius must be >= 0"),
        ({"clearance": np.zeros((3, 3))}, r"clearance of shape \(3, 3\)"),
        ({"passable": np.ones(5, dtype=bool)}, "must be a 2-D grid"),
    ],
)
def test_bad_one_way_input_is_named(change: dict[str, object], match: str) -> None:
    t = _ring()
    args: dict[str, object] = {
        "passable": t.passable(1.0),
        "clearance": t.clearance,
        "resolution": RES,
        "turn_radius": 3.5,
    }
    args.update(change)
    with pytest.raises(ValueError, match=match):
        one_way(**args)  # type: ignore[arg-type]


def test_bad_allowed_steps_are_named() -> None:
    passable = np.ones((4, 5), dtype=bool)
    with pytest.raises(ValueError, match=r"given allowed steps of \(5, 4\)"):
        Wave((4, 5), np.full((5, 4), 255, dtype=np.uint8))
    with pytest.raises(ValueError, match="allowed steps must be uint8 bit masks, got int64"):
        Wave((4, 5), np.full((4, 5), 255, dtype=np.int64))
    dist, _ = Wave((4, 5))(passable, (0, 0), RES)
    with pytest.raises(ValueError, match=r"allowed steps of \(5, 4\) for a wave of \(4, 5\)"):
        path_to(dist, (3, 4), RES, passable, np.full((5, 4), 255, dtype=np.uint8))


def _whole_map_one_way(
    passable: npt.NDArray[np.bool_],
    clearance: npt.NDArray[np.float64],
    resolution: float,
    turn_radius: float,
    monkeypatch: pytest.MonkeyPatch,
) -> tuple[OneWay, int]:
    """The former ``one_way`` (main 3a5fca8), which looked for each street's and
    junction's cells over the whole label map and filtered the allowed steps in numpy
    (the graph's edges as COO, then back to CSR for the strongly connected sets):
    the same code with every bounding box the whole map and the numpy filter put back.
    Also how many bounding boxes were asked for (none would mean the code no longer
    takes them, and this reference no longer differs from it)."""
    asked = [0]

    def whole_map_boxes(labels: npt.NDArray[np.int64]) -> list[tuple[slice, slice]]:
        # A box for every label 1..max, as ndimage.find_objects, each the whole map.
        asked[0] += 1
        n = int(labels.max()) if labels.size else 0
        return [(slice(0, labels.shape[0]), slice(0, labels.shape[1]))] * max(n, 0)

    def coo_labels(
        graph: Any, index: npt.NDArray[np.int64], steps: npt.NDArray[np.uint8]
    ) -> npt.NDArray[np.int64]:
        # The former labels: the graph's edges as COO, filtered in numpy, back to CSR.
        coo = graph.tocoo()
        rc = np.argwhere(index >= 0)
        d = rc[coo.col] - rc[coo.row]
        step_of = np.full(9, -1, dtype=np.int64)
        for k, (dr, dc) in enumerate(STEPS.tolist()):
            step_of[(dr + 1) * 3 + dc + 1] = k
        j = step_of[(d[:, 0] + 1) * 3 + d[:, 1] + 1]
        keep = ((steps[rc[coo.row, 0], rc[coo.row, 1]].astype(np.int64) >> j) & 1).astype(bool)
        n = len(rc)
        m = coo_matrix((np.ones(int(keep.sum())), (coo.row[keep], coo.col[keep])), shape=(n, n))
        _, label = connected_components(m.tocsr(), directed=True, connection="strong")
        out: npt.NDArray[np.int64] = label.astype(np.int64)
        return out

    fake: Any = SimpleNamespace(**{k: getattr(ndimage, k) for k in dir(ndimage) if k[0] != "_"})
    fake.find_objects = whole_map_boxes
    with monkeypatch.context() as m:
        m.setattr(oneway, "ndimage", fake)
        m.setattr(oneway, "_labels", coo_labels)
        ref = one_way(passable, clearance, resolution, turn_radius)
    return ref, asked[0]


def _case(name: str) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64], float, float]:
    """A map's passable cells, clearance, cell side and turning radius: a random street
    site at the cars' radius, the ring round a block, a one-cell ring with no junction
    or the diagonal-only pinch (the check reopens streets)."""
    if name.startswith("site"):
        t = street_territory(int(name[4:]))
        cfg = PatrolConfig(model="car", one_way=True, refine=True)
        passable = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision).passable
        return passable, t.clearance, t.grid.resolution, cfg.turn_radius
    if name == "ring":
        t = _ring()
        return t.passable(1.0), t.clearance, RES, 3.5
    if name == "diamond":
        # A ring one cell wide with no junction at all (the thinning keeps it as it is),
        # away from the map's corner: cut at its first cell.
        rr, cc = np.mgrid[0:60, 0:80]
        passable = (np.abs(rr - 31) + np.abs(cc - 44)) == 20
        clearance = ndimage.distance_transform_edt(passable) * RES
        return passable, np.asarray(clearance, dtype=np.float64), RES, 3.5
    passable, t = _random_streets(47)
    return passable, t.clearance, RES, 3.5


@pytest.mark.parametrize("case", ["site1", "site4", "site6", "ring", "diamond", "pinch"])
def test_one_way_is_the_whole_map_references(case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every field of one_way's system equals the former whole-map code's on random
    street sites (their loops, stubs and one-way streets), rings and a diagonal-only
    pinch."""
    passable, clearance, res, turn_radius = _case(case)
    got = one_way(passable, clearance, res, turn_radius)
    want, asked = _whole_map_one_way(passable, clearance, res, turn_radius, monkeypatch)
    assert asked >= 3
    # Streets whose direction the boxes decide (at the pinch the check reopens all).
    assert got.one_way.any() or case == "pinch"
    for name in OneWay.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


def _city(cols: int, rows: int, street: float = 3.0, block: float = 12.0) -> Territory:
    """A made-up grid of ``cols`` x ``rows`` square blocks of ``block`` metres between
    ``street``-metre streets, walled round."""
    blocks = [
        (street + i * (block + street), street + j * (block + street))
        for i in range(cols)
        for j in range(rows)
    ]
    w, h = street + cols * (block + street), street + rows * (block + street)
    return _site([(x, y, x + block, y + block) for x, y in blocks], w, h)


def _summed_detour(passable: npt.NDArray[np.bool_], steps: npt.NDArray[np.uint8]) -> float:
    """Summed shortest one-way path over summed two-way path along the wave's steps
    (:func:`cell_graph`), from every 50th passable cell to every passable cell."""
    from scipy.sparse.csgraph import dijkstra

    from sonarmap.patrol.graph import cell_graph

    graph, _ = cell_graph(passable, 1.0)
    coo = graph.tocoo()
    rc = np.argwhere(passable)
    bits = steps[rc[coo.row, 0], rc[coo.row, 1]].astype(np.int64)
    code = {tuple(s): j for j, s in enumerate(STEPS.tolist())}
    j = np.array(
        [code[(int(a), int(b))] for a, b in (rc[coo.col] - rc[coo.row]).tolist()],
        dtype=np.int64,
    )
    keep = ((bits >> j) & 1) == 1
    n = len(rc)
    one = coo_matrix((coo.data[keep], (coo.row[keep], coo.col[keep])), shape=(n, n))
    src = np.arange(0, n, 50)
    d2 = dijkstra(graph, directed=True, indices=src)
    d1 = dijkstra(one.tocsr(), directed=True, indices=src)
    assert np.isfinite(d1).all()
    assert np.isfinite(d2).all()
    return float(d1.sum() / d2.sum())


def test_short_orientation_shortens_the_detours_of_a_grid_of_streets() -> None:
    # A 4 x 3 grid of blocks between 3 m streets (narrower than the 7 m turning
    # circle): every street is one-way either way; the local search must keep every
    # place reachable and make the one-way paths shorter than the depth-first ones.
    t = _city(4, 3)
    passable = t.passable(1.0)
    dfs = one_way(passable, t.clearance, RES, turn_radius=3.5)
    short = one_way(passable, t.clearance, RES, turn_radius=3.5, orient="short")
    assert short.one_way.sum() == dfs.one_way.sum() > 20
    np.testing.assert_array_equal(short.bridges, dfs.bridges)
    assert not np.array_equal(short.steps, dfs.steps)
    assert _strongly_connected(passable, short.steps)
    before, after = _summed_detour(passable, dfs.steps), _summed_detour(passable, short.steps)
    assert after < 0.9 * before
    # The search's record: its own model's detour fell, by flipping some streets.
    assert dfs.search is None
    assert short.search is not None
    assert short.search.streets == short.one_way.sum()
    assert 0 < short.search.flipped <= short.search.streets
    assert 1.0 < short.search.after < short.search.before


@pytest.mark.parametrize("seed", [35, 113])
def test_short_orientation_keeps_random_streets_strongly_connected(seed: int) -> None:
    # Maps where the search flips streets (its steps differ from the depth-first ones)
    # and keeps as many one-way: a flip that cut a place off would be repaired by the
    # final check reopening streets both ways, which the count catches.
    passable, t = _random_streets(seed)
    dfs = one_way(passable, t.clearance, RES, turn_radius=3.5)
    ow = one_way(passable, t.clearance, RES, turn_radius=3.5, orient="short")
    assert not np.array_equal(ow.steps, dfs.steps)
    assert ow.one_way.sum() == dfs.one_way.sum() >= 10
    assert _strongly_connected(passable, ow.steps)


def test_short_orientation_is_deterministic() -> None:
    t = _four_blocks()
    passable = t.passable(1.0)
    a = one_way(passable, t.clearance, RES, turn_radius=3.5, orient="short")
    b = one_way(passable.copy(), t.clearance.copy(), RES, turn_radius=3.5, orient="short")
    np.testing.assert_array_equal(a.steps, b.steps)
    np.testing.assert_array_equal(a.along, b.along)


def test_the_flips_never_break_strong_connectivity() -> None:
    # A ring of four streets with a chord: any single flip of a ring street would cut a
    # node off; the search may only take flips that keep every midpoint reachable.
    ends = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2)]
    forward = np.array([True, True, True, True, True])
    directed = np.ones(5, dtype=bool)
    out, _, _ = oneway._shorten(
        4, ends, np.array([10.0, 10.0, 10.0, 10.0, 14.0]), forward, directed
    )
    adj = np.zeros((4, 4))
    for (u, v), f in zip(ends, out.tolist(), strict=True):
        adj[(u, v) if f else (v, u)] = 1.0
    n, _ = connected_components(coo_matrix(adj), directed=True, connection="strong")
    assert n == 1


def test_an_unknown_orientation_is_refused_naming_the_field() -> None:
    with pytest.raises(ConfigError, match="one_way_orient") as e:
        PatrolConfig(model="car", one_way_orient="fast")
    assert e.value.field == "one_way_orient"
    t = _ring()
    with pytest.raises(ValueError, match="unknown orient 'fast'"):
        one_way(t.passable(1.0), t.clearance, RES, turn_radius=3.5, orient="fast")


def test_a_two_way_loop_street_keeps_its_half_length_to_its_midpoint() -> None:
    # A loop street wide enough to stay two-way: node 0 to its midpoint (node 1) is half
    # its length either way round, not the two halves summed.
    graph, mid = oneway._midpoint_graph(
        1, np.array([[0, 0]]), np.array([5.0]), np.array([True]), np.array([False])
    )
    assert mid.tolist() == [1]
    assert graph[0, 1] == pytest.approx(5.0)
    assert graph[1, 0] == pytest.approx(5.0)


def test_symmetric_dijkstra_is_scipys_undirected_one() -> None:
    # Grid graphs full of equal lengths (ties between starts everywhere), several
    # starts: the same lengths and the same nearest start as scipy's undirected
    # dijkstra, for whole-cell and 0.1 m steps, with and without corner cutting.
    from scipy.sparse.csgraph import dijkstra

    from sonarmap.patrol.graph import cell_graph

    rng = np.random.default_rng(11)
    for k in range(60):
        mask = rng.random((int(rng.integers(2, 40)), int(rng.integers(2, 40)))) < 0.8
        if not mask.any():
            continue
        graph, _ = cell_graph(mask, 1.0 if k % 2 else 0.1, corners=k % 3 == 0)
        n = graph.shape[0]
        starts = rng.choice(n, size=min(n, int(rng.integers(1, 8))), replace=False)
        want_d, _, want_src = dijkstra(
            graph, directed=False, indices=starts, min_only=True, return_predecessors=True
        )
        got_d, got_src = oneway._symmetric_dijkstra(graph, starts.astype(np.int64))
        np.testing.assert_array_equal(got_d, want_d)
        np.testing.assert_array_equal(got_src, want_src)


def test_parts_are_the_grid_graphs_connected_components() -> None:
    # Random masks full of diagonal-only touches (which the wave's graph does not join)
    # and corridors: the same cells together as scipy's connected components of
    # cell_graph, however either numbers them.
    from sonarmap.patrol.graph import cell_graph

    rng = np.random.default_rng(29)
    for _ in range(200):
        mask = rng.random((int(rng.integers(1, 40)), int(rng.integers(1, 40)))) < 0.55
        if not mask.any():
            continue
        got = oneway._parts(mask)
        _, want = connected_components(cell_graph(mask, 0.1)[0], directed=False)
        pairs = set(zip(got.tolist(), want.tolist(), strict=True))
        assert len(pairs) == len(set(got.tolist())) == len(set(want.tolist()))


@pytest.mark.parametrize(
    ("on", "orient", "want"),
    [(True, "short", "short"), (True, "dfs", "dfs"), (False, "short", "dfs")],
)
def test_the_orientation_asked_for_is_the_one_the_run_builds(
    on: bool, orient: str, want: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Two cars on the ring, a few seconds: the run builds its one-way streets with the
    # configuration's orientation when it drives them, and the plain one when it
    # builds them only to look down stubs.
    from sonarmap.patrol import simulation

    asked: list[str] = []

    def recorder(*args: Any, **kwargs: Any) -> OneWay:
        asked.append(str(kwargs.get("orient", "dfs")))
        return one_way(*args, **kwargs)

    monkeypatch.setattr(simulation, "one_way", recorder)
    cfg = PatrolConfig(
        model="car",
        duration=2.0,
        vision=5.0,
        crowding="obstacles",
        one_way=on,
        stub_sight=not on,
        one_way_orient=orient,
    )
    run_patrol(_ring(), cfg, robots=2, seed=0)
    assert asked == [want]


def test_the_command_line_orientation_reaches_the_configuration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # The run itself is replaced by a recorder that stops the command (as Ctrl-C would)
    # once it has the configuration.
    import sonarmap.patrol
    from sonarmap.cli import main

    seen: list[PatrolConfig] = []

    def recorder(territory: object, config: PatrolConfig, **kwargs: object) -> None:
        seen.append(config)
        raise KeyboardInterrupt

    monkeypatch.setattr(sonarmap.patrol, "run_patrol", recorder)
    args = ["patrol", "run", "--map", "fig3-10", "--model", "car", "--robots", "2"]
    for extra, want in (([], "dfs"), (["--one-way-orient", "short"], "short")):
        with pytest.raises(SystemExit) as e:
            main([*args, *extra, "-o", str(tmp_path / "out")])
        assert e.value.code == 130
        assert seen[-1].one_way_orient == want
    capsys.readouterr()
    assert not (tmp_path / "out").exists()


def _largest_sets_by_lexsort(
    strong: npt.NDArray[np.int64],
    weak: npt.NDArray[np.int64],
    size: npt.NDArray[np.int64],
    n_weak: int,
) -> npt.NDArray[np.int64]:
    # The form _largest_sets replaced: nodes sorted by part, set size (largest first)
    # and node, then the first node of each part names its set.
    order = np.lexsort((np.arange(len(strong)), -size, weak))
    keep = np.full(n_weak, -1, dtype=np.int64)
    for node in order.tolist():
        if keep[weak[node]] < 0:
            keep[weak[node]] = strong[node]
    return keep


def test_largest_sets_is_the_former_lexsort_form() -> None:
    # Random parts split into a few strong sets of one to three nodes each (so equal
    # sizes, i.e. ties, in most parts), some part numbers unused, no nodes at all:
    # the same set kept for every part as the sort it replaced.
    rng = np.random.default_rng(41)
    ties = 0
    for k in range(400):
        n = 0 if k == 0 else int(rng.integers(1, 60))
        n_weak = int(rng.integers(1, 12))
        weak = rng.integers(0, n_weak, n).astype(np.int64)
        split = weak * 8 + rng.integers(0, 1 + int(rng.integers(1, 8)), n)
        _, strong = np.unique(split, return_inverse=True)
        strong = strong.astype(np.int64).reshape(-1)
        size = np.bincount(strong)[strong].astype(np.int64) if n else strong.copy()
        got = oneway._largest_sets(strong, weak, size, n_weak)
        np.testing.assert_array_equal(got, _largest_sets_by_lexsort(strong, weak, size, n_weak))
        for w in range(n_weak):
            sets = set(strong[(weak == w) & (size == size[weak == w].max(initial=0))].tolist())
            ties += len(sets) > 1
    assert ties > 200


def test_the_one_way_benchmarks_digest_reads_values_not_objects() -> None:
    # benchmarks.one_way compares builds by digest, across processes: a field that is no
    # array (search: None or a Search) counts by its value, not the object's address.
    from benchmarks.one_way import digest

    t = _four_blocks()
    passable = t.passable(1.0)
    a = one_way(passable, t.clearance, RES, turn_radius=3.5, orient="short")
    b = one_way(passable, t.clearance, RES, turn_radius=3.5, orient="short")
    assert a.search is not None
    assert a.search is not b.search
    assert digest(a) == digest(b)
    c = one_way(passable, t.clearance, RES, turn_radius=3.5)
    assert c.search is None
    assert digest(c) == digest(one_way(passable, t.clearance, RES, turn_radius=3.5))
    assert digest(c) != digest(a)


def test_farthest_from_the_junctions_is_the_whole_map_distance_transform() -> None:
    # Random junction masks and random boxes with random cells in them, bounds from 0
    # to past the farthest cell: where the whole map's distance transform says the
    # cells' largest distance is at most the bound, the window gives that very float;
    # otherwise something over the bound (a box on the map's edge, junctions only
    # outside the window, none at all included).
    rng = np.random.default_rng(5)
    exact = over = 0
    for k in range(300):
        rows, cols = int(rng.integers(3, 60)), int(rng.integers(3, 60))
        junction = rng.random((rows, cols)) < [0.0, 0.002, 0.02, 0.2][k % 4]
        r0, c0 = int(rng.integers(0, rows)), int(rng.integers(0, cols))
        r1, c1 = int(rng.integers(r0 + 1, rows + 1)), int(rng.integers(c0 + 1, cols + 1))
        box = (slice(r0, r1), slice(c0, c1))
        pix = rng.random((r1 - r0, c1 - c0)) < 0.5
        pix.flat[int(rng.integers(0, pix.size))] = True
        whole = ndimage.distance_transform_edt(~junction) if junction.any() else None
        want = float(whole[box][pix].max()) if whole is not None else np.inf
        for bound in (0.0, 1.0, 2.5, float(rng.uniform(0, 30)), 100.0):
            got = oneway._farthest_from(junction, box, pix, bound)
            if want <= bound:
                assert got == want
                exact += 1
            else:
                assert got > bound
                over += 1
    assert exact > 200
    assert over > 200
