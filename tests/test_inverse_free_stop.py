"""The inverse's free region stopped short of the echo (``free_stop``; issue 39)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.raster import accumulate, rasterise
from sonarmap.readings import Readings
from sonarmap.sensors import get_sensor
from sonarmap.streaming import StreamingMapper

GRID = Grid(resolution=0.05, origin=(-1.0, -3.0), shape=(120, 120))


def _readings() -> Readings:
    # Two echoes at 2 m and 3 m and one reading with no echo.
    sensor = get_sensor("hc-sr04")
    r = np.array([2.0, 3.0, sensor.r_max])
    n = len(r)
    return Readings(
        t=np.arange(n, dtype=np.float64),
        sensor=np.zeros(n, np.int32),
        x=np.zeros(n),
        y=np.array([0.0, 0.0, 0.0]),
        theta=np.array([0.0, 0.0, -math.pi / 2]),
        range=r,
        names=("s",),
    )


def test_the_free_region_ends_a_share_of_the_range_short_and_the_band_stays() -> None:
    sensor, rd = get_sensor("hc-sr04"), _readings()
    args = (GRID, sensor, rd.x, rd.y, rd.theta, rd.range)
    full = rasterise(*args, dr=0.05)
    short = rasterise(*args, dr=0.05, free_stop=0.25)
    for i, r in enumerate((2.0, 3.0)):
        d_full = full.free.distance[full.free.offsets[i] : full.free.offsets[i + 1]]
        d_short = short.free.distance[short.free.offsets[i] : short.free.offsets[i + 1]]
        assert d_full.max() > r - 0.1
        assert d_short.max() <= 0.75 * r - 0.05 + 1e-6
        assert d_short.max() > 0.75 * r - 0.15
    # The no-echo reading's free region and every band are unchanged.
    np.testing.assert_array_equal(short.free.of(2), full.free.of(2))
    np.testing.assert_array_equal(short.occ.cells, full.occ.cells)
    # The insertion clears the same cells the footprint lists.
    got, got_t = np.zeros(GRID.size), np.zeros(GRID.size, dtype=bool)
    accumulate(*args, got, got_t, inc_free=-1.0, inc_occ=1.0, dr=0.05, free_stop=0.25)
    want = np.zeros(GRID.size)
    np.add.at(want, short.free.cells, -1.0)
    np.add.at(want, short.occ.cells, 1.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    with pytest.raises(ConfigError, match="free_stop"):
        rasterise(*args, free_stop=1.0)


def test_the_inverse_option_off_is_the_default_map_and_beam_follows_the_cone() -> None:
    rd, sensor = _readings(), get_sensor("hc-sr04")
    base = make_mapper("inverse").fit(rd, GRID, sensor).result().occupancy
    off = make_mapper("inverse", free_stop=0.0).fit(rd, GRID, sensor).result().occupancy
    np.testing.assert_array_equal(base, off)
    beam = InverseMapper(free_stop="beam")
    share = 1.0 - math.cos(math.radians(15.0))
    assert beam.free_stop_for(sensor) == pytest.approx(share, abs=1e-9)
    by_share = make_mapper("inverse", free_stop=share).fit(rd, GRID, sensor).result().occupancy
    np.testing.assert_array_equal(beam.fit(rd, GRID, sensor).result().occupancy, by_share)
    # Fewer cells are marked free with the stop, none more.
    n_free = [int(np.sum(np.nan_to_num(m, nan=1.0) < 0.5)) for m in (base, by_share)]
    assert n_free[1] < n_free[0]
    for bad in (-0.1, 1.0, "wide"):
        with pytest.raises(ConfigError, match="free_stop"):
            make_mapper("inverse", free_stop=bad)


def test_a_bounded_stream_refuses_the_stop() -> None:
    sensor = get_sensor("hc-sr04")
    with pytest.raises(ConfigError, match="free_stop=0"):
        StreamingMapper("inverse", GRID, sensor, strategy="cell:4", falloff_deg=0.0, free_stop=0.1)
