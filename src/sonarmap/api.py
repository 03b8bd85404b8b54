"""The operations of the command line, as plain functions."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from .errors import ConfigError, InputError
from .grid import Grid
from .io.rosmap import OccupancyMap
from .mappers import make_mapper
from .readings import Readings
from .rig import Rig

__all__ = ["build_map", "grid_for_readings"]

Progress = Callable[[int, int], None]


def grid_for_readings(
    readings: Readings,
    rig: Rig,
    resolution: float,
    bounds: Sequence[float] | None = None,
    *,
    margin: float = 0.5,
) -> Grid:
    """A grid of ``resolution`` m over ``bounds`` (xmin, ymin, xmax, ymax), or around the data.

    Without bounds the grid covers every sensor position and echo point plus ``margin`` m.
    """
    if bounds is not None:
        if len(bounds) != 4:
            raise ConfigError(f"bounds must be XMIN YMIN XMAX YMAX, got {list(bounds)}")
        x0, y0, x1, y1 = (float(b) for b in bounds)
        return Grid.from_bounds(x0, y0, x1, y1, resolution)
    if len(readings) == 0:
        raise InputError("no readings to size the map from; give bounds")
    echo = readings.range < rig.sensor.r_max
    ex = readings.x[echo] + readings.range[echo] * np.cos(readings.theta[echo])
    ey = readings.y[echo] + readings.range[echo] * np.sin(readings.theta[echo])
    xs = np.concatenate([readings.x, ex])
    ys = np.concatenate([readings.y, ey])
    return Grid.from_bounds(
        float(xs.min()) - margin,
        float(ys.min()) - margin,
        float(xs.max()) + margin,
        float(ys.max()) + margin,
        resolution,
    )


def build_map(
    readings: Readings,
    rig: Rig,
    grid: Grid,
    method: str = "inverse",
    params: Mapping[str, Any] | None = None,
    *,
    progress: Progress | None = None,
) -> OccupancyMap:
    """Build a map with a registered method.

    Parameters
    ----------
    readings : Readings
        Sensor poses and ranges.
    rig : Rig
        Supplies the sensor model; reading names must be the rig's.
    grid : Grid
        The map's grid.
    method : str
        A name from :data:`sonarmap.mappers.MAPPERS`.
    params : mapping, optional
        Keyword parameters of the method.
    """
    unknown = sorted(set(readings.names) - set(rig.names))
    if unknown:
        raise InputError(
            f"readings name sensor(s) {unknown} that the rig lacks; the rig has "
            f"{', '.join(rig.names)}",
            field="sensor",
        )
    below = readings.range < rig.sensor.r_min - 1e-9
    if below.any():
        i = int(np.flatnonzero(below)[0])
        raise InputError(
            f"reading {i}: range {readings.range[i]} is below the sensor's r_min "
            f"({rig.sensor.r_min})",
            field="range",
        )
    mapper = make_mapper(method, **dict(params or {}))
    return mapper.fit(readings, grid, rig, progress=progress).result()
