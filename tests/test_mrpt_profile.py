"""The insertion profile (``python -m benchmarks.mrpt.profile``), on a few seconds of the ring."""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks.mrpt.profile import held_share, kernel_args, main

from sonarmap.raster import CellSet, Footprint


def test_profile_runs_and_refuses_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--minutes", "0.05", "--repeat", "1", "--held", "--clock", "thread"]) == 0
    out = capsys.readouterr().out
    assert "held blocks skipped" in out
    assert "blocks of 8 whose cells all do" in out
    assert main(["--minutes", "0", "--repeat", "1"]) == 2
    assert "--minutes must be > 0" in capsys.readouterr().err
    assert main(["--minutes", "0.05", "--against", "no/such/_raster_kernel.py"]) == 2
    assert "--against: no file no/such/_raster_kernel.py" in capsys.readouterr().err


def repeat(cells: CellSet, times: int) -> CellSet:
    """The first reading's cells, ``times`` readings over."""
    first = cells.of(0)
    n = len(first)
    return CellSet(
        np.arange(times + 1, dtype=np.int64) * n,
        np.tile(first, times),
        np.zeros(n * times, dtype=np.float32),
        np.ones(n * times, dtype=np.float32),
    )


def test_held_share_counts_cells_at_their_bound() -> None:
    """One reading five times over, with clamp bounds closer to 0 than any of its
    weighted increments: the first finds no cell at a bound, the next four find all of
    theirs there."""
    inputs = kernel_args(0.05, footprint=True)
    assert inputs.footprint is not None
    args = list(inputs.args)
    for k in (7, 8, 9, 10, 11):
        args[k] = np.repeat(args[k][:1], 5)
    args[16], args[17] = -1e-6, 1e-6
    fp = inputs.footprint
    again = inputs._replace(
        args=args, n=5, footprint=Footprint(repeat(fp.free, 5), repeat(fp.occ, 5), fp.dr)
    )
    updates, blocks = held_share(again)
    assert updates == pytest.approx(0.8)
    assert blocks == pytest.approx(0.8)
