"""Down-weighting of correlated readings (issue 14, "Correlated readings"; Konolige 1997):
the weights themselves, and what each mapper does with them."""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.mappers import (
    MAPPERS,
    CountingMapper,
    EMMapper,
    InverseMapper,
    StochasticMapper,
    ThrunEMMapper,
    make_mapper,
)
from sonarmap.mappers._correlated import correlation_weights, reading_weights
from sonarmap.raster import accumulate, rasterise
from sonarmap.readings import Readings
from sonarmap.rig import Mount, Rig
from sonarmap.selection import LastN
from sonarmap.sensors import Region, SensorModel


def readings_at(
    x: list[float], y: list[float], theta: list[float], ranges: list[float], sensor: list[int]
) -> Readings:
    n = len(x)
    return Readings(
        np.arange(n, dtype=np.float64),
        np.array(sensor, np.int32),
        np.array(x, np.float64),
        np.array(y, np.float64),
        np.array(theta, np.float64),
        np.array(ranges, np.float64),
        ("a", "b"),
    )


# Readings drawn from few values, so that many fall into one bin.
some_readings = st.integers(1, 40).flatmap(
    lambda n: st.tuples(
        st.lists(st.sampled_from([0.0, 0.01, 0.3, 1.0]), min_size=n, max_size=n),
        st.lists(st.sampled_from([0.0, 0.02, -0.5]), min_size=n, max_size=n),
        st.lists(st.sampled_from([0.0, 0.05, 1.0, -3.0, 2 * math.pi]), min_size=n, max_size=n),
        st.lists(st.sampled_from([0.5, 0.51, 1.0, 3.0, 7.0, math.inf]), min_size=n, max_size=n),
        st.lists(st.sampled_from([0, 1]), min_size=n, max_size=n),
    )
)


@given(data=some_readings, seed=st.integers(0, 2**32 - 1))
def test_weights_do_not_depend_on_reading_order(
    data: tuple[list[float], list[float], list[float], list[float], list[int]], seed: int
) -> None:
    r = readings_at(*data)
    perm = np.random.default_rng(seed).permutation(len(r))
    rng = np.minimum(r.range, 3.0)
    raw = correlation_weights(r.sensor, r.x, r.y, r.theta, rng, 0.05)
    shuffled = r.take(perm)
    got = correlation_weights(
        shuffled.sensor, shuffled.x, shuffled.y, shuffled.theta, rng[perm], 0.05
    )
    np.testing.assert_array_equal(got, raw[perm])
    # Scaled to mean 1 the sum's rounding may move the last bit, no more.
    w = reading_weights(r, 0.05, 3.0)
    np.testing.assert_allclose(reading_weights(shuffled, 0.05, 3.0), w[perm], rtol=1e-14)
    assert w.mean() == pytest.approx(1.0)
    # A weight 1 / n is shared by n readings at a time (whole bins), so the weights
    # of a bin add up to 1.
    for v in np.unique(raw):
        n = round(1.0 / v)
        assert 1.0 / v == pytest.approx(n)
        assert np.sum(raw == v) % n == 0
    assert raw.sum() == pytest.approx(round(raw.sum()))


def test_a_burst_from_one_pose_counts_as_one_reading() -> None:
    """Ten readings of sonar 0 from one pose and heading, ranges within one 5 cm bin,
    then one from 1 m away, one of sonar 1 from the same pose, one 20 degrees round and
    one with a range 10 cm longer: only the ten repeat each other."""
    x = [0.0] * 10 + [1.0, 0.0, 0.0, 0.0]
    y = [0.0] * 14
    th = [0.0] * 12 + [math.radians(20.0), 0.0]
    rng = [1.0 + 0.004 * k for k in range(10)] + [1.0, 1.0, 1.0, 1.1]
    sensor = [0] * 11 + [1, 0, 0]
    w = correlation_weights(
        np.array(sensor, np.int32), np.array(x), np.array(y), np.array(th), np.array(rng), 0.05
    )
    np.testing.assert_array_equal(w, [0.1] * 10 + [1.0] * 4)
    assert w[:10].sum() == pytest.approx(w[10])


def test_no_echo_readings_bin_at_r_max() -> None:
    """No-echo ranges (r_max, anything beyond, inf) repeat each other, with no warning
    from an infinite range."""
    r = readings_at([0.0] * 3, [0.0] * 3, [0.0] * 3, [3.0, 3.7, math.inf], [0] * 3)
    np.testing.assert_array_equal(reading_weights(r, 0.05, 3.0), [1.0, 1.0, 1.0])
    assert len(reading_weights(r.take(slice(0, 0)), 0.05, 3.0)) == 0


