"""Indoor robots on real building maps: blocked share, coverage, MTB and speed.

Setting (issue 36's): ROS ``map_server`` maps (by default the training maps in
``../shared/data/maps``), 0.1 m cells, robots of radius 0.3 m at 1 m/s with 5 m vision,
no start file (starts spread by farthest point, by seed). For each map, policy, robot
count, traffic rule and seed one run of ``--duration`` simulated seconds, reporting:

- ``blocked``: the share of robot-steps whose move was cancelled (goal: < 5 %);
- ``never seen``: the share of the reachable territory never seen;
- ``unreachable``: the share of the map's free cells no robot can reach (left out);
- ``mean MTB``: the mean, after a fifth of the run, of the worst time since last seen;
- ``graph idleness``: the patrol graph's average and worst idleness over the visits;
- ``x real``: simulated seconds per wall-clock second, on one core.

Run with ``python -m benchmarks.patrol_indoor [--maps depot warehouse] [--robots 1 2 4]
[--policies potential] [--traffic thesis give-way] [--seeds 0 1] [--duration 600]
[--min-hold S] [--choice-cell M] [--claim M] [--json F] [--figure F.png]``; ``--maps``
takes names in the data folder or paths to map YAML files. ``--replot F.json [G.json ...]
[--figure F.png]`` tabulates earlier runs
(``--json`` files, or ``runs.json`` of ``sonarmap patrol experiment baselines --map``)
together with issue 36's claims, and draws their figure, without running anything: the
mean MTB against the team's size, one line per policy and traffic rule and one panel per
map (the mean over the seeds, each seed a dot). The runs and the figure are
:mod:`sonarmap.patrol.baselines`'s.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from sonarmap.io.rosmap import read_map
from sonarmap.patrol import PatrolConfig
from sonarmap.patrol.baselines import (
    INDOOR,
    baseline_claims,
    baseline_run,
    baseline_table,
    plot_baselines,
    table_lines,
)
from sonarmap.patrol.territory import Territory

MAPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "maps"


def _map_path(name: str) -> Path:
    p = Path(name)
    return p if p.suffix in (".yaml", ".yml") else MAPS / f"{name}.yaml"


def run_one(
    territory: Territory,
    policy: str,
    robots: int,
    traffic: str,
    seed: int,
    duration: float,
    min_hold: float = 0.0,
    choice_cell: float | None = None,
    claim: float | None = None,
) -> dict[str, Any]:
    """One run's figures (:func:`sonarmap.patrol.baselines.baseline_run`); ``min_hold``,
    ``choice_cell``, ``claim``: :class:`~sonarmap.patrol.PatrolConfig`'s (None: its
    default)."""
    config = PatrolConfig(
        min_hold=min_hold,
        policy=policy,
        radius=INDOOR["radius"],
        speed=INDOOR["speed"],
        vision=INDOOR["vision"],
        cell=INDOOR["cell"],
        duration=duration,
        traffic=traffic,
    )
    if choice_cell is not None:
        config = dataclasses.replace(config, choice_cell=choice_cell)
    if claim is not None:
        config = dataclasses.replace(config, claim=claim)
    return baseline_run(territory, config, robots, seed)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", nargs="+", default=["depot", "warehouse"])
    ap.add_argument("--robots", nargs="+", type=int, default=[1, 2, 4])
    ap.add_argument("--policies", nargs="+", default=["potential"])
    ap.add_argument("--traffic", nargs="+", default=["thesis", "give-way"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--min-hold", type=float, default=0.0, help="seconds (PatrolConfig.min_hold)")
    ap.add_argument(
        "--choice-cell", type=float, help="metres (PatrolConfig.choice_cell; default its default)"
    )
    ap.add_argument("--claim", type=float, help="metres (PatrolConfig.claim; default its default)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--figure", type=Path)
    ap.add_argument(
        "--replot",
        type=Path,
        nargs="+",
        help="Tabulate (and draw --figure of) the runs of these --json files or "
        "'patrol experiment baselines' runs.json files together, running nothing.",
    )
    args = ap.parse_args(argv)
    if args.replot is not None:
        runs = [r for f in args.replot for r in json.loads(f.read_text())["runs"]]
        table = baseline_table(runs)
        print("\n".join(table_lines(table)))
        for c in baseline_claims(table):
            print(f"{c['verdict']}: {c['claim']}: {c['measured']}")
        if args.figure is not None:
            plot_baselines(runs, args.figure)
        return
    rows: list[dict[str, Any]] = []
    print(
        "| map | policy | robots | traffic | seed | blocked | never seen | unreachable "
        "| mean MTB, s | graph idleness, s (avg, worst) | x real |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.maps:
        path = _map_path(name)
        if not path.is_file():
            raise SystemExit(f"{path}: no such map (see ../shared/data/README)")
        territory = Territory.from_map(read_map(path), cell=0.1)
        for policy in args.policies:
            for robots in args.robots:
                for traffic in args.traffic:
                    for seed in args.seeds:
                        row = {
                            "map": path.stem,
                            **run_one(
                                territory,
                                policy,
                                robots,
                                traffic,
                                seed,
                                args.duration,
                                args.min_hold,
                                args.choice_cell,
                                args.claim,
                            ),
                        }
                        rows.append(row)
                        print(
                            f"| {row['map']} | {policy} | {robots} | {row['traffic']} | {seed} "
                            f"| {row['blocked']:.3f} | {row['never_seen']:.3f} "
                            f"| {row['unreachable']:.3f} | {row['mean_mtb']:.1f} "
                            f"| {row['graph_avg_idleness']:.1f}, "
                            f"{row['graph_worst_idleness']:.1f} | {row['x_real']:.0f} |",
                            flush=True,
                        )
    if args.json is not None:
        args.json.write_text(json.dumps({"duration": args.duration, "runs": rows}, indent=2))
    if args.figure is not None:
        plot_baselines(rows, args.figure)


if __name__ == "__main__":
    main()
