"""Where a method's false-occupied cells lie against the walls (issue 39, thick walls).

On the *training* maps of a sweep file (default ``sweeps/rigs6-robust.yaml``: eight
scenes at seeds 0 and 1, MaxSonar EZ1s, HC-SR04s and a Polaroid ring), the map of
``--method`` at its defaults (or ``--param K=V``) is compared with the truth, and each
false-occupied cell (occupied in the map, free in the truth) is counted by

- its distance to the nearest true obstacle cell (within one cell, two, farther);
- for those within two cells, its side: *in front* when a straight line from some
  sensor position within the sensor's range reaches its centre without crossing a true
  obstacle cell (the side the beams come from), *behind* otherwise (a cell the wall
  shadows);
- which readings reach it, in the gradient method's problem (with ``--param`` when the
  method is the gradient's, at its defaults otherwise): some
  Omega_free (a beam crosses it), only Omega_occ bands (no reading says it is empty),
  or none;
- whether part of it is wall in the scene's fine geometry (the truth marks a cell
  occupied when its centre is inside an obstacle).

Then, per map, the median number of echo bands and free beams reaching the cells next
to a wall that the map gets right and wrong, and the bands' detectability ``sum v w0``;
and, for that gradient map, what emptying each occupied cell
alone would change in its objective (:func:`~sonarmap.mappers.gradient.emptying_costs`),
for the false cells next to a wall, the wall's surface cells and the wall's cells behind
its surface; with ``--polish L1 ...``, the scores of that map polished
(:func:`~sonarmap.mappers.gradient.polish`) with each sparsity weight.
Training scenes only: held-out families and seeds are refused.

Run with ``python -m benchmarks.wall_thickness [--sweep sweeps/rigs6-robust.yaml]
[--method gradient] [--param K=V ...] [--polish L1 ...]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Sequence
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from benchmarks.rigs import parse_variant
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import ForwardProblem, make_mapper
from sonarmap.mappers.gradient import GradientMapper, emptying_costs, polish
from sonarmap.metrics import observed_walls, score
from sonarmap.scenarios import Scenario, make_scenario, model_from_dict
from sonarmap.splits import check_training
from sonarmap.sweep import load_sweep

B = npt.NDArray[np.bool_]
F64 = npt.NDArray[np.float64]


def training_scenes(path: str) -> list[tuple[str, int, Scenario]]:
    """The sweep file's scenes, each at each of its seeds (training only)."""
    cfg = load_sweep(path)
    out = []
    for name, params in cfg.scenarios.items():
        p: dict[str, Any] = dict(params)
        kind = str(p.pop("scenario", name))
        if "model" in p:
            p["model"] = model_from_dict(dict(p["model"]))
        for seed in cfg.seeds:
            check_training(kind, seed, where=f"{path}: {name}")
            out.append((name, seed, make_scenario(kind, seed=seed, **p)))
    return out


def in_front(scene: Scenario, rows: npt.NDArray[np.intp], cols: npt.NDArray[np.intp]) -> B:
    """Per cell, whether some sensor position (on a 2-cell lattice) within the sensor's
    range sees its centre along a line that crosses no true obstacle cell (the last half
    cell before the centre not counted)."""
    g = scene.truth.grid
    h = g.resolution
    t = scene.truth.classes() == 1
    xy = np.c_[scene.readings.x, scene.readings.y]
    pts = np.unique(np.round(xy / (2 * h)).astype(np.int64), axis=0) * (2 * h)
    r_max = scene.rig.sensor.r_max
    ox, oy = g.origin
    out = np.zeros(len(rows), bool)
    for i, (r, c) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True)):
        wx, wy = ox + (c + 0.5) * h, oy + (r + 0.5) * h
        near = pts[np.hypot(pts[:, 0] - wx, pts[:, 1] - wy) < r_max]
        if len(near) == 0:
            continue
        length = np.hypot(near[:, 0] - wx, near[:, 1] - wy)
        f = np.linspace(0.0, 1.0, int(np.ceil(length.max() / (h / 3))) + 1)[None, :]
        sx = near[:, :1] + (wx - near[:, :1]) * f
        sy = near[:, 1:2] + (wy - near[:, 1:2]) * f
        stop = (1.0 - 0.5 * h / np.maximum(length, 1e-9))[:, None]
        rr = np.clip(((sy - oy) / h).astype(np.int64), 0, g.rows - 1)
        cc = np.clip(((sx - ox) / h).astype(np.int64), 0, g.cols - 1)
        blocked = (t[rr, cc] & (f < stop)).any(axis=1)
        out[i] = bool((~blocked).any())
    return out


