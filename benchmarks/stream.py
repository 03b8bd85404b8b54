"""The streaming benchmark: a 16-sonar ring touring a 20 m office for 10 minutes.

The ``office`` scenario (20 m x 20 m at 5 cm, the ``ring16`` rig firing every sonar at
20 Hz, 192,000 readings in 10 minutes) is replayed as fast as possible, one update per
0.25 s of log, through each streaming method with its default strategy. Reported: wall
time, real-time factor, median and p99 update latency (the first update, which loads
the compiled kernels, left out), readings in play and the size of the streaming state.

Memory against log length: ``sonarmap stream`` itself is run in a fresh process on the
first 2.5, 5 and 10 minutes of the log (written as CSV, read in chunks) and its peak
resident memory compared. Agreement: the streaming gradient map of the first
``--offline-minutes`` (2) against the offline gradient map over the same readings, and
both against the truth (a third of the acoustic ring's readings are no-echo beams 10.7 m
long, so the offline problem over 10 minutes, 655 M entries, does not fit in 24 GiB).
The offline problem (far larger than the caches) also gives the DRAM-bound rate of the
sparse products, as a fraction of the copy bandwidth.

Run alone with ``python -m benchmarks.stream [--minutes 10] [--stochastic-minutes 2]
[--offline-minutes 2] [--json F]`` (``--offline-minutes 0``: no offline comparison);
``make bench`` runs it with the kernel benchmarks.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.metrics import agreement, score
from sonarmap.readings import write_readings
from sonarmap.rig import save_rig
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.streaming import DEFAULT_STRATEGY, StreamingMapper, replay

PERIOD = 0.25


def _log(msg: str) -> None:
    print(f"[stream benchmark {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def stream_rows(sc: Scenario, stochastic_minutes: float) -> list[dict[str, Any]]:
    grid, rig, r = sc.truth.grid, sc.rig, sc.readings
    rows: list[dict[str, Any]] = []
    for method in ("inverse", "gradient", "stochastic"):
        rd = r
        if method == "stochastic":
            rd = r.take(np.flatnonzero(r.t < r.t[0] + 60.0 * stochastic_minutes))
        # Warm-up: compiled kernels loaded before timing.
        replay([rd.take(np.arange(min(2000, len(rd))))], StreamingMapper(method, grid, rig))
        sm = StreamingMapper(method, grid, rig)
        _log(f"{method}: streaming {len(rd):,} readings")
        rep = replay([rd], sm, period=PERIOD)
        s: dict[str, Any] = dict(rep.summary())
        s.update(
            {
                "method": method,
                "strategy": sm.strategy.spec(),
                "f1": score(sc.truth, sm.result()).f1_all,
            }
        )
        rows.append(s)
    return rows


def memory_rows(sc: Scenario, minutes: list[float]) -> list[dict[str, Any]]:
    """Peak RSS of ``sonarmap stream`` in a fresh process on prefixes of the log."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        save_rig(sc.rig, d / "rig.yaml")
        write_map(sc.truth, d / "truth")
        r = sc.readings
        for m in minutes:
            part = r.take(np.flatnonzero(r.t < r.t[0] + 60.0 * m))
            csv = d / f"log{m:g}.csv"
            write_readings(part, csv)
            out = d / f"out{m:g}"
            # VmHWM is the peak of this process's own address space; ru_maxrss would
            # carry the parent's peak across fork and exec.
            code = (
                "import sys; from sonarmap.cli import main\n"
                "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    assert not e.code\n"
                "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]\n"
                "print('RSS', hwm.split()[1])\n"
            )
            args = [
                sys.executable,
                "-c",
                code,
                "stream",
                str(csv),
                "--rig",
                str(d / "rig.yaml"),
                "--like",
                str(d / "truth.yaml"),
                "-o",
                str(out),
                "--animation",
                "",
                "--snapshot-every",
                "1e9",
            ]
            _log(f"sonarmap stream on the first {m:g} min ({len(part):,} readings)")
            done = subprocess.run(args, capture_output=True, text=True, check=True)
            rss_kb = int(done.stdout.rsplit("RSS", 1)[1].split()[0])
            info = json.loads((out / "stream.json").read_text())
            rows.append(
                {
                    "minutes": m,
                    "readings": len(part),
                    "peak_rss_mb": rss_kb / 1024,
                    "state_mb": info["max_state_mb"],
                    "in_play": info["max_readings_in_play"],
                    "realtime_factor": info["realtime_factor"],
                }
            )
    return rows


