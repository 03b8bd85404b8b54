"""The rasteriser: which cells each reading touches, with distance and weight.

Every mapper and the simulator take their geometry from here. For a batch of readings
and a grid, :func:`rasterise` returns, per reading, the cells of

- Omega_free: cells of the beam nearer than ``r + offset - dr``, and
- Omega_occ: cells of the beam at distance in ``[r + offset - dr, r + offset + dr]``,

as flat arrays with per-reading offsets (CSR layout). A cell belongs to a region when
its centre does; boundaries are inclusive with a slack of 1e-9 m, and a centre on the
free / occupied boundary is in Omega_occ, so results do not change when the world and
the pose are rotated together. The ``offset`` (0 unless asked for) moves the band
behind the echo: a cell is occupied when its centre is inside an obstacle, so the
first occupied cell behind a surface heard at r has its centre between r and about
r + h, not around r (the mappers' ``band_offset``). With a ``band_growth`` g > 0 each
echo's half-width is its own, ``max(dr, g r)``: a sonar's range error and the patch of
wall an echo may come from both grow with the range. A reading with ``r >= r_max`` (no
echo) has no Omega_occ and its Omega_free reaches ``r_max - dr`` (methods.md, Notation).

The weight is the sensitivity weight ``w0 = min(s / S, 1)`` of methods.md section 2,
``s`` the cell area and ``S`` the smallest detectable obstacle area at the cell centre.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ._raster_kernel import accumulate_kernel, accumulate_parallel, rasterise_kernel
from .errors import ConfigError, InputError
from .grid import Grid
from .sensors import Region, SensorModel

__all__ = [
    "CellSet",
    "Footprint",
    "accumulate",
    "beam_cells",
    "default_dr",
    "falloff_fit",
    "falloff_positive",
    "rasterise",
]


@dataclass(frozen=True, eq=False)
class CellSet:
    """Cells touched by each of N readings, CSR layout.

    Attributes
    ----------
    offsets : ndarray of int64, shape (N + 1,)
        Entries of reading ``i`` are ``offsets[i]:offsets[i + 1]``.
    cells : ndarray of int32
        Row-major flat cell index (``row * cols + col``, row 0 at the top).
    distance : ndarray of float32
        Distance from the sensor to the cell centre, metres.
    weight : ndarray of float32
        Sensitivity weight ``w0`` in (0, 1].
    bearing : ndarray of float32 or None
        Angle of the cell centre off the beam axis, radians (when asked for).
    """

    offsets: npt.NDArray[np.int64]
    cells: npt.NDArray[np.int32]
    distance: npt.NDArray[np.float32]
    weight: npt.NDArray[np.float32]
    bearing: npt.NDArray[np.float32] | None = None

    @property
    def n_readings(self) -> int:
        return len(self.offsets) - 1

    @property
    def counts(self) -> npt.NDArray[np.int64]:
        """Number of cells of each reading."""
        return np.diff(self.offsets)

    def reading_index(self) -> npt.NDArray[np.int64]:
        """For each entry, the reading it belongs to."""
        return np.repeat(np.arange(self.n_readings, dtype=np.int64), self.counts)

    def of(self, i: int) -> npt.NDArray[np.int32]:
        """Cells of reading ``i``."""
        return self.cells[self.offsets[i] : self.offsets[i + 1]]

    def matrix(self, n_cells: int, values: npt.ArrayLike | None = None) -> sp.csr_matrix:
        """A (readings x cells) sparse matrix holding ``values`` (default: the weights)."""
        data = self.weight if values is None else np.asarray(values)
        return sp.csr_matrix((data, self.cells, self.offsets), shape=(self.n_readings, n_cells))


@dataclass(frozen=True, eq=False)
class Footprint:
    """Omega_free and Omega_occ of a batch of readings (see :func:`rasterise`).

    ``dr`` is the band's half-width in metres; with a ``band_growth`` it is the least
    one, that of the nearer echoes.
    """

    free: CellSet
    occ: CellSet
    dr: float

    @property
    def n_entries(self) -> int:
        return len(self.free.cells) + len(self.occ.cells)


def default_dr(grid: Grid, sensor: SensorModel) -> float:
    """Half-width of the Omega_occ band: ``max(h / 2, range resolution)``.

    methods.md's Decision was ``max(h, range resolution)``; h / 2 is the largest error
    of a distance measured to a cell centre, and the range resolution bounds what the
    sensor itself can tell apart. A mapper that expects more range noise widens its band
    with its own ``dr`` parameter: the sensor's specification says nothing of the noise
    in a particular run, and a simulation's true noise is not the mapper's to know.
    """
    return max(grid.resolution / 2, sensor.range_resolution)


def _pack_zones(
    sensor: SensorModel, cell_area: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
    def w0(size: float) -> float:
        return 1.0 if size <= 0.0 else min(cell_area / (size * size), 1.0)

    regions: list[Region] = [z[0] for z in sensor.zones]
    kmax = max([len(r.halfplanes) for r in regions] + [1])
    planes = np.zeros((len(regions), kmax, 3))
    planes[:, :, 2] = 1.0  # 0*x + 0*y <= 1 holds everywhere: padding
    for k, r in enumerate(regions):
        planes[k, : len(r.halfplanes)] = r.halfplanes
    radius = np.array([r.radius for r in regions], dtype=np.float64)
    weights = np.array([w0(z[1]) for z in sensor.zones], dtype=np.float64)
    return planes, radius, weights, w0(sensor.min_size)


def _poses(
    x: npt.ArrayLike, y: npt.ArrayLike, theta: npt.ArrayLike, extra: npt.ArrayLike | None = None
) -> tuple[npt.NDArray[np.float64], ...]:
    arrays = [
        np.ascontiguousarray(a, dtype=np.float64).reshape(-1)
        for a in ((x, y, theta) if extra is None else (x, y, theta, extra))
    ]
    n = len(arrays[0])
    for name, a in zip(("x", "y", "theta", "range"), arrays, strict=False):
        if len(a) != n:
            raise InputError(f"'{name}' has {len(a)} entries, expected {n}", field=name)
        if np.isnan(a).any() or (name != "range" and not np.isfinite(a).all()):
            raise InputError(f"'{name}' holds non-finite values", field=name)
    return tuple(arrays)


def _beams(
    grid: Grid,
    sensor: SensorModel,
    sx: npt.NDArray[np.float64],
    sy: npt.NDArray[np.float64],
    st: npt.NDArray[np.float64],
    free_lim: npt.NDArray[np.float64],
    occ_hi: npt.NDArray[np.float64],
) -> tuple[
    float,
    float,
    float,
    int,
    int,
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    float,
]:
    """The arguments both kernels start their beams with, in their order: the grid
    (resolution, origin x and y, rows, cols), the poses, each reading's free limit and
    band end, and the beam's half-planes and radius."""
    return (
        grid.resolution,
        grid.origin[0],
        grid.origin[1],
        grid.rows,
        grid.cols,
        sx,
        sy,
        st,
        free_lim,
        occ_hi,
        np.ascontiguousarray(sensor.beam.halfplanes),
        float(sensor.beam.radius),
    )


