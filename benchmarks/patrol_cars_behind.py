"""Why tracking cars turn round for a path behind them, at the benchmark's defaults.

One run of :mod:`benchmarks.patrol_cars`'s command-line setting (the library's
:data:`sonarmap.patrol.simulation.CAR_DEFAULTS`: forward wave, turn penalty, turn
time, round block, one-way streets for more than one car; refinement, artificial
obstacles for teams, seed 0; :func:`benchmarks.patrol_fallback.fallback_config`) on a
street site. Every reversing manoeuvre a car begins because its path lies behind it
(cause ``behind``) is put in the first class it fits:

- ``start``: the car's first such turn, in the run's first 20 s;
- ``against one-way``: the car stands on the one-way part of a one-way street
  (:mod:`sonarmap.patrol.oneway`) facing against it (the step nearest its heading is
  not allowed out of its cell);
- ``dead end, in a stub`` / ``dead end, elsewhere``: no route to the place leaves
  forwards (the cells up to 4 m behind the car closed,
  :func:`sonarmap.patrol.manoeuvre.behind_cells`, on the run's allowed steps),
  whatever the other cars do; the car stands in a dead-end stub
  (:attr:`sonarmap.patrol.oneway.OneWay.stubs`, ``stub_ends``) or not;
- ``same place, flipped``: the car's route on the step before went for the same place
  (its end within a cell) and led ahead of it: the route flipped behind, the place
  did not change (another car's disc shutting the street, the forward wave's
  dead-end test changing its mind);
- ``new place``: the place is another than on the step before (or the car had no
  route then).

Reported per class: the turns, the DVT they account for (% of the team's time, every
reversing step of the manoeuvre), and for ``same place, flipped`` and ``new place``
how much longer the forward route is (m; none: only with the other cars' discs open).

Run with ``python -m benchmarks.patrol_cars_behind --site 6 --cars 5 --duration 1200``;
one process, one core (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
from collections import Counter
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from benchmarks.patrol_fallback import fallback_site
from sonarmap.patrol import run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.manoeuvre import behind_cells, carrot
from sonarmap.patrol.paths import Wave, nearest_step
from sonarmap.patrol.robots import Car, Team

#: Seconds from the run's start within which a car's first turn counts as ``start``.
START_S = 20.0


def watch_run(site: int, cars: int, duration: float) -> dict[str, Any]:
    """One run's classes of ``behind`` turns (see the module's notes)."""
    cfg, t, passable, ow = fallback_site(site, cars, duration)
    g = t.grid
    oneway_on = cars > 1
    wave = Wave(passable.shape, ow.steps if oneway_on else None)
    seen: dict[int, object] = {}
    current: dict[int, str] = {}
    turned: set[int] = set()
    # Per car, the step before: its route's end cell and whether its route led ahead.
    before: dict[int, tuple[tuple[int, int], bool]] = {}
    count: Counter[str] = Counter()
    steps: Counter[str] = Counter()
    extra: dict[str, list[float]] = {"same place, flipped": [], "new place": []}
    clock = [0]

    def against(team: Car, i: int, cell: tuple[int, int]) -> bool:
        e = int(ow.street[cell])
        if not oneway_on or e < 0 or not ow.one_way[e] or ow.two_way[cell]:
            return False
        h = float(team.heading[i])
        j = nearest_step(math.cos(h), math.sin(h))
        return not (int(ow.steps[cell]) >> j) & 1

    def classify(team: Car, i: int, route: npt.NDArray[np.float64], now: float) -> str:
        x, y, h = float(team.x[i]), float(team.y[i]), float(team.heading[i])
        r0, c0 = g.world_to_cell(x, y)
        gr, gc = g.world_to_cell(route[-1, 0], route[-1, 1])
        start, goal = (int(r0), int(c0)), (int(gr), int(gc))
        first = i not in turned
        turned.add(i)
        if first and now < START_S:
            return "start"
        if against(team, i, start):
            return "against one-way"
        tgt = np.zeros_like(passable)
        tgt[goal] = True
        length = float(np.hypot(*np.diff(route, axis=0).T).sum())
        fwd = wave.to(passable, start, goal, g.resolution, tgt, behind_cells(x, y, h, g))
        if not np.isfinite(fwd):
            e = int(ow.street[start])
            stub = bool(ow.stub_ends[start]) or (e >= 0 and bool(ow.stubs[e]))
            return "dead end, in a stub" if stub else "dead end, elsewhere"
        prev = before.get(i)
        same = prev is not None and max(abs(prev[0][0] - goal[0]), abs(prev[0][1] - goal[1])) <= 1
        kind = "same place, flipped" if same and prev is not None and prev[1] else "new place"
        extra[kind].append(fwd - length)
        return kind

    def on_step(now: float, team: Team, _fog: Fog) -> None:
        assert isinstance(team, Car)
        for i, plan in enumerate(team.plans):
            route = team.routes[i]
            if plan is not None:
                if plan.reverses and i in current:
                    steps[current[i]] += 1
                if seen.get(i) is not plan:
                    seen[i] = plan
                    current.pop(i, None)
                    if plan.reverses and route is not None and team.cause[i] == "behind":
                        kind = classify(team, i, route, now)
                        count[kind] += 1
                        current[i] = kind
                        steps[kind] += 1
            else:
                current.pop(i, None)
                seen.pop(i, None)
            if route is not None and len(route) >= 2:
                end = g.world_to_cell(route[-1, 0], route[-1, 1])
                x, y = float(team.x[i]), float(team.y[i])
                ahead = not team.is_behind(i, carrot(route, x, y, cfg.lookahead))
                before[i] = ((int(end[0]), int(end[1])), ahead)
            else:
                before.pop(i, None)
        clock[0] += 1

    result = run_patrol(t, cfg, robots=cars, seed=0, on_step=on_step)
    n = cars * len(result.t)
    s = result.summary()
    return {
        "site": site,
        "cars": cars,
        "duration": duration,
        "dvt": round(float(s["dvt"]), 2),
        "mean_mtb": round(float(s["mean_mtb"]), 1),
        "never_seen": round(100 * float(s["never_seen"]), 3),
        "behind_turns": dict(count),
        "behind_dvt": {k: round(100.0 * v / n, 2) for k, v in steps.items()},
        "forward_extra_m": {k: sorted(round(e) for e in v) for k, v in extra.items()},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.patrol_cars_behind", description=__doc__
    )
    ap.add_argument("--site", type=int, default=6)
    ap.add_argument("--cars", type=int, default=5)
    ap.add_argument("--duration", type=float, default=1200.0)
    a = ap.parse_args(argv)
    print(json.dumps(watch_run(a.site, a.cars, a.duration)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
