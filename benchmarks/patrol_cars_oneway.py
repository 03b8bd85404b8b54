"""Where one-way cars still manoeuvre: the DVT split by cause and by the car's cell.

Setting: one run of ``benchmarks.patrol_cars``'s cars with one-way streets
(:mod:`sonarmap.patrol.oneway`) on a street site. Every step a car spends on a
manoeuvre (by :data:`sonarmap.patrol.robots.CAUSES`) is put in one class by the cell the
car is on: a ``junction``, a ``stub`` (a bridge of the street graph, two-way, or a
junction beyond one, :attr:`sonarmap.patrol.oneway.OneWay.stub_ends`), a ``two-way
end`` of a one-way street (within its junction's reach of either end), the ``one-way``
part of a street, or a ``wide`` two-way street. Figures are % of the team's
time, so they add up to the run's DVT. The cars run without the turn-time rule
(``car_config``'s ``turn_time`` 0, which predates the rule and keeps this benchmark's
figures as measured; only ``patrol_cars``'s command line sets 30 s).

Also printed: the watched places in dead-end stubs and how many of them a car sees from
the junction the stub opens on (those with a stand point,
:func:`sonarmap.patrol.stubs.stand_points`), and the sizes of the strongly connected
sets of the reachable passable cells under the allowed steps, by the wave's own step rule
(:func:`sonarmap.patrol.oneway.strong_sets`; one set: every place reachable from every other).

Run with ``python -m benchmarks.patrol_cars_oneway --site 3 --cars 5 --duration 1200
[--stub-sight] [--stub-delay 0]``;
one process, one core (``NUMBA_NUM_THREADS=1``); prints one JSON line.
"""

from __future__ import annotations

import json
import os
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from benchmarks.patrol import OneLineParser, non_negative
from benchmarks.patrol_cars import car_config
from sonarmap.patrol import run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.oneway import OneWay, one_way, strong_sets
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import CAUSES, Car, Team
from sonarmap.patrol.simulation import SIGHT_MARGIN
from sonarmap.patrol.stubs import stand_points, stub_places


def cell_class(ow: OneWay, r: int, c: int) -> str:
    """The class of cell (r, c) (see the module's notes)."""
    e = int(ow.street[r, c])
    if ow.stub_ends[r, c]:
        return "stub"  # a junction beyond a stub: as much a dead end
    if e < 0:
        return "junction"
    if ow.bridges[e]:
        return "stub"
    if not ow.one_way[e]:
        return "wide"
    return "two-way end" if ow.two_way[r, c] else "one-way"


def watch_run(
    site: int, cars: int, duration: float, stub_sight: bool = False, stub_delay: float = 0.0
) -> dict[str, Any]:
    """One run's split (see the module's notes)."""
    # The training runs' configuration (benchmarks.patrol_cars, one-way for teams).
    config = car_config(
        "track",
        cars,
        "obstacles",
        duration,
        one_way=True,
        stub_sight=stub_sight,
        stub_delay=stub_delay,
    )
    t = street_territory(site)
    # The simulation's own passable cells, so the system is the one the cars use.
    where = reach(t, config.radius, mode=config.reach, vision=config.vision)
    passable = where.passable
    ow = one_way(passable, t.clearance, t.grid.resolution, config.turn_radius)
    stands = stand_points(
        passable, where.watched, ow, t.grid.resolution, config.vision - SIGHT_MARGIN
    )
    before = {k: np.zeros(cars, dtype=np.int64) for k in CAUSES}
    counts: dict[str, int] = {}

    def keep(_t: float, team: Team, _fog: Fog) -> None:
        assert isinstance(team, Car)
        r, c = t.grid.world_to_cell(team.x, team.y)
        for cause in CAUSES:
            now = team.escape_causes[cause]
            for i in np.flatnonzero(now > before[cause]).tolist():
                key = f"{cause}, {cell_class(ow, int(r[i]), int(c[i]))}"
                counts[key] = counts.get(key, 0) + 1
            before[cause] = now.copy()

    result = run_patrol(t, config, robots=cars, seed=0, on_step=keep)
    steps = len(result.t) * cars
    return {
        "site": site,
        "cars": cars,
        "duration": duration,
        "stub_sight": stub_sight,
        "stub_delay": stub_delay,
        "dvt": round(float(result.summary()["dvt"]), 2),
        "dvt_by_cause_and_cell": {
            k: round(100.0 * v / steps, 2) for k, v in sorted(counts.items())
        },
        "streets": len(ow.one_way),
        "one_way_streets": int(ow.one_way.sum()),
        "bridges": int(ow.bridges.sum()),
        "stub_places": int(stub_places(passable, where.watched, ow).sum()),
        "stub_places_with_stand_point": int((stands >= 0).sum()),
        "strongly_connected_sets": strong_sets(passable, ow.steps)[:5].tolist(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="python -m benchmarks.patrol_cars_oneway", description=__doc__)
    ap.add_argument("--site", type=int, default=3)
    ap.add_argument("--cars", type=int, default=5)
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--stub-sight", action="store_true")
    ap.add_argument("--stub-delay", type=non_negative, default=0.0)
    a = ap.parse_args(argv)
    print(json.dumps(watch_run(a.site, a.cars, a.duration, a.stub_sight, a.stub_delay)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
