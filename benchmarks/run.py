"""Benchmarks of sonarmap's kernels, printed as a table (and written as JSON with --json).

Run with ``make bench`` or ``python -m benchmarks.run [--json out.json] [--repeat N]``.
Numba is pinned to one thread and every kernel is warmed up before timing; each figure
is the best of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.grid import Grid
from sonarmap.mappers import Mapper, make_mapper
from sonarmap.raster import Footprint, rasterise
from sonarmap.readings import Readings
from sonarmap.rig import get_rig
from sonarmap.scenarios import make_scenario
from sonarmap.sensors import SensorModel, get_sensor


def best_of(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    fn()  # warm-up: JIT compilation and caches
    best = float("inf")
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def random_readings(n: int, size: float, sensor_name: str, seed: int = 0) -> Readings:
    """Poses spread over a square floor, ranges uniform up to r_max (a tenth no-echo)."""
    rng = np.random.default_rng(seed)
    r_max = get_sensor(sensor_name).r_max
    ranges = rng.uniform(0.2, r_max, n)
    ranges[rng.random(n) < 0.1] = r_max
    return Readings(
        np.arange(n, dtype=float),
        np.zeros(n, np.int32),
        rng.uniform(0, size, n),
        rng.uniform(0, size, n),
        rng.uniform(-np.pi, np.pi, n),
        ranges,
        ("s",),
    )


def bench_raster(repeat: int) -> list[dict[str, Any]]:
    rows = []
    for sensor_name, n, size in (
        ("maxsonar-ez1", 20_000, 20.0),
        ("hc-sr04", 20_000, 20.0),
        ("polaroid-6500", 5_000, 40.0),
    ):
        sensor = get_sensor(sensor_name)
        grid = Grid.from_bounds(0.0, 0.0, size, size, 0.05)
        r = random_readings(n, size, sensor_name)

        def run(r: Readings = r, s: SensorModel = sensor, g: Grid = grid) -> Footprint:
            return rasterise(g, s, r.x, r.y, r.theta, r.range)

        t, fp = best_of(run, repeat)
        rows.append(
            {
                "benchmark": f"rasterise {sensor_name}",
                "n": n,
                "entries": fp.n_entries,
                "seconds": t,
                "rate": fp.n_entries / t,
                "unit": "cell entries/s",
            }
        )
    scen = make_scenario("doorways")
    sensor = scen.rig.sensor
    rd = scen.readings
    t, fp = best_of(
        lambda: rasterise(scen.truth.grid, sensor, rd.x, rd.y, rd.theta, rd.range), repeat
    )
    rows.append(
        {
            "benchmark": "rasterise doorways scenario",
            "n": len(rd),
            "entries": fp.n_entries,
            "seconds": t,
            "rate": fp.n_entries / t,
            "unit": "cell entries/s",
        }
    )
    return rows


def bench_inverse(repeat: int) -> list[dict[str, Any]]:
    size = 20.0
    grid = Grid.from_bounds(0.0, 0.0, size, size, 0.05)
    rig = get_rig("ring16")
    r = random_readings(20_000, size, "polaroid-6500")
    rows = []
    for falloff in (0.0, 15.0):
        mapper = make_mapper("inverse", falloff_deg=falloff)

        def run(mapper: Mapper = mapper) -> Mapper:
            return mapper.fit(r, grid, rig)

        t, _ = best_of(run, repeat)
        fp = rasterise(grid, rig.sensor, r.x, r.y, r.theta, r.range)
        rows.append(
            {
                "benchmark": f"inverse insertion (fall-off {falloff:g} deg)",
                "n": len(r),
                "entries": fp.n_entries,
                "seconds": t,
                "rate": len(r) / t,
                "unit": "readings/s",
                "cell_updates_per_s": fp.n_entries / t,
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--json", help="Also write the results to this JSON file.")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rows = bench_raster(args.repeat) + bench_inverse(args.repeat)
    table = Table(
        "benchmark",
        "items",
        "cell entries",
        "best time [s]",
        "rate",
        title=f"sonarmap benchmarks (one core; {platform.processor() or platform.machine()})",
    )
    for row in rows:
        extra = ""
        if "cell_updates_per_s" in row:
            extra = f" ({row['cell_updates_per_s'] / 1e6:.1f} M cell updates/s)"
        table.add_row(
            row["benchmark"],
            str(row["n"]),
            f"{row['entries']:,}",
            f"{row['seconds']:.4f}",
            f"{row['rate'] / 1e6:.2f} M {row['unit']}{extra}",
        )
    Console().print(table)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": platform.platform(), "results": rows}, f, indent=2)


if __name__ == "__main__":
    main()
