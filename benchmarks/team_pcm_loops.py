"""How often PCM's test fails loops between two TRUE closures, by the walk's length and
by what it crosses, under the loop model with and without the shared heading bias.

PCM (:mod:`sonarmap.team.pcm`) rejects a closure whose loops with other closures fail
the chi-square test at 99 %: a loop between two right closures should fail about 1 %
of the time. This script runs a team as ``sonarmap team run --patrol --lean`` does
(PCM off, so that every closure found is still in the stores), then, for each robot's
store at the end, takes the closures the scorer counts right
(:meth:`~sonarmap.team.evaluation.MissionEvaluator.correct`), groups them by pair of
layers as PCM does, and tests pairs of them: within the ``--window`` newest of a group
(40, PCM's :data:`~sonarmap.team.pcm.MAX_PER_PAIR`; every pair of the window), or, with
``--window 0``, up to ``--max-pairs`` pairs drawn at random from all of the group's
(seeded: the same pairs every run).

Each loop is tested under three loop models, on the same pairs:

- ``independent``: :class:`~sonarmap.team.pcm.LayerChain` with ``bias_sd=0``, the
  odometry edges' own covariances only (the model PCM had before 2026-12-08: the
  heading bias counted as an independent error per edge);
- ``shared_bias``: the default ``bias_sd`` (:data:`~sonarmap.team.calibration.
  HEADING_BIAS_PRIOR`), one unknown heading bias per layer across every edge;
- ``shared_bias_least``: the same, the layer's forest grown by least x and y variance
  (``forest="least"``) instead of fewest edges (suspect: breadth first prefers
  shortcuts through merged poses).

The walk's length and merged poses are those of ``shared_bias``'s forest.

Printed as JSON: the runs' figures (team F1, ATE, whether the robots calibrated their
odometry: a team's never do, so no stored edge is rewritten), then rows of loops split
by kind (``own``: a robot's own layer; ``received``: a received layer with itself;
``between``: two layers), walk length (metres of odometry the loop's walk or walks
drive), how many poses merged at a closure (``StoreParams.merge_on_closure``) the walk
passes through (0, 1, 2, 3+), with for each model the loops, the share failing
at 99 % and the mean squared distance (3 if the model were exact).

Run with ``python -m benchmarks.team_pcm_loops --map PLAN [--robots 2] [--duration 120]
[--seed 0] [--window 40 | --window 0 --max-pairs 1500] [--json OUT]``. Training maps
and seeds only (a diagnostic of the loop model, not a held-out score).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from sonarmap.cli.common import resolve_map
from sonarmap.errors import SonarmapError
from sonarmap.team.calibration import HEADING_BIAS_PRIOR
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.globalmap import CHI2_99_3DOF
from sonarmap.team.inputs import draw_world, run_territory
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.network import NetworkParams
from sonarmap.team.patrolling import patrol_routes
from sonarmap.team.pcm import LayerChain, loop_distance, orient
from sonarmap.team.presets import PRESETS
from sonarmap.team.records import counter_of
from sonarmap.team.simulation import run_team
from sonarmap.team.store import MERGE_COUNTER_BASE, StoreParams

F64 = npt.NDArray[np.float64]

#: The loop models compared: name -> LayerChain's bias_sd and forest.
MODELS = {
    "independent": (0.0, "hops"),
    "shared_bias": (HEADING_BIAS_PRIOR, "hops"),
    "shared_bias_least": (HEADING_BIAS_PRIOR, "least"),
}
#: Walk lengths (m) the loops are split by.
LENGTHS = ((0.0, 10.0), (10.0, 30.0), (30.0, 100.0), (100.0, 300.0), (300.0, float("inf")))


def _length_bin(m: float) -> str:
    for lo, hi in LENGTHS:
        if lo <= m < hi:
            return f"{lo:g}-{hi:g} m"
    return "other"


def _walk(
    c1: tuple[int, int, F64, F64],
    c2: tuple[int, int, F64, F64],
    chain_a: LayerChain,
    chain_b: LayerChain,
) -> tuple[float, int]:
    """Metres the loop's odometry walks drive, and the merged poses they pass through
    (as :func:`~sonarmap.team.pcm.loop_residual` forms them: one walk within one tree
    of one layer, else one per layer)."""
    a1, b1, _, _ = c1
    a2, b2, _, _ = c2
    walks: list[tuple[LayerChain, int, npt.NDArray[np.int8]]] = []
    pa1, pb1 = chain_a.pose(a1), chain_b.pose(b1)
    if chain_a is chain_b and pa1 is not None and pb1 is not None and pa1[0] == pb1[0]:
        walks.append((chain_a, pa1[0], chain_b.path(b1, b2) + chain_a.path(a2, a1)))
    else:
        if b1 != b2 and pb1 is not None:
            walks.append((chain_b, pb1[0], chain_b.path(b1, b2)))
        if a1 != a2 and pa1 is not None:
            walks.append((chain_a, pa1[0], chain_a.path(a2, a1)))
    metres = sum(ch.walk_metres(t, w) for ch, t, w in walks)
    # Through a merged pose: two of the walk's edges meet there (not a closure's end
    # alone, which merges often are).
    through = sum(
        1
        for ch, t, w in walks
        for u, n in ch.walk_poses(t, w).items()
        if n >= 2 and counter_of(u) >= MERGE_COUNTER_BASE
    )
    return metres, through


def robot_loops(agent: RobotAgent, window: int, max_pairs: int, seed: int) -> list[dict[str, Any]]:
    """Every tested loop between two right closures of ``agent``'s store: its kind,
    walk length, the merged poses it passes through, and its squared distance under each
    model (:data:`MODELS`)."""
    store = agent.store
    layers = {agent.robot: store.local, **store.received}
    layer_of = {u: s for s, layer in layers.items() for u in layer.poses}
    chains = {
        name: {s: LayerChain(layer.edges, bias_sd=sd, forest=f) for s, layer in layers.items()}
        for name, (sd, f) in MODELS.items()
    }
    groups: dict[tuple[int, int], list[int]] = defaultdict(list)
    for i, c in enumerate(store.closures):
        la, lb = layer_of.get(c.a), layer_of.get(c.b)
        if la is None or lb is None or not agent.evaluator.correct(c):
            continue
        groups[(min(la, lb), max(la, lb))].append(i)
    rng = np.random.default_rng(seed)
    rows = []
    for (la, lb), idx in sorted(groups.items()):
        if window:
            idx = idx[-window:]
        pairs = list(itertools.combinations(range(len(idx)), 2))
        if not window and len(pairs) > max_pairs:
            pick = rng.choice(len(pairs), size=max_pairs, replace=False)
            pairs = [pairs[k] for k in sorted(pick)]
        kind = "between" if la != lb else ("own" if la == agent.robot else "received")
        oriented = [orient(store.closures[i], la, layer_of) for i in idx]
        for p, q in pairs:
            c1, c2 = oriented[p], oriented[q]
            d2 = {name: loop_distance(c1, c2, ch[la], ch[lb]) for name, ch in chains.items()}
            if any(v is None for v in d2.values()):
                continue
            metres, merged = _walk(c1, c2, chains["shared_bias"][la], chains["shared_bias"][lb])
            rows.append({"kind": kind, "metres": metres, "merged": merged, **d2})
    return rows


def _summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"loops": len(rows)}
    for name in MODELS:
        d2 = np.array([r[name] for r in rows], dtype=np.float64)
        out[name] = {
            "fail_share": float(np.mean(d2 > CHI2_99_3DOF)) if len(d2) else None,
            "mean_d2": float(np.mean(d2)) if len(d2) else None,
        }
    return out


def split(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The loops' failure shares, all together and split by kind, walk length and
    merged poses passed through."""
    by: dict[str, dict[str, list[dict[str, Any]]]] = {
        "kind": defaultdict(list),
        "length": defaultdict(list),
        "merged": defaultdict(list),
        "length_merged": defaultdict(list),
    }
    for r in rows:
        length = _length_bin(r["metres"])
        k = r["merged"]
        merged = (
            "through no merged pose"
            if k == 0
            else f"through {min(k, 3)}{'+' if k >= 3 else ''} merged"
        )
        by["kind"][r["kind"]].append(r)
        by["length"][length].append(r)
        by["merged"][merged].append(r)
        by["length_merged"][f"{length}, {merged}"].append(r)
    return {
        "all": _summary(rows),
        **{k: {g: _summary(v) for g, v in sorted(groups.items())} for k, groups in by.items()},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", required=True, help="A map_server YAML or a built-in name.")
    parser.add_argument("--robots", type=int, default=2)
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--window", type=int, default=40, help="Newest closures a group (0: all).")
    parser.add_argument("--max-pairs", type=int, default=1500, help="With --window 0.")
    parser.add_argument("--json", help="Also write the result to this JSON file.")
    args = parser.parse_args(argv)
    if args.robots < 2 or args.window < 0 or args.max_pairs < 1:
        parser.error("--robots must be >= 2, --window >= 0 and --max-pairs >= 1")
    if not (math.isfinite(args.duration) and args.duration > 0) or args.seed < 0:
        parser.error("--duration must be a finite number of seconds > 0 and --seed >= 0")
    if args.json and not Path(args.json).parent.is_dir():
        parser.error(f"--json: no folder {Path(args.json).parent}")
    try:
        plan = resolve_map(Path(args.map))
        # As `team run --patrol --lean` (PCM off): its territory, routes, world, settings.
        region = run_territory(None, plan).region
        patrolled, _ = patrol_routes(
            plan, args.robots, args.duration, seed=args.seed, region=region
        )
        routes = dict(enumerate(patrolled))
        world, routes = draw_world(
            plan, args.duration, seed=args.seed, robots=args.robots, region=region, routes=routes
        )
        exchange, store = PRESETS["lean"].apply(ExchangeParams(), StoreParams())
        cfg = MissionConfig(duration=args.duration, seed=args.seed, store=store)
    except SonarmapError as exc:
        print(f"team_pcm_loops: --map {args.map}: {exc}", file=sys.stderr)
        return 2
    team = run_team(
        plan,
        cfg,
        args.robots,
        network=NetworkParams(),
        exchange=exchange,
        seed=args.seed,
        world=world,
        routes=[routes.get(i) for i in range(args.robots)],
        territory=region,
    )
    s = team.summary
    rows: list[dict[str, Any]] = []
    for agent in team.agents:
        rows.extend(robot_loops(agent, args.window, args.max_pairs, args.seed))
    result = {
        "run": {
            "map": args.map,
            "robots": args.robots,
            "duration": args.duration,
            "seed": args.seed,
            "window": args.window,
            "map_f1_team": s["map_f1_team"],
            "ate_m": [r["ate_m"] for r in s["robots"]],
            "calibrate_odometry": [r["parameters"]["calibrate_odometry"] for r in s["robots"]],
            "closures_wrong": sum(len(r.get("closures_wrong", [])) for r in s["robots"]),
        },
        "loops": split(rows),
    }
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
