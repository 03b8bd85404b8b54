"""The streamed gradient map's end: each cell as its steps left it, settled, finished.

For each training map the gradient method is streamed (``last:1000``, one update per
0.25 s of log) folding the readings that leave, without
:meth:`~sonarmap.streaming.StreamingMapper.finish`, and its wall F1 read four ways: the
cells' values as their steps left them ("steps"), with the cells no reading in play
touches set to their folded terms' optimum, 0 or 1 by the sign of the fixed gradient
("settled", tried and not adopted), and both again after ``finish()`` ("finished",
"finished, settled"); then the same stream forgetting the readings that leave (no
folded terms, so nothing to settle), without and with ``finish()`` (the last is the
default since, with ``no_echo="ignore"``). The inverse map of the same readings is the
reference. The maps: single tours at the scenes' own pace, or with ``--long`` long
logs (the ``suite`` and ``hall`` tours at 0.125 m/s with every sonar at 20 Hz,
40,000-132,000 readings, as minutes of mapping give). Training scenes only (seeds
below 1000): this chooses the stream's ending.

Run with ``python -m benchmarks.stream_finish``.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import make_mapper
from sonarmap.mappers.gradient import GradientStream
from sonarmap.metrics import score
from sonarmap.scenarios import make_scenario
from sonarmap.splits import check_training
from sonarmap.streaming import StreamingMapper, replay

_DOORWAYS: list[tuple[str, str | None, int]] = [("doorways", None, s) for s in (0, 1, 2)]
#: (family, rig or None for the scene's own, seed): the doorways scene (its own
#: MaxSonar rig), and the hall and suite families walked by each preset rig.
MAPS: list[tuple[str, str | None, int]] = (
    _DOORWAYS
    + [(f, rig, s) for rig in ("ez1-six", "hcsr04-six") for f in ("hall", "suite") for s in (0, 1)]
    + [("hall", "ring16", 0), ("suite", "ring16", 0), ("suite", "ring16", 1)]
)
#: Long logs: (family, rig, seed), toured at :data:`LONG_PACE`.
LONG: list[tuple[str, str | None, int]] = [
    ("suite", "ring16", 0),
    ("suite", "ring16", 1),
    ("hall", "ring16", 0),
    ("hall", "ring16", 1),
    ("suite", "ez1-six", 0),
    ("suite", "ez1-six", 1),
    ("suite", "hcsr04-six", 0),
]
#: Speed (m/s) and sonar rate (Hz) of the long logs.
LONG_PACE = {"speed": 0.125, "rate": 20.0}
COLUMNS = ("steps", "settled", "finished", "finished, settled", "forget", "forget, finished")


def row(family: str, rig: str | None, seed: int, **pace: float) -> list[float]:
    """Inverse F1, then the wall F1 of each of :data:`COLUMNS`; ``pace`` the scene's
    speed and rate, when not its own."""
    check_training(family, seed, where="stream_finish")
    sc = make_scenario(family, seed=seed, **({} if rig is None else {"rig": rig}), **pace)
    g, r = sc.truth.grid, sc.readings

    def f1(values: np.ndarray) -> float:
        occ = OccupancyMap(g, values.reshape(g.shape).astype(np.float32))
        return score(sc.truth, occ).f1_all

    out = [score(sc.truth, make_mapper("inverse").fit(r, g, sc.rig).result()).f1_all]
    for fold in (True, False):
        sm = StreamingMapper("gradient", g, sc.rig, fold=fold)
        replay([r], sm, period=0.25, finish=False)
        e = sm.engine
        assert isinstance(e, GradientStream)
        for finished in (False, True):
            if finished:
                sm.finish()
            out.append(f1(sm.occupancy_.ravel()))
            if fold:
                done = (e.cov == 0) & (e.fixed != 0.0)
                settled = np.where(done, np.where(e.fixed > 0.0, 0.0, 1.0), e.x)
                out.append(f1(np.where(e.seen, settled, np.nan)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--long", action="store_true", help="the long logs instead")
    args = parser.parse_args()
    maps, pace = (LONG, LONG_PACE) if args.long else (MAPS, {})
    t = Table("map", "inverse", *COLUMNS, title="streamed gradient wall F1 (training)")
    rows = []
    for family, rig, seed in maps:
        v = row(family, rig, seed, **pace)
        rows.append(v)
        t.add_row(f"{family} {rig or ''} {seed}", *(f"{x:.3f}" for x in v))
    mean = np.mean(rows, axis=0)
    t.add_row("mean", *(f"{x:.3f}" for x in mean))
    Console(width=160).print(t)


if __name__ == "__main__":
    main()
