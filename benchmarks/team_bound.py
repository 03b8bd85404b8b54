"""One robot's store against its configured bound as the mission grows (issue 37 item 3).

For each plan and each ``--durations`` length (600 1200 2400 s), one mission with the
default store (or ``--region-limit`` / ``--store-limit``); per run the peak of the local
layer and of the whole store, the local layer's configured bound
(``local_bytes_bound``), the closures' bytes at the end, the regions used and the poses
kept and made. The bound is held when ``local_bytes_peak <= local_bytes_bound``; it is
visible when the peak levels off, i.e. the longest run's peak is within 10 % of the
previous length's.

Plans: a map_server YAML, ``building:SEED`` (a random 20 x 16 m building) or
``standin:SEED``: a stand-in for a scanned drawing (a random 100 x 80 m building,
:func:`~sonarmap.floorplan.random_building`, 0.1 m walls one cell thick, 3 m of free
outside around it, 0.1 m cells). It is a stand-in, not a scanned plan.

Usage::

    python -m benchmarks.team_bound --plans /work/shared/data/maps/depot.yaml standin:0
        [--durations 600 1200 2400] [--seed 0] [--store-limit B] [--region-limit B]
        [--json F]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from sonarmap.floorplan import random_building
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap, read_map
from sonarmap.team.mission import MissionConfig, run_mission
from sonarmap.team.store import StoreParams
from sonarmap.team.world import builtin_plan

#: Per run, from the mission's summary.
KEYS = (
    "local_bytes_peak",
    "local_bytes_bound",
    "store_bytes_peak",
    "closure_bytes_final",
    "regions",
    "regions_used",
    "poses",
    "poses_made",
    "map_f1",
    "map_f1_held_true_poses",
    "map_f1_true_poses",
    "ate_m",
    "ate_odometry_m",
)


def standin_plan(seed: int) -> OccupancyMap:
    """A stand-in for a scanned building drawing: a random 100 x 80 m building with
    0.1 m walls (one cell), 3 m of free space drawn around it, at 0.1 m."""
    fp = random_building(100.0, 80.0, seed=seed, wall=0.1)
    return fp.render(Grid.from_bounds(-3.0, -3.0, 103.0, 83.0, 0.1))


def plan_of(name: str) -> OccupancyMap:
    """A plan by ``--plans`` name: a YAML path, ``building:SEED`` or ``standin:SEED``."""
    kind, _, seed = name.partition(":")
    if kind == "standin" and seed.isdigit():
        return standin_plan(int(seed))
    if kind == "building":
        return builtin_plan(name)
    path = Path(name)
    if not path.is_file():
        raise SystemExit(f"--plans: {name}: no such file, and not building:SEED or standin:SEED")
    return read_map(path)


def measure(
    name: str, durations: list[float], seed: int, store: StoreParams
) -> list[dict[str, Any]]:
    """One row per duration, printed as it is done."""
    plan = plan_of(name)
    rows = []
    for d in durations:
        t0 = time.perf_counter()
        s = run_mission(plan, MissionConfig(duration=d, seed=seed, store=store)).summary
        row = {"plan": name, "duration_s": d, **{k: s[k] for k in KEYS}}
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
        print(
            f"{name} {d:.0f} s: local peak {row['local_bytes_peak'] / 1e3:.0f} kB of bound "
            f"{row['local_bytes_bound'] / 1e3:.0f} kB, store peak "
            f"{row['store_bytes_peak'] / 1e3:.0f} kB, closures "
            f"{row['closure_bytes_final'] / 1e3:.0f} kB, regions {row['regions_used']}/"
            f"{row['regions']}, poses {row['poses']}/"
            f"{row['poses_made']}, F1 {row['map_f1']:.3f} (held at truth "
            f"{row['map_f1_held_true_poses']:.3f}, all readings "
            f"{row['map_f1_true_poses']:.3f}), ATE {row['ate_m']:.2f} m "
            f"({row['ate_odometry_m']:.2f}), {row['wall_s']:.0f} s",
            flush=True,
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--plans", nargs="+", required=True)
    parser.add_argument("--durations", type=float, nargs="+", default=[600.0, 1200.0, 2400.0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--store-limit", type=int, default=None)
    parser.add_argument("--region-limit", type=int, default=None)
    parser.add_argument("--json", help="Also write the rows to this JSON file.")
    args = parser.parse_args()
    for name in args.plans:
        plan_of(name)  # a bad name fails before any run
    extra: dict[str, Any] = {}
    if args.store_limit is not None:
        extra["store_limit"] = args.store_limit
    if args.region_limit is not None:
        extra["region_limit"] = args.region_limit
    store = StoreParams(**extra)
    rows = []
    for name in args.plans:
        got = measure(name, args.durations, args.seed, store)
        rows += got
        peaks = [r["local_bytes_peak"] for r in got]
        held = all(r["local_bytes_peak"] <= r["local_bytes_bound"] for r in got)
        level = len(peaks) < 2 or peaks[-1] <= 1.1 * peaks[-2]
        print(
            f"{name}: peak x{peaks[-1] / max(peaks[0], 1):.2f} from the shortest to the longest; "
            f"bound held {held}; levelled off {level}",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
