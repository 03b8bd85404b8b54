"""One robot with and without its odometry calibration (issue 37's one-robot check;
:mod:`sonarmap.team.calibration`).

For each map and seed, one mission of ``--duration`` seconds (1200) run twice: with the
robot calibrating its odometry's heading bias (the default of a robot alone) and with
``calibrate=False`` (the code before the calibration, value for value). One JSON row per
run with the check's figures: ATE against odometry's, association precision and recall,
the fused map's wall F1 against the map of the same readings at the true poses and of
the kept local maps at their true poses, the alignment's error, the store against its
bound and the bias estimated. ``--sim-heading-bias`` sets the simulator's heading bias
(rad per metre; the robot's model of its odometry keeps 0.003), so that an odometry
without the bias, or with another one, is one command. ``--bias-sd`` is
:class:`RobotAgent`'s ``bias_sd`` (``prior``, the default, holds the prior heading-bias
variance in the calibrating robot's edges; ``remaining`` counts what the calibration
leaves).

Maps: a map_server YAML, ``office`` or ``building:SEED`` (the built-in plans),
``scanned:SEED`` (the 40 x 30 m scanned-plan stand-in of :mod:`benchmarks.team_world`,
outside free, an entrance) or ``standin:SEED`` (the 100 x 80 m one of
:mod:`benchmarks.team_bound`, outside free, no entrance). One JSON row also counts the
batches the calibration fitted and those that ended with a nonzero estimate.

Usage::

    python -m benchmarks.team_calibration --maps scanned:1 scanned:2 [--seeds 0 1]
        [--duration 1200] [--only on|off] [--sim-heading-bias 0.0]
        [--bias-sd prior|remaining] [--json F]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from sonarmap.io.rosmap import OccupancyMap, read_map
from sonarmap.team.mission import BIAS_SD_CHOICES, BiasSd, MissionConfig, RobotAgent
from sonarmap.team.world import ODOMETRY_NOISE, builtin_plan

from .team_bound import standin_plan
from .team_world import scanned_standin

#: Per run, from the mission's summary.
KEYS = (
    "ate_m",
    "ate_odometry_m",
    "association_precision",
    "association_recall",
    "closures_found",
    "map_f1",
    "map_f1_true_poses",
    "map_f1_held_true_poses",
    "alignment_error_m",
    "alignment_error_deg",
    "local_bytes_peak",
    "local_bytes_bound",
    "local_bytes_within_bound",
    "poses",
    "poses_made",
    "odometry_heading_bias",
)


def map_of(name: str) -> OccupancyMap:
    """A map by ``--maps`` name."""
    kind, _, seed = name.partition(":")
    if kind == "scanned" and seed.isdigit():
        return scanned_standin(int(seed))
    if kind == "standin" and seed.isdigit():
        return standin_plan(int(seed))
    if name == "office" or kind == "building":
        return builtin_plan(name)
    path = Path(name)
    if not path.is_file():
        raise SystemExit(f"--maps: {name}: no such file, and not scanned:SEED or standin:SEED")
    return read_map(path)


def run(
    plan: OccupancyMap,
    name: str,
    seed: int,
    duration: float,
    calibrate: bool,
    sim_bias: float | None = None,
    bias_sd: BiasSd = "prior",
) -> dict[str, Any]:
    """One mission's row; ``sim_bias`` (rad per metre) replaces the simulator's
    ``bias_theta`` when given; ``bias_sd`` is :class:`RobotAgent`'s."""
    t0 = time.perf_counter()
    noise = dict(ODOMETRY_NOISE)
    if sim_bias is not None:
        noise["bias_theta"] = sim_bias
    cfg = MissionConfig(duration=duration, seed=seed)
    agent = RobotAgent(plan, cfg, calibrate=calibrate, odometry_noise=noise, bias_sd=bias_sd)
    agent.run()
    s = agent.finish().summary
    row: dict[str, Any] = {"map": name, "seed": seed, "calibrate": calibrate}
    row["sim_heading_bias"] = noise["bias_theta"]
    row["bias_sd"] = bias_sd
    row.update({k: s[k] for k in KEYS})
    row["ate_ratio"] = s["ate_m"] / s["ate_odometry_m"]
    row["map_f1_ratio"] = s["map_f1"] / s["map_f1_true_poses"]
    # Batches fitted, and batches that ended with a nonzero estimate applied (with
    # --sim-heading-bias 0, each is a batch spent with a false bias applied; one gate
    # firing kept over several batches counts in each, so this is not the count of
    # gate firings).
    row["calibration_batches"] = agent.calibration_batches
    row["calibration_batches_applied"] = agent.calibration_batches_applied
    row["wall_s"] = round(time.perf_counter() - t0, 1)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", nargs="+", required=True)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--only", choices=("on", "off"), default=None)
    ap.add_argument("--sim-heading-bias", type=float, default=None)
    ap.add_argument("--bias-sd", choices=BIAS_SD_CHOICES, default="prior")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    if a.sim_heading_bias is not None and not math.isfinite(a.sim_heading_bias):
        ap.exit(2, f"--sim-heading-bias: {a.sim_heading_bias} is not a finite number\n")
    modes = [True, False] if a.only is None else [a.only == "on"]
    rows = []
    for name in a.maps:
        plan = map_of(name)
        for seed in a.seeds:
            for calibrate in modes:
                row = run(plan, name, seed, a.duration, calibrate, a.sim_heading_bias, a.bias_sd)
                print(json.dumps(row), flush=True)
                rows.append(row)
    if a.json is not None:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