# -- a burst from one place and a lone reading from another -----------------------------

#: 1/8 m cells and poses on multiples of them: the lone reading's footprint is the
#: burst's moved by whole cells, bit for bit.
GRID = Grid(resolution=0.125, origin=(0.0, 0.0), shape=(40, 40))
SENSOR = SensorModel("cone", Region.cone(30.0, 3.0), r_min=0.0, r_max=3.0, range_resolution=0.02)
RIG = Rig(SENSOR, (Mount("s", 0.0, 0.0, 0.0),))
N_BURST = 6
#: The lone reading's pose is the burst's moved by this many rows (2 m down the map).
SHIFT = 16


def burst_and_lone(n: int = N_BURST, rng: float = 2.0) -> Readings:
    """n equal readings from (0.5, 2.5) looking along +x, then one from (0.5, 0.5)."""
    y = [2.5] * n + [0.5]
    return readings_at([0.5] * (n + 1), y, [0.0] * (n + 1), [rng] * (n + 1), [0] * (n + 1))


def burst_rows() -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Flat cells of the burst's footprint, and the same cells moved onto the lone's."""
    fp = rasterise(GRID, SENSOR, [0.5], [2.5], [0.0], [2.0], offset=0.75 * GRID.resolution)
    cells = np.concatenate([fp.free.cells, fp.occ.cells]).astype(np.int64)
    assert len(cells) > 50
    return cells, cells + SHIFT * GRID.cols


def test_inverse_burst_weighs_what_the_lone_reading_does() -> None:
    """Each of the burst's n log-odds updates is scaled by 1 / n (times the common mean-1
    scale): over its footprint it adds what the lone reading adds over its own. Off, it
    adds n times as much."""
    burst, lone = burst_rows()
    on = InverseMapper(correlated=0.05).fit(burst_and_lone(), GRID, RIG)
    off = InverseMapper().fit(burst_and_lone(), GRID, RIG)
    logit_on = on._logodds
    np.testing.assert_allclose(logit_on[burst], logit_on[lone], rtol=1e-12)
    assert np.abs(logit_on[lone]).min() > 0
    np.testing.assert_allclose(off._logodds[burst], N_BURST * off._logodds[lone], rtol=1e-12)
    # The scale: weights 1 / n and 1 with mean 1 are s / n and s, s = (n + 1) / 2.
    np.testing.assert_allclose(logit_on[lone], (N_BURST + 1) / 2 * off._logodds[lone])


def test_inverse_partial_fit_still_gives_one_fits_map() -> None:
    """The burst's readings arrive in two batches, the second completing the bin: the
    first batch's updates are weighted again once it is known."""
    r = burst_and_lone()
    one = InverseMapper(correlated=0.05).fit(r, GRID, RIG)
    two = InverseMapper(correlated=0.05).start(GRID, RIG)
    two.partial_fit(r.take(slice(0, 2)))
    two.partial_fit(r.take(slice(2, None)))
    np.testing.assert_array_equal(two.occupancy_, one.occupancy_)


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_weighted_insertion_scales_each_readings_update(parts: int) -> None:
    """The kernel with per-reading weights against the reference: rasterise, then per
    reading add its weight times the increments and clamp; serial and in row stripes."""
    rng = np.random.default_rng(7)
    n = 200
    x, y = rng.uniform(0.5, 4.5, n), rng.uniform(0.5, 4.5, n)
    th, r = rng.uniform(-4, 4, n), rng.uniform(0.2, 3.3, n)
    w = rng.uniform(0.0, 3.0, n)
    inc, clamp = (-0.3, 0.7), (-1.0, 1.2)
    fp = rasterise(GRID, SENSOR, x, y, th, r)
    want = np.zeros(GRID.size)
    for i in range(n):
        for cells, v in ((fp.free.of(i), inc[0]), (fp.occ.of(i), inc[1])):
            want[cells] = np.clip(want[cells] + w[i] * v, *clamp)
    got = np.zeros(GRID.size)
    touched = np.zeros(GRID.size, dtype=np.bool_)
    before = numba.get_num_threads()
    numba.set_num_threads(min(parts, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    try:
        k = accumulate(
            GRID, SENSOR, x, y, th, r, got, touched,
            inc_free=inc[0], inc_occ=inc[1], clamp=clamp, weights=w,
        )  # fmt: skip
    finally:
        numba.set_num_threads(before)
    assert k == fp.n_entries
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_bad_insertion_weights_are_refused() -> None:
    v, t = np.zeros(GRID.size), np.zeros(GRID.size, np.bool_)
    for bad in ([1.0], [1.0, -1.0], [1.0, np.nan]):
        with pytest.raises(ConfigError, match="weights must be 2 finite numbers >= 0"):
            accumulate(
                GRID, SENSOR, [1, 1], [1, 1], [0, 0], [1, 1], v, t,
                inc_free=-0.1, inc_occ=0.1, weights=bad,
            )  # fmt: skip


STREAMING = sorted(
    n for n, c in MAPPERS.items() if c.streamer is not None and "correlated" in c.param_names()
)


@pytest.mark.parametrize("method", STREAMING)
def test_streaming_refuses_correlated_readings(method: str) -> None:
    """A weight depends on readings still to come: no streaming engine can keep it."""
    # The inverse fall-off needs the 'all' strategy, which the others refuse.
    params = {"falloff_deg": 0.0} if method == "inverse" else {}
    assert make_mapper(method, **params).stream(GRID, RIG, LastN(100)) is not None
    with pytest.raises(
        ConfigError,
        match=f"streaming '{method}' cannot down-weight correlated readings .*; set correlated=0",
    ):
        make_mapper(method, correlated=0.05, **params).stream(GRID, RIG, LastN(100))


def test_counting_burst_casts_one_vote() -> None:
    """Where the burst's band meets the free part of the lone reading (taken 0.5 m
    further along, hearing an echo 0.5 m beyond the burst's), a cell gets n "occupied"
    votes and one "free": n / (n + 1) plain, one against one with the burst
    down-weighted."""
    y = [2.5] * (N_BURST + 1)
    r = readings_at(
        [0.5] * N_BURST + [1.0],
        y,
        [0.0] * (N_BURST + 1),
        [2.0] * N_BURST + [2.0],
        [0] * (N_BURST + 1),
    )
    m = CountingMapper()
    both = m.start(GRID, RIG).band_offset_for(GRID)
    burst = rasterise(GRID, SENSOR, [0.5], [2.5], [0.0], [2.0], dr=m.dr, offset=both)
    lone = rasterise(GRID, SENSOR, [1.0], [2.5], [0.0], [2.0], dr=m.dr, offset=both)
    cells = np.intersect1d(burst.occ.cells, lone.free.cells)
    assert len(cells) > 0
    off = CountingMapper().fit(r, GRID, RIG).occupancy_.ravel()
    on = CountingMapper(correlated=0.05).fit(r, GRID, RIG).occupancy_.ravel()
    np.testing.assert_allclose(off[cells], N_BURST / (N_BURST + 1), rtol=1e-6)
    np.testing.assert_allclose(on[cells], 0.5, rtol=1e-6)
    # Split anywhere, partial_fit recounts: one fit's map.
    two = CountingMapper(correlated=0.05).start(GRID, RIG)
    two.partial_fit(r.take(slice(0, 3)))
    two.partial_fit(r.take(slice(3, None)))
    np.testing.assert_array_equal(two.occupancy_.ravel(), on)


def cross_view(n: int) -> Readings:
    """n equal readings from (0.5, 2.5) looking along +x, hearing a wall at 2 m, then
    one from (2.5, 1.0) looking along +y whose beam crosses that wall's place and hears
    an echo 2.5 m away."""
    x, y = [0.5] * n + [2.5], [2.5] * n + [1.0]
    return readings_at(x, y, [0.0] * n + [math.pi / 2], [2.0] * n + [2.5], [0] * (n + 1))


#: The mean-1 scale of weights 1 / n (the burst's) and 1 (the lone reading's).
SCALE = (N_BURST + 1) / 2


@pytest.mark.parametrize("cls", [EMMapper, ThrunEMMapper])
def test_em_burst_counts_as_one_reading(cls: type[EMMapper | ThrunEMMapper]) -> None:
    """Weighted, the burst and the lone reading are the burst's reading and the lone one
    taken once each, every log-likelihood times the mean-1 scale: EM finds the same map
    (its ratio of expected hits to passes, or the sign of each flip's gain, does not see
    the scale), the log-likelihood is the scale times as large, and so are the final
    posterior's log-odds. Plain, the burst outvotes the lone reading."""
    # Thesis 000's p_hit (em's default before issue 39), where the plain burst's
    # passes are strong enough to outvote the lone reading.
    on = cls(correlated=0.05, p_hit=0.75).fit(cross_view(N_BURST), GRID, RIG)
    once = cls(p_hit=0.75).fit(cross_view(1), GRID, RIG)
    plain = cls(p_hit=0.75).fit(cross_view(N_BURST), GRID, RIG)

    def estimate(m: EMMapper | ThrunEMMapper) -> npt.NDArray[np.float32]:
        return m.em_map_ if isinstance(m, EMMapper) else m.binary_map_

    np.testing.assert_allclose(estimate(on), estimate(once), rtol=0, atol=1e-6)
    assert np.nanmax(np.abs(estimate(plain) - estimate(once))) > 0.5
    assert on.loglik_[-1] == pytest.approx(SCALE * once.loglik_[-1], rel=1e-12)
    assert on._post is not None
    assert once._post is not None
    log_odds = np.log(once._post / (1.0 - once._post))
    assert np.abs(log_odds).max() > 1.0
    np.testing.assert_allclose(on._post, 1.0 / (1.0 + np.exp(-SCALE * log_odds)), rtol=1e-9)


def test_stochastic_burst_counts_as_one_reading() -> None:
    """With no shape terms and only improving flips kept, the search's decisions do not
    see a common scale of the log-likelihood: weighted, the burst and the lone reading
    give the map of each taken once (the same cells are proposed in the same order), and
    plain, the burst outvotes the lone reading."""

    def fit(n: int, correlated: float = 0.0) -> StochasticMapper:
        m = StochasticMapper(
            schedule="greedy", p_randomfactor=0.0, w_occ=0.0, w_border=0.0, correlated=correlated
        )
        return m.fit(cross_view(n), GRID, RIG)

    on, once, plain = fit(N_BURST, 0.05), fit(1), fit(N_BURST)
    np.testing.assert_array_equal(on.occupancy_, once.occupancy_)
    assert not np.array_equal(plain.occupancy_, once.occupancy_, equal_nan=True)
    assert on.loglik_ == pytest.approx(SCALE * once.loglik_, rel=1e-12)


# -- every method ------------------------------------------------------------------------


def scattered(n: int = 40) -> Readings:
    """Readings from n different poses, no two in one bin of any size used here."""
    rng = np.random.default_rng(11)
    x, y = rng.uniform(0.5, 4.5, n), rng.uniform(0.5, 4.5, n)
    th, r = rng.uniform(-math.pi, math.pi, n), rng.uniform(0.3, 3.2, n)
    return readings_at(x.tolist(), y.tolist(), th.tolist(), r.tolist(), [0] * n)


def test_every_method_takes_the_option() -> None:
    assert all("correlated" in cls.param_names() for cls in MAPPERS.values())
    assert all(cls.param_defaults()["correlated"] == 0.0 for cls in MAPPERS.values())


@pytest.mark.parametrize("method", sorted(MAPPERS))
def test_unit_weights_change_no_bit(method: str) -> None:
    """When no two readings repeat each other every weight is exactly 1, and the
    weighted path gives the unweighted map bit for bit (weights multiply; nothing else
    changes)."""
    r = scattered()
    assert (reading_weights(r, 0.05, SENSOR.r_max) == 1.0).all()
    off = make_mapper(method).fit(r, GRID, RIG)
    on = make_mapper(method, correlated=0.05).fit(r, GRID, RIG)
    assert np.isfinite(off.occupancy_).sum() > 100
    np.testing.assert_array_equal(on.occupancy_, off.occupancy_)


@pytest.mark.parametrize("method", sorted(MAPPERS))
@pytest.mark.parametrize(
    ("value", "match"),
    [
        (-0.1, r"parameter 'correlated' must be in \[0.0, inf\], got -0.1"),
        (math.nan, r"parameter 'correlated' must be a finite number, got nan"),
        (math.inf, r"parameter 'correlated' must be a finite number, got inf"),
        ("lots", r"parameter 'correlated' must be a finite number, got 'lots'"),
        (True, r"parameter 'correlated' must be a finite number, got True"),
    ],
)
def test_bad_values_are_refused(method: str, value: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make_mapper(method, correlated=value)
