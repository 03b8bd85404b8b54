"""The inverse model's fall-off, inserted without footprints, against a footprint reference.

The insertion kernel weighs each cell by its angle off the beam axis as it visits it,
from a fitted polynomial or from atan2 and exp. The reference here takes each reading's
cells from the rasteriser, computes their angles in float64 from the cell centres and
applies the weighted increments one reading at a time.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from conftest import cone_sensor, poses, zoned_sensor
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.metrics import agreement
from sonarmap.raster import FIT_TOL, accumulate, falloff_fit, rasterise
from sonarmap.readings import Readings
from sonarmap.rig import Mount, Rig
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.sensors import Region, SensorModel, get_sensor

GRID = Grid(resolution=0.1, origin=(-2.0, -2.0), shape=(40, 40))
Values = tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]


def bearings(
    grid: Grid, cells: npt.NDArray[np.int32], x: float, y: float, th: float
) -> npt.NDArray[np.float64]:
    """Angle of each cell centre off the axis of a beam posed at (x, y, th); 0 at the
    sensor, as the rasteriser has it."""
    xc, yc = grid.all_centres()
    dx, dy = xc.ravel()[cells] - x, yc.ravel()[cells] - y
    c, s = math.cos(th), math.sin(th)
    b = np.arctan2(-dx * s + dy * c, dx * c + dy * s)
    return np.where(np.hypot(dx, dy) < 1e-9, 0.0, b)


def reference(
    grid: Grid,
    sensor: SensorModel,
    poses: tuple[list[float], list[float], list[float], list[float]],
    inc: tuple[float, float],
    clamp: tuple[float, float],
    falloff: float,
    dr: float | None = None,
    offset: float = 0.0,
) -> tuple[Values, int]:
    """Per reading, its weighted increments on its free then its occupied cells."""
    xs, ys, ths, rs = poses
    fp = rasterise(grid, sensor, xs, ys, ths, rs, dr=dr, offset=offset)
    values = np.zeros(grid.size)
    touched = np.zeros(grid.size, dtype=bool)
    for i in range(len(xs)):
        for cells, add in ((fp.free.of(i), inc[0]), (fp.occ.of(i), inc[1])):
            w: float | npt.NDArray[np.float64] = 1.0
            if falloff > 0:
                w = np.exp(-0.5 * (bearings(grid, cells, xs[i], ys[i], ths[i]) / falloff) ** 2)
            values[cells] = np.clip(values[cells] + add * w, *clamp)
            touched[cells] = True
    return (values, touched), fp.n_entries


@settings(max_examples=80, deadline=None)
# The sensor on a cell centre, in a row's centre line: its own cell and row.
@example(pose=(0.05, 0.05, 0.3, 1.0), aperture=30.0, falloff_deg=20.0, zoned=False)
@example(pose=(0.05, 0.05, math.pi / 2, 1.0), aperture=90.0, falloff_deg=15.0, zoned=False)
# Beyond the grid's corner, looking in; a no-echo reading.
@example(pose=(-2.3, -2.4, 0.8, 2.0), aperture=30.0, falloff_deg=20.0, zoned=False)
@example(pose=(1.0, -0.5, 2.5, 3.2), aperture=30.0, falloff_deg=20.0, zoned=False)
@given(
    pose=poses,
    aperture=st.floats(5.0, 170.0),
    falloff_deg=st.floats(3.0, 40.0),
    zoned=st.booleans(),
)
def test_falloff_insertion_matches_the_footprint_reference(
    pose: tuple[float, float, float, float], aperture: float, falloff_deg: float, zoned: bool
) -> None:
    sensor = zoned_sensor() if zoned else cone_sensor(aperture)
    falloff = math.radians(falloff_deg)
    x, y, th, r = pose
    # Three readings from nearby poses, so that clamping order matters.
    p = ([x, x + 0.03, x], [y, y, y - 0.07], [th, th + 0.2, th], [r, r, r * 0.7])
    (want, want_t), entries = reference(GRID, sensor, p, (-0.4, 0.9), (-1.0, 1.5), falloff)
    got = np.zeros(GRID.size)
    got_t = np.zeros(GRID.size, dtype=bool)
    n = accumulate(
        GRID,
        sensor,
        *p,
        got,
        got_t,
        inc_free=-0.4,
        inc_occ=0.9,
        clamp=(-1.0, 1.5),
        falloff=falloff,
    )
    assert n == entries
    np.testing.assert_array_equal(got_t, want_t)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-8)


@pytest.mark.parametrize("name", ["polaroid-6500", "hc-sr04", "maxsonar-ez1"])
def test_polynomial_weight_is_the_exact_weight(name: str) -> None:
    """Many readings on a 20 m map, weighted by the polynomial where it reaches and by
    atan2 and exp everywhere: the same map to well below float32 rounding."""
    from sonarmap._raster_kernel import accumulate_kernel

    sensor = get_sensor(name)
    grid = Grid.from_bounds(0.0, 0.0, 20.0, 20.0, 0.05)
    rng = np.random.default_rng(5)
    n = 3000
    x, y = rng.uniform(-1, 21, n), rng.uniform(-1, 21, n)
    th, r = rng.uniform(-4, 4, n), rng.uniform(0.1, sensor.r_max * 1.05, n)
    free_lim = np.where(r < sensor.r_max, r - 0.05, sensor.r_max - 0.05)
    occ_hi = np.where(r < sensor.r_max, r + 0.05, -np.inf)
    sigma = math.radians(20.0)
    coef = falloff_fit(sensor, sigma)[1]
    assert coef, "the defaults' fall-off has a polynomial on every built-in sensor"
    out = []
    for c in (coef, ()):
        v = np.zeros(grid.size)
        t = np.zeros(grid.size, dtype=bool)
        k = accumulate_kernel(
            v,
            t,
            grid.resolution,
            *grid.origin,
            grid.rows,
            grid.cols,
            x,
            y,
            th,
            free_lim,
            occ_hi,
            np.ascontiguousarray(sensor.beam.halfplanes),
            sensor.beam.radius,
            -0.2,
            0.04,
            -2.0,
            3.5,
            sigma,
            c,
        )
        out.append((k, v, t))
    (k1, v1, t1), (k2, v2, t2) = out
    assert k1 == k2
    np.testing.assert_array_equal(t1, t2)
    assert t1.sum() > 10_000
    np.testing.assert_allclose(v1, v2, rtol=0, atol=1e-9 * 50)


@pytest.mark.parametrize("name", ["polaroid-6500", "hc-sr04", "maxsonar-ez1"])
@pytest.mark.parametrize("falloff_deg", [5.0, 10.0, 20.0, 30.0])
def test_falloff_fit_is_within_tolerance_over_the_beam(name: str, falloff_deg: float) -> None:
    sensor = get_sensor(name)
    sigma = math.radians(falloff_deg)
    u_max, coef = falloff_fit(sensor, sigma)
    if not coef:
        assert u_max == 0.0
        return
    pts = sensor.beam.outline[1:]
    widest = float(np.abs(np.arctan2(pts[:, 1], pts[:, 0])).max())
    assert math.tan(widest) ** 2 < u_max
    u = np.linspace(0.0, u_max, 100_001)
    exact = np.exp(-0.5 * (np.arctan(np.sqrt(u)) / sigma) ** 2)
    assert np.abs(np.polynomial.polynomial.polyval(u, coef) - exact).max() <= FIT_TOL * 1.01


def test_beam_half_angle_from_the_half_planes() -> None:
    from sonarmap.raster import _beam_half_angle

    assert math.degrees(_beam_half_angle(cone_sensor(30.0))) == pytest.approx(15.0)
    assert math.degrees(_beam_half_angle(cone_sensor(170.0))) == pytest.approx(85.0)
    assert math.degrees(_beam_half_angle(get_sensor("maxsonar-ez1"))) == pytest.approx(45.0)
    widest = math.degrees(math.atan2(1.0, 2.5))
    assert math.degrees(_beam_half_angle(zoned_sensor())) == pytest.approx(widest)

    def polygon(pts: list[list[float]]) -> SensorModel:
        return SensorModel("p", Region.polygon(pts), r_min=0.0, r_max=3.0, range_resolution=0.02)

    # Ahead of the sensor, off its apex; and all round it.
    ahead = polygon([[0.5, -1.0], [2.0, -1.0], [2.0, 1.0], [0.5, 1.0]])
    assert _beam_half_angle(ahead) == pytest.approx(math.atan2(1.0, 0.5))
    around = polygon([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    assert _beam_half_angle(around) == pytest.approx(math.pi)


def test_falloff_fit_gives_up_on_wide_beams_and_no_falloff() -> None:
    assert falloff_fit(cone_sensor(170.0), math.radians(20.0)) == (0.0, ())
    assert falloff_fit(get_sensor("polaroid-6500"), 0.0) == (0.0, ())
    assert falloff_fit(get_sensor("polaroid-6500"), math.radians(20.0))[1]

    def one_reading(values: npt.NDArray[np.float64], falloff: float = 0.0) -> None:
        touched = np.zeros(GRID.size, bool)
        accumulate(
            GRID,
            cone_sensor(30.0),
            [0],
            [0],
            [0],
            [1],
            values,
            touched,
            inc_free=-1,
            inc_occ=1,
            falloff=falloff,
        )

    with pytest.raises(ConfigError, match="contiguous"):
        one_reading(np.zeros(2 * GRID.size)[::2])
    with pytest.raises(ConfigError, match="falloff"):
        one_reading(np.zeros(GRID.size), falloff=-0.1)


def _logit(p: float) -> float:
    return math.log(p / (1 - p))


def reference_map(mapper: InverseMapper, readings: Readings, grid: Grid, rig: Rig) -> Values:
    """What the mapper's parameters make of the readings, by :func:`reference`."""
    s = rig.sensor
    if mapper.no_echo == "ignore":
        readings = readings.take(readings.range < s.r_max)
    poses = (
        readings.x.tolist(),
        readings.y.tolist(),
        readings.theta.tolist(),
        readings.range.tolist(),
    )
    (values, touched), _ = reference(
        grid,
        s,
        poses,
        (_logit(mapper.p_free), _logit(mapper.p_occ)),
        (_logit(mapper.clamp_min), _logit(mapper.clamp_max)),
        math.radians(mapper.falloff_deg),
        dr=mapper.dr,
        offset=mapper.band_offset_for(grid),
    )
    return values, touched


