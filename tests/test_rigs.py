"""Issue 39: rigs in scenarios and sweeps, the observed walls, the objective, and
defaults that keep the walls a MaxSonar rig hears."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
import yaml

from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import make_mapper
from sonarmap.metrics import observed_walls, quality, score
from sonarmap.readings import Readings
from sonarmap.rig import SIX_BEARINGS, Mount, Rig, get_rig
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.sensors import Region, SensorModel
from sonarmap.splits import TRAINING_FAMILIES, check_training
from sonarmap.sweep import load_sweep, run_task


@pytest.mark.parametrize(
    ("name", "sensor"), [("ez1-six", "maxsonar-ez1"), ("hcsr04-six", "hc-sr04")]
)
def test_six_sonar_rigs(name: str, sensor: str) -> None:
    rig = get_rig(name)
    assert rig.sensor.name == sensor
    assert [m.yaw_deg for m in rig.mounts] == [yaw for _, yaw in SIX_BEARINGS]
    # Each sonar sits 0.15 m out from the centre along its own bearing.
    for m in rig.mounts:
        assert math.hypot(m.x, m.y) == pytest.approx(0.15)
        assert math.degrees(math.atan2(m.y, m.x)) % 360 == pytest.approx(m.yaw_deg % 360)


def test_scenarios_take_a_rig_preset() -> None:
    scene = make_scenario("doorways", rig="ring16", size=4.0, door_widths=(0.8,), rate=2.0)
    assert scene.rig.sensor.name == "polaroid-6500"
    assert len(scene.rig.mounts) == 16
    assert set(np.unique(scene.readings.sensor)) == set(range(16))
    assert scene.params["rig"] == "ring16"
    # The research's rig stays the default.
    assert make_scenario("doorways", size=4.0, door_widths=(0.8,), rate=2.0).rig.names == (
        get_rig("paper-synthetic").names
    )


def test_a_bad_rig_names_the_parameter() -> None:
    with pytest.raises(ConfigError, match="scenario parameter 'rig' must be a rig preset"):
        make_scenario("hall", rig="ring17")


def test_hall_is_a_training_scene_drawn_from_its_seed() -> None:
    assert "hall" in TRAINING_FAMILIES
    a = make_scenario("hall", rig="hcsr04-six", rate=2.0, seed=3)
    b = make_scenario("hall", rig="hcsr04-six", rate=2.0, seed=4)
    assert a.rig.sensor.name == "hc-sr04"
    assert a.params["length"] != b.params["length"]
    assert [p.name for p in a.passages] == ["door"]
    assert [o.name for o in a.obstacles] == ["pillar"]
    # The robot walks inside the hall: every pose on a free cell of the truth.
    rows, cols = a.truth.grid.world_to_cell(a.trajectory.x, a.trajectory.y)
    assert np.all(a.truth.occupancy[rows, cols] < 0.5)


def test_suite_is_a_training_scene_of_rooms_off_a_corridor() -> None:
    assert "suite" in TRAINING_FAMILIES
    check_training("suite", 999)
    with pytest.raises(ConfigError, match="held out"):
        check_training("suite", 1000)
    a = make_scenario("suite", rig="ring16", rate=1.0, seed=3)
    b = make_scenario("suite", rig="ring16", rate=1.0, seed=4)
    assert a.rig.sensor.name == "polaroid-6500"
    # Drawn from the seed: another floor, not only other readings.
    assert a.params["length"] != b.params["length"]
    assert a.truth.grid.shape != b.truth.grid.shape or not np.array_equal(
        a.truth.occupancy, b.truth.occupancy
    )
    # Three or four rooms, each with a door onto the corridor and a post.
    assert 3 <= len(a.passages) <= 4
    assert len(a.obstacles) == len(a.passages)
    assert all(0.7 <= p.width <= 1.1 for p in a.passages)
    # The tour stays on the floor and goes through every door.
    rows, cols = a.truth.grid.world_to_cell(a.trajectory.x, a.trajectory.y)
    assert np.all(a.truth.occupancy[rows, cols] < 0.5)
    for p in a.passages:
        mx, my = (p.a[0] + p.b[0]) / 2, (p.a[1] + p.b[1]) / 2
        assert np.min(np.hypot(a.trajectory.x - mx, a.trajectory.y - my)) < 0.1
    # Every door is a passage the metrics can measure on the truth itself.
    s = score(a.truth, a.truth, a.passages)
    assert s.passage_f1 == 1.0


def test_inverse_no_echo_reach_clears_only_near_cells() -> None:
    """The wall case's no-echo reading, alone: with a 1 m reach only cells within 1 m of
    the sonar are marked (free); without one its beam is cleared through the wall."""
    truth, rig, readings = _wall_case()
    alone = readings.take(np.array([2]))
    xc, _ = truth.grid.all_centres()
    far = (xc - 0.5) > 1.0
    near = make_mapper("inverse", no_echo="free", no_echo_reach=1.0)
    p = near.fit(alone, truth.grid, rig).result().occupancy
    assert np.all(np.isnan(p[far]))
    assert np.nanmax(p) < 0.5
    assert np.sum(~np.isnan(p)) > 0
    full = make_mapper("inverse", no_echo="free").fit(alone, truth.grid, rig).result().occupancy
    assert np.nanmin(full[truth.occupancy > 0.5]) < 0.5  # the wall cleared
    with pytest.raises(ConfigError, match="no_echo_reach"):
        make_mapper("inverse", no_echo_reach=0.0)
    # Readings with no echo ignored, a reach would change nothing: refused, not ignored.
    with pytest.raises(ConfigError, match="no_echo='free'"):
        make_mapper("inverse", no_echo="ignore", no_echo_reach=1.0)


def test_a_sweep_scenario_takes_a_rig(tmp_path: object) -> None:
    from pathlib import Path

    path = Path(str(tmp_path)) / "sweep.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "scenarios": {"hall-ring": {"scenario": "hall", "rig": "ring16", "rate": 1.0}},
                "methods": {"counting": {}},
            }
        )
    )
    config = load_sweep(path)
    (task,) = config.tasks()
    row = run_task(task)
    assert row["scenario"] == "hall-ring"
    assert 0.0 <= row["observed_wall_recall"] <= 1.0
    path.write_text(
        yaml.safe_dump(
            {
                "scenarios": {"o": {"scenario": "office", "rig": "ez1-six"}},
                "methods": {"inverse": {}},
            }
        )
    )
    with pytest.raises(InputError, match="held out"):
        load_sweep(path)


def _wall_case() -> tuple[OccupancyMap, Rig, Readings]:
    """A wall two cells thick at x in [2, 2.2) m; one narrow sonar at x = 0.5 looking at it."""
    g = Grid(0.1, (0.0, 0.0), (10, 30))
    data = np.zeros(g.shape, dtype=np.float32)
    data[:, 20:22] = 1.0
    sensor = SensorModel(
        "narrow", Region.cone(10.0, 5.0), r_min=0.0, r_max=5.0, range_resolution=0.01
    )
    rig = Rig(sensor, (Mount("s", 0.0, 0.0, 0.0),))
    n = 3
    readings = Readings(
        t=np.arange(n, dtype=np.float64),
        sensor=np.zeros(n, dtype=np.int32),
        x=np.full(n, 0.5),
        y=np.full(n, 0.5),
        theta=np.zeros(n),
        # Two echoes from the wall's face 1.5 m ahead, one reading without an echo.
        range=np.array([1.5, 1.5, 5.0]),
        names=("s",),
    )
    return OccupancyMap(g, data), rig, readings


def test_observed_walls_are_the_faces_the_echoes_sit_on() -> None:
    truth, rig, readings = _wall_case()
    seen = observed_walls(truth, rig, readings)
    cols = np.flatnonzero(seen.any(axis=0))
    # The near face of the wall only: not its far side, nor free cells.
    assert cols.tolist() == [20]
    assert seen[:, 20].sum() >= 1
    assert not np.any(seen & (truth.occupancy < 0.5))
    # Without echoes nothing is observed.
    none = observed_walls(truth, rig, readings.take(np.array([2])))
    assert not none.any()


def test_observed_wall_recall_and_quality() -> None:
    truth, rig, readings = _wall_case()
    seen = observed_walls(truth, rig, readings)
    cleared = OccupancyMap(truth.grid, np.where(seen, 0.0, truth.occupancy).astype(np.float32))
    s_clear = score(truth, cleared, observed=seen)
    s_true = score(truth, truth, observed=seen)
    assert s_true.observed_wall_recall == 1.0
    assert s_clear.observed_wall_recall == 0.0
    # Without passages the quality is the geometric mean of wall F1 and the recall: a
    # map that cleared every wall the sonar heard scores 0 whatever its wall F1.
    assert s_clear.f1_all > 0.3
    assert s_clear.quality == 0.0
    assert s_true.quality == pytest.approx(1.0)
    # Not given the observed walls, the recall is left out.
    assert math.isnan(score(truth, cleared).observed_wall_recall)
    assert score(truth, cleared).quality == pytest.approx(s_clear.f1_all)
    assert quality(0.2, 0.625, 0.512) == pytest.approx(0.4)
    # No part can be traded for another: closing every door costs it all.
    assert quality(0.9, 0.0, 1.0) == 0.0
    assert quality(float("nan"), 0.6, 0.9) == 0.0
    with pytest.raises(InputError, match="observed walls"):
        score(truth, truth, observed=seen[:, :5])


def test_observed_wall_recall_on_maps_built_to_fool_it() -> None:
    truth, rig, readings = _wall_case()
    seen = observed_walls(truth, rig, readings)
    g = truth.grid
    unknown = score(truth, OccupancyMap(g, np.full(g.shape, np.nan, np.float32)), observed=seen)
    free = score(truth, OccupancyMap(g, np.zeros(g.shape, np.float32)), observed=seen)
    solid = score(truth, OccupancyMap(g, np.ones(g.shape, np.float32)), observed=seen)
    rng = np.random.default_rng(0)
    speckle = score(
        truth, OccupancyMap(g, (rng.random(g.shape) < 0.5).astype(np.float32)), observed=seen
    )
    # Unknown and free maps recover no heard wall; a map marked occupied everywhere
    # recovers all of them but its wall F1, and so its quality, stays low; speckle
    # recovers about half and is no better.
    assert unknown.observed_wall_recall == 0.0
    assert free.observed_wall_recall == 0.0
    assert unknown.quality == 0.0
    assert free.quality == 0.0
    assert solid.observed_wall_recall == 1.0
    assert solid.quality < 0.6
    assert 0.3 < speckle.observed_wall_recall < 0.7
    assert speckle.quality < 0.6


#: Each method's defaults before issue 39, where they differ from today's (the
#: gradient's band was half a 5 cm cell behind the echo until 2026-12-07).
OLD_DEFAULTS: dict[str, dict[str, Any]] = {
    "inverse": {"p_free": 0.48, "falloff_deg": 10.0, "dr": None},
    "gradient": {"a2": 0.03, "no_echo": "free", "band_offset": 0.025},
}


@pytest.fixture(scope="module")
def maxsonar_hall() -> tuple[Scenario, npt.NDArray[np.bool_]]:
    # A hall the tuning never saw (seed 11; the sweep used seed 0), six MaxSonar EZ1s
    # at 2 Hz to keep the test short.
    scene = make_scenario("hall", rig="ez1-six", seed=11, rate=2.0)
    return scene, observed_walls(scene.truth, scene.rig, scene.readings)


@pytest.mark.slow
@pytest.mark.parametrize(("method", "least"), [("inverse", 0.55), ("gradient", 0.4)])
def test_default_maps_keep_the_walls_a_maxsonar_rig_hears(
    maxsonar_hall: tuple[Scenario, npt.NDArray[np.bool_]], method: str, least: float
) -> None:
    # Measured: inverse 0.60 (0.46 at the old defaults), gradient 0.46 (0.11: its
    # no-echo beams cleared the walls they crossed). Issue 39 asks for 0.7; neither
    # default reaches it (docs/results/2026-12-06-rig-defaults.md).
    scene, observed = maxsonar_hall

    def recall(**params: Any) -> float:
        m = make_mapper(method, **params).fit(scene.readings, scene.truth.grid, scene.rig)
        s = score(scene.truth, m.result(), scene.passages, scene.obstacles, observed)
        return s.observed_wall_recall

    assert recall() >= least
    assert recall(**OLD_DEFAULTS[method]) < least


def test_the_rigs_sweep_spans_the_sensor_presets() -> None:
    from pathlib import Path

    config = load_sweep(Path(__file__).parents[1] / "sweeps" / "rigs.yaml")
    rigs = {p.get("rig", "paper-synthetic") for p in config.scenarios.values()}
    sensors = {get_rig(r).sensor.name for r in rigs}
    assert sensors == {"maxsonar-ez1", "hc-sr04", "polaroid-6500"}
    assert config.metrics[0] == "quality"


def options_claim(
    hall: tuple[Scenario, npt.NDArray[np.bool_]],
    params: dict[str, Any],
    band_offset: float | None,
) -> None:
    """The claim of the tests below: on the held-out MaxSonar hall the option keeps at
    least 0.015 more of the observed walls than the gradient's default, both maps with
    the band ``band_offset`` behind the echo (None: the mapper's default)."""
    scene, observed = hall

    def recall(**p: Any) -> float:
        m = make_mapper("gradient", band_offset=band_offset, **p)
        m.fit(scene.readings, scene.truth.grid, scene.rig)
        s = score(scene.truth, m.result(), scene.passages, scene.obstacles, observed)
        return s.observed_wall_recall

    assert recall(**params) >= recall() + 0.015


@pytest.mark.slow
@pytest.mark.parametrize("params", [{"convex_start": True}, {"specular_deg": 15.0}])
def test_the_gradient_options_keep_more_walls_than_its_default_at_the_band_of_the_time(
    maxsonar_hall: tuple[Scenario, npt.NDArray[np.bool_]], params: dict[str, Any]
) -> None:
    # Measured: default 0.463, convex start 0.484, specular 15 degrees 0.496; passage
    # F1 0.25 for all three. Neither is the default: on the training scenes both lost
    # more passages than they gained walls (docs/results/2026-12-06-rig-defaults.md,
    # third pass). Measured with the band half a cell behind the echo (the default then,
    # before 2026-12-07), which every map here keeps.
    options_claim(maxsonar_hall, params, band_offset=0.025)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="at the band three quarters of a cell behind the echo (the default since "
    "2026-12-07) convex_start keeps 0.651 of the observed walls against the default's "
    "0.641, less than the 0.015 more claimed",
)
def test_convex_start_keeps_more_walls_than_the_default_at_the_default_band(
    maxsonar_hall: tuple[Scenario, npt.NDArray[np.bool_]],
) -> None:
    options_claim(maxsonar_hall, {"convex_start": True}, band_offset=None)


