"""Streaming maps: readings in as they arrive, the map readable at any moment.

:class:`StreamingMapper` keeps a method's map over a bounded set of readings (chosen by
a :mod:`~sonarmap.selection` strategy): :meth:`~StreamingMapper.add` takes a batch of
new readings and updates the map around them; :meth:`~StreamingMapper.improve` spends
spare time improving the whole map; :attr:`~StreamingMapper.occupancy_` is the map now.
:func:`replay` plays a log through it, as fast as possible or at the recorded pace,
and measures every update.

Examples
--------
>>> from sonarmap.scenarios import make_scenario
>>> sc = make_scenario("doorways")
>>> sm = StreamingMapper("gradient", sc.truth.grid, sc.rig, strategy="cell:4")
>>> report = replay([sc.readings], sm, period=0.5)
>>> report.n_readings == len(sc.readings)
True
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from .errors import ConfigError
from .grid import Grid
from .io.rosmap import OccupancyMap
from .mappers import Mapper, StreamEngine, check_ranges, make_mapper
from .readings import Readings
from .rig import Rig
from .selection import Strategy, parse_strategy
from .sensors import SensorModel

__all__ = ["DEFAULT_STRATEGY", "ReplayReport", "StreamingMapper", "replay", "time_batches"]

#: Passes of :meth:`StreamingMapper.finish` at the end of a :func:`replay` (chosen on
#: training scenes: docs/results/2026-12-06-streaming.md, "fifth pass").
FINISH_PASSES = 100

#: The strategy each method streams with unless told otherwise: ``inverse`` keeps no
#: readings, so it folds in everything; ``gradient`` and ``stochastic`` keep the last
#: 1000 readings. On the first two minutes of the ``office`` scene (``benchmarks/stream.py``)
#: a window of the last 500-2000 readings agreed with the offline gradient map on 99.6 %
#: of cells at 30-75x real time; cell:1-4 on 99.1-99.3 % and pose:1-3 on 86-95 %.
#: ``em-thrun`` keeps the last 50: on the training ``doorways`` scene (offline wall F1
#: 0.301) last:25/50/100 streamed 0.290/0.308/0.298, the smallest window the fastest.
#: Both measured with the gradient's band half a cell behind the echo, before 2026-12-07
#: (not re-run at today's band; its stream at the new band:
#: docs/results/2026-12-07-gradient-wall-thickness.md, "The stream at the new band").
DEFAULT_STRATEGY = {
    "inverse": "all",
    "gradient": "last:1000",
    "stochastic": "last:1000",
    "em-thrun": "last:50",
}


class StreamingMapper:
    """A method's map, updated as readings arrive, over a bounded set of them.

    Parameters
    ----------
    method : str or Mapper
        A method that streams (``inverse``, ``gradient``, ``em-thrun``, ``stochastic``),
        or a mapper instance carrying its parameters.
    grid : Grid
        The map grid; fixed for the stream.
    sensor : SensorModel or Rig
        The sonars' model.
    strategy : Strategy or str, optional
        Which readings stay in play (see :func:`sonarmap.selection.parse_strategy`);
        default :data:`DEFAULT_STRATEGY` of the method.
    effort : int
        Work per update: gradient steps (``gradient``), flip sweeps over the updated
        cells (``stochastic``), M-step sweeps at most (``em-thrun``); ignored by
        ``inverse``.
    fold : bool, optional
        ``gradient``, ``em-thrun``: fold each reading that leaves into fixed per-cell
        evidence rather than forget it (see :mod:`sonarmap.mappers._stream`). Default:
        the method's (``em-thrun`` folds; ``gradient`` folds only when its no-echo
        readings clear their beams, ``no_echo="free"``). Fixed for the stream.

    Raises
    ------
    ConfigError
        ``fold`` given for a method that cannot fold (``inverse``, ``stochastic``), or a
        parameter, strategy or effort the method cannot stream with.
    **params
        The method's parameters, when ``method`` is a name.
    """

    def __init__(
        self,
        method: str | Mapper,
        grid: Grid,
        sensor: SensorModel | Rig,
        *,
        strategy: Strategy | str | None = None,
        effort: int = 1,
        fold: bool | None = None,
        **params: Any,
    ) -> None:
        if isinstance(method, Mapper):
            if params:
                raise ConfigError("give parameters either in the mapper or as keywords")
            mapper = method
        else:
            mapper = make_mapper(method, **params)
        if strategy is None:
            strategy = DEFAULT_STRATEGY.get(mapper.name, "cell:4")
        self.strategy = parse_strategy(strategy) if isinstance(strategy, str) else strategy
        self.engine: StreamEngine = mapper.stream(
            grid, sensor, self.strategy, effort=effort, fold=fold
        )
        self.mapper = mapper
        self.grid = grid
        self.n_readings = 0
        #: The latest batch taken (where the robot is now, what it just heard).
        self.last_batch: Readings | None = None

    def add(self, readings: Readings) -> float:
        """Take a batch of new readings and update the map; returns the seconds it took."""
        check_ranges(readings, offset=self.n_readings)
        t0 = time.perf_counter()
        self.engine.add(readings)
        self.n_readings += len(readings)
        self.last_batch = readings
        return time.perf_counter() - t0

    def improve(self, budget: float) -> int:
        """Improve the map over every reading in play for up to ``budget`` seconds."""
        return self.engine.improve(budget)

    def finish(self, passes: int = FINISH_PASSES, stop: Callable[[], bool] | None = None) -> int:
        """Bring the map to rest at the end of a log.

        ``gradient`` takes ``passes`` projected steps on every cell the readings in play
        touch (during the stream a cell steps only in the updates whose readings touch
        it); the other methods have nothing to finish and return 0. The state stays
        bounded, and more readings may follow.

        Parameters
        ----------
        passes : int
            Passes over every reading in play, at most; default :data:`FINISH_PASSES`.
        stop : callable, optional
            Asked before each pass; when it returns True the finish ends there, the map
            as it is.

        Returns
        -------
        int
            The passes done: ``passes``, fewer if ``stop`` said so, 0 for the methods
            with nothing to finish.

        Raises
        ------
        ConfigError
            ``passes`` is not an integer >= 0.
        """
        if isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 0:
            raise ConfigError(f"finish passes must be an integer >= 0, got {passes!r}")
        return self.engine.finish(int(passes), stop)

    @property
    def occupancy_(self) -> npt.NDArray[np.float32]:
        """The map now: occupancy in [0, 1], NaN where no reading has been."""
        return self.engine.occupancy().reshape(self.grid.shape)

    def result(self) -> OccupancyMap:
        return OccupancyMap(self.grid, self.occupancy_)

    @property
    def n_in_play(self) -> int:
        """Readings the map is currently optimised over."""
        return self.engine.n_in_play

    def nbytes(self) -> int:
        """Memory of the streaming state (map, coverage, readings in play)."""
        return self.engine.nbytes()


@dataclass
class ReplayReport:
    """What a replay measured. Times in seconds; ``latency`` holds every update's.

    ``max_lag`` (``realtime`` only) is how long after its batch's log time, scaled by
    the replay speed, the latest update finished; it includes time spent in
    ``on_snapshot`` (writing pictures makes the map late too).
    """

    n_readings: int = 0
    data_duration: float = 0.0
    #: Wall time of the replay, not counting ``on_snapshot`` calls.
    wall_time: float = 0.0
    latency: list[float] = field(default_factory=list)
    max_in_play: int = 0
    max_state_bytes: int = 0
    max_lag: float = 0.0
    #: How late the latest update finished (``realtime`` only), seconds.
    lag: float = 0.0
    improve_units: int = 0
    #: Passes of :meth:`StreamingMapper.finish` at the end of the log.
    finish_units: int = 0
    #: Wall time of that finish, seconds (counted in ``wall_time`` too).
    finish_time: float = 0.0
    snapshot_time: float = 0.0
    #: The replay stopped early because ``stop()`` said so.
    interrupted: bool = False

    @property
    def n_updates(self) -> int:
        return len(self.latency)

    @property
    def realtime_factor(self) -> float:
        """Seconds of log per second of wall time."""
        return self.data_duration / self.wall_time if self.wall_time > 0 else float("inf")

    def summary(self) -> dict[str, float | int]:
        """The figures as a flat dict. Latency statistics leave out the first update,
        which includes compiling (or loading) the kernels; it is given on its own."""
        lat = np.asarray(self.latency[1:] if len(self.latency) > 1 else self.latency or [0.0])
        return {
            "readings": self.n_readings,
            "updates": self.n_updates,
            "log_seconds": round(self.data_duration, 3),
            "wall_seconds": round(self.wall_time, 3),
            "realtime_factor": round(self.realtime_factor, 2),
            "readings_per_second": round(self.n_readings / max(self.wall_time, 1e-12), 1),
            "latency_median_ms": round(1e3 * float(np.median(lat)), 3),
            "latency_p99_ms": round(1e3 * float(np.percentile(lat, 99)), 3),
            "latency_max_ms": round(1e3 * float(lat.max()), 3),
            "first_update_ms": round(1e3 * self.latency[0], 3) if self.latency else 0.0,
            "max_readings_in_play": self.max_in_play,
            "max_state_mb": round(self.max_state_bytes / 2**20, 2),
            "max_lag_ms": round(1e3 * self.max_lag, 3),
            "improve_units": self.improve_units,
            "finish_units": self.finish_units,
            "finish_seconds": round(self.finish_time, 3),
            "snapshot_seconds": round(self.snapshot_time, 3),
            "interrupted": self.interrupted,
        }


def time_batches(source: Iterable[Readings], period: float) -> Iterator[Readings]:
    """Re-cut a stream of readings into batches of ``period`` seconds of log time.

    Batch k holds the readings with ``t0 + k period <= t < t0 + (k + 1) period``; empty
    periods are skipped. Only one period is held beyond the incoming chunk.
    """
    if not (period > 0):
        raise ConfigError(f"update period must be > 0 s, got {period}")
    held: list[Readings] = []
    start: float | None = None
    for chunk in source:
        if len(chunk) == 0:
            continue
        if start is None:
            start = float(chunk.t[0])
        k = np.floor((chunk.t - start) / period).astype(np.int64)
        cuts = np.flatnonzero(np.diff(k)) + 1
        pieces = np.split(np.arange(len(chunk)), cuts)
        for piece in pieces:
            part = chunk.take(piece)
            if held and np.floor((held[0].t[0] - start) / period) != k[piece[0]]:
                yield Readings.concat(held)
                held = []
            held.append(part)
    if held:
        yield Readings.concat(held)


#: Seconds behind the log at which a realtime replay first warns.
LAG_WARNING = 2.0


def replay(
    source: Iterable[Readings],
    streamer: StreamingMapper,
    *,
    period: float = 0.25,
    realtime: bool = False,
    speed: float = 1.0,
    snapshot_every: float | None = None,
    on_snapshot: Callable[[float, StreamingMapper], None] | None = None,
    progress: Callable[[float], None] | None = None,
    stop: Callable[[], bool] | None = None,
    on_warning: Callable[[str], None] | None = None,
    report: ReplayReport | None = None,
    on_update: Callable[[Readings, StreamingMapper], None] | None = None,
    finish: bool = True,
) -> ReplayReport:
    """Play readings through ``streamer``, one update per ``period`` s of log time.

    Parameters
    ----------
    source : iterable of Readings
        The log, in time order, in chunks of any size.
    streamer : StreamingMapper
    period : float
        Log time per update, seconds.
    realtime : bool
        Wait for each batch's log time to come round on the wall clock (scaled by
        ``speed``), spending the wait on :meth:`StreamingMapper.improve`; otherwise
        update as fast as possible.
    snapshot_every : float, optional
        Log seconds between calls of ``on_snapshot(log_time, streamer)``; one more call
        follows the last update.
    progress : callable, optional
        Called with the log time after each update.
    stop : callable, optional
        Asked before each update (and while waiting in ``realtime``) and before each
        pass of the finish; when it returns True the replay ends there, the map as it
        is, and the report says ``interrupted`` (a stop before the log's end skips the
        finish altogether).
    on_warning : callable, optional
        ``realtime``: told, in one line, when the map falls behind the log by more than
        :data:`LAG_WARNING` seconds, and again each time the lag doubles.
    report : ReplayReport, optional
        Filled in as the replay goes (a caller can show ``report.lag`` while it runs);
        a new one by default.
    on_update : callable, optional
        Called with each batch and the streamer after the batch is in the map (to
        record the run, for instance); its time counts as snapshot time.
    finish : bool
        At the end of the log (not after a ``stop``), bring the map to rest with
        :meth:`StreamingMapper.finish` (default True); its time counts in the replay's
        and is reported as ``finish_time``.
    """
    if not (speed > 0):
        raise ConfigError(f"replay speed must be > 0, got {speed}")
    if snapshot_every is not None and not (snapshot_every > 0):
        raise ConfigError(f"snapshot interval must be > 0 s, got {snapshot_every}")
    rep = report if report is not None else ReplayReport()
    warn_at = LAG_WARNING
    t_first: float | None = None
    t_last = 0.0
    next_snap = 0.0
    wall0 = time.perf_counter()
    for batch in time_batches(source, period):
        if stop is not None and stop():
            rep.interrupted = True
            break
        if t_first is None:
            t_first = float(batch.t[0])
            next_snap = t_first + (snapshot_every or 0.0)
        # The batch is complete when its period has passed on the log's clock.
        due_log = t_first + (np.floor((batch.t[0] - t_first) / period) + 1) * period
        if realtime:
            due = wall0 + (due_log - t_first) / speed
            while (left := due - time.perf_counter()) > 0 and not (stop and stop()):
                done = streamer.improve(min(left, 0.1))
                rep.improve_units += done
                if done == 0:
                    time.sleep(min(0.1, max(0.0, due - time.perf_counter())))
        rep.latency.append(streamer.add(batch))
        if realtime and len(rep.latency) > 1:
            # How late the map is; the first update, which loads the kernels, aside.
            rep.lag = time.perf_counter() - (wall0 + (due_log - t_first) / speed)
            rep.max_lag = max(rep.max_lag, rep.lag)
            if rep.lag > warn_at:
                warn_at = 2 * rep.lag
                if on_warning is not None:
                    pace = (due_log - t_first) / (time.perf_counter() - wall0)
                    on_warning(
                        f"falling behind: the map is {rep.lag:.1f} s behind the log, "
                        f"{pace:.2f}x real time so far against --speed {speed:g}; a lower "
                        "--speed, less --effort or a smaller --window keeps up"
                    )
        rep.n_readings += len(batch)
        t_last = float(batch.t[-1])
        rep.max_in_play = max(rep.max_in_play, streamer.n_in_play)
        rep.max_state_bytes = max(rep.max_state_bytes, streamer.nbytes())
        if on_update is not None:
            t_rec = time.perf_counter()
            on_update(batch, streamer)
            rep.snapshot_time += time.perf_counter() - t_rec
        if snapshot_every is not None and on_snapshot is not None and t_last >= next_snap:
            t_snap = time.perf_counter()
            on_snapshot(t_last - t_first, streamer)
            rep.snapshot_time += time.perf_counter() - t_snap
            while next_snap <= t_last:
                next_snap += snapshot_every
        if progress is not None:
            progress(t_last - t_first)
    if finish and not rep.interrupted and t_first is not None:
        t_fin = time.perf_counter()
        rep.finish_units = streamer.finish(stop=stop)
        rep.finish_time = time.perf_counter() - t_fin
        rep.interrupted = stop is not None and rep.finish_units < FINISH_PASSES and stop()
    rep.wall_time = time.perf_counter() - wall0 - rep.snapshot_time
    rep.data_duration = 0.0 if t_first is None else t_last - t_first
    if on_snapshot is not None and t_first is not None:
        t_snap = time.perf_counter()
        on_snapshot(t_last - t_first, streamer)
        rep.snapshot_time += time.perf_counter() - t_snap
    return rep
