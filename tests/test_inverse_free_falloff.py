"""The inverse's free increment under its own fall-off (``falloff_free_deg``; issue 39)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pandas as pd
import pytest
from benchmarks.inverse_free_falloff import figures, main, verdicts
from benchmarks.inverse_walls import DEFAULTS

from conftest import refused_in_one_line, training_sweep
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import make_mapper
from sonarmap.mappers.inverse import InverseMapper
from sonarmap.raster import rasterise
from sonarmap.readings import Readings
from sonarmap.sensors import get_sensor
from sonarmap.streaming import StreamingMapper

GRID = Grid(resolution=0.05, origin=(-1.0, -3.0), shape=(120, 120))
SENSOR = "maxsonar-ez1"


def _readings() -> Readings:
    # Echoes at 1.5-3 m from four poses facing a wall at x = 3, met head-on and at a
    # slant, twelve times each in turn: enough repeats that cells reach the clamps; a
    # fifth every third turn, so that correlated readings' weights differ; and a beam
    # with no echo (range r_max) from a sixth pose, so that no_echo matters.
    poses = [(0.0, 0.0, 0.0), (0.0, -0.5, 0.3), (0.5, 0.5, -0.4), (-0.5, 0.0, 0.1)]
    r_max = get_sensor(SENSOR).r_max
    x, y, th, r = [], [], [], []
    for k in range(12):
        for px, py, pt in poses if k % 3 else [*poses, (1.0, -1.0, 0.2)]:
            x.append(px)
            y.append(py)
            th.append(pt)
            r.append((3.0 - px) / math.cos(pt))
        x.append(0.0)
        y.append(-2.0)
        th.append(0.6)
        r.append(r_max)
    n = len(r)
    return Readings(
        t=np.arange(n, dtype=np.float64),
        sensor=np.zeros(n, np.int32),
        x=np.array(x),
        y=np.array(y),
        theta=np.array(th),
        range=np.array(r),
        names=("s",),
    )


def _by_hand(rd: Readings, m: InverseMapper) -> npt.NDArray[np.float32]:
    """``m``'s map of ``rd`` from :func:`rasterise`'s footprints: the free cells weighed
    by the free fall-off, the band by ``falloff_deg``, reading by reading, clamped."""
    sensor = get_sensor(SENSOR)
    if m.no_echo == "ignore":
        rd = rd.take(rd.range < sensor.r_max)
    fp = rasterise(
        GRID,
        sensor,
        rd.x,
        rd.y,
        rd.theta,
        rd.range,
        dr=m.dr,
        offset=m.band_offset_for(GRID),
        with_bearing=True,
        free_stop=m.free_stop_for(sensor),
    )
    free_deg = m.falloff_deg if m.falloff_free_deg is None else m.falloff_free_deg
    lo, hi = (math.log(p / (1 - p)) for p in (m.clamp_min, m.clamp_max))
    v, seen = np.zeros(GRID.size), np.zeros(GRID.size, dtype=bool)
    for i in range(fp.free.n_readings):
        for cs, p, deg in ((fp.free, m.p_free, free_deg), (fp.occ, m.p_occ, m.falloff_deg)):
            assert cs.bearing is not None
            b = cs.bearing[cs.offsets[i] : cs.offsets[i + 1]].astype(np.float64)
            w = np.exp(-(b * b) / (2 * math.radians(deg) ** 2)) if deg > 0 else np.ones(len(b))
            c = cs.of(i)
            v[c] = np.clip(v[c] + math.log(p / (1 - p)) * w, lo, hi)
            seen[c] = True
    occ = 1.0 / (1.0 + np.exp(-v))
    occ[~seen] = np.nan
    return np.asarray(occ, dtype=np.float32).reshape(GRID.shape)


@pytest.mark.parametrize(
    "params",
    [
        {"falloff_free_deg": 2.5},
        {"falloff_free_deg": 3.0, "falloff_deg": 0.0},
        {"falloff_free_deg": 10.0, "falloff_deg": 2.0},
        {"falloff_free_deg": 0.0},
        {"falloff_free_deg": 2.5, "free_stop": 0.1},
        {"falloff_free_deg": 2.5, "no_echo": "free"},
    ],
)
def test_each_increment_takes_its_own_fall_off(params: dict[str, float]) -> None:
    rd, sensor = _readings(), get_sensor(SENSOR)
    m = InverseMapper(**params)  # type: ignore[arg-type]
    got = m.fit(rd, GRID, sensor).result().occupancy
    want = _by_hand(rd, m)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6, equal_nan=True)
    # Some cells held at a clamp: the reading-by-reading order was exercised.
    assert np.nanmin(got) == pytest.approx(InverseMapper().clamp_min, abs=1e-6)


#: Options whose insertion takes other paths: the incidence weighting (footprints kept,
#: free increments scaled per cell) and the correlated readings' weights.
OTHER_PATHS = [{}, {"specular_deg": 30.0}, {"correlated": 0.5}]


@pytest.mark.parametrize("extra", OTHER_PATHS)
def test_off_or_equal_is_the_kernel_map_and_the_split_path_agrees_with_it(
    extra: dict[str, float],
) -> None:
    rd, sensor = _readings(), get_sensor(SENSOR)
    base = make_mapper("inverse", **extra).fit(rd, GRID, sensor).result().occupancy
    same = (
        make_mapper("inverse", falloff_free_deg=5.0, **extra)
        .fit(rd, GRID, sensor)
        .result()
        .occupancy
    )
    np.testing.assert_array_equal(same, base)
    # A hair apart, the footprints' path: the kernel's cells and values to float32's
    # bearings (the kernel's fall-off is a fit within 1e-9 of the Gaussian).
    split = (
        InverseMapper(falloff_free_deg=5.0 + 1e-9, **extra)  # type: ignore[arg-type]
        .fit(rd, GRID, sensor)
        .result()
        .occupancy
    )
    np.testing.assert_array_equal(np.isnan(split), np.isnan(base))
    np.testing.assert_allclose(split, base, rtol=0, atol=1e-6, equal_nan=True)
    # A narrower free fall-off clears fewer cells, none more.
    narrow = (
        InverseMapper(falloff_free_deg=2.0, **extra)  # type: ignore[arg-type]
        .fit(rd, GRID, sensor)
        .result()
        .occupancy
    )
    n_free = [int(np.sum(np.nan_to_num(m, nan=1.0) < 0.5)) for m in (base, narrow)]
    assert n_free[1] < n_free[0]


@pytest.mark.parametrize("extra", OTHER_PATHS)
def test_partial_fit_and_the_all_stream_give_the_fit_map(extra: dict[str, float]) -> None:
    rd, sensor = _readings(), get_sensor(SENSOR)
    m = InverseMapper(falloff_free_deg=2.5, **extra)  # type: ignore[arg-type]
    want = m.fit(rd, GRID, sensor).result().occupancy
    parts = InverseMapper(falloff_free_deg=2.5, **extra)  # type: ignore[arg-type]
    parts.start(GRID, sensor)
    for a in range(0, len(rd), 7):
        parts.partial_fit(rd.take(slice(a, a + 7)))
    np.testing.assert_array_equal(parts.result().occupancy, want)
    if extra:
        return  # streaming refuses both options
    sm = StreamingMapper("inverse", GRID, sensor, strategy="all", falloff_free_deg=2.5)
    sm.add(rd)
    np.testing.assert_array_equal(sm.occupancy_, want)


def test_bad_values_and_a_bounded_stream_are_refused() -> None:
    for bad in (-1.0, math.nan, "narrow", True):
        with pytest.raises(ConfigError, match="falloff_free_deg"):
            make_mapper("inverse", falloff_free_deg=bad)
    with pytest.raises(ConfigError, match="falloff_free_deg streams only"):
        StreamingMapper(
            "inverse",
            GRID,
            get_sensor(SENSOR),
            strategy="cell:4",
            falloff_deg=0.0,
            falloff_free_deg=2.0,
        )
    # 0, as falloff_deg=0, weighs nothing by its bearing: a bounded window takes it.
    StreamingMapper(
        "inverse",
        GRID,
        get_sensor(SENSOR),
        strategy="cell:4",
        falloff_deg=0.0,
        falloff_free_deg=0.0,
    )


SWEEP = {
    DEFAULTS: {},
    "walls": {"recall": 0.8, "f1": 0.305, "precision": 0.66},
    "walls-no-ring-passage": {"recall": 0.8, "ring_passages": 0},
    "faint": {"recall": 0.69, "quality": 0.1},
}


def test_the_rule_scores_each_setting_against_the_defaults() -> None:
    got = verdicts(figures(training_sweep("inverse", SWEEP))).set_index("setting")
    assert got["maps"].tolist() == [16] * 4
    assert got.loc["walls", "passages_ring16"] == 4
    assert got.loc[DEFAULTS, "passages"] == 16
    assert got["fails"].to_dict() == {
        DEFAULTS: "1",
        "walls": "none",
        "walls-no-ring-passage": "3",
        "faint": "1, 5",
    }


def test_pooled_sweeps_and_missing_scenes_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    one = training_sweep("inverse", SWEEP)
    # Two sweeps' files pooled: the defaults on 32 maps, each candidate on 16.
    pooled = pd.concat([one, training_sweep("inverse", {DEFAULTS: {}})], ignore_index=True)
    with pytest.raises(ValueError, match="'walls' has 16 maps, the defaults 32"):
        verdicts(figures(pooled))
    # The MaxSonar hall missing from every setting: NaN, which no comparison fails.
    with pytest.raises(ValueError, match="no figure for ez1_hall_observed"):
        verdicts(figures(one[one.scenario != "hall-ez1"]))
    no_ring = one[~one.scenario.str.endswith("ring16")]
    with pytest.raises(ValueError, match="passages_ring16, f1_ring16"):
        verdicts(figures(no_ring))
    with pytest.raises(ValueError, match="no row of the defaults"):
        verdicts(figures(one[one.params != DEFAULTS]))
    pooled.to_csv(tmp_path / "pooled.csv", index=False)
    one.to_csv(tmp_path / "one.csv", index=False)
    main([str(tmp_path / "one.csv")])
    assert "walls-no-ring-passage" in capsys.readouterr().out
    bad = [
        ([str(tmp_path / "pooled.csv")], "pooled.csv: setting 'walls' has 16 maps"),
        ([str(tmp_path / "none.csv")], "none.csv: no such file"),
        ([str(tmp_path / "one.csv"), str(tmp_path / "one.csv")], "unrecognized arguments"),
        (["--issue14", "passages", "--setting", "falloff_free_deg=2"], "needs -o DIR"),
    ]
    for setting, why in (
        ("falloff_free_deg=abc", "want K=V,K=V with numbers"),
        ("=2", "want K=V,K=V with numbers"),
        ("falloff_free_deg=-1", "falloff_free_deg"),
        ("widest=2", "unknown parameter"),
    ):
        args = ["--issue14", "passages", "-o", str(tmp_path / "x"), "--setting", setting]
        bad.append((args, why))
    for args, why in bad:
        refused_in_one_line(main, args, why, capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.csv", "pooled.csv"]
