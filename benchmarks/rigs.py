"""Every method on held-out floors mapped by each sensor preset (issue 39).

For each rig preset (``ez1-six``: six MaxSonar EZ1s; ``hcsr04-six``: six HC-SR04s;
``ring16``: 16 Polaroid 6500s) and each held-out family:

- ``office`` (the default): a 10 m office floor, four rooms off a corridor, toured once
  (130 s at 0.5 m/s, every sonar at 5 Hz), acoustic readings with 2 % outliers and 1 cm
  noise (issue 39's user run, on a smaller floor);
- ``corridor``: the held-out corridor with its doors and rooms, acoustic readings at the
  model's defaults;
- ``hall``: the *training* L-shaped hall (issue 39's second user run), acoustic readings
  at the model's defaults, sonars at 10 Hz: to reproduce the issue, never a claim (it
  takes any seed);

every method is run at its defaults (``new``) and at the defaults before issue 39
(``old``, :data:`OLD_DEFAULTS`), and scored against the truth: wall F1, observed-wall
recall (:func:`sonarmap.metrics.observed_walls`), passage F1, false openings, the
tuning objective and the seconds the map took (one thread). Held-out seeds only
(``--seeds``, from 1000).

Run with ``python -m benchmarks.rigs [--seeds 1000] [--rigs ...] [--families office
corridor] [--methods ...] [--which old new] [--variant "METHOD K=V ..."] -o
out/rigs-heldout``; writes ``results.csv`` there and prints one table per rig
(``--report CSV ...`` prints the tables of earlier runs).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

if __name__ == "__main__":
    # One core per run, set before numba is imported; not when benchmarks.doors or a
    # test imports this module (numba may already have started its threads there).
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pandas as pd

from sonarmap.mappers import make_mapper
from sonarmap.metrics import observed_walls, score
from sonarmap.scenarios import Scenario, make_scenario, model_from_dict
from sonarmap.splits import held_out_seeds

RIGS = ("ez1-six", "hcsr04-six", "ring16")
FAMILIES = ("office", "corridor", "hall")
METHODS = ("inverse", "counting", "gradient", "em", "em-thrun", "stochastic")
#: What runs unless ``--methods`` says otherwise: stochastic costs the most and was not
#: re-tuned.
DEFAULT_METHODS = ("inverse", "counting", "gradient", "em", "em-thrun")

#: Each method's defaults before issue 39 (docs/results/2026-11-22-mapper-defaults.md).
OLD_DEFAULTS: dict[str, dict[str, Any]] = {
    "inverse": {
        "p_occ": 0.52,
        "p_free": 0.48,
        "falloff_deg": 10.0,
        "no_echo": "ignore",
        "dr": None,
    },
    "counting": {"no_echo": "ignore", "dr": 0.025, "band_offset": None},
    "gradient": {"a1": 0.3, "a2": 0.03, "c1": 10.0, "c2": 1.0, "no_echo": "free"},
    "em": {"p_rand": 0.1, "p_hit": 0.75, "sigma": 0.03},
    "em-thrun": {"p_rand": 0.1, "p_hit": 0.75, "sigma": 0.05},
    "stochastic": {"p_rand": 0.05, "p_hit": 0.3, "w_occ": 0.0, "w_border": -0.005},
}

#: The office floor of the benchmark: four 5 m rooms off a 2 m corridor, toured once.
OFFICE = {
    "size": 10.0,
    "rooms": 2,
    "door_widths": (1.0, 0.8, 0.9, 0.7),
    "duration": 130.0,
    "rate": 5.0,
}
#: Issue 39's readings on the office floor: acoustic, 2 % outliers, 1 cm noise.
OFFICE_MODEL = {"kind": "acoustic", "p_rand": 0.02, "sigma": 0.01}


def held_out_scene(family: str, rig: str, seed: int) -> Scenario:
    """The benchmark's held-out scene of ``family`` mapped by the preset ``rig``."""
    if family == "hall":
        return make_scenario("hall", rig=rig, seed=seed)
    if family == "office":
        return make_scenario(
            "office", rig=rig, seed=seed, model=model_from_dict(dict(OFFICE_MODEL)), **OFFICE
        )
    return make_scenario(family, rig=rig, seed=seed)


