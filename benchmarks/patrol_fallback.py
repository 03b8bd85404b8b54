"""Where and how tracking cars fall back on the thesis's escape (``fallback``: no manoeuvre found).

Setting: one run of ``benchmarks.patrol_cars``'s cars at its command line's defaults (the
library's :data:`sonarmap.patrol.simulation.CAR_DEFAULTS`, one-way streets for more
than one car, artificial obstacles for teams, refinement, seed 0) on a street site.
Every step a car spends in the fallback (its ``escape_causes["fallback"]`` count grows)
is recorded with the car, its position and heading, the street width at its cell (twice
the territory's clearance there, metres), the cell's class
(:func:`benchmarks.patrol_cars_oneway.cell_class`), whether the car moved on that step,
whether the collision rule cancelled its move, whether it is resting after a failed
manoeuvre search (``rest`` > 0), the distance to the nearest other car, and the angle
between its heading and its route's direction 1-3 m on.

Printed: one JSON line: the fallback share of the team's time (as the benchmark's
``dvt_by_cause``), the episodes (runs of consecutive fallback steps of one car: count,
longest, the share of fallback time in episodes of at least 60 s), the fallback time
per car, per cell class and per spot (2 m cells, the five largest), the share of fallback
steps on which the car did not move, was held by the collision rule, had another car
within 6 m; with ``--png F`` a map of the site with the fallback steps marked (colour:
car).

Run with ``python -m benchmarks.patrol_fallback --site 1027 --cars 3 --duration 3600
[--png F] [--json F]``, or ``--starts-only SITE [SITE ...] [--plus-x]`` for no run but,
per site and team of 1, 3 and 5 cars, the starts from which no step's arc is clear
(:func:`boxed_starts`); one process, one core (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from benchmarks.patrol_cars import car_config
from benchmarks.patrol_cars_oneway import cell_class
from sonarmap.patrol import run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.oneway import OneWay, one_way
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Car, Team
from sonarmap.patrol.simulation import CAR_DEFAULTS, PatrolConfig, car_starts
from sonarmap.patrol.starts import spread_starts
from sonarmap.patrol.territory import Territory

#: Seconds a step lasts in the simulation (the simulation's 0.5 s step).
STEP = 0.5


def route_angle(team: Car, i: int) -> float:
    """Degrees between car i's heading and its route's direction 1-3 m on; NaN without
    a route that long."""
    route = team.routes[i]
    if route is None or len(route) < 2:
        return math.nan
    x, y = float(team.x[i]), float(team.y[i])
    d = np.hypot(route[:, 0] - x, route[:, 1] - y)
    k = int(np.argmin(d))
    tail = route[k:]
    if len(tail) < 2:
        return math.nan
    dx, dy = float(tail[-1, 0] - tail[0, 0]), float(tail[-1, 1] - tail[0, 1])
    step = np.hypot(np.diff(tail[:, 0]), np.diff(tail[:, 1]))
    along = np.concatenate([[0.0], np.cumsum(step)])
    a = int(np.searchsorted(along, 1.0))
    b = int(np.searchsorted(along, 3.0))
    if b >= len(tail) or a >= b:
        if math.hypot(dx, dy) < 1.0:
            return math.nan
    else:
        dx, dy = float(tail[b, 0] - tail[a, 0]), float(tail[b, 1] - tail[a, 1])
    h = math.atan2(dy, dx) - float(team.heading[i])
    return abs(math.degrees((h + math.pi) % (2 * math.pi) - math.pi))


def fallback_config(cars: int, duration: float) -> PatrolConfig:
    """The runs' setting (the module's notes) for ``cars`` cars and ``duration`` s."""
    return car_config(
        "track",
        cars,
        "obstacles",
        duration,
        forward_wave=bool(CAR_DEFAULTS["forward_wave"]),
        forward_stale=float(CAR_DEFAULTS["forward_stale"]),
        turn_penalty=float(CAR_DEFAULTS["turn_penalty"]),
        turn_time=float(CAR_DEFAULTS["turn_time"]),
        out_of_sight=bool(CAR_DEFAULTS["out_of_sight"]),
        round_block=float(CAR_DEFAULTS["round_block"]),
        one_way=cars > 1,
    )


def fallback_site(
    site: int, cars: int, duration: float
) -> tuple[PatrolConfig, Territory, npt.NDArray[np.bool_], OneWay]:
    """The runs' setting on street site ``site``: the config, the territory, the cells a
    car's centre may take and the streets' one-way analysis (whether or not the config
    uses it)."""
    config = fallback_config(cars, duration)
    t = street_territory(site)
    passable = reach(t, config.radius, mode=config.reach, vision=config.vision).passable
    ow = one_way(passable, t.clearance, t.grid.resolution, config.turn_radius)
    return config, t, passable, ow


def watch_run(site: int, cars: int, duration: float) -> tuple[dict[str, Any], list[Any], Any]:
    """One run's fallback record (see the module's notes): the summary, the steps and
    the territory's passable cells with the grid."""
    config, t, passable, ow = fallback_site(site, cars, duration)
    before = np.zeros(cars, dtype=np.int64)
    last_xy: list[np.ndarray[Any, Any]] = []
    steps: list[dict[str, Any]] = []
    clock = [0]

    def keep(_t: float, team: Team, _fog: Fog) -> None:
        assert isinstance(team, Car)
        now = team.escape_causes["fallback"]
        xy = np.column_stack([team.x, team.y])
        r, c = t.grid.world_to_cell(team.x, team.y)
        for i in np.flatnonzero(now > before).tolist():
            others = np.delete(xy, i, axis=0)
            near = float(np.hypot(*(others - xy[i]).T).min()) if len(others) else math.inf
            ri, ci = int(r[i]), int(c[i])
            e = int(ow.street[ri, ci])
            steps.append(
                {
                    "step": clock[0],
                    "car": i,
                    "x": float(team.x[i]),
                    "y": float(team.y[i]),
                    "heading_deg": math.degrees(float(team.heading[i])),
                    "width_m": 2.0 * float(t.clearance[ri, ci]),
                    "street_width_m": float(ow.widths[e]) if e >= 0 else math.nan,
                    "one_way": bool(ow.one_way[e]) if e >= 0 else False,
                    "cell": cell_class(ow, ri, ci),
                    "moved": bool(last_xy and np.hypot(*(xy[i] - last_xy[0][i])) > 1e-9),
                    "blocked": bool(team.blocked[i]),
                    "resting": bool(team.rest[i] > 0),
                    "nearest_car_m": near,
                    "route_angle_deg": route_angle(team, i),
                }
            )
        before[:] = now
        last_xy[:] = [xy.copy()]
        clock[0] += 1

    result = run_patrol(t, config, robots=cars, seed=0, on_step=keep)
    total = len(result.t) * cars
    summary = summarise(steps, total)
    summary.update(
        {
            "site": site,
            "cars": cars,
            "duration": duration,
            "dvt": round(float(result.summary()["dvt"]), 2),
        }
    )
    return summary, steps, (passable, t.grid)