def wall_share(scene: Scenario) -> F64 | None:
    """Per cell of the truth's grid, the share of it that is obstacle in the fine
    geometry (None without one)."""
    geo = scene.geometry
    if geo is None:
        return None
    g = scene.truth.grid
    k = round(g.resolution / geo.grid.resolution)
    fine = np.nan_to_num(geo.occupancy) > 0.5
    pad = np.zeros((g.rows * k, g.cols * k), bool)
    # The geometry's grid shares the truth's origin (lower-left corner) and may be a
    # few fine cells short of k times the truth's shape.
    a, b = min(pad.shape[0], fine.shape[0]), min(pad.shape[1], fine.shape[1])
    if g.origin != geo.grid.origin:
        return None
    pad[:a, :b] = fine[:a, :b]
    return np.asarray(pad.reshape(g.rows, k, g.cols, k).mean(axis=(1, 3)), dtype=np.float64)


def gradient_problem(scene: Scenario, params: dict[str, Any]) -> tuple[ForwardProblem, F64]:
    """The gradient method's problem with ``params`` (its defaults otherwise), with the
    robust form's final weights, and its solution, both over the problem's cells."""
    m = GradientMapper(**params).fit(scene.readings, scene.truth.grid, scene.rig)
    p = dataclasses.replace(m.problem(scene.readings), v=m.term_weights_)
    x = m.solution_
    assert x is not None
    return p, np.clip(x, 0.0, 1.0)


def reach(scene: Scenario, p: ForwardProblem) -> tuple[F64, F64, F64]:
    """Per cell: how many Omega_occ bands and Omega_free beams of the problem ``p``
    reach it, and the bands' detectability ``sum v w0`` (v the terms' weights)."""
    g = scene.truth.grid
    v = np.ones(p.n_terms) if p.v is None else p.v
    W = p.W.tocsc()
    col = np.repeat(np.arange(p.n_cells), np.diff(W.indptr))
    occ = p.is_occ[W.indices]
    w0 = W.data / p.X0[W.indices]

    def total(mask: B, weights: F64) -> F64:
        out = np.zeros(g.size)
        np.add.at(out, p.cells[col[mask]], weights[mask])
        return out.reshape(g.shape)

    ones = np.ones(len(occ))
    return total(occ, ones), total(~occ, ones), total(occ, v[W.indices] * w0)


def on_grid(scene: Scenario, p: ForwardProblem, x: F64) -> OccupancyMap:
    """The map ``x`` over ``p.cells`` on the truth's grid (unknown elsewhere)."""
    g = scene.truth.grid
    occ = np.full(g.size, np.nan, np.float32)
    occ[p.cells] = x
    return OccupancyMap(g, occ.reshape(g.shape))


