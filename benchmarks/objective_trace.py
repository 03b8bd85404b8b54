"""Where the gradient method's objective and its map disagree (issue 14).

On held-out ``gaps`` scenes (``--seeds``, from 1000), the plain deterministic model
(``robust=0``; the robust form reweights the same terms):

1. **Solvers.** The map and the objective S, split into its free terms, occ terms and
   the tent R2, for pgd as tuned (300 steps from 0.5), pgd for 3000 steps with a 4x step,
   pgd from the inverse map, L-BFGS-B, and (``--ccp``) the convex-concave procedure.
2. **The truth.** S at the true map (a cell occupied when its centre is inside an
   obstacle), and the share of echoes whose Omega_occ band holds a true obstacle cell,
   with the band at the echo and moved ``--offset`` behind it.
3. **Gaps.** The change of S, split the same way, when one gap of the true map is
   closed (its cells set to 1) and nothing else changes.

``--param K=V`` sets the model's constants (the defaults otherwise): the constants before
the band offset were ``--param a1=0.2 --param c2=0.3 --param band_offset=0``.

Run with ``python -m benchmarks.objective_trace [--seeds 1000 1001 1002] [--offset
0.025] [--ccp] [--param K=V ...]``.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from sonarmap.errors import ConfigError
from sonarmap.mappers import ForwardProblem
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.metrics import score
from sonarmap.raster import rasterise
from sonarmap.scenarios import Scenario, make_scenario

F64 = npt.NDArray[np.float64]

#: The solves compared: name and the mapper's parameters besides ``robust=0``.
SOLVES: tuple[tuple[str, dict[str, object]], ...] = (
    ("pgd, 300 steps (tuned)", {}),
    ("pgd, 3000 steps, step 0.2", {"max_iter": 3000, "patience": 1000, "step": 0.2}),
    ("pgd from the inverse map", {"init": "inverse"}),
    ("lbfgs", {"solver": "lbfgs", "max_iter": 900}),
)


def split(p: ForwardProblem, x: F64) -> tuple[float, float, float]:
    """S(x) as (free terms, occ terms, R2): the regulariser is what S has beyond the
    terms, all of it R2 for x in [0, 1], where R1 is 0."""
    X = p.W @ x
    t = p.term_values(X)
    return float(t[~p.is_occ].sum()), float(t[p.is_occ].sum()), p.value(x, X) - float(t.sum())


def _row(name: str, parts: Sequence[float], extra: str = "") -> str:
    f, o, r = parts
    return f"  {name:28s} S {f + o + r:8.1f} = free {f:6.1f} + occ {o:7.1f} + R2 {r:6.1f}{extra}"


def band_share(sc: Scenario, sensor_mapper: GradientMapper, offset: float) -> float:
    """Share of echoes whose band (default half-width, moved ``offset``) holds a true
    obstacle cell."""
    r = sc.readings
    s = sensor_mapper.sensor
    echo = r.take(r.range < s.r_max)
    truth = np.asarray(sc.truth.occupancy, np.float64).ravel() > 0.5
    fp = rasterise(
        sc.truth.grid, s, echo.x, echo.y, echo.theta, echo.range, dr=sensor_mapper.dr, offset=offset
    )
    held = np.bincount(
        fp.occ.reading_index(), weights=truth[fp.occ.cells], minlength=fp.occ.n_readings
    )
    return float(np.mean(held > 0))


def trace(seed: int, offset: float, ccp: bool, model: dict[str, float]) -> None:
    sc = make_scenario("gaps", seed=seed)
    g = sc.truth.grid
    base = GradientMapper(robust=0.0, **model)  # type: ignore[arg-type]
    base.start(g, sc.rig)
    p = base.problem(sc.readings)
    print(f"gaps seed {seed}: {p.n_terms} terms ({int(p.is_occ.sum())} occ), {p.n_cells} cells")
    solves = list(SOLVES) + ([("ccp", {"solver": "ccp", "max_iter": 30})] if ccp else [])
    for name, params in solves:
        kw = {**model, **params}
        m = GradientMapper(robust=0.0, **kw).fit(sc.readings, g, sc.rig)  # type: ignore[arg-type]
        s = score(sc.truth, m.result(), sc.passages)
        extra = (
            f" | detected {s.passages_detected}/{s.passages}, false openings "
            f"{s.false_openings}, wall F1 {s.f1_all:.3f}"
        )
        print(_row(name, split(p, m.solution_ if m.solution_ is not None else np.empty(0)), extra))
    truth = (np.asarray(sc.truth.occupancy, np.float64).ravel()[p.cells] > 0.5).astype(float)
    parts = split(p, truth)
    unexplained = int(np.sum(p.term_values(p.W @ truth)[p.is_occ] >= 1.0 - 1e-9))
    print(_row("the true map", parts, f" | {unexplained} occ terms with nothing in the band"))
    for off in sorted({0.0, offset, base.band_offset_for(g)}):
        print(
            f"  echoes whose band holds a true obstacle cell, band moved {off:.4f} m: "
            f"{band_share(sc, base, off):.1%}"
        )
    cx, cy = g.all_centres()
    cx, cy = cx.ravel()[p.cells], cy.ravel()[p.cells]
    print("  closing one gap of the true map:")
    for gap in sorted(sc.passages, key=lambda q: q.width):
        (ax, ay), (bx, by) = gap.a, gap.b
        cells = (
            (cy > min(ay, by))
            & (cy < max(ay, by))
            & (np.abs(cx - 0.5 * (ax + bx)) < gap.depth / 2 + 0.5 * g.resolution)
        )
        closed = truth.copy()
        closed[cells] = 1.0
        d = np.subtract(split(p, closed), parts)
        print(
            f"    {gap.width:.2f} m ({int(cells.sum()):3d} cells): dS {d.sum():+7.2f} = "
            f"free {d[0]:+6.2f} + occ {d[1]:+7.2f}"
        )


def _constant(text: str) -> tuple[str, float]:
    """One ``--param K=V``; argparse turns the ValueError into a one-line usage error."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected K=V")
    try:
        return key, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: {value!r} is not a number") from None


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001, 1002])
    ap.add_argument("--offset", type=float, default=0.025)
    ap.add_argument("--ccp", action="store_true", help="also the convex-concave procedure (slow)")
    ap.add_argument("--param", action="append", default=[], metavar="K=V", type=_constant)
    a = ap.parse_args(argv)
    model = dict(a.param)
    try:
        mapper = GradientMapper(robust=0.0, **model)
    except (TypeError, ConfigError) as e:
        ap.error(f"--param: {e}")
    print(f"model constants: {mapper.get_params()}")
    for seed in a.seeds:
        trace(seed, a.offset, a.ccp, model)


if __name__ == "__main__":
    main()
