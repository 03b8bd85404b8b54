"""Numbers written in exponent form in configuration files (PyYAML reads ``1e-2`` as a
string): wherever a number is expected they are that number; other strings are refused
in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.acoustics import AcousticModel
from sonarmap.checks import numbers_where_floats
from sonarmap.cli import main
from sonarmap.errors import ConfigError, InputError
from sonarmap.mappers import make_mapper
from sonarmap.scenarios import Scenario, make_scenario, model_from_dict
from sonarmap.sensors import Noise
from sonarmap.sweep import load_sweep

EXPONENTS = """\
scenarios:
  doorways: {}
  noisy: {scenario: doorways, model: {kind: acoustic, p_rand: 2e-2, sigma: 1e-2}}
  thrun: {scenario: doorways, model: {kind: thrun, p_rand: 2e-2, sigma: 1e-2}}
methods:
  inverse: {p_occ: [7e-1, 0.6], dr: [null, 5e-2]}
"""


def test_sweep_file_reads_exponents_as_numbers(tmp_path: Path) -> None:
    (tmp_path / "s.yaml").write_text(EXPONENTS)
    cfg = load_sweep(tmp_path / "s.yaml")
    assert cfg.methods["inverse"] == {"p_occ": [0.7, 0.6], "dr": [None, 0.05]}
    noisy = cfg.scenarios["noisy"]["model"]
    assert model_from_dict(dict(noisy)) == AcousticModel(p_rand=0.02, sigma=0.01)
    thrun = cfg.scenarios["thrun"]["model"]
    assert model_from_dict(dict(thrun)) == Noise(p_rand=0.02, sigma=0.01)


def test_mapper_parameter_in_exponent_form_maps_the_same(doorways: Scenario) -> None:
    scene = doorways
    grid = scene.truth.grid
    a = make_mapper("inverse", p_occ="7e-1", dr="5e-2").fit(scene.readings, grid, scene.rig)
    b = make_mapper("inverse", p_occ=0.7, dr=0.05).fit(scene.readings, grid, scene.rig)
    assert a.get_params() == b.get_params()
    assert isinstance(a.get_params()["p_occ"], float)
    np.testing.assert_array_equal(a.occupancy_, b.occupancy_)


def test_scenario_parameters_in_exponent_form_simulate_the_same() -> None:
    a = make_scenario("passages", widths=["3e-1", "6e-1"], speed="2.5e-1", seed=3)
    b = make_scenario("passages", widths=[0.3, 0.6], speed=0.25, seed=3)
    np.testing.assert_array_equal(a.readings.range, b.readings.range)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "scenarios: {doorways: {}}\nmethods: {inverse: {p_occ: [abc]}}\n",
            r"s.yaml: parameter 'p_occ' must be a finite number, got 'abc'$",
        ),
        (
            "scenarios: {doorways: {}}\nmethods: {inverse: {p_occ: [1e-2e]}}\n",
            r"parameter 'p_occ' must be a finite number, got '1e-2e'$",
        ),
        (
            "scenarios: {d: {scenario: doorways, model: {sigma: 1e-2x}}}\nmethods: {inverse: {}}\n",
            r"acoustic model: sigma must be a number, got '1e-2x'$",
        ),
        (
            "scenarios: {d: {scenario: doorways, model: {kind: thrun, p_rand: abc}}}\n"
            "methods: {inverse: {}}\n",
            r"p_rand must be a number, got 'abc'$",
        ),
        # A name stays a name: no_echo takes words, and 1e5 is not one of them.
        (
            "scenarios: {doorways: {}}\nmethods: {inverse: {no_echo: [1e5]}}\n",
            r"parameter 'no_echo' must be one of free, ignore; got '1e5'$",
        ),
    ],
)
def test_a_string_that_is_not_a_number_is_refused(tmp_path: Path, text: str, match: str) -> None:
    (tmp_path / "s.yaml").write_text(text)
    with pytest.raises(InputError, match=match):
        load_sweep(tmp_path / "s.yaml")


def test_cli_refuses_a_word_for_a_number_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "s.yaml").write_text(
        "scenarios: {d: {scenario: doorways, model: {sigma: lots}}}\nmethods: {inverse: {}}\n"
    )
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "out"), "--workers", "1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "sigma must be a number, got 'lots'" in err
    assert not (tmp_path / "out").exists()


def test_numbers_where_floats_converts_only_float_parameters() -> None:
    def fn(*, x: float, xs: list[float], y: float | None, n: int, name: str) -> None: ...

    got = numbers_where_floats(
        {"x": "1e-2", "xs": ["2e1", 3], "y": "-.5", "n": "1e3", "name": "1e5"}, fn
    )
    assert got == {"x": 0.01, "xs": [20.0, 3], "y": -0.5, "n": "1e3", "name": "1e5"}
    assert numbers_where_floats({"x": "0x10"}, fn) == {"x": "0x10"}


def test_the_python_constructors_still_want_numbers() -> None:
    with pytest.raises(ConfigError, match="sigma must be a number, got '1e-2'"):
        AcousticModel(sigma="1e-2")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="sigma must be a number, got '1e-2'"):
        Noise(sigma="1e-2")  # type: ignore[arg-type]
