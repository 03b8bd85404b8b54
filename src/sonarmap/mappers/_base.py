"""The shared mapper interface and the method registry."""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING, Any, ClassVar, Self

import numpy as np
import numpy.typing as npt

from ..checks import numbers_where_floats
from ..errors import ConfigError, SonarmapError, quote
from ..grid import Grid
from ..io.rosmap import OccupancyMap
from ..raster import Footprint, rasterise
from ..readings import Readings
from ..rig import Rig
from ..sensors import SensorModel

if TYPE_CHECKING:
    from ..selection import Strategy
    from ._stream import StreamEngine

__all__ = [
    "MAPPERS",
    "MAX_ENTRIES",
    "Mapper",
    "NotFittedError",
    "make_mapper",
    "parse_params",
    "preset_params",
    "register",
]

Progress = Callable[[int, int], None]

MAPPERS: dict[str, type[Mapper]] = {}

#: Most (reading, cell) pairs a method that keeps every footprint may hold: about 10 GB
#: with the sparse matrices built from them. Beyond it the map is refused, with what to
#: do, before memory runs out.
MAX_ENTRIES = 250_000_000


class NotFittedError(SonarmapError, RuntimeError):
    """A result was read before any readings were given to the mapper."""


def register(cls: type[Mapper]) -> type[Mapper]:
    """Class decorator adding a mapper to :data:`MAPPERS` under ``cls.name``."""
    if cls.name in MAPPERS:
        raise RuntimeError(f"mapper name '{cls.name}' registered twice")
    MAPPERS[cls.name] = cls
    return cls


