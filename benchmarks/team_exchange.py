"""A team's exchange against its claims (issue 15): bandwidth, double counting, identical
maps, and the team's map against the central upper bound.

``--robots`` robots (3) patrol random waypoints on the office floor plan (or
``--plan building:N``) for ``--duration`` seconds (300), every one mapping with sonars
and stereo landmarks and exchanging over the simulated network
(:func:`sonarmap.team.simulation.run_team`). Settings:

- networks ``full``, ``limited`` (70 m range with line of sight) and ``none``; on the
  first two each protocol: the thesis's ``good`` and ``limited`` (cap T = ``--caps``'
  first value) and the ``naive`` baseline (every new pose to everyone); on ``none``
  nothing is exchanged, whatever the protocol, so one run;
- on the full network, the limited protocol as its cap T shrinks (``--caps``: 64k, 16k,
  4k, 1k, 256 bytes), and at the first cap with a budget per robot (``--budgets``:
  2000, 1000, 500 bytes/s of answers, :attr:`~sonarmap.team.exchange.ExchangeParams.budget`);
- on the full network, the good protocol with a store that folds a deleted pose's map
  into the newest pose (``--fold``), and lean settings (``--lean K:HOLD``, each also
  folding): landmarks only on every K-th pose
  (:attr:`~sonarmap.team.exchange.ExchangeParams.anchor_every`) and own poses offered
  once HOLD seconds old (:attr:`~sonarmap.team.exchange.ExchangeParams.hold`);
- quantised (``--quantised BITS:T``, 3:1): the good protocol (folding) and the naive
  baseline with descriptors of BITS bits and, if T is 1, ternary local maps as they
  travel (:attr:`~sonarmap.team.exchange.ExchangeParams.descriptor_bits`,
  :attr:`~sonarmap.team.exchange.ExchangeParams.ternary_maps`); a lean setting may add
  the same (``--lean K:HOLD:BITS:T``), and anchors also where loops close
  (``--lean K:HOLD:BITS:T:L`` with L 1,
  :attr:`~sonarmap.team.exchange.ExchangeParams.loop_anchors`). A quantised row's
  share is of the exact naive baseline's bytes (the one the issue names), and is also
  printed against the naive baseline quantised alike, when that row ran;
- the central upper bound (:func:`sonarmap.team.central.central_map`: one graph and map
  from every pose every robot made), once: the robots' data are the same in every
  setting.

``--groups`` picks which of these run: ``main`` (the three networks with every
protocol), ``caps``, ``budgets``, ``lean`` (the fold and lean rows) and ``quantised``;
all by default.

Per setting: bytes per robot-minute (message bodies, deflated as sent, while the robots
drive and in the quiet phase after, over the minutes of driving: the maps are scored
after the quiet phase, so a protocol that defers its sending pays for it) and their
share of the naive baseline's on the same network, ``map_f1_team`` (the mean of
the robots' global-map wall F1), duplicate poses, identical pose sets after the network
was quiet, the seconds that took, and the share of the other robots' poses a robot held
when the routes ended (what a hold keeps back). Then the issue's targets, each ``holds`` or
``FAILS``. Nothing here is tuned to make a target hold.

Run with ``python -m benchmarks.team_exchange [--plan office] [--robots 3]
[--duration 300] [--seed 0] [--caps 65536 16384 4096 1024 256] [--budgets 2000 1000 500]
[--lean 4:30 8:30 8:60 8:120] [--quantised 3:1]
[--groups main caps budgets lean quantised] [--jobs 2] [--plot FILE]
[--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from benchmarks.team import plan_by_name
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams
from sonarmap.team.simulation import run_team
from sonarmap.team.store import StoreParams

#: The goal of the issue: the team's F1 within this of the central bound...
F1_GAP = 0.05
#: ...at no more than this share of the naive baseline's bytes.
BYTES_SHARE = 0.2


def _one(
    plan_name: str, robots: int, duration: float, seed: int, setting: dict[str, Any]
) -> dict[str, Any]:
    """One team run; its summary's figures and the setting."""
    t0 = time.perf_counter()
    s = run_team(
        plan_by_name(plan_name),
        MissionConfig(
            duration=duration, seed=seed, store=StoreParams(fold=setting.get("fold", False))
        ),
        robots,
        network=NetworkParams(kind=setting["network"]),
        exchange=ExchangeParams(
            mode=setting["mode"],
            cap_bytes=setting["cap"],
            budget=setting["budget"],
            anchor_every=setting.get("anchors", 1),
            hold=setting.get("hold", 0.0),
            descriptor_bits=setting.get("bits", 8),
            ternary_maps=setting.get("ternary", False),
            loop_anchors=setting.get("loops", False),
        ),
        seed=seed,
        central=setting.get("central", False),
    ).summary
    keys = (
        "bytes_per_robot_minute",
        "bytes_per_robot_minute_all",
        "map_f1_team",
        "map_f1_central",
        "central",
        "duplicate_poses",
        "identical_maps",
        "map_agreement",
        "convergence_s",
        "settled",
        "settle_seconds",
        "held_share_at_routes_end",
    )
    row = {**setting, **{k: s[k] for k in keys}}
    row["poses_local"] = sum(r["poses_local"] for r in s["robots"])
    row["poses_received"] = sum(r["poses_received"] for r in s["robots"])
    row["wall_s"] = time.perf_counter() - t0
    return row


