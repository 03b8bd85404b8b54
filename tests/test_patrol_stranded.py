"""A tracking car whose forward wave leaves it nothing to go for runs its wave in every
direction (issue 36: cars standing for good on the fig. 3.10 map)."""

from __future__ import annotations

import math

import numpy as np

from conftest import CROSS_STREET_BLOCKS, walled_site
from sonarmap.patrol.manoeuvre import behind_cells, leads_on
from sonarmap.patrol.oneway import one_way
from sonarmap.patrol.paths import Wave
from sonarmap.patrol.robots import Car
from sonarmap.patrol.simulation import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory

RES = 0.5
#: A car at the mouth of a 3 m cross street on the site's bottom edge street, facing
#: east along it: a junction whose one-way streets all lead into it, its only way out
#: the cross street behind the car (found by searching the site's junctions).
TRAPPED = (26.25, 1.75, 0.0)


def _site() -> Territory:
    """The 44 x 44 m four-block site (``conftest.CROSS_STREET_BLOCKS``)."""
    return walled_site(CROSS_STREET_BLOCKS, 44.0, 44.0, RES)


def test_the_junction_traps_the_forward_wave() -> None:
    # The dead-end test floods the passable cells and finds the way ahead leading on;
    # the wave, keeping to the one-way streets, reaches only the junction.
    t = _site()
    g = t.grid
    passable = t.passable(1.0)
    streets = one_way(passable, t.clearance, RES, turn_radius=3.5)
    x, y, heading = TRAPPED
    r, c = (int(v) for v in g.world_to_cell(x, y))
    back = behind_cells(x, y, heading, g)
    assert leads_on(passable, back, (r, c))
    dist, _ = Wave(passable.shape, streets.steps)(passable, (r, c), RES, closed=back)
    reached = np.isfinite(dist)
    assert 0 < reached.sum() < 0.01 * passable.sum()
    rr, cc = np.nonzero(reached)
    px, py = g.cell_centres(rr, cc)
    assert np.hypot(px - x, py - y).max() < PatrolConfig().vision


def test_a_car_facing_into_the_trap_drives_on() -> None:
    # The places start long unseen (``start_fog``), so only those out of sight pull
    # and none in the junction does. The lift for stale places is off
    # (``forward_stale`` 0): in a team the other cars keep the mean time since seen up
    # and it does not fire (the fig. 3.10 map), where a lone standing car's own fog
    # would fire it. Measured before the change: the car stood the whole run (91 % of
    # the site never seen); now it turns round and drives on (88 m, 32 %).
    t = _site()
    path: list[tuple[float, float]] = []

    def keep(_t: float, team: object, _fog: object) -> None:
        assert isinstance(team, Car)
        path.append((float(team.x[0]), float(team.y[0])))

    cfg = PatrolConfig(model="car", duration=90.0, one_way=True, forward_stale=0.0, start_fog=60.0)
    assert cfg.forward_wave
    res = run_patrol(t, cfg, starts=np.array([TRAPPED]), seed=0, on_step=keep)
    xy = np.array(path)
    assert float(np.hypot(*np.diff(xy, axis=0).T).sum()) > 60.0
    assert res.summary()["never_seen"] < 0.5
    assert math.hypot(xy[-1, 0] - TRAPPED[0], xy[-1, 1] - TRAPPED[1]) > 5.0
