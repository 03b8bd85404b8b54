"""Why a car team on one-way streets can be slower than one car: distances to the stalest place.

One run of :mod:`benchmarks.patrol_cars_mtb`'s setting (the library's car defaults;
``--one-way teams`` drives the streets narrower than the turning circle one way for
teams only, as the library does; ``all`` also for a lone car; ``off`` never;
``--leftover M`` as the benchmark's; ``--orient short`` orients the one-way streets for
shorter detours, :attr:`~sonarmap.patrol.PatrolConfig.one_way_orient`) per team size.
The one-way street system is :func:`sonarmap.patrol.oneway.one_way` on the run's
passable cells; "one-way distance"
is the shortest path along the wave's steps that system allows, "two-way distance" the
same path with every step allowed (the car's heading and turning are left out of both).

Printed per run (one JSON line), besides ``benchmarks.patrol_cars_mtb``'s DVT,
never-seen share, ``all_seen_s``, ``mean_mtb`` and ``mtb_late``:

- ``detour``: the site's one-way street network against two-way streets, over the
  pairs from ``SOURCES`` passable cells drawn with seed 0 to every passable cell:
  ``summed``, the summed one-way distances over the summed two-way ones (the headline:
  close pairs behind each other on a one-way street do not dominate it);
  ``mean_ratio``, the mean of the pairs' one-way to two-way ratios (such close pairs
  blow it up); ``median``, their median; ``twice_share``, the share of pairs at least
  twice as far one-way, %;
- every ``EVERY_S`` seconds after a fifth of the run, the worst place (the watched
  place longest unseen; never-seen places count from that time) and the passable cells
  within the cars' sight of it (``vision - SIGHT_MARGIN``, walls left out); from them:
  ``worst_age``, the worst place's mean time unseen, s; ``near_oneway_m`` /
  ``near_twoway_m``, the mean over the samples of the nearest car's one-way / two-way
  distance to a cell that sees it, m; ``near_ratio``, the mean of their per-sample
  ratio; ``behind_share``, the samples whose nearest car is at least twice as far
  one-way as two-way, %; both leave out the samples where the nearest car already
  sees the place (two-way distance 0) or cannot reach it one-way;
  ``worst_on_one_way``, the samples whose worst place's nearest
  passable cell is on the one-way part of a one-way street, %; ``worst_streak_s``, the
  longest chain of samples whose worst place is within sight of the previous sample's
  (:func:`streak`: the place may drift along the chain, and samples whose worst place
  has no passable cell in sight are left out, joining the samples either side; each
  link counts ``EVERY_S``), s; ``worst_stay_s``, the longest run of samples whose worst
  place is within sight of the run's first one, s; ``streak_closest_m``, within the
  chain, the sample whose nearest car was closest to
  it two-way: that distance and the nearest car's one-way distance then, m;
  ``pass_by_share``, the samples where a car is within ``PASS_NEAR_M`` of it two-way
  but every car at least ``PASS_FAR_M`` one-way, %;
- ``follow_share``: the samples where two cars are within ``FOLLOW_M`` of each other
  heading within 45 degrees of each other (one behind the other), %;
  ``pair_gap_m``: the mean over samples of the closest two cars' distance, m;
- ``driven_m``: the mean over the cars of the distance a car moved, summed over the
  steps (the straight line between its positions at consecutive steps), m.

With ``--network``, only the one-way system's figures per site, without a run:
streets, one-way streets, the share of the passable cells on them, the turning circle's
diameter (``2 * turn_radius``, the width below which a street is one-way), the streets'
smallest, median and largest width (m) and ``detour``.

With ``--orient-report``, per site the 'short' orientation's search against the
depth-first one, without a run (one JSON line each): the one-way streets it could flip,
how many it flipped, and its own model's summed detour (the midpoint graph's, weighted
by the streets' lengths) before and after (:class:`~sonarmap.patrol.oneway.Search`);
and the CPU seconds of ``REPEATS`` whole builds of the system with each orientation,
alternated after one untimed build of each (``build_s``, each build's; ``extra_s``, the
median 'short' build less the median 'dfs' one: the search's cost). ``--table4`` adds
Table 4's territory (:func:`benchmarks.patrol.table4` at a 0.1 m cell, the first 5
starts' reach) and ``--city N ...`` made-up grids of N x N square 12 m blocks between
3 m streets (0.5 m cells, all one-way with the 3.5 m turning radius given), where the
search's cost grows with the number of one-way streets.

Run with ``python -m benchmarks.patrol_oneway_mtb --sites 0 --cars 3 --duration 3600
--leftover 2`` (or ``--sites 0 1 2 --network``, or ``--sites 0 5 --orient-report
--table4 --city 4 6``); one process, one core (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import json
import math
import os
import time
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from benchmarks.patrol import OneLineParser, non_negative, table4
from benchmarks.patrol_cars import car_config
from benchmarks.patrol_cars_mtb import EVERY_S, KNOBS, run_figures
from benchmarks.patrol_fallback import fallback_site
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.patrol import run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.graph import cell_graph
from sonarmap.patrol.oneway import ORIENTS, OneWay, one_way
from sonarmap.patrol.paths import STEPS
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Team
from sonarmap.patrol.simulation import SIGHT_MARGIN
from sonarmap.patrol.territory import Territory

#: Passable cells drawn for the network's detour.
SOURCES = 40
#: A car this close to a cell that sees the worst place two-way (metres), but at least
#: ``PASS_FAR_M`` from one one-way, passes it by.
PASS_NEAR_M = 20.0
PASS_FAR_M = 60.0
#: Two cars this close (metres), heading the same way, count as one following the other.
FOLLOW_M = 20.0
#: Builds of the one-way system per orientation timed by ``--orient-report``.
REPEATS = 3
#: The made-up city grids of ``--orient-report --city``: cell, street and block side,
#: the cars' turning radius (metres; streets narrower than twice it are one-way).
CITY_CELL, CITY_STREET, CITY_BLOCK, CITY_TURN = 0.5, 3.0, 12.0, 3.5

F64 = npt.NDArray[np.float64]


def allowed_graph(
    graph: csr_matrix, index: npt.NDArray[np.int64], steps: npt.NDArray[np.uint8]
) -> csr_matrix:
    """The edges of ``graph`` (:func:`cell_graph`, nodes ``index``) whose step its tail
    cell's ``steps`` allows (bit j for :data:`STEPS` [j]).

    Relies on :func:`cell_graph` numbering the cells in ``np.argwhere`` order (row-major,
    ``index[mask] = arange(n)``): node k is the k-th row of ``np.argwhere(index >= 0)``.
    """
    coo = graph.tocoo()
    rc = np.argwhere(index >= 0)
    dr = rc[coo.col, 0] - rc[coo.row, 0]
    dc = rc[coo.col, 1] - rc[coo.row, 1]
    code = np.full(9, -1, dtype=np.int64)
    for j, (a, b) in enumerate(STEPS.tolist()):
        code[(a + 1) * 3 + b + 1] = j
    j = code[(dr + 1) * 3 + dc + 1]
    bits = steps[rc[coo.row, 0], rc[coo.row, 1]].astype(np.int64)
    keep = ((bits >> j) & 1) == 1
    out = csr_matrix((coo.data[keep], (coo.row[keep], coo.col[keep])), shape=graph.shape)
    return out


def detour(two: csr_matrix, one: csr_matrix, n: int) -> dict[str, float]:
    """The one-way network's detour (see the module's notes): summed one-way over summed
    two-way distance, mean and median of the pairs' ratios, share of pairs at least
    twice as far one-way, %. Pairs one cell apart or unreachable either way are left out."""
    src = np.random.default_rng(0).choice(n, size=min(SOURCES, n), replace=False)
    d2 = dijkstra(two, directed=False, indices=src)
    d1 = dijkstra(one, directed=True, indices=src)
    ok = (d2 > 0) & np.isfinite(d2) & np.isfinite(d1)
    ratio = d1[ok] / d2[ok]
    return {
        "summed": round(float(d1[ok].sum() / d2[ok].sum()), 3),
        "mean_ratio": round(float(ratio.mean()), 3),
        "median": round(float(np.median(ratio)), 3),
        "twice_share": round(float(100.0 * np.mean(ratio >= 2.0)), 1),
    }


def one_way_cell_share(ow: OneWay, passable: npt.NDArray[np.bool_]) -> float:
    """The share of the ``passable`` cells on one-way streets (their two-way ends
    included), %."""
    return round(100.0 * float(np.isfinite(ow.along).sum()) / max(1, int(passable.sum())), 1)


def streak(
    xy: list[tuple[float, float]], near_m: float, every_s: float, anchored: bool = False
) -> tuple[float, int, int]:
    """The longest chain of consecutive samples' worst places ``xy`` each within
    ``near_m`` of the previous one's (``anchored``: of the chain's first), in seconds
    (``every_s`` per link), with its first and last sample's index; ``(0.0, 0, 0)``
    for fewer than two samples or no link."""
    best, first, last = 0.0, 0, 0
    start = 0
    for k in range(1, len(xy)):
        ref = xy[start] if anchored else xy[k - 1]
        if math.hypot(xy[k][0] - ref[0], xy[k][1] - ref[1]) > near_m:
            start = k
            continue
        if (k - start) * every_s > best:
            best, first, last = (k - start) * every_s, start, k
    return best, first, last


def network(site: int, cars: int, orient: str = "dfs") -> dict[str, Any]:
    """The one-way street system of training or test site ``site`` as the cars' setting
    builds it with ``orient`` (:func:`one_way`), and its detour (no run)."""
    cfg, t, passable, ow = fallback_site(site, cars, 60.0)
    if orient != "dfs":
        ow = one_way(passable, t.clearance, t.grid.resolution, cfg.turn_radius, orient=orient)
    two, index = cell_graph(passable, t.grid.resolution)
    n = int(passable.sum())
    return {
        "site": site,
        "orient": orient,
        "one_way_streets": int(ow.one_way.sum()),
        "streets": len(ow.one_way),
        "one_way_cell_share": one_way_cell_share(ow, passable),
        "turn_circle_m": round(2.0 * cfg.turn_radius, 2),
        "street_width_m": [round(float(q), 2) for q in np.percentile(ow.widths, [0, 50, 100])],
        "detour": detour(two, allowed_graph(two, index, ow.steps), n),
    }


def city(n: int) -> Territory:
    """A made-up grid of ``n`` x ``n`` square blocks (``CITY_BLOCK`` m) between
    ``CITY_STREET``-metre streets, walled round, ``CITY_CELL`` m cells."""
    side = CITY_STREET + n * (CITY_BLOCK + CITY_STREET)
    cells = int(side / CITY_CELL)
    occ = np.zeros((cells, cells), np.float32)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = 1.0
    step = round((CITY_BLOCK + CITY_STREET) / CITY_CELL)
    first, size = round(CITY_STREET / CITY_CELL), round(CITY_BLOCK / CITY_CELL)
    for i in range(n):
        for j in range(n):
            r, c = first + i * step, first + j * step
            occ[r : r + size, c : c + size] = 1.0
    g = Grid(resolution=CITY_CELL, origin=(0.0, 0.0), shape=occ.shape)
    return Territory.from_map(OccupancyMap(g, occ))


def orient_report(
    name: str,
    passable: npt.NDArray[np.bool_],
    clearance: F64,
    resolution: float,
    turn_radius: float,
) -> dict[str, Any]:
    """The 'short' search's record and the builds' CPU seconds on one map (the module's
    notes)."""
    times: dict[str, list[float]] = {o: [] for o in ORIENTS}
    short: OneWay | None = None
    # One untimed build of each first: the first build of a process pays for caches and
    # compiled code, and would always fall to whichever orientation comes first.
    for orient in ORIENTS:
        one_way(passable, clearance, resolution, turn_radius, orient=orient)
    for _ in range(REPEATS):
        for orient in ORIENTS:
            c0 = time.process_time()
            ow = one_way(passable, clearance, resolution, turn_radius, orient=orient)
            times[orient].append(time.process_time() - c0)
            if orient == "short":
                short = ow
    assert short is not None
    assert short.search is not None
    s = short.search
    return {
        "map": name,
        "streets": len(short.one_way),
        "one_way_streets": int(short.one_way.sum()),
        "search_streets": s.streets,
        "flipped": s.flipped,
        "model_before": round(s.before, 3),
        "model_after": round(s.after, 3),
        "build_s": {o: [round(v, 3) for v in times[o]] for o in ORIENTS},
        "extra_s": round(float(np.median(times["short"]) - np.median(times["dfs"])), 3),
    }


def orient_reports(sites: list[int], cars: int, with_table4: bool, grids: list[int]) -> None:
    """Print :func:`orient_report` for the street ``sites`` (the cars' setting for
    ``cars``), Table 4's territory and the city grids ``grids``."""
    for site in sites:
        cfg, t, passable, _ = fallback_site(site, cars, 60.0)
        row = orient_report(
            f"site {site}", passable, t.clearance, t.grid.resolution, cfg.turn_radius
        )
        print(json.dumps(row), flush=True)
    if with_table4:
        t, cfg, starts = table4(0.1, 300.0)
        rc = np.column_stack(t.grid.world_to_cell(starts[:, 0], starts[:, 1]))
        where = reach(t, cfg.radius, starts=rc, mode=cfg.reach, vision=cfg.vision)
        row = orient_report(
            "table4", where.passable, t.clearance, t.grid.resolution, cfg.turn_radius
        )
        print(json.dumps(row), flush=True)
    for n in grids:
        t = city(n)
        row = orient_report(f"city {n}x{n}", t.passable(1.0), t.clearance, CITY_CELL, CITY_TURN)
        print(json.dumps(row), flush=True)


