"""Where each method's wall cells go wrong on the HC-SR04 training floors (issue 39).

Issue 39 asks that the best offline forward method beat the inverse by 0.05 wall F1 on
held-out floors mapped by every sensor preset; on the HC-SR04 office (the narrow-beam
rig) it does not. This script counts, on *training* maps only (the scenes of a sweep
file whose name holds ``--only``, default the HC-SR04 scenes of
``sweeps/rigs8-band.yaml``: the hall and the ``suite`` floor at seeds 0 and 1), each
method's cells by error class against the truth:

- ``tp``: wall cells marked occupied;
- false occupied (free in the truth): ``fp front`` within two cells of a wall on the
  side the beams come from, ``fp behind`` within two cells in the wall's shadow (see
  :func:`benchmarks.wall_thickness.in_front`), ``fp far`` farther than two cells;
- missed walls: ``fn surface`` a wall cell next to free space that some echo's band
  reached, ``fn unheard`` one next to free space that no echo's band reached,
  ``fn inside`` a wall cell deeper than one cell (no sonar sees it), ``fn beyond``
  a wall cell no reading's beam reaches, with or without an echo (out of range or never
  faced: no method can find it);
- ``corner``: of the false and missed cells, those within two cells of a corner (a wall
  cell with free space on two perpendicular sides, or a free cell with wall on two).

The echo bands are the gradient method's (at its defaults, or ``--param K=V``), so
"reached" means what the forward model's occ terms see. With ``--reach`` each map also
prints, for the gradient, the median number of echo bands and free beams on its false
cells in front of walls and on the wall surface it finds. Training scenes only:
held-out families and seeds are refused.

Run with ``python -m benchmarks.hcsr04_margin [--sweep sweeps/rigs8-band.yaml] [--only
hcsr04] [--methods inverse gradient em em-thrun stochastic] [--param K=V ...]
[--reach]``. ``--report CSV ...`` instead prints, from sweeps' ``results.csv`` files
over those 16 maps, the gradient's means per rig and setting, the passages it detected
(summed) and its margin over the inverse per rig (the pages' acceptance rules' figures).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from typing import Any, cast

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from benchmarks.rigs import parse_variant
from benchmarks.wall_thickness import in_front, reach, training_scenes
from sonarmap.mappers import make_mapper
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.metrics import observed_walls, score
from sonarmap.scenarios import Scenario

B = npt.NDArray[np.bool_]

#: The error classes, in the table's order.
CLASSES = (
    "tp",
    "fp front",
    "fp behind",
    "fp far",
    "fn surface",
    "fn unheard",
    "fn inside",
    "fn beyond",
    "fp corner",
    "fn corner",
)


def corner_zone(wall: B, scored: B) -> B:
    """Cells within two cells of a corner: a wall cell with free 4-neighbours on two
    perpendicular sides (convex) or a free cell with wall on two (concave)."""
    free = scored & ~wall

    def sides(mask: B) -> tuple[B, B]:
        p = np.pad(mask, 1)
        horizontal = p[1:-1, :-2] | p[1:-1, 2:]
        vertical = p[:-2, 1:-1] | p[2:, 1:-1]
        return horizontal, vertical

    fh, fv = sides(free)
    wh, wv = sides(wall)
    corner = (wall & fh & fv) | (free & wh & wv)
    return np.asarray(ndimage.binary_dilation(corner, iterations=2), dtype=bool)


def reached(scene: Scenario) -> B:
    """Cells some reading's beam reaches, echo or not."""
    g = scene.truth.grid
    cells = GradientMapper(no_echo="free").start(g, scene.rig).problem(scene.readings).cells
    out = np.zeros(g.size, bool)
    out[cells] = True
    return out.reshape(g.shape)


def classify(
    scene: Scenario, occupancy: npt.NDArray[np.floating[Any]], bands: B, known: B
) -> dict[str, int]:
    """Counts of :data:`CLASSES` for one map (``bands``: cells some echo's band
    reaches; ``known``: cells some beam reaches)."""
    cls = scene.truth.classes()
    wall, scored = cls == 1, cls != -1
    occ = np.nan_to_num(occupancy) > 0.5
    d = ndimage.distance_transform_edt(~wall)
    depth = ndimage.distance_transform_edt(wall)
    fp = occ & ~wall & scored
    near = fp & (d <= 2.01)
    front = np.zeros(wall.shape, bool)
    front[near] = in_front(scene, *np.nonzero(near))
    fn = wall & ~occ
    surface = depth <= 1.01
    corner = corner_zone(wall, scored)
    return {
        "tp": int(np.sum(occ & wall)),
        "fp front": int(np.sum(near & front)),
        "fp behind": int(np.sum(near & ~front)),
        "fp far": int(np.sum(fp & ~near)),
        "fn surface": int(np.sum(fn & known & surface & bands)),
        "fn unheard": int(np.sum(fn & known & surface & ~bands)),
        "fn inside": int(np.sum(fn & known & ~surface)),
        "fn beyond": int(np.sum(fn & ~known)),
        "fp corner": int(np.sum(fp & corner)),
        "fn corner": int(np.sum(fn & corner)),
    }


