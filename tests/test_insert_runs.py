"""The insertion kernel's runs: each row's band as column intervals, against each cell's
distance tested as the rasteriser tests it.

``accumulate_kernel(..., runs=False)`` decides every centre by its distance (the kernel
as it was before the runs, itself checked against the rasteriser's footprints in
``test_raster.py`` and ``test_inverse_falloff.py``); with runs it must give the same map
to the bit: the same cells, and each cell's weight from the same arithmetic.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from conftest import cone_sensor
from sonarmap._raster_kernel import accumulate_kernel
from sonarmap.grid import Grid
from sonarmap.raster import accumulate, falloff_fit
from sonarmap.sensors import SensorModel, get_sensor
from test_inverse_falloff import reference

Result = tuple[int, npt.NDArray[np.float64], npt.NDArray[np.bool_]]


def insert(
    grid: Grid,
    sensor: SensorModel,
    poses: tuple[npt.NDArray[np.float64], ...],
    limits: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
    falloff: float,
    runs: bool,
) -> Result:
    x, y, th = poses
    values = np.zeros(grid.size)
    touched = np.zeros(grid.size, dtype=bool)
    n = accumulate_kernel(
        values,
        touched,
        grid.resolution,
        *grid.origin,
        grid.rows,
        grid.cols,
        x,
        y,
        th,
        *limits,
        np.ascontiguousarray(sensor.beam.halfplanes),
        sensor.beam.radius,
        -0.2,
        0.3,
        -4.0,
        5.0,
        falloff,
        falloff_fit(sensor, falloff)[1],
        runs=runs,
    )
    return n, values, touched


def assert_same(a: Result, b: Result) -> None:
    assert a[0] == b[0]
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_array_equal(a[1], b[1])


def band(
    r: npt.NDArray[np.float64], sensor: SensorModel, dr: float, offset: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The rasteriser's free limit and band end (no band for a no-echo reading)."""
    echo = r < sensor.r_max
    return (
        np.where(echo, r + offset - dr, sensor.r_max - dr),
        np.where(echo, r + offset + dr, -np.inf),
    )


@pytest.mark.parametrize("falloff_deg", [0.0, 10.0])
@pytest.mark.parametrize("name", ["polaroid-6500", "hc-sr04", "maxsonar-ez1", "wide"])
def test_runs_are_the_per_cell_test_bit_for_bit(name: str, falloff_deg: float) -> None:
    """Random beams on a 20 m map at 5 cm, inside it, across its edges and outside."""
    sensor = cone_sensor(170.0) if name == "wide" else get_sensor(name)
    grid = Grid.from_bounds(0.0, 0.0, 20.0, 20.0, 0.05)
    rng = np.random.default_rng(11)
    n = 2000
    poses = (rng.uniform(-2, 22, n), rng.uniform(-2, 22, n), rng.uniform(-4, 4, n))
    r = rng.uniform(0.0, sensor.r_max * 1.05, n)
    limits = band(r, sensor, float(rng.uniform(0.025, 0.06)), 0.0375)
    falloff = math.radians(falloff_deg)
    fast = insert(grid, sensor, poses, limits, falloff, runs=True)
    slow = insert(grid, sensor, poses, limits, falloff, runs=False)
    assert fast[0] > 100 * n
    assert_same(fast, slow)


@pytest.mark.parametrize("falloff_deg", [0.0, 10.0])
def test_runs_decide_centres_on_a_band_edge_as_the_per_cell_test(falloff_deg: float) -> None:
    """Sensors on cell centres and corners, beams along the grid's axes and diagonals,
    and band limits within a few ulps of cell centres' distances (the kernel's test
    takes EDGE_TOL off the free limit and adds it to the band's end): the edges the
    runs cannot place for sure, which must fall back to the per-cell test."""
    sensor = cone_sensor(60.0)
    grid = Grid(resolution=0.1, origin=(-2.0, -2.0), shape=(40, 40))
    h = grid.resolution
    tol = 1e-9  # EDGE_TOL
    rows: list[tuple[float, float, float, float, float]] = []
    for x0, y0 in ((0.05, 0.05), (0.0, 0.0), (0.05, 0.0), (-1.15, 0.75)):
        for th in np.arange(8) * math.pi / 4:
            for i, j in ((3, 0), (3, 4), (0, 7), (5, 12), (10, 1)):
                dx = grid.origin[0] + (round((x0 - grid.origin[0]) / h - 0.5) + i + 0.5) * h - x0
                dy = grid.origin[1] + (round((y0 - grid.origin[1]) / h - 0.5) + j + 0.5) * h - y0
                d = math.sqrt(dx * dx + dy * dy)
                for k in range(-3, 4):
                    near = d + k * math.ulp(d)
                    # The free limit on the centre, then the band's end on it.
                    rows.append((x0, y0, th, near + tol, near + tol + 0.1))
                    rows.append((x0, y0, th, near - tol - 0.1, near - tol))
    x, y, th, free_lim, occ_hi = (np.array(c) for c in zip(*rows, strict=True))
    falloff = math.radians(falloff_deg)
    assert_same(
        insert(grid, sensor, (x, y, th), (free_lim, occ_hi), falloff, runs=True),
        insert(grid, sensor, (x, y, th), (free_lim, occ_hi), falloff, runs=False),
    )


def test_runs_visit_the_rasterisers_cells() -> None:
    """A straightforward reference: the rasteriser's footprints, weighted with atan2 and
    exp, reading by reading, on random beams of the office ring's sonar."""
    sensor = get_sensor("polaroid-6500")
    grid = Grid.from_bounds(0.0, 0.0, 8.0, 8.0, 0.05)
    rng = np.random.default_rng(4)
    n = 150
    x, y = rng.uniform(-1, 9, n), rng.uniform(-1, 9, n)
    th, r = rng.uniform(-4, 4, n), rng.uniform(0.1, 6.0, n)
    p = (x.tolist(), y.tolist(), th.tolist(), r.tolist())
    falloff = math.radians(10.0)
    (want, want_t), entries = reference(
        grid, sensor, p, (-0.2, 0.3), (-50.0, 50.0), falloff, offset=0.0375
    )
    got = np.zeros(grid.size)
    got_t = np.zeros(grid.size, dtype=bool)
    count = accumulate(
        grid,
        sensor,
        x,
        y,
        th,
        r,
        got,
        got_t,
        inc_free=-0.2,
        inc_occ=0.3,
        clamp=(-50.0, 50.0),
        offset=0.0375,
        falloff=falloff,
    )
    assert count == entries
    np.testing.assert_array_equal(got_t, want_t)
    # Each weight within FIT_TOL (1e-9) of the Gaussian, times at most n readings.
    np.testing.assert_allclose(got, want, rtol=0, atol=n * 0.3 * 1e-9)
