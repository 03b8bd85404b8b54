"""Whether two versions of the patrol simulator give the same answers, to the bit, in
:mod:`benchmarks.patrol`'s setting (the thesis's Table 4: the built-in ``fig3-10`` map,
5 car-like robots at the map's starts, the car defaults), for speed changes that must
change nothing.

``--save FILE`` runs ``--duration`` simulated seconds (300) at ``--cell`` metres (0.1)
and writes every per-step answer and the final state to ``FILE`` (``.npz``): MTB(t),
mean TB(t), DVT(t), the final poses, the final TB of every cell, the cells never seen,
the steps each robot was blocked and escaping, and the stalls. Run it once with each
version (e.g. the older one from a snapshot of its ``src`` on ``PYTHONPATH``), then
``--compare A B`` prints, for each, identical or DIFFERENT (exit code 1 when any
differs).

Run with ``python -m benchmarks.patrol_answers --save A.npz [--duration 300]
[--cell 0.1] [--seed 0]`` and ``python -m benchmarks.patrol_answers --compare A.npz B.npz``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from benchmarks.patrol import table4
from sonarmap.patrol import run_patrol

#: The answers kept, as :class:`~sonarmap.patrol.simulation.PatrolResult` names them.
FIELDS = (
    "mtb",
    "mean_tb",
    "dvt",
    "positions",
    "final_tb",
    "never_seen",
    "blocked_steps",
    "escape_steps",
    "stalls",
)


def save(path: str, duration: float, cell: float, seed: int) -> None:
    """Run the setting and write its answers to ``path``."""
    territory, config, starts = table4(cell, duration)
    c0 = time.process_time()
    res = run_patrol(territory, config, starts=starts, seed=seed)
    cpu = time.process_time() - c0
    answers = {name: np.asarray(getattr(res, name)) for name in FIELDS}
    with open(path, "wb") as f:
        np.savez(f, **answers)  # type: ignore[arg-type]  # a key could be allow_pickle
    s = res.summary()
    print(
        f"{path}: {duration:g} s at {cell:g} m, seed {seed}, {cpu:.1f} s CPU; mean MTB "
        f"{s['mean_mtb']:.3f} s, DVT {s['dvt']:.4f} %, never seen {s['never_seen']:.5f}"
    )


def compare(a: str, b: str) -> bool:
    """Print, answer by answer, whether the files ``a`` and ``b`` hold the same bits."""
    with np.load(a) as fa, np.load(b) as fb:
        same = True
        for name in FIELDS:
            ok = (
                name in fa.files
                and name in fb.files
                and fa[name].shape == fb[name].shape
                and fa[name].dtype == fb[name].dtype
                and np.array_equal(fa[name], fb[name], equal_nan=True)
            )
            same &= ok
            print(f"{name:>14}: {'identical' if ok else 'DIFFERENT'}")
    print("every answer identical" if same else "the answers DIFFER")
    return same


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--save", metavar="FILE")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"))
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--cell", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if (args.save is None) == (args.compare is None):
        parser.error("give one of --save FILE or --compare A B")
    if args.save is not None:
        save(args.save, args.duration, args.cell, args.seed)
        return
    sys.exit(0 if compare(*args.compare) else 1)


if __name__ == "__main__":
    main()
