"""Why a second robot gains little: who looks at what, from a run's own records.

Setting as ``benchmarks.patrol_indoor`` (issue 36's indoor robots: radius 0.3 m, 1 m/s,
5 m vision, 0.1 m cells, no start file, giving way), on the training maps in
``../shared/data/maps`` and, with ``--buildings SEED ...``, seeded floor plans
(:func:`sonarmap.floorplan.random_building`, ``--size`` metres; seeds below 1000 are
training scenes). Each run is recorded step by step (``run_patrol``'s ``on_step``: the
robots' positions and the shared fog) and reported with, after the warm-up (a fifth of
the run):

- ``mean MTB``, ``blocked``, ``never seen``: as ``patrol_indoor``;
- ``near``: the share of steps some two robots are within the vision radius of each
  other (their discs overlap by more than a third);
- ``redundant``: of the cells coming into a robot's view (not in its own view in the
  last 5 s), the share another robot saw in the last 30 s (a robot following another,
  or two robots sweeping the same rooms); 0 for one robot;
- ``stood``: the share of robot-steps that moved less than a tenth of a step (waits);
- ``worst seen``: the share of the steps at which the worst place (the watched cell
  unseen longest) was seen by a robot that another robot was within ``vision`` + 5 m of
  (both robots at the stale place together), and ``worst age``, the mean age, seconds,
  of the worst place when it was seen;
- ``split``: over 5 m squares, the mean of the largest share of the square's looks one
  robot made (1: every square looked at by one robot only; 1/N: all robots alike).

``--choice-cell``, ``--claim``: as :class:`~sonarmap.patrol.PatrolConfig`'s fields.
Run with ``python -m benchmarks.patrol_team_size [--maps depot warehouse] [--buildings 0 1]
[--size 40 30] [--robots 1 2 4] [--seeds 0 1 2] [--duration 1800] [--json F]``.

``--judge BASE.json CLAIM.json OTHERS.json`` runs nothing: it checks the rule of
``docs/results/2026-12-08-patrol-team-size.md`` on the ``--json`` files of a run without
and one with ``--claim``, and ``benchmarks.patrol_indoor``'s ``--json`` of the random
walk and the reactive baseline (:func:`judge`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from sonarmap.errors import InputError, SonarmapError
from sonarmap.floorplan import random_building
from sonarmap.grid import Grid
from sonarmap.io.rosmap import read_map
from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.baselines import INDOOR, baseline_claims, baseline_table
from sonarmap.patrol.fog import Fog, disc_offsets
from sonarmap.patrol.robots import Team
from sonarmap.patrol.territory import Territory

MAPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "maps"
#: A cell is new to a robot's view when the robot has not seen it for this long, s.
OWN_RECENT = 5.0
#: A new cell is a redundant look when another robot saw it this recently, s.
OTHER_RECENT = 30.0
#: Side of the squares of ``split``, metres.
SQUARE = 5.0


def config_for(duration: float, **fields: Any) -> PatrolConfig:
    """Issue 36's indoor robots, giving way, for ``duration`` seconds; ``fields`` (those
    not None) replace :class:`~sonarmap.patrol.PatrolConfig`'s defaults."""
    config = PatrolConfig(
        radius=INDOOR["radius"],
        speed=INDOOR["speed"],
        vision=INDOOR["vision"],
        cell=INDOOR["cell"],
        duration=duration,
        traffic="give-way",
    )
    given = {k: v for k, v in fields.items() if v is not None}
    return dataclasses.replace(config, **given) if given else config


