"""Why a car team's mean MTB does or does not fall with its size, on one street site.

One run of :mod:`benchmarks.patrol_cars`'s command-line setting (the library's car
defaults, :func:`benchmarks.patrol_fallback.fallback_config`; ``--one-way off`` drives
every street both ways also for teams; ``--orient short`` orients the teams' one-way
streets for shorter detours, :attr:`~sonarmap.patrol.PatrolConfig.one_way_orient`;
``--leftover M`` as the benchmark's) per team size. Sampled every 10 s of the run:

- ``all_seen_s``: when the last place of the site was first seen (None: never);
- ``mean_mtb``: the benchmark's mean MTB (after a fifth of the run), s;
- ``mtb_late``: the mean MTB over the run's second half, s (places first seen late
  keep the first figure high, not this one);
- ``worst_in_stub``: the share of the samples after a fifth of the run whose worst
  place (the longest unseen) lies in a dead-end stub
  (:func:`sonarmap.patrol.stubs.stub_places`), against ``stub_share``, the stubs'
  share of the places;
- ``gap_stub`` / ``gap_other``: the mean, over the places in stubs and the others, of
  each place's longest time unseen after a fifth of the run (never-seen places count
  from that time), s;
- ``unreached_share``: the share of the places no wave reaches (more than a step from
  every cell a car's centre may be on; ``PatrolConfig.leftover``'s places), %;
- ``never_seen_closest_m``: per group of places never seen in the run (8-connected),
  the closest any car's point came to a cell centre of it, metres, sampled every step.

Run with ``python -m benchmarks.patrol_cars_mtb --sites 3 --cars 1 3 5 --duration 3600``;
one process, one core (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import json
import os
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.spatial import cKDTree

from benchmarks.patrol import OneLineParser, non_negative
from benchmarks.patrol_cars import car_config
from benchmarks.patrol_fallback import fallback_config
from sonarmap.patrol import PatrolResult, run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.oneway import ORIENTS, one_way
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Team
from sonarmap.patrol.stubs import stub_places

#: The setting's knobs taken over from :func:`fallback_config`.
KNOBS = (
    "forward_wave",
    "forward_stale",
    "turn_penalty",
    "turn_time",
    "out_of_sight",
    "round_block",
)
#: Seconds between samples.
EVERY_S = 10.0


def run_figures(result: PatrolResult, duration: float, all_seen: float | None) -> dict[str, Any]:
    """The run's figures every row of these benchmarks starts with (the module's notes):
    DVT %, never-seen %, when every place was first seen (s, None: never), mean MTB and
    the mean MTB over the run's second half (s)."""
    s = result.summary()
    late = result.t > duration / 2
    return {
        "dvt": round(float(s["dvt"]), 2),
        "never_seen": round(100 * float(s["never_seen"]), 3),
        "all_seen_s": all_seen,
        "mean_mtb": round(float(s["mean_mtb"]), 1),
        "mtb_late": round(float(result.mtb[late].mean()), 1),
    }


def watch_run(
    site: int,
    cars: int,
    duration: float,
    oneway: bool,
    leftover: float = 0.0,
    orient: str = "dfs",
) -> dict[str, Any]:
    """One run's MTB record (see the module's notes); ``orient``: the one-way streets'
    :attr:`~sonarmap.patrol.PatrolConfig.one_way_orient`."""
    base = fallback_config(cars, duration)
    # Built anew, not replaced: the configuration settles its car defaults once.
    cfg = car_config(
        "track",
        cars,
        "obstacles",
        duration,
        **{k: getattr(base, k) for k in KNOBS},
        one_way=oneway and cars > 1,
        leftover=leftover,
        one_way_orient=orient if oneway and cars > 1 else "dfs",
    )
    t = street_territory(site)
    w = reach(t, cfg.radius, mode=cfg.reach, vision=cfg.vision)
    ow = one_way(w.passable, t.clearance, t.grid.resolution, cfg.turn_radius)
    in_stub = stub_places(w.passable, w.watched, ow)
    warm = duration / 5
    rec: dict[str, Any] = {"all_seen": None, "worst": [], "gap": None}
    points: list[npt.NDArray[np.float64]] = []

    def on_step(now: float, team: Team, fog: Fog) -> None:
        points.append(np.column_stack([team.x, team.y]).astype(np.float64))
        if round(now / cfg.dt) % round(EVERY_S / cfg.dt):
            return
        if rec["all_seen"] is None and not fog.never_seen().any():
            rec["all_seen"] = now
        if now <= warm:
            return
        tb = fog.tb
        # Never-seen places count from the warm-up's end, as if seen then.
        tb = np.minimum(tb, now - warm + np.where(fog.never_seen(), 0.0, np.inf))
        tb = np.where(fog.watched, tb, -1.0)
        worst = np.unravel_index(int(np.argmax(tb)), tb.shape)
        rec["worst"].append(bool(in_stub[worst]))
        rec["gap"] = tb if rec["gap"] is None else np.maximum(rec["gap"], tb)

    result = run_patrol(t, cfg, robots=cars, seed=0, on_step=on_step)
    s = result.summary()
    gap = rec["gap"]
    watched = w.watched & (gap >= 0)
    other = watched & ~in_stub
    stubs = watched & in_stub
    unreached = w.watched & ~ndimage.binary_dilation(w.passable, structure=np.ones((3, 3)))
    closest = []
    if result.never_seen is not None and result.never_seen.any():
        groups, n_groups = ndimage.label(result.never_seen, structure=np.ones((3, 3)))
        tree = cKDTree(np.concatenate(points))
        for label in range(1, n_groups + 1):
            gx, gy = t.grid.cell_centres(*np.nonzero(groups == label))
            closest.append(round(float(tree.query(np.column_stack([gx, gy]))[0].min()), 2))
    return {
        "site": site,
        "cars": cars,
        "one_way": oneway and cars > 1,
        # None where the run drives no one-way street (a lone car, --one-way off).
        "one_way_orient": orient if oneway and cars > 1 else None,
        "leftover": leftover,
        "duration": duration,
        **run_figures(result, duration, rec["all_seen"]),
        "mean_idleness": round(float(s["mean_idleness"]), 1),
        "stub_share": round(100 * float(in_stub.sum() / max(1, w.watched.sum())), 1),
        "worst_in_stub": round(100 * float(np.mean(rec["worst"])), 1),
        "gap_stub": round(float(gap[stubs].mean()), 1) if stubs.any() else None,
        "gap_other": round(float(gap[other].mean()), 1),
        "unreached_share": round(100 * float(unreached.sum() / max(1, w.watched.sum())), 1),
        "never_seen_closest_m": closest,
        "wall_seconds": round(float(s["wall_seconds"]), 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="python -m benchmarks.patrol_cars_mtb", description=__doc__)
    ap.add_argument("--sites", type=int, nargs="+", default=[3])
    ap.add_argument("--cars", type=int, nargs="+", default=[1, 3, 5])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--one-way", choices=["teams", "off"], default="teams")
    ap.add_argument("--leftover", type=non_negative, default=0.0)
    ap.add_argument("--orient", choices=list(ORIENTS), default="dfs")
    a = ap.parse_args(argv)
    for site in a.sites:
        for cars in a.cars:
            row = watch_run(site, cars, a.duration, a.one_way == "teams", a.leftover, a.orient)
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
