"""A mission's world on real maps: landmarks, route and regions, measured and pictured
(issue 37, item 1; :mod:`sonarmap.team.survey`).

For each map, the world, the route and the regions a one-robot ``sonarmap team run``
makes by default (seed 0: :func:`~sonarmap.team.world.make_world`,
:func:`~sonarmap.team.world.patrol_route` and the mission's regions, as
:class:`~sonarmap.team.mission.RobotAgent` draws them), measured by
:func:`~sonarmap.team.survey.survey`: one JSON row and one PNG per map, and a markdown
table on stdout.

Maps: a map_server YAML path, a built-in name (``building:SEED``), or ``scanned:SEED``:
a *stand-in* for a scanned building drawing (no real one is in the shared data): a
random building (:func:`~sonarmap.floorplan.random_building`, 40 x 30 m) drawn at
0.1 m with 1-cell walls, a 1.2 m entrance in its south wall, 4 m of free "outside" all
round, as a scanner draws the paper's white margin.

Run with ``python -m benchmarks.team_world [MAP ...] [--duration 1200] [--out DIR]
[--before | --tour]``. ``--before``: the world as missions made it before issue 37,
measured the same way; ``--tour``: the route is the tour driven lap after lap. Default
maps: the shared depot, warehouse, tb3_sandbox, ``building:1`` and ``scanned:1``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from sonarmap.builtins import builtin_plan
from sonarmap.floorplan import random_building
from sonarmap.grid import Grid
from sonarmap.io.rosmap import FREE, OccupancyMap, read_map
from sonarmap.team.regions import cut_regions, mission_regions
from sonarmap.team.survey import draw_survey, survey
from sonarmap.team.world import make_world, patrol_route

SHARED = Path("/work/shared/data/maps")
DEFAULT_MAPS = (
    str(SHARED / "depot.yaml"),
    str(SHARED / "warehouse.yaml"),
    str(SHARED / "tb3_sandbox.yaml"),
    "building:1",
    "scanned:1",
)

#: Columns of the markdown table, in order (survey keys).
COLUMNS = (
    "landmarks_per_m",
    "landmarks_face_within_1m",
    "landmarks_reachable_share",
    "landmarks_speckle_share",
    "landmarks_unreachable_share",
    "landmarks_unknown_share",
    "landmarks_seen_share",
    "route_on_territory_share",
    "route_covered_2m_share",
    "route_revisits",
    "route_revisit_time_share",
    "route_revisit_since_median_s",
    "regions",
    "regions_unreachable",
    "regions_cuts",
    "regions_cuts_at_doors",
    "regions_cut_width_median_m",
)


def scanned_standin(seed: int, margin: float = 4.0, res: float = 0.1) -> OccupancyMap:
    """The scanned-plan stand-in (module notes): 1-cell walls, the outside free."""
    fp = random_building(40.0, 30.0, seed=seed, wall=res)
    fp.clear(20.0 - 0.6, -0.01, 20.0 + 0.6, res + 0.01)  # the entrance
    x0, y0, x1, y1 = -margin, -margin, 40.0 + margin, 30.0 + margin
    inner = fp.render(fp.grid(res))
    grid = Grid.from_bounds(x0, y0, x1, y1, res)
    occ = np.zeros(grid.shape, dtype=np.float32)
    k = round(margin / res)
    occ[k : k + inner.grid.rows, k : k + inner.grid.cols] = inner.occupancy
    return OccupancyMap(grid, occ)


def load_plan(name: str) -> OccupancyMap:
    if name.startswith("scanned:"):
        return scanned_standin(int(name.partition(":")[2]))
    if Path(name).exists():
        return read_map(name)
    return builtin_plan(name)


def label_of(name: str) -> str:
    return Path(name).stem if Path(name).exists() else name


def measure(
    name: str, duration: float, out: Path, *, before: bool = False, tour: bool = False
) -> dict[str, Any]:
    """One map's survey row; its picture goes to ``out/<label>.png``. ``before``: the
    world as missions made it before issue 37 (landmarks on every face, random
    waypoints, regions cut on every free cell); ``tour``: the route is the tour driven lap
    after lap (``patrol_route(style="tour")``)."""
    t0 = time.perf_counter()
    plan = load_plan(name)
    if before:
        world = make_world(plan, seed=0, duration=duration, faces="all")
        route = patrol_route(plan, duration, seed=0, style="waypoints")
        labels = cut_regions(plan.classes() == FREE, plan.grid.resolution)
    else:
        world = make_world(plan, seed=0, duration=duration)
        route = patrol_route(plan, duration, seed=0, style="tour" if tour else "waypoints")
        labels = mission_regions(plan)
    s = survey(plan, world, route, labels)
    label = label_of(name)
    draw_survey(plan, world, route, s, out / f"{label}.png", title=f"{label}, {duration:g} s")
    return {"map": label, **s.figures, "seconds": round(time.perf_counter() - t0, 1)}


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def table(rows: list[dict[str, Any]]) -> str:
    """Maps as columns, figures as rows."""
    head = "| figure | " + " | ".join(r["map"] for r in rows) + " |"
    sep = "|---|" + "---|" * len(rows)
    body = [f"| {k} | " + " | ".join(_cell(r.get(k)) for r in rows) + " |" for k in COLUMNS]
    return "\n".join([head, sep, *body])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("maps", nargs="*", default=list(DEFAULT_MAPS))
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--out", type=Path, default=Path("out/team_world"))
    ap.add_argument(
        "--before",
        action="store_true",
        help="The world as missions made it before issue 37 (every face, random "
        "waypoints, regions on every free cell).",
    )
    ap.add_argument("--tour", action="store_true", help="Drive the tour, lap after lap.")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.maps:
        row = measure(name, args.duration, args.out, before=args.before, tour=args.tour)
        print(json.dumps(row), flush=True)
        rows.append(row)
    (args.out / "survey.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(table(rows))


if __name__ == "__main__":
    main()
