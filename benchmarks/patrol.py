"""The patrol simulator in the thesis's Table 4 setting: how fast, and whether the
shortcuts change anything.

Setting: the built-in ``fig3-10`` map (240 x 159 m, narrow corridors), 5 car-like
robots at the map's starts, the wave, direction refinement, artificial obstacles, mode
direction choice, one core. For each cell size (``--cells``, default the thesis's
0.1 m and the simulator's default 0.5 m):

- ``x real time``: simulated seconds per wall-clock second over ``--duration`` (1200 s)
  simulated seconds (the target is 20: one simulated hour in 3 minutes);
- ``CPU s`` and ``x per CPU s``: the CPU seconds of this process over the same run
  (``time.process_time``, the run's set-up included), and simulated seconds per CPU
  second: on a shared machine, what the wall clock cannot tell;
- ``same as whole-map waves``: the first ``--check`` (120) seconds run again with every
  wave over the whole map (``prune=False``); the MTB and DVT of every step and the
  final positions must be identical;
- mean MTB, DVT and the share never seen, so the two cell sizes can be compared.

Run with ``python -m benchmarks.patrol [--cells 0.1 0.5] [--duration 1200] [--check 120]
[--seed 0] [--leftover 0] [--json F]`` (``--leftover M``: the cars'
``PatrolConfig.leftover``, off by default).

With ``--profile SECONDS`` it measures nothing of the above: for each cell size it runs
5 simulated seconds untimed (numba's kernels compiled or loaded, the territory built),
then ``SECONDS`` simulated seconds of the same setting under ``cProfile``, and prints
that run's CPU seconds and the profile's 30 lines of most time spent in a function
itself (``tottime``).

With ``--setup REPEAT`` it measures nothing of the above either: for each cell size it
runs 5 simulated seconds untimed, then ``REPEAT`` runs of 0.5 simulated seconds (5
steps) timed as the speed run is (``time.process_time`` over the ``run_patrol`` call):
about what a run's own set-up (the territory's one-way streets, reach and the rest
``run_patrol`` builds) adds to the CPU seconds above.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import math
import os
import platform
import pstats
import time
from typing import Any, NoReturn

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.maps import builtin_territory
from sonarmap.patrol.simulation import PatrolResult
from sonarmap.patrol.starts import starts_from_dm
from sonarmap.patrol.territory import Territory


def non_negative(text: str) -> float:
    """An ``argparse`` type: ``text`` as a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def positive(text: str) -> float:
    """An ``argparse`` type: ``text`` as a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose refusal is one line (the problem and the option), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message}\n")


def table4(
    cell: float, duration: float, prune: bool = True, leftover: float = 0.0
) -> tuple[Territory, PatrolConfig, npt.NDArray[np.float64]]:
    """Table 4's setting: the ``fig3-10`` map at ``cell`` metres, the car defaults with
    refinement, crowding by obstacles and the mode's direction, ``duration`` seconds,
    and the map's first 5 starts (world x, y, heading). ``prune``: waves limited to
    what they need (default True; False: whole-map waves, the reference).
    ``leftover``: :attr:`~sonarmap.patrol.simulation.PatrolConfig.leftover`, metres
    (default 0: none)."""
    territory, starts = builtin_territory("fig3-10", cell)
    config = PatrolConfig(
        model="car",
        refine=True,
        crowding="obstacles",
        direction="mode",
        paths="wave",
        duration=duration,
        cell=cell,
        prune=prune,
        leftover=leftover,
    )
    return territory, config, starts_from_dm(starts[:5], territory)


def _run(
    cell: float, duration: float, prune: bool, seed: int, leftover: float = 0.0
) -> tuple[PatrolResult, float, float]:
    territory, config, starts = table4(cell, duration, prune, leftover)
    t0, c0 = time.perf_counter(), time.process_time()
    res = run_patrol(territory, config, starts=starts, seed=seed)
    return res, time.perf_counter() - t0, time.process_time() - c0


def _same(a: PatrolResult, b: PatrolResult) -> bool:
    return bool(
        np.array_equal(a.mtb, b.mtb)
        and np.array_equal(a.dvt, b.dvt)
        and np.array_equal(a.positions, b.positions)
    )


def measure(
    cell: float, duration: float, check: float, seed: int, leftover: float = 0.0
) -> dict[str, Any]:
    """One cell size: speed over ``duration``, identity with whole-map waves over
    ``check`` seconds (``leftover``: the cars' option, metres; default 0)."""
    _run(cell, 5.0, True, seed, leftover)  # compile and build the territory before timing
    res, wall, cpu = _run(cell, duration, True, seed, leftover)
    short, _, _ = _run(cell, check, True, seed, leftover)
    full, full_wall, _ = _run(cell, check, False, seed, leftover)
    s = res.summary()
    return {
        "cell_m": cell,
        "simulated_s": duration,
        "wall_s": round(res.wall_seconds, 2),
        "x_real_time": round(duration / res.wall_seconds, 2),
        "cpu_s": round(cpu, 2),
        "x_per_cpu_s": round(duration / cpu, 2),
        "target_met": duration / res.wall_seconds >= 20.0,
        "same_as_whole_map_waves": _same(short, full),
        "whole_map_x_real_time": round(check / full.wall_seconds, 2),
        "mean_mtb": round(s["mean_mtb"], 1),
        "dvt": round(s["dvt"], 2),
        "never_seen": round(s["never_seen"], 4),
        "total_wall_s": round(wall + full_wall, 1),
    }


def profile(
    cell: float, duration: float, seed: int, leftover: float = 0.0, lines: int = 30
) -> None:
    """Print the CPU seconds and the ``lines`` largest ``tottime`` entries of a profiled
    run of ``duration`` simulated seconds at ``cell`` metres (after an untimed 5 s;
    ``leftover``: the cars' option, metres; default 0)."""
    _run(cell, 5.0, True, seed, leftover)
    prof = cProfile.Profile()
    prof.enable()
    _, wall, cpu = _run(cell, duration, True, seed, leftover)
    prof.disable()
    print(
        f"profile: fig3-10 at {cell} m, {duration:g} simulated s, seed {seed}, "
        f"leftover {leftover:g} m: "
        f"{cpu:.1f} s CPU, {wall:.1f} s wall (under the profiler)"
    )
    pstats.Stats(prof).sort_stats("tottime").print_stats(lines)


def setup(cell: float, repeat: int, seed: int, leftover: float = 0.0) -> list[float]:
    """The CPU seconds of ``repeat`` timed ``run_patrol`` calls of 0.5 simulated seconds
    at ``cell`` metres, after an untimed 5 s (``leftover``: the cars' option, metres;
    default 0)."""
    _run(cell, 5.0, True, seed, leftover)
    return [_run(cell, 0.5, True, seed, leftover)[2] for _ in range(repeat)]


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(prog="python -m benchmarks.patrol", description=__doc__)
    parser.add_argument("--cells", type=positive, nargs="+", default=[0.1, 0.5])
    parser.add_argument("--duration", type=positive, default=1200.0)
    parser.add_argument("--check", type=float, default=120.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="Also write the rows to this JSON file.")
    parser.add_argument(
        "--leftover", type=non_negative, default=0.0, help="The cars' leftover option, metres."
    )
    parser.add_argument(
        "--profile",
        type=float,
        metavar="SECONDS",
        help="Profile a run of this many simulated seconds per cell size instead.",
    )
    parser.add_argument(
        "--setup",
        type=int,
        metavar="REPEAT",
        help="Time this many 0.5 s runs per cell size (the set-up's CPU) instead.",
    )
    args = parser.parse_args(argv)
    if args.setup is not None and args.profile is not None:
        parser.error("--setup and --profile: give one of them")
    if args.setup is not None:
        if args.setup < 1:
            parser.error(f"--setup must be >= 1 runs, got {args.setup}")
        for c in args.cells:
            cpu = setup(c, args.setup, args.seed, args.leftover)
            print(
                f"setup: fig3-10 at {c} m, 0.5 simulated s, seed {args.seed}: CPU s "
                + ", ".join(f"{v:.2f}" for v in cpu)
            )
        return
    if args.profile is not None:
        if not args.profile > 0:
            parser.error(f"--profile must be > 0 simulated seconds, got {args.profile}")
        for c in args.cells:
            profile(c, args.profile, args.seed, args.leftover)
        return
    rows = [measure(c, args.duration, args.check, args.seed, args.leftover) for c in args.cells]
    head = (
        f"{'cell':>5} {'x real time':>11} {'CPU s':>7} {'x per CPU s':>11} {'target':>7} "
        f"{'same':>5} {'whole-map x':>11} "
        f"{'mean MTB':>9} {'DVT %':>6} {'unseen':>7}"
    )
    print(f"patrol, Table 4 setting (fig3-10, 5 cars), {platform.processor() or 'cpu'}")
    print(head)
    for r in rows:
        met = "yes" if r["target_met"] else "no"
        same = "yes" if r["same_as_whole_map_waves"] else "NO"
        print(
            f"{r['cell_m']:>5g} {r['x_real_time']:>11.1f} {r['cpu_s']:>7.1f} "
            f"{r['x_per_cpu_s']:>11.1f} {met:>7} {same:>5} "
            f"{r['whole_map_x_real_time']:>11.1f} {r['mean_mtb']:>9.1f} {r['dvt']:>6.2f} "
            f"{r['never_seen']:>7.4f}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
