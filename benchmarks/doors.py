"""Why a map misses a door: each door's walls, crossing and width (issue 39, diagnostic).

A door is detected (:func:`sonarmap.metrics.measure_passage`) when the walls beside both
jambs are closed (share >= ``WALL_SHARE``), a free path crosses it, and its recovered
width is within the tolerance of the true one. For each door of the *training* ``suite``
scenes (rooms off a corridor; issue 39's readings: acoustic, 2 % outliers, 1 cm noise)
walked by each rig, this names the first of those that fails, per method setting, and
counts them.

With ``--evidence`` it weighs instead what the inverse model (at its defaults) adds to
the walls beside the jambs (the 0.3 m next to each jamb that the detection asks to be
closed) and to the other observed wall cells: per cell, the summed fall-off weights of
the readings whose echo band holds it and of those whose free region holds it, and the
log-odds they add up to (before clamping). Where a wall cell's free weight comes from
is split by how far beyond the cell the reading's echo lay (:data:`BEYOND`, metres) and
by the cell's angle off the beam's axis (within the fall-off's standard deviation or
not), as shares of that free weight (the ``from_`` columns). No-echo readings take no
part: the inverse ignores them at its defaults.

Run with ``python -m benchmarks.doors [--seeds 0 1] [--rigs ...] --variant "METHOD K=V"
... -o out/doors``; writes ``doors.csv`` there and prints the counts per rig and setting
(``--evidence``: ``evidence.csv`` and the means per rig).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

if __name__ == "__main__":
    # One core per run, set before numba is imported; not when a test imports the
    # helpers (numba in the test's process may already have started its threads).
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import math

import numpy as np
import numpy.typing as npt
import pandas as pd

from benchmarks.rigs import OFFICE_MODEL, RIGS, parse_variant
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.metrics import JAMB_LENGTH, PassageResult, measure_passage, observed_walls
from sonarmap.raster import CellSet, rasterise
from sonarmap.scenarios import Scenario, make_scenario, model_from_dict


def verdict(r: PassageResult) -> str:
    """The first test a door fails, in the order ``crossed``, ``walls``, ``width``."""
    if r.detected:
        return "detected"
    if not r.crossed:
        return "closed"
    if not r.open:
        return "walls"
    return "width"


#: Bins of how far beyond a wall cell the echo of a reading whose free region holds the
#: cell lay, metres: an echo just behind the wall (the wall's far side or the band's
#: edge), one from a surface near it, one from far down the beam (the wall missed).
BEYOND = (0.3, 1.0)


def jamb_walls(scene: Scenario) -> npt.NDArray[np.bool_]:
    """The truth's wall cells within ``JAMB_LENGTH`` of a jamb, along its wall, flat."""
    xc, yc = scene.truth.grid.all_centres()
    h = scene.truth.grid.resolution
    out = np.zeros(scene.truth.grid.shape, dtype=bool)
    for p in scene.passages:
        (ax, ay), (bx, by) = p.a, p.b
        ux, uy = (bx - ax) / p.width, (by - ay) / p.width
        mx, my = (ax + bx) / 2, (ay + by) / 2
        along = (xc - mx) * ux + (yc - my) * uy
        across = -(xc - mx) * uy + (yc - my) * ux
        beyond = np.abs(along) - p.width / 2
        out |= (beyond >= 0) & (beyond < JAMB_LENGTH) & (np.abs(across) <= p.depth / 2 + h / 2)
    return (out & (scene.truth.occupancy > 0.5)).reshape(-1)


