"""The operations of the command line, as plain functions."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from .errors import ConfigError, InputError
from .grid import Grid
from .io.rosmap import OccupancyMap
from .mappers import make_mapper
from .readings import Readings, TimeOrder, iter_readings
from .rig import Rig
from .selection import Strategy
from .streaming import ReplayReport, StreamingMapper, replay

__all__ = [
    "build_map",
    "grid_for_log",
    "grid_for_readings",
    "off_grid",
    "off_grid_note",
    "stream_log",
]

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
    box = _extent(readings, rig)
    if box is None:
        raise InputError("no readings to size the map from; give bounds")
    return _grid_around(box, resolution, margin)


def _extent(readings: Readings, rig: Rig) -> tuple[float, float, float, float] | None:
    """(xmin, ymin, xmax, ymax) of the sensor positions and echo points."""
    if len(readings) == 0:
        return None
    echo = readings.range < rig.sensor.r_max
    ex = readings.x[echo] + readings.range[echo] * np.cos(readings.theta[echo])
    ey = readings.y[echo] + readings.range[echo] * np.sin(readings.theta[echo])
    xs = np.concatenate([readings.x, ex])
    ys = np.concatenate([readings.y, ey])
    return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())


def _grid_around(box: tuple[float, float, float, float], resolution: float, margin: float) -> Grid:
    x0, y0, x1, y1 = box
    try:
        return Grid.from_bounds(x0 - margin, y0 - margin, x1 + margin, y1 + margin, resolution)
    except ConfigError as err:
        # Usually a few poses far from the rest: say where the data reach and what to do.
        raise ConfigError(
            f"{err}: the readings reach x {x0:g} to {x1:g}, y {y0:g} to {y1:g} m; give "
            "--bounds or --like to map the part you want"
        ) from err


def grid_for_log(
    path: str | Path,
    rig: Rig,
    resolution: float,
    bounds: Sequence[float] | None = None,
    *,
    margin: float = 0.5,
) -> Grid:
    """Like :func:`grid_for_readings` for a readings CSV, read chunk by chunk (one pass,
    memory bounded by the chunk)."""
    if bounds is not None:
        return grid_for_readings(Readings.concat([]), rig, resolution, bounds)
    box: tuple[float, float, float, float] | None = None
    for chunk in iter_readings(path, names=rig.names):
        b = _extent(chunk, rig)
        if b is None:
            continue
        box = (
            b
            if box is None
            else (min(box[0], b[0]), min(box[1], b[1]), max(box[2], b[2]), max(box[3], b[3]))
        )
    if box is None:
        raise InputError("no readings (the file has a header only)", path=path)
    return _grid_around(box, resolution, margin)


#: CSV rows read at once while streaming: a few seconds of a 16-sonar ring at 20 Hz.
STREAM_CHUNK = 5_000


def stream_log(
    path: str | Path,
    rig: Rig,
    grid: Grid,
    method: str = "gradient",
    params: Mapping[str, Any] | None = None,
    *,
    strategy: Strategy | str | None = None,
    effort: int = 1,
    period: float = 0.25,
    realtime: bool = False,
    speed: float = 1.0,
    snapshot_every: float | None = None,
    on_snapshot: Callable[[float, StreamingMapper], None] | None = None,
    progress: Callable[[float], None] | None = None,
    order: TimeOrder | None = None,
    on_note: Callable[[str], None] | None = None,
    stop: Callable[[], bool] | None = None,
    report: ReplayReport | None = None,
    on_update: Callable[[Readings, StreamingMapper], None] | None = None,
    finish: bool = True,
) -> tuple[StreamingMapper, ReplayReport]:
    """Replay a readings CSV through a streaming map (see :func:`sonarmap.streaming.replay`).

    The file is read in chunks, in time order (``order``: see
    :func:`sonarmap.readings.iter_readings`): memory is the streaming state's plus one
    chunk. ``on_note`` hears, at the end, how many readings fell wholly outside the grid
    (see :func:`off_grid`), and at once when a realtime replay falls behind; ``stop``,
    ``report``, ``on_update`` and ``finish`` are passed to
    :func:`~sonarmap.streaming.replay`.
    """
    sm = StreamingMapper(method, grid, rig, strategy=strategy, effort=effort, **dict(params or {}))

    outside = 0
    first_outside: Readings | None = None

    def checked() -> Iterator[Readings]:
        nonlocal outside, first_outside
        done = 0
        for chunk in iter_readings(path, names=rig.names, chunk_size=STREAM_CHUNK, order=order):
            _check_r_min(chunk, rig, offset=done, path=path)
            out = off_grid(chunk, rig, grid)
            if out.any():
                outside += int(out.sum())
                if first_outside is None:
                    first_outside = chunk.take(out)
            done += len(chunk)
            yield chunk

    rep = replay(
        checked(),
        sm,
        period=period,
        realtime=realtime,
        speed=speed,
        snapshot_every=snapshot_every,
        on_snapshot=on_snapshot,
        progress=progress,
        stop=stop,
        on_warning=on_note,
        report=report,
        on_update=on_update,
        finish=finish,
    )
    if rep.n_readings == 0 and not rep.interrupted:
        raise InputError("no readings (the file has a header only)", path=path)
    if on_note is not None and first_outside is not None:
        on_note(_off_grid_line(outside, rep.n_readings, rig, first_outside))
    return sm, rep


def _check_r_min(
    readings: Readings, rig: Rig, *, offset: int = 0, path: str | Path | None = None
) -> None:
    below = readings.range < rig.sensor.r_min - 1e-9
    if below.any():
        i = int(np.flatnonzero(below)[0])
        raise InputError(
            f"reading {offset + i} (t={readings.t[i]:g}): range {readings.range[i]} is below "
            f"the sensor's r_min "
            f"({rig.sensor.r_min})",
            path=path,
            field="range",
        )


def off_grid(readings: Readings, rig: Rig, grid: Grid) -> npt.NDArray[np.bool_]:
    """Readings whose beam cannot touch ``grid``: the sonar is farther than the sensor's
    r_max from every cell (they add nothing to a map on that grid)."""
    x0, x1, y0, y1 = grid.extent
    dx = np.maximum(np.maximum(x0 - readings.x, readings.x - x1), 0.0)
    dy = np.maximum(np.maximum(y0 - readings.y, readings.y - y1), 0.0)
    return np.hypot(dx, dy) > rig.sensor.r_max


def off_grid_note(readings: Readings, rig: Rig, grid: Grid) -> str | None:
    """A line saying how many readings :func:`off_grid` leaves out, or None."""
    out = off_grid(readings, rig, grid)
    n = int(out.sum())
    if n == 0:
        return None
    return _off_grid_line(n, len(readings), rig, readings.take(out))


def _off_grid_line(n: int, total: int, rig: Rig, outside: Readings) -> str:
    return (
        f"{n} of {total} readings are more than r_max ({rig.sensor.r_max:g} m) outside "
        f"the grid and add nothing to the map (the first at t={outside.t[0]:g}, sonar at "
        f"x={outside.x[0]:g}, y={outside.y[0]:g})"
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
    _check_r_min(readings, rig)
    mapper = make_mapper(method, **dict(params or {}))
    return mapper.fit(readings, grid, rig, progress=progress).result()
