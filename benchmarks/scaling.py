"""How each method's time grows with the map's size and with the number of readings.

Two sweeps, every method with a fixed amount of work so that time measures cost, not
convergence: ``gradient`` 50 projected-subgradient steps, ``em`` 5 EM iterations,
``stochastic`` 5 sweeps of flips, ``inverse`` and ``counting`` as they are.

- map side 6, 12, 25, 50, 100 m at 5 cm (1.4 k to 4 M cells), 10,000 readings;
- 1e3, 1e4, 1e5, 1e6 readings on a 20 m map at 5 cm.

Readings are HC-SR04 poses spread uniformly over the floor, ranges uniform in
0.2-2 m (about 150 cells each). The table gives seconds and the slope of log time
against log size between the two largest points (1 = linear).

Run alone with ``python -m benchmarks.scaling [--quick] [--json F]``; ``make bench`` runs it too.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.readings import Readings
from sonarmap.sensors import get_sensor

METHODS: dict[str, dict[str, Any]] = {
    "inverse": {},
    "counting": {},
    "gradient": {"max_iter": 50, "patience": 10_000},
    "stochastic": {"sweeps": 5.0},
    "em": {"max_iter": 5, "tol": 0.0},
}
SENSOR = "hc-sr04"


def readings(n: int, size: float, seed: int = 0) -> Readings:
    rng = np.random.default_rng(seed)
    return Readings(
        np.arange(n, dtype=float),
        np.zeros(n, np.int32),
        rng.uniform(0, size, n),
        rng.uniform(0, size, n),
        rng.uniform(-np.pi, np.pi, n),
        rng.uniform(0.2, 2.0, n),
        ("s",),
    )


def time_fit(method: str, r: Readings, size: float) -> float:
    grid = Grid.from_bounds(0.0, 0.0, size, size, 0.05)
    sensor = get_sensor(SENSOR)
    mapper = make_mapper(method, **METHODS[method])
    t0 = time.perf_counter()
    mapper.fit(r, grid, sensor)
    return time.perf_counter() - t0


def sweep(sizes: list[float], counts: list[int]) -> dict[str, Any]:
    # Compile and load every kernel first.
    for m in METHODS:
        time_fit(m, readings(200, 6.0), 6.0)
    by_size: dict[str, list[float]] = {m: [] for m in METHODS}
    for size in sizes:
        r = readings(10_000, size)
        for m in METHODS:
            by_size[m].append(time_fit(m, r, size))
            print(f"[scaling] {size:g} m, {m}: {by_size[m][-1]:.2f} s", file=sys.stderr)
    by_count: dict[str, list[float]] = {m: [] for m in METHODS}
    for n in counts:
        r = readings(n, 20.0)
        for m in METHODS:
            by_count[m].append(time_fit(m, r, 20.0))
            print(f"[scaling] {n:,} readings, {m}: {by_count[m][-1]:.2f} s", file=sys.stderr)
    return {"sizes": sizes, "counts": counts, "by_size": by_size, "by_count": by_count}


def _slope(x: list[float], y: list[float]) -> float:
    return math.log(y[-1] / y[-2]) / math.log(x[-1] / x[-2])


WHY = {
    "inverse": "one pass over the cells each reading touches; the grid is allocated once",
    "counting": "as inverse",
    "gradient": "each step is two sparse products over the readings' cells; W is built "
    "with a sort of the touched cells",
    "stochastic": "indexing sorts every (reading, cell) pair; flips scale with the cells "
    "some beam holds, each costing the readings through that cell",
    "em": "each iteration passes over every (reading, cell) pair; indexing as stochastic",
}


def print_tables(res: dict[str, Any], console: Console) -> None:
    for key, xs, label in (
        ("by_size", [s * s / 0.0025 for s in res["sizes"]], "map side [m]"),
        ("by_count", [float(n) for n in res["counts"]], "readings"),
    ):
        heads = [f"{v:g}" if key == "by_size" else f"{v:.0e}" for v in res[key[3:] + "s"]]
        t = Table(
            "method",
            *heads,
            "slope",
            "why",
            title=f"scaling: seconds against {label} "
            + ("(10,000 readings)" if key == "by_size" else "(20 m map at 5 cm)"),
        )
        for m, ys in res[key].items():
            t.add_row(m, *[f"{y:.3g}" for y in ys], f"{_slope(xs, ys):.2f}", WHY[m])
        console.print(t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="up to 50 m and 1e5 readings")
    parser.add_argument("--json")
    args = parser.parse_args()
    sizes = [6.0, 12.0, 25.0, 50.0] + ([] if args.quick else [100.0])
    counts = [1_000, 10_000, 100_000] + ([] if args.quick else [1_000_000])
    res = sweep(sizes, counts)
    print_tables(res, Console(width=160))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
