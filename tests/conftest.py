"""Shared fixtures: small scenes that keep the suite fast."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
from hypothesis import settings
from hypothesis import strategies as st

from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.sensors import Region, SensorModel

# CI replays a fixed sequence of examples so that a run is reproducible; developers'
# runs explore new ones each time.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


# Beams and poses the rasteriser's and the insertion kernel's property tests share.
def cone_sensor(aperture: float) -> SensorModel:
    return SensorModel(
        "cone", Region.cone(aperture, 3.0), r_min=0.0, r_max=3.0, range_resolution=0.02
    )


def zoned_sensor() -> SensorModel:
    return SensorModel(
        "zoned",
        Region.polygon([[0.0, 0.0], [2.5, -1.0], [3.0, 0.0], [2.5, 1.0]]),
        r_min=0.0,
        r_max=3.0,
        range_resolution=0.02,
        min_size=0.2,
        zones=((Region.polygon([[0.0, 0.0], [1.5, -0.3], [1.5, 0.3]]), 0.05),),
    )


poses = st.tuples(
    st.floats(-2.5, 2.5),
    st.floats(-2.5, 2.5),
    st.floats(-math.pi, math.pi),
    st.floats(0.0, 3.5),
)


@pytest.fixture(scope="session")
def doorways() -> Scenario:
    return make_scenario("doorways")


@pytest.fixture(scope="session")
def small_passages() -> Scenario:
    return make_scenario("passages", widths=(0.3, 0.6))
