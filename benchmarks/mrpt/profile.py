"""What the inverse insertion's time goes to, on the readings ``make bench-mrpt`` times.

Runs the insertion kernel (``accumulate_kernel``, one thread) on the office ring's echoes
at the inverse mapper's defaults, and on variants that each change one part of its work:

- ``positive=False``: every cell's weight computed, also in blocks whose cells all hold
  the clamp bound their increment pushes towards (the kernel before that skip);
- ``runs=False``: every centre decided by its distance (the kernel before the runs);
- the 10-degree fall-off (a 13-term polynomial; the defaults' 5 degrees take 21);
- no fall-off (uniform increments);
- the fall-off's polynomial cut to fewer terms: the weights are then wrong, so these rows
  time the polynomial's terms and nothing else.

With ``--held`` it also counts, reading by reading, the updates that find their cell at
the clamp bound their increment pushes towards, and the blocks of LANES cells (from each
row's first cell, as the runs form them) whose cells all do: the blocks the defaults
skip the weights of.

Each figure is the sum, over chunks of 500 readings, of the fastest of ``--repeat`` runs of
the chunk, the variants run in turn chunk by chunk: on a machine shared with other jobs the
fastest run of a short chunk is the one nothing interrupted. The chunks' numba calls add a
fixed overhead (a few ms in all) that a single call, as the mapper makes, does not have.

``--against FILE`` times another tree's kernel module (such as main's: ``git archive main
src | tar -x -C /tmp/base``, then ``--against /tmp/base/src/sonarmap/_raster_kernel.py``)
at the defaults and without the fall-off, in the same process, on the same chunks.

Run with ``python -m benchmarks.mrpt.profile [--minutes 2] [--repeat 5] [--held] [--clock
thread] [--against FILE]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numba
import numpy as np
import numpy.typing as npt
from rich.console import Console
from rich.table import Table

from sonarmap._raster_kernel import LANES
from sonarmap._raster_kernel import accumulate_kernel as _kernel
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.raster import Footprint, default_dr, falloff_fit, falloff_positive, rasterise
from sonarmap.scenarios import make_scenario

CHUNK = 500
# Called with a list of arguments: typed loosely.
kernel: Any = _kernel


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class Inputs(NamedTuple):
    """What the inverse mapper at its defaults gives the kernel."""

    args: list[Any]
    kw: dict[str, Any]
    n: int
    grid: Grid
    # The readings' cells from the rasteriser (when asked for): the kernel's cells.
    footprint: Footprint | None


def kernel_args(minutes: float, footprint: bool = False) -> Inputs:
    """The kernel's arguments for ``minutes`` of the office ring (its echoes: the
    defaults ignore no-echo readings)."""
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
    fp = None
    if footprint:
        fp = rasterise(grid, sensor, r.x, r.y, r.theta, r.range, dr=dr, offset=offset)
    return Inputs(args, {"positive": falloff_positive(sensor, falloff)}, len(r), grid, fp)


# A kernel's arguments, positional and keyword, and the kernel (None: this tree's).
Case = tuple[list[Any], dict[str, Any], Any]


def variants(args: list[Any], kw: dict[str, Any], coef10: tuple[float, ...]) -> dict[str, Case]:
    """The defaults (``args``, ``kw``) and the variants, each as its arguments;
    ``coef10`` is the 10-degree fall-off's polynomial."""
    coef = args[19]
    flat = [*args[:18], 0.0, ()]
    every = {**kw, "positive": False}
    deg = math.degrees(args[18])
    return {
        f"defaults: runs, {deg:g}-degree fall-off ({len(coef)} terms), held blocks skipped": (
            args,
            kw,
            None,
        ),
        "runs, fall-off, every weight computed": (args, every, None),
        "per-cell distance test (runs=False), fall-off, held blocks skipped": (
            args,
            {**kw, "runs": False},
            None,
        ),
        "per-cell distance test (runs=False), fall-off, every weight": (
            args,
            {**every, "runs": False},
            None,
        ),
        f"runs, 10-degree fall-off ({len(coef10)} terms), held blocks skipped": (
            [*args[:18], math.radians(10.0), coef10],
            kw,
            None,
        ),
        f"runs, 10-degree fall-off ({len(coef10)} terms), every weight": (
            [*args[:18], math.radians(10.0), coef10],
            every,
            None,
        ),
        "runs, fall-off cut to 7 terms, every weight (timing only)": (
            [*args[:19], coef[:7]],
            every,
            None,
        ),
        "runs, fall-off cut to 2 terms, every weight (timing only)": (
            [*args[:19], coef[:2]],
            every,
            None,
        ),
        "runs, no fall-off": (flat, {}, None),
        "per-cell distance test (runs=False), no fall-off": (flat, {"runs": False}, None),
    }


def foreign_kernel(path: Path) -> Any:
    """``accumulate_kernel`` of the kernel module at ``path``, compiled afresh (numba's
    cache would look for it under a module name it does not have)."""
    module = types.ModuleType("_against_raster_kernel")
    module.__file__ = str(path)
    source = path.read_text().replace("cache=True", "cache=False")
    exec(compile(source, str(path), "exec"), module.__dict__)
    return module.accumulate_kernel


