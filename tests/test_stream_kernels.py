"""The streaming gradient's kernels against the entry-by-entry loops they replaced.

The pool's spans and the step over them are a faster layout of the same arithmetic:
every sum takes its terms in the same order, so the maps must agree to the bit, not to
a tolerance. The reference step below is the kernel the spans replaced, kept here as
the definition.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import numpy.typing as npt
import pytest

from conftest import zoned_sensor
from sonarmap.grid import Grid
from sonarmap.mappers import GradientMapper
from sonarmap.mappers._pool import ReadingPool
from sonarmap.mappers._stream import touching
from sonarmap.mappers.gradient import (
    STEP,
    STREAM_STEP_CAP,
    GradientStream,
    _stream_steps,
    _term_sums,
    stream_step_sizes,
)
from sonarmap.raster import rasterise
from sonarmap.scenarios import Scenario
from sonarmap.selection import parse_strategy
from sonarmap.streaming import time_batches

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]


@nb.njit(cache=True)
def _entry_steps(
    sel: I64,
    f_start: I64,
    f_len: I64,
    o_start: I64,
    o_len: I64,
    f_sum: F64,
    o_sum: F64,
    echo: npt.NDArray[np.bool_],
    cell: npt.NDArray[np.int32],
    w: npt.NDArray[np.float32],
    x: F64,
    g: F64,
    mark: npt.NDArray[np.bool_],
    dirty: I64,
    cov: npt.NDArray[np.int32],
    kcount: npt.NDArray[np.int32],
    a1: float,
    a2: float,
    step: float,
    k_cap: int,
    n_steps: int,
) -> None:
    """The streaming step entry by entry, as it was before the spans."""
    for _ in range(n_steps):
        for s in sel:
            for part in range(2):
                if part == 0:
                    a, n, tot = f_start[s], f_len[s], f_sum[s]
                else:
                    if not echo[s]:
                        continue
                    a, n, tot = o_start[s], o_len[s], o_sum[s]
                if n == 0 or tot <= 0.0:
                    continue
                big_x = 0.0
                for j in range(a, a + n):
                    big_x += w[j] * x[cell[j]]
                big_x /= tot
                x0 = 1.0 / tot
                if part == 0:
                    below = a1
                    above = (1.0 - a1 * x0) / (1.0 - x0) if x0 < 1.0 else a1
                else:
                    below = -(1.0 - a2 + a2 * x0) / x0
                    above = -a2
                if big_x < x0:
                    slope = below
                elif big_x > x0:
                    slope = above
                else:
                    continue
                f = slope / tot
                for j in range(a, a + n):
                    c = cell[j]
                    if mark[c]:
                        g[c] += f * w[j]
        for c in dirty:
            if cov[c] > 0:
                k = min(kcount[c] + 1, k_cap)
                kcount[c] = k
                v = x[c] - step / math.sqrt(k) * g[c]
                x[c] = min(max(v, 0.0), 1.0)
            g[c] = 0.0


GRID = Grid(resolution=0.05, origin=(-3.0, -3.0), shape=(120, 120))


def _batch(rng: np.random.Generator, n: int, pools: tuple[ReadingPool, ...]) -> I64:
    """Rasterise n random readings of a sensor with a zone (two weights, so spans also
    break where the weight changes) into each pool; a fifth have no echo."""
    sensor = zoned_sensor()
    x, y = rng.uniform(-2.5, 2.5, (2, n))
    theta = rng.uniform(-math.pi, math.pi, n)
    r = rng.uniform(0.1, 3.2, n)
    r[rng.random(n) < 0.2] = sensor.r_max
    fp = rasterise(GRID, sensor, x, y, theta, r, offset=0.025)
    slots = [pool.add(fp, np.minimum(r, sensor.r_max), r < sensor.r_max) for pool in pools]
    for other in slots[1:]:
        np.testing.assert_array_equal(other, slots[0])
    return slots[0]


def _pools(seed: int) -> tuple[ReadingPool, ReadingPool]:
    """The same readings in a pool of entries and one of spans, after adds, removals in
    any order, slot reuse and compactions (not at the same moments in both: the span
    arena fills up on its own)."""
    rng = np.random.default_rng(seed)
    pools = (ReadingPool(GRID.cols), ReadingPool(GRID.cols, spans=True))
    live = _batch(rng, 60, pools)
    for _ in range(4):
        gone = rng.choice(live, len(live) // 3, replace=False)
        for pool in pools:
            pool.remove(gone)
        live = np.concatenate([np.setdiff1d(live, gone), _batch(rng, 30, pools)])
        if rng.random() < 0.5:
            pools[int(rng.integers(2))].compact()
    return pools


def _parts(pool: ReadingPool, s: int) -> list[tuple[int, int, int, int]]:
    return [
        (int(pool.f_start[s]), int(pool.f_len[s]), int(pool.fs_start[s]), int(pool.fs_len[s])),
        (int(pool.o_start[s]), int(pool.o_len[s]), int(pool.os_start[s]), int(pool.os_len[s])),
    ]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_spans_are_the_entries_in_order(seed: int) -> None:
    entries, pool = _pools(seed)
    np.testing.assert_array_equal(pool.alive, entries.alive)
    assert len(pool.w) == len(pool.dist) == 0
    for s in pool.alive_slots():
        for (a, n, _, _), (pa, pn, sa, sn) in zip(
            _parts(entries, int(s)), _parts(pool, int(s)), strict=True
        ):
            cells = [
                c
                for q in range(sa, sa + sn)
                for c in range(pool.sp_cell[q], pool.sp_cell[q] + pool.sp_len[q])
            ]
            weights = np.repeat(pool.sp_w[sa : sa + sn], pool.sp_len[sa : sa + sn])
            assert cells == entries.cell[a : a + n].tolist() == pool.cell[pa : pa + pn].tolist()
            np.testing.assert_array_equal(weights, entries.w[a : a + n])
            # Maximal: a span never continues the one before it.
            for q in range(sa + 1, sa + sn):
                follows = pool.sp_cell[q] == pool.sp_cell[q - 1] + pool.sp_len[q - 1]
                assert not (follows and pool.sp_w[q] == pool.sp_w[q - 1])
        for name in ("f_sum", "o_sum", "box", "echo"):
            np.testing.assert_array_equal(getattr(pool, name)[s], getattr(entries, name)[s])
    # The zone's weight splits some spans.
    assert len(np.unique(pool.sp_w[: pool.sp_end])) > 1


def test_term_sums_are_the_sums_in_order() -> None:
    rng = np.random.default_rng(3)
    n_cells = 5000
    # Terms of 0 to 400 entries in spans of 1 to 60 cells, weights of a few sizes (and
    # values of the map that make products round), the map with exact 0s and 1s.
    lengths = rng.integers(1, 61, 3000).astype(np.int32)
    sp_cell = rng.integers(0, n_cells - 60, 3000).astype(np.int32)
    sp_w = rng.choice(np.array([1.0, 0.3, 1e-3, 0.77], np.float32), 3000)
    x = rng.uniform(0.0, 1.0, n_cells)
    x[rng.random(n_cells) < 0.3] = 0.0
    x[rng.random(n_cells) < 0.1] = 1.0
    t_spans = rng.integers(0, 12, 211)
    t_start = np.concatenate([[0], np.cumsum(t_spans)[:-1]]).astype(np.int64)
    t_len = np.array([lengths[a : a + n].sum() for a, n in zip(t_start, t_spans, strict=True)])
    order = np.argsort(t_len).astype(np.int64)
    out = np.full(len(t_len), np.nan)
    _term_sums(
        t_start, t_spans, t_len, order, sp_cell, lengths, sp_w, x, out, np.empty(8 * t_len.max())
    )
    for t in range(len(t_len)):
        want = 0.0
        for q in range(t_start[t], t_start[t] + t_spans[t]):
            for c in range(sp_cell[q], sp_cell[q] + lengths[q]):
                want += float(sp_w[q]) * x[c]
        assert np.float64(want).view(np.int64) == out[t].view(np.int64)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(("n_steps", "step"), [(1, 0.05), (3, 0.05), (1, 20.0)])
def test_stream_steps_are_the_entry_by_entry_steps(seed: int, n_steps: int, step: float) -> None:
    """The same x, step counts and (zero) gradient buffer, bit for bit, as the loop
    over entries, update after update (the terms' known X carried from one to the
    next), on marked sets of every size, with the readings that touch them, and maps
    with cells at the bounds. The large step moves X across X0, so that known values
    must be given up."""
    entries, pool = _pools(seed)
    rng = np.random.default_rng(seed + 10)
    cov = np.zeros(GRID.size, np.int32)
    for s in pool.alive_slots():
        np.add.at(cov, pool.cell[pool.f_start[s] : pool.f_start[s] + pool.f_len[s]], 1)
        np.add.at(cov, pool.cell[pool.o_start[s] : pool.o_start[s] + pool.o_len[s]], 1)
    covered = np.flatnonzero(cov > 0)
    x = rng.uniform(0.0, 1.0, GRID.size)
    x[rng.random(GRID.size) < 0.2] = 0.0
    x[rng.random(GRID.size) < 0.05] = 1.0
    k = rng.integers(0, STREAM_STEP_CAP + 5, GRID.size).astype(np.int32)
    x_ref, k_ref = x.copy(), k.copy()
    known = np.zeros((pool.capacity, 2))
    known_at = np.full((pool.capacity, 2), -np.inf)
    drift = np.zeros(1)
    a1, a2 = 0.3, 0.03
    summed_again = reused = 0
    for share in (0.05, 0.5, 1.0, 0.2, 0.05, 1.0):
        dirty = rng.choice(covered, int(share * len(covered)), replace=False).astype(np.int64)
        # A cell no reading covers any more may be dirty too (a reading just left).
        dirty = np.concatenate([dirty, np.flatnonzero(cov == 0)[:50]])
        mark = np.zeros(GRID.size, np.bool_)
        mark[dirty] = True
        sel = touching(
            pool.alive, pool.box, pool.f_start, pool.f_len, pool.o_len, pool.cell, mark,
            0, GRID.rows, 0, GRID.cols,
        )  # fmt: skip
        x_start = x_ref.copy()
        g_ref = np.zeros(GRID.size)
        _entry_steps(
            sel,
            entries.f_start,
            entries.f_len,
            entries.o_start,
            entries.o_len,
            entries.f_sum,
            entries.o_sum,
            entries.echo,
            entries.cell,
            entries.w,
            x_ref,
            g_ref,
            mark,
            dirty,
            cov,
            k_ref,
            a1,
            a2,
            step,
            STREAM_STEP_CAP,
            n_steps,
        )
        g = np.zeros(GRID.size)
        before = known_at.copy()
        _stream_steps(
            sel,
            *pool.span_terms(),
            x,
            g,
            dirty,
            cov,
            k,
            a1,
            a2,
            stream_step_sizes(step),
            n_steps,
            known,
            known_at,
            drift,
        )
        # The steps moved most of the covered dirty cells (the test is not of a no-op).
        live = dirty[cov[dirty] > 0]
        assert np.mean(x_ref[live] != x_start[live]) > 0.5
        np.testing.assert_array_equal(x.view(np.int64), x_ref.view(np.int64))
        np.testing.assert_array_equal(k, k_ref)
        np.testing.assert_array_equal(g.view(np.int64), g_ref.view(np.int64))
        seen = np.isfinite(before[sel])
        summed_again += int(np.sum(seen & (known_at[sel] > before[sel])))
        reused += int(np.sum(seen & (known_at[sel] == before[sel])))
    assert reused > 0
    if step > 1:
        assert summed_again > 0


class _SpanStream(GradientStream):
    """The streaming gradient without folding leaving readings in (the entry-by-entry
    step below has no fold; the fold is the same code for both)."""

    fold = False


class _EntryStream(_SpanStream):
    """The streaming gradient with the entry-by-entry step: the definition."""

    spans = False

    def _run(self, sel: I64, dirty: I64, n: int) -> None:
        m = self.mapper
        assert isinstance(m, GradientMapper)
        p = self.pool
        # The entry-by-entry step gathers the gradient of the marked cells only.
        self._mark[dirty] = True
        _entry_steps(
            sel,
            p.f_start,
            p.f_len,
            p.o_start,
            p.o_len,
            p.f_sum,
            p.o_sum,
            p.echo,
            p.cell,
            p.w,
            self.x,
            self._g,
            self._mark,
            dirty,
            self.cov,
            self._k,
            m.a1,
            m.a2,
            STEP["pgd"],
            STREAM_STEP_CAP,
            n,
        )
        self._mark[dirty] = False


def _check_known(engine: GradientStream) -> None:
    """Every known X of a term in play is within the map's moves since of its X now
    (what lets the step skip the sum)."""
    p = engine.pool
    for s in p.alive_slots():
        for part, (a, n, tot) in enumerate(
            [(p.fs_start[s], p.fs_len[s], p.f_sum[s]), (p.os_start[s], p.os_len[s], p.o_sum[s])]
        ):
            if not np.isfinite(engine._known_at[s, part]):
                continue
            now = sum(
                float(p.sp_w[q]) * engine.x[p.sp_cell[q] : p.sp_cell[q] + p.sp_len[q]].sum()
                for q in range(a, a + n)
            )
            moved = engine._drift[0] - engine._known_at[s, part]
            assert abs(engine._known[s, part] - now / tot) <= moved + 1e-9


@pytest.mark.parametrize(("strategy", "effort"), [("last:150", 1), ("cell:3", 2)])
def test_stream_maps_are_the_entry_by_entry_maps(
    doorways: Scenario, strategy: str, effort: int
) -> None:
    """Whole streams, with slots reused, arenas compacted and whole-map improvement
    between updates: the same map, bit for bit."""
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    mapper = GradientMapper()
    engines = [
        cls(mapper, g, rig.sensor, parse_strategy(strategy), effort)
        for cls in (_SpanStream, _EntryStream)
    ]
    fast, slow = engines
    for i, batch in enumerate(time_batches([r], 0.5)):
        for engine in engines:
            engine.add(batch)
            if i % 7 == 3:
                engine._run(engine.pool.alive_slots(), np.flatnonzero(engine.cov > 0), 1)
        assert fast.pool.n_alive == slow.pool.n_alive
        _check_known(fast)
    np.testing.assert_array_equal(fast.x.view(np.int64), slow.x.view(np.int64))
    np.testing.assert_array_equal(fast._k, slow._k)
    assert np.isfinite(fast._known_at).sum() > 0
