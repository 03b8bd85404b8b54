"""Junctions beyond dead-end stubs: how many the street graph makes, per street site.

Where a dead end bends or branches, or the thinning forks at its far end, the street
graph (:func:`sonarmap.patrol.oneway.one_way`) makes a junction there; its cells belong
to no street. :attr:`sonarmap.patrol.oneway.OneWay.stub_ends` marks those beyond a stub
whose streets are all stubs, and :func:`sonarmap.patrol.stubs.stub_cells` counts them
in the stub. Printed per site: the stubs, the junctions beyond them (8-connected
groups of ``stub_ends`` cells) with their sizes in cells, the watched places there
(those whose nearest passable cell is one) and how many of those have a stand point,
and all the watched places in stubs and how many have a stand point; the last two also
as they were with those junctions left out of the stubs (``stub_ends`` all False), with
how many of those stand points lay on such a junction, inside the dead end.

The cars are ``benchmarks.patrol_cars``'s (the simulation's own passable cells and
watched places, turning radius 3.5 m, vision 10 m), built by its ``car_config``
without the turn-time rule (``turn_time`` 0, that function's default, which predates
the rule and keeps this page's figures as measured; only ``patrol_cars``'s command line
sets 30 s).

Run with ``python -m benchmarks.patrol_stub_ends --sites 0 1 2 3 4 5 6 7 8 9 10 11``;
one process, one core (``NUMBA_NUM_THREADS=1``); prints one JSON line a site.
"""

from __future__ import annotations

import argparse
import dataclasses
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
    # As it was before stub_ends: the same street system with none marked.
    old = dataclasses.replace(ow, stub_ends=np.zeros_like(ow.stub_ends))
    stands_old = stand_points(
        passable, where.watched, old, t.grid.resolution, config.vision - SIGHT_MARGIN
    )
    has_old = stands_old >= 0
    return {
        "site": site,
        "stubs": int(ow.stubs.sum()),
        "junctions_beyond_stubs": int(n),
        "their_cells": sorted(np.bincount(groups.ravel())[1:].tolist()),
        "their_places": int(at_ends.sum()),
        "their_places_with_stand_point": int((at_ends & (stands >= 0)).sum()),
        "stub_places": int(stub_places(passable, where.watched, ow).sum()),
        "stub_places_with_stand_point": int((stands >= 0).sum()),
        "without_stub_ends": {
            "stub_places": int(stub_places(passable, where.watched, old).sum()),
            "stub_places_with_stand_point": int(has_old.sum()),
            "stand_point_on_a_junction_beyond_a_stub": int(
                ow.stub_ends.ravel()[stands_old[has_old]].sum()
            ),
        },
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
