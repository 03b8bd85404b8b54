"""The Omega_occ band moved behind the echo (``offset``; the mappers' ``band_offset``)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import cone_sensor, poses
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.raster import accumulate, rasterise
from sonarmap.scenarios import Scenario
from sonarmap.sensors import Region, SensorModel

GRID = Grid(resolution=0.1, origin=(-2.0, -2.0), shape=(40, 40))


def _cells(fp_set_cells: np.ndarray) -> list[int]:
    return sorted(fp_set_cells.tolist())


@settings(max_examples=60, deadline=None)
@given(pose=poses, offset=st.floats(0.0, 0.2), dr=st.floats(0.0, 0.1))
def test_offset_is_the_band_of_a_longer_echo(
    pose: tuple[float, float, float, float], offset: float, dr: float
) -> None:
    # For an echo, the band at r + offset; a no-echo reading is not moved.
    s = cone_sensor(30.0)
    x, y, th, r = pose
    moved = rasterise(GRID, s, [x, x], [y, y], [th, th], [r, s.r_max], dr=dr, offset=offset)
    want_r = r + offset if r < s.r_max else s.r_max + offset
    want = rasterise(GRID, s, [x, x], [y, y], [th, th], [want_r, s.r_max], dr=dr)
    for got_set, want_set in ((moved.free, want.free), (moved.occ, want.occ)):
        assert _cells(got_set.of(1)) == _cells(want_set.of(1))
        if want_r < s.r_max:
            assert _cells(got_set.of(0)) == _cells(want_set.of(0))
    assert len(moved.occ.of(1)) == 0


@settings(max_examples=30, deadline=None)
@given(pose=poses, offset=st.floats(0.0, 0.2))
def test_accumulate_takes_the_same_band(
    pose: tuple[float, float, float, float], offset: float
) -> None:
    s = cone_sensor(40.0)
    x, y, th, r = pose
    fp = rasterise(GRID, s, [x], [y], [th], [r], offset=offset)
    values = np.zeros(GRID.size)
    touched = np.zeros(GRID.size, bool)
    accumulate(
        GRID, s, [x], [y], [th], [r], values, touched, inc_free=-1.0, inc_occ=1.0, offset=offset
    )
    assert _cells(np.flatnonzero(values > 0)) == _cells(fp.occ.cells)
    assert _cells(np.flatnonzero(values < 0)) == _cells(fp.free.cells)


def test_band_at_the_surface_is_half_the_time_the_free_cell() -> None:
    # A wall whose face lies anywhere between two cell centres, heard square-on by a
    # narrow beam along a row of 10 cm cells. Truth: a cell is occupied when its centre
    # is inside the wall. A band of half a cell either side of the range holds the
    # first occupied cell only when the face is in the cell's nearer half; moved half a
    # cell behind the echo it always does, and the free region never reaches it.
    grid = Grid(0.1, (0.0, 0.0), (1, 40))
    s = SensorModel("n", Region.cone(2.0, 4.0), r_min=0.0, r_max=4.0, range_resolution=0.01)
    faces = np.linspace(2.0, 2.1, 41)[:-1] + 1e-4
    centres = grid.cell_centres(np.zeros(40, np.int64), np.arange(40))[0]
    hits = {0.0: 0, 0.05: 0}
    for face in faces:
        first = int(np.flatnonzero(centres > face)[0])
        for offset in hits:
            fp = rasterise(grid, s, [0.0], [0.05], [0.0], [face], dr=0.05, offset=offset)
            occ = fp.occ.cells.tolist()
            hits[offset] += occ == [first]
            assert all(c < first for c in fp.free.cells.tolist())
    assert hits[0.05] == len(faces)
    assert 0.4 * len(faces) <= hits[0.0] <= 0.6 * len(faces)


METHODS = ["inverse", "counting", "gradient", "em", "em-thrun", "stochastic"]


@pytest.mark.parametrize("method", METHODS)
def test_mappers_take_and_check_the_offset(method: str) -> None:
    assert make_mapper(method).get_params()["band_offset"] is None
    assert make_mapper(method, band_offset=0.025).get_params()["band_offset"] == 0.025
    with pytest.raises(ConfigError, match="band_offset"):
        make_mapper(method, band_offset=-0.01)


def test_rasteriser_refuses_a_bad_offset() -> None:
    s = cone_sensor(30.0)
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="band offset must be a non-negative"):
            rasterise(GRID, s, [0.0], [0.0], [0.0], [1.0], offset=bad)


@pytest.mark.parametrize("method", ["inverse", "gradient", "stochastic"])
def test_streaming_takes_the_mappers_offset(doorways: Scenario, method: str) -> None:
    from sonarmap.streaming import StreamingMapper

    g, rig = doorways.truth.grid, doorways.rig
    r = doorways.readings.take(np.arange(300))
    echo = r.range < rig.sensor.r_max - 0.1
    longer = dataclasses.replace(r, range=np.where(echo, r.range + 0.03, r.range))
    maps = []
    for readings, offset in ((r, 0.03), (longer, 0.0), (r, 0.0)):
        # (each explicit: a method's default may move the band itself)
        extra: dict[str, Any] = {"falloff_deg": 0.0} if method == "inverse" else {}
        sm = StreamingMapper(method, g, rig, strategy="last:1000", band_offset=offset, **extra)
        for k in range(0, len(readings), 100):
            sm.add(readings.take(np.arange(k, min(k + 100, len(readings)))))
        maps.append(np.nan_to_num(sm.occupancy_, nan=-1.0))
    np.testing.assert_allclose(maps[0], maps[1], atol=1e-5)
    assert not np.allclose(maps[0], maps[2])


@pytest.mark.parametrize(
    "method",
    [pytest.param(m, marks=pytest.mark.slow) if m == "stochastic" else m for m in METHODS],
)
def test_an_offset_map_is_the_map_of_echoes_heard_that_much_further(
    doorways: Scenario, method: str
) -> None:
    # Every model compares a range with the distances of the cells that could have
    # caused it; moving the band by the offset is hearing each echo that much further.
    g, rig = doorways.truth.grid, doorways.rig
    r = doorways.readings.take(np.arange(400))
    echo = r.range < rig.sensor.r_max - 0.1
    longer = dataclasses.replace(r, range=np.where(echo, r.range + 0.03, r.range))
    fast = {"max_iter": 30} if method == "gradient" else {}
    moved = make_mapper(method, band_offset=0.03, **fast).fit(r, g, rig).result()
    heard = make_mapper(method, band_offset=0.0, **fast).fit(longer, g, rig).result()
    np.testing.assert_allclose(moved.occupancy, heard.occupancy, atol=1e-5)
    plain = make_mapper(method, band_offset=0.0, **fast).fit(r, g, rig).result()
    assert not np.allclose(np.nan_to_num(plain.occupancy), np.nan_to_num(moved.occupancy))
