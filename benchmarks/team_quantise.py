"""What quantising the poses as they travel costs the map, and saves in bytes (issue 15).

One team mission (``--robots`` robots on ``--plan`` for ``--duration`` s, no network: the
robots' data do not depend on it), then the central upper bound
(:func:`sonarmap.team.central.central_map`) built once per setting from every pose
quantised as it would travel (``--settings BITS:T``: descriptors of BITS bits, ternary
local maps if T is 1; ``8:0`` is exact). Per setting: the bound's wall F1, and the
deflated bytes of all the poses (as one stream, as an answer carries them) as a share of
the exact poses' bytes, and the same of the poses stripped of their landmarks (still a
share of the exact poses' bytes with landmarks).

Run with ``python -m benchmarks.team_quantise [--plan office] [--robots 3]
[--duration 300] [--seed 0] [--settings 8:0 4:0 3:0 2:0 8:1 3:1]``.
"""

from __future__ import annotations

import argparse
import os
import time
import zlib

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import msgpack
import numpy as np

from benchmarks.team import plan_by_name
from benchmarks.team_exchange import parse_quantised
from sonarmap.team.central import central_map, raw_poses
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams
from sonarmap.team.quantise import quantise_pose
from sonarmap.team.records import Pose, encode
from sonarmap.team.simulation import run_team


def _deflated(poses: list[Pose]) -> int:
    return len(zlib.compress(msgpack.packb([encode(p) for p in poses]), 6))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--plan", default="office", help="office, or building:SEED")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--settings",
        type=parse_quantised,
        nargs="+",
        default=[(8, False), (4, False), (3, False), (2, False), (8, True), (3, True)],
        help="BITS:T, descriptor bits and (T = 1) ternary maps.",
    )
    args = parser.parse_args()
    plan = plan_by_name(args.plan)
    t0 = time.perf_counter()
    team = run_team(
        plan,
        MissionConfig(duration=args.duration, seed=args.seed),
        args.robots,
        network=NetworkParams(kind="none"),
        exchange=ExchangeParams(),
        seed=args.seed,
    )
    poses = [p for a in team.agents for p in raw_poses(a)]
    bare = [p.with_landmarks(p.landmarks.take(np.zeros(0, dtype=np.intp))) for p in poses]
    exact, exact_bare = _deflated(poses), _deflated(bare)
    print(
        f"team quantisation, {args.plan} plan, {args.robots} robots, {args.duration:.0f} s, "
        f"seed {args.seed}: {len(poses)} poses, {exact} B deflated ({exact_bare} B without "
        f"landmarks); mission {time.perf_counter() - t0:.0f} s"
    )
    print("setting: central wall F1, bytes % of exact (without landmarks, % of exact), wall s")
    for bits, ternary in args.settings:
        t1 = time.perf_counter()
        bound = central_map(team.agents, seed=args.seed, descriptor_bits=bits, ternary_maps=ternary)
        share = _deflated([quantise_pose(p, bits, ternary) for p in poses]) / exact
        share_bare = _deflated([quantise_pose(p, bits, ternary) for p in bare]) / exact
        name = f"{bits}-bit descriptors{', ternary maps' if ternary else ''}"
        print(
            f"{name}: F1 {bound.summary['map_f1']:.3f}, bytes {100 * share:.1f} % "
            f"({100 * share_bare:.1f} %), {time.perf_counter() - t1:.0f} s",
            flush=True,
        )


if __name__ == "__main__":
    main()