def _run(
    grid: Grid,
    sensor: SensorModel,
    sx: npt.NDArray[np.float64],
    sy: npt.NDArray[np.float64],
    st: npt.NDArray[np.float64],
    free_lim: npt.NDArray[np.float64],
    occ_hi: npt.NDArray[np.float64],
    with_bearing: bool,
) -> tuple[CellSet, CellSet]:
    zp, zr, zw, bw = _pack_zones(sensor, grid.resolution**2)
    # A first guess at the output size saves most re-allocations, but too large a guess
    # is dear as well: 0.6 r^2 per beam was three times the cells of the office ring's
    # 15-degree cones and made the rasteriser twice as slow. A beam's centres within
    # `reach` lie in the sector of its widest angle off the axis, so that sector's area
    # and a cell along its edges bound them (save rounding, which the kernel absorbs).
    h = grid.resolution
    half = _region_half_angle(sensor.beam)
    reach = np.minimum(np.maximum(free_lim, occ_hi), sensor.beam.radius).clip(0.0)
    guess = np.sum(half * reach**2) / h**2 + np.sum((2.0 + 2.0 * half) * reach) / h
    capacity = int(min(guess, 2e8)) + 1024
    out = rasterise_kernel(
        *_beams(grid, sensor, sx, sy, st, free_lim, occ_hi),
        zp,
        zr,
        zw,
        bw,
        with_bearing,
        capacity,
    )
    f = CellSet(out[0], out[1], out[2], out[3], out[4] if with_bearing else None)
    o = CellSet(out[5], out[6], out[7], out[8], out[9] if with_bearing else None)
    return f, o


