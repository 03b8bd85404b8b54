"""Surface normals from the echoes, and the slanted beams' weight (mappers._incidence)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.mappers._incidence import echo_normals, free_factors, head_on
from sonarmap.raster import CellSet
from sonarmap.readings import Readings
from sonarmap.rig import get_rig

F64 = npt.NDArray[np.float64]


def _cells(grid: Grid, per_reading: list[list[tuple[int, int]]]) -> CellSet:
    """A CellSet holding each reading's (row, col) cells at weight 1."""
    flat = [grid.flat_index(*zip(*cells, strict=True)) for cells in per_reading]
    counts = [len(f) for f in flat]
    return CellSet(
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        cells=np.concatenate(flat).astype(np.int32),
        distance=np.zeros(sum(counts), np.float32),
        weight=np.ones(sum(counts), np.float32),
    )


GRID = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(40, 40))
#: A wall along row 20 (world y 1.95), columns 5-34, piled up by ten echoes' bands.
WALL = _cells(GRID, [[(20, c) for c in range(5, 35)]] * 10)


def test_the_normal_of_a_wall_is_across_it_and_coherent() -> None:
    n = echo_normals(GRID, [WALL])
    on = GRID.flat_index(20, 20)
    assert abs(n.ny[on]) == pytest.approx(1.0, abs=1e-6)
    assert n.coherence[on] > 0.9
    assert n.pile[on] == 10.0
    # Far from any echo there is no surface, and nothing to be coherent about.
    far = GRID.flat_index(2, 2)
    assert n.coherence[far] == 0.0
    assert n.pile[far] == 0.0


def test_head_on_is_one_across_the_wall_and_small_along_it() -> None:
    n = echo_normals(GRID, [WALL])
    cs = _cells(GRID, [[(20, 20)], [(20, 20)]])
    cx, cy = GRID.cell_centres(20, 20)
    # One sensor straight below the wall's cell, one at 60 degrees off its normal.
    x = np.array([float(cx), float(cx) - 1.0 * math.tan(math.radians(60.0))])
    y = np.array([float(cy) - 1.0, float(cy) - 1.0])
    e = head_on(GRID, cs, x, y, n, math.radians(15.0))
    assert e[0] == pytest.approx(1.0, abs=1e-6)
    assert e[1] == pytest.approx(math.exp(-((60.0 / 15.0) ** 2)), rel=1e-3)


def _slanted_pass(extra_head_on: bool) -> tuple[F64, F64]:
    """Factors of a beam crossing the wall at 60 degrees, and of one crossing open
    space; with ``extra_head_on`` a third beam has crossed the wall's cell head-on."""
    cell, empty = (20, 20), (5, 20)
    beams = [[cell], [empty]] + ([[cell]] if extra_head_on else [])
    cs = _cells(GRID, beams)
    cx, cy = GRID.cell_centres(20, 20)
    ex, ey = GRID.cell_centres(5, 20)
    slant = math.tan(math.radians(60.0))
    x = [float(cx) - slant, float(ex) - slant] + ([float(cx)] if extra_head_on else [])
    y = [float(cy) - 1.0, float(ey) - 1.0] + ([float(cy) - 1.0] if extra_head_on else [])
    (f,) = free_factors(GRID, [cs], [WALL], [np.array(x)], [np.array(y)], math.radians(15.0))
    return f[0], f[1]


def test_a_slanted_beam_says_little_about_a_wall_only_echoes_have_met() -> None:
    on_wall, in_open = _slanted_pass(extra_head_on=False)
    assert on_wall < 0.2
    # Where no echo ever landed, the beam keeps its full say.
    assert in_open == 1.0


def test_a_cell_a_beam_passed_head_on_is_not_shielded() -> None:
    alone, _ = _slanted_pass(extra_head_on=False)
    passed, _ = _slanted_pass(extra_head_on=True)
    # Ten echoes' pile against one head-on pass: the shield drops by about a tenth.
    assert passed > alone + 0.05


def _wall_readings() -> Readings:
    """A MaxSonar rig's front sonar ranging a wall 1 m ahead while driving along it,
    and its +45-degree sonar crossing the same wall at a slant to a farther echo."""
    n = 20
    xs = np.linspace(0.5, 3.5, n)
    front = (xs, np.full(n, 1.0), np.full(n, math.pi / 2), np.full(n, 0.95))
    slant = (xs - 1.0, np.full(n, 1.0), np.full(n, math.pi / 4), np.full(n, 2.5))
    x, y, th, r = (np.concatenate([a, b]) for a, b in zip(front, slant, strict=True))
    return Readings(
        t=np.arange(2 * n, dtype=np.float64),
        sensor=np.zeros(2 * n, np.int32),
        x=x,
        y=y,
        theta=th,
        range=r,
        names=("s",),
    )


def test_the_gradient_keeps_only_its_free_weights_changed() -> None:
    grid = Grid(resolution=0.05, origin=(0.0, 0.0), shape=(80, 100))
    rig = get_rig("ez1-six")
    readings = _wall_readings()
    plain = make_mapper("gradient")
    plain.start(grid, rig)
    slanted = make_mapper("gradient", specular_deg=15.0)
    slanted.start(grid, rig)
    p0 = plain.problem(readings)  # type: ignore[attr-defined]
    p1 = slanted.problem(readings)  # type: ignore[attr-defined]
    assert np.array_equal(p0.X0, p1.X0)
    assert np.array_equal(p0.is_occ, p1.is_occ)
    occ0, occ1 = p0.W[p0.is_occ], p1.W[p1.is_occ]
    assert (occ0 != occ1).nnz == 0
    free0, free1 = p0.W[~p0.is_occ], p1.W[~p1.is_occ]
    assert np.all(free1.data <= free0.data + 1e-12)
    assert free1.sum() < free0.sum()


@pytest.mark.parametrize("bad", [-1.0, 90.0, float("nan")])
def test_a_bad_specular_angle_names_the_parameter(bad: float) -> None:
    with pytest.raises(ConfigError, match="specular_deg"):
        make_mapper("gradient", specular_deg=bad)


def test_a_convex_start_must_be_a_flag() -> None:
    with pytest.raises(ConfigError, match="convex_start"):
        make_mapper("gradient", convex_start=1)
    assert make_mapper("gradient", convex_start=True).convex_start is True  # type: ignore[attr-defined]


def test_the_stream_ignores_convex_start() -> None:
    from sonarmap.scenarios import make_scenario
    from sonarmap.streaming import StreamingMapper

    sc = make_scenario("doorways", seed=0)
    maps = []
    options: list[dict[str, Any]] = [{}, {"convex_start": True}]
    for p in options:
        s = StreamingMapper("gradient", sc.truth.grid, sc.rig, **p)
        s.add(sc.readings.take(np.arange(300)))
        maps.append(s.occupancy_)
    assert np.count_nonzero(np.isfinite(maps[0])) > 0
    np.testing.assert_array_equal(maps[0], maps[1])


def test_the_stream_refuses_the_incidence_weighting() -> None:
    from sonarmap.scenarios import make_scenario
    from sonarmap.streaming import StreamingMapper

    sc = make_scenario("doorways", seed=0)
    with pytest.raises(ConfigError, match="specular_deg=0"):
        StreamingMapper("gradient", sc.truth.grid, sc.rig, specular_deg=15.0)
