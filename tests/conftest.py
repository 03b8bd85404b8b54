"""Shared fixtures: small scenes that keep the suite fast."""

from __future__ import annotations

from pathlib import Path

import pytest

from sonarmap.scenarios import Scenario, make_scenario

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def doorways() -> Scenario:
    return make_scenario("doorways")


@pytest.fixture(scope="session")
def small_passages() -> Scenario:
    return make_scenario("passages", widths=(0.3, 0.6))
