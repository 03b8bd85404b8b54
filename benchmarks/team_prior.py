"""What an imprecise prior map costs one robot (issue 37 item 6).

For each map and each prior error (``--errors``, each a ``team run --prior-error`` spec;
``none`` is the truth as the prior), one robot's mission of ``--duration`` seconds (1200)
runs as ``sonarmap team run --map MAP --duration D [--prior-error SPEC] -o OUT/NAME__TAG``
(a run whose ``summary.json`` is already there is read, not run again), and a Markdown
table gives what the error changed on the map (doorways closed and opened, furniture
left out, cells changed, how far the scale moves the farthest corner) and the mission's
scores against the truth: ATE (odometry's), the alignment's error (metres, degrees), the
map's wall F1 (at the true poses), closures found, regions.

Each run's recorded prior is checked against :func:`~sonarmap.team.prior.degrade_plan`
made again now, so that a table never mixes runs of different code.

Run with ``python -m benchmarks.team_prior --out DIR [--maps depot.yaml building:0]
[--errors none close-doors=2 ...] [--duration 1200] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from sonarmap.cli.common import resolve_map
from sonarmap.team.prior import degrade_plan, parse_prior_error

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "maps"
MAPS = [str(SHARED / "depot.yaml"), "building:0", str(SHARED / "tb3_sandbox.yaml"),
        str(SHARED / "warehouse.yaml")]  # fmt: skip
ALL = "close-doors=2,open-doors=2,furniture=3,scale=0.03"
ERRORS = ["none", "close-doors=2", "open-doors=2", "furniture=3", "scale=0.03", "scale=0.08", ALL]


def run_name(map_: str, error: str) -> str:
    """``NAME__TAG`` of one run's folder: the map's file stem (``building0`` for
    ``building:0``), the spec with ``,`` and ``=`` as ``_``."""
    stem = Path(map_).stem if map_.endswith(".yaml") else map_
    tag = error.replace(",", "_").replace("=", "_")
    return f"{stem.replace(':', '')}__{tag}"


def run(map_: str, error: str, out: Path, duration: float, seed: int) -> dict[str, Any]:
    """One mission's summary, run unless already there."""
    folder = out / run_name(map_, error)
    if not (folder / "summary.json").exists():
        cmd = [sys.executable, "-m", "sonarmap", "team", "run", "--map", map_,
               "--duration", f"{duration:g}", "--seed", str(seed), "-o", str(folder)]  # fmt: skip
        if error != "none":
            cmd += ["--prior-error", error]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, timeout=3600)
    s: dict[str, Any] = json.loads((folder / "summary.json").read_text())
    return s


def check_recorded(map_: str, error: str, summary: dict[str, Any], seed: int) -> None:
    """Refuse a run whose recorded prior the current code would not make."""
    if error == "none":
        if "prior" in summary:
            raise SystemExit(f"{map_} none: the run had a prior")
        return
    _, report = degrade_plan(resolve_map(Path(map_)), parse_prior_error(error, seed=seed))
    now, then = report.to_dict(), summary["prior"]
    for key in ("cells_changed", "doors_closed", "doors_opened", "furniture_dropped"):
        if now[key] != then[key]:
            raise SystemExit(f"{map_} {error}: recorded {key} {then[key]} != {now[key]} now")


def _f(v: Any, digits: int = 3) -> str:
    return "nan" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def row(map_: str, error: str, s: dict[str, Any]) -> str:
    """One Markdown row."""
    r = s["robots"][0]
    p = s.get("prior")
    if p is None:
        change = "-"
    else:
        change = (
            f"{len(p['doors_closed'])}/{p['doors_found']} closed, "
            f"{len(p['doors_opened'])} opened, "
            f"{len(p['furniture_dropped'])}/{p['furniture_found']} furniture, "
            f"{p['cells_changed']} cells, {p['scale_shift_max_m']:.2f} m"
        )
    name = Path(map_).stem if map_.endswith(".yaml") else map_
    return (
        f"| {name} | {error} | {change} | {_f(r['ate_m'])} ({_f(r['ate_odometry_m'])}) | "
        f"{_f(r['alignment_error_m'], 2)} / {_f(r['alignment_error_deg'], 1)} | "
        f"{_f(r['map_f1'])} ({_f(r['map_f1_true_poses'])}) | "
        f"{r['closures_found']}/{r['closures_correct']} | {r['regions']} |"
    )


HEADER = (
    "| map | prior error | changed (doorways closed/found, opened, furniture left out/found, "
    "cells, scale shift of the far corner) | ATE m (odometry) | alignment error m / deg | "
    "map F1 (true poses) | closures found/correct | regions |\n|---|---|---|---|---|---|---|---|"
)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--maps", nargs="+", default=MAPS)
    ap.add_argument("--errors", nargs="+", default=ERRORS)
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(HEADER)
    for map_ in a.maps:
        for error in a.errors:
            s = run(map_, error, a.out, a.duration, a.seed)
            check_recorded(map_, error, s, a.seed)
            print(row(map_, error, s), flush=True)


if __name__ == "__main__":
    main()
