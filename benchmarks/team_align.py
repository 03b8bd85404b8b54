"""What the alignment of one robot's fused map to the prior costs, and how far it is off.

One robot, one mission on a map (``--duration``, default 1,200 s, the defaults of
:class:`~sonarmap.team.mission.MissionConfig`); its last batch and fused map as
``RobotAgent.finish`` makes them; then :func:`~sonarmap.team.globalmap.align_to_prior`
once per ``--coarse`` value (metres; the prior's own resolution gives the search without
pooling), each timed, its peak of traced memory (numpy's and scipy's arrays, by
:mod:`tracemalloc`) and its error against the true alignment (mean over the own layer's
poses, like ``summary.json``'s ``alignment_error_m``). Also the fused map's wall F1
placed by the found alignment and by the true one: when the trajectory is bent, the
true alignment can score lower than the found one, which then is not the alignment's
fault.

Run with ``python -m benchmarks.team_align --map PLAN [--duration 1200] [--seed 0]
[--coarse 0.1 ...]``; prints JSON. What a search at a fine prior's own resolution
costs is on the results page (docs/results/2026-12-06-team-real-maps-align.md).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
import tracemalloc
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from sonarmap.cli.common import resolve_map
from sonarmap.metrics import score
from sonarmap.team.globalmap import fuse_local_maps, grid_around
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.records import compose


def trace(plan_path: str, duration: float, seed: int, coarse: Sequence[float]) -> dict[str, Any]:
    """Run the mission, then align its fused map once per coarse cell (see the notes)."""
    plan = resolve_map(Path(plan_path))
    cfg = MissionConfig(duration=duration, seed=seed)
    agent = RobotAgent(plan, cfg)
    while not agent.done:
        agent.step()
    graph = agent.batch()
    poses = agent.all_poses()
    est = graph.estimates
    built = fuse_local_maps(
        poses, est, grid_around(est, cfg.local_size / 2, cfg.map_resolution, margin=1.0)
    )
    a_true = agent.sensing.a_true
    kept = np.array([est[u] for u in agent.store.local.poses])

    def error(a: np.ndarray[Any, Any]) -> tuple[float, float]:
        placed, should = compose(a, kept), compose(a_true, kept)
        metres = float(np.mean(np.hypot(*(placed[:, :2] - should[:, :2]).T)))
        return metres, math.degrees(abs(math.remainder(float(a[2] - a_true[2]), 2 * math.pi)))

    def f1(a: np.ndarray[Any, Any]) -> float:
        placed = {u: compose(a, est[u]) for u in poses if u in est}
        return score(plan, fuse_local_maps(poses, placed, plan.grid)).f1_all

    runs = []
    for c in coarse:
        tracemalloc.start()
        t0 = time.perf_counter()
        al = agent.align(built, coarse_resolution=c)
        seconds = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        m, deg = error(al.transform)
        runs.append(
            {
                "coarse_resolution": c,
                "seconds": round(seconds, 2),
                "peak_traced_mb": round(peak / 1e6, 1),
                "alignment_error_m": round(m, 3),
                "alignment_error_deg": round(deg, 2),
                "map_f1_found_alignment": round(f1(al.transform), 4),
            }
        )
    return {
        "map": plan_path,
        "duration_s": duration,
        "seed": seed,
        "prior_resolution": agent.prior.grid.resolution,
        "prior_cells": list(agent.prior.grid.shape),
        "map_f1_true_alignment": round(f1(a_true), 4),
        "alignments": runs,
    }


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--map", required=True, help="map_server YAML or a built-in name")
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--coarse", type=float, nargs="+", default=[0.1], help="metres")
    a = ap.parse_args(argv)
    if not (0 < a.duration <= 86400):
        raise SystemExit(f"--duration: in (0, 86400] seconds, got {a.duration}")
    if not all(math.isfinite(c) and c > 0 for c in a.coarse):
        raise SystemExit(f"--coarse: metres > 0, got {a.coarse}")
    print(json.dumps(trace(a.map, a.duration, a.seed, a.coarse), indent=1))


if __name__ == "__main__":
    main()
