"""The rasteriser against a brute-force reference over every cell centre."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from conftest import cone_sensor, poses, zoned_sensor
from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.raster import Footprint, accumulate, beam_cells, default_dr, rasterise
from sonarmap.sensors import Region, SensorModel, get_sensor

GRID = Grid(resolution=0.1, origin=(-2.0, -2.0), shape=(40, 40))


def reference(
    grid: Grid, sensor: SensorModel, x: float, y: float, theta: float, r: float, dr: float
) -> tuple[set[int], set[int], dict[int, float]]:
    """Free and occupied cells and their weights by testing every cell centre."""
    xc, yc = grid.all_centres()
    dx, dy = xc.ravel() - x, yc.ravel() - y
    c, s = math.cos(theta), math.sin(theta)
    local = np.c_[dx * c + dy * s, -dx * s + dy * c]
    inside = sensor.beam.contains(local)
    d = np.hypot(dx, dy)
    tol = 1e-9  # the kernel's inclusive slack: ties go to Omega_occ
    if r >= sensor.r_max:
        free = inside & (d < sensor.r_max - dr - tol)
        occ = np.zeros_like(free)
    else:
        free = inside & (d < r - dr - tol)
        # The kernel's contract: a band whose outer bound r + dr is not above 0 admits no
        # centre, not even one exactly at the sensor.
        occ = inside & (d >= r - dr - tol) & (d <= r + dr + tol) & (r + dr > 0)
    size = sensor.sensitivity(local)
    safe = np.where(size > 0, size, 1.0)
    w = np.where(size > 0, np.minimum(grid.resolution**2 / safe**2, 1.0), 1.0)
    weights = {int(i): float(w[i]) for i in np.flatnonzero(inside)}
    return set(np.flatnonzero(free).tolist()), set(np.flatnonzero(occ).tolist()), weights


@settings(max_examples=60, deadline=None)
@given(pose=poses, aperture=st.floats(5.0, 170.0), dr=st.floats(0.0, 0.3))
@example(pose=(0.75, 0.75, 0.0, 0.0), aperture=5.0, dr=0.0)  # a zero range at a cell centre
def test_cone_matches_reference(
    pose: tuple[float, float, float, float], aperture: float, dr: float
) -> None:
    sensor = cone_sensor(aperture)
    x, y, th, r = pose
    fp = rasterise(GRID, sensor, [x], [y], [th], [r], dr=dr)
    free, occ, _ = reference(GRID, sensor, x, y, th, r, dr)
    assert set(fp.free.cells.tolist()) == free
    assert set(fp.occ.cells.tolist()) == occ


@settings(max_examples=60, deadline=None)
@given(pose=poses)
def test_polygon_with_zones_matches_reference(pose: tuple[float, float, float, float]) -> None:
    sensor = zoned_sensor()
    x, y, th, r = pose
    fp = rasterise(GRID, sensor, [x], [y], [th], [r], dr=0.1)
    free, occ, weights = reference(GRID, sensor, x, y, th, r, 0.1)
    assert set(fp.free.cells.tolist()) == free
    assert set(fp.occ.cells.tolist()) == occ
    for cells, w in ((fp.free.cells, fp.free.weight), (fp.occ.cells, fp.occ.weight)):
        got = dict(zip(cells.tolist(), w.tolist(), strict=True))
        for cell, value in got.items():
            assert value == pytest.approx(weights[cell], rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(pose=poses, aperture=st.floats(5.0, 170.0))
def test_sets_disjoint_inside_beam_and_band(
    pose: tuple[float, float, float, float], aperture: float
) -> None:
    sensor = cone_sensor(aperture)
    x, y, th, r = pose
    dr = 0.1
    fp = rasterise(GRID, sensor, [x], [y], [th], [r], dr=dr, with_bearing=True)
    assert not set(fp.free.cells.tolist()) & set(fp.occ.cells.tolist())
    assert np.all(fp.free.distance < max(r if r < sensor.r_max else sensor.r_max, 0) - dr + 1e-6)
    assert np.all(fp.occ.distance >= r - dr - 1e-6)
    assert np.all(fp.occ.distance <= r + dr + 1e-6)
    half = math.radians(aperture) / 2
    for cs in (fp.free, fp.occ):
        assert cs.bearing is not None
        assert np.all(np.abs(cs.bearing) <= half + 1e-6)
        assert np.unique(cs.cells).size == cs.cells.size


@settings(max_examples=40, deadline=None)
@example(pose=(0.0, 0.25, 0.0, 0.25), turns=2)  # a centre exactly at r - dr (found by CI)
@given(pose=poses, turns=st.integers(1, 3))
def test_rotating_pose_and_world_gives_same_cells(
    pose: tuple[float, float, float, float], turns: int
) -> None:
    sensor = zoned_sensor()
    grid = Grid(resolution=0.1, origin=(-2.0, -2.0), shape=(40, 40))
    x, y, th, r = pose
    base = rasterise(grid, sensor, [x], [y], [th], [r], dr=0.1)
    xc, yc = grid.all_centres()
    for k in range(1, turns + 1):
        a = k * math.pi / 2
        ca, sa = round(math.cos(a)), round(math.sin(a))
        rx, ry = ca * x - sa * y, sa * x + ca * y
        turned = rasterise(grid, sensor, [rx], [ry], [th + a], [r], dr=0.1)
        # Where does each original cell centre land?
        for cs_base, cs_turn in ((base.free, turned.free), (base.occ, turned.occ)):
            bx, by = xc.ravel()[cs_base.cells], yc.ravel()[cs_base.cells]
            tx, ty = ca * bx - sa * by, sa * bx + ca * by
            rr, cc = grid.world_to_cell(tx, ty)
            expected = set(grid.flat_index(rr, cc).tolist())
            assert set(cs_turn.cells.tolist()) == expected
            np.testing.assert_allclose(
                np.sort(cs_turn.distance), np.sort(cs_base.distance), atol=1e-5
            )


def test_cell_centres_decide_membership() -> None:
    # A 1 m grid and a 10-degree cone along a row: a cell is in when its centre is.
    grid = Grid(1.0, (0.0, 0.0), (3, 6))
    sensor = SensorModel("c", Region.cone(10.0, 10.0), r_min=0.0, r_max=10.0, range_resolution=0.1)
    fp = rasterise(grid, sensor, [0.0], [1.5], [0.0], [4.5], dr=0.5)
    assert fp.free.cells.tolist() == [6, 7, 8, 9]  # middle row, centres at x = 0.5 .. 3.5
    assert fp.occ.cells.tolist() == [10]  # centre at x = 4.5, inside [4.0, 5.0]
    # A 90-degree cone: the centre of cell 12 (row 2, col 0; centre (0.5, 0.5)) lies exactly
    # on the lower edge when the sensor is at (-0.5, 1.5), and 1 cm outside when it moves.
    wide = SensorModel("w", Region.cone(90.0, 10.0), r_min=0.0, r_max=10.0, range_resolution=0.1)
    on = rasterise(grid, wide, [-0.5], [1.5], [0.0], [3.0], dr=0.0)
    assert 12 in on.free.cells.tolist()
    off = rasterise(grid, wide, [-0.49], [1.5], [0.0], [3.0], dr=0.0)
    assert 12 not in off.free.cells.tolist()


def test_no_echo_has_no_occupied_band() -> None:
    sensor = get_sensor("hc-sr04")
    fp = rasterise(GRID, sensor, [0.0], [0.0], [0.0], [sensor.r_max], dr=0.05)
    assert len(fp.occ.cells) == 0
    assert fp.free.distance.max() < sensor.r_max - 0.05


def test_no_echo_reach_shortens_only_the_no_echo_beams() -> None:
    sensor = get_sensor("hc-sr04")
    xs, ys, ths, rs = [0.0, 0.0], [0.0, 0.0], [0.0, math.pi], [sensor.r_max, 1.5]
    full = rasterise(GRID, sensor, xs, ys, ths, rs, dr=0.05)
    near = rasterise(GRID, sensor, xs, ys, ths, rs, dr=0.05, no_echo_reach=1.0)
    # The no-echo beam clears out to 1.0 - dr only; the echo is untouched.
    assert near.free.distance[: near.free.offsets[1]].max() < 0.95
    assert full.free.distance[: full.free.offsets[1]].max() > 1.5
    np.testing.assert_array_equal(near.free.of(1), full.free.of(1))
    np.testing.assert_array_equal(near.occ.cells, full.occ.cells)
    # A reach past r_max is r_max; the insertion clears the same cells.
    far = rasterise(GRID, sensor, xs, ys, ths, rs, dr=0.05, no_echo_reach=sensor.r_max + 5)
    np.testing.assert_array_equal(far.free.cells, full.free.cells)
    got, got_t = np.zeros(GRID.size), np.zeros(GRID.size, dtype=bool)
    accumulate(
        GRID,
        sensor,
        xs,
        ys,
        ths,
        rs,
        got,
        got_t,
        inc_free=-1.0,
        inc_occ=1.0,
        dr=0.05,
        no_echo_reach=1.0,
    )
    want, want_t = _apply_footprint(near, GRID.size, (-1.0, 1.0), (-np.inf, np.inf))
    np.testing.assert_array_equal(got_t, want_t)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    with pytest.raises(ConfigError, match="no_echo_reach"):
        rasterise(GRID, sensor, xs, ys, ths, rs, no_echo_reach=0.0)


def test_clipped_to_grid_and_offsets_consistent() -> None:
    sensor = get_sensor("maxsonar-ez1")
    rng = np.random.default_rng(1)
    n = 200
    fp = rasterise(
        GRID,
        sensor,
        rng.uniform(-4, 4, n),
        rng.uniform(-4, 4, n),
        rng.uniform(-3, 3, n),
        rng.uniform(0.1, 7, n),
    )
    for cs in (fp.free, fp.occ):
        assert cs.offsets[0] == 0
        assert cs.offsets[-1] == len(cs.cells)
        assert np.all(np.diff(cs.offsets) >= 0)
        assert cs.cells.min(initial=0) >= 0
        assert cs.cells.max(initial=0) < GRID.size
        assert cs.matrix(GRID.size).shape == (n, GRID.size)


def test_beam_cells_is_union_of_bands() -> None:
    sensor = get_sensor("maxsonar-ez1")
    all_cells = beam_cells(GRID, sensor, [0.0], [0.0], [0.3], max_range=1.5)
    fp = rasterise(GRID, sensor, [0.0], [0.0], [0.3], [1.0], dr=0.5)
    assert set(all_cells.cells.tolist()) == set(fp.free.cells.tolist()) | set(fp.occ.cells.tolist())


def test_default_dr_and_bad_input() -> None:
    sensor = get_sensor("maxsonar-ez1")
    assert default_dr(GRID, sensor) == pytest.approx(0.05)
    with pytest.raises(InputError, match="'range' holds non-finite"):
        rasterise(GRID, sensor, [0.0], [0.0], [0.0], [float("nan")])
    with pytest.raises(InputError, match="ranges must be >= 0"):
        rasterise(GRID, sensor, [0.0], [0.0], [0.0], [-1.0])
    with pytest.raises(InputError, match="'y' has 2 entries, expected 1"):
        rasterise(GRID, sensor, [0.0], [0.0, 1.0], [0.0], [1.0])
    with pytest.raises(ConfigError, match="dr must be a non-negative"):
        rasterise(GRID, sensor, [0.0], [0.0], [0.0], [1.0], dr=-0.1)


def _apply_footprint(
    fp: Footprint, size: int, inc: tuple[float, float], clamp: tuple[float, float]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Per reading, add to its free then its occupied cells, clamping: the reference."""
    values = np.zeros(size)
    touched = np.zeros(size, dtype=bool)
    for i in range(fp.free.n_readings):
        for cells, add in ((fp.free.of(i), inc[0]), (fp.occ.of(i), inc[1])):
            values[cells] = np.clip(values[cells] + add, *clamp)
            touched[cells] = True
    return values, touched


