"""Where the slow car test's margin went: training street site 0, 1 car, 600 s.

The setting of ``tests/test_patrol_car.py``'s slow DVT test (refinement, the forward
wave, seed 0), run with each of the three changes of the cars-unstuck work switched
back one at a time: the start heading (``--plus-x``: the spread start faces +x, as
before), the manoeuvre search's arc check (``--samples N``: points checked per metre,
64 now, 16 before) and the stall watch (``--no-unstall``: a stalled car never searches
again). Printed: one JSON line (DVT %, its causes, the stalls).

With ``--fallback-setting`` the setting is instead ``benchmarks.patrol_fallback``'s
(the library's car defaults, artificial obstacles; its 1,200 s training table).

Run with ``python -m benchmarks.patrol_car_margin [--plus-x] [--samples 16]
[--no-unstall] [--fallback-setting] [--duration S]``; one process, one core
(``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from benchmarks.patrol_fallback import fallback_config
from sonarmap.grid import Grid
from sonarmap.patrol import manoeuvre, run_patrol
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Car
from sonarmap.patrol.simulation import PatrolConfig
from sonarmap.patrol.starts import spread_starts


def main(argv: list[str] | None = None) -> None:
    """Run the test's setting once with the changes asked for switched back."""
    ap = argparse.ArgumentParser(prog="python -m benchmarks.patrol_car_margin", description=__doc__)
    ap.add_argument("--site", type=int, default=0)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--plus-x", action="store_true", help="the spread start faces +x")
    ap.add_argument("--samples", type=int, default=manoeuvre.SAMPLES_PER_M)
    ap.add_argument("--no-unstall", action="store_true", help="a stalled car never searches")
    ap.add_argument("--fallback-setting", action="store_true", help="patrol_fallback's setting")
    a = ap.parse_args(argv)
    # Module constants switched for this process only: the benchmark's whole point.
    manoeuvre.SAMPLES_PER_M = a.samples
    if a.no_unstall:

        def never(self: Car, i: int, passable: npt.NDArray[np.bool_], grid: Grid) -> bool:
            self.still[i] = 0
            return False

        Car.unstall = never  # type: ignore[method-assign]  # the point of --no-unstall
    t = street_territory(a.site)
    cfg = (
        fallback_config(1, a.duration)
        if a.fallback_setting
        else PatrolConfig(model="car", refine=True, duration=a.duration, forward_wave=True)
    )
    starts = None
    if a.plus_x:
        where = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision)
        starts = spread_starts(1, t, where.passable, cfg.min_separation, 0)
    seen: list[Car] = []

    def keep(time: float, team: object, fog: object) -> None:
        if not seen and isinstance(team, Car):
            seen.append(team)

    res = run_patrol(t, cfg, starts=starts, robots=None if a.plus_x else 1, seed=0, on_step=keep)
    car = seen[0]
    steps = max(1, len(res.t))
    s = res.summary()
    out = {
        "site": a.site,
        "duration": a.duration,
        "plus_x": a.plus_x,
        "samples_per_m": a.samples,
        "unstall": not a.no_unstall,
        "setting": "patrol_fallback" if a.fallback_setting else "test",
        "start": [round(float(v), 4) for v in res.starts[0]],
        "dvt": round(float(s["dvt"]), 2),
        "dvt_by_cause": {
            k: round(100.0 * float(v.sum()) / steps, 2) for k, v in car.escape_causes.items()
        },
        "stalls": int(car.stalls.sum()),
        "never_seen": round(float(s["never_seen"]), 4),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
