"""The inverse's free increment under its own fall-off (``falloff_free_deg``; issue 39)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.raster import rasterise
from sonarmap.readings import Readings
from sonarmap.sensors import get_sensor
from sonarmap.streaming import StreamingMapper

GRID = Grid(resolution=0.05, origin=(-1.0, -3.0), shape=(120, 120))
SENSOR = "maxsonar-ez1"


def _readings() -> Readings:
    # Echoes at 1.5-3 m from four poses facing a wall at x = 3, met head-on and at a
    # slant, twelve times each in turn: enough repeats that cells reach the clamps.
    poses = [(0.0, 0.0, 0.0), (0.0, -0.5, 0.3), (0.5, 0.5, -0.4), (-0.5, 0.0, 0.1)]
    x, y, th, r = [], [], [], []
    for _ in range(12):
        for px, py, pt in poses:
            x.append(px)
            y.append(py)
            th.append(pt)
            r.append((3.0 - px) / math.cos(pt))
    n = len(r)
    return Readings(
        t=np.arange(n, dtype=np.float64),
        sensor=np.zeros(n, np.int32),
        x=np.array(x),
        y=np.array(y),
        theta=np.array(th),
        range=np.array(r),
        names=("s",),
    )


def _by_hand(rd: Readings, m: InverseMapper) -> npt.NDArray[np.float32]:
    """``m``'s map of ``rd`` from :func:`rasterise`'s footprints: the free cells weighed
    by the free fall-off, the band by ``falloff_deg``, reading by reading, clamped."""
    sensor = get_sensor(SENSOR)
    fp = rasterise(
        GRID,
        sensor,
        rd.x,
        rd.y,
        rd.theta,
        rd.range,
        dr=m.dr,
        offset=m.band_offset_for(GRID),
        with_bearing=True,
        free_stop=m.free_stop_for(sensor),
    )
    free_deg = m.falloff_deg if m.falloff_free_deg is None else m.falloff_free_deg
    lo, hi = (math.log(p / (1 - p)) for p in (m.clamp_min, m.clamp_max))
    v, seen = np.zeros(GRID.size), np.zeros(GRID.size, dtype=bool)
    for i in range(fp.free.n_readings):
        for cs, p, deg in ((fp.free, m.p_free, free_deg), (fp.occ, m.p_occ, m.falloff_deg)):
            assert cs.bearing is not None
            b = cs.bearing[cs.offsets[i] : cs.offsets[i + 1]].astype(np.float64)
            w = np.exp(-(b * b) / (2 * math.radians(deg) ** 2)) if deg > 0 else np.ones(len(b))
            c = cs.of(i)
            v[c] = np.clip(v[c] + math.log(p / (1 - p)) * w, lo, hi)
            seen[c] = True
    occ = 1.0 / (1.0 + np.exp(-v))
    occ[~seen] = np.nan
    return np.asarray(occ, dtype=np.float32).reshape(GRID.shape)


@pytest.mark.parametrize(
    "params",
    [
        {"falloff_free_deg": 2.5},
        {"falloff_free_deg": 3.0, "falloff_deg": 0.0},
        {"falloff_free_deg": 10.0, "falloff_deg": 2.0},
        {"falloff_free_deg": 0.0},
        {"falloff_free_deg": 2.5, "free_stop": 0.1},
    ],
)
def test_each_increment_takes_its_own_fall_off(params: dict[str, float]) -> None:
    rd, sensor = _readings(), get_sensor(SENSOR)
    m = InverseMapper(**params)  # type: ignore[arg-type]
    got = m.fit(rd, GRID, sensor).result().occupancy
    want = _by_hand(rd, m)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6, equal_nan=True)
    # Some cells held at a clamp: the reading-by-reading order was exercised.
    assert np.nanmin(got) == pytest.approx(InverseMapper().clamp_min, abs=1e-6)


def test_off_or_equal_is_the_kernel_map_and_the_split_path_agrees_with_it() -> None:
    rd, sensor = _readings(), get_sensor(SENSOR)
    base = make_mapper("inverse").fit(rd, GRID, sensor).result().occupancy
    same = make_mapper("inverse", falloff_free_deg=5.0).fit(rd, GRID, sensor).result().occupancy
    np.testing.assert_array_equal(same, base)
    # A hair apart, the footprints' path: the kernel's cells and values to float32's
    # bearings (the kernel's fall-off is a fit within 1e-9 of the Gaussian).
    split = InverseMapper(falloff_free_deg=5.0 + 1e-9).fit(rd, GRID, sensor).result().occupancy
    np.testing.assert_array_equal(np.isnan(split), np.isnan(base))
    np.testing.assert_allclose(split, base, rtol=0, atol=1e-6, equal_nan=True)
    # A narrower free fall-off clears fewer cells, none more.
    narrow = InverseMapper(falloff_free_deg=2.0).fit(rd, GRID, sensor).result().occupancy
    n_free = [int(np.sum(np.nan_to_num(m, nan=1.0) < 0.5)) for m in (base, narrow)]
    assert n_free[1] < n_free[0]


def test_partial_fit_and_the_all_stream_give_the_fit_map() -> None:
    rd, sensor = _readings(), get_sensor(SENSOR)
    m = InverseMapper(falloff_free_deg=2.5)
    want = m.fit(rd, GRID, sensor).result().occupancy
    parts = InverseMapper(falloff_free_deg=2.5)
    parts.start(GRID, sensor)
    for a in range(0, len(rd), 7):
        parts.partial_fit(rd.take(slice(a, a + 7)))
    np.testing.assert_array_equal(parts.result().occupancy, want)
    sm = StreamingMapper("inverse", GRID, sensor, strategy="all", falloff_free_deg=2.5)
    sm.add(rd)
    np.testing.assert_array_equal(sm.occupancy_, want)


def test_bad_values_and_a_bounded_stream_are_refused() -> None:
    for bad in (-1.0, math.nan, "narrow", True):
        with pytest.raises(ConfigError, match="falloff_free_deg"):
            make_mapper("inverse", falloff_free_deg=bad)
    with pytest.raises(ConfigError, match="falloff_free_deg streams only"):
        StreamingMapper(
            "inverse",
            GRID,
            get_sensor(SENSOR),
            strategy="cell:4",
            falloff_deg=0.0,
            falloff_free_deg=2.0,
        )