def assert_same_map(mapper: InverseMapper, readings: Readings, grid: Grid, rig: Rig) -> None:
    want, want_t = reference_map(mapper, readings, grid, rig)
    mapper.fit(readings, grid, rig)
    np.testing.assert_array_equal(mapper.touched_, want_t)
    np.testing.assert_allclose(mapper.log_odds_, want, rtol=0, atol=1e-7)
    p = np.where(want_t, 1 / (1 + np.exp(-want)), np.nan).astype(np.float32)
    ref = OccupancyMap(grid, p.reshape(grid.shape))
    np.testing.assert_array_equal(mapper.result().classes(), ref.classes())
    agree, n = agreement(mapper.result(), ref)
    assert n > 0
    assert agree == 1.0


@pytest.mark.parametrize("params", [{}, {"no_echo": "free"}, {"falloff_deg": 8.0}])
def test_mapper_defaults_match_the_reference_on_doorways(
    doorways: Scenario, params: dict[str, object]
) -> None:
    mapper = make_mapper("inverse", **params)
    assert isinstance(mapper, InverseMapper)
    assert_same_map(mapper, doorways.readings, doorways.truth.grid, doorways.rig)


def test_mapper_matches_the_reference_with_no_echo_readings() -> None:
    scene = make_scenario("room-turn")
    assert (scene.readings.range >= scene.rig.sensor.r_max).any()
    for no_echo in ("free", "ignore"):
        mapper = make_mapper("inverse", no_echo=no_echo)
        assert isinstance(mapper, InverseMapper)
        assert_same_map(mapper, scene.readings, scene.truth.grid, scene.rig)


@pytest.mark.parametrize("name", ["polaroid-6500", "hc-sr04"])
def test_mapper_matches_the_reference_for_cone_sonars(name: str) -> None:
    """Readings from all over a small map, some from outside it, some without echo."""
    sensor = get_sensor(name)
    rig = Rig(sensor, (Mount("s", 0, 0, 0),))
    grid = Grid.from_bounds(0.0, 0.0, 6.0, 5.0, 0.05)
    rng = np.random.default_rng(11)
    n = 300
    ranges = rng.uniform(0.1, sensor.r_max, n)
    ranges[rng.random(n) < 0.2] = sensor.r_max
    readings = Readings(
        np.arange(n, dtype=float),
        np.zeros(n, np.int32),
        rng.uniform(-0.5, 6.5, n),
        rng.uniform(-0.5, 5.5, n),
        rng.uniform(-np.pi, np.pi, n),
        ranges,
        ("s",),
    )
    for no_echo in ("free", "ignore"):
        mapper = make_mapper("inverse", no_echo=no_echo)
        assert isinstance(mapper, InverseMapper)
        assert_same_map(mapper, readings, grid, rig)
