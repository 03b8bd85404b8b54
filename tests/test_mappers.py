"""Every registered mapper honours the shared contract; method-specific behaviour."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import MAPPERS, NotFittedError, make_mapper, parse_params
from sonarmap.metrics import agreement
from sonarmap.raster import beam_cells
from sonarmap.readings import Readings
from sonarmap.scenarios import Scenario


def beyond_every_beam(scene: Scenario, margin: float = 0.5) -> npt.NDArray[np.bool_]:
    """Cells outside every reading's beam cut at its range plus ``margin`` metres: no
    method's footprint reaches them."""
    r = scene.readings
    reach = np.minimum(r.range + margin, scene.rig.sensor.r_max)
    cs = beam_cells(scene.truth.grid, scene.rig.sensor, r.x, r.y, r.theta, max_range=reach)
    out = np.ones(scene.truth.grid.size, dtype=np.bool_)
    out[cs.cells] = False
    return out.reshape(scene.truth.grid.shape)


@pytest.mark.parametrize(
    "method",
    [pytest.param(m, marks=pytest.mark.slow) if m == "stochastic" else m for m in sorted(MAPPERS)],
)
def test_contract(method: str, doorways: Scenario) -> None:
    mapper = make_mapper(method)
    assert set(mapper.get_params()) == set(type(mapper).param_names())
    with pytest.raises(NotFittedError, match="fit"):
        _ = mapper.occupancy_
    grid = doorways.truth.grid
    mapper.fit(doorways.readings, grid, doorways.rig)
    occ = mapper.occupancy_
    assert occ.shape == grid.shape
    assert occ.dtype == np.float32
    known = occ[np.isfinite(occ)]
    assert known.size > 0
    assert np.all((known >= 0) & (known <= 1))
    # Cells no beam reaches stay unknown (NaN), and there are such cells here.
    unreached = beyond_every_beam(doorways)
    assert unreached.sum() > 100
    assert np.isnan(occ[unreached]).all()
    # The map says something of every class (how well is the claims' business).
    assert {-1, 0, 1} <= set(np.unique(mapper.result().classes()).tolist())
    # Streaming in two halves: exactly one batch's map where the method promises it,
    # otherwise the same cells known and nearly the same binarised map.
    half = len(doorways.readings) // 2
    idx = np.arange(len(doorways.readings))
    streamed = make_mapper(method).start(grid, doorways.rig)
    streamed.partial_fit(doorways.readings.take(idx[:half]))
    streamed.partial_fit(doorways.readings.take(idx[half:]))
    got = streamed.occupancy_
    if type(mapper).exact_streaming:
        np.testing.assert_allclose(got, occ, equal_nan=True, rtol=1e-6)
    else:
        np.testing.assert_array_equal(np.isnan(got), np.isnan(occ))
        agree, n = agreement(OccupancyMap(grid, got), OccupancyMap(grid, occ))
        assert n > 0
        if method == "stochastic":
            # A random search is no closer to itself: the two halves' map must agree
            # with one batch's about as well as another seed's does (70 % here).
            other = make_mapper(method, seed=1).fit(doorways.readings, grid, doorways.rig)
            same, _ = agreement(other.result(), OccupancyMap(grid, occ))
            assert agree > same - 0.05
        else:
            assert agree > 0.97


@pytest.mark.parametrize("method", sorted(MAPPERS))
def test_unknown_parameter_is_named(method: str) -> None:
    with pytest.raises(
        ConfigError, match=f"unknown parameter\\(s\\) \\['bogus'\\] for method '{method}'; valid:"
    ):
        make_mapper(method, bogus=1)


