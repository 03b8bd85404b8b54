"""The streaming gradient's kernels against the entry-by-entry loops they replace.

The pool's spans are a faster layout of the same entries, in the same order.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from conftest import zoned_sensor
from sonarmap.grid import Grid
from sonarmap.mappers._pool import ReadingPool
from sonarmap.raster import rasterise

I64 = npt.NDArray[np.int64]


GRID = Grid(resolution=0.05, origin=(-3.0, -3.0), shape=(120, 120))


def _batch(rng: np.random.Generator, n: int, pool: ReadingPool) -> I64:
    """Rasterise n random readings of a sensor with a zone (two weights, so spans also
    break where the weight changes) into the pool; a fifth have no echo."""
    sensor = zoned_sensor()
    x, y = rng.uniform(-2.5, 2.5, (2, n))
    theta = rng.uniform(-math.pi, math.pi, n)
    r = rng.uniform(0.1, 3.2, n)
    r[rng.random(n) < 0.2] = sensor.r_max
    fp = rasterise(GRID, sensor, x, y, theta, r, offset=0.025)
    return pool.add(fp, np.minimum(r, sensor.r_max), r < sensor.r_max)


def _pool(seed: int) -> ReadingPool:
    """A pool after adds, removals in any order, slot reuse and compactions."""
    rng = np.random.default_rng(seed)
    pool = ReadingPool(GRID.cols, spans=True)
    live = _batch(rng, 60, pool)
    for _ in range(4):
        gone = rng.choice(live, len(live) // 3, replace=False)
        pool.remove(gone)
        live = np.concatenate([np.setdiff1d(live, gone), _batch(rng, 30, pool)])
        if rng.random() < 0.5:
            pool.compact()
    return pool


def _parts(pool: ReadingPool, s: int) -> list[tuple[int, int, int, int]]:
    return [
        (int(pool.f_start[s]), int(pool.f_len[s]), int(pool.fs_start[s]), int(pool.fs_len[s])),
        (int(pool.o_start[s]), int(pool.o_len[s]), int(pool.os_start[s]), int(pool.os_len[s])),
    ]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_spans_are_the_entries_in_order(seed: int) -> None:
    pool = _pool(seed)
    for s in pool.alive_slots():
        for a, n, sa, sn in _parts(pool, int(s)):
            cells = [
                c
                for q in range(sa, sa + sn)
                for c in range(pool.sp_cell[q], pool.sp_cell[q] + pool.sp_len[q])
            ]
            weights = np.repeat(pool.sp_w[sa : sa + sn], pool.sp_len[sa : sa + sn])
            assert cells == pool.cell[a : a + n].tolist()
            np.testing.assert_array_equal(weights, pool.w[a : a + n])
            # Maximal: a span never continues the one before it.
            for q in range(sa + 1, sa + sn):
                follows = pool.sp_cell[q] == pool.sp_cell[q - 1] + pool.sp_len[q - 1]
                assert not (follows and pool.sp_w[q] == pool.sp_w[q - 1])
    # The zone's weight splits some spans.
    assert len(np.unique(pool.sp_w[: pool.sp_end])) > 1