def watch_run(
    site: int,
    cars: int,
    duration: float,
    oneway: str,
    leftover: float = 0.0,
    orient: str = "dfs",
) -> dict[str, Any]:
    """One run's record (see the module's notes); ``orient``: the one-way streets'
    :attr:`~sonarmap.patrol.PatrolConfig.one_way_orient`."""
    base, t, passable, ow = fallback_site(site, cars, duration)
    use = oneway == "all" or (oneway == "teams" and cars > 1)
    # Unused, the orientation is not recorded and its system not built: the distances
    # are then the depth-first system's, as the run's own would be.
    used_orient = orient if use else None
    if use and orient != "dfs":
        ow = one_way(passable, t.clearance, t.grid.resolution, base.turn_radius, orient=orient)
    cfg = car_config(
        "track",
        cars,
        "obstacles",
        duration,
        **{k: getattr(base, k) for k in KNOBS},
        one_way=use,
        leftover=leftover,
        one_way_orient=used_orient or "dfs",
    )
    two, index = cell_graph(passable, t.grid.resolution)
    one = allowed_graph(two, index, ow.steps)
    one_t = one.T.tocsr()  # distances *to* a set: from it along reversed steps
    n = int(passable.sum())
    # The passable cell nearest every cell (a car's centre may round off the mask).
    _, (near_r, near_c) = ndimage.distance_transform_edt(~passable, return_indices=True)
    pr, pc = np.nonzero(passable)
    px, py = t.grid.cell_centres(pr, pc)
    tree = cKDTree(np.column_stack([px, py]))
    sight = cfg.vision - SIGHT_MARGIN
    warm = duration / 5
    rec: dict[str, list[float]] = {
        k: [] for k in ("age", "d1", "d2", "ratio", "behind", "follow", "gap")
    }
    first: dict[str, float | None] = {"all_seen": None}
    # Per sample: the worst place (x, y), whether its nearest passable cell is on the
    # one-way part of a street, and the nearest car's one-way and two-way distance, m.
    worst: list[tuple[float, float, bool, float, float]] = []
    driven = np.zeros(cars)
    last: list[F64] = []

    def on_step(now: float, team: Team, fog: Fog) -> None:
        xy = np.column_stack([team.x, team.y]).astype(np.float64)
        if last:
            driven[:] += np.hypot(*(xy - last[0]).T)
            last[0] = xy
        else:
            last.append(xy)
        if round(now / cfg.dt) % round(EVERY_S / cfg.dt):
            return
        if first["all_seen"] is None and not fog.never_seen().any():
            first["all_seen"] = now
        if now <= warm:
            return
        tb = np.minimum(fog.tb, now - warm + np.where(fog.never_seen(), 0.0, np.inf))
        tb = np.where(fog.watched, tb, -1.0)
        wr, wc = np.unravel_index(int(np.argmax(tb)), tb.shape)
        wx, wy = t.grid.cell_centres(np.array([wr]), np.array([wc]))
        targets = tree.query_ball_point([float(wx[0]), float(wy[0])], sight)
        if not targets:
            return
        tnodes = index[pr[targets], pc[targets]]
        r, c = t.grid.world_to_cell(team.x, team.y)
        r = np.clip(r, 0, passable.shape[0] - 1)
        c = np.clip(c, 0, passable.shape[1] - 1)
        cn = index[near_r[r, c], near_c[r, c]]
        d1 = dijkstra(one_t, directed=True, indices=tnodes, min_only=True)[cn]
        d2 = dijkstra(two, directed=False, indices=tnodes, min_only=True)[cn]
        near = int(np.argmin(d2))
        on = bool(np.isfinite(ow.along[near_r[wr, wc], near_c[wr, wc]]))
        on &= not bool(ow.two_way[near_r[wr, wc], near_c[wr, wc]])
        worst.append((float(wx[0]), float(wy[0]), on, float(d1.min()), float(d2.min())))
        rec["age"].append(float(tb[wr, wc]))
        rec["d1"].append(float(d1.min()))
        rec["d2"].append(float(d2.min()))
        if d2[near] > 0 and np.isfinite(d1[near]):
            rec["ratio"].append(float(d1[near] / d2[near]))
            rec["behind"].append(float(d1[near] >= 2.0 * d2[near]))
        follow = False
        gap = math.inf
        for i in range(cars):
            for k in range(i + 1, cars):
                dd = float(np.hypot(xy[i, 0] - xy[k, 0], xy[i, 1] - xy[k, 1]))
                gap = min(gap, dd)
                dh = abs(math.remainder(float(team.heading[i] - team.heading[k]), 2 * math.pi))
                follow |= dd <= FOLLOW_M and dh <= math.pi / 4
        rec["follow"].append(float(follow))
        if cars > 1:
            rec["gap"].append(gap)

    result = run_patrol(t, cfg, robots=cars, seed=0, on_step=on_step)
    s = result.summary()

    places = [(v[0], v[1]) for v in worst]
    best, begin, end = streak(places, sight, EVERY_S)
    stay, _, _ = streak(places, sight, EVERY_S, anchored=True)
    # Within the chain, the sample whose nearest car (two-way) came closest.
    run = worst[begin : end + 1]
    close = min(run, key=lambda v: v[4]) if run else None
    passby = [v[4] <= PASS_NEAR_M and v[3] >= PASS_FAR_M for v in worst]

    def mean(k: str, scale: float = 1.0) -> float | None:
        return round(scale * float(np.mean(rec[k])), 2) if rec[k] else None

    return {
        "site": site,
        "cars": cars,
        "one_way": use,
        "one_way_orient": used_orient,
        "leftover": leftover,
        "duration": duration,
        **run_figures(result, duration, first["all_seen"]),
        "one_way_streets": int(ow.one_way.sum()),
        "streets": len(ow.one_way),
        "one_way_cell_share": one_way_cell_share(ow, passable),
        "detour": detour(two, one, n),
        "worst_age": mean("age"),
        "near_oneway_m": mean("d1"),
        "near_twoway_m": mean("d2"),
        "near_ratio": mean("ratio"),
        "behind_share": mean("behind", 100.0),
        "worst_on_one_way": (
            round(100.0 * float(np.mean([v[2] for v in worst])), 1) if worst else None
        ),
        "worst_streak_s": best,
        "worst_stay_s": stay,
        "streak_closest_m": (
            {"twoway": round(close[4], 1), "oneway": round(close[3], 1)} if close else None
        ),
        "pass_by_share": round(100.0 * float(np.mean(passby)), 1) if passby else None,
        "follow_share": mean("follow", 100.0),
        "pair_gap_m": mean("gap"),
        "driven_m": round(float(driven.mean()), 1),
        "wall_seconds": round(float(s["wall_seconds"]), 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="python -m benchmarks.patrol_oneway_mtb", description=__doc__)
    ap.add_argument("--sites", type=int, nargs="+", default=[0])
    ap.add_argument("--cars", type=int, nargs="+", default=[3])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--one-way", choices=["teams", "all", "off"], default="teams")
    ap.add_argument("--leftover", type=non_negative, default=0.0)
    ap.add_argument("--orient", choices=list(ORIENTS), default="dfs")
    ap.add_argument("--network", action="store_true")
    ap.add_argument("--orient-report", action="store_true")
    ap.add_argument("--table4", action="store_true")
    ap.add_argument("--city", type=int, nargs="*", default=[])
    a = ap.parse_args(argv)
    if min(a.sites) < 0:
        ap.error(f"--sites: a site is a seed >= 0, got {min(a.sites)}")
    if min(a.cars) < 1:
        ap.error(f"--cars: a team has at least one car, got {min(a.cars)}")
    if a.city and min(a.city) < 1:
        ap.error(f"--city: a city grid has at least 1 x 1 blocks, got {min(a.city)}")
    if a.orient_report:
        orient_reports(a.sites, max(a.cars), a.table4, a.city)
        return 0
    if a.network:
        for site in a.sites:
            print(json.dumps(network(site, max(a.cars), a.orient)), flush=True)
        return 0
    for site in a.sites:
        for cars in a.cars:
            row = watch_run(site, cars, a.duration, a.one_way, a.leftover, a.orient)
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