@settings(max_examples=60, deadline=None)
@example(pose=(0.0, 0.25, 0.0, 0.25), aperture=30.0, zoned=False)
@example(pose=(0.05, 0.05, math.pi / 2, 1.0), aperture=90.0, zoned=False)
@given(
    pose=poses,
    aperture=st.floats(5.0, 170.0),
    zoned=st.booleans(),
)
def test_accumulate_visits_the_rasterisers_cells(
    pose: tuple[float, float, float, float], aperture: float, zoned: bool
) -> None:
    sensor = zoned_sensor() if zoned else cone_sensor(aperture)
    x, y, th, r = pose
    # Three readings from nearby poses, so that clamping order matters.
    xs, ys, ths, rs = [x, x + 0.03, x], [y, y, y - 0.07], [th, th + 0.2, th], [r, r, r * 0.7]
    fp = rasterise(GRID, sensor, xs, ys, ths, rs)
    want, want_t = _apply_footprint(fp, GRID.size, (-0.4, 0.9), (-1.0, 1.5))
    got = np.zeros(GRID.size)
    got_t = np.zeros(GRID.size, dtype=bool)
    n = accumulate(
        GRID, sensor, xs, ys, ths, rs, got, got_t, inc_free=-0.4, inc_occ=0.9, clamp=(-1.0, 1.5)
    )
    assert n == fp.n_entries
    np.testing.assert_array_equal(got_t, want_t)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_accumulate_checks_its_arrays() -> None:
    s = cone_sensor(30.0)
    with pytest.raises(ConfigError, match="shape"):
        accumulate(
            GRID, s, [0], [0], [0], [1], np.zeros(3), np.zeros(3, bool), inc_free=0, inc_occ=1
        )