GROUPS = ("main", "caps", "budgets", "lean", "quantised")

#: A lean setting: landmarks on every K-th pose, a hold (s), descriptor bits, ternary maps,
#: loop anchors.
Lean = tuple[int, float, int, bool, bool]


def settings(
    caps: list[int],
    budgets: list[float],
    lean: list[Lean] | None = None,
    groups: tuple[str, ...] = GROUPS,
    quantised: tuple[int, bool] = (3, True),
) -> list[dict[str, Any]]:
    """Every run, the first the one that also builds the central bound (the full
    network's naive baseline is always run: shares are of its bytes)."""
    out: list[dict[str, Any]] = []
    plain = {"cap": caps[0], "budget": 0.0, "curve": False}
    for network in ("full", "limited"):
        for mode in ("good", "limited", "naive"):
            if "main" in groups or (network, mode) == ("full", "naive"):
                out.append({"network": network, "mode": mode, **plain})
    out[0]["central"] = True
    if "main" in groups:
        out.append({"network": "none", "mode": "good", **plain})
    if "caps" in groups:
        for cap in caps[1:]:
            out.append(
                {"network": "full", "mode": "limited", "cap": cap, "budget": 0.0, "curve": True}
            )
    if "budgets" in groups:
        for b in budgets:
            out.append(
                {"network": "full", "mode": "limited", "cap": caps[0], "budget": b, "curve": True}
            )
    if "lean" in groups:
        out.append({"network": "full", "mode": "good", **plain, "curve": True, "fold": True})
        for k, hold, bits, ternary, loops in lean or []:
            out.append(
                {
                    "network": "full",
                    "mode": "good",
                    **plain,
                    "curve": True,
                    "fold": True,
                    "anchors": k,
                    "hold": hold,
                    "bits": bits,
                    "ternary": ternary,
                    "loops": loops,
                }
            )
    if "quantised" in groups:
        # The baseline sending what the protocol sends quantised: the saving that is the
        # quantisation's alone, beside the protocol's.
        bits, ternary = quantised
        for mode, fold in (("good", True), ("naive", False)):
            out.append(
                {
                    "network": "full",
                    "mode": mode,
                    **plain,
                    "curve": True,
                    "fold": fold,
                    "bits": bits,
                    "ternary": ternary,
                }
            )
    return out


def measure(
    plan_name: str,
    robots: int,
    duration: float,
    seed: int,
    caps: list[int],
    budgets: list[float],
    jobs: int,
    lean: list[Lean] | None = None,
    groups: tuple[str, ...] = GROUPS,
    quantised: tuple[int, bool] = (3, True),
) -> list[dict[str, Any]]:
    todo = settings(caps, budgets, lean, groups, quantised)
    if jobs <= 1:
        return [_one(plan_name, robots, duration, seed, s) for s in todo]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(_one, plan_name, robots, duration, seed, s) for s in todo]
        return [f.result() for f in futures]


def _naive(rows: list[dict[str, Any]], network: str) -> float:
    return next(
        float(r["bytes_per_robot_minute_all"])
        for r in rows
        if r["network"] == network and r["mode"] == "naive" and not r["curve"]
    )


def _naive_alike(rows: list[dict[str, Any]], r: dict[str, Any]) -> float | None:
    """The bytes of the full network's naive baseline quantised as ``r`` is, if ``r`` is
    quantised and that row was run."""
    q = (r.get("bits", 8), r.get("ternary", False))
    if q == (8, False):
        return None
    for x in rows:
        if (
            x["mode"] == "naive"
            and x["network"] == "full"
            and (x.get("bits", 8), x.get("ternary", False)) == q
        ):
            return float(x["bytes_per_robot_minute_all"])
    return None


