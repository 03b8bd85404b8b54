"""What the inverse insertion's time goes to, on the readings ``make bench-mrpt`` times.

Runs the insertion kernel (``accumulate_kernel``, one thread) on the office ring's echoes
at the inverse mapper's defaults, and on variants that each change one part of its work:

- ``runs=False``: every centre decided by its distance (the kernel before the runs);
- no fall-off (uniform increments);
- the fall-off's polynomial cut to fewer terms: the weights are then wrong, so these rows
  time the polynomial's terms and nothing else.

Each figure is the sum, over chunks of 500 readings, of the fastest of ``--repeat`` runs of
the chunk, the variants run in turn chunk by chunk: on a machine shared with other jobs the
fastest run of a short chunk is the one nothing interrupted. The chunks' numba calls add a
fixed overhead (a few ms in all) that a single call, as the mapper makes, does not have.

Run with ``python -m benchmarks.mrpt.profile [--minutes 2] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

import numba
import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap._raster_kernel import accumulate_kernel as _kernel
from sonarmap.mappers import make_mapper
from sonarmap.raster import default_dr, falloff_fit
from sonarmap.scenarios import make_scenario

CHUNK = 500
# Called with a list of arguments: typed loosely.
kernel: Any = _kernel


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


def kernel_args(minutes: float) -> tuple[list[Any], int]:
    """The arguments the inverse mapper at its defaults gives the kernel on ``minutes``
    of the office ring (its echoes: the defaults ignore no-echo readings)."""
    sc = make_scenario("office", duration=60.0 * minutes)
    mapper = make_mapper("inverse")
    p = mapper.get_params()
    grid, sensor = sc.truth.grid, sc.rig.sensor
    r = sc.readings.take(sc.readings.range < sensor.r_max)
    dr = default_dr(grid, sensor) if p["dr"] is None else float(p["dr"])
    offset = mapper.band_offset_for(grid)
    falloff = math.radians(p["falloff_deg"])
    args = [
        np.zeros(grid.size),
        np.zeros(grid.size, dtype=np.bool_),
        grid.resolution,
        grid.origin[0],
        grid.origin[1],
        grid.rows,
        grid.cols,
        np.ascontiguousarray(r.x, dtype=np.float64),
        np.ascontiguousarray(r.y, dtype=np.float64),
        np.ascontiguousarray(r.theta, dtype=np.float64),
        np.asarray(r.range + offset - dr, dtype=np.float64),
        np.asarray(r.range + offset + dr, dtype=np.float64),
        np.ascontiguousarray(sensor.beam.halfplanes),
        float(sensor.beam.radius),
        _logit(p["p_free"]),
        _logit(p["p_occ"]),
        _logit(p["clamp_min"]),
        _logit(p["clamp_max"]),
        falloff,
        falloff_fit(sensor, falloff)[1],
    ]
    return args, len(r)


def variants(args: list[Any]) -> dict[str, tuple[list[Any], bool]]:
    coef = args[19]
    flat = [*args[:18], 0.0, ()]
    return {
        f"defaults: runs, {math.degrees(args[18]):g}-degree fall-off ({len(coef)} terms)": (
            args,
            True,
        ),
        "per-cell distance test (runs=False), fall-off": (args, False),
        "runs, fall-off cut to 7 terms (timing only)": ([*args[:19], coef[:7]], True),
        "runs, fall-off cut to 2 terms (timing only)": ([*args[:19], coef[:2]], True),
        "runs, no fall-off": (flat, True),
        "per-cell distance test (runs=False), no fall-off": (flat, False),
    }


def chunked(cases: dict[str, tuple[list[Any], bool]], n: int, repeat: int) -> dict[str, float]:
    """Each case's time in seconds (summed chunk minima)."""
    total = dict.fromkeys(cases, 0.0)
    for lo in range(0, n, CHUNK):
        hi = min(n, lo + CHUNK)
        best = dict.fromkeys(cases, math.inf)
        for _ in range(repeat):
            for name, (args, runs) in cases.items():
                a = list(args)
                for k in (7, 8, 9, 10, 11):
                    a[k] = np.ascontiguousarray(args[k][lo:hi])
                t0 = time.perf_counter()
                kernel(*a, runs=runs)
                best[name] = min(best[name], time.perf_counter() - t0)
        for name in cases:
            total[name] += best[name]
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=2.0, help="office log length")
    parser.add_argument("--repeat", type=int, default=5, help="runs of each chunk")
    a = parser.parse_args(argv)
    if a.minutes <= 0 or a.repeat < 1:
        print("--minutes must be > 0 and --repeat >= 1", file=sys.stderr)
        return 2
    numba.set_num_threads(1)
    args, n = kernel_args(a.minutes)
    cases = variants(args)
    # Compile every variant before timing; count the cell updates once.
    for case_args, runs in cases.values():
        fresh = list(case_args)
        fresh[0] = np.zeros_like(case_args[0])
        fresh[1] = np.zeros_like(case_args[1])
        cells = kernel(*fresh, runs=runs)
    result = chunked(cases, n, a.repeat)
    table = Table(
        "kernel",
        "time [ms]",
        "ns / cell update",
        title=f"inverse insertion, {n:,} echoes of {a.minutes:g} min of the office ring, "
        f"{cells:,} cell updates, one thread",
    )
    for name, t in result.items():
        table.add_row(name, f"{1e3 * t:.1f}", f"{1e9 * t / cells:.2f}")
    Console(width=120).print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
