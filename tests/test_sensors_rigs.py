"""Sensor models, presets and rigs, and their YAML forms."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sonarmap.errors import ConfigError, InputError
from sonarmap.rig import RIG_PRESETS, get_rig, load_rig, save_rig
from sonarmap.sensors import SENSOR_PRESETS, Region, get_sensor, load_sensor, sensor_from_dict


@pytest.mark.parametrize("name", list(SENSOR_PRESETS))
def test_presets_round_trip_through_dict(name: str) -> None:
    s = get_sensor(name)
    assert sensor_from_dict(s.to_dict()) == s
    assert s.beam.contains(np.array([[min(1.0, s.r_max / 2), 0.0]]))[0]


def test_maxsonar_zones_are_nested_and_graded() -> None:
    s = get_sensor("maxsonar-ez1")
    sizes = [z[1] for z in s.zones]
    assert sizes == sorted(sizes)
    assert sizes[-1] < s.min_size
    near_axis = s.sensitivity(np.array([[1.0, 0.0], [3.0, 0.0], [5.0, 0.0]]))
    assert near_axis.tolist() == [0.0061, 0.0254, 0.0889]
    for region, _ in s.zones:
        assert np.all(s.beam.contains(region.outline))


def test_polygon_validation() -> None:
    with pytest.raises(ConfigError, match="not convex"):
        Region.polygon([[0.0, 0.0], [2.0, 0.0], [0.5, 0.5], [2.0, 1.0], [0.0, 1.0]])
    with pytest.raises(ConfigError, match="at least 3 vertices"):
        Region.polygon([[0, 0], [1, 1]])
    with pytest.raises(ConfigError, match="aperture_deg must be in"):
        Region.cone(200.0, 1.0)
    clockwise = Region.polygon([[0, 0], [0, 1], [1, 1], [1, 0]])
    assert clockwise.contains(np.array([[0.5, 0.5]]))[0]


def test_custom_sensor_yaml(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_text(
        "name: mine\nbeam: {cone: {aperture_deg: 40}}\nr_min: 0.05\nr_max: 3\n"
        "range_resolution: 0.01\nzones:\n  - {cone: {aperture_deg: 10}, min_size: 0.01}\n"
        "noise: {p_rand: 0.02, p_hit: 0.9, sigma: 0.01}\n"
    )
    s = load_sensor(p)
    assert s.r_max == 3.0
    assert s.noise.p_hit == 0.9
    assert len(s.zones) == 1
    p.write_text("name: mine\nbeam: {cone: {aperture_deg: 40}}\nr_max: 3\n")
    with pytest.raises(InputError, match="missing key 'range_resolution'"):
        load_sensor(p)
    p.write_text("preset: hc-sr04\nr_max: 2.0\nnoise: {p_hit: 2}\n")
    with pytest.raises(InputError, match="p_hit must be in"):
        load_sensor(p)


@pytest.mark.parametrize("name", list(RIG_PRESETS))
def test_rig_presets_round_trip(tmp_path: Path, name: str) -> None:
    rig = get_rig(name)
    save_rig(rig, tmp_path / "rig.yaml")
    back = load_rig(tmp_path / "rig.yaml")
    assert back.names == rig.names
    assert back.sensor == rig.sensor
    assert [m.yaw_deg for m in back.mounts] == [m.yaw_deg for m in rig.mounts]


def test_paper_rigs_match_the_research() -> None:
    synth = get_rig("paper-synthetic")
    yaws = sorted(m.yaw_deg for m in synth.mounts)
    assert yaws == [-120.0, -90.0, -60.0, 60.0, 90.0, 120.0]
    real = get_rig("paper-real")
    assert sorted(abs(m.yaw_deg) for m in real.mounts) == [0.0, 0.0, 45.0, 45.0]


def test_sensor_poses() -> None:
    rig = get_rig("paper-real")
    sx, sy, st = rig.sensor_poses([1.0], [2.0], [math.pi / 2])
    i = rig.index("outer_left")
    m = rig.mounts[i]
    assert sx[0, i] == pytest.approx(1.0 - m.y)
    assert sy[0, i] == pytest.approx(2.0 + m.x)
    assert st[0, i] == pytest.approx(math.pi / 2 + math.radians(45))
    with pytest.raises(ConfigError, match="unknown sensor 'x'"):
        rig.index("x")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("sonars: []\n", "missing key 'sensor'"),
        ("sensor: maxsonar-ez1\nsonars: []\n", "expected a non-empty list"),
        ("sensor: nope\nsonars: [{name: a, x: 0, y: 0, yaw_deg: 0}]\n", "unknown sensor preset"),
        (
            "sensor: hc-sr04\nsonars: [{name: a, x: 0, y: 0}]\n",
            r"sonars\[0\]: missing key 'yaw_deg'",
        ),
        (
            "sensor: hc-sr04\nsonars: [{name: a, x: q, y: 0, yaw_deg: 0}]\n",
            r"sonars\[0\].x: expected a number",
        ),
        (
            "sensor: hc-sr04\nsonars:\n - {name: a, x: 0, y: 0, yaw_deg: 0}\n"
            " - {name: a, x: 0, y: 0, yaw_deg: 9}\n",
            "duplicate sonar name",
        ),
        ("sensor: [\n", "not valid YAML"),
    ],
)
def test_bad_rig_files(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "rig.yaml"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        load_rig(p)


def test_rig_with_sensor_file(tmp_path: Path) -> None:
    (tmp_path / "sonar.yaml").write_text(
        "name: mine\nbeam: {cone: {aperture_deg: 25}}\nr_max: 3.0\nrange_resolution: 0.01\n"
    )
    (tmp_path / "rig.yaml").write_text(
        "sensor: sonar.yaml\nsonars: [{name: a, x: 0, y: 0, yaw_deg: 0}]\n"
    )
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.sensor.name == "mine"
    assert rig.sensor.r_max == 3.0
    (tmp_path / "rig.yaml").write_text(
        "sensor: missing.yaml\nsonars: [{name: a, x: 0, y: 0, yaw_deg: 0}]\n"
    )
    with pytest.raises(InputError, match=r"missing\.yaml: cannot read file"):
        load_rig(tmp_path / "rig.yaml")