def targets(rows: list[dict[str, Any]], central: float) -> list[tuple[str, bool]]:
    """The issue's targets, each with whether these rows meet it."""
    naive = _naive(rows, "full")
    full = [r for r in rows if r["network"] == "full"]
    good_enough = [
        r
        for r in full
        if r["map_f1_team"] >= central - F1_GAP
        and r["bytes_per_robot_minute_all"] <= BYTES_SHARE * naive
    ]
    best = ", ".join(_name(r) for r in good_enough) or "none"
    # A budget leaves poses behind by design; identical sets are asked of the caps alone.
    limited = [r for r in full if r["mode"] == "limited" and not r["budget"]]
    starved = ", ".join(str(r["cap"]) for r in limited if not r["identical_maps"]) or "none"
    alike = [
        r
        for r in full
        if r["mode"] != "naive" and (naive_alike := _naive_alike(rows, r)) is not None
        if r["map_f1_team"] >= central - F1_GAP
        and r["bytes_per_robot_minute_all"] <= BYTES_SHARE * naive_alike
    ]
    ran_alike = any(_naive_alike(rows, r) is not None for r in full if r["mode"] != "naive")
    against_alike = (
        [
            (
                "the same against the naive baseline quantised alike (settings that do: "
                f"{', '.join(_name(r) for r in alike) or 'none'})",
                bool(alike),
            )
        ]
        if ran_alike
        else []
    )
    return [
        (
            "0 duplicate poses in every robot's graph in every setting",
            all(r["duplicate_poses"] == 0 for r in rows),
        ),
        (
            "identical pose sets on every robot with full connectivity, good protocol "
            "(the thesis's claim)",
            all(r["identical_maps"] for r in full if r["mode"] == "good"),
        ),
        (
            f"the same with the limited protocol at every cap T (caps that do not: {starved})",
            all(r["identical_maps"] for r in limited),
        ),
        (
            f"team F1 within {F1_GAP} of central at <= {100 * BYTES_SHARE:.0f} % of naive's "
            f"bytes on the full network (settings that do: {best})",
            bool(good_enough),
        ),
        *against_alike,
    ]


def _name(r: dict[str, Any]) -> str:
    fold = ", fold" if r.get("fold") else ""
    if r.get("bits", 8) < 8:
        fold += f", {r['bits']}-bit descriptors"
    if r.get("ternary"):
        fold += ", ternary maps"
    if r.get("anchors", 1) > 1 or r.get("hold", 0.0) > 0:
        loops = " + loops" if r.get("loops") else ""
        return (
            f"{r['mode']}, anchors 1/{r.get('anchors', 1)}{loops}, "
            f"hold {r.get('hold', 0.0):.0f} s{fold}"
        )
    if r["mode"] != "limited":
        return f"{r['mode']}{fold}"
    budget = f", {r['budget']:.0f} B/s" if r["budget"] else ""
    return f"limited T={r['cap']}{budget}{fold}"


def _lean(text: str) -> Lean:
    k_text, sep, rest = text.partition(":")
    hold_text, _, tail = rest.partition(":")
    try:
        k, hold = int(k_text), float(hold_text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"K:HOLD, K:HOLD:BITS:T or K:HOLD:BITS:T:L expected (e.g. 8:30 or 8:30:3:1:1), "
            f"got {text!r}"
        ) from None
    if not sep or k < 1 or not (math.isfinite(hold) and hold >= 0):
        raise argparse.ArgumentTypeError(f"K >= 1 and HOLD >= 0 expected, got {text!r}")
    quant, loops = tail, False
    if tail.count(":") == 2:
        quant, _, loops_text = tail.rpartition(":")
        if loops_text not in ("0", "1"):
            raise argparse.ArgumentTypeError(f"L must be 0 or 1, got {text!r}")
        loops = loops_text == "1"
    bits, ternary = parse_quantised(quant) if quant else (8, False)
    return k, hold, bits, ternary, loops


def parse_quantised(text: str) -> tuple[int, bool]:
    bits_text, sep, t_text = text.partition(":")
    try:
        bits, ternary = int(bits_text), int(t_text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"BITS:T expected (e.g. 3:1), got {text!r}") from None
    if not sep or not 1 <= bits <= 8 or ternary not in (0, 1):
        raise argparse.ArgumentTypeError(f"BITS in 1..8 and T 0 or 1 expected, got {text!r}")
    return bits, bool(ternary)


