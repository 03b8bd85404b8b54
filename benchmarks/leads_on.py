"""The forward wave's dead-end test on the thesis-scale map: CPU time per call.

Setting: the built-in ``fig3-10`` map at ``--cell`` metres (0.1, as Table 4), the
cells a car of radius 1 m may stand on, ``--calls`` cars at random passable cells
facing random headings (seeded), the cells up to 4 m behind each closed
(:func:`~sonarmap.patrol.manoeuvre.behind_cells`). For each call: CPU seconds of
:meth:`~sonarmap.patrol.manoeuvre.DeadEnds.leads_on` (a flood from the car's cell
that stops at half the passable cells, cell by cell in the 16-cell blocks the closed
cells and the car touch and a block's piece at a time outside them, on one
:class:`~sonarmap.patrol.manoeuvre.DeadEnds` built once as the simulator builds it;
its build's CPU time is printed apart) and of the former
whole-map labelling (``ndimage.label``, here only to compare), and whether their
answers agree (they must, every call).

CPU time (``time.process_time``), not wall time: the machine is shared.

Run with ``python -m benchmarks.leads_on [--cell 0.1] [--calls 200] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import math
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from sonarmap.patrol.manoeuvre import DeadEnds, behind_cells
from sonarmap.patrol.maps import builtin_territory


def _by_labels(
    passable: npt.NDArray[np.bool_], closed: npt.NDArray[np.intp], start: tuple[int, int]
) -> bool:
    open_ = passable.copy()
    open_[closed[:, 0], closed[:, 1]] = False
    open_[start] = True
    labels, _ = ndimage.label(open_, structure=np.ones((3, 3), dtype=bool))
    return bool(np.count_nonzero(labels == labels[start]) >= 0.5 * np.count_nonzero(passable))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.leads_on", description=__doc__)
    ap.add_argument("--cell", type=float, default=0.1)
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    territory, _ = builtin_territory("fig3-10", a.cell)
    passable = territory.passable(1.0)
    g = territory.grid
    n = int(np.count_nonzero(passable))
    rr, cc = np.nonzero(passable)
    rng = np.random.default_rng(a.seed)
    picks = rng.integers(0, len(rr), a.calls)
    headings = rng.uniform(-math.pi, math.pi, a.calls)
    # Compile (or load) the kernels before timing, on a call that floods.
    x0, y0 = g.cell_centres(rr[:1], cc[:1])
    warm = behind_cells(float(x0[0]), float(y0[0]), 0.0, g)
    DeadEnds(passable).leads_on(warm, (int(rr[0]), int(cc[0])))
    _by_labels(passable, warm, (int(rr[0]), int(cc[0])))
    t0 = time.process_time()
    ends = DeadEnds(passable)
    build_s = time.process_time() - t0
    new_s = old_s = 0.0
    agree = true = 0
    for k, h in zip(picks.tolist(), headings.tolist(), strict=True):
        start = (int(rr[k]), int(cc[k]))
        x, y = g.cell_centres(np.array([start[0]]), np.array([start[1]]))
        back = behind_cells(float(x[0]), float(y[0]), h, g)
        t0 = time.process_time()
        new = ends.leads_on(back, start)
        t1 = time.process_time()
        old = _by_labels(passable, back, start) if len(back) else True
        t2 = time.process_time()
        new_s, old_s = new_s + t1 - t0, old_s + t2 - t1
        agree += new == old
        true += new
    print(
        f"fig3-10 at {a.cell} m: {passable.shape[0]} x {passable.shape[1]} cells, {n} passable; "
        f"{a.calls} calls ({true} leading on)"
    )
    print(
        f"dead-end test {1e3 * new_s / a.calls:.3f} ms/call (built once in "
        f"{1e3 * build_s:.0f} ms), labelling {1e3 * old_s / a.calls:.2f} ms/call (CPU), "
        f"{old_s / max(new_s, 1e-12):.1f}x; answers agree {agree}/{a.calls}"
    )
    return 0 if agree == a.calls else 1


if __name__ == "__main__":
    raise SystemExit(main())
