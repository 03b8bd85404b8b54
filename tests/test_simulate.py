"""The simulator: exact ranges without noise, outlier rate, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.readings import Trajectory
from sonarmap.rig import Mount, Rig
from sonarmap.sensors import Noise, Region, SensorModel
from sonarmap.simulate import PoseNoise, simulate

SENSOR = SensorModel("cone", Region.cone(30.0, 5.0), r_min=0.1, r_max=5.0, range_resolution=0.01)
RIG = Rig(SENSOR, (Mount("front", 0.0, 0.0, 0.0), Mount("left", 0.0, 0.0, 90.0)))


def scattered_map(seed: int = 0) -> OccupancyMap:
    grid = Grid(0.05, (0.0, 0.0), (100, 100))
    rng = np.random.default_rng(seed)
    occ = (rng.random(grid.shape) < 0.02).astype(np.float32)
    return OccupancyMap(grid, occ)


def random_trajectory(n: int, seed: int = 1) -> Trajectory:
    rng = np.random.default_rng(seed)
    return Trajectory(
        np.arange(n, dtype=float),
        rng.uniform(1, 4, n),
        rng.uniform(1, 4, n),
        rng.uniform(-math.pi, math.pi, n),
    )


def test_noise_free_reading_is_distance_to_nearest_occupied_cell_in_beam() -> None:
    truth = scattered_map()
    traj = random_trajectory(50)
    readings = simulate(truth, RIG, traj, noise=Noise(0.0, 1.0, 0.0), seed=3)
    xc, yc = truth.grid.all_centres()
    occ = truth.occupancy >= 0.5
    ox, oy = xc[occ], yc[occ]
    for i in range(len(readings)):
        x, y, th = readings.x[i], readings.y[i], readings.theta[i]
        dx, dy = ox - x, oy - y
        local = np.c_[dx * math.cos(th) + dy * math.sin(th), -dx * math.sin(th) + dy * math.cos(th)]
        d = np.hypot(dx, dy)
        inside = SENSOR.beam.contains(local) & (d <= SENSOR.r_max)
        expected = d[inside].min() if inside.any() else SENSOR.r_max
        expected = min(max(expected, SENSOR.r_min), SENSOR.r_max)
        assert readings.range[i] == pytest.approx(expected, abs=1e-12)


def test_outlier_rate_near_p_rand() -> None:
    grid = Grid(0.1, (0.0, 0.0), (50, 50))
    empty = OccupancyMap(grid, np.zeros(grid.shape, dtype=np.float32))
    traj = random_trajectory(5000)
    readings = simulate(empty, RIG, traj, noise=Noise(0.1, 1.0, 0.0), seed=5)
    # In an empty world every non-outlier reads r_max; outliers are uniform below it.
    rate = float(np.mean(readings.range < SENSOR.r_max))
    assert rate == pytest.approx(0.1, abs=0.01)
    out = readings.range[readings.range < SENSOR.r_max]
    assert out.min() >= SENSOR.r_min
    assert np.mean(out) == pytest.approx((SENSOR.r_min + SENSOR.r_max) / 2, rel=0.05)


def test_p_hit_lets_beams_pass_obstacles() -> None:
    # A wall of one cell in front of a pencil beam along a row of cell centres: with
    # p_hit = 0.5 about half the readings pass it (nothing is behind it).
    grid = Grid(0.1, (0.0, 0.0), (20, 60))
    occ = np.zeros(grid.shape, dtype=np.float32)
    occ[:, 20] = 1.0  # a wall at x in [2.0, 2.1]
    truth = OccupancyMap(grid, occ)
    n = 4000
    traj = Trajectory(np.arange(n, dtype=float), np.full(n, 0.5), np.full(n, 1.05), np.zeros(n))
    rig = Rig(
        SensorModel("pencil", Region.cone(1.0, 5.0), 0.0, 5.0, 0.01), (Mount("s", 0.0, 0.0, 0.0),)
    )
    readings = simulate(truth, rig, traj, noise=Noise(0.0, 0.5, 0.0), seed=2)
    assert float(np.mean(readings.range < 2.0)) == pytest.approx(0.5, abs=0.03)


def test_sigma_spreads_ranges() -> None:
    truth = scattered_map(2)
    traj = random_trajectory(400)
    exact = simulate(truth, RIG, traj, noise=Noise(0.0, 1.0, 0.0), seed=1)
    noisy = simulate(truth, RIG, traj, noise=Noise(0.0, 1.0, 0.05), seed=1)
    mask = (exact.range < 4.5) & (exact.range > 0.5)
    diff = noisy.range[mask] - exact.range[mask]
    assert np.std(diff) == pytest.approx(0.05, rel=0.15)


def test_seed_determinism_and_pose_noise() -> None:
    truth = scattered_map()
    traj = random_trajectory(100)
    a = simulate(truth, RIG, traj, noise=Noise(0.05, 0.8, 0.02), seed=9)
    b = simulate(truth, RIG, traj, noise=Noise(0.05, 0.8, 0.02), seed=9, chunk_size=7)
    c = simulate(truth, RIG, traj, noise=Noise(0.05, 0.8, 0.02), seed=10)
    np.testing.assert_array_equal(a.range, b.range)
    assert not np.array_equal(a.range, c.range)
    noisy = simulate(
        truth, RIG, traj, noise=Noise(0.0, 1.0, 0.0), seed=9, pose_noise=PoseNoise(0.05, 0.0)
    )
    exact = simulate(truth, RIG, traj, noise=Noise(0.0, 1.0, 0.0), seed=9)
    # Ranges come from the true poses; only the recorded poses move.
    np.testing.assert_array_equal(noisy.range, exact.range)
    assert np.std(noisy.x - exact.x) == pytest.approx(0.05, rel=0.3)


def test_bad_arguments() -> None:
    truth = scattered_map()
    with pytest.raises(InputError, match="trajectory is empty"):
        simulate(truth, RIG, Trajectory(*(np.empty(0) for _ in range(4))))
    with pytest.raises(ConfigError, match="p_hit must be in"):
        Noise(0.0, 0.0, 0.0)
    with pytest.raises(ConfigError, match="pose sigma_xy must be"):
        PoseNoise(-1.0)