def _plot(rows: list[dict[str, Any]], central: float, path: str) -> None:
    """Team F1 against bytes (% of naive) for every setting on the full network, and
    the robots alone at 0 bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    naive = _naive(rows, "full")
    fig, ax = plt.subplots(figsize=(7, 4.5))
    marks = {"good": "o", "limited": "s", "naive": "^"}
    for r in rows:
        if r["network"] not in ("full", "none"):
            continue
        x = 0.0 if r["network"] == "none" else 100 * r["bytes_per_robot_minute_all"] / naive
        label = "no network" if r["network"] == "none" else _name(r)
        ax.plot(x, r["map_f1_team"], marks.get(r["mode"], "o"), color="black")
        ax.annotate(
            label, (x, r["map_f1_team"]), fontsize=6, xytext=(3, 3), textcoords="offset points"
        )
    ax.axhline(central, color="green", ls="--", label="central bound")
    ax.axhline(central - F1_GAP, color="green", ls=":", label=f"central - {F1_GAP}")
    ax.axvline(100 * BYTES_SHARE, color="grey", ls=":", label=f"{100 * BYTES_SHARE:.0f} % of naive")
    ax.set_xlabel("bytes per robot-minute, % of the naive baseline's")
    ax.set_ylabel("team wall F1")
    ax.legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--plan", default="office", help="office, or building:SEED")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--caps", type=int, nargs="+", default=[65536, 16384, 4096, 1024, 256])
    parser.add_argument(
        "--budgets", type=float, nargs="*", default=[2000.0, 1000.0, 500.0], help="Bytes/s."
    )
    parser.add_argument(
        "--lean",
        type=_lean,
        nargs="*",
        default=[
            (4, 30.0, 8, False, False),
            (8, 30.0, 8, False, False),
            (8, 60.0, 8, False, False),
            (8, 120.0, 8, False, False),
        ],
        help="K:HOLD[:BITS:T[:L]], landmarks on every K-th pose (and, L = 1, where loops "
        "close), poses offered HOLD s old, descriptors of BITS bits and (T = 1) ternary "
        "local maps as they travel.",
    )
    parser.add_argument(
        "--quantised",
        type=parse_quantised,
        default=(3, True),
        help="BITS:T of the quantised group's rows (the good protocol and the naive "
        "baseline, both quantised so).",
    )
    parser.add_argument("--groups", nargs="+", choices=GROUPS, default=list(GROUPS))
    parser.add_argument("--jobs", type=int, default=2, help="Runs at once (processes).")
    parser.add_argument("--plot", help="Also draw the cap curve to this PNG.")
    parser.add_argument("--json", help="Also write the rows to this JSON file.")
    args = parser.parse_args()
    if args.robots < 2:
        raise SystemExit(f"--robots: a team needs >= 2 robots, got {args.robots}")
    plan_by_name(args.plan)  # a bad --plan fails before any run
    t0 = time.perf_counter()
    rows = measure(
        args.plan,
        args.robots,
        args.duration,
        args.seed,
        args.caps,
        args.budgets,
        args.jobs,
        args.lean,
        tuple(args.groups),
        args.quantised,
    )
    wall = time.perf_counter() - t0
    c = rows[0]["central"]
    central = float(rows[0]["map_f1_central"])
    print(
        f"team exchange, {args.plan} plan, {args.robots} robots, {args.duration:.0f} s, "
        f"seed {args.seed}"
    )
    print(
        f"central bound: map F1 {central:.3f} from {c['poses']} poses, {c['closures']} "
        f"closures ({c['closures_correct']} correct, {c['closures_rejected_by_graph']} "
        f"rejected by the graph), ATE {c['ate_m']:.3f} m, {c['wall_seconds']:.0f} s"
    )
    print("network  setting: B/robot-min (% naive), team F1 (- central), dup, identical,")
    print("          converged s, poses local/received, held at the routes' end, wall s")
    for r in rows:
        has_naive = r["network"] != "none" and any(
            x["network"] == r["network"] and x["mode"] == "naive" for x in rows
        )
        naive = _naive(rows, r["network"]) if has_naive else math.nan
        share = 100 * r["bytes_per_robot_minute_all"] / naive if naive else math.nan
        conv = r["convergence_s"]
        print(
            f"{r['network']:8} {_name(r)}: "
            f"{r['bytes_per_robot_minute_all']:9.0f} "
            f"({share:5.1f} %), F1 {r['map_f1_team']:.3f} ({r['map_f1_team'] - central:+.3f}), "
            f"dup {r['duplicate_poses']}, identical {r['identical_maps']} (maps agree on "
            f"{100 * r['map_agreement']:.1f} %), converged "
            f"{'never' if conv is None else f'{conv:.1f}'}, poses {r['poses_local']}/"
            f"{r['poses_received']}, held {100 * r['held_share_at_routes_end']:.0f} %, "
            f"{r['wall_s']:.0f} s"
        )
        alike = _naive_alike(rows, r)
        if alike and r["mode"] != "naive":
            like = 100 * r["bytes_per_robot_minute_all"] / alike
            print(f"         ({like:.1f} % of the naive baseline quantised alike)")
    print("targets:")
    for name, ok in targets(rows, central):
        print(f"  {'holds' if ok else 'FAILS'}: {name}")
    print(f"wall {wall:.0f} s with {args.jobs} job(s)")
    if args.plot:
        _plot(rows, central, args.plot)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
