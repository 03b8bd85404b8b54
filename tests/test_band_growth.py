"""An echo band whose half-width grows with the range (``band_growth``; issue 39's
HC-SR04 margin)."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import ForwardProblem
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.raster import rasterise
from sonarmap.readings import Readings
from sonarmap.rig import get_rig
from sonarmap.sensors import Region, SensorModel
from sonarmap.streaming import StreamingMapper

GRID = Grid(resolution=0.05, origin=(0.0, 0.0), shape=(60, 200))
HCSR04 = get_rig("hcsr04-six").sensor
NARROW = SensorModel("narrow", Region.cone(4.0, 9.0), r_min=0.0, r_max=9.0, range_resolution=0.01)


def _band_depth(r: float, growth: float, dr: float = 0.025) -> tuple[float, float]:
    """Nearest and farthest centre of one echo's band, along a narrow beam."""
    fp = rasterise(GRID, NARROW, [0.01], [1.5], [0.0], [r], dr=dr, band_growth=growth)
    xc, yc = GRID.all_centres()
    d = np.hypot(xc.ravel()[fp.occ.cells] - 0.01, yc.ravel()[fp.occ.cells] - 1.5)
    return float(d.min()), float(d.max())


def test_band_grows_with_range_and_keeps_the_least_width() -> None:
    """max(dr, g r): near echoes keep dr, far ones take g r either side."""
    near = _band_depth(0.8, 0.02)
    assert near == _band_depth(0.8, 0.0)  # 0.02 * 0.8 = 0.016 < dr
    lo, hi = _band_depth(6.0, 0.02)  # half-width 0.12
    lo0, hi0 = _band_depth(6.0, 0.0)
    assert lo < lo0 - 0.05
    assert hi > hi0 + 0.05
    assert lo >= 6.0 - 0.12 - 1e-9
    assert hi <= 6.0 + 0.12 + 1e-9
    assert lo <= 6.0 - 0.12 + 0.05
    assert hi >= 6.0 + 0.12 - 0.05


#: A growth whose band ``g r`` is below ``dr`` at every range of these tests: the
#: per-reading path (``max(dr, g r)``) taken, each band ``dr`` wide.
TINY = 1e-6


def test_a_growth_below_dr_is_the_fixed_band_to_the_bit() -> None:
    """The per-reading band path, where no band grows, hands the kernel the fixed
    band's limits."""
    rng = np.random.default_rng(3)
    n = 40
    x, y = rng.uniform(0.5, 9.0, n), rng.uniform(0.5, 2.5, n)
    th, r = rng.uniform(-np.pi, np.pi, n), rng.uniform(0.1, 4.5, n)
    a = rasterise(GRID, HCSR04, x, y, th, r, offset=0.0375)
    b = rasterise(GRID, HCSR04, x, y, th, r, offset=0.0375, band_growth=TINY)
    assert TINY * r.max() < a.dr
    assert len(a.occ.cells) > 0
    for p, q in ((a.free, b.free), (a.occ, b.occ)):
        assert np.array_equal(p.offsets, q.offsets)
        assert np.array_equal(p.cells, q.cells)
        assert np.array_equal(p.weight, q.weight)
        assert np.array_equal(p.distance, q.distance)


def test_no_echo_readings_do_not_move() -> None:
    """A no-echo reading's free region ends at r_max - dr whatever the growth."""
    r = [HCSR04.r_max, 1.0]
    a = rasterise(GRID, HCSR04, [0.1, 0.1], [1.5, 1.5], [0.0, 0.0], r)
    b = rasterise(GRID, HCSR04, [0.1, 0.1], [1.5, 1.5], [0.0, 0.0], r, band_growth=0.05)
    assert np.array_equal(a.free.of(0), b.free.of(0))
    assert len(b.occ.of(0)) == 0


