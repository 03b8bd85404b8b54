"""Down-weighting of correlated readings (Konolige 1997), for every mapper that takes it.

A robot standing still, or turning in place, fires the same sonar at the same surface
over and over: many readings from one pose then outvote a few from elsewhere, though
they repeat one measurement rather than add independent ones. Each reading is given a
weight ``1 / n``, n the readings that repeat it (:func:`correlation_weights`), and the
mappers' ``correlated`` parameter (metres; 0 is off) scales each reading's evidence by
it. How the weights are scaled (:func:`reading_weights` gives them with mean 1) is each
method's choice, explained where it uses them.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..readings import Readings

__all__ = ["CORRELATED_ANGLE", "correlation_weights", "reading_weights"]

F64 = npt.NDArray[np.float64]

#: Heading bin of :func:`correlation_weights`, radians: readings whose sonar points
#: within about this of each other's direction (besides sharing a position bin) repeat
#: each other.
CORRELATED_ANGLE = math.radians(10.0)


def correlation_weights(
    sensor: npt.NDArray[np.int32],
    x: F64,
    y: F64,
    theta: F64,
    rng: F64,
    cell: float,
    angle: float = CORRELATED_ANGLE,
) -> F64:
    """Per-reading weight ``1 / n`` with n the readings that repeat it (Konolige 1997).

    Readings repeat each other when they come from the same sonar, from poses in the
    same bin (``cell`` metres in x and y, ``angle`` radians in heading) and with ranges
    in the same ``cell``-metre bin: n such readings then count as one. Bins, not
    distances, keep it one pass and deterministic (two readings astride a bin edge are
    not grouped). The ranges must be finite.

    Examples
    --------
    >>> z = np.zeros(3)
    >>> correlation_weights(np.zeros(3, np.int32), z, z, z, np.array([1.0, 1.01, 2.0]), 0.05)
    array([0.5, 0.5, 1. ])
    """
    keys = np.stack(
        [
            sensor.astype(np.int64),
            np.floor(x / cell).astype(np.int64),
            np.floor(y / cell).astype(np.int64),
            np.floor(np.mod(theta, 2 * math.pi) / angle).astype(np.int64),
            np.floor(rng / cell).astype(np.int64),
        ],
        axis=1,
    )
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    return np.asarray(1.0 / counts[inverse.ravel()], dtype=np.float64)


def reading_weights(readings: Readings, cell: float, r_max: float) -> F64:
    """:func:`correlation_weights` of ``readings`` with ``cell``-metre bins, scaled to
    mean 1 (empty for no readings).

    A no-echo reading may carry any range from ``r_max`` up (``inf`` included); all
    say the same, so they are binned at ``r_max``.

    Examples
    --------
    >>> z = np.zeros(4)
    >>> r = Readings(z, np.zeros(4, np.int32), z, z, z, np.array([1.0, 1.0, 3.0, np.inf]), ("s",))
    >>> reading_weights(r, 0.05, 3.0)
    array([1., 1., 1., 1.])
    >>> reading_weights(r.take([0, 1, 2]), 0.05, 3.0)
    array([0.75, 0.75, 1.5 ])
    """
    if len(readings) == 0:
        return np.empty(0)
    rng = np.minimum(readings.range, r_max)
    w = correlation_weights(readings.sensor, readings.x, readings.y, readings.theta, rng, cell)
    return np.asarray(w / w.mean(), dtype=np.float64)
