"""What one turn out of a dead-end stub costs a tracking car, and what reversing out would.

One run of :mod:`benchmarks.patrol_cars`'s command-line setting (the library's car
defaults, :func:`benchmarks.patrol_fallback.fallback_config`) on a street site. Every
reversing manoeuvre a car begins for a path behind it (cause ``behind``) while it
stands in a dead-end stub (:func:`sonarmap.patrol.stubs.stub_cells`) is recorded:

- ``steps``: the steps the car drove it (the DVT it costs), and ``est``: the steps the
  planned arcs take at the car's speed where it began (:func:`steps_of`: a change of
  gear waits for the next step, as the car drives them), to check the estimate;
- the plan: ``cusps`` (changes of gear), metres in reverse and forwards;
- ``out_m``: how far along its route the car is from the stub's mouth (the first route
  point off the stub's cells), and the street's width there (twice the clearance);
- ``tail``: the steps of a recorded turn driven once every arc left is forwards (past
  the last cusp), and ``tail_aligned`` those with the route's pursuit point within
  :data:`ALIGNED` of the heading. A manoeuvre stops counting as DVT, and a turn stops
  being recorded, once no reversing arc is left, so the forward tail is not DVT and
  ``tail`` stays 0 unless that rule changes (a check, not a cost);
- ``alt``: the manoeuvre a search finds from the same pose (the same other cars in
  the way) to the route 1-8 m beyond the stub's mouth rather than 3-10 m on: the
  car may back straight out and turn into the street it came from, as a
  Reeds-Shepp path with one cusp does; its cusps, metres and ``alt_est`` steps, and
  ``alt_rev_est``, the steps up to and including its last reversing arc.

Printed: one JSON line per turn and a summary line: ``stub_turns``, ``stub_turn_dvt``
(their steps, % of the car-steps), ``mean_steps``, ``mean_cusps``, ``mean_out_m`` and
``width_m`` (min, median, max) over every turn; over the turns where ``alt`` was found
(``alt_found``), the like-for-like reversing steps: ``plan_mean_rev_est``, the mean of
each plan's steps up to its last reversing arc (``rev_est``: the arcs left after the
first step, estimated, plus that step), ``alt_mean_rev_est`` the same of ``alt``, and
``alt_fewer_reversing``, the turns whose ``alt`` has fewer of them than the plan;
``alt_mean_est`` and ``alt_fewer`` compare ``alt``'s total estimated steps (forward
arcs included) with the steps measured (reversing only), not like with like.

Run with ``python -m benchmarks.patrol_stub_turns --site 11 --cars 3 --duration 1200``;
one process, one core (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from benchmarks.patrol_fallback import fallback_site
from sonarmap.patrol import run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.manoeuvre import carrot, plan_manoeuvre, route_goals
from sonarmap.patrol.robots import Car, Team, wrap_angle
from sonarmap.patrol.stubs import stub_cells

#: Radians off the pursuit point within which a car in a manoeuvre's forward tail
#: counts as aligned with its route.
ALIGNED = 0.5


def steps_of(arcs: list[tuple[float, float]], per_step: float) -> tuple[int, int]:
    """Steps a car driving ``per_step`` metres a step takes for ``arcs`` (signed
    lengths, metres), a change of gear waiting for the next step, and the steps up to
    the end of the last arc in reverse."""
    total = 0
    upto = 0
    k = 0
    while k < len(arcs):
        gear = math.copysign(1.0, arcs[k][0])
        run = 0.0
        while k < len(arcs) and math.copysign(1.0, arcs[k][0]) == gear:
            run += abs(arcs[k][0])
            k += 1
        total += max(1, math.ceil(run / per_step - 1e-9))
        if gear < 0:
            upto = total
    return total, upto


def shape(arcs: list[tuple[float, float]]) -> dict[str, Any]:
    """Cusps and metres in reverse and forwards of ``arcs``."""
    gears = [math.copysign(1.0, a) for a, _ in arcs]
    return {
        "cusps": sum(1 for a, b in itertools.pairwise(gears) if a != b),
        "rev_m": round(sum(-a for a, _ in arcs if a < 0), 1),
        "fwd_m": round(sum(a for a, _ in arcs if a > 0), 1),
    }


def watch_run(site: int, cars: int, duration: float) -> dict[str, Any]:
    """One run's stub turns (see the module's notes)."""
    cfg, t, passable, ow = fallback_site(site, cars, duration)
    g = t.grid
    stub = stub_cells(passable, ow)
    prev: dict[int, tuple[float, float, float]] = {}
    prev_xy: list[npt.NDArray[np.float64]] = []
    open_turn: dict[int, dict[str, Any]] = {}
    turns: list[dict[str, Any]] = []

    def begin(team: Car, i: int, now: float) -> dict[str, Any] | None:
        route = team.routes[i]
        if route is None or len(route) < 2 or i not in prev:
            return None
        x, y, h = prev[i]
        r, c = (int(v) for v in g.world_to_cell(x, y))
        if not stub[r, c]:
            return None
        rr, cc = g.world_to_cell(route[:, 0], route[:, 1])
        off = np.flatnonzero(~stub[np.asarray(rr), np.asarray(cc)])
        seg = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(route, axis=0).T))])
        out_m = float(seg[off[0]]) if len(off) else float(seg[-1])
        per_step = team.speed_of(i, g) * cfg.dt
        plan = team.plans[i]
        assert plan is not None
        others = np.delete(prev_xy[0], i, axis=0) if prev_xy else None
        alt = plan_manoeuvre(
            (x, y, h),
            route_goals(route, near=out_m + 1.0, far=out_m + 8.0),
            passable,
            g,
            team.turn_radius,
            others=others,
            separation=team.min_separation + 0.5,
        )
        rec: dict[str, Any] = {
            "t": now,
            "car": i,
            "out_m": round(out_m, 1),
            "width_m": round(2 * float(t.clearance[r, c]), 1),
            "per_step_m": round(per_step, 3),
            "steps": 0,
            "tail": 0,
            "tail_aligned": 0,
            "arcs_left": [tuple(a) for a in plan.arcs],
        }
        if alt is not None:
            est, rev = steps_of(alt.arcs, per_step)
            rec["alt"] = {**shape(alt.arcs), "est": est, "rev_est": rev}
        else:
            rec["alt"] = None
        return rec

    def on_step(now: float, team: Team, _fog: Fog) -> None:
        assert isinstance(team, Car)
        for i in range(len(team)):
            plan = team.plans[i]
            active = plan is not None and plan.reverses and team.cause[i] == "behind"
            if i in open_turn and not active:
                turns.append(open_turn.pop(i))
            if active and i not in open_turn:
                rec = begin(team, i, now)
                if rec is not None:
                    open_turn[i] = rec
            if i in open_turn:
                rec = open_turn[i]
                rec["steps"] += 1
                assert plan is not None
                if all(length > 0 for length, _ in plan.arcs):
                    rec["tail"] += 1
                    route = team.routes[i]
                    x, y, h = float(team.x[i]), float(team.y[i]), float(team.heading[i])
                    if route is not None and len(route) >= 2:
                        px, py = carrot(route, x, y, cfg.lookahead)
                        off = abs(wrap_angle(math.atan2(py - y, px - x) - h))
                        rec["tail_aligned"] += int(off <= ALIGNED)
            prev[i] = (float(team.x[i]), float(team.y[i]), float(team.heading[i]))
        prev_xy[:] = [np.column_stack([team.x, team.y]).astype(np.float64)]

    result = run_patrol(t, cfg, robots=cars, seed=0, on_step=on_step)
    turns.extend(open_turn.values())
    for rec in turns:
        # The plan as driven: the arcs left after the first step plus that step.
        arcs = rec.pop("arcs_left")
        est, rev = steps_of(arcs, rec["per_step_m"])
        rec["plan"] = {
            **shape(arcs),
            "est_after_first": est,
            "rev_est_after_first": rev,
            "rev_est": rev + 1,
        }
    n = cars * len(result.t)
    alt_ok = [r for r in turns if r["alt"] is not None]
    return {
        "site": site,
        "cars": cars,
        "duration": duration,
        "dvt": round(float(result.summary()["dvt"]), 2),
        "stub_turns": len(turns),
        "stub_turn_dvt": round(100.0 * sum(r["steps"] for r in turns) / n, 2),
        "mean_steps": round(float(np.mean([r["steps"] for r in turns])), 1) if turns else None,
        "mean_out_m": round(float(np.mean([r["out_m"] for r in turns])), 1) if turns else None,
        "mean_cusps": (
            round(float(np.mean([r["plan"]["cusps"] for r in turns])), 1) if turns else None
        ),
        "tail_dvt": round(100.0 * sum(r["tail"] for r in turns) / n, 2),
        "tail_aligned_dvt": round(100.0 * sum(r["tail_aligned"] for r in turns) / n, 2),
        "alt_found": len(alt_ok),
        "alt_mean_est": (
            round(float(np.mean([r["alt"]["est"] for r in alt_ok])), 1) if alt_ok else None
        ),
        "alt_mean_rev_est": (
            round(float(np.mean([r["alt"]["rev_est"] for r in alt_ok])), 1) if alt_ok else None
        ),
        "alt_fewer": sum(1 for r in alt_ok if r["alt"]["est"] < r["steps"]),
        "plan_mean_rev_est": (
            round(float(np.mean([r["plan"]["rev_est"] for r in alt_ok])), 1) if alt_ok else None
        ),
        "alt_fewer_reversing": sum(1 for r in alt_ok if r["alt"]["rev_est"] < r["plan"]["rev_est"]),
        "width_m": (
            [round(float(f([r["width_m"] for r in turns])), 1) for f in (np.min, np.median, np.max)]
            if turns
            else None
        ),
        "turns": turns,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.patrol_stub_turns", description=__doc__)
    ap.add_argument("--site", type=int, default=11)
    ap.add_argument("--cars", type=int, default=3)
    ap.add_argument("--duration", type=float, default=1200.0)
    a = ap.parse_args(argv)
    out = watch_run(a.site, a.cars, a.duration)
    for rec in out.pop("turns"):
        print(json.dumps(rec))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