def parse_variant(text: str) -> tuple[str, dict[str, Any]]:
    """``"METHOD K=V K=V"`` as the method and its parameters (true / false, integers and
    numbers where they parse).

    Examples
    --------
    >>> parse_variant("gradient a2=0.2 max_iter=30 convex_start=true no_echo=free")
    ('gradient', {'a2': 0.2, 'max_iter': 30, 'convex_start': True, 'no_echo': 'free'})
    """
    method, *pairs = text.split()
    params: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        if value in ("true", "false"):
            params[key] = value == "true"
            continue
        for kind in (int, float, str):
            try:
                params[key] = kind(value)
                break
            except ValueError:
                continue
    return method, params


def run(
    rigs: Sequence[str],
    families: Sequence[str],
    seeds: Sequence[int],
    methods: Sequence[str],
    which: Sequence[str],
    variants: Sequence[str] = (),
) -> pd.DataFrame:
    """One row per (rig, family, seed, method, defaults), then one per variant (its
    text in ``defaults``)."""
    rows = []
    for rig in rigs:
        for family in families:
            for seed in seeds:
                scene = held_out_scene(family, rig, seed)
                observed = observed_walls(scene.truth, scene.rig, scene.readings)
                runs = [
                    (method, label, OLD_DEFAULTS[method] if label == "old" else {})
                    for method in methods
                    for label in which
                ]
                for text in variants:
                    method, params = parse_variant(text)
                    runs.append((method, " ".join(text.split()[1:]), params))
                for method, label, params in runs:
                    t0 = time.perf_counter()
                    mapper = make_mapper(method, **params)
                    m = mapper.fit(scene.readings, scene.truth.grid, scene.rig).result()
                    seconds = time.perf_counter() - t0
                    s = score(scene.truth, m, scene.passages, scene.obstacles, observed)
                    rows.append(
                        {
                            "rig": rig,
                            "family": family,
                            "seed": seed,
                            "method": method,
                            "defaults": label,
                            "readings": len(scene.readings.t),
                            "seconds": seconds,
                            **s.as_dict(),
                        }
                    )
                    print(
                        f"{rig} {family} {seed} {method} {label}: wall F1 {s.f1_all:.3f}, "
                        f"observed walls {s.observed_wall_recall:.3f}, passage F1 "
                        f"{s.passage_f1:.3f}, false openings {s.false_openings}, "
                        f"{seconds:.1f} s",
                        flush=True,
                    )
    return pd.DataFrame(rows)


def markdown(df: pd.DataFrame) -> str:
    """One table per rig: each method at old and new defaults, means over the scenes."""
    cols = ["f1_all", "observed_wall_recall", "passage_f1", "false_openings", "seconds"]
    head = (
        "| method | defaults | wall F1 | observed walls | passage F1 | false openings "
        "| s / map |\n|---|---|---|---|---|---|---|"
    )
    out = []
    for rig, part in df.groupby("rig", sort=False):
        mean = part.groupby(["method", "defaults"], sort=False)[cols].mean()
        lines = [f"**{rig}** ({part['readings'].iloc[0]} readings a map)", "", head]
        for key, r in mean.iterrows():
            method, label = cast(tuple[str, str], key)
            lines.append(
                f"| {method} | {label} | {r.f1_all:.3f} | {r.observed_wall_recall:.3f} "
                f"| {r.passage_f1:.3f} | {r.false_openings:.1f} | {r.seconds:.1f} |"
            )
        out.append("\n".join(lines))
    return "\n\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", type=Path, default=Path("out/rigs-heldout"))
    ap.add_argument("--seeds", type=int, nargs="+", default=held_out_seeds(1))
    ap.add_argument("--rigs", nargs="+", default=list(RIGS), choices=RIGS)
    ap.add_argument("--families", nargs="+", default=["office"], choices=FAMILIES)
    ap.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), choices=METHODS)
    ap.add_argument("--which", nargs="+", default=["old", "new"], choices=("old", "new"))
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        help='also run "METHOD K=V ..." (repeatable), e.g. "inverse p_occ=0.6"',
    )
    ap.add_argument(
        "--report",
        type=Path,
        nargs="+",
        help="print the tables of earlier runs' results.csv files and run nothing",
    )
    args = ap.parse_args(argv)
    if args.report:
        print(markdown(pd.concat([pd.read_csv(p) for p in args.report], ignore_index=True)))
        return
    if min(args.seeds) < held_out_seeds(1)[0] and args.families != ["hall"]:
        ap.error(f"--seeds: held-out seeds start at {held_out_seeds(1)[0]}")
    df = run(args.rigs, args.families, args.seeds, args.methods, args.which, args.variant)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / "results.csv", index=False)
    print(markdown(df))


if __name__ == "__main__":
    main()
