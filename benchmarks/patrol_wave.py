"""The patrol wave on the thesis's Table 4 map: the bucket-queue wave against the former
binary-heap one.

The built-in ``fig3-10`` map (240 x 159 m, buildings and narrow lanes) drawn at 10 cm
(the thesis's pixel) and coarsened to cells of 0.1, 0.2, 0.25 and 0.5 m
(``Territory.from_map(m, cell=...)``; 0.25 m is not a whole number of 10 cm pixels, so
that row is coarsened from a 5 cm drawing). Paths run over the cells a robot of radius
1 m may occupy (``passable(1.0)``) and end on any free cell, as in the simulator. One
wave is run from each of the map's five robot starts (Table 4's largest team); a figure
is the mean over the five of the best of ``--repeat`` runs, in ms per wave:

- ``heap``: the former kernel (binary heap with lazy deletion), kept here for comparison,
  with the simulator's step rule (a target cell off the passable ones ends a path);
- ``wave()``: the bucket-queue wave, allocating its arrays on each call;
- ``Wave``: the same reusing its buffers (only the cells the last wave reached are
  cleared);
- ``wave(), 50 m`` and ``Wave, 50 m``: stopped at 50 m of path (``limit=50``), with the
  cells it reached.

The heap and bucket waves are checked to agree on every distance (to 1e-9 m) before
timing. The time budget of the target (one simulated hour in 3 minutes, 7200 steps of
0.5 s, five robots) is about 5 ms per wave.

Run with ``python -m benchmarks.patrol_wave [--repeat 5] [--cells 0.1,0.2,0.25,0.5]
[--json out.json]`` (``--cells``: the cell sizes, metres, comma-separated).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from collections.abc import Callable
from functools import partial
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numba as nb
import numpy as np
import numpy.typing as npt
from rich.console import Console
from rich.table import Table

from sonarmap.patrol.maps import builtin_map
from sonarmap.patrol.paths import STEPS, Wave, wave
from sonarmap.patrol.territory import Territory

CELLS = (0.1, 0.2, 0.25, 0.5)
LIMIT = 50.0
RADIUS = 1.0


@nb.njit(cache=True)
def _wave_heap(
    passable: npt.NDArray[np.bool_],
    target: npt.NDArray[np.bool_],
    r0: int,
    c0: int,
    steps: npt.NDArray[np.int64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
    """The former wave: Dijkstra with a binary heap of (distance, cell) and lazy
    deletion, distances in cells (as in ``sonarmap.patrol.paths`` before the bucket
    queue), with today's step rule: paths cross passable cells only and take one last
    step onto a target cell."""
    rows, cols = passable.shape
    dist = np.full((rows, cols), np.inf)
    first = np.full((rows, cols), -1, dtype=np.int8)
    cap = 8 * rows * cols + 1
    hd = np.empty(min(cap, 1 << 26), dtype=np.float64)
    hc = np.empty(hd.shape[0], dtype=np.int64)
    dist[r0, c0] = 0.0
    hd[0] = 0.0
    hc[0] = r0 * cols + c0
    size = 1
    diag = math.sqrt(2.0)
    while size > 0:
        d = hd[0]
        cell = hc[0]
        size -= 1
        if size > 0:
            ld = hd[size]
            lc = hc[size]
            i = 0
            while True:
                j = 2 * i + 1
                if j >= size:
                    break
                if j + 1 < size and hd[j + 1] < hd[j]:
                    j += 1
                if hd[j] >= ld:
                    break
                hd[i] = hd[j]
                hc[i] = hc[j]
                i = j
            hd[i] = ld
            hc[i] = lc
        r = cell // cols
        c = cell % cols
        if d > dist[r, c]:
            continue
        if not passable[r, c]:
            # A target cell off the passable ones ends its path (the simulator's rule
            # since the wave took one last step onto a target cell, never across them).
            continue
        for k in range(8):
            rr = r + steps[k, 0]
            cc = c + steps[k, 1]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols or not target[rr, cc]:
                continue
            if k % 2 == 1:
                if not target[r, cc] or not target[rr, c]:
                    continue
                if passable[rr, cc] and (not passable[r, cc] or not passable[rr, c]):
                    continue
                nd = d + diag
            else:
                nd = d + 1.0
            if nd < dist[rr, cc]:
                dist[rr, cc] = nd
                first[rr, cc] = k if (r == r0 and c == c0) else first[r, c]
                if size >= hd.shape[0]:
                    nh = np.empty(hd.shape[0] * 2, dtype=np.float64)
                    nc = np.empty(hd.shape[0] * 2, dtype=np.int64)
                    nh[:size] = hd[:size]
                    nc[:size] = hc[:size]
                    hd = nh
                    hc = nc
                i = size
                size += 1
                while i > 0:
                    p = (i - 1) // 2
                    if hd[p] <= nd:
                        break
                    hd[i] = hd[p]
                    hc[i] = hc[p]
                    i = p
                hd[i] = nd
                hc[i] = rr * cols + cc
    return dist, first


def heap_wave(
    passable: npt.NDArray[np.bool_],
    start: tuple[int, int],
    resolution: float,
    target: npt.NDArray[np.bool_] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
    """The former ``wave`` (same arguments, no limit)."""
    ok = np.ascontiguousarray(passable)
    tg = ok if target is None else np.ascontiguousarray(target | passable)
    dist, first = _wave_heap(ok, tg, int(start[0]), int(start[1]), STEPS)
    return dist * resolution, first


def best_ms(fn: Callable[[], Any], repeat: int) -> float:
    fn()  # warm-up: JIT compilation and caches
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return 1e3 * best


def territory(cell: float) -> Territory:
    """fig3-10 coarsened to ``cell`` metres from a drawing at 10 cm (5 cm when ``cell``
    is not a whole number of 10 cm pixels)."""
    plan = builtin_map("fig3-10").plan
    base = 0.1 if abs(cell / 0.1 - round(cell / 0.1)) < 1e-9 else 0.05
    return Territory.from_map(plan.render(plan.grid(base)), cell=cell)


def starts(t: Territory, passable: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """The map's robot starts (dm from the top-left, y down) as cells, each moved to the
    nearest passable cell."""
    top = t.grid.origin[1] + t.grid.rows * t.grid.resolution
    free_rc = np.argwhere(passable)
    out = []
    for x_dm, y_dm, _phi in builtin_map("fig3-10").starts:
        r, c = t.cell_of(t.grid.origin[0] + x_dm / 10, top - y_dm / 10)
        k = int(np.argmin((free_rc[:, 0] - int(r)) ** 2 + (free_rc[:, 1] - int(c)) ** 2))
        out.append((int(free_rc[k, 0]), int(free_rc[k, 1])))
    return out


def run(cells: tuple[float, ...], repeat: int) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for cell in cells:
        t = territory(cell)
        passable = t.passable(RADIUS)
        res = t.grid.resolution
        w = Wave(passable.shape)
        times: dict[str, list[float]] = {
            k: [] for k in ("heap", "wave", "Wave", "wave_limit", "limit")
        }
        reached = []
        for st in starts(t, passable):
            d_old, _ = heap_wave(passable, st, res, t.free)
            d_new, _ = wave(passable, st, res, t.free)
            fin = np.isfinite(d_old)
            assert np.array_equal(fin, np.isfinite(d_new))
            assert np.allclose(d_old[fin], d_new[fin], rtol=0.0, atol=1e-9)

            runs = {
                "heap": partial(heap_wave, passable, st, res, t.free),
                "wave": partial(wave, passable, st, res, t.free),
                "Wave": partial(w, passable, st, res, t.free),
                "wave_limit": partial(wave, passable, st, res, t.free, limit=LIMIT),
                "limit": partial(w, passable, st, res, t.free, limit=LIMIT),
            }
            for key, fn in runs.items():
                times[key].append(best_ms(fn, repeat))
            reached.append(len(w.reached()[0]))
        row = {
            "cell": res,
            "shape": list(passable.shape),
            "free": int(t.free.sum()),
            "passable": int(passable.sum()),
            "reached_limit": float(np.mean(reached)),
        }
        row.update({f"ms_{k}": float(np.mean(v)) for k, v in times.items()})
        rows.append(row)
    return rows


def print_table(rows: list[dict[str, Any]], console: Console) -> None:
    table = Table(
        "cell [m]",
        "grid",
        "free cells",
        "passable",
        "heap [ms]",
        "wave() [ms]",
        "Wave [ms]",
        "speed-up",
        f"wave(), {LIMIT:g} m [ms]",
        f"Wave, {LIMIT:g} m [ms]",
        f"cells within {LIMIT:g} m",
        title=f"patrol wave on fig3-10, ms per wave (mean of the 5 starts; one core, "
        f"{platform.machine()})",
    )
    for r in rows:
        table.add_row(
            f"{r['cell']:g}",
            f"{r['shape'][0]} x {r['shape'][1]}",
            f"{r['free']:,}",
            f"{r['passable']:,}",
            f"{r['ms_heap']:.1f}",
            f"{r['ms_wave']:.1f}",
            f"{r['ms_Wave']:.1f}",
            f"{r['ms_heap'] / r['ms_Wave']:.1f} x",
            f"{r['ms_wave_limit']:.2f}",
            f"{r['ms_limit']:.2f}",
            f"{r['reached_limit']:,.0f}",
        )
    console.print(table)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=5, help="best of this many runs")
    parser.add_argument("--cells", default=",".join(f"{c:g}" for c in CELLS), help="cell sizes [m]")
    parser.add_argument("--json", help="Also write the results to this JSON file.")
    args = parser.parse_args(argv)
    cells = tuple(float(c) for c in args.cells.split(","))
    rows = run(cells, args.repeat)
    print_table(rows, Console(width=160))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": platform.platform(), "results": rows}, f, indent=2)


if __name__ == "__main__":
    main()