def test_door_verdict_names_the_first_test_failed() -> None:
    from benchmarks.doors import verdict

    from sonarmap.metrics import PassageResult

    def door(width: float, walls: tuple[float, float], crossed: bool) -> PassageResult:
        is_open = min(walls) >= 0.75 and crossed
        detected = is_open and abs(width - 0.9) <= 0.225
        return PassageResult("d", 0.9, width, walls, crossed, is_open, detected)

    assert verdict(door(0.85, (1.0, 1.0), True)) == "detected"
    assert verdict(door(math.nan, (1.0, 1.0), False)) == "closed"
    assert verdict(door(0.85, (0.33, 1.0), True)) == "walls"
    assert verdict(door(0.2, (1.0, 1.0), True)) == "width"


def test_jamb_walls_are_the_walls_beside_each_door() -> None:
    from benchmarks.doors import jamb_walls

    scene = make_scenario("suite", rig="hcsr04-six", rate=1.0, seed=5)
    cells = jamb_walls(scene)
    assert cells.any()
    assert np.all(scene.truth.occupancy.reshape(-1)[cells] > 0.5)
    xc, yc = scene.truth.grid.all_centres()
    x, y = xc.reshape(-1)[cells], yc.reshape(-1)[cells]
    # Each lies within half a door and 0.3 m (and a cell) of some door's middle, on the
    # door's wall, and each door has such cells on both sides.
    h = scene.truth.grid.resolution
    for p in scene.passages:
        mx, my = (p.a[0] + p.b[0]) / 2, (p.a[1] + p.b[1]) / 2
        near = np.hypot(x - mx, y - my) <= p.width / 2 + 0.3 + 2 * h
        assert np.sum(near & (x < mx)) > 0
        assert np.sum(near & (x > mx)) > 0
    mids = np.array([((p.a[0] + p.b[0]) / 2, (p.a[1] + p.b[1]) / 2) for p in scene.passages])
    d = np.min(np.hypot(x[:, None] - mids[:, 0], y[:, None] - mids[:, 1]), axis=1)
    assert np.all(d <= max(p.width for p in scene.passages) / 2 + 0.3 + 2 * h)