@pytest.mark.parametrize("bad", [-0.01, 1.0, 1.5, float("nan"), float("inf")])
def test_bad_growth_refused(bad: float) -> None:
    """Negative, not finite, or >= 1 (a band reaching back to the sensor) refused by
    the rasteriser and the mapper alike."""
    with pytest.raises(ConfigError, match="band_growth"):
        rasterise(GRID, HCSR04, [0.1], [1.5], [0.0], [1.0], band_growth=bad)
    with pytest.raises(ConfigError, match="band_growth"):
        GradientMapper(band_growth=bad)


def test_growth_just_below_one_taken() -> None:
    fp = rasterise(GRID, HCSR04, [0.1], [1.5], [0.0], [1.0], band_growth=0.99)
    assert len(fp.occ.cells) > 0
    assert GradientMapper(band_growth=0.99).band_growth == 0.99


def _readings() -> Readings:
    """Twelve echoes off a wall 3.5 m away, from the grid's left edge, and one
    silence."""
    r = np.r_[np.full(12, 3.5), HCSR04.r_max]
    n = len(r)
    return Readings(
        np.arange(n, dtype=np.float64) * 0.1,
        np.zeros(n, np.int32),
        np.full(n, 0.1),
        np.linspace(1.0, 2.0, n),
        np.zeros(n),
        r,
        ("s",),
    )


def test_gradient_bands_follow_the_option() -> None:
    """The gradient's occ terms cover more cells with a growth; its free terms fewer
    (they end where the wider band begins); with a growth below ``dr`` at every range
    the problem is the default's."""
    rd = _readings()
    base = GradientMapper().start(GRID, HCSR04).problem(rd)
    same = GradientMapper(band_growth=TINY).start(GRID, HCSR04).problem(rd)
    assert base.W.shape == same.W.shape
    assert np.array_equal(base.cells, same.cells)
    assert np.array_equal(base.is_occ, same.is_occ)
    assert (base.W != same.W).nnz == 0
    grown = GradientMapper(band_growth=0.02).start(GRID, HCSR04).problem(rd)
    occ_n = np.diff(grown.W.indptr)[grown.is_occ].sum()
    assert occ_n > np.diff(base.W.indptr)[base.is_occ].sum()
    assert np.diff(grown.W.indptr)[~grown.is_occ].sum() < np.diff(base.W.indptr)[~base.is_occ].sum()


def _offline_bands(problem: ForwardProblem) -> list[tuple[int, ...]]:
    """Each occ term's cells (flat grid indices), sorted; the terms sorted."""
    W, cells = problem.W, problem.cells
    rows = np.flatnonzero(problem.is_occ)
    return sorted(
        tuple(sorted(cells[W.indices[W.indptr[t] : W.indptr[t + 1]]].tolist())) for t in rows
    )


def _stream_bands(s: StreamingMapper) -> list[tuple[int, ...]]:
    """Each in-play echo's band cells as the stream keeps them, sorted; sorted."""
    pool = s.engine.pool
    out = []
    for k in pool.alive_slots().tolist():
        if pool.echo[k]:
            a = int(pool.o_start[k])
            out.append(tuple(sorted(pool.cell[a : a + int(pool.o_len[k])].tolist())))
    return sorted(out)


def test_stream_takes_the_growth() -> None:
    """The stream rasterises with the mapper's growth: its band entries are the
    offline problem's band terms at the same growth (not the fixed band's), and its map
    differs from the fixed band's and equals a second run's."""
    rd = _readings()

    def run(growth: float) -> StreamingMapper:
        s = StreamingMapper(GradientMapper(band_growth=growth), GRID, HCSR04, strategy="last:50")
        s.add(rd)
        return s

    a, b, c = run(0.0), run(0.03), run(0.03)
    grown = _offline_bands(GradientMapper(band_growth=0.03).start(GRID, HCSR04).problem(rd))
    fixed = _offline_bands(GradientMapper().start(GRID, HCSR04).problem(rd))
    assert len(grown) == 12  # one band per echo, none for the silence
    assert grown != fixed
    assert _stream_bands(b) == grown
    assert _stream_bands(a) == fixed
    occ = [np.nan_to_num(s.occupancy_, nan=-1.0) for s in (a, b, c)]
    assert np.array_equal(occ[1], occ[2])
    assert not np.array_equal(occ[0], occ[1])
