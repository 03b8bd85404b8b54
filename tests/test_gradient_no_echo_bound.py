"""The gradient's no-echo readings as bounded evidence (``no_echo_share``,
``no_echo_weight``; issue 39's HC-SR04 margin)."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers._forward import ForwardProblem
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.readings import Readings
from sonarmap.rig import get_rig
from sonarmap.streaming import StreamingMapper

HCSR04 = get_rig("hcsr04-six").sensor
GRID = Grid(resolution=0.05, origin=(0.0, 0.0), shape=(100, 100))


def _readings() -> Readings:
    """Two echoes at 1.5 m and two no-echo readings, from the grid's left edge."""
    r = np.array([1.5, HCSR04.r_max, 1.5, HCSR04.r_max + 1.0])
    n = len(r)
    return Readings(
        np.arange(n, dtype=np.float64),
        np.zeros(n, np.int32),
        np.full(n, 0.1),
        np.full(n, 2.5),
        np.zeros(n),
        r,
        ("s",),
    )


def _free_cells(p: ForwardProblem, reading: int) -> set[int]:
    """Grid cells of one reading's free term."""
    assert p.reading is not None
    (row,) = np.flatnonzero(~p.is_occ & (p.reading == reading))
    W = p.W
    return set(p.cells[W.indices[W.indptr[row] : W.indptr[row + 1]]].tolist())


def test_share_bounds_only_the_no_echo_beams() -> None:
    """A share cuts the no-echo readings' free cells at share * r_max; the echoes'
    free cells and bands do not change."""
    readings = _readings()
    full = GradientMapper(no_echo="free").start(GRID, HCSR04).problem(readings)
    half = GradientMapper(no_echo="free", no_echo_share=0.5).start(GRID, HCSR04).problem(readings)
    assert _free_cells(half, 0) == _free_cells(full, 0)
    near, far = _free_cells(half, 1), _free_cells(full, 1)
    assert near < far
    cx = (np.array(sorted(near)) % GRID.shape[1] + 0.5) * GRID.resolution
    assert cx.max() - 0.1 <= 0.5 * HCSR04.r_max + GRID.resolution
    assert (np.sort(full.X0[full.is_occ]) == np.sort(half.X0[half.is_occ])).all()


def test_weight_scales_only_the_no_echo_terms() -> None:
    readings = _readings()
    p = GradientMapper(no_echo="free", no_echo_weight=0.3).start(GRID, HCSR04).problem(readings)
    assert p.v is not None
    assert p.reading is not None
    quiet = readings.range[p.reading] >= HCSR04.r_max
    assert quiet.sum() == 2
    assert np.allclose(p.v[quiet], 0.3)
    assert np.allclose(p.v[~quiet], 1.0)


def test_off_is_the_default_path() -> None:
    readings = _readings()
    a = GradientMapper().start(GRID, HCSR04).problem(readings)
    b = GradientMapper(no_echo_share=1.0, no_echo_weight=1.0).start(GRID, HCSR04).problem(readings)
    assert a.v is None
    assert b.v is None
    assert (a.W != b.W).nnz == 0


def test_bad_settings_refused() -> None:
    with pytest.raises(ConfigError, match="no_echo_share"):
        GradientMapper(no_echo="free", no_echo_share=0.0)
    with pytest.raises(ConfigError, match="no_echo_weight"):
        GradientMapper(no_echo="free", no_echo_weight=1.5)
    with pytest.raises(ConfigError, match="need no_echo='free'"):
        GradientMapper(no_echo_share=0.5)
    with pytest.raises(ConfigError, match=r"streaming 'gradient' .*no_echo_share.*=1"):
        StreamingMapper(
            GradientMapper(no_echo="free", no_echo_share=0.5), GRID, get_rig("hcsr04-six")
        )
