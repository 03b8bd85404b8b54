"""Indoor robots on real building maps: blocked share, coverage, MTB and speed.

Setting (issue 36's): ROS ``map_server`` maps (by default the training maps in
``../shared/data/maps``), 0.1 m cells, robots of radius 0.3 m at 1 m/s with 5 m vision,
no start file (starts spread by farthest point, by seed). For each map, policy, robot
count, traffic rule and seed one run of ``--duration`` simulated seconds, reporting:

- ``blocked``: the share of robot-steps whose move was cancelled (goal: < 5 %);
- ``never seen``: the share of the reachable territory never seen;
- ``unreachable``: the share of the map's free cells no robot can reach (left out);
- ``mean MTB``: the mean, after a fifth of the run, of the worst time since last seen;
- ``x real``: simulated seconds per wall-clock second, on one core.

Run with ``python -m benchmarks.patrol_indoor [--maps depot warehouse] [--robots 1 2 4]
[--policies potential] [--traffic thesis give-way] [--seeds 0 1] [--duration 600]
[--json F] [--figure F.png]``; ``--maps`` takes names in the data folder or paths to map
YAML files. ``--replot F.json --figure F.png`` draws the figure of an earlier ``--json``
without running anything: the mean MTB against the team's size, one line per policy and
traffic rule and one panel per map (the mean over the seeds, each seed a dot).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from sonarmap.io.rosmap import read_map
from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.territory import Territory

MAPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "maps"


def _map_path(name: str) -> Path:
    p = Path(name)
    return p if p.suffix in (".yaml", ".yml") else MAPS / f"{name}.yaml"


def run_one(
    territory: Territory, policy: str, robots: int, traffic: str, seed: int, duration: float
) -> dict[str, Any]:
    """One run's figures (see the module's notes)."""
    config = PatrolConfig(
        policy=policy,
        radius=0.3,
        speed=1.0,
        vision=5.0,
        cell=0.1,
        duration=duration,
        traffic=traffic,
    )
    t0 = time.perf_counter()
    s = run_patrol(territory, config, robots=robots, seed=seed).summary()
    wall = time.perf_counter() - t0
    return {
        "policy": policy,
        "robots": robots,
        "traffic": config.traffic,
        "seed": seed,
        "blocked": s["blocked_share"],
        "never_seen": s["never_seen"],
        "unreachable": s["unreachable_free_share"],
        "mean_mtb": s["mean_mtb"],
        "x_real": duration / wall,
    }


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """The figure of runs ``rows`` (see the module's notes), written to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    maps = sorted({r["map"] for r in rows})
    fig, axes = plt.subplots(1, len(maps), figsize=(5.0 * len(maps), 3.8), squeeze=False)
    for ax, name in zip(axes[0], maps, strict=True):
        mine = [r for r in rows if r["map"] == name]
        lines = sorted({(r["policy"], r["traffic"]) for r in mine})
        for policy, traffic in lines:
            runs = [r for r in mine if (r["policy"], r["traffic"]) == (policy, traffic)]
            sizes = sorted({r["robots"] for r in runs})
            mean = [
                sum(r["mean_mtb"] for r in runs if r["robots"] == n)
                / sum(1 for r in runs if r["robots"] == n)
                for n in sizes
            ]
            label = policy if len({t for _, t in lines}) == 1 else f"{policy}, {traffic}"
            (line,) = ax.plot(sizes, mean, marker="o", label=label)
            ax.scatter(
                [r["robots"] for r in runs],
                [r["mean_mtb"] for r in runs],
                s=10,
                color=line.get_color(),
                alpha=0.5,
            )
        ax.set_xticks(sorted({r["robots"] for r in mine}))
        ax.set_xlabel("robots")
        ax.set_ylabel("mean MTB [s]")
        ax.set_ylim(bottom=0.0)
        ax.set_title(name)
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", nargs="+", default=["depot", "warehouse"])
    ap.add_argument("--robots", nargs="+", type=int, default=[1, 2, 4])
    ap.add_argument("--policies", nargs="+", default=["potential"])
    ap.add_argument("--traffic", nargs="+", default=["thesis", "give-way"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--figure", type=Path)
    ap.add_argument("--replot", type=Path, help="Draw --figure from this --json file.")
    args = ap.parse_args(argv)
    if args.replot is not None:
        if args.figure is None:
            raise SystemExit("--replot needs --figure")
        plot(json.loads(args.replot.read_text())["runs"], args.figure)
        return
    rows: list[dict[str, Any]] = []
    print(
        "| map | policy | robots | traffic | seed | blocked | never seen | unreachable "
        "| mean MTB, s | x real |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
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
                            **run_one(territory, policy, robots, traffic, seed, args.duration),
                        }
                        rows.append(row)
                        print(
                            f"| {row['map']} | {policy} | {robots} | {row['traffic']} | {seed} "
                            f"| {row['blocked']:.3f} | {row['never_seen']:.3f} "
                            f"| {row['unreachable']:.3f} | {row['mean_mtb']:.1f} "
                            f"| {row['x_real']:.0f} |",
                            flush=True,
                        )
    if args.json is not None:
        args.json.write_text(json.dumps({"duration": args.duration, "runs": rows}, indent=2))
    if args.figure is not None:
        plot(rows, args.figure)


if __name__ == "__main__":
    main()
