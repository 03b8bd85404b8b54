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

Run with ``python -m benchmarks.inverse_free_falloff out/invwalls-freefall/results.csv``
(one sweep's file: each setting is scored against the defaults' rows of the same sweep,
and a file in which a setting has a map count other than the defaults' or a figure is
missing is refused).
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

from benchmarks.inverse_walls import DEFAULTS, RIGS, refuse_uneven, rig_figures
from sonarmap.errors import ConfigError
from sonarmap.experiments import MethodSpec, run_experiment
from sonarmap.mappers import make_mapper

#: Rule 1: the observed-wall recall the MaxSonar training maps must reach.
BAR = 0.70
#: Rule 2: how far a rig's mean training wall F1 may fall.
F1_DROP = 0.01
#: Rule 4: how far the mean wall precision may fall.
PRECISION_DROP = 0.05
#: Rule 5: how far the mean quality may fall.
QUALITY_DROP = 0.005


def figures(df: pd.DataFrame) -> pd.DataFrame:
    """Per inverse setting of sweep results ``df``, the rule's training figures."""
    rows = []
    for setting, d in df[df.method == "inverse"].groupby("params", sort=False):
        row: dict[str, Any] = {"setting": setting, "maps": len(d), **rig_figures(d)}
        row["precision"] = d["precision_all"].mean()
        rows.append(row)
    return pd.DataFrame(rows)


def verdicts(fig: pd.DataFrame) -> pd.DataFrame:
    """``fig`` (:func:`figures`) with the rule's parts 1-5 each setting fails, against
    the row of the defaults.

    Raises
    ------
    ValueError
        As :func:`benchmarks.inverse_walls.refuse_uneven`: no row of the defaults, a
        setting mapped on a number of maps other than the defaults', a figure that is
        NaN.
    """
    refuse_uneven(fig)
    b = fig.loc[fig.setting == DEFAULTS].iloc[0]
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


#: The columns of a sweep's results.csv the rule reads.
COLUMNS = (
    "method",
    "params",
    "scenario",
    "quality",
    "observed_wall_recall",
    "passages_detected",
    "f1_all",
    "precision_all",
)


def issue14(which: str, out: Path, settings: Sequence[dict[str, Any]]) -> None:
    """Issue 14's training ``which`` scenes (seeds 0-4), the inverse at its defaults and
    at each of ``settings``, into ``out`` (an ``experiment`` folder)."""
    specs = [MethodSpec("inverse", "inverse", {})]
    for s in settings:
        label = "inverse-" + "-".join(f"{k}{v}" for k, v in sorted(s.items()))
        specs.append(MethodSpec(label, "inverse", dict(s)))
    run_experiment(which, out, seed=0, seeds=5, methods=specs)


def _setting(text: str) -> dict[str, Any]:
    """``K=V,K=V`` (numbers) as inverse parameters.

    Raises
    ------
    ValueError
        Not of that form, a value not a number, or parameters the inverse refuses.
    """
    out: dict[str, Any] = {}
    for part in text.split(","):
        k, _, v = (x.strip() for x in part.partition("="))
        try:
            if not k:
                raise ValueError
            out[k] = float(v)
        except ValueError:
            raise ValueError(f"--setting {text!r}: want K=V,K=V with numbers") from None
    try:
        make_mapper("inverse", **out)
    except ConfigError as e:
        raise ValueError(f"--setting {text!r}: {e}") from None
    return out


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, nargs="?", help="one sweep's results.csv")
    ap.add_argument("--issue14", choices=("passages", "doorways"))
    ap.add_argument("-o", "--out", type=Path)
    ap.add_argument("--setting", nargs="*", default=[], help="K=V,K=V (numbers)")
    args = ap.parse_args(argv)
    if args.issue14:
        if args.out is None:
            ap.error("--issue14 needs -o DIR")
        try:
            settings = [_setting(s) for s in args.setting]
        except ValueError as e:
            ap.error(str(e))
        issue14(args.issue14, args.out, settings)
        return
    if args.results is None:
        ap.error("give a sweep's results.csv, or --issue14")
    if not args.results.is_file():
        ap.error(f"{args.results}: no such file")
    df = pd.read_csv(args.results)
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        ap.error(f"{args.results}: not a sweep's results.csv (no {', '.join(missing)})")
    try:
        table = verdicts(figures(df))
    except ValueError as e:
        ap.error(f"{args.results}: {e}")
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(table.round(3).to_string(index=False))


if __name__ == "__main__":
    main()
