"""The claims of the held-out results page (``docs/results/2026-11-22-held-out-scenes.md``),
on held-out scenes only (sonarmap.splits): families and seeds no method was tuned on, read
by the acoustic sonar, every method at its defaults.

The full-size figures come from ``sonarmap experiment passages`` and ``sonarmap
experiment doorways`` (ten and five scenes); these tests run smaller held-out scenes and
assert the claims with the margins those runs showed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import pytest

from sonarmap.experiments import METHODS, MethodSpec
from sonarmap.mappers import make_mapper
from sonarmap.metrics import measure_passage, score
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.splits import HELD_OUT_SEED

# Its module fixtures map whole held-out scenes with every method (minutes).
pytestmark = pytest.mark.slow

SEEDS = (HELD_OUT_SEED + 20, HELD_OUT_SEED + 21, HELD_OUT_SEED + 22)
WIDTHS = (0.3, 0.5, 0.7, 0.9, 1.2)


@dataclass(frozen=True)
class Result:
    """One method over several held-out scenes."""

    detected: dict[float, list[bool]]
    false_openings: list[int]
    wall_f1: list[float]
    passage_f1: list[float]

    @property
    def n_detected(self) -> int:
        return sum(sum(v) for v in self.detected.values())

    @property
    def narrowest(self) -> float:
        """Narrowest width detected in any scene (inf when none)."""
        return min((w for w, got in self.detected.items() if any(got)), default=math.inf)

    def mean(self, values: Sequence[float]) -> float:
        return sum(values) / len(values)


def run(spec: MethodSpec, scenes: Sequence[Scenario]) -> Result:
    detected: dict[float, list[bool]] = {}
    fo, wf1, pf1 = [], [], []
    for scene in scenes:
        m = make_mapper(spec.method, **spec.params)
        got = m.fit(scene.readings, scene.truth.grid, scene.rig).result()
        for p in scene.passages:
            r = measure_passage(scene.truth, got, p)
            detected.setdefault(round(p.width, 2), []).append(r.detected)
        s = score(scene.truth, got, scene.passages)
        fo.append(s.false_openings)
        wf1.append(s.f1_all)
        pf1.append(s.passage_f1)
    return Result(detected, fo, wf1, pf1)


@pytest.fixture(scope="module")
def gaps() -> dict[str, Result]:
    scenes = [make_scenario("gaps", seed=sd, widths=WIDTHS, posts=0) for sd in SEEDS]
    return {spec.label: run(spec, scenes) for spec in METHODS}


@pytest.fixture(scope="module")
def corridors() -> dict[str, Result]:
    scenes = [make_scenario("corridor", seed=sd) for sd in SEEDS]
    return {spec.label: run(spec, scenes) for spec in METHODS}


FAMILIES = ("gaps", "corridors")
ADAPTIVE = [m.label for m in METHODS if m.label != "inverse-traditional"]


@pytest.fixture(scope="module")
def both(gaps: dict[str, Result], corridors: dict[str, Result]) -> dict[str, dict[str, Result]]:
    return {"gaps": gaps, "corridors": corridors}


@pytest.mark.parametrize("family", FAMILIES)
def test_every_tuned_method_detects_passages_the_traditional_inverse_none(
    both: dict[str, dict[str, Result]], family: str
) -> None:
    res = both[family]
    for label in ADAPTIVE:
        assert math.isfinite(res[label].narrowest), label
    assert res["inverse-traditional"].n_detected == 0


@pytest.mark.parametrize("family", FAMILIES)
def test_tuned_inverse_beats_the_traditional_setting(
    both: dict[str, dict[str, Result]], family: str
) -> None:
    tuned, trad = both[family]["inverse"], both[family]["inverse-traditional"]
    assert tuned.n_detected > trad.n_detected
    assert tuned.mean(tuned.passage_f1) > trad.mean(trad.passage_f1)
    assert tuned.mean(tuned.wall_f1) > trad.mean(trad.wall_f1)


@pytest.mark.parametrize("family", FAMILIES)
def test_em_detects_as_many_as_the_tuned_inverse_with_fewer_false_openings(
    both: dict[str, dict[str, Result]], family: str
) -> None:
    # Before the band offset EM found twice the inverse's passages with half its false
    # openings; the inverse gained more from the offset (full runs: gaps 45 against 23,
    # corridors 14 against 13), and these scenes show as many on gaps (5 and 5).
    em, inv = both[family]["em"], both[family]["inverse"]
    assert em.n_detected >= inv.n_detected
    assert sum(em.false_openings) < sum(inv.false_openings)
    assert em.mean(em.passage_f1) > inv.mean(inv.passage_f1) + 0.03


@pytest.mark.parametrize("family", FAMILIES)
def test_gradient_at_its_defaults_detects_more_than_the_tuned_inverse(
    both: dict[str, dict[str, Result]], family: str
) -> None:
    grad, inv = both[family]["gradient"], both[family]["inverse"]
    assert grad.n_detected > inv.n_detected
    assert grad.narrowest <= inv.narrowest
    assert grad.mean(grad.passage_f1) > inv.mean(inv.passage_f1)


@pytest.mark.parametrize("family", FAMILIES)
def test_stochastic_search_sees_through_walls_most(
    both: dict[str, dict[str, Result]], family: str
) -> None:
    # Where a forward method loses: Thrun's model explains a reading with one occupied
    # cell, so walls come out dotted, and every gap between dots is a false opening.
    res = both[family]
    worst = sum(res["stochastic"].false_openings)
    assert all(worst > 2 * sum(res[k].false_openings) for k in res if k != "stochastic")


def test_no_method_detects_gaps_of_half_a_metre(gaps: dict[str, Result]) -> None:
    # A wide-beam sonar a metre off hears the jambs of a narrow gap before anything
    # behind it: on held-out scenes no method finds 0.3 or 0.5 m gaps.
    for label, res in gaps.items():
        assert not any(res.detected[0.3] + res.detected[0.5]), label
