"""Down-weighting of correlated readings (issue 14, "Correlated readings"; Konolige 1997):
the weights themselves, and what each mapper does with them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sonarmap.mappers._correlated import correlation_weights, reading_weights
from sonarmap.readings import Readings


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
