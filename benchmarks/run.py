"""sonarmap's benchmarks, printed as tables (and written as JSON with --json).

Run everything with ``make bench`` (``python -m benchmarks.run``): the kernels
(rasteriser, inverse insertion, gradient solvers and sparse products against the copy
bandwidth, stochastic flips, EM), the streaming ring scenario (``benchmarks/stream.py``),
the scaling sweeps (``benchmarks/scaling.py``) and, when MRPT is installed, the side by
side with MRPT (``benchmarks/mrpt/run.py``). ``--skip stream,scaling,mrpt`` leaves parts
out; ``--quick`` runs short versions (2 minutes of the ring log, smaller sweeps).
Numba is pinned to one thread and every kernel is warmed up before timing; each kernel
figure is the best of ``--repeat`` runs.
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
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.mappers.stochastic import StochasticMapper
from sonarmap.raster import Footprint, rasterise
from sonarmap.readings import Readings
from sonarmap.rig import get_rig
from sonarmap.scenarios import make_scenario
from sonarmap.sensors import SensorModel, get_sensor


def _si(v: float) -> str:
    """A rate with a k / M / G prefix."""
    for factor, prefix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if v >= factor:
            return f"{v / factor:.2f} {prefix}"
    return f"{v:.2f}"


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


def copy_bandwidth(repeat: int) -> float:
    """Bytes per second of a streaming copy of 256 MB (read + write counted)."""
    src = np.ones(32 * 1024 * 1024)
    dst = np.empty_like(src)
    t, _ = best_of(lambda: np.copyto(dst, src), max(repeat, 3))
    return 2 * src.nbytes / t


def bench_forward(repeat: int, bandwidth: float) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    scen = make_scenario("doorways")
    grid, rig, rd = scen.truth.grid, scen.rig, scen.readings
    for solver in ("pgd", "gd", "lbfgs"):
        mapper = make_mapper("gradient", solver=solver)

        def fit(mapper: Mapper = mapper) -> Mapper:
            return mapper.fit(rd, grid, rig)

        t, _ = best_of(fit, repeat)
        rows.append(
            {
                "benchmark": f"gradient ({solver}) on doorways, 5 cm",
                "n": len(rd),
                "entries": 0,
                "seconds": t,
                "rate": 1.0 / t,
                "unit": "maps/s",
            }
        )
    problem = GradientMapper().start(grid, rig).problem(rd)
    x = np.full(problem.n_cells, 0.5)
    y = np.ones(problem.n_terms)
    n_prod = 200

    def products() -> None:
        for _ in range(n_prod // 2):
            problem.W @ x
            problem.WT @ y

    t, _ = best_of(products, repeat)
    nnz = problem.W.nnz
    # Per product: CSR values (8 B) and column indices (4 B) per entry, the row pointer,
    # the gathered input (8 B per entry at worst) and the output vector.
    moved = 20 * nnz + 8 * (problem.n_terms + problem.n_cells) + 8 * problem.n_terms
    rate = n_prod / t
    rows.append(
        {
            "benchmark": "gradient sparse products (W x, W^T y)",
            "n": nnz,
            "entries": nnz,
            "seconds": t / n_prod,
            "rate": rate,
            "unit": "products/s",
            "bandwidth_fraction": rate * moved / bandwidth,
        }
    )
    for res in (0.1, 0.05):
        sc = make_scenario("doorways", resolution=res)
        sm = make_mapper("stochastic")

        def search(sm: Mapper = sm, sc: Any = sc) -> Mapper:
            return sm.fit(sc.readings, sc.truth.grid, sc.rig)

        t, fitted = best_of(search, repeat)
        assert isinstance(fitted, StochasticMapper)
        assert fitted.index_ is not None
        flips = round(fitted.sweeps * fitted.index_.n_cells)
        rows.append(
            {
                "benchmark": f"stochastic on doorways, {res * 100:g} cm",
                "n": flips,
                "entries": 0,
                "seconds": t,
                "rate": flips / t,
                "unit": "flips/s",
            }
        )
    em = make_mapper("em")

    def run_em() -> Mapper:
        return em.fit(rd, grid, rig)

    t, _ = best_of(run_em, repeat)
    rows.append(
        {
            "benchmark": "em on doorways, 5 cm",
            "n": len(rd),
            "entries": 0,
            "seconds": t,
            "rate": 1.0 / t,
            "unit": "maps/s",
        }
    )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--json", help="Also write the results to this JSON file.")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--skip", default="", help="comma-separated: stream,scaling,mrpt")
    parser.add_argument("--quick", action="store_true", help="short streaming and sweeps")
    args = parser.parse_args()
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    bad = skip - {"stream", "scaling", "mrpt"}
    if bad:
        parser.error(f"unknown part(s) to skip: {', '.join(sorted(bad))}")
    bandwidth = copy_bandwidth(args.repeat)
    rows = bench_raster(args.repeat) + bench_inverse(args.repeat)
    rows += bench_forward(args.repeat, bandwidth)
    table = Table(
        "benchmark",
        "items",
        "cell entries",
        "best time [s]",
        "rate",
        title=f"sonarmap benchmarks (one core; {platform.machine()})",
    )
    for row in rows:
        extra = ""
        if "cell_updates_per_s" in row:
            extra = f" ({_si(row['cell_updates_per_s'])} cell updates/s)"
        if "bandwidth_fraction" in row:
            extra = f" ({100 * row['bandwidth_fraction']:.0f} % of copy bandwidth)"
        table.add_row(
            row["benchmark"],
            f"{row['n']:,}",
            f"{row['entries']:,}" if row["entries"] else "-",
            f"{row['seconds']:.4g}",
            f"{_si(row['rate'])} {row['unit']}{extra}",
        )
    console = Console(width=160)
    console.print(table)
    console.print(f"streaming copy bandwidth: {bandwidth / 1e9:.1f} GB/s")
    out: dict[str, Any] = {
        "machine": platform.platform(),
        "cpu": platform.processor(),
        "copy_bandwidth": bandwidth,
        "results": rows,
    }
    if "stream" not in skip:
        from benchmarks import stream

        res = stream.run(2.0 if args.quick else 10.0, 1.0 if args.quick else 2.0, bandwidth)
        stream.print_tables(res, console)
        out["stream"] = res
    if "scaling" not in skip:
        from benchmarks import scaling

        sizes = [6.0, 12.0, 25.0] + ([] if args.quick else [50.0, 100.0])
        counts = [1_000, 10_000] + ([] if args.quick else [100_000, 1_000_000])
        res = scaling.sweep(sizes, counts)
        scaling.print_tables(res, console)
        out["scaling"] = res
    if "mrpt" not in skip:
        from benchmarks.mrpt import run as mrpt

        if mrpt.available():
            mrpt.main(["--minutes", "2" if args.quick else "10"])
        else:
            console.print("MRPT not installed: `make bench-mrpt` installs it and runs that part.")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2, default=float)


if __name__ == "__main__":
    main()
