"""The pruned wave (the pulls' wave stopped near the robot) against whole-map waves in
two modes the Table 4 benchmark (``benchmarks.patrol --check``) does not run: holonomic
robots each with its own fog (no network), and cars whose places out of sight and
ahead pull (their targets are run buffers changed in place every step)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.maps import street_territory


@pytest.mark.parametrize(
    "settings",
    [
        {"model": "holonomic", "network": "none"},
        {"model": "car", "refine": True, "crowding": "obstacles", "out_of_sight": True},
    ],
    ids=["holonomic-own-fogs", "car-out-of-sight"],
)
def test_pruned_waves_give_the_whole_map_waves_answers(settings: dict[str, Any]) -> None:
    t = street_territory(0)
    runs = [
        run_patrol(
            t,
            PatrolConfig(
                duration=60.0 if settings["model"] == "car" else 20.0, prune=prune, **settings
            ),
            robots=3,
            seed=0,
        )
        for prune in (True, False)
    ]
    np.testing.assert_array_equal(runs[0].mtb, runs[1].mtb)
    np.testing.assert_array_equal(runs[0].dvt, runs[1].dvt)
    np.testing.assert_array_equal(runs[0].positions, runs[1].positions)
    # Something happened: the robots moved.
    assert runs[0].summary()["mean_mtb"] > 0
