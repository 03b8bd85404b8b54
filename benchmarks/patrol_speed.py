"""How fast the patrol runs on a large building at the thesis's 0.1 m cells.

Setting (issue 36's speed goal): a seeded floor plan of rooms off one another
(:func:`sonarmap.floorplan.random_building`, ``--size`` 100 x 80 m by default, rooms of
3-10 m, doors of 1.0-1.5 m) drawn at 0.1 m, patrolled on 0.1 m cells by ``--robots``
indoor robots (radius 0.3 m, 1 m/s, 5 m vision), no start file, the default motion
(the wave's paths, giving way). One run per seed of ``--duration`` simulated seconds
after a warm-up that compiles the kernels, on one core. Reported per seed:

- ``x real``: simulated seconds per wall-clock second (goal: 100; the check: 20);
- ``x cpu``: simulated seconds per second of this process's CPU time, which other jobs
  on a shared machine disturb less than the wall clock;
- the run's mean MTB, blocked share and never-seen share, so a faster version can be
  seen to patrol alike.

Run with ``python -m benchmarks.patrol_speed [--robots 4] [--duration 600] [--seeds 0]
[--size 100 80] [--min-hold S] [--choice-cell M] [--json F]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from typing import Any

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from sonarmap.floorplan import random_building
from sonarmap.grid import Grid
from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.paths import Wave
from sonarmap.patrol.territory import Territory


def indoor(
    duration: float, min_hold: float = 0.0, choice_cell: float | None = None
) -> PatrolConfig:
    """Issue 36's indoor robots on 0.1 m cells, otherwise the defaults (``min_hold``,
    ``choice_cell``: :class:`~sonarmap.patrol.PatrolConfig`'s; None: its default)."""
    config = PatrolConfig(
        radius=0.3, speed=1.0, vision=5.0, cell=0.1, duration=duration, min_hold=min_hold
    )
    return config if choice_cell is None else dataclasses.replace(config, choice_cell=choice_cell)


def building(width: float, height: float, seed: int) -> Territory:
    """The benchmark's building as a territory on 0.1 m cells."""
    plan = random_building(width, height, seed=seed, max_room=10.0, door=(1.0, 1.5))
    return Territory.from_map(plan.render(Grid.from_bounds(0, 0, width, height, 0.1)), cell=0.1)


def warm_up(territory: Territory, robots: int, seed: int) -> None:
    """Compile every kernel the timed run calls: a short run, and a wave to a kept
    place (a run as short as a few steps may not keep one, and the wave's kernel is
    compiled once per kind of stop and not cached on disk)."""
    run_patrol(territory, indoor(2.0), robots=robots, seed=seed)
    passable = territory.passable(0.3)
    free = np.argwhere(passable)
    if len(free):
        start = (int(free[0, 0]), int(free[0, 1]))
        Wave(passable.shape).to(passable, start, start, 0.1, territory.free)


def run_one(
    territory: Territory,
    robots: int,
    duration: float,
    seed: int,
    min_hold: float = 0.0,
    choice_cell: float | None = None,
) -> dict[str, Any]:
    """One timed run's figures (see the module's notes)."""
    config = indoor(duration, min_hold, choice_cell)
    t0, c0 = time.perf_counter(), time.process_time()
    s = run_patrol(territory, config, robots=robots, seed=seed).summary()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {
        "seed": seed,
        "robots": robots,
        "cells": int(territory.free.size),
        "x_real": duration / wall,
        "x_cpu": duration / cpu,
        "mean_mtb": s["mean_mtb"],
        "blocked": s["blocked_share"],
        "never_seen": s["never_seen"],
        "unreachable": s["unreachable_free_share"],
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=4)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--size", nargs=2, type=float, default=[100.0, 80.0])
    ap.add_argument("--min-hold", type=float, default=0.0, help="seconds (PatrolConfig.min_hold)")
    ap.add_argument(
        "--choice-cell", type=float, help="metres (PatrolConfig.choice_cell; default its default)"
    )
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    rows = []
    print(
        "| seed | robots | cells | x real | x cpu | mean MTB, s | blocked | never seen "
        "| unreachable |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        territory = building(args.size[0], args.size[1], seed)
        # Compile the kernels first: the timed run should not pay for them.
        warm_up(territory, args.robots, seed)
        row = run_one(territory, args.robots, args.duration, seed, args.min_hold, args.choice_cell)
        rows.append(row)
        print(
            f"| {seed} | {row['robots']} | {row['cells']:,} | {row['x_real']:.1f} "
            f"| {row['x_cpu']:.1f} "
            f"| {row['mean_mtb']:.1f} | {row['blocked']:.3f} | {row['never_seen']:.3f} "
            f"| {row['unreachable']:.3f} |",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {
                    "size_m": args.size,
                    "duration": args.duration,
                    "min_hold": args.min_hold,
                    "choice_cell": args.choice_cell,
                    "runs": rows,
                },
                f,
                indent=2,
            )


if __name__ == "__main__":
    main()
