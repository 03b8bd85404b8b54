"""The finer search of a stalled car on training street site 4's lock.

The car askew at the two-way end of a 2.5 m street one passable cell wide (the pose and
route of ``tests/test_patrol_unstuck.py``'s lock, from the fallback page): the ordinary
manoeuvre search and the finer one (:data:`sonarmap.patrol.robots.UNSTALL_SEARCH`) are
run from it once each, a lone car at the default 3.5 m turning radius on the 1 m disc's
passable cells. Printed: one JSON line (whether each found a manoeuvre, its arcs, the
CPU seconds of the finer search after a first call that compiles).

Run with ``python -m benchmarks.patrol_unstall_lock``; one process, one core
(``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import json
import math
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from sonarmap.patrol.manoeuvre import plan_manoeuvre, route_goals
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.robots import UNSTALL_SEARCH

#: The lock's pose (x, y metres, heading radians) and its route (the tests' LOCK, ROUTE).
LOCK = (27.26991489503502, 44.022203400780704, math.radians(56.35908116844356))
ROUTE = np.array(
    [(27.25, 44.75), (27.25, 45.25), (27.25, 45.75), (27.25, 46.25), (27.75, 46.25)]
    + [(x, 46.75) for x in np.arange(28.25, 38.0, 0.5)]
)


def main() -> None:
    """Search from the lock with both searches and print what they found."""
    t = street_territory(4)
    passable = t.passable(1.0)
    goals = route_goals(ROUTE)

    def fine() -> object:
        return plan_manoeuvre(
            LOCK,
            goals,
            passable,
            t.grid,
            3.5,
            headings=UNSTALL_SEARCH.headings,
            bin_size=UNSTALL_SEARCH.bin_size,
            budget=UNSTALL_SEARCH.budget,
        )

    fine()  # compiles
    cpu = time.process_time()
    found = fine()
    cpu = time.process_time() - cpu
    ordinary = plan_manoeuvre(LOCK, goals, passable, t.grid, 3.5)
    arcs = getattr(found, "arcs", None)
    print(
        json.dumps(
            {
                "ordinary_found": ordinary is not None and bool(ordinary.arcs),
                "fine_found": bool(arcs),
                "fine_arcs": len(arcs) if arcs else 0,
                "fine_cpu_s": round(cpu, 3),
            }
        )
    )


if __name__ == "__main__":
    main()
