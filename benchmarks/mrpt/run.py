"""Side by side with MRPT: sonar insertion into an occupancy grid, same readings.

MRPT's ``COccupancyGridMap2D`` inserts a ``CObservationRange`` with a cone model (a free
triangle up to the range, an occupied arc at it). ``sonar_insert.cpp`` (ours, built here
against the Debian packages) feeds it the readings one observation each and times the
insertion loop; sonarmap's inverse mapper (rasteriser included) is timed on the same
readings, and the two maps are compared cell by cell and against the truth.

Run with ``python -m benchmarks.mrpt.run [--install] [--minutes 2] [--scene office]
[--repeat 3] [--json F]`` (``make bench-mrpt``: ``--install --minutes 10``).
``--install`` installs ``libmrpt-maps-dev``, ``libmrpt-obs-dev`` and ``g++`` with apt
(root needed). Without MRPT the command says so and exits with status 77.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numba
import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import make_mapper
from sonarmap.metrics import agreement, score
from sonarmap.raster import rasterise
from sonarmap.scenarios import Scenario, make_scenario

HERE = Path(__file__).resolve().parent
HEADER = Path("/usr/include/mrpt/maps/include/mrpt/maps/COccupancyGridMap2D.h")
PACKAGES = ["libmrpt-maps-dev", "libmrpt-obs-dev", "g++"]
LIBS = [
    "mrpt-maps",
    "mrpt-obs",
    "mrpt-poses",
    "mrpt-math",
    "mrpt-core",
    "mrpt-serialization",
    "mrpt-rtti",
    "mrpt-system",
    "mrpt-img",
    "mrpt-config",
]
SKIP = 77


def available() -> bool:
    """Whether MRPT's headers and a C++ compiler are installed."""
    return HEADER.exists() and shutil.which("g++") is not None


def install() -> None:
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run(["apt-get", "update", "-qq"], check=True, env=env)
    subprocess.run(
        ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *PACKAGES],
        check=True,
        env=env,
    )


def build(out_dir: Path) -> Path:
    """Compile the harness against MRPT; returns the executable."""
    includes = [f"-I{p}" for p in sorted(Path("/usr/include/mrpt").glob("*/include"))]
    exe = out_dir / "sonar_insert"
    cmd = [
        "g++",
        "-O2",
        "-std=c++17",
        *includes,
        str(HERE / "sonar_insert.cpp"),
        "-o",
        str(exe),
        *[f"-l{lib}" for lib in LIBS],
    ]
    subprocess.run(cmd, check=True)
    return exe


def run_mrpt(exe: Path, sc: Scenario, work: Path, repeat: int) -> tuple[float, OccupancyMap]:
    r, g, s = sc.readings, sc.truth.grid, sc.rig.sensor
    data = np.column_stack([r.x, r.y, r.theta, r.range]).astype(np.float64)
    src = work / "readings.bin"
    data.tofile(src)
    out = work / "map.bin"
    # MRPT's model is a cone: the beam's full opening, read off its outline.
    pts = s.beam.outline[np.hypot(*s.beam.outline.T) > 0]
    cone = math.degrees(2 * float(np.abs(np.arctan2(pts[:, 1], pts[:, 0])).max()))
    args = [
        str(exe),
        str(src),
        str(len(r)),
        repr(g.origin[0]),
        repr(g.origin[1]),
        str(g.cols),
        str(g.rows),
        repr(g.resolution),
        repr(cone),
        repr(s.r_min),
        repr(s.r_max),
        str(out),
    ]
    best = math.inf
    for _ in range(repeat):
        done = subprocess.run(args, capture_output=True, text=True, check=True)
        best = min(best, float(done.stdout.split("insert_seconds")[1].split()[0]))
    # MRPT's cells hold the probability of being free; it starts every cell at 0.5 and
    # has no separate "unknown".
    free = np.fromfile(out, dtype=np.float32).reshape(g.shape)
    occ = np.where(free == 0.5, np.nan, 1.0 - free).astype(np.float32)
    return best, OccupancyMap(g, occ)


