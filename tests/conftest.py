"""Shared fixtures: small scenes that keep the suite fast."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from sonarmap.scenarios import Scenario, make_scenario

# CI replays a fixed sequence of examples so that a run is reproducible; developers'
# runs explore new ones each time.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def doorways() -> Scenario:
    return make_scenario("doorways")


@pytest.fixture(scope="session")
def small_passages() -> Scenario:
    return make_scenario("passages", widths=(0.3, 0.6))
