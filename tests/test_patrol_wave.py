"""The patrol wave (bucket queue): first steps by the documented tie rule, the early stop
at a path length, and the reusable :class:`Wave` (``tests/test_patrol.py`` checks the
lengths against scipy's Dijkstra)."""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator

import numba as nb
import numpy as np
import numpy.typing as npt
import pytest
from scipy import ndimage

from sonarmap.patrol.paths import STEPS, TIE, Wave, path_to, shadows, wave

_S = math.sqrt(0.5)
_UNITS = [(1, 0), (_S, _S), (0, 1), (-_S, _S), (-1, 0), (-_S, -_S), (0, -1), (_S, -_S)]


def _reference(
    passable: npt.NDArray[np.bool_],
    start: tuple[int, int],
    target: npt.NDArray[np.bool_] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
    """The wave written plainly (resolution 1): a heapq Dijkstra over the same steps, then
    for every cell the set of first steps of all its shortest paths (cells in order of
    length), and of that set the step closest to the cell's bearing, the smallest index
    among equals."""
    tg = passable if target is None else (target | passable)
    rows, cols = passable.shape

    def steps(r: int, c: int) -> Iterator[tuple[int, int, int, float]]:
        for k, (dr, dc) in enumerate(STEPS.tolist()):
            rr, cc = r + dr, c + dc
            if not (0 <= rr < rows and 0 <= cc < cols and tg[rr, cc]):
                continue
            if not passable[r, c]:
                return  # a target-only cell is a path's last step
            if k % 2:
                if not (tg[r, cc] and tg[rr, c]):
                    continue
                if passable[rr, cc] and not (passable[r, cc] and passable[rr, c]):
                    continue
            yield k, rr, cc, (math.sqrt(2) if k % 2 else 1.0)

    dist = np.full((rows, cols), np.inf)
    dist[start] = 0.0
    heap = [(0.0, start)]
    while heap:
        d, (r, c) = heapq.heappop(heap)
        if d > dist[r, c]:
            continue
        for _k, rr, cc, w in steps(r, c):
            if d + w < dist[rr, cc]:
                dist[rr, cc] = d + w
                heapq.heappush(heap, (d + w, (rr, cc)))
    sets: dict[tuple[int, int], set[int]] = {start: set()}
    for flat in np.argsort(dist, axis=None, kind="stable").tolist():
        r, c = divmod(flat, cols)
        if not np.isfinite(dist[r, c]):
            break
        for k, rr, cc, w in steps(r, c):
            if abs(dist[r, c] + w - dist[rr, cc]) <= TIE:
                sets.setdefault((rr, cc), set()).update(sets[r, c] or {k})
    first = np.full((rows, cols), -1, dtype=np.int8)
    for (r, c), ks in sets.items():
        if ks:
            dx, dy = c - start[1], start[0] - r
            first[r, c] = max(sorted(ks), key=lambda k: dx * _UNITS[k][0] + dy * _UNITS[k][1])
    return dist, first


def _maps(seed: int) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    rng = np.random.default_rng(seed)
    free = rng.random((30, 40)) > 0.1 * (seed % 4)
    passable = free & (rng.random(free.shape) > 0.15)
    passable[15, 20] = True
    return passable, free


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
@pytest.mark.parametrize("with_target", [False, True])
def test_first_steps_follow_the_tie_rule(seed: int, with_target: bool) -> None:
    passable, free = _maps(seed)
    target = free if with_target else None
    ref_d, ref_f = _reference(passable, (15, 20), target)
    dist, first = wave(passable, (15, 20), 0.25, target)
    np.testing.assert_array_equal(np.isfinite(dist), np.isfinite(ref_d))
    fin = np.isfinite(ref_d)
    np.testing.assert_allclose(dist[fin], 0.25 * ref_d[fin], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(first, ref_f)


def test_open_field_first_step_is_the_nearest_direction() -> None:
    """With no obstacle, every shortest path's first step is one of the two steps around
    the bearing, so the rule picks the step nearest the straight line (as straight
    paths would)."""
    rows, cols, r0, c0 = 61, 81, 25, 37
    w = Wave((rows, cols))
    size = w._ring.shape[1]
    dist, first = w(np.ones((rows, cols), dtype=bool), (r0, c0), 0.5)
    assert w._ring.shape[1] > size  # the wave fronts outgrew the bucket ring
    r, c = np.mgrid[:rows, :cols]
    dx, dy = c - c0, r0 - r
    nearest = np.round(np.arctan2(dy, dx) / (math.pi / 4)).astype(int) % 8
    nearest[r0, c0] = -1
    np.testing.assert_array_equal(first, nearest)
    octile = np.maximum(abs(dx), abs(dy)) + (math.sqrt(2) - 1) * np.minimum(abs(dx), abs(dy))
    np.testing.assert_allclose(dist, 0.5 * octile, rtol=0, atol=1e-9)


@pytest.mark.parametrize("with_target", [False, True])
def test_limit_stops_the_wave_exactly(with_target: bool) -> None:
    passable, free = _maps(1)
    target = free if with_target else None
    dist, first = wave(passable, (15, 20), 0.1, target)
    for limit in (0.0, 0.05, 0.1, 0.73, 1.5, 2.2, 100.0):
        d, f = wave(passable, (15, 20), 0.1, target, limit=limit)
        np.testing.assert_array_equal(d, np.where(dist <= limit, dist, np.inf))
        np.testing.assert_array_equal(f, np.where(dist <= limit, first, -1))
    with pytest.raises(ValueError, match="limit"):
        wave(passable, (15, 20), 0.1, limit=-1.0)


def test_wave_object_reuses_its_buffers() -> None:
    """A Wave gives, call after call (other maps, starts, limits), what a fresh wave
    gives; reached() lists the reached cells, start first, by path length."""
    rng = np.random.default_rng(7)
    w = Wave((30, 40))
    for i in range(12):
        passable, free = _maps(i)
        starts = np.argwhere(passable)
        start = (int(starts[i * 37 % len(starts), 0]), int(starts[i * 37 % len(starts), 1]))
        target = free if i % 2 else None
        limit = None if i % 3 == 0 else float(rng.uniform(0.0, 3.0))
        d, f = w(passable, start, 0.1, target, limit=limit)
        d0, f0 = wave(passable, start, 0.1, target, limit=limit)
        np.testing.assert_array_equal(d, d0)
        np.testing.assert_array_equal(f, f0)
        rr, cc = w.reached()
        assert (rr[0], cc[0]) == start
        assert len(rr) == np.isfinite(d0).sum()
        assert np.isfinite(d0[rr, cc]).all()
        assert (np.diff(d0[rr, cc]) > -0.1 - 1e-9).all()  # by length, within a cell
    with pytest.raises(ValueError, match="a wave for"):
        w(np.ones((5, 5), dtype=bool), (1, 1), 0.1)
    with pytest.raises(ValueError, match="impassable"):
        w(np.zeros((30, 40), dtype=bool), (1, 1), 0.1)


def test_reached_in_is_the_masked_reached_cells() -> None:
    """reached_in(mask) gives, in reached() order, the cells of the mask with a first
    step, and their first steps and lengths, after waves of every kind."""
    rng = np.random.default_rng(3)
    w = Wave((30, 40))
    for i in range(10):
        passable, free = _maps(i)
        starts = np.argwhere(passable)
        start = (int(starts[i * 31 % len(starts), 0]), int(starts[i * 31 % len(starts), 1]))
        limit = None if i % 2 else float(rng.uniform(0.5, 3.0))
        w(passable, start, 0.1, free if i % 3 else None, limit=limit)
        mask = rng.random(passable.shape) < 0.7
        mask[start] = True
        rr, cc = w.reached()
        step = w.first[rr, cc]
        keep = mask[rr, cc] & (step >= 0)
        got: tuple[npt.NDArray[np.generic], ...] = w.reached_in(mask)
        want: tuple[npt.NDArray[np.generic], ...] = (
            rr[keep],
            cc[keep],
            step[keep],
            w.dist[rr[keep], cc[keep]],
        )
        assert 0 < len(got[0]) < len(rr)
        for a, b in zip(got, want, strict=True):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="a mask of"):
        w.reached_in(np.ones((5, 5), dtype=bool))


def test_closed_cells_off_the_map_change_nothing() -> None:
    """A closed cell off the padded map is refused before any cell is closed: the
    next wave is a fresh wave's."""
    passable, free = _maps(2)
    w = Wave(passable.shape)
    near = np.argwhere(passable)[:50]
    with pytest.raises(IndexError, match="off the map"):
        w(passable, (15, 20), 0.1, free, closed=np.vstack([near, [[500, 3]]]))
    d, f = w(passable, (15, 20), 0.1, free)
    d0, f0 = wave(passable, (15, 20), 0.1, free)
    np.testing.assert_array_equal(d, d0)
    np.testing.assert_array_equal(f, f0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("how", ["in place, forgotten", "new array", "unchanged"])
def test_targets_kept_between_calls_give_the_reference(seed: int, how: str) -> None:
    """One Wave, one passable map, targets (cells along the walls, where the wave reads
    targets, as well as passable ones) changed between calls in place (then
    ``forget_targets``), as a new array, or not at all (the wave keeps the rim codes
    it read); closed cells on some calls: every call gives the plain reference's
    lengths and first steps for the targets as they are then."""
    passable, free = _maps(seed)
    rng = np.random.default_rng(100 + seed)
    w = Wave(passable.shape)
    target = free.copy()
    starts = np.argwhere(passable)
    for i in range(8):
        if how != "unchanged":
            flip = rng.random(target.shape) < 0.2
            if how == "new array":
                target = target.copy()
            target[flip] = ~target[flip]
            if how == "in place, forgotten":
                w.forget_targets()
        r, c = starts[rng.integers(len(starts))].tolist()
        closed = np.argwhere(passable & (rng.random(passable.shape) < 0.05)) if i % 2 else None
        d, f = w(passable, (r, c), 1.0, target, closed=closed)
        shut = passable.copy()
        if closed is not None:
            shut[closed[:, 0], closed[:, 1]] = False
            shut[r, c] = True
        ref_d, ref_f = _reference(shut, (r, c), target | (passable & ~shut))
        np.testing.assert_array_equal(np.isfinite(d), np.isfinite(ref_d))
        fin = np.isfinite(ref_d)
        np.testing.assert_allclose(d[fin], ref_d[fin], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(f, ref_f)


def test_comb_of_corridors() -> None:
    """Many corridors reached at the same lengths (long wave fronts, many ties)."""
    passable = np.zeros((50, 81), dtype=bool)
    passable[0, :] = True
    passable[:, ::2] = True
    passable[49, 1::4] = True
    dist, first = wave(passable, (0, 40), 1.0)
    ref_d, ref_f = _reference(passable, (0, 40))
    np.testing.assert_allclose(dist, ref_d, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(first, ref_f)


@nb.njit
def _scheduled_visit(
    order: npt.NDArray[np.int32],
    lo: int,
    hi: int,
    dist: npt.NDArray[np.float64],
    first: npt.NDArray[np.uint8],
    width: int,
    ctx: tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64]],
) -> float:
    """Counts every cell it is shown and answers the next length of a schedule."""
    schedule, calls, shown = ctx
    for i in range(lo, hi):
        shown[order[i]] += 1
    told = float(schedule[min(calls[0], len(schedule) - 1)])
    calls[0] += 1
    return told


@pytest.mark.parametrize("seed", range(8))
def test_a_visitor_sees_each_cell_once_and_its_limit_may_rise_and_fall(seed: int) -> None:
    """Whatever lengths a visitor answers, and in whatever order, the wave shows it every
    cell it takes exactly once, with the full wave's length and first step, and takes
    every cell no farther than the visitor's last answer."""
    rng = np.random.default_rng(seed)
    passable, free = _maps(seed)
    target = free if seed % 2 else None
    full_d, full_f = wave(passable, (15, 20), 0.1, target)
    schedule = rng.uniform(0.0, 2.5, size=40)
    calls = np.zeros(1, dtype=np.int64)
    w = Wave(passable.shape)
    shown = np.zeros(w._dist.size, dtype=np.int64)
    d, f = w(passable, (15, 20), 0.1, target, visit=(_scheduled_visit, (schedule, calls, shown)))
    told = schedule[min(int(calls[0]), len(schedule)) - 1]
    reached = np.isfinite(d)
    np.testing.assert_array_equal(d[reached], full_d[reached])
    np.testing.assert_array_equal(f[reached], full_f[reached])
    assert reached[full_d <= told].all()
    assert reached.sum() < np.isfinite(full_d).sum()  # the schedule did stop it early
    counts = w._inner(shown)
    assert set(np.unique(counts[reached]).tolist()) == {1}
    assert not counts[~reached].any()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_wave_to_a_goal_gives_the_full_waves_path_there(seed: int) -> None:
    """Wave.to: the goal's length and the path read back to it are the full wave's,
    every cell reached has the full wave's length, none is more than two cells farther
    than the goal (the wave stops between buckets of a cell's length), and an
    unreachable goal is inf."""
    passable, free = _maps(seed)
    full = Wave(passable.shape)
    dist, first = full(passable, (15, 20), 0.2, free)
    dist, first = dist.copy(), first.copy()
    part = Wave(passable.shape)
    rng = np.random.default_rng(seed)
    reached = np.argwhere(np.isfinite(dist))
    for r, c in reached[rng.choice(len(reached), 5, replace=False)].tolist():
        length = part.to(passable, (15, 20), (r, c), 0.2, free)
        assert length == dist[r, c]
        got = np.isfinite(part.dist)
        np.testing.assert_array_equal(part.dist[got], dist[got])
        assert not (got & (dist > dist[r, c] + 2 * 0.2)).any()
        np.testing.assert_array_equal(
            path_to(part.dist, (r, c), 0.2, passable), path_to(dist, (r, c), 0.2, passable)
        )
    walled = np.ones((9, 9), dtype=bool)
    walled[:, 4] = False
    assert Wave(walled.shape).to(walled, (4, 1), (4, 7), 0.2) == math.inf
    with pytest.raises(ValueError, match="off the grid"):
        part.to(passable, (15, 20), (-1, 3), 0.2)


def test_shadows_tie_every_unreached_watched_cell_to_a_reached_one() -> None:
    """paths.shadows: the watched cells of a wall-side strip more than one cell deep are
    not reached by the wave; each is tied to the nearest cell that is, at its straight
    distance, and the shadows and the reached cells together are every watched cell."""
    free = np.ones((20, 30), dtype=bool)
    free[:, 0] = free[:, -1] = free[0, :] = free[-1, :] = False
    clearance = ndimage.distance_transform_edt(free)
    passable = clearance >= 4  # a strip three cells deep along every wall
    watched = free.copy()
    res = 0.1
    dist, _ = wave(passable, (10, 15), res, watched)
    reached = np.isfinite(dist)
    sh = shadows(passable, watched, res)
    shadow = np.zeros_like(free)
    shadow[sh.rows, sh.cols] = True
    np.testing.assert_array_equal(shadow, watched & ~reached)
    assert len(sh) > 0
    cols = free.shape[1]
    for k in range(free.size):
        for j in range(int(sh.ptr[k]), int(sh.ptr[k + 1])):
            ar, ac = divmod(k, cols)
            assert reached[ar, ac]
            d = math.hypot(sh.rows[j] - ar, sh.cols[j] - ac) * res
            assert sh.extra[j] == pytest.approx(d)
            nearest = np.min(np.hypot(*(np.argwhere(reached) - [sh.rows[j], sh.cols[j]]).T))
            assert d == pytest.approx(nearest * res)
    with pytest.raises(ValueError, match="watched"):
        shadows(passable, watched[:-1], res)
