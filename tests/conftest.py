"""Shared fixtures: small scenes that keep the suite fast."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pandas as pd
import pytest
from hypothesis import settings
from hypothesis import strategies as st

from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol.territory import Territory
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.sensors import Region, SensorModel

# CI replays a fixed sequence of examples so that a run is reproducible; developers'
# runs explore new ones each time.
# Benchmark modules that tests import set NUMBA_NUM_THREADS=1 (setdefault) for their own
# runs, and numba refuses a new value once its threads have started: pin the value numba
# already chose, so that importing one mid-session changes nothing.
os.environ.setdefault("NUMBA_NUM_THREADS", str(numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]

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


#: Four 17-18 x 13-17 m blocks of a 44 x 44 m site (x0, y0, x1, y1 metres): 3 m edge
#: streets, a 3 m cross street (x 20-23 m) and an 8 m middle street (y 16-24 m).
CROSS_STREET_BLOCKS = [
    (3.0, 3.0, 20.0, 16.0),
    (23.0, 3.0, 41.0, 16.0),
    (3.0, 24.0, 20.0, 41.0),
    (23.0, 24.0, 41.0, 41.0),
]


def walled_site(
    blocks: list[tuple[float, float, float, float]], w: float, h: float, res: float = 0.5
) -> Territory:
    """A ``w`` x ``h`` m street site walled round at ``res`` m cells, with solid blocks
    (x0, y0, x1, y1) metres, origin at (0, 0)."""
    g = Grid(resolution=res, origin=(0.0, 0.0), shape=(int(h / res), int(w / res)))
    occ = np.zeros(g.shape, np.float32)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    for x0, y0, x1, y1 in blocks:
        # Rows grow downwards: y = h at row 0.
        occ[int((h - y1) / res) : int((h - y0) / res), int(x0 / res) : int(x1 / res)] = 1.0
    return Territory.from_map(OccupancyMap(g, occ))


def training_sweep(method: str, settings: dict[str, dict[str, Any]]) -> pd.DataFrame:
    """A made-up sweep's results.csv for the training-rule scorers: each setting of
    ``method`` on the 16 training maps (seeds 0 and 1), every map with the setting's
    figures (keys ``quality``, ``recall``, ``f1``, ``precision``; defaults 0.2, 0.5, 0.3,
    0.7) and one passage, a hall-ring16 map's passages by ``ring_passages`` (default 1)."""
    from benchmarks.inverse_walls import RIG_OF

    rows = []
    for setting, f in settings.items():
        for scenario in RIG_OF:
            for seed in (0, 1):
                ring = scenario == "hall-ring16"
                rows.append(
                    {
                        "scenario": scenario,
                        "seed": seed,
                        "method": method,
                        "params": setting,
                        "quality": f.get("quality", 0.2),
                        "observed_wall_recall": f.get("recall", 0.5),
                        "passages_detected": f.get("ring_passages", 1) if ring else 1,
                        "f1_all": f.get("f1", 0.3),
                        "precision_all": f.get("precision", 0.7),
                    }
                )
    return pd.DataFrame(rows)


def refused_in_one_line(
    main: Any, args: list[str], why: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Assert that the argparse command ``main(args)`` exits 2 with argparse's usage and
    then one error line that holds ``why``."""
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert why in err[-1]
    assert sum("error:" in line for line in err) == 1


#: The drawn test building (x0, y0, x1, y1 metres): 8 x 6 m, one-cell walls, a 1.2 m
#: door between its two rooms and an entrance in its south wall centred at x = 6 m.
BUILDING = (0.0, 0.0, 8.0, 6.0)


def drawn_building(
    outside: float = 0.0, entrance: bool = True, width: float = 1.2, res: float = 0.1
) -> OccupancyMap:
    """The test building drawn at ``res`` metres (0.1; walls 0.1 m thick at 0.05 too)
    with 5 m of outside all round, the outside at occupancy ``outside`` (0 free, 0.5
    unknown) and the entrance ``width`` metres wide (none when ``entrance`` is false)."""
    grid = Grid.from_bounds(-5.0, -5.0, 13.0, 11.0, res)
    occ = np.full(grid.shape, outside, dtype=np.float32)
    x, y = grid.all_centres()
    x0, y0, x1, y1 = BUILDING
    ring = (x > x0) & (x < x1) & (y > y0) & (y < y1)
    inner = (x > x0 + 0.1) & (x < x1 - 0.1) & (y > y0 + 0.1) & (y < y1 - 0.1)
    occ[ring] = 0.0
    occ[ring & ~inner] = 1.0
    if entrance:
        occ[ring & (y < y0 + 0.1) & (np.abs(x - 6.0) < 0.5 * width)] = 0.0
    occ[ring & (np.abs(x - 4.05) < 0.05) & ~((y > 2.4) & (y < 3.6))] = 1.0
    return OccupancyMap(grid, occ)


def building_cells(plan: OccupancyMap) -> np.ndarray:
    """The cells of ``plan`` inside the test building's outer outline, walls included."""
    x, y = plan.grid.all_centres()
    x0, y0, x1, y1 = BUILDING
    return np.asarray((x > x0) & (x < x1) & (y > y0) & (y < y1))
