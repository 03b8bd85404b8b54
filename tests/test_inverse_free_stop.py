"""The inverse's free region stopped short of the echo (``free_stop``; issue 39)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.raster import accumulate, rasterise
from sonarmap.readings import Readings
from sonarmap.sensors import Region, SensorModel, get_sensor
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
    # The insertion clears and marks the same cells the footprint lists, no others
    # (the cells between the free region and the band stay untouched), once each.
    got, got_t = np.zeros(GRID.size), np.zeros(GRID.size, dtype=bool)
    n = accumulate(*args, got, got_t, inc_free=-1.0, inc_occ=1.0, dr=0.05, free_stop=0.25)
    want = np.zeros(GRID.size)
    np.add.at(want, short.free.cells, -1.0)
    np.add.at(want, short.occ.cells, 1.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    want_t = np.zeros(GRID.size, dtype=bool)
    want_t[short.free.cells] = want_t[short.occ.cells] = True
    np.testing.assert_array_equal(got_t, want_t)
    assert n == short.n_entries
    with pytest.raises(ConfigError, match="free_stop"):
        rasterise(*args, free_stop=1.0)


def _footprint_map(rd: Readings, stop: float) -> npt.NDArray[np.float32]:
    """The default inverse's map of ``rd`` built from :func:`rasterise`'s footprints
    (the path the incidence weighting takes), with the free regions stopped ``stop``
    short: increments, fall-off and clamps as the mapper's, reading by reading."""
    sensor, m = get_sensor("hc-sr04"), InverseMapper()
    echo = rd.range < sensor.r_max
    fp = rasterise(
        GRID,
        sensor,
        rd.x[echo],
        rd.y[echo],
        rd.theta[echo],
        rd.range[echo],
        dr=m.dr,
        offset=m.band_offset_for(GRID),
        with_bearing=True,
        free_stop=stop,
    )
    sigma = math.radians(m.falloff_deg)
    lo, hi = (math.log(p / (1 - p)) for p in (m.clamp_min, m.clamp_max))
    v, seen = np.zeros(GRID.size), np.zeros(GRID.size, dtype=bool)
    for i in range(fp.free.n_readings):
        for cs, p in ((fp.free, m.p_free), (fp.occ, m.p_occ)):
            assert cs.bearing is not None
            b = cs.bearing[cs.offsets[i] : cs.offsets[i + 1]].astype(np.float64)
            c = cs.of(i)
            v[c] = np.clip(v[c] + math.log(p / (1 - p)) * np.exp(-(b * b) / (2 * sigma**2)), lo, hi)
            seen[c] = True
    occ = 1.0 / (1.0 + np.exp(-v))
    occ[~seen] = np.nan
    return np.asarray(occ, dtype=np.float32).reshape(GRID.shape)


def test_the_two_insertion_paths_agree_with_the_stop_on_and_off() -> None:
    """The insertion kernel (the default path) and the footprints (``specular_deg > 0``)
    give one map, unknown cells included, with the option off and on."""
    rd, sensor = _readings(), get_sensor("hc-sr04")
    share = 1.0 - math.cos(math.radians(15.0))
    for stop in (0.0, share):
        got = make_mapper("inverse", free_stop=stop).fit(rd, GRID, sensor).result().occupancy
        want = _footprint_map(rd, stop)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6, equal_nan=True)
    beam = InverseMapper(free_stop="beam")
    assert beam.free_stop_for(sensor) == pytest.approx(share, abs=1e-9)
    by_share = make_mapper("inverse", free_stop=share).fit(rd, GRID, sensor).result().occupancy
    np.testing.assert_array_equal(beam.fit(rd, GRID, sensor).result().occupancy, by_share)
    # Fewer cells are marked free with the stop, none more.
    base = make_mapper("inverse").fit(rd, GRID, sensor).result().occupancy
    n_free = [int(np.sum(np.nan_to_num(m, nan=1.0) < 0.5)) for m in (base, by_share)]
    assert n_free[1] < n_free[0]
    for bad in (-0.1, 1.0, "wide"):
        with pytest.raises(ConfigError, match="free_stop"):
            make_mapper("inverse", free_stop=bad)


def test_beam_is_refused_by_name_for_a_beam_reaching_90_degrees() -> None:
    # A box beside the sonar: its corners lie 90 degrees off the axis.
    box = Region.polygon([(0.0, -1.0), (3.0, -1.0), (3.0, 1.0), (0.0, 1.0)])
    wide = SensorModel("wide", box, r_min=0.0, r_max=3.0, range_resolution=0.01)
    with pytest.raises(ConfigError, match="free_stop='beam' needs a beam narrower than 90"):
        InverseMapper(free_stop="beam").free_stop_for(wide)


def test_a_bounded_stream_refuses_the_stop() -> None:
    sensor = get_sensor("hc-sr04")
    with pytest.raises(ConfigError, match="free_stop=0"):
        StreamingMapper("inverse", GRID, sensor, strategy="cell:4", falloff_deg=0.0, free_stop=0.1)