def rasterise(
    grid: Grid,
    sensor: SensorModel,
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    theta: npt.ArrayLike,
    ranges: npt.ArrayLike,
    *,
    dr: float | None = None,
    offset: float = 0.0,
    with_bearing: bool = False,
    no_echo_reach: float | None = None,
    free_stop: float = 0.0,
    band_growth: float = 0.0,
) -> Footprint:
    """Omega_free and Omega_occ of each reading.

    Parameters
    ----------
    grid : Grid
        The map grid; cells outside it are clipped.
    sensor : SensorModel
        Beam, range limits and sensitivity diagram.
    x, y, theta : array_like, shape (N,)
        World pose of the sensor at each reading (metres, radians).
    ranges : array_like, shape (N,)
        Measured ranges (metres); ``>= sensor.r_max`` means no echo.
    dr : float, optional
        Half-width of the Omega_occ band; default :func:`default_dr`.
    offset : float
        How far behind the range the band's centre lies, metres (>= 0; default 0).
    with_bearing : bool
        Also return each cell's angle off the beam axis.
    no_echo_reach : float, optional
        How far (metres) a no-echo reading's Omega_free reaches, less ``dr``; default
        (None) ``r_max``.
    free_stop : float
        How far short of the band an echo's Omega_free stops, as a fraction of its range,
        in [0, 1) (default 0: at the band's near edge). No-echo readings are not moved.
    band_growth : float
        Growth of an echo's band half-width with its range, metres per metre, in
        [0, 1) (default 0: every band ``dr``). With g > 0 the echo at range r has the
        half-width ``max(dr, g r)``; no-echo readings' free regions still end at
        ``reach - dr``.

    Returns
    -------
    Footprint
        ``free`` and ``occ`` cell sets; disjoint per reading.

    Examples
    --------
    >>> from sonarmap.sensors import Region, SensorModel
    >>> g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(1, 5))
    >>> s = SensorModel("narrow", Region.cone(10.0, 10.0), r_min=0.0, r_max=10.0,
    ...                 range_resolution=0.1)
    >>> fp = rasterise(g, s, [0.0], [0.5], [0.0], [3.5], dr=0.5)
    >>> fp.free.cells.tolist(), fp.occ.cells.tolist()
    ([0, 1, 2], [3])
    """
    sx, sy, st, r = _poses(x, y, theta, ranges)
    d, free_lim, occ_hi = _limits(grid, sensor, r, dr, offset, no_echo_reach, band_growth)
    if free_stop == 0:
        f, o = _run(grid, sensor, sx, sy, st, free_lim, occ_hi, with_bearing)
        return Footprint(free=f, occ=o, dr=d)
    # The kernel's band starts where the free region ends: the free cells and the band
    # are listed by two runs, leaving the cells between them out of both.
    short = _stopped(sensor, r, free_lim, free_stop)
    f, _ = _run(grid, sensor, sx, sy, st, short, np.full_like(occ_hi, -np.inf), with_bearing)
    _, o = _run(grid, sensor, sx, sy, st, free_lim, occ_hi, with_bearing)
    return Footprint(free=f, occ=o, dr=d)


