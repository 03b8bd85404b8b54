"""The gradient's first-return evidence per range shell (``free_shell``, issue 39's
HC-SR04 margin): off by default, each free cell weighed against its shell of the beam
when on, refused by the stream."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers._forward import shell_factors
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.raster import CellSet
from sonarmap.readings import Readings
from sonarmap.rig import get_rig

GRID = Grid(resolution=0.05, origin=(-0.5, -1.5), shape=(60, 70))
HCSR04 = get_rig("hcsr04-six").sensor


def test_each_entry_is_weighed_against_its_shell() -> None:
    """Two readings: the first's cells in shells of 1 and 3 cells, the second's in one
    shell; each factor is ``1 + g sum(w0) / sum(w0 over the shell)``."""
    cs = CellSet(
        offsets=np.array([0, 4, 6], np.int64),
        cells=np.arange(6, dtype=np.int32),
        distance=np.array([0.02, 0.07, 0.08, 0.09, 0.5, 0.51], np.float32),
        weight=np.array([1.0, 1.0, 0.5, 0.5, 1.0, 1.0], np.float32),
    )
    f = shell_factors(cs, 0.05, 0.1)
    beam = 3.0
    assert f[:4] == pytest.approx([1 + 0.1 * beam / 1.0] + [1 + 0.1 * beam / 2.0] * 3)
    assert f[4:] == pytest.approx([1.1, 1.1])
    assert shell_factors(cs, 0.05, 0.0) == pytest.approx(np.ones(6))


def readings_at_a_wall() -> Readings:
    """An HC-SR04 facing the wall x = 2 m from x = 0 and 1 m, y -0.5 to 0.5 m, head-on."""
    xs, ys = np.meshgrid([0.0, 1.0], np.arange(-0.5, 0.51, 0.25))
    x, y = xs.ravel(), ys.ravel()
    n = len(x)
    return Readings(
        np.arange(n, dtype=np.float64), np.zeros(n, np.int32), x, y, np.zeros(n), 2.0 - x, ("s",)
    )


def test_a_beam_weighs_one_plus_g_per_shell() -> None:
    """With ``free_shell=g`` a free term's weights sum to 1 + g times its shells (each
    shell's own weights sum to one); off, to 1, as in the documents' model."""
    readings = readings_at_a_wall()
    off = GradientMapper().start(GRID, HCSR04).problem(readings)
    on = GradientMapper(free_shell=0.2).start(GRID, HCSR04).problem(readings)
    free = ~off.is_occ
    assert np.asarray(off.W[free].sum(axis=1)).ravel() == pytest.approx(1.0)
    sums = np.asarray(on.W[~on.is_occ].sum(axis=1)).ravel()
    # A reading 2 m away has shells of 5 cm (the band's width 2 dr) from its first
    # occupied shell to 2 m less dr; the one 1 m away about half as many.
    far, near = sums[0], sums[1]
    assert far > near > 1.0
    shells_far = (far - 1.0) / 0.2
    assert shells_far == pytest.approx(round(shells_far), abs=1e-6)
    assert 30 <= shells_far <= 40
    # The occ terms are untouched.
    assert on.W[on.is_occ].toarray() == pytest.approx(off.W[off.is_occ].toarray())


def test_a_lone_short_echo_across_a_wall_seen_head_on_is_cleared() -> None:
    """The cells 1 m ahead that one short echo put in its band, which two head-on beams
    to a wall 2 m away crossed: off, the band's reward (a2 over its 11 cells) outweighs
    the two beams' (each one over its 400 cells) and keeps them occupied; with the
    shells' evidence (g over a shell's 11 cells more) the beams clear them."""
    x = np.zeros(3)
    y = np.zeros(3)
    r = np.array([2.0, 2.0, 1.0])
    n = len(x)
    readings = Readings(
        np.arange(n, dtype=np.float64), np.zeros(n, np.int32), x, y, np.zeros(n), r, ("s",)
    )
    m_off = GradientMapper(robust=0.0).fit(readings, GRID, HCSR04)
    m_on = GradientMapper(robust=0.0, free_shell=0.1).fit(readings, GRID, HCSR04)
    occ_off = np.nan_to_num(m_off.result().occupancy) > 0.5
    occ_on = np.nan_to_num(m_on.result().occupancy) > 0.5
    # The short echo's band on the axis: cells from 1.0 to 1.1 m, y = 0.
    rows, cols = GRID.world_to_cell(np.array([1.025, 1.075]), np.array([0.0, 0.0]))
    assert occ_off[rows, cols].any()
    assert not occ_on[rows, cols].any()


def test_the_option_is_checked_and_offline_only() -> None:
    from sonarmap.streaming import StreamingMapper

    with pytest.raises(ConfigError, match="free_shell"):
        GradientMapper(free_shell=-0.1)
    with pytest.raises(ConfigError, match=r"streaming 'gradient' .*free_shell.*; set free_shell=0"):
        StreamingMapper(GradientMapper(free_shell=0.1), GRID, get_rig("hcsr04-six"))


def test_the_shells_multiply_the_incidence_factors() -> None:
    """With ``specular_deg`` as well, each free weight is the plain one times both
    factors: the shells' ratio is the same with and without the incidence's."""
    readings = readings_at_a_wall()
    readings = readings.take(np.r_[np.arange(len(readings)), np.arange(len(readings))])
    readings.theta[len(readings) // 2 :] = 0.3

    def free(**kw: Any) -> npt.NDArray[np.float64]:
        p = GradientMapper(**kw).start(GRID, HCSR04).problem(readings)
        return np.asarray(p.W[~p.is_occ].toarray())

    plain, shells = free(), free(free_shell=0.2)
    slanted, both = free(specular_deg=30.0), free(specular_deg=30.0, free_shell=0.2)
    assert not np.allclose(slanted, plain)
    on = plain > 0
    assert both[on] / slanted[on] == pytest.approx(shells[on] / plain[on])
