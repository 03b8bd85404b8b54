"""The research's claims on small scenes (README, "What the maps show")."""

from __future__ import annotations

import math

import pytest

from sonarmap.experiments import TRADITIONAL_INVERSE
from sonarmap.mappers import make_mapper
from sonarmap.metrics import PassageResult, measure_passage, passage_open
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.sensors import Noise

FORWARD = ("gradient", "stochastic", "em")


def open_doors(scene: Scenario, method: str, **params: object) -> int:
    m = make_mapper(method, **params).fit(scene.readings, scene.truth.grid, scene.rig).result()
    return sum(passage_open(scene.truth, m, p) for p in scene.passages)


def passages(scene: Scenario, method: str, **params: object) -> list[PassageResult]:
    m = make_mapper(method, **params).fit(scene.readings, scene.truth.grid, scene.rig).result()
    return [measure_passage(scene.truth, m, p) for p in scene.passages]


def narrowest(results: list[PassageResult]) -> float:
    return min((r.true_width for r in results if r.detected), default=math.inf)


@pytest.fixture(scope="module")
def ladder() -> Scenario:
    return make_scenario("passages", widths=(0.2, 0.4, 0.6, 0.8))


def test_traditional_inverse_closes_doorways(doorways: Scenario) -> None:
    assert open_doors(doorways, "inverse", **TRADITIONAL_INVERSE) < len(doorways.passages)


@pytest.mark.parametrize("method", FORWARD)
def test_forward_models_keep_every_doorway_open(doorways: Scenario, method: str) -> None:
    assert open_doors(doorways, method) == len(doorways.passages)


def test_tuned_inverse_keeps_doorways_open_too(doorways: Scenario) -> None:
    # Our finding: with sonar-appropriate increments the inverse baseline opens them all.
    assert open_doors(doorways, "inverse") == len(doorways.passages)


def test_stochastic_finds_passages_narrower_than_tuned_inverse(ladder: Scenario) -> None:
    inverse = narrowest(passages(ladder, "inverse"))
    stochastic = narrowest(passages(ladder, "stochastic"))
    assert stochastic * 1.6 <= inverse


@pytest.mark.parametrize(
    ("method", "params"), [("stochastic", {}), ("em", {}), ("gradient", {"a2": 0.001})]
)
def test_recovered_widths_within_one_cell(
    ladder: Scenario, method: str, params: dict[str, float]
) -> None:
    h = ladder.truth.grid.resolution
    results = [r for r in passages(ladder, method, **params) if r.detected]
    assert results
    for r in results:
        assert abs(r.width - r.true_width) <= h + 1e-9, r


@pytest.mark.parametrize("method", FORWARD)
def test_doorways_stay_open_with_outliers_and_noise(method: str) -> None:
    scene = make_scenario("doorways", noise=Noise(0.05, 1.0, 0.02), seed=3)
    assert open_doors(scene, method) == len(scene.passages)