def boxed_starts(site: int, cars: int, plus_x: bool = False) -> list[dict[str, Any]]:
    """The starts of a run of ``cars`` cars on ``site`` (seed 0, as
    :func:`sonarmap.patrol.run_patrol` spreads them and faces them,
    :func:`sonarmap.patrol.simulation.car_starts`; with ``plus_x`` as spread before
    cars had start headings: every cell, facing +x) from which no arc of one step's
    length (the speed rule's speed at the start's clearance, for the 0.5 s step), of 9
    curvatures from -1 to +1 over the turning radius, forward or in reverse, stays on
    the passable cells: a car there can never move."""
    config = car_config("track", cars, "obstacles", 60.0, one_way=cars > 1)
    t = street_territory(site)
    where = reach(t, config.radius, mode=config.reach, vision=config.vision)
    cars_at = car_starts(t, where.passable, config)
    if plus_x:
        starts = spread_starts(cars, t, where.passable, config.min_separation, 0)
    else:
        starts = cars_at.spread(cars, config.min_separation, 0)
    out = []
    for i, (x, y, h) in enumerate(starts.tolist()):
        # The library's own test (CarStarts.moves: the config's speed rule and step).
        if not cars_at.moves(x, y, h):
            out.append(
                {"car": i, "x": round(x, 2), "y": round(y, 2), "heading_deg": math.degrees(h)}
            )
    return out