def test_unknown_method_lists_valid() -> None:
    with pytest.raises(
        ConfigError,
        match=(
            "unknown method 'magic'; valid: counting, em, em-thrun, gradient, inverse, stochastic"
        ),
    ):
        make_mapper("magic")


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"p_occ": 0.4}, r"parameter 'p_occ' must be in \(0.5, 1.0\)"),
        ({"p_free": 0.5}, r"parameter 'p_free' must be in \(0.0, 0.5\)"),
        ({"clamp_max": 1.0}, r"parameter 'clamp_max' must be in"),
        ({"falloff_deg": -1.0}, r"parameter 'falloff_deg' must be in \[0.0, inf\]"),
        ({"no_echo": "maybe"}, r"parameter 'no_echo' must be one of free, ignore"),
        ({"dr": float("nan")}, r"parameter 'dr' must be a finite number"),
    ],
)
def test_inverse_parameter_ranges(params: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make_mapper("inverse", **params)


def test_parse_params_types() -> None:
    assert parse_params("inverse", {"p_occ": "0.8", "no_echo": "ignore", "dr": "none"}) == {
        "p_occ": 0.8,
        "no_echo": "ignore",
        "dr": None,
    }
    with pytest.raises(ConfigError, match="parameter 'p_occ' expects a number, got 'x'"):
        parse_params("inverse", {"p_occ": "x"})


def one_reading(r: float) -> Readings:
    return Readings(
        np.zeros(1),
        np.zeros(1, np.int32),
        np.array([0.05]),
        np.array([0.55]),
        np.zeros(1),
        np.array([r]),
        ("s",),
    )


def test_inverse_update_rule_and_clamping() -> None:
    from sonarmap.rig import Mount, Rig
    from sonarmap.sensors import Region, SensorModel

    sensor = SensorModel("pencil", Region.cone(2.0, 2.0), 0.0, 2.0, 0.05)
    rig = Rig(sensor, (Mount("s", 0, 0, 0),))
    grid = Grid(0.1, (0.0, 0.0), (11, 20))
    # The band centred on the echo, so that the cell at 1.0 m is the occupied one.
    m = make_mapper(
        "inverse",
        p_occ=0.7,
        p_free=0.4,
        falloff_deg=0.0,
        clamp_min=0.2,
        clamp_max=0.9,
        band_offset=0.0,
    ).start(grid, rig)
    m.partial_fit(one_reading(1.0))
    occ = m.occupancy_
    row = 5
    assert occ[row, 3] == pytest.approx(0.4)  # free cell in front, one update
    assert occ[row, 10] == pytest.approx(0.7)  # the cell at 1.0 m
    assert np.isnan(occ[row, 15])  # beyond the band: untouched
    for _ in range(20):
        m.partial_fit(one_reading(1.0))
    assert m.occupancy_[row, 10] == pytest.approx(0.9)
    assert m.occupancy_[row, 3] == pytest.approx(0.2)
    ignore = make_mapper("inverse", no_echo="ignore").start(grid, rig)
    ignore.partial_fit(one_reading(2.0))
    assert np.isnan(ignore.occupancy_).all()
    clear = make_mapper("inverse", no_echo="free").start(grid, rig)
    clear.partial_fit(one_reading(2.0))
    assert np.nanmax(clear.occupancy_) < 0.5


def test_counting_votes() -> None:
    from sonarmap.rig import Mount, Rig
    from sonarmap.sensors import Region, SensorModel

    sensor = SensorModel("pencil", Region.cone(2.0, 2.0), 0.0, 2.0, 0.05)
    rig = Rig(sensor, (Mount("s", 0, 0, 0),))
    grid = Grid(0.1, (0.0, 0.0), (11, 20))
    m = make_mapper("counting", band_offset=0.0).start(grid, rig)
    m.partial_fit(one_reading(1.0))
    m.partial_fit(one_reading(1.0))
    m.partial_fit(one_reading(0.5))
    occ = m.occupancy_
    # The cell at 1.0 m: two "occupied" votes and one "free" (it lies beyond 0.5 m? no:
    # the 0.5 m reading's beam ends at 0.6 m, so only the two hits count).
    assert occ[5, 10] == pytest.approx(1.0)
    # The cell at 0.5 m: two "free" votes and one "occupied" -> (O + C) / 2C = 1/3.
    assert occ[5, 5] == pytest.approx(1 / 3)