def run(
    sweep: str, only: str, methods: Sequence[str], params: dict[str, Any], show_reach: bool
) -> list[tuple[str, int, str, float, dict[str, int]]]:
    """One row per (map, method): name, seed, method, wall F1 and the class counts."""
    rows = []
    for name, seed, scene in training_scenes(sweep):
        if only not in name:
            continue
        g = scene.truth.grid
        p = GradientMapper(**params).start(g, scene.rig).problem(scene.readings)
        n_occ, n_free, _ = reach(scene, p)
        bands = n_occ > 0
        known = reached(scene)
        observed = observed_walls(scene.truth, scene.rig, scene.readings)
        for method in methods:
            kw = params if method == "gradient" else {}
            m = make_mapper(method, **kw).fit(scene.readings, g, scene.rig).result()
            s = score(scene.truth, m, scene.passages, scene.obstacles, observed)
            counts = classify(scene, m.occupancy, bands, known)
            rows.append((name, seed, method, s.f1_all, counts))
            print(
                f"{name} {seed} {method}: wall F1 {s.f1_all:.3f} (precision "
                f"{s.precision_all:.3f}, recall {s.recall_all:.3f}); "
                + ", ".join(f"{k} {v}" for k, v in counts.items()),
                flush=True,
            )
            if show_reach and method == "gradient":
                occ = np.nan_to_num(m.occupancy) > 0.5
                cls = scene.truth.classes()
                wall = cls == 1
                d = ndimage.distance_transform_edt(~wall)
                depth = ndimage.distance_transform_edt(wall)
                groups = {
                    "false, next to a wall": occ & ~wall & (cls != -1) & (d <= 1.01),
                    "wall surface found": occ & wall & (depth <= 1.01),
                    "wall surface missed, in a band": ~occ & wall & (depth <= 1.01) & bands,
                }
                for label, mask in groups.items():
                    if mask.any():
                        print(
                            f"    {label}: {int(mask.sum())} cells, median echo bands "
                            f"{np.median(n_occ[mask]):.0f}, free beams "
                            f"{np.median(n_free[mask]):.0f}",
                            flush=True,
                        )
    return rows


def table(rows: list[tuple[str, int, str, float, dict[str, int]]], base: str) -> str:
    """Sums over the maps per method, and each method minus ``base``."""
    methods = list(dict.fromkeys(r[2] for r in rows))
    head = "| method | maps | mean wall F1 | " + " | ".join(CLASSES) + " |"
    lines = [head, "|" + "---|" * (len(CLASSES) + 3)]
    total: dict[str, dict[str, int]] = {}
    for method in methods:
        mine = [r for r in rows if r[2] == method]
        total[method] = {k: sum(r[4][k] for r in mine) for k in CLASSES}
        f1 = float(np.mean([r[3] for r in mine]))
        cells = " | ".join(f"{total[method][k]:,}" for k in CLASSES)
        lines.append(f"| {method} | {len(mine)} | {f1:.3f} | {cells} |")
    if base in total:
        for method in methods:
            if method == base:
                continue
            diff = " | ".join(f"{total[method][k] - total[base][k]:+,}" for k in CLASSES)
            lines.append(f"| {method} minus {base} | | | {diff} |")
    return "\n".join(lines)


#: The rig of each training scene of ``sweeps/rigs8-band.yaml`` (the others: MaxSonar).
SCENE_RIG = {
    "hall-hcsr04": "hcsr04",
    "suite-hcsr04": "hcsr04",
    "hall-ring16": "ring16",
    "suite-ring16": "ring16",
}


def report(paths: Sequence[str]) -> str:
    """The gradient's means per setting and rig, the passages it detected and its
    margin over the inverse per rig, from sweeps' ``results.csv``."""
    import pandas as pd

    d = pd.concat([pd.read_csv(p) for p in paths], ignore_index=True)
    d["rig"] = d["scenario"].map(lambda s: SCENE_RIG.get(s, "ez1"))
    inverse = {
        str(k): float(v)
        for k, v in d[d["method"] == "inverse"].groupby("rig")["f1_all"].mean().items()
    }
    g = d[d["method"] == "gradient"]
    cols = ["f1_all", "quality", "precision_all", "recall_all", "passage_f1"]
    lines = [
        "| setting | rig | maps | wall F1 | quality | precision | recall | passage F1 "
        "| passages detected | minus inverse |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, part in g.groupby(["params", "rig"], sort=True):
        params, rig = (str(k) for k in cast(tuple[Any, Any], key))
        r = part[cols].mean()
        margin = f"{r.f1_all - inverse[rig]:+.3f}" if rig in inverse else ""
        lines.append(
            f"| {params} | {rig} | {len(part)} | {r.f1_all:.3f} | {r.quality:.3f} | "
            f"{r.precision_all:.3f} | {r.recall_all:.3f} | {r.passage_f1:.3f} | "
            f"{int(part['passages_detected'].sum())} | {margin} |"
        )
    for setting, part in g.groupby("params", sort=True):
        lines.append(
            f"| {setting!s} | all | {len(part)} | {part['f1_all'].mean():.3f} | "
            f"{part['quality'].mean():.3f} | | | | {int(part['passages_detected'].sum())} | |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", default="sweeps/rigs8-band.yaml")
    ap.add_argument("--only", default="hcsr04", help="scenes whose name holds this")
    ap.add_argument(
        "--methods", nargs="+", default=["inverse", "gradient", "em", "em-thrun", "stochastic"]
    )
    ap.add_argument("--param", action="append", default=[], help="gradient K=V (repeatable)")
    ap.add_argument("--reach", action="store_true", help="print the gradient's reach counts")
    ap.add_argument("--report", nargs="+", help="sweeps' results.csv: print their means")
    args = ap.parse_args(argv)
    if args.report:
        print(report(args.report))
        return
    _, params = parse_variant(" ".join(["gradient", *args.param]))
    rows = run(args.sweep, args.only, args.methods, params, args.reach)
    print(table(rows, "inverse"))


if __name__ == "__main__":
    main()