def summarise(steps: list[dict[str, Any]], total: int) -> dict[str, Any]:
    """The figures of the module's notes from the recorded fallback steps; ``total``:
    car-steps in the run."""
    n = len(steps)
    out: dict[str, Any] = {"fallback_pct": round(100.0 * n / total, 2), "fallback_steps": n}
    if not n:
        return out
    # Episodes: consecutive steps of one car.
    episodes: list[list[dict[str, Any]]] = []
    last: dict[int, dict[str, Any]] = {}
    open_: dict[int, list[dict[str, Any]]] = {}
    for s in steps:
        car = s["car"]
        if car in last and last[car]["step"] == s["step"] - 1:
            open_[car].append(s)
        else:
            open_[car] = [s]
            episodes.append(open_[car])
        last[car] = s
    lengths = np.array([len(e) for e in episodes]) * STEP
    long_ = lengths >= 60.0
    out["episodes"] = len(episodes)
    out["episode_s_median"] = float(np.median(lengths))
    out["episode_s_max"] = float(lengths.max())
    out["share_in_episodes_ge_60s_pct"] = round(100.0 * lengths[long_].sum() / lengths.sum(), 1)
    out["longest_episodes"] = [
        {
            "car": e[0]["car"],
            "from_s": e[0]["step"] * STEP,
            "seconds": len(e) * STEP,
            "x": round(e[0]["x"], 1),
            "y": round(e[0]["y"], 1),
            "moved_m": round(math.hypot(e[-1]["x"] - e[0]["x"], e[-1]["y"] - e[0]["y"]), 2),
            "width_m": round(e[0]["width_m"], 2),
            "cell": e[0]["cell"],
        }
        for e in sorted(episodes, key=len, reverse=True)[:5]
    ]
    cars: dict[str, int] = {}
    cells: dict[str, int] = {}
    spots: dict[str, int] = {}
    for s in steps:
        cars[str(s["car"])] = cars.get(str(s["car"]), 0) + 1
        cells[s["cell"]] = cells.get(s["cell"], 0) + 1
        key = f"{2 * math.floor(s['x'] / 2):.0f},{2 * math.floor(s['y'] / 2):.0f}"
        spots[key] = spots.get(key, 0) + 1
    out["by_car_pct_of_fallback"] = {k: round(100.0 * v / n, 1) for k, v in sorted(cars.items())}
    out["by_cell_pct_of_fallback"] = {k: round(100.0 * v / n, 1) for k, v in sorted(cells.items())}
    out["top_spots_2m_pct_of_fallback"] = {
        k: round(100.0 * v / n, 1) for k, v in sorted(spots.items(), key=lambda kv: -kv[1])[:5]
    }

    def share(key: str) -> float:
        return round(100.0 * sum(bool(s[key]) for s in steps) / n, 1)

    out["not_moved_pct"] = round(100.0 - share("moved"), 1)
    out["blocked_pct"] = share("blocked")
    out["resting_pct"] = share("resting")
    out["car_within_6m_pct"] = round(100.0 * sum(s["nearest_car_m"] < 6.0 for s in steps) / n, 1)
    widths = np.array([s["width_m"] for s in steps])
    out["width_m_median"] = round(float(np.median(widths)), 2)
    sw = np.array([s["street_width_m"] for s in steps])
    sw = sw[np.isfinite(sw)]
    out["street_width_m_median"] = round(float(np.median(sw)), 2) if len(sw) else None
    out["one_way_pct"] = share("one_way")
    ang = np.array([s["route_angle_deg"] for s in steps])
    ang = ang[np.isfinite(ang)]
    out["route_angle_deg_median"] = round(float(np.median(ang)), 1) if len(ang) else None
    out["route_behind_pct"] = (
        round(100.0 * float((ang > math.degrees(1.75)).mean()), 1) if len(ang) else None
    )
    return out


def draw(path: Path, passable: Any, grid: Any, steps: list[dict[str, Any]], title: str) -> None:
    """The site's passable cells with the fallback steps marked (colour: car)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 8))
    rows, cols = passable.shape
    ox, oy = grid.origin
    res = grid.resolution
    # Row 0 is the map's top (y largest), as the grid stores it.
    ax.imshow(
        passable,
        cmap="Greys",
        vmin=-1,
        vmax=1.5,
        origin="upper",
        interpolation="nearest",
        extent=(ox, ox + cols * res, oy, oy + rows * res),
    )
    if steps:
        xs = np.array([s["x"] for s in steps])
        ys = np.array([s["y"] for s in steps])
        car = np.array([s["car"] for s in steps])
        sc = ax.scatter(xs, ys, c=car, s=6, cmap="tab10", vmin=0, vmax=9, alpha=0.5)
        ax.legend(*sc.legend_elements(), title="car", loc="upper right")
    ax.set_title(title)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.patrol_fallback", description=__doc__)
    ap.add_argument("--site", type=int, default=1027)
    ap.add_argument("--cars", type=int, default=3)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--png", type=Path)
    ap.add_argument("--json", type=Path, help="also write every fallback step here")
    ap.add_argument(
        "--starts-only",
        type=int,
        nargs="+",
        metavar="SITE",
        help="no run: print, per site of these and team size of 1, 3, 5, the boxed starts",
    )
    ap.add_argument(
        "--plus-x",
        action="store_true",
        help="with --starts-only: the starts as spread before cars had start headings",
    )
    a = ap.parse_args(argv)
    if a.starts_only:
        for site in a.starts_only:
            for cars in (1, 3, 5):
                boxed = boxed_starts(site, cars, a.plus_x)
                print(json.dumps({"site": site, "cars": cars, "boxed": boxed}))
        return 0
    summary, steps, (passable, grid) = watch_run(a.site, a.cars, a.duration)
    print(json.dumps(summary))
    if a.json:
        a.json.write_text(json.dumps(steps) + "\n")
    if a.png:
        draw(
            a.png,
            passable,
            grid,
            steps,
            f"site {a.site}, {a.cars} cars, {a.duration:g} s: fallback steps "
            f"({summary['fallback_pct']} % of the team's time)",
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