def diagnose(
    name: str,
    seed: int,
    scene: Scenario,
    method: str,
    params: dict[str, Any],
    polish_l1: Sequence[float] = (),
) -> None:
    """Print one map's counts (see the module notes)."""
    g = scene.truth.grid
    p, x = gradient_problem(scene, params if method == "gradient" else {})
    if method == "gradient":
        res = on_grid(scene, p, x)
    else:
        res = make_mapper(method, **params).fit(scene.readings, g, scene.rig).result()
    observed = observed_walls(scene.truth, scene.rig, scene.readings)
    s = score(scene.truth, res, scene.passages, scene.obstacles, observed)
    tcls = scene.truth.classes()
    t, scored = tcls == 1, tcls != -1
    occ = np.nan_to_num(res.occupancy) > 0.5
    fp = occ & ~t & scored
    d = ndimage.distance_transform_edt(~t)
    depth = ndimage.distance_transform_edt(t)
    n_occ, n_free, det = reach(scene, p)
    near2 = fp & (d <= 2.01)
    front = np.zeros(g.shape, bool)
    front[near2] = in_front(scene, *np.nonzero(near2))
    freed = n_free > 0
    only_occ = ~freed & (n_occ > 0)
    share = wall_share(scene)
    near1 = fp & (d <= 1.01)
    part = "" if share is None else f", of these part wall {int(np.sum(near1 & (share > 0)))}"
    print(
        f"{name} {seed}: wall F1 {s.f1_all:.3f} (precision {s.precision_all:.3f}, recall "
        f"{s.recall_all:.3f}), false-occupied {int(fp.sum())}: within 1 cell "
        f"{int(near1.sum())}{part}; within 2 {int(near2.sum())}: in front "
        f"{int(np.sum(near2 & front))} (a beam crosses {int(np.sum(near2 & front & freed))}, "
        f"only bands {int(np.sum(near2 & front & only_occ))}), behind "
        f"{int(np.sum(near2 & ~front))} (a beam crosses {int(np.sum(near2 & ~front & freed))}, "
        f"only bands {int(np.sum(near2 & ~front & only_occ))}), no reading "
        f"{int(np.sum(near2 & (n_occ + n_free == 0)))}; farther {int(np.sum(fp & ~near2))}",
        flush=True,
    )
    groups = {
        "false-occupied next to a wall": near1,
        "wall surface found": occ & t & (depth <= 1.01),
        "wall surface missed, in a band": ~occ & t & (depth <= 1.01) & (n_occ > 0),
        "free next to a wall, in a band": ~occ & ~t & scored & (d <= 1.01) & (n_occ > 0),
    }
    for label, mask in groups.items():
        if not mask.any():
            continue
        print(
            f"    {label}: {int(mask.sum())} cells, median bands {np.median(n_occ[mask]):.0f}, "
            f"beams {np.median(n_free[mask]):.0f}, band detectability "
            f"{np.median(det[mask]):.2f}",
            flush=True,
        )
    # What emptying each occupied cell of the gradient's map alone changes in its
    # objective: whether the extra cells are the objective's choice or the solver's.
    cost = np.full(g.size, np.nan)
    cost[p.cells] = emptying_costs(p, x)
    cost = cost.reshape(g.shape)
    full = np.zeros(g.size, bool)
    full[p.cells] = x > 0.5
    full = full.reshape(g.shape)
    groups = {
        "false-occupied next to a wall": full & ~t & scored & (d <= 1.01),
        "wall surface": full & t & (depth <= 1.01),
        "wall behind its surface": full & t & (depth > 1.01),
    }
    for label, mask in groups.items():
        if not mask.any():
            continue
        q = np.percentile(cost[mask], [25, 50, 75])
        print(
            f"    gradient, emptying one cell: {label}: {int(mask.sum())} cells, lowers S "
            f"for {int(np.sum(cost[mask] < 0))}; change quartiles {q[0]:.4f} {q[1]:.4f} "
            f"{q[2]:.4f}",
            flush=True,
        )
    for l1 in polish_l1:
        sp = score(scene.truth, on_grid(scene, p, polish(p, x, l1)), scene.passages, (), observed)
        print(
            f"    gradient polished, l1 {l1}: wall F1 {sp.f1_all:.3f} (precision "
            f"{sp.precision_all:.3f}, recall {sp.recall_all:.3f}), observed walls "
            f"{sp.observed_wall_recall:.3f}, passage F1 {sp.passage_f1:.3f}, quality "
            f"{sp.quality:.3f}",
            flush=True,
        )


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", default="sweeps/rigs6-robust.yaml")
    ap.add_argument("--method", default="gradient")
    ap.add_argument("--param", action="append", default=[], help="K=V (repeatable)")
    ap.add_argument(
        "--polish",
        type=float,
        nargs="+",
        default=[],
        help="also score the gradient's map polished with these sparsity weights",
    )
    args = ap.parse_args(argv)
    _, params = parse_variant(" ".join([args.method, *args.param]))
    for name, seed, scene in training_scenes(args.sweep):
        diagnose(name, seed, scene, args.method, params, args.polish)


if __name__ == "__main__":
    main()