def _limits(
    grid: Grid,
    sensor: SensorModel,
    r: npt.NDArray[np.float64],
    dr: float | None,
    offset: float = 0.0,
    no_echo_reach: float | None = None,
    band_growth: float = 0.0,
) -> tuple[float, npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    if (r < 0).any():
        raise InputError("ranges must be >= 0", field="range")
    d = default_dr(grid, sensor) if dr is None else float(dr)
    if not (np.isfinite(d) and d >= 0):
        raise ConfigError(f"dr must be a non-negative number of metres, got {dr}")
    if not (math.isfinite(offset) and offset >= 0):
        raise ConfigError(f"the band offset must be a non-negative number of metres, got {offset}")
    if no_echo_reach is not None and not (math.isfinite(no_echo_reach) and no_echo_reach > 0):
        raise ConfigError(f"no_echo_reach must be a positive number of metres, got {no_echo_reach}")
    # At g >= 1 the band would reach back to the sensor: no free region, the beam all band.
    if not (math.isfinite(band_growth) and 0.0 <= band_growth < 1.0):
        raise ConfigError(
            f"band_growth must be a number of metres per metre in [0, 1), got {band_growth}"
        )
    echo = r < sensor.r_max
    # A no-echo reading has no band to move: its free region ends at r_max - dr, or
    # at the reach asked for when that is nearer.
    reach = sensor.r_max if no_echo_reach is None else min(no_echo_reach, sensor.r_max)
    # The kernel takes each reading's own limits, so a per-reading band costs nothing
    # there; at g = 0 the arithmetic is the fixed band's, to the bit.
    band = np.maximum(d, band_growth * r) if band_growth > 0 else d
    free_lim = np.where(echo, r + offset - band, reach - d)
    occ_hi = np.where(echo, r + offset + band, -np.inf)
    return d, free_lim, occ_hi


def _stopped(
    sensor: SensorModel, r: npt.NDArray[np.float64], free_lim: npt.NDArray[np.float64], stop: float
) -> npt.NDArray[np.float64]:
    """``free_lim`` of the echoes moved ``stop * r`` towards the sensor."""
    if not (math.isfinite(stop) and 0.0 <= stop < 1.0):
        raise ConfigError(f"free_stop must be a fraction of the range in [0, 1), got {stop}")
    return np.where(r < sensor.r_max, free_lim - stop * r, free_lim)


def accumulate(
    grid: Grid,
    sensor: SensorModel,
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    theta: npt.ArrayLike,
    ranges: npt.ArrayLike,
    values: npt.NDArray[np.float64],
    touched: npt.NDArray[np.bool_],
    *,
    inc_free: float,
    inc_occ: float,
    clamp: tuple[float, float] = (-np.inf, np.inf),
    dr: float | None = None,
    offset: float = 0.0,
    falloff: float = 0.0,
    weights: npt.ArrayLike | None = None,
    no_echo_reach: float | None = None,
    free_stop: float = 0.0,
) -> int:
    """Add to the Omega_free and Omega_occ cells of each reading, in place.

    The cells are those :func:`rasterise` gives, but no footprint is stored: each row of
    a beam is visited in blocks of cells. This is the inverse model's insertion. With
    more than one numba thread (``NUMBA_NUM_THREADS``) the rows are shared out in
    interleaved stripes; every cell still takes the readings in order, so the result is
    the same.

    With a fall-off, a cell at angle b off the beam axis (the bearing
    ``rasterise(..., with_bearing=True)`` gives) takes the increments times
    ``exp(-b**2 / (2 * falloff**2))``. That weight comes from a polynomial in tan(b)**2
    fitted to it over the beam's angles to within 1e-9 (:func:`falloff_fit`), and from
    atan2 and exp where no polynomial fits the beam and fall-off and in the rows within
    10 µm of the sensor. Either is closer to the Gaussian than weights computed from
    the float32 bearings of a footprint (6e-8).

    Parameters
    ----------
    values : ndarray of float64, shape (grid.size,)
        Flat per-cell values, updated in reading order and clamped to ``clamp`` after
        each addition.
    touched : ndarray of bool, shape (grid.size,)
        Set True for every cell a reading touches.
    inc_free, inc_occ : float
        What a reading adds to its free and occupied cells.
    dr, offset : float
        The band, as for :func:`rasterise`.
    falloff : float
        Standard deviation (radians) of the Gaussian fall-off of both increments with
        the angle off the axis; 0 adds them uniformly.
    weights : array_like, shape (N,), optional
        A factor (finite, >= 0) on both increments of each reading, such as the
        mappers' correlation weights; None (default) adds them as given, at no cost.
    no_echo_reach : float, optional
        How far (metres) a no-echo reading's free cells reach, as for :func:`rasterise`.
    free_stop : float
        How far short of the band an echo's free cells stop, as for :func:`rasterise`;
        the cells between take nothing and are not marked touched. With a stop each
        reading takes two kernel calls of its own (slower).

    Returns
    -------
    int
        Cell updates made.
    """
    sx, sy, st, r = _poses(x, y, theta, ranges)
    _, free_lim, occ_hi = _limits(grid, sensor, r, dr, offset, no_echo_reach)
    if values.shape != (grid.size,) or touched.shape != (grid.size,):
        raise ConfigError(f"values and touched must have shape ({grid.size},)")
    if not (values.flags.c_contiguous and touched.flags.c_contiguous):
        raise ConfigError("values and touched must be contiguous arrays")
    if not (math.isfinite(falloff) and falloff >= 0):
        raise ConfigError(f"falloff must be a non-negative angle in radians, got {falloff}")
    args = (
        values,
        touched,
        *_beams(grid, sensor, sx, sy, st, free_lim, occ_hi),
        inc_free,
        inc_occ,
        clamp[0],
        clamp[1],
        *_falloff_args(sensor, falloff),
    )
    threads = nb.get_num_threads()
    positive = falloff_positive(sensor, falloff)
    w = None
    if weights is not None:
        w = np.ascontiguousarray(weights, dtype=np.float64).reshape(-1)
        if len(w) != len(sx) or not (np.isfinite(w).all() and (w >= 0).all()):
            raise ConfigError(f"weights must be {len(sx)} finite numbers >= 0, one per reading")
    if free_stop != 0:
        short = _stopped(sensor, r, free_lim, free_stop)

        def bands(a: int, b: int) -> CellSet:
            # Readings a..b's bands, listed as rasterise lists them (its band run also
            # walks the free cells: a few readings at a time keeps that small).
            sl = slice(a, b)
            return _run(grid, sensor, sx[sl], sy[sl], st[sl], free_lim[sl], occ_hi[sl], False)[1]

        return _accumulate_stopped(args, short, bands, w, positive)
    if w is not None:
        if threads > 1 and len(sx) >= 64:
            return int(accumulate_parallel(*args, threads, w, positive))
        return int(accumulate_kernel(*args, weight=w, positive=positive))
    # Unweighted, the kernels compile without the weight branch: the insertion keeps
    # the speed ``make bench-mrpt`` measures.
    if threads > 1 and len(sx) >= 64:
        return int(accumulate_parallel(*args, threads, None, positive))
    return int(accumulate_kernel(*args, positive=positive))


# Readings whose bands _accumulate_stopped lists at a time.
_STOP_BLOCK = 256


def _accumulate_stopped(
    args: tuple[Any, ...],
    short: npt.NDArray[np.float64],
    bands: Callable[[int, int], CellSet],
    w: npt.NDArray[np.float64] | None,
    positive: bool,
) -> int:
    """:func:`accumulate` with the free cells ending at ``short``: reading by reading,
    its free cells (no band) and then its band (free increment 0), so that each
    cell takes the readings in order and is clamped after each, as in one run. The
    cells between the two are left as they were, untouched if no reading touched them,
    as :func:`rasterise` leaves them out of both sets: only the cells ``bands(a, b)``
    lists for readings a..b are marked touched with the band.

    One kernel call per reading and part: only for the ``free_stop`` option, never on
    the default path ``make bench-mrpt`` times.
    """
    head, tail = args[:10], args[12:]
    free_lim, occ_hi = args[10], args[11]
    inc_free, inc_occ = tail[2], tail[3]
    touched = head[1]
    # The band's kernel call also visits the cells nearer than the band (adding 0,
    # which leaves their values as they are); its marks go to a spare array, and only
    # the band's cells are marked in ``touched``.
    spare = np.zeros_like(touched)
    none = np.full(1, -np.inf)
    n = 0
    for start in range(0, len(short), _STOP_BLOCK):
        stop = min(start + _STOP_BLOCK, len(short))
        band = bands(start, stop)
        for i in range(start, stop):
            one = tuple(a[i : i + 1] for a in head[7:10])
            kw: dict[str, Any] = {"positive": positive}
            if w is not None:
                kw["weight"] = w[i : i + 1]
            n += int(
                accumulate_kernel(  # type: ignore[call-arg]
                    *head[:7],
                    *one,
                    short[i : i + 1],
                    none,
                    *tail[:2],
                    inc_free,
                    0.0,
                    *tail[4:],
                    **kw,
                )
            )
            accumulate_kernel(  # type: ignore[call-arg]
                head[0],
                spare,
                *head[2:7],
                *one,
                free_lim[i : i + 1],
                occ_hi[i : i + 1],
                *tail[:2],
                0.0,
                inc_occ,
                *tail[4:],
                **kw,
            )
            cells = band.of(i - start)
            touched[cells] = True
            n += len(cells)
    return n


# Numbers of coefficients the fall-off fit tries, fewest first; the insertion kernel is
# compiled once for each (numba specialises on the tuple's length).
FIT_SIZES = (7, 13, 21)
FIT_TOL = 1e-9
# Beams reaching this far off their axis (radians) are weighted cell by cell: tan^2
# grows without bound towards 90 degrees.
FIT_MAX_ANGLE = math.radians(80.0)
# The fit's domain reaches this much (radians) past the beam's widest angle. A centre
# the kernel counts in the beam lies within EDGE_TOL of it; in a row at least ROW_TOL
# from the sensor that is at most EDGE_TOL / ROW_TOL = 1e-4 rad outside its angles.
FIT_MARGIN = 0.01
# The least Gaussian weight over the fit's angles for which falloff_positive vouches
# for the polynomial's sign: a thousand times FIT_TOL, which leaves room for the fit's
# error between the points it is checked at.
POSITIVE_FLOOR = 1e3 * FIT_TOL


def beam_half_angle(sensor: SensorModel) -> float:
    """The widest angle off the axis (radians) of a point of the sensor's beam; pi when
    the beam surrounds the sensor.

    Examples
    --------
    >>> from sonarmap.sensors import get_sensor
    >>> round(math.degrees(beam_half_angle(get_sensor("hc-sr04"))), 6)
    15.0
    """
    return _beam_half_angle(sensor)


def _beam_half_angle(sensor: SensorModel) -> float:
    """The widest angle off the axis (radians) of a point of the beam; pi when the beam
    surrounds the sensor.

    The beam is convex: seen from a sensor outside it or on its edge, its extreme
    directions pass through a corner, where two edges meet or an edge meets the disk.
    """
    return _region_half_angle(sensor.beam)


@functools.lru_cache(maxsize=64)
def _region_half_angle(beam: Region) -> float:
    # Cached: the rasteriser sizes its output with it on every call.
    planes = np.asarray(beam.halfplanes, dtype=np.float64)
    radius = float(beam.radius)
    normals, offsets = planes[:, :2], planes[:, 2]
    if np.all(offsets > 1e-12):
        return math.pi
    corners = []
    for i, (a, b) in enumerate(normals):
        norm = math.hypot(a, b)
        dist = offsets[i] / norm
        if abs(dist) <= radius:
            foot = np.array([a, b]) / norm * dist
            along = np.array([-b, a]) / norm * math.sqrt(radius**2 - dist**2)
            corners += [foot + along, foot - along]
        for j in range(i + 1, len(planes)):
            det = a * normals[j, 1] - b * normals[j, 0]
            if abs(det) > 1e-12:
                corners.append(np.linalg.solve(normals[[i, j]], offsets[[i, j]]))
    if not corners:
        return math.pi
    pts = np.array(corners)
    norms = np.hypot(pts[:, 0], pts[:, 1])
    inside = np.all(pts @ normals.T <= offsets + 1e-9, axis=1) & (norms <= radius + 1e-9)
    pts = pts[inside & (norms > 1e-12)]
    return float(np.abs(np.arctan2(pts[:, 1], pts[:, 0])).max()) if len(pts) else math.pi


@functools.lru_cache(maxsize=64)
def _fit(half_angle: float, sigma: float) -> tuple[float, tuple[float, ...]]:
    angle = half_angle + FIT_MARGIN
    if angle >= FIT_MAX_ANGLE:
        return 0.0, ()
    u_max = math.tan(angle) ** 2

    def weight(u: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.asarray(np.exp(-0.5 * (np.arctan(np.sqrt(u)) / sigma) ** 2))

    # Checked on a fine grid, with Horner's scheme as the kernel evaluates it.
    u = np.linspace(0.0, u_max, 20_001)
    for size in FIT_SIZES:
        k = np.arange(size)
        nodes = 0.5 * u_max * (1.0 - np.cos(np.pi * (k + 0.5) / size))
        coef = np.linalg.solve(np.vander(nodes, size, increasing=True), weight(nodes))
        if np.abs(np.polynomial.polynomial.polyval(u, coef) - weight(u)).max() <= FIT_TOL:
            return u_max, tuple(float(c) for c in coef)
    return 0.0, ()


def falloff_fit(sensor: SensorModel, falloff: float) -> tuple[float, tuple[float, ...]]:
    """The polynomial the insertion kernel weighs cells with (see :func:`accumulate`).

    Returns ``(u_max, coef)``: coefficients (lowest first) of a polynomial in
    u = tan(b)**2, b a cell's angle off the beam axis, within :data:`FIT_TOL` of
    ``exp(-b**2 / (2 * falloff**2))`` for ``0 <= u <= u_max``; ``u_max`` covers the
    beam's widest angle. ``coef`` is empty when no polynomial of :data:`FIT_SIZES`
    terms is that close over the beam, or the beam is too wide: the kernel then
    weighs each cell exactly.

    Examples
    --------
    >>> from sonarmap.sensors import get_sensor
    >>> u_max, coef = falloff_fit(get_sensor("polaroid-6500"), math.radians(20))
    >>> round(math.degrees(math.atan(math.sqrt(u_max))), 2), len(coef)
    (15.57, 7)
    """
    if falloff <= 0:
        return 0.0, ()
    return _fit(_beam_half_angle(sensor), float(falloff))


def falloff_positive(sensor: SensorModel, falloff: float) -> bool:
    """Whether the fall-off polynomial (:func:`falloff_fit`) is positive over the beam's
    angles: the Gaussian it fits stays above :data:`POSITIVE_FLOOR` there. False without
    a polynomial.

    The insertion kernel relies on it to leave a cell held at a clamp bound by its
    increment without computing its weight (any weight >= 0 gives the same value).

    Examples
    --------
    >>> from sonarmap.sensors import get_sensor
    >>> s = get_sensor("polaroid-6500")
    >>> falloff_positive(s, math.radians(5)), falloff_positive(s, math.radians(2))
    (True, False)
    """
    u_max, coef = falloff_fit(sensor, falloff)
    if not coef:
        return False
    widest = math.atan(math.sqrt(u_max))
    return math.exp(-0.5 * (widest / falloff) ** 2) > POSITIVE_FLOOR


def _falloff_args(sensor: SensorModel, falloff: float) -> tuple[float, tuple[float, ...]]:
    return float(falloff), falloff_fit(sensor, falloff)[1]


def beam_cells(
    grid: Grid,
    sensor: SensorModel,
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    theta: npt.ArrayLike,
    *,
    max_range: float | npt.ArrayLike | None = None,
    with_bearing: bool = False,
) -> CellSet:
    """Every cell of the beam within ``max_range`` (default ``r_max``; one value, or one
    per pose) of each pose.

    Examples
    --------
    >>> from sonarmap.sensors import Region, SensorModel
    >>> g = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(1, 5))
    >>> s = SensorModel("narrow", Region.cone(10.0, 10.0), r_min=0.0, r_max=2.6,
    ...                 range_resolution=0.1)
    >>> beam_cells(g, s, [0.0], [0.5], [0.0]).cells.tolist()
    [0, 1, 2]
    """
    sx, sy, st = _poses(x, y, theta)
    n = len(sx)
    lim = np.broadcast_to(
        np.asarray(sensor.r_max if max_range is None else max_range, dtype=np.float64), (n,)
    )
    _, o = _run(grid, sensor, sx, sy, st, np.full(n, -1.0), np.ascontiguousarray(lim), with_bearing)
    return o