def test_free_parts_split_a_cells_free_weight_by_where_the_echo_lay() -> None:
    """Two readings cross cell 3: one whose echo lay 0.1 m beyond it on its axis, one
    whose echo lay 2 m beyond it 10 degrees off its axis; the parts split each cell's
    fall-off weight between the bins of :data:`benchmarks.doors.BEYOND`, and the bins
    add up to the whole."""
    from benchmarks.doors import free_parts

    from sonarmap.raster import CellSet

    sigma = math.radians(5.0)
    free = CellSet(
        offsets=np.array([0, 2, 4], np.int64),
        cells=np.array([3, 4, 3, 5], np.int32),
        distance=np.array([1.0, 0.5, 1.0, 0.5], np.float32),
        weight=np.ones(4, np.float32),
        bearing=np.radians(np.array([0.0, 0.0, 10.0, 10.0])).astype(np.float32),
    )
    parts = free_parts(free, np.array([1.1, 3.0]), sigma, 8)
    off_axis = math.exp(-2.0)  # 10 degrees at a 5-degree standard deviation
    assert parts["from_echo_within_0.3m"][3] == pytest.approx(1.0)
    assert parts["from_echo_beyond_1.0m"][3] == pytest.approx(off_axis, rel=1e-6)
    assert parts["from_echo_0.3_1.0m"][4] == pytest.approx(1.0)
    assert parts["from_on_axis"][3] == pytest.approx(1.0)
    bins = [k for k in parts if k.startswith("from_echo")]
    total = sum(parts[k] for k in bins)
    np.testing.assert_allclose(total, [0, 0, 0, 1 + off_axis, 1, off_axis, 0, 0], rtol=1e-6)
