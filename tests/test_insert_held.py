"""The insertion kernel's skip of cells held at a clamp bound, against computing every
weight.

With ``positive=True`` (the fall-off polynomial is positive over the beam) a block of
cells that all hold the clamp bound their increment pushes towards takes that bound
without its weights; ``positive=False`` computes every weight, as the kernel did before
the skip. The two must give the same map to the bit (``uint64`` views: -0.0 and 0.0
differ), the same touched cells and the same count, on beams that revisit the same
cells until most of them sit at a bound.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt
import pytest

from sonarmap._raster_kernel import accumulate_kernel, accumulate_parallel
from sonarmap.grid import Grid
from sonarmap.raster import FIT_TOL, accumulate, falloff_fit, falloff_positive
from sonarmap.sensors import SensorModel, get_sensor

F64 = npt.NDArray[np.float64]
Result = tuple[int, F64, npt.NDArray[np.bool_]]
# x, y, theta, free limit, band end: one per reading.
Beams = tuple[F64, F64, F64, F64, F64]
GRID = Grid.from_bounds(0.0, 0.0, 4.0, 4.0, 0.05)


def beams(sensor: SensorModel, n: int, seed: int) -> Beams:
    """``n`` random readings from a few spots of a 4 m map (so that cells are seen
    again and again), some from outside it; free limit and band end as the rasteriser
    has them, no-echo readings (no band) included."""
    rng = np.random.default_rng(seed)
    spots = rng.uniform(-0.5, 4.5, (12, 2))
    at = spots[rng.integers(0, len(spots), n)] + rng.normal(0.0, 0.02, (n, 2))
    th = rng.uniform(-4.0, 4.0, n)
    r = rng.uniform(0.0, sensor.r_max * 1.05, n)
    echo = r < sensor.r_max
    free_lim = np.where(echo, r - 0.05, sensor.r_max - 0.05)
    occ_hi = np.where(echo, r + 0.05, -np.inf)
    return at[:, 0].copy(), at[:, 1].copy(), th, free_lim, occ_hi


def insert(
    sensor: SensorModel,
    readings: Beams,
    falloff: float,
    inc: tuple[float, float],
    clamp: tuple[float, float],
    positive: bool,
    *,
    runs: bool = True,
    start: float = 0.0,
    weight: F64 | None = None,
) -> Result:
    x, y, th, free_lim, occ_hi = readings
    values = np.full(GRID.size, start)
    touched = np.zeros(GRID.size, dtype=bool)
    n = accumulate_kernel(
        values,
        touched,
        GRID.resolution,
        *GRID.origin,
        GRID.rows,
        GRID.cols,
        x,
        y,
        th,
        free_lim,
        occ_hi,
        np.ascontiguousarray(sensor.beam.halfplanes),
        sensor.beam.radius,
        *inc,
        *clamp,
        falloff,
        falloff_fit(sensor, falloff)[1],
        weight=weight,
        runs=runs,
        positive=positive,
    )
    return n, values, touched


def assert_same(a: Result, b: Result) -> None:
    assert a[0] == b[0]
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_array_equal(a[1].view(np.uint64), b[1].view(np.uint64))


def held(result: Result, clamp: tuple[float, float]) -> float:
    """Share of the touched cells that end at a clamp bound."""
    _, values, touched = result
    return float(np.isin(values[touched], clamp).mean())


@pytest.mark.parametrize("runs", [True, False])
@pytest.mark.parametrize(
    ("name", "falloff_deg"), [("polaroid-6500", 5.0), ("hc-sr04", 10.0), ("maxsonar-ez1", 20.0)]
)
@pytest.mark.parametrize(
    ("inc", "clamp"),
    [
        ((-0.2, 0.3), (-0.6, 0.9)),  # the usual signs
        ((0.25, -0.15), (-0.5, 0.7)),  # free cells pushed up, occupied ones down
        ((-0.2, -0.1), (-0.6, 0.9)),  # both pushed down
    ],
)
def test_skipping_held_cells_changes_no_bit(
    name: str,
    falloff_deg: float,
    inc: tuple[float, float],
    clamp: tuple[float, float],
    runs: bool,
) -> None:
    sensor = get_sensor(name)
    falloff = math.radians(falloff_deg)
    assert falloff_positive(sensor, falloff)
    readings = beams(sensor, 1500, seed=7)
    fast = insert(sensor, readings, falloff, inc, clamp, True, runs=runs)
    full = insert(sensor, readings, falloff, inc, clamp, False, runs=runs)
    assert fast[0] > 50_000
    # Most of the map ends at a bound: the later readings' blocks are mostly skipped.
    assert held(full, clamp) > 0.5
    assert_same(fast, full)


def test_a_bound_is_written_with_its_own_bits() -> None:
    """Cells start at -0.0 and the clamp's lower bound is +0.0: a skipped cell must end
    at +0.0, as computing its weight and clamping gives, not keep its -0.0; cells that
    start at a bound but untouched end touched."""
    sensor = get_sensor("polaroid-6500")
    falloff = math.radians(5.0)
    readings = beams(sensor, 400, seed=3)
    for start, clamp in ((-0.0, (0.0, 0.8)), (0.8, (0.0, 0.8)), (-0.5, (-0.5, 0.5))):
        fast = insert(sensor, readings, falloff, (-0.2, 0.3), clamp, True, start=start)
        full = insert(sensor, readings, falloff, (-0.2, 0.3), clamp, False, start=start)
        assert_same(fast, full)
        assert fast[2].sum() > 0.3 * GRID.size


def test_weighted_readings_and_threads_change_no_bit() -> None:
    """Per-reading weights (zeros among them: an increment of 0 holds no bound), and the
    rows split in stripes as the parallel kernel splits them."""
    sensor = get_sensor("polaroid-6500")
    falloff = math.radians(5.0)
    readings = beams(sensor, 1500, seed=5)
    w = np.random.default_rng(9).choice([0.0, 0.5, 1.0, 2.0], size=1500)
    inc, clamp = (-0.2, 0.3), (-0.6, 0.9)
    fast = insert(sensor, readings, falloff, inc, clamp, True, weight=w)
    full = insert(sensor, readings, falloff, inc, clamp, False, weight=w)
    assert held(full, clamp) > 0.5
    assert_same(fast, full)
    x, y, th, free_lim, occ_hi = readings
    values = np.zeros(GRID.size)
    touched = np.zeros(GRID.size, dtype=bool)
    n = accumulate_parallel(
        values,
        touched,
        GRID.resolution,
        *GRID.origin,
        GRID.rows,
        GRID.cols,
        x,
        y,
        th,
        free_lim,
        occ_hi,
        np.ascontiguousarray(sensor.beam.halfplanes),
        sensor.beam.radius,
        *inc,
        *clamp,
        falloff,
        falloff_fit(sensor, falloff)[1],
        2,
        w,
        True,
    )
    assert_same((n, values, touched), full)


def test_positive_only_where_the_gaussian_clears_the_fit_tolerance() -> None:
    """At 2.8 degrees a 21-term fit exists but the Gaussian at the beam's edge (2e-7) is
    too near the fit's tolerance to vouch for the polynomial's sign; at 3 degrees and
    wider it is vouched for, and the polynomial is indeed positive over its angles."""
    sensor = get_sensor("polaroid-6500")
    narrow = math.radians(2.8)
    assert falloff_fit(sensor, narrow)[1]
    assert not falloff_positive(sensor, narrow)
    assert not falloff_positive(sensor, 0.0)
    for deg in (3.0, 5.0, 10.0):
        u_max, coef = falloff_fit(sensor, math.radians(deg))
        assert falloff_positive(sensor, math.radians(deg))
        u = np.linspace(0.0, u_max, 200_001)
        assert np.polynomial.polynomial.polyval(u, coef).min() > 1e3 * FIT_TOL


@pytest.mark.parametrize("weighted", [False, True])
def test_accumulate_on_two_threads_changes_no_bit(weighted: bool) -> None:
    """The public insertion, which vouches for the polynomial itself, on one thread and
    on two (the parallel kernel, unweighted or weighted), against every weight
    computed."""
    sensor = get_sensor("polaroid-6500")
    falloff = math.radians(5.0)
    n = 800
    rng = np.random.default_rng(2)
    spots = rng.uniform(0.5, 3.5, (6, 2))[rng.integers(0, 6, n)]
    x, y = spots[:, 0], spots[:, 1]
    th, r = rng.uniform(-4.0, 4.0, n), rng.uniform(0.2, 3.0, n)
    w = rng.choice([0.5, 1.0, 2.0], size=n) if weighted else None
    inc, clamp = (-0.2, 0.3), (-0.6, 0.9)
    got = []
    before = numba.get_num_threads()
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):  # type: ignore[attr-defined]
        numba.set_num_threads(threads)
        try:
            values = np.zeros(GRID.size)
            touched = np.zeros(GRID.size, dtype=bool)
            count = accumulate(
                GRID, sensor, x, y, th, r, values, touched,
                inc_free=inc[0], inc_occ=inc[1], clamp=clamp, dr=0.05, falloff=falloff,
                weights=w,
            )  # fmt: skip
        finally:
            numba.set_num_threads(before)
        got.append((count, values, touched))
    # The same readings' limits, every weight computed.
    free_lim, occ_hi = r - 0.05, r + 0.05
    full = insert(sensor, (x, y, th, free_lim, occ_hi), falloff, inc, clamp, False, weight=w)
    assert held(full, clamp) > 0.5
    for result in got:
        assert_same(result, full)