def evidence(rigs: Sequence[str], seeds: Sequence[int]) -> pd.DataFrame:
    """Per (rig, seed, cell group), the mean occupied and free weight a wall cell takes
    from the inverse model at its defaults, and the log-odds they sum to."""
    inv = InverseMapper()
    l_occ = math.log(inv.p_occ / (1 - inv.p_occ))
    l_free = math.log(inv.p_free / (1 - inv.p_free))
    sigma = math.radians(inv.falloff_deg)
    rows = []
    for rig in rigs:
        for seed in seeds:
            scene = make_scenario(
                "suite", rig=rig, seed=seed, model=model_from_dict(dict(OFFICE_MODEL))
            )
            g, r = scene.truth.grid, scene.readings
            echo = r.range < scene.rig.sensor.r_max
            fp = rasterise(
                g,
                scene.rig.sensor,
                r.x[echo],
                r.y[echo],
                r.theta[echo],
                r.range[echo],
                dr=inv.dr,
                offset=inv.band_offset_for(g),
                with_bearing=True,
            )
            sums = []
            for cs in (fp.occ, fp.free):
                assert cs.bearing is not None
                w = np.exp(-(cs.bearing.astype(np.float64) ** 2) / (2 * sigma**2))
                sums.append(np.bincount(cs.cells, weights=w, minlength=g.size))
            parts = free_parts(fp.free, r.range[echo], sigma, g.size)
            jamb = jamb_walls(scene)
            seen = observed_walls(scene.truth, scene.rig, r).reshape(-1)
            for group, cells in (("beside a jamb", jamb), ("other observed walls", seen & ~jamb)):
                occ, free = sums[0][cells], sums[1][cells]
                total = max(float(free.sum()), 1e-12)
                shares = {k: float(v[cells].sum()) / total for k, v in parts.items()}
                rows.append(
                    shares
                    | {
                        "rig": rig,
                        "seed": seed,
                        "cells": group,
                        "n": int(cells.sum()),
                        "occupied_weight": float(occ.mean()),
                        "free_weight": float(free.mean()),
                        "log_odds": float(np.mean(occ * l_occ + free * l_free)),
                        "share_positive": float(np.mean(occ * l_occ + free * l_free > 0)),
                    }
                )
    return pd.DataFrame(rows)


def free_parts(
    free: CellSet, ranges: npt.NDArray[np.float64], sigma: float, n_cells: int
) -> dict[str, npt.NDArray[np.float64]]:
    """Per cell, the fall-off weight of the free regions that hold it, split by how far
    beyond the cell the echo lay (:data:`BEYOND`) and by the cell's angle off the axis
    (within ``sigma`` radians or not)."""
    assert free.bearing is not None
    b = free.bearing.astype(np.float64)
    w = np.exp(-(b**2) / (2 * sigma**2))
    beyond = ranges[free.reading_index()] - free.distance.astype(np.float64)
    near, mid = BEYOND
    masks = {
        f"from_echo_within_{near}m": beyond < near,
        f"from_echo_{near}_{mid}m": (beyond >= near) & (beyond < mid),
        f"from_echo_beyond_{mid}m": beyond >= mid,
        "from_on_axis": np.abs(b) <= sigma,
    }
    return {
        k: np.bincount(free.cells, weights=w * m, minlength=n_cells).astype(np.float64)
        for k, m in masks.items()
    }


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
    ap.add_argument("--variant", action="append", default=[], help='"METHOD K=V ..."')
    ap.add_argument("--evidence", action="store_true", help="weigh the jambs' walls instead")
    args = ap.parse_args(argv)
    if max(args.seeds) >= 1000:
        ap.error("--seeds: suite is a training family; seeds are 0 to 999")
    if args.evidence:
        ev = evidence(args.rigs, args.seeds)
        args.out.mkdir(parents=True, exist_ok=True)
        ev.to_csv(args.out / "evidence.csv", index=False)
        cols = ["n", "occupied_weight", "free_weight", "log_odds", "share_positive"]
        cols += [c for c in ev.columns if c.startswith("from_")]
        print(ev.groupby(["rig", "cells"], sort=False)[cols].mean().round(3).to_string())
        return
    if not args.variant:
        ap.error("--variant: give at least one (or --evidence)")
    df = run(args.rigs, args.seeds, args.variant)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / "doors.csv", index=False)
    counts = df.groupby(["rig", "setting", "verdict"], sort=False).size().unstack(fill_value=0)
    print(counts.to_string())


if __name__ == "__main__":
    main()
