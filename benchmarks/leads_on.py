"""The forward wave's dead-end test on the thesis-scale map: CPU time per call.

Setting: the built-in ``fig3-10`` map at ``--cell`` metres (0.1, as Table 4), the
cells a car of radius 1 m may stand on, ``--calls`` cars at random passable cells
facing random headings (seeded), the cells up to 4 m behind each closed
(:func:`~sonarmap.patrol.manoeuvre.behind_cells`). For each call: CPU seconds of
:func:`~sonarmap.patrol.manoeuvre.leads_on` (the flood fill, the passable count given
once as the simulator gives it) and of the former whole-map labelling (``ndimage.label``,
here only to compare), and whether their answers agree (they must, every call).

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

from sonarmap.patrol.manoeuvre import behind_cells, leads_on
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
    leads_on(passable, behind_cells(0.0, 0.0, 0.0, g), (int(rr[0]), int(cc[0])), n_passable=n)
    new_s = old_s = 0.0
    agree = true = 0
    for k, h in zip(picks.tolist(), headings.tolist(), strict=True):
        start = (int(rr[k]), int(cc[k]))
        x, y = g.cell_centres(np.array([start[0]]), np.array([start[1]]))
        back = behind_cells(float(x[0]), float(y[0]), h, g)
        t0 = time.process_time()
        new = leads_on(passable, back, start, n_passable=n)
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
        f"flood fill {1e3 * new_s / a.calls:.2f} ms/call, labelling {1e3 * old_s / a.calls:.2f} "
        f"ms/call (CPU), {old_s / max(new_s, 1e-12):.1f}x; answers agree {agree}/{a.calls}"
    )
    return 0 if agree == a.calls else 1


if __name__ == "__main__":
    raise SystemExit(main())
