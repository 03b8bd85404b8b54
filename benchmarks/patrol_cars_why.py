"""Why tracking cars turn round, and whether they stand: one street-site run, watched.

For one run of :mod:`benchmarks.patrol_cars`'s setting (street site, cars, refinement,
artificial obstacles for teams, places out of sight, a turn penalty of 10, driving on
round the block rather than turning round when that is at most ``--round-block``
metres longer, 0 by default: the shortest path), every reversing manoeuvre a car
begins because its path leaves behind it (cause ``behind``) is put in one class, by the
shortest route to the same place that leaves forwards (the cells up to 4 m behind the car closed,
:func:`sonarmap.patrol.manoeuvre.behind_cells`):

- ``near``: the place is under 4 m away along the path;
- ``dead end``: no route leaves forwards even with no other robot about;
- ``others shut forward, same way`` / ``oncoming far`` / ``head-on``: one does, but
  not with the discs round the other robots (artificial obstacles, ``r_obst``) closed;
  it does again with the discs round the robots ahead going the car's way open
  (``same way``); or only with those round the robots ahead coming the other way
  farther than ``ONCOMING_NEAR`` open too, as a car driving on round the block leaves
  them (``oncoming far``); or not (``head-on``);
- ``forward longer``: one does with every disc closed, but it is longer.

The discs are the cars' own (:func:`sonarmap.patrol.simulation.obstacle_discs`, halved
as the run halves them), so this account cannot drift from the rule the cars follow.

Reported: the count of each class, the DVT each accounts for (% of the team's time,
every step of the manoeuvre), the extra length of the forward routes (m), and per car
the metres driven and the steps it stood still (a car standing for good is a
deadlock the DVT does not show).

Run with ``python -m benchmarks.patrol_cars_why --site 0 --cars 5 --duration 600
[--round-block 0]``; one process, one core.
"""

from __future__ import annotations

import argparse
import json
import os
from collections import Counter
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.fog import Fog, disc_offsets
from sonarmap.patrol.manoeuvre import behind_cells
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.paths import Wave
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Car, Team
from sonarmap.patrol.simulation import ONCOMING_NEAR, halves_discs, obstacle_discs


def watch_run(site: int, cars: int, duration: float, round_block: float) -> dict[str, Any]:
    """One run's classes of turns and standing (see the module's notes)."""
    t = street_territory(site)
    cfg = PatrolConfig(
        model="car",
        refine=True,
        crowding="obstacles" if cars > 1 else "none",
        duration=duration,
        turn_penalty=10.0,
        out_of_sight=True,
        round_block=round_block,
    )
    passable = reach(t, cfg.radius, mode="reachable", vision=cfg.vision).passable
    g = t.grid
    wave = Wave(passable.shape)
    obst = disc_offsets(cfg.r_obst, g.resolution)
    halve = halves_discs(cfg)
    seen: dict[int, object] = {}
    current: dict[int, str] = {}
    count: Counter[str] = Counter()
    steps: Counter[str] = Counter()
    extra: list[float] = []
    last: list[npt.NDArray[np.float64]] = []
    driven = np.zeros(cars)
    still = np.zeros(cars, dtype=np.int64)

    def discs(
        team: Team, i: int, following: bool, near: float = ONCOMING_NEAR
    ) -> list[npt.NDArray[np.intp]]:
        r, c = g.world_to_cell(team.x, team.y)
        cells = np.column_stack([np.asarray(r), np.asarray(c)])
        return obstacle_discs(
            team, i, cells, obst, passable.shape, halve=halve, following=following, near=near
        )

    def classify(team: Car, i: int, route: npt.NDArray[np.float64]) -> str:
        x, y, h = float(team.x[i]), float(team.y[i]), float(team.heading[i])
        r0, c0 = g.world_to_cell(x, y)
        gr, gc = g.world_to_cell(route[-1, 0], route[-1, 1])
        start, goal = (int(r0), int(c0)), (int(gr), int(gc))
        length = float(np.hypot(*np.diff(route, axis=0).T).sum())
        if length < 4.0:
            return "near"
        tgt = np.zeros_like(passable)
        tgt[goal] = True
        back = behind_cells(x, y, h, g)

        def forward(closed: list[npt.NDArray[np.intp]]) -> float:
            shut = np.concatenate([back, *closed])
            return wave.to(passable, start, goal, g.resolution, tgt, shut)

        if not np.isfinite(forward([])):
            return "dead end"
        with_all = forward(discs(team, i, following=False))
        if np.isfinite(with_all):
            extra.append(with_all - length)
            return "forward longer"
        if np.isfinite(forward(discs(team, i, following=True, near=np.inf))):
            return "others shut forward, same way"
        if np.isfinite(forward(discs(team, i, following=True))):
            return "others shut forward, oncoming far"
        return "others shut forward, head-on"

    def on_step(_t: float, team: Team, _fog: Fog) -> None:
        assert isinstance(team, Car)
        pose = np.concatenate([team.x, team.y])
        if last:
            d = np.hypot(team.x - last[0][:cars], team.y - last[0][cars:])
            driven[:] += d
            still[:] += d < 1e-9
        last[:] = [pose]
        for i, plan in enumerate(team.plans):
            if plan is None:
                current.pop(i, None)
                seen.pop(i, None)
                continue
            if plan.reverses and i in current:
                steps[current[i]] += 1
            # The plan itself, not its id(): a freed plan's address is often reused.
            if seen.get(i) is plan:
                continue
            seen[i] = plan
            route = team.routes[i]
            if not plan.reverses or route is None or team.cause[i] != "behind":
                current.pop(i, None)
                continue
            kind = classify(team, i, route)
            count[kind] += 1
            current[i] = kind

    result = run_patrol(t, cfg, robots=cars, seed=0, on_step=on_step)
    n = cars * duration / cfg.dt
    return {
        "site": site,
        "cars": cars,
        "duration": duration,
        "round_block": round_block,
        "dvt": round(float(result.summary()["dvt"]), 2),
        "mean_idleness": round(float(result.summary()["mean_idleness"]), 1),
        "behind_turns": dict(count),
        "behind_dvt": {k: round(100.0 * v / n, 2) for k, v in steps.items()},
        "forward_extra_m": sorted(round(e) for e in extra),
        "driven_m": driven.round().tolist(),
        "standing_steps": still.tolist(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.patrol_cars_why", description=__doc__)
    ap.add_argument("--site", type=int, default=0)
    ap.add_argument("--cars", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--round-block", type=float, default=0.0)
    a = ap.parse_args(argv)
    print(json.dumps(watch_run(a.site, a.cars, a.duration, a.round_block)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