class Recorder:
    """Accumulates one run's diagnostics step by step (``run_patrol``'s ``on_step``)."""

    def __init__(self, grid: Grid, robots: int, vision: float, warmup: float) -> None:
        self.grid = grid
        self.n = robots
        self.vision = vision
        self.warmup = warmup
        self.disc = disc_offsets(vision, grid.resolution)
        shape = grid.shape
        self.own = np.full((robots, *shape), -np.inf)
        self.prev: npt.NDArray[np.float64] | None = None
        self.prev_xy: npt.NDArray[np.float64] | None = None
        k = max(1, round(SQUARE / grid.resolution))
        self.k = k
        self.looks = np.zeros((robots, shape[0] // k + 1, shape[1] // k + 1))
        self.steps = 0
        self.near = 0
        self.new = 0
        self.redundant = 0
        self.stood = 0
        self.worst_events = 0
        self.worst_together = 0
        self.worst_age = 0.0

    def cells(self, r: int, c: int, watched: npt.NDArray[np.bool_]) -> tuple[Any, Any]:
        rows = self.disc[:, 0] + r
        cols = self.disc[:, 1] + c
        ok = (rows >= 0) & (rows < watched.shape[0]) & (cols >= 0) & (cols < watched.shape[1])
        rows, cols = rows[ok], cols[ok]
        keep = watched[rows, cols]
        return rows[keep], cols[keep]

    def __call__(self, t: float, team: Team, fog: Fog) -> None:
        x = np.asarray(team.x, dtype=np.float64)
        y = np.asarray(team.y, dtype=np.float64)
        r, c = self.grid.world_to_cell(x, y)
        after = t > self.warmup
        seen = [self.cells(int(r[i]), int(c[i]), fog.watched) for i in range(self.n)]
        if after and self.prev is not None and self.prev_xy is not None:
            self.steps += 1
            if self.n > 1:
                d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
                np.fill_diagonal(d, np.inf)
                self.near += int(d.min() < self.vision)
            moved = np.hypot(x - self.prev_xy[:, 0], y - self.prev_xy[:, 1])
            self.stood += int(np.count_nonzero(moved < 0.05))
            for i, (rr, cc) in enumerate(seen):
                fresh = self.own[i][rr, cc] < t - OWN_RECENT
                self.new += int(np.count_nonzero(fresh))
                if self.n > 1:
                    others = np.delete(self.own[:, rr[fresh], cc[fresh]], i, axis=0).max(axis=0)
                    self.redundant += int(np.count_nonzero(others >= t - OTHER_RECENT))
                np.add.at(self.looks[i], (rr[fresh] // self.k, cc[fresh] // self.k), 1)
            # The worst place of the step before: seen now, by whom, with whom near.
            last = np.where(fog.watched, self.prev, np.inf)
            w = np.unravel_index(int(np.argmin(last)), last.shape)
            if fog.last[w] == t and math.isfinite(float(last[w])):
                self.worst_events += 1
                self.worst_age += t - float(last[w])
                wx, wy = self.grid.cell_centres(w[0], w[1])
                dist = np.hypot(x - float(wx), y - float(wy))
                self.worst_together += int(np.count_nonzero(dist <= self.vision + 5.0) > 1)
        for i, (rr, cc) in enumerate(seen):
            self.own[i][rr, cc] = t
        self.prev = fog.last.copy()
        self.prev_xy = np.column_stack([x, y])

    def figures(self) -> dict[str, float]:
        """The run's diagnostics (see the module's notes)."""
        total = self.looks.sum(axis=0)
        used = total > 0
        split = float((self.looks.max(axis=0)[used] / total[used]).mean()) if used.any() else 1.0
        return {
            "near": self.near / max(1, self.steps),
            "redundant": self.redundant / max(1, self.new),
            "stood": self.stood / max(1, self.steps * self.n),
            "worst_together": self.worst_together / max(1, self.worst_events),
            "worst_age": self.worst_age / max(1, self.worst_events),
            "split": split,
        }


def diagnose(territory: Territory, config: PatrolConfig, robots: int, seed: int) -> dict[str, Any]:
    """One recorded run's row: the summary's figures and :meth:`Recorder.figures`."""
    rec = Recorder(territory.grid, robots, config.vision, config.warmup_s)
    t0 = time.process_time()
    s = run_patrol(territory, config, robots=robots, seed=seed, on_step=rec).summary()
    return {
        "policy": config.policy,
        "traffic": config.traffic,
        "robots": robots,
        "seed": seed,
        "mean_mtb": s["mean_mtb"],
        "blocked": s["blocked_share"],
        "never_seen": s["never_seen"],
        **rec.figures(),
        "cpu_s": time.process_time() - t0,
    }


def territories(
    maps: list[str], buildings: list[int], size: tuple[float, float]
) -> list[tuple[str, Territory]]:
    """The named maps (data folder names or YAML paths) and seeded floor plans."""
    out = []
    for name in maps:
        p = Path(name)
        path = p if p.suffix in (".yaml", ".yml") else MAPS / f"{name}.yaml"
        if not path.is_file():
            raise InputError("no such map (see ../shared/data/README)", path=path)
        out.append((path.stem, Territory.from_map(read_map(path), cell=0.1)))
    for seed in buildings:
        if seed >= 1000:
            raise InputError(f"--buildings {seed}: seeds from 1000 are held out")
        w, h = size
        plan = random_building(w, h, seed=seed, max_room=10.0, door=(1.0, 1.5))
        grid = Grid.from_bounds(0, 0, w, h, 0.1)
        out.append((f"building-{seed}", Territory.from_map(plan.render(grid), cell=0.1)))
    return out


#: The rule's thresholds: a map's 1-to-2 ratio is weak above WEAK and must fall by at
#: least GAIN; no mean MTB with 2 or 4 robots may exceed NOISE x the base's.
WEAK, GAIN, NOISE = 0.6, 0.05, 1.05


def judge(
    base: list[dict[str, Any]], claim: list[dict[str, Any]], others: list[dict[str, Any]]
) -> list[tuple[str, bool]]:
    """The rule's checks, each (what was checked and measured, whether it holds): the
    1-to-2 ratio on the weak maps, nothing worse by more than the noise, one robot's
    runs the same, ``baseline_claims``' comparisons that hold for ``base`` also holding
    for ``claim`` (with ``others``' policies beside each), blocked and never seen."""

    def potential(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        # Rows written before the diagnostics named their policy are the field's.
        return [{"policy": "potential", "traffic": "give-way", **r} for r in rows]

    def means(rows: list[dict[str, Any]]) -> dict[tuple[str, int], float]:
        runs: dict[tuple[str, int], list[float]] = {}
        for r in rows:
            runs.setdefault((r["map"], int(r["robots"])), []).append(float(r["mean_mtb"]))
        return {k: sum(v) / len(v) for k, v in runs.items()}

    out: list[tuple[str, bool]] = []
    mb, mc = means(base), means(claim)
    for m in dict.fromkeys(r["map"] for r in base):
        rb, rc = mb[(m, 2)] / mb[(m, 1)], mc[(m, 2)] / mc[(m, 1)]
        if rb > WEAK:
            out.append((f"{m}: 2/1 ratio {rb:.3f} -> {rc:.3f}", rc <= rb - GAIN))
        for n in (2, 4):
            q = mc[(m, n)] / mb[(m, n)]
            out.append(
                (f"{m}: {n} robots {mb[(m, n)]:.1f} -> {mc[(m, n)]:.1f} s ({q:.2f}x)", q <= NOISE)
            )
        falls = mc[(m, 1)] > mc[(m, 2)] > mc[(m, 4)]
        out.append((f"{m}: mean MTB falls from 1 to 2 to 4 robots with claims", falls))
        one_b = [r["mean_mtb"] for r in base if r["map"] == m and r["robots"] == 1]
        one_c = [r["mean_mtb"] for r in claim if r["map"] == m and r["robots"] == 1]
        out.append((f"{m}: one robot's runs the same", one_b == one_c))
        worst = max(float(r["blocked"]) for r in claim if r["map"] == m)
        out.append((f"{m}: blocked, worst run {100 * worst:.1f} %", worst < 0.05))
        unseen = max(float(r["never_seen"]) for r in claim if r["map"] == m and r["robots"] == 4)
        out.append((f"{m}: never seen with 4 robots, worst {unseen:.3f}", unseen == 0))
    maps = {r["map"] for r in others}
    before = {
        c["claim"]: c
        for c in baseline_claims(baseline_table(potential(base) + others))
        if c["claim"].split(":")[0] in maps
    }
    after = {c["claim"]: c for c in baseline_claims(baseline_table(potential(claim) + others))}
    for text, c in before.items():
        if "potential" not in text or any(w in text for w in ("blocked", "seen", "falls")):
            continue
        now = after[text]
        kept = c["verdict"] != "holds" or now["verdict"] == "holds"
        out.append(
            (
                f"{text}: base {c['verdict']} ({c['measured']}), "
                f"claims {now['verdict']} ({now['measured']})",
                kept,
            )
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", nargs="*", default=["depot", "warehouse"])
    ap.add_argument("--buildings", nargs="*", type=int, default=[])
    ap.add_argument("--size", nargs=2, type=float, default=[40.0, 30.0])
    ap.add_argument("--robots", nargs="+", type=int, default=[1, 2, 4])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=1800.0)
    ap.add_argument("--choice-cell", type=float, help="metres (PatrolConfig.choice_cell)")
    ap.add_argument("--claim", type=float, help="metres (PatrolConfig.claim)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--judge", type=Path, nargs=3, metavar=("BASE", "CLAIM", "OTHERS"))
    args = ap.parse_args(argv)
    if args.judge is not None:
        try:
            base, claim, others = (json.loads(p.read_text())["runs"] for p in args.judge)
        except (OSError, KeyError, TypeError, json.JSONDecodeError) as exc:
            print(f"patrol_team_size: --judge: not a runs file ({exc})", file=sys.stderr)
            return 2
        checks = judge(base, claim, others)
        for text, ok in checks:
            print(f"{'holds' if ok else 'FAILS'}: {text}")
        print("rule " + ("passes" if all(ok for _, ok in checks) else "fails"))
        return 0
    if args.json is not None and not args.json.parent.is_dir():
        ap.error(f"--json: no folder {args.json.parent}")
    try:
        config = config_for(args.duration, choice_cell=args.choice_cell, claim=args.claim)
        places = list(territories(args.maps, args.buildings, tuple(args.size)))
    except SonarmapError as exc:
        print(f"patrol_team_size: {exc}", file=sys.stderr)
        return 2
    rows: list[dict[str, Any]] = []
    print(
        "| map | robots | seed | mean MTB, s | blocked | never seen | near | redundant "
        "| stood | worst together | worst age, s | split | cpu s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, territory in places:
        for robots in args.robots:
            for seed in args.seeds:
                row = {"map": name, **diagnose(territory, config, robots, seed)}
                rows.append(row)
                print(
                    f"| {name} | {robots} | {seed} | {row['mean_mtb']:.1f} | {row['blocked']:.3f} "
                    f"| {row['never_seen']:.3f} | {row['near']:.2f} | {row['redundant']:.2f} "
                    f"| {row['stood']:.3f} | {row['worst_together']:.2f} "
                    f"| {row['worst_age']:.1f} | {row['split']:.2f} | {row['cpu_s']:.0f} |",
                    flush=True,
                )
    if args.json is not None:
        args.json.write_text(json.dumps({"duration": args.duration, "runs": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
