"""Cars on street sites: DVT, never-seen share and mean MTB per planner and team size.

Setting (issue 36, goal 4): street sites of blocks with 3-6 m streets and dead-end stubs
(:func:`sonarmap.patrol.maps.street_site`; seeds below 1000 are training sites, 1000
and above held out), cars (turning radius 3.5 m, the thesis's speed rule), refinement,
mode, artificial obstacles, starts spread by farthest point (by seed). The tracking
cars' tuning defaults to the library's defaults for them
(:data:`sonarmap.patrol.simulation.CAR_DEFAULTS`, chosen on the training sites:
docs/results/2026-12-07-cars-defaults.md): they choose among the places out of their
sight with places behind them damped (``--turn-penalty 10``; ``--turn-penalty 0
--no-out-of-sight`` are the thesis's pulls), not for places they saw less than 30 s
ago behind them (``--turn-time 30``; 0: they do), drive on round the block rather
than turn round when that is at most 60 m longer, following the cars ahead going
their way (``--round-block 60``; 0: the shortest path), and their waves leave
forwards while the way ahead leads on (``--forward-wave``; ``--no-forward-wave``:
in every direction) but in every direction on the steps when the worst time since
seen exceeds 10 times the mean over the places seen at least once
(``--forward-stale 10``; 0: never); ``--one-way teams`` (the default) drives every
street narrower than the turning circle one way only (:mod:`sonarmap.patrol.oneway`)
in the runs of more than one car (``all``: every run; ``off``: none); ``--stub-sight``
has a car look down a dead-end stub
from its junction rather than drive in for a place it sees from there, and
``--stub-delay S`` has the places it must enter a stub to see pull as if seen S
seconds later (:mod:`sonarmap.patrol.stubs`; both off by default); ``--leftover M``
has a car whose place was seen go next for the places within M metres of it its look
missed (``PatrolConfig.leftover``; 0, the default: none). For each site,
planner, team size and seed one run of ``--duration`` simulated seconds, reporting:

- ``DVT``: the team's mean share of time in the dead-end escape mode, %;
- ``blocked``: the team's mean share of time a robot's move was cancelled by the
  collision rule (held by another robot, standing), %: the thesis's car escapes at
  once when held, so this time counts towards its DVT, a tracking car's only when it
  then manoeuvres in reverse;
- ``never seen``: the share of the reachable site never seen by the end, %;
- ``given up``: the share of it the cars stopped going for (never seen places they
  turned round on the way to three times, :mod:`sonarmap.patrol.giveup`), %;
- ``mean idleness``: the mean, after a fifth of the run, of the mean time since last
  seen over the places, s;
- ``mean MTB``: the mean, after a fifth of the run, of the worst time since last seen, s;
- ``DVT by cause`` (tracking cars): the DVT split by why the car manoeuvred
  (:data:`sonarmap.patrol.robots.CAUSES`: held by another car, path behind, no clear
  arc ahead, no manoeuvre found), %.

Run with ``python -m benchmarks.patrol_cars [--sites 1000 1001] [--cars 1 3 5]
[--planners track thesis] [--crowding obstacles] [--no-forward-wave]
[--forward-stale 10] [--give-up 3]
[--turn-penalty 10] [--turn-time 30] [--no-out-of-sight] [--round-block 60]
[--one-way off|teams|all]
[--stub-sight] [--stub-delay 0] [--leftover 0]
[--seeds 0]
[--duration 3600]
[--json F]``; one process, one core (``NUMBA_NUM_THREADS=1``). Each run prints one
line as it ends; the table follows.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from benchmarks.patrol import OneLineParser, non_negative
from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.maps import street_territory
from sonarmap.patrol.robots import Car, Team
from sonarmap.patrol.simulation import CAR_DEFAULTS


def car_config(
    planner: str,
    cars: int,
    crowding: str,
    duration: float,
    forward_wave: bool = False,
    forward_stale: float = 0.0,
    give_up: int = 3,
    turn_penalty: float = 10.0,
    turn_time: float = 0.0,
    out_of_sight: bool = True,
    round_block: float = 60.0,
    one_way: bool = False,
    stub_sight: bool = False,
    stub_delay: float = 0.0,
    leftover: float = 0.0,
    one_way_orient: str = "dfs",
) -> PatrolConfig:
    """The cars' configuration of one run (see the module's notes): ``crowding`` only
    with more than one car, refined paths. Every knob is given, with this function's
    defaults (no forward wave, no turn-time rule, two-way streets), unlike this
    module's command line (the library's car defaults): ``patrol_stub_ends`` and
    ``patrol_cars_oneway`` build their cars here and were measured so."""
    return PatrolConfig(
        model="car",
        car_planner=planner,
        forward_wave=forward_wave,
        forward_stale=forward_stale,
        give_up=give_up,
        turn_penalty=turn_penalty,
        turn_time=turn_time,
        out_of_sight=out_of_sight,
        round_block=round_block,
        one_way=one_way,
        one_way_orient=one_way_orient,
        stub_sight=stub_sight,
        stub_delay=stub_delay,
        leftover=leftover,
        refine=True,
        crowding=crowding if cars > 1 else "none",
        duration=duration,
    )


#: The configuration's knobs each row records after the planner and the number of cars,
#: under the row's key.
RECORDED = {
    "crowding": "crowding",
    "forward_wave": "forward_wave",
    "forward_stale": "forward_stale",
    "give_up": "give_up",
    "turn_penalty": "turn_penalty",
    "turn_time": "turn_time",
    "out_of_sight": "out_of_sight",
    "round_block": "round_block",
    "one_way": "one_way",
    "stub_sight": "stub_sight",
    "stub_delay": "stub_delay",
    "leftover": "leftover",
}


def run_one(site: int, cars: int, seed: int, config: PatrolConfig) -> dict[str, Any]:
    """One run's figures (see the module's notes), for ``cars`` cars driven by
    ``config`` (:func:`car_config`) on street site ``site``."""
    t0 = time.perf_counter()
    last: list[Team] = []

    def keep(_t: float, team: Team, _fog: Fog) -> None:
        last[:] = [team]

    result = run_patrol(street_territory(site), config, robots=cars, seed=seed, on_step=keep)
    s = result.summary()
    causes = {}
    if last and isinstance(last[0], Car) and config.car_planner == "track":
        causes = {
            k: round(float(100.0 * v.mean() / len(result.t)), 2)
            for k, v in last[0].escape_causes.items()
        }
    return {
        "site": site,
        "split": "held-out" if site >= 1000 else "training",
        "planner": config.car_planner,
        "cars": cars,
        **{key: getattr(config, field) for key, field in RECORDED.items()},
        "seed": seed,
        "duration": config.duration,
        "dvt": round(float(s["dvt"]), 2),
        "mean_idleness": round(float(s["mean_idleness"]), 1),
        "blocked": round(100 * float(s["blocked_share"]), 2),
        "never_seen": round(100 * float(s["never_seen"]), 2),
        "given_up": round(100 * float(s["given_up"]), 3),
        "mean_mtb": round(float(s["mean_mtb"]), 1),
        "dvt_by_cause": causes,
        "wall_seconds": round(time.perf_counter() - t0, 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="python -m benchmarks.patrol_cars", description=__doc__)
    ap.add_argument("--sites", type=int, nargs="+", default=[1000])
    ap.add_argument("--cars", type=int, nargs="+", default=[1, 3, 5])
    ap.add_argument("--planners", nargs="+", default=["track"])
    ap.add_argument("--crowding", default="obstacles")
    ap.add_argument(
        "--forward-wave",
        action=argparse.BooleanOptionalAction,
        default=bool(CAR_DEFAULTS["forward_wave"]),
    )
    ap.add_argument(
        "--forward-stale",
        type=float,
        default=None,
        help=f"default: {CAR_DEFAULTS['forward_stale']:g} with --forward-wave, else 0",
    )
    ap.add_argument("--give-up", type=int, default=3)
    ap.add_argument("--turn-penalty", type=float, default=float(CAR_DEFAULTS["turn_penalty"]))
    ap.add_argument("--turn-time", type=float, default=float(CAR_DEFAULTS["turn_time"]))
    ap.add_argument("--no-out-of-sight", dest="out_of_sight", action="store_false")
    ap.add_argument("--round-block", type=float, default=float(CAR_DEFAULTS["round_block"]))
    ap.add_argument("--one-way", choices=["off", "teams", "all"], default="teams")
    ap.add_argument("--stub-sight", action="store_true")
    ap.add_argument("--stub-delay", type=non_negative, default=0.0)
    ap.add_argument("--leftover", type=non_negative, default=0.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    if a.forward_stale is None:
        a.forward_stale = float(CAR_DEFAULTS["forward_stale"]) if a.forward_wave else 0.0
    elif a.forward_stale > 0 and not a.forward_wave:
        # As the library refuses it: there is no forward wave to lift.
        print("patrol_cars: --forward-stale needs --forward-wave", file=sys.stderr)
        return 2
    rows = []
    for site in a.sites:
        for planner in a.planners:
            for cars in a.cars:
                for seed in a.seeds:
                    config = car_config(
                        planner,
                        cars,
                        a.crowding,
                        a.duration,
                        forward_wave=a.forward_wave,
                        forward_stale=a.forward_stale,
                        give_up=a.give_up,
                        turn_penalty=a.turn_penalty,
                        turn_time=a.turn_time,
                        out_of_sight=a.out_of_sight,
                        round_block=a.round_block,
                        one_way=a.one_way == "all" or (a.one_way == "teams" and cars > 1),
                        stub_sight=a.stub_sight,
                        stub_delay=a.stub_delay,
                        leftover=a.leftover,
                    )
                    row = run_one(site, cars, seed, config)
                    print(json.dumps(row), flush=True)
                    rows.append(row)
                    if a.json:
                        a.json.write_text(json.dumps(rows, indent=1) + "\n")
    print("| site | split | planner | cars | DVT % | never seen % | mean MTB s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['site']} | {r['split']} | {r['planner']} | {r['cars']} | {r['dvt']:.1f} "
            f"| {r['never_seen']:.1f} | {r['mean_mtb']:.0f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