class Mapper(ABC):
    """A mapping method: readings in, occupancy grid out.

    Subclasses take every parameter as an explicit keyword argument, store it unchanged
    under the same name and validate it in ``__init__``; a parameter never changes
    while a map is being built.

    Use :meth:`fit` for a batch of readings, or :meth:`start` then :meth:`partial_fit`
    repeatedly for readings that arrive over time. Results: :attr:`occupancy_` and
    :meth:`result`.
    """

    name: ClassVar[str]
    #: Whether readings given in several partial_fit calls give exactly the map of one
    #: fit. Methods that re-optimise a coupled objective warm-start from the previous
    #: map instead, and end near, not at, the batch optimum.
    exact_streaming: ClassVar[bool] = False
    #: Readings rasterised at once; bounds the memory of a batch.
    chunk_size: ClassVar[int] = 50_000
    #: The method's streaming engine over a bounded set of readings, if it has one.
    streamer: ClassVar[type[StreamEngine] | None] = None
    #: Named parameter sets (``--preset NAME``): keyword arguments that replace the
    #: defaults they name; parameters given explicitly override them in turn.
    presets: ClassVar[Mapping[str, Mapping[str, Any]]] = {}
    #: Presets ``sonarmap demo`` maps beside the defaults, each labelled
    #: ``{name}-{preset}``.
    demo_presets: ClassVar[tuple[str, ...]] = ()
    #: Where the band sits behind the echo when ``band_offset`` is None, in cells: the
    #: first occupied cell behind a surface lies up to a cell behind it, so the best
    #: offset on the training scenes scales with the cell (see :mod:`sonarmap.raster`).
    offset_cells: ClassVar[float] = 0.0

    _grid: Grid | None = None
    _sensor: SensorModel | None = None

    @classmethod
    def param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values() if p.kind is p.KEYWORD_ONLY]

    @classmethod
    def param_defaults(cls) -> dict[str, Any]:
        sig = inspect.signature(cls.__init__)
        return {p.name: p.default for p in sig.parameters.values() if p.kind is p.KEYWORD_ONLY}

    def get_params(self) -> dict[str, Any]:
        """The mapper's parameters, as given."""
        return {k: getattr(self, k) for k in self.param_names()}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    # -- building a map ------------------------------------------------------------

    def start(self, grid: Grid, sensor: SensorModel | Rig) -> Self:
        """Begin a new map on ``grid`` for readings of ``sensor``."""
        self._grid = grid
        self._sensor = self._model(sensor.sensor if isinstance(sensor, Rig) else sensor)
        self._batches: list[Readings] = []
        self._reset()
        return self

    def attach(self, grid: Grid, sensor: SensorModel) -> None:
        """Give the mapper a grid and sensor model without starting a map.

        For a stream engine that keeps the map itself and calls the mapper's methods,
        which read :attr:`grid` and :attr:`sensor`.

        Parameters
        ----------
        grid : Grid
            Returned by :attr:`grid` from now on.
        sensor : SensorModel
            Returned by :attr:`sensor` as given (the mapper's own model of it is not
            applied, unlike :meth:`start`).
        """
        self._grid, self._sensor = grid, sensor

    def fit(
        self,
        readings: Readings,
        grid: Grid,
        sensor: SensorModel | Rig,
        *,
        progress: Progress | None = None,
    ) -> Self:
        """Build a map from a batch of readings (replacing any previous map)."""
        self.start(grid, sensor)
        return self.partial_fit(readings, progress=progress)

    def partial_fit(self, readings: Readings, *, progress: Progress | None = None) -> Self:
        """Add readings to the map being built."""
        if self._grid is None:
            raise NotFittedError(f"{type(self).__name__}: call start() or fit() first")
        check_ranges(readings)
        kept = len(self._batches)
        try:
            self._add(readings, progress)
        except ConfigError:
            # A refused batch is not kept: the next partial_fit rebuilds from the
            # batches taken before it.
            del self._batches[kept:]
            raise
        return self

    def stream(
        self,
        grid: Grid,
        sensor: SensorModel | Rig,
        strategy: Strategy,
        *,
        effort: int = 1,
        fold: bool | None = None,
    ) -> StreamEngine:
        """A streaming map of this method on ``grid``, over the readings ``strategy`` keeps;
        ``fold`` as :class:`sonarmap.streaming.StreamingMapper` takes it.

        See :mod:`sonarmap.streaming` for the public interface.
        """
        if self.streamer is None:
            have = sorted(n for n, c in MAPPERS.items() if c.streamer is not None)
            raise ConfigError(
                f"method '{self.name}' has no streaming mode; methods that stream: "
                f"{', '.join(have)}"
            )
        model = self._model(sensor.sensor if isinstance(sensor, Rig) else sensor)
        return self.streamer(self, grid, model, strategy, effort, fold=fold)

    def _model(self, sensor: SensorModel) -> SensorModel:
        """The sensor as the method models it (a method may, say, cap its range)."""
        return sensor

    @property
    def grid(self) -> Grid:
        if self._grid is None:
            raise NotFittedError(f"{type(self).__name__} has no map yet; call fit() first")
        return self._grid

    @property
    def sensor(self) -> SensorModel:
        if self._sensor is None:
            raise NotFittedError(f"{type(self).__name__} has no map yet; call fit() first")
        return self._sensor

    @property
    def occupancy_(self) -> npt.NDArray[np.float32]:
        """Occupancy in [0, 1], NaN where no reading touched the cell; shape ``grid.shape``."""
        if self._grid is None:
            raise NotFittedError(f"{type(self).__name__} has no map yet; call fit() first")
        return self._occupancy().reshape(self._grid.shape)

    def result(self) -> OccupancyMap:
        """The current map."""
        return OccupancyMap(self.grid, self.occupancy_)

    # -- for subclasses --------------------------------------------------------------

    @abstractmethod
    def _reset(self) -> None:
        """Allocate an empty map for ``self.grid``."""

    @abstractmethod
    def _add(self, readings: Readings, progress: Progress | None) -> None:
        """Fold readings into the map."""

    @abstractmethod
    def _occupancy(self) -> npt.NDArray[np.float32]:
        """Flat occupancy, NaN where unknown."""

    def band_offset_for(self, grid: Grid) -> float:
        """How far behind the echo the band of occupied cells is moved, on ``grid``.

        Parameters
        ----------
        grid : Grid
            The grid the band is rasterised on.

        Returns
        -------
        float
            Metres: the mapper's ``band_offset`` when it has one and it is given, else
            :attr:`offset_cells` cells of ``grid``.
        """
        given: float | None = getattr(self, "band_offset", None)
        return float(given) if given is not None else self.offset_cells * grid.resolution

    def _footprints(
        self,
        readings: Readings,
        *,
        dr: float | None = None,
        offset: float = 0.0,
        progress: Progress | None = None,
        with_bearing: bool = False,
        no_echo_reach: float | None = None,
        free_stop: float = 0.0,
        band_growth: float = 0.0,
    ) -> Iterator[tuple[int, Footprint]]:
        """Rasterise readings chunk by chunk; yields (index of first reading, footprint)."""
        for a, r in self._chunks(readings, progress):
            fp = rasterise(
                self.grid,
                self.sensor,
                r.x,
                r.y,
                r.theta,
                r.range,
                dr=dr,
                offset=offset,
                with_bearing=with_bearing,
                no_echo_reach=no_echo_reach,
                free_stop=free_stop,
                band_growth=band_growth,
            )
            yield a, fp

    def _chunks(
        self, readings: Readings, progress: Progress | None = None
    ) -> Iterator[tuple[int, Readings]]:
        """``chunk_size`` readings at a time, with the index of the first; ``progress``
        hears of each chunk once the caller is done with it."""
        n = len(readings)
        for a in range(0, n, self.chunk_size):
            b = min(a + self.chunk_size, n)
            yield a, readings.take(slice(a, b))
            if progress is not None:
                progress(b, n)

    def kept_footprints(
        self,
        readings: Readings,
        *,
        dr: float | None,
        offset: float = 0.0,
        with_bearing: bool = False,
        no_echo_reach: float | None = None,
        free_stop: float = 0.0,
        band_growth: float = 0.0,
        advice: str | None = None,
    ) -> list[Footprint]:
        """Every reading's footprint, for methods whose objective couples them all.

        Parameters
        ----------
        readings : Readings
            Rasterised ``chunk_size`` at a time on the started grid and sensor.
        dr : float or None
            Width of the band about the range (metres); None for the sensor's default.
        offset : float, default 0.0
            How far the band is moved behind the range (metres).
        with_bearing : bool, default False
            Also keep each cell's angle off the beam axis.
        no_echo_reach : float or None, default None
            How far a no-echo reading's free cells reach (metres, less ``dr``); None:
            ``r_max`` (see :func:`~sonarmap.raster.rasterise`).
        free_stop : float, default 0.0
            How far short of the band an echo's free cells stop, as a fraction of its
            range (see :func:`~sonarmap.raster.rasterise`).
        band_growth : float, default 0.0
            Growth of an echo's band half-width with its range, metres per metre: the
            half-width ``max(dr, band_growth * range)`` (see
            :func:`~sonarmap.raster.rasterise`).
        advice : str or None, default None
            What the refusal suggests doing instead; None: fewer readings at once,
            coarser cells or no-echo readings dropped.

        Returns
        -------
        list of Footprint
            One per chunk, in reading order.

        Raises
        ------
        ConfigError
            Once the footprints hold more than :data:`MAX_ENTRIES` (reading, cell)
            entries, saying what to do instead.
        """
        out: list[Footprint] = []
        total = 0
        for a, fp in self._footprints(
            readings,
            dr=dr,
            offset=offset,
            with_bearing=with_bearing,
            no_echo_reach=no_echo_reach,
            free_stop=free_stop,
            band_growth=band_growth,
        ):
            total += fp.n_entries
            if total > MAX_ENTRIES:
                raise ConfigError(
                    f"method '{self.name}': the first {a + fp.free.n_readings:,} of "
                    f"{len(readings):,} readings already touch {total / 1e6:.0f} M cells "
                    f"(the limit is {MAX_ENTRIES / 1e6:.0f} M, about 10 GB); "
                    + (
                        advice
                        or "map fewer readings at once (sonarmap stream keeps a bounded "
                        "window), use coarser cells, or drop the no-echo readings "
                        "(no_echo=ignore, where the method has it)"
                    )
                )
            out.append(fp)
        return out

    def _echoes(self, readings: Readings) -> Readings:
        """The readings with an echo (for methods told to ignore no-echo readings)."""
        return readings.take(readings.range < self.sensor.r_max)

    def _accumulate(self, readings: Readings) -> Readings:
        """Keep ``readings`` with the earlier batches and return them all.

        For methods whose objective couples every reading: each partial_fit re-solves
        over everything seen, warm-started from the current map.
        """
        self._batches.append(readings)
        return Readings.concat(self._batches)