@pytest.mark.parametrize("falloff", [0.0, math.radians(20.0)])
def test_parallel_accumulate_gives_the_serial_result(falloff: float) -> None:
    """Row stripes shared between threads: every cell still takes readings in order."""
    from sonarmap._raster_kernel import accumulate_kernel, accumulate_parallel
    from sonarmap.raster import falloff_fit

    rng = np.random.default_rng(3)
    n = 400
    s = cone_sensor(40.0)
    x, y = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
    th, r = rng.uniform(-4, 4, n), rng.uniform(0, 3.2, n)
    free_lim = np.where(r < s.r_max, r - 0.05, s.r_max - 0.05)
    occ_hi = np.where(r < s.r_max, r + 0.05, -np.inf)
    coef = falloff_fit(s, falloff)[1]
    assert (len(coef) > 0) == (falloff > 0)
    out = []
    for parts in (1, 2, 3):
        v = np.zeros(GRID.size)
        t = np.zeros(GRID.size, dtype=bool)
        args = (
            v,
            t,
            GRID.resolution,
            *GRID.origin,
            GRID.rows,
            GRID.cols,
            x,
            y,
            th,
            free_lim,
            occ_hi,
            s.beam.halfplanes,
            s.beam.radius,
            -0.3,
            0.8,
            -1.0,
            1.2,
            falloff,
            coef,
        )
        k = accumulate_kernel(*args) if parts == 1 else accumulate_parallel(*args, parts)
        out.append((k, v, t))
    for k, v, t in out[1:]:
        assert k == out[0][0]
        np.testing.assert_array_equal(v, out[0][1])
        np.testing.assert_array_equal(t, out[0][2])


