"""An echo band whose half-width grows with the range (``band_growth``; issue 39's
HC-SR04 margin)."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
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


def test_zero_growth_is_the_fixed_band_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    n = 40
    x, y = rng.uniform(0.5, 9.0, n), rng.uniform(0.5, 2.5, n)
    th, r = rng.uniform(-np.pi, np.pi, n), rng.uniform(0.1, 4.5, n)
    a = rasterise(GRID, HCSR04, x, y, th, r)
    b = rasterise(GRID, HCSR04, x, y, th, r, band_growth=0.0)
    for p, q in ((a.free, b.free), (a.occ, b.occ)):
        assert np.array_equal(p.offsets, q.offsets)
        assert np.array_equal(p.cells, q.cells)
        assert np.array_equal(p.weight, q.weight)


def test_no_echo_readings_do_not_move() -> None:
    """A no-echo reading's free region ends at r_max - dr whatever the growth."""
    r = [HCSR04.r_max, 1.0]
    a = rasterise(GRID, HCSR04, [0.1, 0.1], [1.5, 1.5], [0.0, 0.0], r)
    b = rasterise(GRID, HCSR04, [0.1, 0.1], [1.5, 1.5], [0.0, 0.0], r, band_growth=0.05)
    assert np.array_equal(a.free.of(0), b.free.of(0))
    assert len(b.occ.of(0)) == 0


def test_bad_growth_refused() -> None:
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="band_growth"):
            rasterise(GRID, HCSR04, [0.1], [1.5], [0.0], [1.0], band_growth=bad)
    with pytest.raises(ConfigError, match="band_growth"):
        GradientMapper(band_growth=-1.0)


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
    (they end where the wider band begins); at 0 the problem is the default's."""
    rd = _readings()
    base = GradientMapper().start(GRID, HCSR04).problem(rd)
    same = GradientMapper(band_growth=0.0).start(GRID, HCSR04).problem(rd)
    assert (base.W != same.W).nnz == 0
    grown = GradientMapper(band_growth=0.02).start(GRID, HCSR04).problem(rd)
    occ_n = np.diff(grown.W.indptr)[grown.is_occ].sum()
    assert occ_n > np.diff(base.W.indptr)[base.is_occ].sum()
    assert np.diff(grown.W.indptr)[~grown.is_occ].sum() < np.diff(base.W.indptr)[~base.is_occ].sum()


def test_stream_takes_the_growth() -> None:
    """The stream rasterises with the mapper's growth: its map differs from the fixed
    band's and equals a second run's."""
    rd = _readings()

    def run(growth: float) -> np.ndarray:
        s = StreamingMapper(GradientMapper(band_growth=growth), GRID, HCSR04, strategy="last:50")
        s.add(rd)
        return np.nan_to_num(s.occupancy_, nan=-1.0)

    a, b, c = run(0.0), run(0.03), run(0.03)
    assert np.array_equal(b, c)
    assert not np.array_equal(a, b)
