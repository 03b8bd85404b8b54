"""The inverse's free and occupied fall-offs apart: the acceptance rule (issue 39, training).

Reads the ``results.csv`` of ``sonarmap sweep sweeps/invwalls-freefall.yaml`` (the inverse
with ``falloff_free_deg`` and ``falloff_deg`` varied on the 16 training maps of
:mod:`benchmarks.inverse_walls`) and prints, per setting, the figures of the acceptance
rule written in docs/results/2026-12-07-inverse-free-falloff.md before any candidate was
run, and which of its parts the setting fails, against the defaults' row of the same
sweep:

1. the mean observed-wall recall on the MaxSonar training halls (``hall-ez1``) and over
   the eight MaxSonar maps each at least :data:`BAR`;
2. each rig's mean training wall F1 (``f1_all``) no lower than the defaults' by more
   than :data:`F1_DROP`;
3. passages detected, in all and on each rig, no fewer than the defaults';
4. mean wall precision (``precision_all``) no lower than the defaults' by more than
   :data:`PRECISION_DROP`;
5. mean quality no lower than the defaults' by more than :data:`QUALITY_DROP`.

Issue 14's training gaps and doorways (the rule's part 6) are mapped with
``--issue14 passages|doorways -o DIR --setting K=V,K=V ...`` (the defaults beside the
settings given) and read with ``python -m benchmarks.issue14_goals``.

Run with ``python -m benchmarks.inverse_free_falloff out/invwalls-freefall/results.csv``.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

if __name__ == "__main__":
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pandas as pd

from benchmarks.inverse_walls import RIG_OF

#: Rule 1: the observed-wall recall the MaxSonar training maps must reach.
BAR = 0.70
#: Rule 2: how far a rig's mean training wall F1 may fall.
F1_DROP = 0.01
#: Rule 4: how far the mean wall precision may fall.
PRECISION_DROP = 0.05
#: Rule 5: how far the mean quality may fall.
QUALITY_DROP = 0.005
RIGS = ("ez1-six", "hcsr04-six", "ring16")
DEFAULTS = "(defaults)"


def figures(df: pd.DataFrame) -> pd.DataFrame:
    """Per inverse setting of sweep results ``df``, the rule's training figures."""
    inv = df[df.method == "inverse"].assign(rig=lambda d: d["scenario"].map(RIG_OF))
    rows = []
    for setting, d in inv.groupby("params", sort=False):
        per_rig = d.groupby("rig")
        row: dict[str, Any] = {
            "setting": setting,
            "maps": len(d),
            "quality": d["quality"].mean(),
            "ez1_hall_observed": d.loc[d.scenario == "hall-ez1", "observed_wall_recall"].mean(),
            "ez1_observed": d.loc[d.rig == "ez1-six", "observed_wall_recall"].mean(),
            "precision": d["precision_all"].mean(),
            "passages": int(d["passages_detected"].sum()),
        }
        for rig in RIGS:
            row[f"passages_{rig}"] = int(per_rig["passages_detected"].sum()[rig])
        for rig in RIGS:
            row[f"f1_{rig}"] = per_rig["f1_all"].mean()[rig]
        rows.append(row)
    return pd.DataFrame(rows)


def verdicts(fig: pd.DataFrame) -> pd.DataFrame:
    """``fig`` (:func:`figures`) with the rule's parts 1-5 each setting fails, against
    the row of the defaults."""
    base = fig.loc[fig.setting == DEFAULTS]
    if len(base) != 1:
        raise SystemExit("the sweep has no row of the defaults: run it with include_defaults")
    b = base.iloc[0]
    fails = []
    for _, r in fig.iterrows():
        f = []
        if r.ez1_hall_observed < BAR or r.ez1_observed < BAR:
            f.append("1")
        if any(r[f"f1_{rig}"] < b[f"f1_{rig}"] - F1_DROP for rig in RIGS):
            f.append("2")
        if r.passages < b.passages or any(
            r[f"passages_{rig}"] < b[f"passages_{rig}"] for rig in RIGS
        ):
            f.append("3")
        if r.precision < b.precision - PRECISION_DROP:
            f.append("4")
        if r.quality < b.quality - QUALITY_DROP:
            f.append("5")
        fails.append(", ".join(f) or "none")
    return fig.assign(fails=fails)


def issue14(which: str, out: Path, settings: Sequence[dict[str, Any]]) -> None:
    """Issue 14's training ``which`` scenes (seeds 0-4), the inverse at its defaults and
    at each of ``settings``, into ``out`` (an ``experiment`` folder)."""
    import sonarmap.experiments as e

    specs = [e.MethodSpec("inverse", "inverse", {})]
    for s in settings:
        label = "inverse-" + "-".join(f"{k}{v}" for k, v in sorted(s.items()))
        specs.append(e.MethodSpec(label, "inverse", dict(s)))
    e.METHODS = tuple(specs)
    e.run_experiment(which, out, seed=0, seeds=5)


def _setting(text: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for part in text.split(","):
        k, _, v = part.partition("=")
        if not v:
            raise SystemExit(f"--setting {text!r}: want K=V,K=V")
        out[k.strip()] = float(v)
    return out


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, nargs="*", help="sweep results.csv files")
    ap.add_argument("--issue14", choices=("passages", "doorways"))
    ap.add_argument("-o", "--out", type=Path)
    ap.add_argument("--setting", nargs="*", default=[], help="K=V,K=V (numbers)")
    args = ap.parse_args(argv)
    if args.issue14:
        if args.out is None:
            raise SystemExit("--issue14 needs -o DIR")
        issue14(args.issue14, args.out, [_setting(s) for s in args.setting])
        return
    if not args.results:
        raise SystemExit("give sweep results.csv files, or --issue14")
    df = pd.concat([pd.read_csv(p) for p in args.results], ignore_index=True)
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(verdicts(figures(df)).round(3).to_string(index=False))


if __name__ == "__main__":
    main()
