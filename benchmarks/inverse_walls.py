"""Why the inverse misses the walls the sonars heard (issue 39, diagnostic, training only).

For each training map of a sweep file (by default ``sweeps/rigs7-inverse-specular.yaml``:
the hall, ``suite``, ``doorways`` and noisy ``passages`` scenes of issue 39, seeds 0 and
1), maps the scene with the inverse at the given setting (its defaults unless
``--param``) and sorts every observed wall cell (:func:`sonarmap.metrics.observed_walls`)
the map does not mark occupied by why, from the increments the model adds to it (the
fall-off weights of the readings whose echo band holds the cell and of those whose free
region holds it, as :mod:`benchmarks.doors` weighs them; the free ones by the free
increment's own fall-off when the setting gives one, ``falloff_free_deg``):

- ``order``: the log-odds the increments add up to (before clamping) are > 0 but the
  clamped, reading-by-reading sum is not (the clamping bounds and the readings' order);
  tested first, so that a faint cell the clamps lost counts here;
- ``faint``: otherwise, the bands that hold it weigh less than :data:`FAINT` in all
  (the cell lies far off the axis of every echo that put its range on it: the
  fall-off);
- ``outvoted``: otherwise (the unclamped sum is <= 0 and the bands are not faint) --
  the free regions of other readings outweigh the bands;
- (a missed cell no reading touched cannot be observed.)

For the ``outvoted`` cells, the free weight is split by how far beyond the cell the
reading's echo lay (:data:`benchmarks.doors.BEYOND`): an echo under 0.3 m beyond is the
free arc stopping just short of a wall (its own far side or the band's near edge);
farther, a beam that crossed the wall without an echo from it. Also the observed-wall
recall the unclamped sums would give with each part of the free weight taken away
(what each part costs).

Run with ``python -m benchmarks.inverse_walls [--sweep FILE] [--scenes NAME ...]
[--param K=V ...] -o out/inverse-walls``; writes ``walls.csv`` and prints the table.
``--rule GRADIENT_CSV INVERSE_CSV ...`` prints the acceptance rule's training figures
per inverse setting instead (:func:`rule_table`); inverse files whose settings were
mapped on different maps (several sweeps' files each with its defaults' rows, a sweep
cut short, a scene missing) are refused.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

if __name__ == "__main__":
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import math

import numpy as np
import pandas as pd

from benchmarks.doors import BEYOND
from benchmarks.rigs import parse_variant
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.metrics import observed_walls
from sonarmap.raster import rasterise
from sonarmap.scenarios import Scenario, make_scenario, model_from_dict
from sonarmap.sweep import load_sweep

#: Total band weight below which a missed cell counts as ``faint``.
FAINT = 0.05
#: Fractions of the echo's range for the stop-short counterfactuals.
STOPS = (0.05, 0.1, 0.15, 0.2)
SWEEP = Path("sweeps/rigs7-inverse-specular.yaml")


def scene_of(params: dict[str, Any], seed: int) -> Scenario:
    """The sweep entry ``params`` (its ``scenario`` key the family) at ``seed``."""
    p = dict(params)
    kind = p.pop("scenario")
    if "model" in p:
        p["model"] = model_from_dict(dict(p["model"]))
    return make_scenario(kind, seed=seed, **p)


def diagnose(scene: Scenario, inv: InverseMapper) -> dict[str, float]:
    """The observed wall cells of ``scene`` the map of ``inv`` keeps and misses, by why."""
    g, r, sensor = scene.truth.grid, scene.readings, scene.rig.sensor
    occ_map = inv.fit(r, g, scene.rig).result().occupancy.reshape(-1)
    seen = observed_walls(scene.truth, scene.rig, r).reshape(-1)
    echo = r.range < sensor.r_max
    fp = rasterise(
        g,
        sensor,
        r.x[echo],
        r.y[echo],
        r.theta[echo],
        r.range[echo],
        dr=inv.dr,
        offset=inv.band_offset_for(g),
        with_bearing=True,
        free_stop=inv.free_stop_for(sensor),
    )

    def fall(b: np.ndarray[Any, np.dtype[np.float32]] | None, deg: float) -> np.ndarray[Any, Any]:
        assert b is not None
        if deg == 0:
            return np.ones(len(b))
        s = math.radians(deg)
        bb = b.astype(np.float64)
        return np.exp(-(bb * bb) / (2 * s * s))

    w_occ = np.bincount(
        fp.occ.cells, weights=fall(fp.occ.bearing, inv.falloff_deg), minlength=g.size
    )
    # The free increment's own fall-off, when the mapper has one (falloff_free_deg).
    wf = fall(fp.free.bearing, inv.free_falloff_deg)
    beyond = r.range[echo][fp.free.reading_index()] - fp.free.distance.astype(np.float64)
    near, mid = BEYOND
    parts = {
        "near": beyond < near,
        "mid": (beyond >= near) & (beyond < mid),
        "far": beyond >= mid,
    }
    w_free = {
        k: np.bincount(fp.free.cells, weights=wf * m, minlength=g.size) for k, m in parts.items()
    }
    free = w_free["near"] + w_free["mid"] + w_free["far"]
    l_occ, l_free = math.log(inv.p_occ / (1 - inv.p_occ)), math.log(inv.p_free / (1 - inv.p_free))
    total = w_occ * l_occ + free * l_free
    kept = np.nan_to_num(occ_map, nan=0.0) > 0.5
    missed = seen & ~kept
    # The clamps first: a cell whose unclamped sum is positive was lost to them and the
    # readings' order, however faint its bands.
    order = missed & (total > 0)
    faint = missed & ~order & (w_occ < FAINT)
    outvoted = missed & ~order & ~faint
    n = max(int(seen.sum()), 1)
    fo = max(float(free[outvoted].sum()), 1e-12)
    out: dict[str, float] = {
        "observed": float(seen.sum()),
        "recall": float(kept[seen].mean()),
        "recall_unclamped": float((total[seen] > 0).mean()),
        "faint": float(faint.sum()) / n,
        "outvoted": float(outvoted.sum()) / n,
        "order": float(order.sum()) / n,
        "occ_weight_kept": float(w_occ[seen & kept].mean()) if (seen & kept).any() else math.nan,
        "occ_weight_outvoted": float(w_occ[outvoted].mean()) if outvoted.any() else math.nan,
        "free_weight_outvoted": float(free[outvoted].mean()) if outvoted.any() else math.nan,
    }
    for k, v in w_free.items():
        out[f"outvoted_free_{k}"] = float(v[outvoted].sum()) / fo
        # The recall the unclamped sums would give without this part of the free weight.
        out[f"recall_without_{k}"] = float(((total - v * l_free)[seen] > 0).mean())
    rel = beyond / r.range[echo][fp.free.reading_index()]
    for stop in STOPS:
        # Without the free weight of the readings whose echo lay less than ``stop`` of
        # its range beyond the cell: a free region that stops that share short.
        near_r = np.bincount(fp.free.cells, weights=wf * (rel < stop), minlength=g.size)
        out[f"outvoted_free_within_{stop}r"] = float(near_r[outvoted].sum()) / fo
        out[f"recall_stop_{stop}r"] = float(((total - near_r * l_free)[seen] > 0).mean())
    return out


def run(sweep: Path, scenes: Sequence[str], params: dict[str, Any]) -> pd.DataFrame:
    cfg = load_sweep(sweep)
    rows = []
    for name, sp in cfg.scenarios.items():
        if scenes and name not in scenes:
            continue
        for seed in cfg.seeds:
            row = diagnose(scene_of(sp, seed), InverseMapper(**params))
            rows.append({"scene": name, "seed": seed} | row)
            print(
                f"{name} {seed}: recall {row['recall']:.3f}, faint {row['faint']:.3f}, "
                f"outvoted {row['outvoted']:.3f}, order {row['order']:.3f}",
                flush=True,
            )
    return pd.DataFrame(rows)


#: The rig of each training map of the sweep (its scene's name).
RIG_OF = {
    "hall-ez1": "ez1-six",
    "suite-ez1": "ez1-six",
    "doorways": "ez1-six",
    "passages-noisy": "ez1-six",
    "hall-hcsr04": "hcsr04-six",
    "suite-hcsr04": "hcsr04-six",
    "hall-ring16": "ring16",
    "suite-ring16": "ring16",
}


#: The training maps' rigs, in the order the tables give them.
RIGS = ("ez1-six", "hcsr04-six", "ring16")


def rig_figures(d: pd.DataFrame) -> dict[str, Any]:
    """The acceptance rules' training figures of one setting's sweep rows ``d``.

    Returns the mean quality, the mean observed-wall recall on ``hall-ez1`` and over
    the MaxSonar maps, the passages detected in all and per rig (``passages_RIG``) and
    the mean wall F1 per rig (``f1_RIG``), for each rig of :data:`RIGS`. A figure of
    a scene or rig ``d`` has no rows of is NaN.
    """
    rig = d["scenario"].map(RIG_OF)
    row: dict[str, Any] = {
        "quality": d["quality"].mean(),
        "ez1_hall_observed": d.loc[d.scenario == "hall-ez1", "observed_wall_recall"].mean(),
        "ez1_observed": d.loc[rig == "ez1-six", "observed_wall_recall"].mean(),
        "passages": int(d["passages_detected"].sum()),
    }
    for r in RIGS:
        mine = d[rig == r]
        row[f"passages_{r}"] = int(mine["passages_detected"].sum()) if len(mine) else math.nan
    for r in RIGS:
        row[f"f1_{r}"] = d.loc[rig == r, "f1_all"].mean()
    return row


#: The ``params`` of the defaults' rows in a sweep's results.csv.
DEFAULTS = "(defaults)"


def refuse_uneven(fig: pd.DataFrame) -> None:
    """Refuse per-setting figures ``fig`` (columns ``setting``, ``maps`` and figures)
    that compare settings mapped on different maps.

    Raises
    ------
    ValueError
        No row of the defaults; a setting mapped on a number of maps other than the
        defaults' (e.g. the rows of several sweeps pooled, each with its defaults, or a
        sweep cut short); a figure that is NaN (a scene or rig with no rows), which no
        comparison would catch.
    """
    base = fig.loc[fig.setting == DEFAULTS]
    if len(base) != 1:
        raise ValueError("no row of the defaults: run the sweep with include_defaults")
    b = base.iloc[0]
    for _, r in fig.iterrows():
        if r.maps != b.maps:
            raise ValueError(
                f"setting {r.setting!r} has {r.maps} maps, the defaults {b.maps}: "
                "give one complete sweep's results.csv"
            )
        nan = [str(k) for k, v in r.items() if isinstance(v, float) and math.isnan(v)]
        if nan:
            raise ValueError(f"setting {r.setting!r}: no figure for {', '.join(nan)}")


def rule_table(inverse: pd.DataFrame, gradient: pd.DataFrame) -> pd.DataFrame:
    """Per inverse setting of sweep results ``inverse``, the acceptance rule's training
    figures (docs/results/2026-12-07-inverse-walls.md), the forward margin against the
    gradient rows of ``gradient``; the defaults' row first.

    Raises
    ------
    ValueError
        As :func:`refuse_uneven` (the margins counted as figures), or gradient rows on
        a number of maps other than the inverse defaults'.
    """
    grad = gradient.assign(rig=gradient["scenario"].map(RIG_OF)).groupby("rig")["f1_all"].mean()
    rows = []
    for setting, d in inverse.groupby("params", sort=False):
        row: dict[str, Any] = {"setting": setting, "maps": len(d), **rig_figures(d)}
        for r in RIGS:
            row[f"margin_{r}"] = grad.get(r, math.nan) - row[f"f1_{r}"]
        rows.append(row)
    table = pd.DataFrame(rows)
    refuse_uneven(table)
    base = int(table.loc[table.setting == DEFAULTS, "maps"].iloc[0])
    if len(gradient) != base:
        raise ValueError(f"the gradient has {len(gradient)} maps, the inverse defaults {base}")
    return table.drop(columns="maps")


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", type=Path, default=Path("out/inverse-walls"))
    ap.add_argument("--sweep", type=Path, default=SWEEP)
    ap.add_argument("--scenes", nargs="*", default=[])
    ap.add_argument("--param", nargs="*", default=[], help="inverse K=V ...")
    ap.add_argument(
        "--rule",
        type=Path,
        nargs="+",
        help="GRADIENT_CSV INVERSE_CSV ...: print the acceptance rule's training figures "
        "of the sweeps' inverse settings and run nothing",
    )
    args = ap.parse_args(argv)
    if args.rule:
        if len(args.rule) < 2:
            ap.error("--rule needs GRADIENT_CSV and at least one INVERSE_CSV")
        for p in args.rule:
            if not p.is_file():
                ap.error(f"{p}: no such file")
        grad = pd.read_csv(args.rule[0])
        inv = pd.concat([pd.read_csv(p) for p in args.rule[1:]], ignore_index=True)
        try:
            table = rule_table(inv[inv.method == "inverse"], grad[grad.method == "gradient"])
        except ValueError as e:
            ap.error(f"--rule {' '.join(map(str, args.rule[1:]))}: {e}")
        with pd.option_context("display.width", 250, "display.max_columns", 30):
            print(table.round(3))
        return
    _, params = parse_variant(" ".join(["inverse", *args.param]))
    df = run(args.sweep, args.scenes, params)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / "walls.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(df.groupby("scene", sort=False).mean(numeric_only=True).drop(columns="seed").round(3))


if __name__ == "__main__":
    main()
