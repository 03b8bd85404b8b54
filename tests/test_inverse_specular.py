"""The inverse with its free increments weighed by incidence (``specular_deg``).

A hand-built scene: a wall along y = 3 m with a doorway in it, x 4.3-4.7 m. A sonar
below it ranges the wall head-on, moving along it, and crosses it at 60 degrees off
its normal towards farther echoes (a smooth wall met at a slant returns nothing); a
second pass looks straight through the doorway to an echo beyond it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import _base as base
from sonarmap.mappers import _incidence as incidence
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.readings import Readings
from sonarmap.sensors import Region, SensorModel
from sonarmap.streaming import StreamingMapper

GRID = Grid(resolution=0.05, origin=(0.0, 0.0), shape=(120, 130))
SENSOR = SensorModel("cone30", Region.cone(30.0, 5.0), r_min=0.0, r_max=5.0, range_resolution=0.02)
WALL_Y, ROBOT_Y = 3.0, 2.0
#: Wall cells only the slanted beams cross (x 2.2-3.3 m), and the doorway's (4.4-4.6 m).
SLANTED_X, DOOR_X = (2.2, 3.3), (4.4, 4.6)


def _readings() -> Readings:
    # Echoes from the wall, 1 m ahead, up to both jambs: the arcs of those near them
    # reach over the doorway, as a wide beam's do.
    head_on = np.concatenate([np.linspace(0.6, 4.25, 48), np.linspace(4.75, 5.5, 12)])
    # Beams at 30 degrees above the wall's line cross it 2 m away, x 2.0-3.5 m, and
    # echo 0.5 m beyond.
    slant = np.linspace(0.27, 1.77, 40)
    door = np.linspace(4.45, 4.55, 5)  # through the doorway to an echo 2 m beyond it
    x = np.concatenate([head_on, slant, door])
    th = np.concatenate(
        [np.full(60, math.pi / 2), np.full(40, math.pi / 6), np.full(5, math.pi / 2)]
    )
    r = np.concatenate([np.full(60, 1.0), np.full(40, 4.5), np.full(5, 3.0)])
    n = len(x)
    return Readings(
        t=np.arange(n, dtype=np.float64),
        sensor=np.zeros(n, np.int32),
        x=x,
        y=np.full(n, ROBOT_Y),
        theta=th,
        range=r,
        names=("s",),
    )


def _row_cells(xs: tuple[float, float], y: float) -> npt.NDArray[np.int64]:
    rows, cols = GRID.world_to_cell(np.array(xs), np.array([y, y]))
    c0, c1 = int(cols[0]), int(cols[1])
    return np.asarray(GRID.flat_index(np.full(c1 - c0 + 1, int(rows[0])), np.arange(c0, c1 + 1)))


def _log_odds(**params: float) -> npt.NDArray[np.float64]:
    m = make_mapper("inverse", **params).fit(_readings(), GRID, SENSOR)
    assert isinstance(m, InverseMapper)
    return m.log_odds_


# The wall's cells lie just behind its line: the band sits 0.75 of a cell behind the echo.
WALL_CELL_Y = WALL_Y + 0.025


def test_a_wall_met_only_at_a_slant_keeps_its_echoes_with_the_option() -> None:
    wall = _row_cells(SLANTED_X, WALL_CELL_Y)
    plain, slanted = _log_odds(specular_deg=0.0), _log_odds(specular_deg=15.0)
    # Without the option the slanted beams outweigh the echoes on every cell.
    assert np.all(plain[wall] < 0)
    assert np.all(slanted[wall] > 0)


def test_a_doorway_crossed_head_on_stays_free_with_the_option() -> None:
    door = _row_cells(DOOR_X, WALL_CELL_Y)
    plain, slanted = _log_odds(specular_deg=0.0), _log_odds(specular_deg=15.0)
    # The jambs' echoes reach over the doorway, but the beams through it met it head-on:
    # it keeps at least four fifths of its free evidence.
    assert np.all(plain[door] < 0)
    assert np.all(slanted[door] <= 0.8 * plain[door])


def test_occupied_increments_are_left_alone() -> None:
    # With a free increment of a millionth the maps are the occupied increments alone.
    plain = _log_odds(p_free=0.4999999, specular_deg=0.0)
    slanted = _log_odds(p_free=0.4999999, specular_deg=15.0)
    assert np.count_nonzero(plain > 0.1) > 100
    np.testing.assert_allclose(slanted, plain, atol=1e-4)


def test_partial_fits_give_one_fits_map() -> None:
    r = _readings()
    whole = _log_odds(specular_deg=15.0)
    m = make_mapper("inverse", specular_deg=15.0).start(GRID, SENSOR)
    m.partial_fit(r.take(slice(0, 70)))
    m.partial_fit(r.take(slice(70, len(r))))
    assert isinstance(m, InverseMapper)
    np.testing.assert_array_equal(m.log_odds_, whole)


@pytest.mark.parametrize("bad", [-1.0, 90.0, float("nan")])
def test_a_bad_specular_angle_names_the_parameter(bad: float) -> None:
    with pytest.raises(ConfigError, match="specular_deg"):
        make_mapper("inverse", specular_deg=bad)


def test_the_stream_refuses_the_option() -> None:
    with pytest.raises(ConfigError, match="specular_deg=0"):
        StreamingMapper("inverse", GRID, SENSOR, specular_deg=15.0)


def test_a_refused_batch_leaves_the_map_and_the_kept_readings_as_they_were(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    r = _readings()
    first, second = r.take(slice(0, 30)), r.take(slice(30, len(r)))
    m = make_mapper("inverse", specular_deg=15.0).start(GRID, SENSOR)
    assert isinstance(m, InverseMapper)
    m.partial_fit(first)
    size = sum(fp.n_entries for fp in m.kept_footprints(first, dr=m.dr))
    logodds, touched = m.log_odds_.copy(), m.touched_.copy()
    monkeypatch.setattr(base, "MAX_ENTRIES", size + 10)
    with pytest.raises(ConfigError, match=r"specular_deg=0"):
        m.partial_fit(second)
    np.testing.assert_array_equal(m.log_odds_, logodds)
    np.testing.assert_array_equal(m.touched_, touched)
    # The readings kept are the first batch's alone: with the limit back, the second
    # batch gives the map of one fit of the two.
    monkeypatch.undo()
    m.partial_fit(second)
    np.testing.assert_array_equal(m.log_odds_, _log_odds(specular_deg=15.0))


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"falloff_deg": 0.0},
        {"correlated": 0.05},
        {"no_echo": "free"},
        {"p_occ": 0.7},
    ],
)
def test_with_factors_of_one_it_is_the_kernels_map(
    monkeypatch: pytest.MonkeyPatch, params: dict[str, Any]
) -> None:
    # Far echoes, beyond r_max: no-echo readings for no_echo="free".
    r = _readings()
    far = np.where(np.arange(len(r)) % 7 == 0, SENSOR.r_max, r.range)
    r = Readings(t=r.t, sensor=r.sensor, x=r.x, y=r.y, theta=r.theta, range=far, names=r.names)
    plain = make_mapper("inverse", **params).fit(r, GRID, SENSOR)
    monkeypatch.setattr(incidence.Shield, "factors", lambda self, cs, x, y: np.ones(len(cs.cells)))
    monkeypatch.setattr(InverseMapper, "chunk_size", 16)
    forced = make_mapper("inverse", specular_deg=15.0, **params).fit(r, GRID, SENSOR)
    assert isinstance(plain, InverseMapper)
    assert isinstance(forced, InverseMapper)
    np.testing.assert_array_equal(forced.touched_, plain.touched_)
    np.testing.assert_allclose(forced.log_odds_, plain.log_odds_, atol=1e-6, rtol=0)
    if params.get("p_occ") == 0.7:
        hi = math.log(0.97 / 0.03)
        assert np.isclose(plain.log_odds_, hi).any()  # the clamp was reached
