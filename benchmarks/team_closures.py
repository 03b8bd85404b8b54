"""Where one robot's loop closures go on a map: found against which stored poses, how
many the store still holds at the end, and what each stage of association removed from
the true revisits.

One robot, one mission (``--duration``, default 1,200 s), the store at its defaults
unless ``--region-limit`` is given. Printed as JSON:

- ``closures_by_gap``: the closures found, counted by the time between their two poses
  (0-10 s: mostly the pose made just before; > 60 s: a revisit);
- ``pairs_by_gap``: per bucket, the (new, stored) pairs that truly shared at least
  ``n_min`` landmarks when the new pose was associated, how many of them association
  found, and, for the revisits (> 60 s), the stage that removed the rest (``votes``,
  ``bounds``, ``ransac``, ``accepted``: the odometry gate and the certainty limits);
- ``closures_kept``: closures in the store at the end, of ``closures_found``;
- ``ate_*``: the summary's, over the kept poses, and the ATE of every pose made at the
  estimate it had when it was made (``ate_made_m``) against dead reckoning's;
- ``f1_*``: the fused map's wall F1 split into its losses: every local map made, fused
  at the true poses; the kept poses' maps at the true poses; the kept maps at the
  graph's estimates placed by the true alignment; the summary's (found alignment).

Run with ``python -m benchmarks.team_closures --map PLAN [--duration 1200] [--seed 0]
[--region-limit B] [--inlier-sigmas N]`` (N: ``AssociationParams.inlier_sigmas``, 0 for the
fixed 3-D bound alone; its default otherwise).
"""

from __future__ import annotations

import argparse
import json
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from sonarmap.cli.common import resolve_map
from sonarmap.metrics import score
from sonarmap.team.association import AssociationStats
from sonarmap.team.globalmap import fuse_local_maps
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.records import ClosureEdge, Pose, compose
from sonarmap.team.scoring import origin_of, rigid_ate

#: Time buckets (s) of a (new, stored) pair.
BUCKETS = ((0.0, 10.0), (10.0, 60.0), (60.0, float("inf")))
STAGES = ("votes", "bounds", "ransac", "accepted")


def _bucket(gap: float) -> str:
    for lo, hi in BUCKETS:
        if lo <= gap < hi:
            return f"{lo:g}-{hi:g}s"
    return "other"


def trace(
    plan_path: str,
    duration: float,
    seed: int,
    region_limit: int | None,
    inlier_sigmas: float | None = None,
) -> dict[str, Any]:
    """Run the mission and trace its closures (see the module's notes)."""
    plan = resolve_map(Path(plan_path))
    cfg = MissionConfig(duration=duration, seed=seed)
    if region_limit is not None:
        cfg = replace(cfg, store=replace(cfg.store, region_limit=region_limit))
    if inlier_sigmas is not None:
        cfg = replace(cfg, association=replace(cfg.association, inlier_sigmas=inlier_sigmas))
    agent = RobotAgent(plan, cfg)
    n_min = cfg.association.n_min
    by_gap: Counter[str] = Counter()
    pairs: dict[str, Counter[str]] = {_bucket(lo): Counter() for lo, _ in BUCKETS}
    made_at: dict[int, np.ndarray[Any, Any]] = {}
    scored = agent.evaluator.associated

    def hook(
        pose: Pose,
        stored: Sequence[Pose],
        closures: Sequence[ClosureEdge],
        stats: AssociationStats,
        t: float,
    ) -> None:
        scored(pose, stored, closures, stats, t)
        made_at[pose.uid] = pose.estimate.copy()
        times = {p.uid: p.time for p in stored}
        for c in closures:
            by_gap[_bucket(pose.time - times[c.a])] += 1
        ids = set(pose.landmarks.ids[pose.landmarks.ids >= 0].tolist())
        for p in stored:
            shared = ids & set(p.landmarks.ids[p.landmarks.ids >= 0].tolist())
            if p.uid == pose.uid or len(shared) < n_min:
                continue
            row = pairs[_bucket(pose.time - p.time)]
            row["true_pairs"] += 1
            lost = next((s for s in STAGES if p.uid not in stats.kept[s]), "found")
            row[lost] += 1

    agent.evaluator.associated = hook  # type: ignore[method-assign]
    while not agent.done:
        agent.step()
    result = agent.finish()
    s = result.summary
    truth, made = agent.truth, agent.made
    uids = sorted(made_at)
    est = np.array([made_at[u][:2] for u in uids])
    tru = np.array([truth[u][:2] for u in uids])
    odo = np.array([agent.odo_poses[u][:2] for u in uids])
    kept = {u: origin_of(u, truth, made) for u in agent.store.local.poses}
    kept_truth = {u: truth[o] for u, o in kept.items() if o is not None}
    graph = result.graph.estimates
    placed = {u: compose(agent.sensing.a_true, graph[u]) for u in kept_truth}
    everything = {u: made[u] for u in truth}
    return {
        "map": plan_path,
        "duration_s": duration,
        "seed": seed,
        "region_limit": cfg.store.region_limit,
        "inlier_sigmas": cfg.association.inlier_sigmas,
        "association_precision": s["association_precision"],
        "association_recall": s["association_recall"],
        "poses_made": s["poses_made"],
        "poses_kept": s["poses"],
        "closures_found": s["closures_found"],
        "closures_correct": s["closures_correct"],
        "closures_kept": s["closures"],
        "closures_by_gap": dict(by_gap),
        "pairs_by_gap": {k: dict(v) for k, v in pairs.items()},
        "ate_m": s["ate_m"],
        "ate_odometry_m": s["ate_odometry_m"],
        "ate_made_m": rigid_ate(est, tru),
        "ate_made_odometry_m": rigid_ate(odo, tru),
        "f1_all_maps_true_poses": score(
            plan, fuse_local_maps(everything, {u: truth[u] for u in truth}, plan.grid)
        ).f1_all,
        "f1_kept_maps_true_poses": score(
            plan, fuse_local_maps(agent.store.local.poses, kept_truth, plan.grid)
        ).f1_all,
        "f1_kept_maps_true_alignment": score(
            plan, fuse_local_maps(agent.store.local.poses, placed, plan.grid)
        ).f1_all,
        "map_f1": s["map_f1"],
        "map_f1_true_poses": s["map_f1_true_poses"],
        "alignment_error_m": s["alignment_error_m"],
        "alignment_error_deg": s["alignment_error_deg"],
    }


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--map", required=True, help="map_server YAML or a built-in name")
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--region-limit", type=int, default=None)
    ap.add_argument(
        "--inlier-sigmas", type=float, default=None, help="default: AssociationParams' (3)"
    )
    a = ap.parse_args(argv)
    if not (0 < a.duration <= 86400):
        raise SystemExit(f"--duration: in (0, 86400] seconds, got {a.duration}")
    print(json.dumps(trace(a.map, a.duration, a.seed, a.region_limit, a.inlier_sigmas), indent=1))


if __name__ == "__main__":
    main()