def offline_rows(sc: Scenario, minutes: float, bandwidth: float) -> dict[str, Any]:
    grid, rig = sc.truth.grid, sc.rig
    r = sc.readings.take(np.flatnonzero(sc.readings.t < sc.readings.t[0] + 60.0 * minutes))
    _log(f"streaming, then offline gradient over the first {len(r):,} readings")
    sm = StreamingMapper("gradient", grid, rig)
    replay([r], sm, period=PERIOD)
    streamed = sm.result()
    mapper = GradientMapper()
    t0 = time.perf_counter()
    mapper.start(grid, rig)
    problem = mapper.problem(r)
    t_build = time.perf_counter() - t0
    x0 = np.full(problem.n_cells, 0.5)
    x, n_iter, _ = mapper.solve(problem, x0)
    t_total = time.perf_counter() - t0
    occ = np.full(grid.size, np.nan, dtype=np.float32)
    occ[problem.cells] = np.clip(x, 0, 1)
    offline = OccupancyMap(grid, occ.reshape(grid.shape))
    agree, n_cells = agreement(streamed, offline)
    # Sparse products on a problem far larger than the caches.
    y = np.ones(problem.n_terms)
    reps = 10
    t0 = time.perf_counter()
    for _ in range(reps // 2):
        problem.W @ x0
        problem.WT @ y
    t_prod = (time.perf_counter() - t0) / reps
    nnz = problem.W.nnz
    moved = 20 * nnz + 8 * (problem.n_terms + problem.n_cells) + 8 * problem.n_terms
    return {
        "readings": len(r),
        "terms": problem.n_terms,
        "entries": nnz,
        "build_s": t_build,
        "total_s": t_total,
        "iterations": n_iter,
        "agreement": agree,
        "cells_compared": n_cells,
        "f1_offline": score(sc.truth, offline).f1_all,
        "f1_streamed": score(sc.truth, streamed).f1_all,
        "product_s": t_prod,
        "product_bandwidth_fraction": moved / t_prod / bandwidth,
    }


def run(
    minutes: float, stochastic_minutes: float, bandwidth: float, offline_minutes: float = 2.0
) -> dict[str, Any]:
    _log(f"simulating the office scenario, {minutes:g} min")
    t0 = time.perf_counter()
    sc = make_scenario("office", duration=60.0 * minutes)
    _log(f"simulated {len(sc.readings):,} readings in {time.perf_counter() - t0:.0f} s")
    rows = stream_rows(sc, stochastic_minutes)
    prefixes = sorted({minutes / 4, minutes / 2, minutes})
    mem = memory_rows(sc, prefixes)
    out: dict[str, Any] = {"stream": rows, "memory": mem}
    if offline_minutes > 0:
        out["offline"] = offline_rows(sc, min(offline_minutes, minutes), bandwidth)
    return out


def print_tables(res: dict[str, Any], console: Console) -> None:
    t = Table(
        "method (strategy)",
        "readings",
        "wall [s]",
        "x real time",
        "median [ms]",
        "p99 [ms]",
        "in play",
        "state [MB]",
        "wall F1",
        title=f"streaming: office, 16-sonar ring at 20 Hz, update every {PERIOD} s of log",
    )
    for s in res["stream"]:
        t.add_row(
            f"{s['method']} ({s['strategy']})",
            f"{s['readings']:,}",
            f"{s['wall_seconds']:.1f}",
            f"{s['realtime_factor']:.1f}",
            f"{s['latency_median_ms']:.1f}",
            f"{s['latency_p99_ms']:.1f}",
            f"{s['max_readings_in_play']:,}",
            f"{s['max_state_mb']:.0f}",
            f"{s['f1']:.3f}",
        )
    console.print(t)
    m = Table(
        "log [min]",
        "readings",
        "peak RSS [MB]",
        "state [MB]",
        "in play",
        "x real time",
        title=f"memory against log length: sonarmap stream --method gradient "
        f"(default {DEFAULT_STRATEGY['gradient']}), fresh process each",
    )
    for row in res["memory"]:
        m.add_row(
            f"{row['minutes']:g}",
            f"{row['readings']:,}",
            f"{row['peak_rss_mb']:.0f}",
            f"{row['state_mb']:.1f}",
            f"{row['in_play']:,}",
            f"{row['realtime_factor']:.1f}",
        )
    console.print(m)
    if "offline" in res:
        o = res["offline"]
        console.print(
            f"offline gradient over the first {o['readings']:,} readings "
            f"({o['entries']:,} entries): "
            f"{o['total_s']:.0f} s ({o['iterations']} iterations); streaming map agrees on "
            f"{100 * o['agreement']:.2f} % of {o['cells_compared']:,} cells; F1 offline "
            f"{o['f1_offline']:.3f}, streamed {o['f1_streamed']:.3f}; one sparse product "
            f"{1e3 * o['product_s']:.0f} ms = {100 * o['product_bandwidth_fraction']:.0f} % "
            "of copy bandwidth"
        )


def main() -> None:
    from benchmarks.run import copy_bandwidth

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--stochastic-minutes", type=float, default=2.0)
    parser.add_argument(
        "--offline-minutes", type=float, default=2.0, help="0: no offline comparison"
    )
    parser.add_argument("--json")
    args = parser.parse_args()
    bw = copy_bandwidth(3)
    res = run(args.minutes, args.stochastic_minutes, bw, offline_minutes=args.offline_minutes)
    print_tables(res, Console(width=150))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2, default=float))


if __name__ == "__main__":
    main()
