"""The one-way street system on the thesis-scale map: CPU time of one build.

Setting: a built-in map (``--map``, default ``fig3-10``) at ``--cell`` metres (0.1,
as Table 4), the
places the car defaults patrol from the map's first five starts (as
``benchmarks.patrol`` runs them), the cars' turning radius. :func:`~sonarmap.patrol.
oneway.one_way` is built once untimed (numba's kernels compiled or loaded), then
``--repeat`` times, each timed in CPU seconds (``time.process_time``; the machine is
shared, so not the wall clock).

It prints each build's CPU time and a digest (SHA-256 over every field of the
:class:`~sonarmap.patrol.oneway.OneWay`, in the dataclass's order), the same for
every build. It uses only public names, so that the same file run against another
version's sources (``PYTHONPATH=OTHER/src``) times that version on the same input,
and equal digests mean equal systems. Whether the system equals the former
whole-map code's is the tests' question (``tests/test_patrol_oneway.py``).

Run with ``python -m benchmarks.one_way [--map fig3-10] [--cell 0.1] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

import sonarmap
from sonarmap.patrol import PatrolConfig
from sonarmap.patrol.maps import BUILTIN_MAPS, builtin_territory
from sonarmap.patrol.oneway import OneWay, one_way
from sonarmap.patrol.reach import reach
from sonarmap.patrol.starts import starts_from_dm


def digest(ow: OneWay) -> str:
    """SHA-256 (first 16 hex digits) over every field of ``ow``: dtype, shape, bytes of
    the arrays, the ``repr`` of the rest (``search``: None or a ``Search``)."""
    h = hashlib.sha256()
    for f in dataclasses.fields(ow):
        value = getattr(ow, f.name)
        if not isinstance(value, np.ndarray):
            # As an object array its bytes would be a pointer: another each process.
            h.update(f"{f.name}:{value!r}".encode())
            continue
        a = np.ascontiguousarray(value)
        h.update(f"{f.name}:{a.dtype}:{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.one_way", description=__doc__)
    ap.add_argument("--map", default="fig3-10", choices=sorted(BUILTIN_MAPS))
    ap.add_argument("--cell", type=float, default=0.1)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    if a.repeat < 1:
        ap.error(f"--repeat must be >= 1, got {a.repeat}")
    territory, starts = builtin_territory(a.map, a.cell)
    cfg = PatrolConfig(model="car", cell=a.cell)
    xy = starts_from_dm(starts[:5], territory)
    g = territory.grid
    rc = np.column_stack(g.world_to_cell(xy[:, 0], xy[:, 1]))
    passable = reach(territory, cfg.radius, starts=rc, mode=cfg.reach, vision=cfg.vision).passable
    args = (passable, territory.clearance, g.resolution, cfg.turn_radius)
    want = digest(one_way(*args))
    print(
        f"{a.map} at {a.cell} m: {passable.shape[0]} x {passable.shape[1]} cells, "
        f"{int(passable.sum())} passable, turn radius {cfg.turn_radius} m; "
        f"sonarmap from {os.path.dirname(sonarmap.__file__)}"
    )
    same = True
    for k in range(a.repeat):
        t0 = time.process_time()
        ow = one_way(*args)
        cpu = time.process_time() - t0
        d = digest(ow)
        same &= d == want
        print(
            f"build {k + 1}: {cpu:.2f} s CPU, {int(ow.one_way.sum())} one-way streets, digest {d}"
        )
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
