"""The simulator: exact ranges without noise, outlier rate, determinism."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sonarmap.acoustics import AcousticModel, beam_pattern
from sonarmap.errors import ConfigError, InputError
from sonarmap.floorplan import FloorPlan
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.readings import Trajectory
from sonarmap.rig import Mount, Rig
from sonarmap.scenarios import Scenario
from sonarmap.sensors import Noise, Region, SensorModel
from sonarmap.simulate import PoseNoise, make_model, simulate

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
    readings = simulate(truth, RIG, traj, model=Noise(0.0, 1.0, 0.0), seed=3)
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
    readings = simulate(empty, RIG, traj, model=Noise(0.1, 1.0, 0.0), seed=5)
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
    readings = simulate(truth, rig, traj, model=Noise(0.0, 0.5, 0.0), seed=2)
    assert float(np.mean(readings.range < 2.0)) == pytest.approx(0.5, abs=0.03)


def test_sigma_spreads_ranges() -> None:
    truth = scattered_map(2)
    traj = random_trajectory(400)
    exact = simulate(truth, RIG, traj, model=Noise(0.0, 1.0, 0.0), seed=1)
    noisy = simulate(truth, RIG, traj, model=Noise(0.0, 1.0, 0.05), seed=1)
    mask = (exact.range < 4.5) & (exact.range > 0.5)
    diff = noisy.range[mask] - exact.range[mask]
    assert np.std(diff) == pytest.approx(0.05, rel=0.15)


def test_seed_determinism_and_pose_noise() -> None:
    truth = scattered_map()
    traj = random_trajectory(100)
    a = simulate(truth, RIG, traj, model=Noise(0.05, 0.8, 0.02), seed=9)
    b = simulate(truth, RIG, traj, model=Noise(0.05, 0.8, 0.02), seed=9, chunk_size=7)
    c = simulate(truth, RIG, traj, model=Noise(0.05, 0.8, 0.02), seed=10)
    np.testing.assert_array_equal(a.range, b.range)
    assert not np.array_equal(a.range, c.range)
    noisy = simulate(
        truth, RIG, traj, model=Noise(0.0, 1.0, 0.0), seed=9, pose_noise=PoseNoise(0.05, 0.0)
    )
    exact = simulate(truth, RIG, traj, model=Noise(0.0, 1.0, 0.0), seed=9)
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


# -- the acoustic sonar -----------------------------------------------------------------

EXACT = AcousticModel(sigma=0.0, sigma_rel=0.0, p_rand=0.0, scale_sigma=0.0)
POLAROID = SensorModel(
    "polaroid", Region.cone(30.0, 10.7), r_min=0.15, r_max=10.7, range_resolution=0.001
)


def plan_with(*boxes: tuple[float, float, float, float], size: float = 6.0) -> OccupancyMap:
    plan = FloorPlan((0.0, 0.0, size, size))
    for b in boxes:
        plan.box(*b)
    return plan.render(plan.grid(0.01))


def one_reading(world: OccupancyMap, x: float, y: float, heading_deg: float, **kw: float) -> float:
    rig = Rig(POLAROID, (Mount("s", 0.0, 0.0, 0.0),))
    traj = Trajectory(np.zeros(1), np.array([x]), np.array([y]), np.radians([heading_deg]))
    model = replace(EXACT, **kw)
    return float(simulate(world, rig, traj, model=model).range[0])


def test_acoustic_range_is_the_distance_to_the_surface() -> None:
    # A wall whose face is at x = 2.0, met head-on from x = 1.0: the echo is from the
    # face, not from a cell centre (a 5 cm map's cell centre would read 1.025).
    wall = plan_with((2.0, 0.0, 2.1, 6.0))
    assert one_reading(wall, 1.0, 3.0, 0.0) == pytest.approx(1.0, abs=0.0011)
    # Off the cell boundaries too: a face at 2.03.
    wall = plan_with((2.03, 0.0, 2.13, 6.0))
    assert one_reading(wall, 1.0, 3.0, 0.0) == pytest.approx(1.03, abs=0.0011)
    # The same plan given as a 5 cm map is subdivided: still the face.
    coarse = FloorPlan((0.0, 0.0, 6.0, 6.0))
    coarse.box(2.0, 0.0, 2.1, 6.0)
    assert one_reading(coarse.render(coarse.grid(0.05)), 1.0, 3.0, 0.0) == pytest.approx(1.0, 1e-3)


def test_a_smooth_wall_met_obliquely_returns_nothing_but_a_corner_does() -> None:
    # A wall at 45 degrees to the beam, 4 m off: its mirror reflection goes elsewhere.
    wall = plan_with((4.0, 0.0, 4.1, 6.0))
    assert one_reading(wall, 1.0, 1.0, 45.0) == POLAROID.r_max
    # Head-on, the same wall answers from 3 m.
    assert one_reading(wall, 1.0, 1.0, 0.0) == pytest.approx(3.0, abs=0.002)
    # A concave corner in the beam reflects the pulse back whatever the angle.
    corner = plan_with((4.0, 0.0, 4.1, 6.0), (0.0, 4.0, 6.0, 4.1))
    r = one_reading(corner, 1.0, 1.0, 45.0)
    assert r == pytest.approx(math.hypot(3.0, 3.0), abs=0.05)
    # Without the mirror lobe's width (a rough wall) the oblique wall answers.
    rough = one_reading(wall, 1.0, 1.0, 45.0, roughness=0.9)
    assert rough < POLAROID.r_max


def test_the_beam_pattern_widens_for_near_strong_targets() -> None:
    # A post 25 degrees off the axis: outside the nominal 15-degree half-aperture, heard
    # through a side lobe when near, not when far.
    def post_at(d: float) -> OccupancyMap:
        a = math.radians(25.0)
        cx, cy = 0.5 + d * math.cos(a), 3.0 + d * math.sin(a)
        return plan_with((cx - 0.05, cy - 0.05, cx + 0.05, cy + 0.05))

    assert one_reading(post_at(0.6), 0.5, 3.0, 0.0) < 0.6
    assert one_reading(post_at(4.0), 0.5, 3.0, 0.0) == POLAROID.r_max
    phi, amp = beam_pattern(AcousticModel(), POLAROID)
    assert phi[0] == 0.0
    assert amp[0] == 1.0
    # The first null at the nominal half-aperture (rays hearing nothing are dropped),
    # side lobes beyond it no louder than a piston's first, -17.6 dB.
    assert np.all(amp[np.abs(np.abs(phi) - math.radians(15.0)) < math.radians(0.6)] < 0.03)
    assert amp[np.abs(phi) > math.radians(15.5)].max() == pytest.approx(0.132, abs=0.003)


def test_acoustic_errors_and_determinism() -> None:
    wall = plan_with((5.0, 0.0, 5.1, 6.0))
    rig = Rig(POLAROID, (Mount("a", 0.0, 0.0, 0.0), Mount("b", 0.0, 0.1, 0.0)))
    n = 4000
    traj = Trajectory(np.arange(n, dtype=float), np.full(n, 1.0), np.full(n, 3.0), np.zeros(n))
    model = AcousticModel(sigma=0.01, sigma_rel=0.01, p_rand=0.05, scale_sigma=0.0)
    r = simulate(wall, rig, traj, model=model, seed=4).range
    spurious = np.abs(r - 4.0) > 0.3
    assert spurious.mean() == pytest.approx(0.05, abs=0.015)
    # Noise sigma + sigma_rel * d = 0.05 m at 4 m.
    assert np.std(r[~spurious]) == pytest.approx(0.05, rel=0.1)
    same = simulate(wall, rig, traj, model=model, seed=4, chunk_size=7).range
    np.testing.assert_array_equal(r, same)
    assert not np.array_equal(r, simulate(wall, rig, traj, model=model, seed=5).range)
    # A per-sonar scale error: each sonar's readings off by its own factor.
    scaled = simulate(wall, rig, traj, model=replace(EXACT, scale_sigma=0.02), seed=1).range
    a, b = scaled[0::2], scaled[1::2]
    assert np.ptp(a) == 0.0
    assert np.ptp(b) == 0.0
    assert a[0] != b[0]


def test_acoustic_readings_are_not_the_mappers_model(doorways: Scenario) -> None:
    # The same scene read by Thrun's model on the map's cells and by the acoustic sonar:
    # the echoes differ (faces against cell centres, mirror-like walls).
    thrun = simulate(doorways.truth, doorways.rig, doorways.trajectory, model=Noise())
    acoustic = doorways.readings
    assert doorways.params["model"]["kind"] == "acoustic"
    echo = (thrun.range < doorways.rig.sensor.r_max) & (acoustic.range < doorways.rig.sensor.r_max)
    assert np.median(acoustic.range[echo] - thrun.range[echo]) < -0.01
    # The rig a scene writes states the sensor's specification, not the noise used.
    assert doorways.rig.sensor.noise == Noise()


def test_bad_acoustic_parameters() -> None:
    with pytest.raises(ConfigError, match=r"specular_deg must be in \(0.0, 90.0\]"):
        AcousticModel(specular_deg=0.0)
    with pytest.raises(ConfigError, match=r"unknown parameter\(s\) \['bogus'\]"):
        AcousticModel.from_dict({"bogus": 1.0})
    with pytest.raises(ConfigError, match="p_hit belongs to Thrun's model"):
        make_model("acoustic", p_hit=0.5)
    with pytest.raises(ConfigError, match="belong to the acoustic model"):
        make_model("thrun", params={"roughness": "0.1"})
    with pytest.raises(ConfigError, match="roughness expects a number"):
        make_model("acoustic", params={"roughness": "rough"})