def check_ranges(readings: Readings, *, offset: int = 0) -> None:
    """Refuse NaN or negative ranges, naming the first (numbered from ``offset``)."""
    r = readings.range
    if np.isnan(r).any() or (r < 0).any():
        i = int(np.flatnonzero(np.isnan(r) | (r < 0))[0])
        raise ConfigError(f"reading {offset + i}: range must be a number >= 0, got {r[i]}")


def _coerce(value: str, default: Any, key: str, annotation: str = "") -> Any:
    # ``annotation`` is the parameter's annotation as a string: a number that may also
    # be a word (``float | str``) passes a word on for the mapper's own check to name.
    if isinstance(default, bool):
        if value.lower() in ("1", "true", "yes", "on"):
            return True
        if value.lower() in ("0", "false", "no", "off"):
            return False
        raise ConfigError(f"parameter '{key}' expects true or false, got {quote(value)}")
    if isinstance(default, int):
        try:
            return int(value)
        except ValueError:
            raise ConfigError(f"parameter '{key}' expects an integer, got {quote(value)}") from None
    if isinstance(default, float) or default is None:
        if default is None and value.lower() in ("none", ""):
            return None
        try:
            return float(value)
        except ValueError:
            if default is None or "str" in (t.strip() for t in annotation.split("|")):
                return value
            raise ConfigError(f"parameter '{key}' expects a number, got {quote(value)}") from None
    return value