def chunked(
    cases: dict[str, Case], n: int, repeat: int, clock: Callable[[], float] = time.perf_counter
) -> dict[str, float]:
    """Each case's time in seconds (summed chunk minima) on ``clock``.

    Each case inserts into a map of its own, and every run of a chunk starts from the
    map the chunks before it left (a copy, outside the timing): the kernel's work
    depends on the map (cells held at a clamp bound skip their weights), so each run
    sees the map one insertion of the whole log would.
    """
    total = dict.fromkeys(cases, 0.0)
    maps = {name: (np.zeros_like(a[0]), np.zeros_like(a[1])) for name, (a, _, _) in cases.items()}
    for lo in range(0, n, CHUNK):
        hi = min(n, lo + CHUNK)
        best = dict.fromkeys(cases, math.inf)
        latest = dict(maps)
        for _ in range(repeat):
            for name, (args, kw, other) in cases.items():
                run = kernel if other is None else other
                a = list(args)
                a[0], a[1] = maps[name][0].copy(), maps[name][1].copy()
                for k in (7, 8, 9, 10, 11):
                    a[k] = np.ascontiguousarray(args[k][lo:hi])
                t0 = clock()
                run(*a, **kw)
                best[name] = min(best[name], clock() - t0)
                latest[name] = (a[0], a[1])
        maps.update(latest)
        for name in cases:
            total[name] += best[name]
    return total


@numba.njit(cache=True)
def _held_counts(
    values: npt.NDArray[np.float64],
    cols: int,
    cells: npt.NDArray[np.int64],
    incs: npt.NDArray[np.float64],
    lo: float,
    hi: float,
) -> tuple[int, int, int]:
    """Held updates, blocks and held blocks of one reading, ``cells`` sorted."""
    held = 0
    blocks = 0
    held_blocks = 0
    k = 0
    while k < cells.shape[0]:
        row = cells[k] // cols
        first = cells[k]
        all_held = True
        while k < cells.shape[0] and cells[k] // cols == row and cells[k] < first + LANES:
            v = values[cells[k]]
            h = (v == lo and incs[k] < 0.0) or (v == hi and incs[k] > 0.0)
            held += h
            all_held = all_held and h
            k += 1
        blocks += 1
        held_blocks += all_held
    return held, blocks, held_blocks


def held_share(inputs: Inputs) -> tuple[float, float]:
    """Shares of the updates, and of the blocks, that find their cells held at a clamp
    bound, the readings inserted one at a time by the kernel at the defaults."""
    fp = inputs.footprint
    assert fp is not None
    a = list(inputs.args)
    a[0] = np.zeros_like(a[0])
    a[1] = np.zeros_like(a[1])
    inc_free, inc_occ, lo, hi = a[14:18]
    totals = np.zeros(4, dtype=np.int64)
    for i in range(inputs.n):
        free, occ = fp.free.of(i), fp.occ.of(i)
        cells = np.concatenate([free, occ]).astype(np.int64)
        incs = np.concatenate([np.full(len(free), inc_free), np.full(len(occ), inc_occ)])
        order = np.argsort(cells, kind="stable")
        held, blocks, held_blocks = _held_counts(
            a[0], inputs.grid.cols, cells[order], incs[order], lo, hi
        )
        totals += (held, len(cells), blocks, held_blocks)
        for k in (7, 8, 9, 10, 11):
            a[k] = np.ascontiguousarray(inputs.args[k][i : i + 1])
        kernel(*a, **inputs.kw)
    return float(totals[0] / totals[1]), float(totals[3] / totals[2])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=2.0, help="office log length")
    parser.add_argument("--repeat", type=int, default=5, help="runs of each chunk")
    parser.add_argument("--held", action="store_true", help="count the held cells too")
    parser.add_argument(
        "--against",
        type=Path,
        help="another tree's _raster_kernel.py (such as main's, from git archive), timed "
        "at the defaults in the same process",
    )
    parser.add_argument(
        "--clock",
        choices=("wall", "thread"),
        default="wall",
        help="wall time, or this thread's CPU time (leaves out the time a virtual "
        "machine's host gives other guests, which a shared machine has plenty of)",
    )
    a = parser.parse_args(argv)
    if a.minutes <= 0 or a.repeat < 1:
        print("--minutes must be > 0 and --repeat >= 1", file=sys.stderr)
        return 2
    if a.against is not None and not a.against.is_file():
        print(f"--against: no file {a.against}", file=sys.stderr)
        return 2
    numba.set_num_threads(1)
    inputs = kernel_args(a.minutes, footprint=a.held)
    sensor = make_scenario("office", duration=1.0).rig.sensor
    cases = variants(inputs.args, inputs.kw, falloff_fit(sensor, math.radians(10.0))[1])
    # Compile every variant before timing; count the cell updates once.
    if a.against is not None:
        # Without the skip's keyword: a kernel from before it computes every weight.
        other = foreign_kernel(a.against)
        cases[f"{a.against}: defaults"] = (inputs.args, {}, other)
        cases[f"{a.against}: no fall-off"] = ([*inputs.args[:18], 0.0, ()], {}, other)
    for case_args, kw, other in cases.values():
        fresh = list(case_args)
        fresh[0] = np.zeros_like(case_args[0])
        fresh[1] = np.zeros_like(case_args[1])
        cells = (kernel if other is None else other)(*fresh, **kw)
    clock = time.thread_time if a.clock == "thread" else time.perf_counter
    result = chunked(cases, inputs.n, a.repeat, clock)
    table = Table(
        "kernel",
        f"{a.clock} time \\[ms]",
        "ns / cell update",
        title=f"inverse insertion, {inputs.n:,} echoes of {a.minutes:g} min of the office "
        f"ring, {cells:,} cell updates, one thread",
    )
    for name, t in result.items():
        table.add_row(name, f"{1e3 * t:.1f}", f"{1e9 * t / cells:.2f}")
    Console(width=120).print(table)
    if a.held:
        updates, blocks = held_share(inputs)
        print(
            f"updates finding their cell at the bound their increment pushes towards: "
            f"{100 * updates:.1f} %; blocks of {LANES} whose cells all do: {100 * blocks:.1f} %"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
