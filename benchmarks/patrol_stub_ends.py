"""Junctions beyond dead-end stubs: how many the street graph makes, per street site.

Where a dead end bends or branches, or the thinning forks at its far end, the street
graph (:func:`sonarmap.patrol.oneway.one_way`) makes a junction there; its cells belong
to no street. :attr:`sonarmap.patrol.oneway.OneWay.stub_ends` marks those beyond a stub
whose streets are all stubs, and :func:`sonarmap.patrol.stubs.stub_cells` counts them
in the stub. Printed per site: the stubs, the junctions beyond them (8-connected
groups of ``stub_ends`` cells) with their sizes in cells, the watched places there
(those whose nearest passable cell is one) and how many of those have a stand point,
and all the watched places in stubs.

The cars are ``benchmarks.patrol_cars``'s (the simulation's own passable cells and
watched places, turning radius 3.5 m, vision 10 m).

Run with ``python -m benchmarks.patrol_stub_ends --sites 0 1 2 3 4 5 6 7 8 9 10 11``;
one process, one core (``NUMBA_NUM_THREADS=1``); prints one JSON line a site.
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from scipy import ndimage

from benchmarks.patrol_cars import car_config
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.oneway import one_way
from sonarmap.patrol.reach import reach
from sonarmap.patrol.simulation import SIGHT_MARGIN
from sonarmap.patrol.stubs import stand_points, stub_places


def count(site: int) -> dict[str, object]:
    """The counts of one street site (see the module's notes)."""
    config = car_config("track", 3, "obstacles", 1200.0, one_way=True, stub_sight=True)
    t = street_territory(site)
    where = reach(t, config.radius, mode=config.reach, vision=config.vision)
    passable = where.passable
    ow = one_way(passable, t.clearance, t.grid.resolution, config.turn_radius)
    groups, n = ndimage.label(ow.stub_ends, structure=np.ones((3, 3), dtype=bool))
    _, (nr, nc) = ndimage.distance_transform_edt(~passable, return_indices=True)
    at_ends = where.watched & ow.stub_ends[nr, nc]
    stands = stand_points(
        passable, where.watched, ow, t.grid.resolution, config.vision - SIGHT_MARGIN
    )
    return {
        "site": site,
        "stubs": int(ow.stubs.sum()),
        "junctions_beyond_stubs": int(n),
        "their_cells": sorted(np.bincount(groups.ravel())[1:].tolist()),
        "their_places": int(at_ends.sum()),
        "their_places_with_stand_point": int((at_ends & (stands >= 0)).sum()),
        "stub_places": int(stub_places(passable, where.watched, ow).sum()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.patrol_stub_ends", description=__doc__)
    ap.add_argument("--sites", type=int, nargs="+", default=list(range(12)))
    a = ap.parse_args(argv)
    for site in a.sites:
        print(json.dumps(count(site)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