def preset_params(method: str, preset: str) -> dict[str, Any]:
    """The keyword arguments of one of a method's named parameter sets.

    Examples
    --------
    >>> preset_params("gradient", "thesis002")["c2"]
    1.0
    """
    cls = _lookup(method)
    if preset not in cls.presets:
        have = ", ".join(cls.presets) if cls.presets else "none"
        raise ConfigError(f"unknown preset '{preset}' for method '{method}'; valid: {have}")
    return dict(cls.presets[preset])


def parse_params(
    method: str, pairs: Mapping[str, str], *, preset: str | None = None
) -> dict[str, Any]:
    """Typed keyword arguments from ``KEY=VALUE`` strings, typed like each default;
    ``none`` for a parameter that may be None (``float | None``). With ``preset``, the
    preset's parameters first, those given in ``pairs`` overriding them."""
    cls = _lookup(method)
    if preset is not None:
        return {**preset_params(method, preset), **parse_params(method, pairs)}
    defaults = cls.param_defaults()
    bad = sorted(set(pairs) - set(defaults))
    if bad:
        raise ConfigError(
            f"unknown parameter(s) {bad} for method '{method}'; valid: {', '.join(defaults)}"
        )
    sig = inspect.signature(cls.__init__).parameters
    out: dict[str, Any] = {}
    for k, v in pairs.items():
        # Annotations are strings here (postponed evaluation).
        if v.strip().lower() == "none" and "None" in str(sig[k].annotation):
            out[k] = None
        else:
            out[k] = _coerce(v, defaults[k], k, str(sig[k].annotation))
    return out


def _lookup(method: str) -> type[Mapper]:
    try:
        return MAPPERS[method]
    except KeyError:
        raise ConfigError(
            f"unknown method '{method}'; valid: {', '.join(sorted(MAPPERS))}"
        ) from None


def make_mapper(method: str, **params: Any) -> Mapper:
    """A mapper by registered name, with keyword parameters.

    A float parameter given as a string written as a decimal number (``"1e-2"``, as
    PyYAML reads it from a sweep or experiment file) is that number
    (:func:`sonarmap.checks.numbers_where_floats`).

    Examples
    --------
    >>> make_mapper("inverse", p_occ=0.8).p_occ
    0.8
    """
    cls = _lookup(method)
    bad = sorted(set(params) - set(cls.param_names()))
    if bad:
        raise ConfigError(
            f"unknown parameter(s) {bad} for method '{method}'; valid: "
            f"{', '.join(cls.param_names())}"
        )
    return cls(**numbers_where_floats(params, cls))
