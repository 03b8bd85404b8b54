"""Why the gradient method's walls came out a cell thick (issue 39): the band moved three
quarters of a cell behind the echo by default, and the sparsity options tried (a cost
``l1`` per unit of occupancy, in the descent or in a last pass of single-cell flips)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers.gradient import GradientMapper, emptying_costs, polish
from sonarmap.readings import Readings
from sonarmap.rig import get_rig
from sonarmap.sensors import SensorModel

GRID = Grid(resolution=0.05, origin=(-0.5, -1.5), shape=(60, 70))
EZ1: SensorModel = get_rig("ez1-six").sensor
HCSR04: SensorModel = get_rig("hcsr04-six").sensor
#: The gradient's band offset before issue 39's thick walls: half a 5 cm cell.
HALF_CELL = 0.025


def wall_readings(
    face: float,
    sensor: SensorModel,
    places: list[float],
    headings: list[float],
    sigma: float = 0.0,
) -> Readings:
    """A sonar facing a wall whose face is the line x = ``face``, from x in ``places``
    and y every 0.1 m from -1 to 1 m, at each of ``headings`` (radians): the first echo
    is the nearest point of the wall in the beam (plus Gaussian noise of ``sigma``)."""
    xs, ys, th = np.meshgrid(places, np.arange(-1.0, 1.01, 0.1), headings)
    x, y, t = xs.ravel(), ys.ravel(), th.ravel()
    half = np.arctan2(sensor.beam.outline[:, 1], sensor.beam.outline[:, 0]).max()
    r = (face - x) / np.cos(np.maximum(np.abs(t) - half, 0.0))
    if sigma > 0:
        r = r + np.random.default_rng(0).normal(0.0, sigma, len(r))
    n = len(r)
    return Readings(np.arange(n, dtype=np.float64), np.zeros(n, np.int32), x, y, t, r, ("s",))


def occupied_columns(m: GradientMapper) -> dict[float, int]:
    """How many cells of each column (by its centre's x, metres) are occupied, within
    0.8 m of the wall's middle (32 cells a column)."""
    occ: npt.NDArray[np.float32] = m.result().occupancy
    rows, cols = np.nonzero(np.nan_to_num(occ) > 0.5)
    x = GRID.origin[0] + (cols + 0.5) * GRID.resolution
    y = GRID.origin[1] + (rows + 0.5) * GRID.resolution
    x = np.round(x[np.abs(y) < 0.8], 3)
    return {float(v): int(np.sum(x == v)) for v in np.unique(x)}


def test_the_cell_in_front_of_a_wall_ends_free() -> None:
    """A wall one cell thick, x from 2.04 to 2.09 m: the cell 2.00-2.05 has its centre
    in front of the face (free in the truth), the cell 2.05-2.10 in the wall. MaxSonar
    beams from three distances, head-on and 0.4 rad either side: the echoes' bands half
    a cell behind the echo held the cell in front as firmly as the wall's, and the map
    marked both; three quarters of a cell behind, only the wall's."""
    readings = wall_readings(2.04, EZ1, [0.0, 0.5, 1.0], [-0.4, 0.0, 0.4])
    before = occupied_columns(GradientMapper(band_offset=HALF_CELL).fit(readings, GRID, EZ1))
    after = occupied_columns(GradientMapper().fit(readings, GRID, EZ1))
    assert before.get(2.025, 0) >= 20
    assert before.get(2.075, 0) == 32
    assert after == {2.075: 32}


def test_the_band_further_behind_costs_a_cell_behind_a_face_near_a_cell_front() -> None:
    """The trade, kept in view: with the face at 2.02 m (the cell 2.00-2.05 in the wall,
    2.05-2.10 behind it free for a wall one cell thick) and head-on echoes from 2 m,
    the band three quarters of a cell behind the echo holds the cell behind the face as
    well; half a cell behind, it did not."""
    readings = wall_readings(2.02, EZ1, [0.0], [0.0])
    before = occupied_columns(GradientMapper(band_offset=HALF_CELL).fit(readings, GRID, EZ1))
    after = occupied_columns(GradientMapper().fit(readings, GRID, EZ1))
    assert before == {2.025: 32}
    assert after == {2.025: 32, 2.075: 32}


def test_sparsity_adds_its_cost_and_slope() -> None:
    m = GradientMapper().start(GRID, HCSR04)
    p = m.problem(wall_readings(2.02, HCSR04, [0.0], [0.0]))
    q = dataclasses.replace(p, pen=dataclasses.replace(p.pen, l1=0.2))
    x = np.random.default_rng(1).uniform(0.0, 1.0, p.n_cells)
    assert q.value(x) == pytest.approx(p.value(x) + 0.2 * float(np.sum(x)))
    np.testing.assert_allclose(q.grad(x), p.grad(x) + 0.2)


def test_sparsity_in_the_descent_empties_the_cell_behind_a_thin_wall() -> None:
    """Noisy echoes off a face at 2.02 m put bands on the cell behind it, which no beam
    crosses; the sparsity cost (0.1) leaves that column free and keeps the wall (all but
    a few of its 32 cells). Not a default: on the training maps every weight tried cost
    more wall than it saved."""
    readings = wall_readings(2.02, HCSR04, [0.0, 0.5, 1.0], [-0.3, -0.15, 0.0, 0.15, 0.3], 0.01)
    plain = GradientMapper(band_offset=HALF_CELL, sparsity=0.0)
    sparse = GradientMapper(band_offset=HALF_CELL, sparsity=0.1)
    before = occupied_columns(plain.fit(readings, GRID, HCSR04))
    after = occupied_columns(sparse.fit(readings, GRID, HCSR04))
    assert before.get(2.075, 0) >= 10
    assert after.get(2.025, 0) >= 28
    assert after.get(2.075, 0) <= 1


def test_polish_lowers_the_objective_with_sparsity_and_agrees_with_the_costs() -> None:
    readings = wall_readings(2.02, HCSR04, [0.0, 1.0], [0.0, 0.3], 0.01)
    m = GradientMapper(band_offset=HALF_CELL, max_iter=60).fit(readings, GRID, HCSR04)
    x = m.solution_
    assert x is not None
    p = dataclasses.replace(m.problem(readings), v=m.term_weights_)
    x = np.clip(x, 0.0, 1.0)
    l1 = 0.02
    sparse = dataclasses.replace(p, pen=dataclasses.replace(p.pen, l1=l1))
    cost = emptying_costs(p, x, l1)
    j = int(np.argmax(x))
    emptied = x.copy()
    emptied[j] = 0.0
    assert cost[j] == pytest.approx(sparse.value(emptied) - sparse.value(x))
    y = polish(p, x, l1)
    assert sparse.value(y) <= sparse.value(x)
    assert set(np.unique(y[y != x]).tolist()) <= {0.0}


def test_the_options_must_not_be_negative() -> None:
    with pytest.raises(ConfigError, match="sparsity"):
        GradientMapper(sparsity=-0.1)
    with pytest.raises(ConfigError, match="polish"):
        GradientMapper(polish=-0.1)


@pytest.mark.parametrize("option", ["sparsity", "polish"])
def test_the_stream_refuses_the_sparsity_options(option: str) -> None:
    """Offline only: the stream refuses them rather than ignore them."""
    from sonarmap.streaming import StreamingMapper

    assert StreamingMapper("gradient", GRID, get_rig("ez1-six")) is not None
    params: dict[str, Any] = {option: 0.1}
    mapper = GradientMapper(**params)
    with pytest.raises(ConfigError, match=f"streaming 'gradient' .*{option}.*; set {option}=0"):
        StreamingMapper(mapper, GRID, get_rig("ez1-six"))


def test_polish_counts_the_problems_own_sparsity() -> None:
    """With ``sparsity`` and ``polish`` both set, the emptying costs are the change of
    ``S + polish sum x`` where S already holds ``sparsity sum x``: emptying a cell saves
    both weights. (Before the fix the costs left the problem's own weight out.)"""
    readings = wall_readings(2.02, HCSR04, [0.0, 1.0], [0.0, 0.3], 0.01)
    m = GradientMapper(band_offset=HALF_CELL, max_iter=60, sparsity=0.2, polish=0.02)
    m.fit(readings, GRID, HCSR04)
    p = dataclasses.replace(m.problem(readings), v=m.term_weights_)
    assert p.pen.l1 == 0.2
    with_polish = dataclasses.replace(p, pen=dataclasses.replace(p.pen, l1=0.2 + 0.02))
    x = np.clip(np.asarray(m.solution_), 0.0, 1.0)
    cost = emptying_costs(p, x, 0.02)
    for j in [*np.flatnonzero(x > 0.5)[:5].tolist(), int(np.argmax(x))]:
        emptied = x.copy()
        emptied[j] = 0.0
        assert cost[j] == pytest.approx(with_polish.value(emptied) - with_polish.value(x))
    alone = emptying_costs(p, x)
    j = int(np.argmax(x))
    emptied = x.copy()
    emptied[j] = 0.0
    assert alone[j] == pytest.approx(p.value(emptied) - p.value(x))
    y = polish(p, x, 0.02)
    assert with_polish.value(y) <= with_polish.value(x)
