"""Each robot's store as a team's mission grows (issue 15: "mission length not bounded
by memory ... per robot, with 3-8 robots").

``--robots`` robots (3) patrol random waypoints on the office floor plan (or ``--plan
building:N``) for ``--base`` seconds (300) times each of ``--scales`` (1 4 10), exchanging
by the good protocol over the full simulated network
(:func:`sonarmap.team.simulation.run_team`). For each length and robot: the peak bytes
of its whole store (own layer, every received layer, closures) and of its own layer, the
poses it made, kept and received. A robot's store is bounded by its own layer's bound
(every region of the prior at M_r, plus the newest pose) and, for each other robot, that
robot's layer, whose copy it receives: ``robots`` x regions x M_r + M_pose, plus the
closures, which go with the poses they join. The targets: every peak within that bound
plus the closures, and each robot's peaks of the two longest missions (4x and 10x)
within 10 %. Each length's figures are printed as soon as it is done.

Run with ``python -m benchmarks.team_memory [--robots 3] [--base 300] [--scales 1 4 10]
[--plan office] [--seed 2] [--json F] [--plot F.png]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from benchmarks.team import plan_by_name
from sonarmap.plot import save_memory_series
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams
from sonarmap.team.simulation import run_team

#: Per robot and length.
KEYS = (
    "store_bytes_peak",
    "local_bytes_peak",
    "local_bytes_bound",
    "closure_bytes_final",
    "poses_made",
    "poses_local",
    "poses_received",
    "association_precision",
    "map_f1",
)


def measure(
    plan_name: str,
    robots: int,
    base: float,
    scales: list[float],
    seed: int,
    report: Callable[[dict[str, Any]], None] | None = None,
) -> tuple[list[dict[str, Any]], dict[str, list[int]]]:
    """One row per length (the team's figures and a row per robot), and each robot's
    whole-store bytes per pose of the longest mission."""
    plan = plan_by_name(plan_name)
    rows: list[dict[str, Any]] = []
    series: dict[str, list[int]] = {}
    for k in scales:
        t0 = time.perf_counter()
        r = run_team(
            plan,
            MissionConfig(duration=base * k, seed=seed),
            robots,
            network=NetworkParams(kind="full"),
            exchange=ExchangeParams(),
            seed=seed,
        )
        s = r.summary
        rows.append(
            {
                "scale": k,
                "duration_s": base * k,
                "duplicate_poses": s["duplicate_poses"],
                "identical_maps": s["identical_maps"],
                "map_f1_team": s["map_f1_team"],
                "bytes_per_robot_minute": s["bytes_per_robot_minute"],
                "robots": [{key: row[key] for key in KEYS} for row in s["robots"]],
                "wall_s": time.perf_counter() - t0,
            }
        )
        series = {f"robot {i}": m.bytes_per_pose for i, m in enumerate(r.robots)}
        if report is not None:
            report(rows[-1])
    return rows, series


def bound(robot: dict[str, Any], robots: int) -> int:
    """A robot's store bound: every robot's layer at its bound (they are the same plan's
    regions), plus its closures."""
    return int(robots * robot["local_bytes_bound"] + robot["closure_bytes_final"])


def targets(rows: list[dict[str, Any]], robots: int) -> list[tuple[str, bool]]:
    """The claims, each with whether these rows meet it."""
    out = [
        (
            "every robot's peak within robots x (its layer's bound) + its closures",
            all(r["store_bytes_peak"] <= bound(r, robots) for row in rows for r in row["robots"]),
        ),
        ("no duplicate poses at any length", all(row["duplicate_poses"] == 0 for row in rows)),
    ]
    if len(rows) >= 2:
        spreads = []
        for i in range(robots):
            peaks = [row["robots"][i]["store_bytes_peak"] for row in rows[-2:]]
            spreads.append(max(peaks) / min(peaks) - 1)
        worst = max(spreads)
        out.append(
            (
                f"each robot's peaks of the two longest missions within 10 % (worst "
                f"{100 * worst:.1f} %)",
                worst <= 0.1,
            )
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--plan", default="office", help="office, or building:SEED")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--base", type=float, default=300.0)
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0, 4.0, 10.0])
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--json", help="Also write the rows to this JSON file.")
    parser.add_argument("--plot", help="Also draw each robot's store over the longest mission.")
    args = parser.parse_args()
    print(f"team memory, {args.plan} plan, {args.robots} robots, good protocol, full network")

    def show(row: dict[str, Any]) -> None:
        print(
            f"x{row['scale']:g} ({row['duration_s']:.0f} s, wall {row['wall_s']:.0f} s): "
            f"duplicates {row['duplicate_poses']}, identical {row['identical_maps']}, "
            f"team F1 {row['map_f1_team']:.3f}, {row['bytes_per_robot_minute'] / 1e3:.0f} kB "
            "per robot-minute",
            flush=True,
        )
        for i, r in enumerate(row["robots"]):
            print(
                f"  robot {i}: peak {r['store_bytes_peak']} B (bound {bound(r, args.robots)} "
                f"B; own layer {r['local_bytes_peak']} B), poses made {r['poses_made']}, "
                f"kept {r['poses_local']}, received {r['poses_received']}, precision "
                f"{r['association_precision']:.3f}, map F1 {r['map_f1']:.3f}",
                flush=True,
            )

    rows, series = measure(args.plan, args.robots, args.base, args.scales, args.seed, show)
    print("targets:")
    for name, ok in targets(rows, args.robots):
        print(f"  {'holds' if ok else 'FAILS'}: {name}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    if args.plot:
        save_memory_series(
            series,
            args.plot,
            interval=args.base * args.scales[-1] / max(len(next(iter(series.values()))), 1),
            bound=args.robots * rows[-1]["robots"][0]["local_bytes_bound"],
            ylabel="store [MB]",
        )


if __name__ == "__main__":
    main()