def run_ours(
    sc: Scenario, repeat: int, threads: int = 1, **params: Any
) -> tuple[float, OccupancyMap]:
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        mapper = make_mapper("inverse", **params)
        warm = sc.readings.take(np.arange(min(1000, len(sc.readings))))
        mapper.fit(warm, sc.truth.grid, sc.rig)
        best = math.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            mapper.fit(sc.readings, sc.truth.grid, sc.rig)
            best = min(best, time.perf_counter() - t0)
    finally:
        numba.set_num_threads(before)
    return best, mapper.result()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--install", action="store_true", help="apt-get install MRPT first")
    parser.add_argument("--minutes", type=float, default=2.0, help="office log length")
    parser.add_argument("--scene", default="office", help="built-in scenario")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    if args.install and not available():
        install()
    if not available():
        print(
            "MRPT is not installed (needs libmrpt-maps-dev, libmrpt-obs-dev, g++); "
            "run with --install",
            file=sys.stderr,
        )
        return SKIP
    params: dict[str, Any] = {"duration": 60.0 * args.minutes} if args.scene == "office" else {}
    sc = make_scenario(args.scene, **params)
    r = sc.readings
    fp = rasterise(sc.truth.grid, sc.rig.sensor, r.x, r.y, r.theta, r.range)
    with tempfile.TemporaryDirectory() as tmp:
        exe = build(Path(tmp))
        t_mrpt, m_mrpt = run_mrpt(exe, sc, Path(tmp), args.repeat)
    t_ours, m_ours = run_ours(sc, args.repeat)
    # The tuned default weighs cells by their angle off the axis; the same kernel
    # without the fall-off shows what that weighting costs.
    t_flat, m_flat = run_ours(sc, args.repeat, falloff_deg=0.0)
    # MRPT's default increments in our terms: free logit(0.35), occupied 3 logit(0.65).
    p_occ = 1 / (1 + math.exp(-3 * math.log(0.65 / 0.35)))
    t_like, m_like = run_ours(sc, args.repeat, p_occ=p_occ, p_free=0.35, falloff_deg=0.0)
    cores = int(os.environ.get("NUMBA_NUM_THREADS", os.cpu_count() or 1))
    fall = make_mapper("inverse").get_params()["falloff_deg"]
    entries = [
        ("MRPT COccupancyGridMap2D (defaults), 1 thread", t_mrpt, m_mrpt),
        (f"sonarmap inverse (defaults: {fall:g}-degree fall-off), 1 thread", t_ours, m_ours),
        ("sonarmap inverse (no fall-off), 1 thread", t_flat, m_flat),
        ("sonarmap inverse (MRPT's increments, no fall-off), 1 thread", t_like, m_like),
    ]
    if cores > 1:
        t_par, m_par = run_ours(sc, args.repeat, threads=cores)
        entries.append((f"sonarmap inverse (defaults), {cores} threads", t_par, m_par))
    rows: list[dict[str, Any]] = []
    for name, t, m in entries:
        agree, n = agreement(m, m_mrpt)
        rows.append(
            {
                "mapper": name,
                "seconds": t,
                "readings_per_s": len(r) / t,
                "ratio_to_mrpt": t_mrpt / t,
                "agreement_with_mrpt": agree,
                "cells_compared": n,
                "f1": score(sc.truth, m).f1_all,
            }
        )
    table = Table(
        "mapper",
        "time [s]",
        "readings/s",
        "x MRPT",
        "agrees with MRPT",
        "wall F1",
        title=f"sonar insertion, {len(r):,} readings of the {args.scene} scene "
        f"({sc.truth.grid.cols} x {sc.truth.grid.rows} cells; sonarmap touches "
        f"{fp.n_entries / len(r):.0f} cells per reading)",
    )
    for row in rows:
        table.add_row(
            row["mapper"],
            f"{row['seconds']:.3f}",
            f"{row['readings_per_s']:,.0f}",
            f"{row['ratio_to_mrpt']:.2f}",
            f"{100 * row['agreement_with_mrpt']:.1f} %",
            f"{row['f1']:.3f}",
        )
    Console(width=150).print(table)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