def test_accumulate_decides_centres_on_a_threshold_as_the_rasteriser() -> None:
    """Band limits within a few ulps of a centre's distance: the insertion compares
    squared distances and takes the root only near a threshold, and must still decide
    every such centre as the rasteriser's root does."""
    sensor = cone_sensor(30.0)
    dr = 0.05
    x0, y0 = 0.0, 0.05  # on the centre row of cells at y = 0.05
    d = abs(GRID.origin[0] + (30 + 0.5) * GRID.resolution - x0)  # the centre at x = 1.05
    step = math.ulp(d)
    tol = 1e-9  # the rasteriser's EDGE_TOL
    ranges = [d + tol + dr + k * step for k in range(-40, 41)]  # free limit at the centre
    ranges += [d - tol - dr + k * step for k in range(-40, 41)]  # occupied limit there
    n = len(ranges)
    xs, ys, ths = [x0] * n, [y0] * n, [0.0] * n
    fp = rasterise(GRID, sensor, xs, ys, ths, ranges, dr=dr)
    free_here = {
        i
        for i in range(n)
        if ((GRID.rows - 1 - 20) * GRID.cols + 30) in set(fp.free.of(i).tolist())
    }
    assert 0 < len(free_here) < 81, "the ranges must straddle the free limit at the centre"
    want, want_t = _apply_footprint(fp, GRID.size, (-0.4, 0.9), (-50.0, 50.0))
    got = np.zeros(GRID.size)
    got_t = np.zeros(GRID.size, dtype=bool)
    count = accumulate(
        GRID,
        sensor,
        xs,
        ys,
        ths,
        ranges,
        got,
        got_t,
        inc_free=-0.4,
        inc_occ=0.9,
        clamp=(-50.0, 50.0),
        dr=dr,
    )
    assert count == fp.n_entries
    np.testing.assert_array_equal(got_t, want_t)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
