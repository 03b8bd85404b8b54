"""Why a map misses a door: each door's walls, crossing and width (issue 39, diagnostic).

A door is detected (:func:`sonarmap.metrics.measure_passage`) when the walls beside both
jambs are closed (share >= ``WALL_SHARE``), a free path crosses it, and its recovered
width is within the tolerance of the true one. For each door of the *training* ``suite``
scenes (rooms off a corridor; issue 39's readings: acoustic, 2 % outliers, 1 cm noise)
walked by each rig, this names the first of those that fails, per method setting, and
counts them.

Run with ``python -m benchmarks.doors [--seeds 0 1] [--rigs ...] --variant "METHOD K=V"
... -o out/doors``; writes ``doors.csv`` there and prints the counts per rig and setting.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pandas as pd

from benchmarks.rigs import OFFICE_MODEL, RIGS, parse_variant
from sonarmap.mappers import make_mapper
from sonarmap.metrics import PassageResult, measure_passage
from sonarmap.scenarios import make_scenario, model_from_dict


def verdict(r: PassageResult) -> str:
    """The first test a door fails, in the order ``crossed``, ``walls``, ``width``."""
    if r.detected:
        return "detected"
    if not r.crossed:
        return "closed"
    if not r.open:
        return "walls"
    return "width"


def run(rigs: Sequence[str], seeds: Sequence[int], variants: Sequence[str]) -> pd.DataFrame:
    """One row per (rig, seed, setting, door)."""
    rows = []
    for rig in rigs:
        for seed in seeds:
            scene = make_scenario(
                "suite", rig=rig, seed=seed, model=model_from_dict(dict(OFFICE_MODEL))
            )
            for text in variants:
                method, params = parse_variant(text)
                m = make_mapper(method, **params).fit(scene.readings, scene.truth.grid, scene.rig)
                result = m.result()
                for p in scene.passages:
                    r = measure_passage(scene.truth, result, p)
                    rows.append(
                        {
                            "rig": rig,
                            "seed": seed,
                            "setting": text,
                            "door": p.name,
                            "true_width": r.true_width,
                            "width": r.width,
                            "wall_a": r.walls[0],
                            "wall_b": r.walls[1],
                            "crossed": r.crossed,
                            "verdict": verdict(r),
                        }
                    )
    return pd.DataFrame(rows)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", type=Path, default=Path("out/doors"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--rigs", nargs="+", default=list(RIGS), choices=RIGS)
    ap.add_argument("--variant", action="append", required=True, help='"METHOD K=V ..."')
    args = ap.parse_args(argv)
    if max(args.seeds) >= 1000:
        ap.error("--seeds: suite is a training family; seeds are 0 to 999")
    df = run(args.rigs, args.seeds, args.variant)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / "doors.csv", index=False)
    counts = df.groupby(["rig", "setting", "verdict"], sort=False).size().unstack(fill_value=0)
    print(counts.to_string())


if __name__ == "__main__":
    main()
