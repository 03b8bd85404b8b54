"""The traditional inverse-model occupancy grid (Moravec & Elfes; methods.md section 1).

Each cell keeps log-odds ``l``; every reading adds ``logit(p_free)`` to the cells of its
Omega_free and ``logit(p_occ)`` to those of its Omega_occ, optionally scaled by a
Gaussian fall-off with the angle off the beam axis, and clamps ``l`` to
``[logit(clamp_min), logit(clamp_max)]`` after each reading -- the update rule of
OctoMap, with its clamping bounds [0.12, 0.97].

The increments are not OctoMap's laser values (0.7 / 0.4): with a wide beam, the
occupied arc of one reading covers many free cells, and strong occupied increments
paint the space in front of walls. A sonar's no-echo readings are mostly beams a smooth
wall mirrored away, not free space. The defaults (p_occ 0.52, p_free 0.46, a 5-degree
Gaussian fall-off off the axis, no-echo readings ignored, a band 5 cm either side of a
point 0.75 of a cell behind the echo) had the highest quality (the geometric mean of
wall F1, passage F1 and observed-wall recall; :func:`sonarmap.metrics.quality`) on the
training scenes of issue 39 (``sweeps/rigs.yaml``; docs/results/2026-12-06-rig-defaults.md).

An option, off by default, weighs each free increment by how well a surface at the cell
would face the beam (``specular_deg``, Konolige 1997); when it helps and what it costs
is in docs/results/2026-12-07-inverse-specular.md.
"""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..grid import Grid
from ..raster import CellSet, Footprint, accumulate, beam_half_angle
from ..readings import Readings
from ..selection import Strategy
from ..sensors import SensorModel
from ._base import Mapper, Progress, register
from ._checks import choice, number
from ._correlated import reading_weights
from ._incidence import shield
from ._stream import StreamEngine

__all__ = ["PRESETS", "TRADITIONAL", "InverseMapper"]

#: Laser-style log-odds (OctoMap's increments, no fall-off, no-echo beams cleared) on the
#: 5 cm band centred on the echo that the tuned inverse had before the band offset: the
#: kind of baseline the research compared against (``--preset traditional``).
TRADITIONAL: dict[str, Any] = {
    "p_occ": 0.7,
    "p_free": 0.4,
    "falloff_deg": 0.0,
    "no_echo": "free",
    "dr": 0.05,
    "band_offset": 0.0,
}

#: Named parameter sets (``--preset NAME``).
PRESETS: dict[str, dict[str, Any]] = {"traditional": TRADITIONAL}


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@register
class InverseMapper(Mapper):
    """Log-odds occupancy grid with an inverse sonar model.

    Parameters
    ----------
    p_occ : float
        Inverse-model probability for a cell of Omega_occ, in (0.5, 1).
    p_free : float
        Inverse-model probability for a cell of Omega_free, in (0, 0.5).
    clamp_min, clamp_max : float
        Occupancy clamping bounds, ``0 < clamp_min < 0.5 < clamp_max < 1``.
    falloff_deg : float
        Standard deviation (degrees) of a Gaussian fall-off of both increments with the angle
        off the beam axis (5); 0 applies them uniformly over the beam. With
        ``falloff_free_deg`` set, of the occupied increment alone.
    falloff_free_deg : float or None
        Standard deviation (degrees, >= 0) of a Gaussian fall-off of the free increment
        alone; 0 applies it uniformly over the beam; None (default): ``falloff_deg``, one
        fall-off for both. A wide beam hears a surface off its axis less well than on
        it, so that an echo's range says most surely "nothing nearer" near the axis,
        while where on its arc the echo came from is not known: a narrower free
        fall-off confines the free evidence to where the no-wall claim is surest. With
        a value other than ``falloff_deg`` each chunk of readings (``chunk_size``,
        50,000 readings) is rasterised with its bearings and inserted from that
        footprint: slower than the insertion kernel, which weighs both increments with
        one fall-off, and it holds, per chunk, the footprint (each entry's cell,
        distance, sensitivity and bearing) and two float64 arrays of weights (one
        weight per free entry, one per occupied entry), which the kernel does not. Off
        by default: a narrower free fall-off keeps the walls a wide beam meets at a
        slant but leaves more cells in front of the walls occupied and closes doorways
        (docs/results/2026-12-07-inverse-free-falloff.md). Streams with the ``all``
        strategy only, unless unset or 0 (a bounded window also needs
        ``falloff_deg=0``).
    no_echo : {"free", "ignore"}
        A reading with no echo clears its beam up to ``no_echo_reach - dr`` (``free``) or
        is skipped (``ignore``).
    no_echo_reach : float or None
        How far a no-echo reading clears its beam with ``no_echo="free"``, metres (> 0);
        None (default): ``r_max``. A no-echo reading is mostly a beam a slanted wall
        mirrored away, and the farther the wall the likelier that: a short reach clears
        the doorways a passing robot looks through without the walls far down its beam.
    dr : float or None
        Half-width of the Omega_occ band, metres (0.05); None uses the rasteriser's
        default ``max(resolution / 2, range resolution)`` (:func:`sonarmap.raster.default_dr`).
    band_offset : float or None
        How far behind the echo the Omega_occ band's centre lies, metres (>= 0); None
        (default): 0.75 of a cell. See :mod:`sonarmap.raster` for why.
    correlated : float
        Down-weighting of correlated readings (Konolige 1997), metres; 0 (default) is off.
        With c > 0 the n readings of one sonar from poses in the same c-metre bin (and
        10-degree heading bin) with ranges in the same c-metre bin each weigh 1 / n (see
        :func:`~sonarmap.mappers._correlated.correlation_weights`), scaled to mean 1 over
        the readings used, and each reading's log-odds update is its weight times
        ``logit(p_free)`` or ``logit(p_occ)``. A weight depends on readings that come later,
        so :meth:`partial_fit` then keeps the readings and rebuilds the map from all of them
        (still exactly one fit's map), and streaming refuses it. Off by default: in
        ``sonarmap sweep sweeps/correlated.yaml`` (bins of 2, 5, 10 and 20 cm, the ten
        training scenes) 2 cm tied with off (quality 0.309 both), 5 cm scored 0.289 and
        10-20 cm 0.18-0.21.
    specular_deg : float
        Angular width of a smooth surface's echo, degrees, in [0, 90); 0 (default) is off.
        With a width, each free increment is scaled by how well a surface at the
        cell would face the beam (Konolige 1997): surface normals are estimated from
        all the echoes' bands, and a cell that only echoes and slanted beams have met
        takes little free evidence from a beam crossing it at a slant, while one that
        beams have crossed head-on (a doorway) keeps most of it (see
        :func:`~sonarmap.mappers._incidence.free_factors`). Occupied increments are
        unchanged. The normals depend on every reading, so :meth:`partial_fit` then
        keeps the readings and rebuilds the map from all of them (still exactly one
        fit's map), and holds every reading's cells while it inserts them; streaming
        refuses it. Off by default: it keeps
        walls met at a slant but closes doorways, and holds the whole log in memory;
        turn it on for wide-beam rigs where walls matter more than doors and the log
        fits in memory (docs/results/2026-12-07-inverse-specular.md).
    free_stop : float or "beam"
        How far short of the band an echo's Omega_free stops, as a fraction of the
        echo's range, in [0, 1); 0 (default): at the band's near edge. ``"beam"``:
        ``1 - cos(a)``, a the beam's widest angle off the axis -- the echo's place on
        its arc is not known, and a surface facing the sonar through any point of the
        arc reaches no nearer than ``r cos(a)`` along the beam; refused for a beam that
        reaches 90 degrees or more. The cells between the free region and the band take
        nothing: unknown unless another reading touches them. Off by default: it keeps the walls
        a wide beam meets at a slant but leaves the band's spill in front of the walls
        occupied, which narrows and closes doorways, and it inserts each reading with
        two kernel calls (docs/results/2026-12-07-inverse-walls.md). Streams with the
        ``all`` strategy only.
    """

    name = "inverse"
    presets = PRESETS
    demo_presets = ("traditional",)
    offset_cells = 0.75
    exact_streaming = True
    _logodds: npt.NDArray[np.float64]
    _touched: npt.NDArray[np.bool_]

    def __init__(
        self,
        *,
        p_occ: float = 0.52,
        p_free: float = 0.46,
        clamp_min: float = 0.12,
        clamp_max: float = 0.97,
        falloff_deg: float = 5.0,
        falloff_free_deg: float | None = None,
        no_echo: str = "ignore",
        no_echo_reach: float | None = None,
        dr: float | None = 0.05,
        band_offset: float | None = None,
        correlated: float = 0.0,
        specular_deg: float = 0.0,
        free_stop: float | str = 0.0,
    ) -> None:
        self.p_occ = p_occ
        self.p_free = p_free
        self.clamp_min = clamp_min
        self.clamp_max = clamp_max
        self.falloff_deg = falloff_deg
        self.falloff_free_deg = falloff_free_deg
        self.no_echo = no_echo
        self.no_echo_reach = no_echo_reach
        self.dr = dr
        self.band_offset = band_offset
        self.correlated = correlated
        self.specular_deg = specular_deg
        self.free_stop = free_stop
        number("p_occ", p_occ, 0.5, 1.0, lo_open=True, hi_open=True)
        number("p_free", p_free, 0.0, 0.5, lo_open=True, hi_open=True)
        number("clamp_min", clamp_min, 0.0, 0.5, lo_open=True, hi_open=True)
        number("clamp_max", clamp_max, 0.5, 1.0, lo_open=True, hi_open=True)
        number("falloff_deg", falloff_deg, 0.0, None)
        if falloff_free_deg is not None:
            number("falloff_free_deg", falloff_free_deg, 0.0, None)
        choice("no_echo", no_echo, ("free", "ignore"))
        if no_echo_reach is not None:
            number("no_echo_reach", no_echo_reach, 0.0, None, lo_open=True)
            if no_echo != "free":
                raise ConfigError(
                    "no_echo_reach shortens the beams of readings with no echo: it needs "
                    f"no_echo='free', got no_echo={no_echo!r}"
                )
        if dr is not None:
            number("dr", dr, 0.0, None)
        if band_offset is not None:
            number("band_offset", band_offset, 0.0, None)
        number("correlated", correlated, 0.0, None)
        number("specular_deg", specular_deg, 0.0, 90.0, hi_open=True)
        if isinstance(free_stop, str):
            choice("free_stop", free_stop, ("beam",))
        else:
            number("free_stop", free_stop, 0.0, 1.0, hi_open=True)

    def free_stop_for(self, sensor: SensorModel) -> float:
        """The fraction of an echo's range its Omega_free stops short of the band, for
        ``sensor`` (``free_stop``, with ``"beam"`` resolved).

        Raises
        ------
        ConfigError
            ``"beam"`` for a sensor whose beam reaches 90 degrees or more off its axis
            (it would stop the free region at the sonar).
        """
        if isinstance(self.free_stop, str):
            a = beam_half_angle(sensor)
            if a >= math.pi / 2:
                raise ConfigError(
                    f"free_stop='beam' needs a beam narrower than 90 degrees off its axis; "
                    f"sensor '{sensor.name}' reaches {math.degrees(a):.0f}: give a number"
                )
            return 1.0 - math.cos(a)
        return float(self.free_stop)

    @property
    def free_falloff_deg(self) -> float:
        """The free increment's fall-off in effect, degrees: ``falloff_free_deg`` when
        set, else ``falloff_deg``."""
        return self.falloff_deg if self.falloff_free_deg is None else self.falloff_free_deg

    def _reset(self) -> None:
        self._logodds = np.zeros(self.grid.size, dtype=np.float64)
        self._touched = np.zeros(self.grid.size, dtype=np.bool_)

    def _add(self, readings: Readings, progress: Progress | None) -> None:
        rebuild = self.correlated > 0 or self.specular_deg > 0
        if rebuild:
            # A reading's weight depends on the readings that repeat it, and a free
            # increment's on the normals of all the echoes, later ones too: the map is
            # rebuilt from every reading so far, so that partial_fit still gives one
            # fit's map. (partial_fit forgets the batch again if this refuses it.)
            readings = self._accumulate(readings)
        if self.no_echo == "ignore":
            # Dropped before inserting: a no-echo beam is the longest there is.
            readings = self._echoes(readings)
        weights = None
        if self.correlated > 0:
            # Mean 1: the map takes as much evidence in all as without the weighting,
            # so p_occ, p_free and the clamping bounds, tuned per reading, keep their
            # meaning; a burst from one pose gives what one reading gives.
            weights = reading_weights(readings, self.correlated, self.sensor.r_max)
        l_free, l_occ = _logit(self.p_free), _logit(self.p_occ)
        lo, hi = _logit(self.clamp_min), _logit(self.clamp_max)
        if self.specular_deg > 0:
            # Built (and their size checked) before the map is cleared: a refused
            # batch leaves the map as it was.
            fps = self.kept_footprints(
                readings,
                dr=self.dr,
                offset=self.band_offset_for(self.grid),
                with_bearing=self.falloff_deg > 0 or self.free_falloff_deg > 0,
                no_echo_reach=self.no_echo_reach,
                free_stop=self.free_stop_for(self.sensor),
                advice="turn the incidence weighting off (specular_deg=0), map fewer "
                "readings at once, or use coarser cells",
            )
            self._reset()
            self._insert_slanted(readings, fps, weights, (l_free, l_occ), (lo, hi), progress)
            return
        if rebuild:
            self._reset()
        if self.free_falloff_deg != self.falloff_deg:
            self._insert_split(readings, weights, (l_free, l_occ), (lo, hi), progress)
            return
        # Nothing is stored per reading, fall-off or not: the insertion kernel weighs
        # each cell by its angle off the axis as it visits it.
        for a, r in self._chunks(readings, progress):
            accumulate(
                self.grid,
                self.sensor,
                r.x,
                r.y,
                r.theta,
                r.range,
                self._logodds,
                self._touched,
                inc_free=l_free,
                inc_occ=l_occ,
                clamp=(lo, hi),
                dr=self.dr,
                offset=self.band_offset_for(self.grid),
                falloff=math.radians(self.falloff_deg),
                weights=None if weights is None else weights[a : a + len(r)],
                no_echo_reach=self.no_echo_reach,
                free_stop=self.free_stop_for(self.sensor),
            )

    def _insert_split(
        self,
        readings: Readings,
        weights: npt.NDArray[np.float64] | None,
        inc: tuple[float, float],
        clamp: tuple[float, float],
        progress: Progress | None,
    ) -> None:
        """Insert ``readings`` with the free and occupied increments under their own
        fall-offs (``falloff_free_deg``): chunk by chunk from footprints with bearings,
        reading by reading and clamping after each, as
        :func:`~sonarmap.raster.accumulate` does; no footprint outlives its chunk."""
        sig_free, sig_occ = math.radians(self.free_falloff_deg), math.radians(self.falloff_deg)
        for a, fp in self._footprints(
            readings,
            dr=self.dr,
            offset=self.band_offset_for(self.grid),
            progress=progress,
            with_bearing=True,
            no_echo_reach=self.no_echo_reach,
            free_stop=self.free_stop_for(self.sensor),
        ):
            b = a + fp.free.n_readings
            w = None if weights is None else weights[a:b]
            _insert(
                fp.free.offsets,
                fp.free.cells,
                inc[0] * self._entry_weights(fp.free, sig_free, w),
                fp.occ.offsets,
                fp.occ.cells,
                inc[1] * self._entry_weights(fp.occ, sig_occ, w),
                self._logodds,
                self._touched,
                *clamp,
            )

    def _insert_slanted(
        self,
        readings: Readings,
        fps: list[Footprint],
        weights: npt.NDArray[np.float64] | None,
        inc: tuple[float, float],
        clamp: tuple[float, float],
        progress: Progress | None,
    ) -> None:
        """Insert ``readings`` (footprints ``fps``) with each free increment scaled by
        its cell's incidence factor (``specular_deg``).

        Two passes over the footprints: the first keeps only grid-sized sums (the
        echoes' normals and how much each cell is shielded), the second recomputes the
        factors batch by batch and adds the increments reading by reading, clamping
        after each, as :func:`~sonarmap.raster.accumulate` does.
        """
        x, y = readings.x, readings.y
        sh = shield(self.grid, fps, x, y, math.radians(self.specular_deg))
        sigma, sig_free = math.radians(self.falloff_deg), math.radians(self.free_falloff_deg)
        a = 0
        for fp in fps:
            b = a + fp.free.n_readings
            w = None if weights is None else weights[a:b]
            inc_free = inc[0] * sh.factors(fp.free, x[a:b], y[a:b])
            inc_free *= self._entry_weights(fp.free, sig_free, w)
            inc_occ = inc[1] * self._entry_weights(fp.occ, sigma, w)
            _insert(
                fp.free.offsets,
                fp.free.cells,
                inc_free,
                fp.occ.offsets,
                fp.occ.cells,
                inc_occ,
                self._logodds,
                self._touched,
                *clamp,
            )
            del inc_free, inc_occ
            a = b
            if progress is not None:
                progress(b, len(readings))

    @staticmethod
    def _entry_weights(
        cs: CellSet, sigma: float, weights: npt.NDArray[np.float64] | None
    ) -> npt.NDArray[np.float64]:
        """Per entry of ``cs``, the fall-off at its bearing times its reading's weight."""
        out = np.ones(len(cs.cells))
        if sigma > 0:
            assert cs.bearing is not None
            b = cs.bearing.astype(np.float64)
            out = np.exp(-(b * b) / (2.0 * sigma * sigma))
        if weights is not None:
            out = out * weights[cs.reading_index()]
        return out

    @property
    def log_odds_(self) -> npt.NDArray[np.float64]:
        """Each cell's log-odds of occupancy, flat over the grid (0 where untouched).

        The mapper's own array, read-only by contract; set once :meth:`start` has run.
        """
        return self._logodds

    @property
    def touched_(self) -> npt.NDArray[np.bool_]:
        """Whether any reading touched each cell, flat over the grid.

        The mapper's own array, read-only by contract; set once :meth:`start` has run.
        """
        return self._touched

    def _occupancy(self) -> npt.NDArray[np.float32]:
        p = 1.0 / (1.0 + np.exp(-self._logodds))
        p[~self._touched] = np.nan
        return np.asarray(p, dtype=np.float32)


@nb.njit(cache=True)
def _insert(
    f_off: npt.NDArray[np.int64],
    f_cell: npt.NDArray[np.int32],
    f_inc: npt.NDArray[np.float64],
    o_off: npt.NDArray[np.int64],
    o_cell: npt.NDArray[np.int32],
    o_inc: npt.NDArray[np.float64],
    values: npt.NDArray[np.float64],
    touched: npt.NDArray[np.bool_],
    lo: float,
    hi: float,
) -> None:
    # Reading by reading, clamping each cell after its addition: a reading's free and
    # occupied cells are disjoint, so this is the insertion kernel's order.
    for i in range(len(f_off) - 1):
        for j in range(f_off[i], f_off[i + 1]):
            c = f_cell[j]
            values[c] = min(max(values[c] + f_inc[j], lo), hi)
            touched[c] = True
        for j in range(o_off[i], o_off[i + 1]):
            c = o_cell[j]
            values[c] = min(max(values[c] + o_inc[j], lo), hi)
            touched[c] = True


@nb.njit(cache=True)
def _sum_increments(
    slots: npt.NDArray[np.int64],
    sign: float,
    f_start: npt.NDArray[np.int64],
    f_len: npt.NDArray[np.int64],
    o_start: npt.NDArray[np.int64],
    o_len: npt.NDArray[np.int64],
    cell: npt.NDArray[np.int32],
    total: npt.NDArray[np.float64],
    l_free: float,
    l_occ: float,
) -> None:
    for s in slots:
        for j in range(f_start[s], f_start[s] + f_len[s]):
            total[cell[j]] += sign * l_free
        for j in range(o_start[s], o_start[s] + o_len[s]):
            total[cell[j]] += sign * l_occ


class InverseStream(StreamEngine):
    """The inverse model, streamed.

    With the ``all`` strategy every reading is folded in as it comes, exactly as
    :meth:`InverseMapper.partial_fit` does, and no reading is kept. With a bounded
    strategy a cell's log-odds are the sum of the increments of the readings in play
    that touch it -- added as readings enter, subtracted as they leave -- clamped when
    read; a cell that no reading in play touches keeps its last value. That forgets old
    evidence, which lets the map follow a changing scene. The fall-off options need
    the ``all`` strategy: a bounded window needs ``falloff_deg=0`` and
    ``falloff_free_deg`` unset (or 0). The incidence weighting (``specular_deg``) is
    refused: it needs every echo's band before the first free increment.
    """

    keeps_readings = False

    def __init__(
        self,
        mapper: Mapper,
        grid: Grid,
        sensor: SensorModel,
        strategy: Strategy,
        effort: int,
        *,
        fold: bool | None = None,
    ) -> None:
        assert isinstance(mapper, InverseMapper)
        if strategy.bounded and mapper.falloff_deg > 0:
            raise ConfigError(
                "inverse fall-off streams only with the 'all' strategy; for a bounded "
                "window set falloff_deg=0"
            )
        if strategy.bounded and mapper.free_falloff_deg > 0:
            raise ConfigError(
                "inverse falloff_free_deg streams only with the 'all' strategy; for a "
                "bounded window leave it unset"
            )
        if strategy.bounded and mapper.free_stop_for(sensor) > 0:
            raise ConfigError(
                "inverse free_stop streams only with the 'all' strategy; for a bounded "
                "window set free_stop=0"
            )
        if strategy.bounded and mapper.no_echo == "free" and mapper.no_echo_reach is not None:
            raise ConfigError(
                "inverse no_echo_reach streams only with the 'all' strategy; for a "
                "bounded window leave it unset"
            )
        super().__init__(mapper, grid, sensor, strategy, effort, fold=fold)
        self._exact = mapper if not strategy.bounded else None
        if self._exact is not None:
            self._exact.start(grid, sensor)
        self._sum = np.zeros(grid.size)
        self._shown = np.zeros(grid.size)
        lo, hi = _logit(mapper.clamp_min), _logit(mapper.clamp_max)
        self._range = (lo, hi)
        self._inc = (_logit(mapper.p_free), _logit(mapper.p_occ))

    def add(self, readings: Readings) -> None:
        if self._exact is None:
            super().add(readings)
            return
        self._exact.partial_fit(readings)
        self.n_updates += 1

    def _increments(self, slots: npt.NDArray[np.int64], sign: float) -> None:
        p = self.pool
        _sum_increments(
            slots, sign, p.f_start, p.f_len, p.o_start, p.o_len, p.cell, self._sum, *self._inc
        )

    def _enter(self, new: npt.NDArray[np.int64]) -> None:
        self._increments(new, 1.0)

    def _leave(self, gone: npt.NDArray[np.int64]) -> None:
        self._increments(gone, -1.0)

    def _optimise(self, dirty: npt.NDArray[np.int64], box: tuple[int, int, int, int]) -> None:
        live = dirty[self.cov[dirty] > 0]
        self._shown[live] = np.clip(self._sum[live], *self._range)

    def occupancy(self) -> npt.NDArray[np.float32]:
        if self._exact is not None:
            return self._exact.occupancy_.reshape(-1)
        p = 1.0 / (1.0 + np.exp(-self._shown))
        p[~self.seen] = np.nan
        return np.asarray(p, dtype=np.float32)

    def nbytes(self) -> int:
        return super().nbytes() + self._sum.nbytes * 2


InverseMapper.streamer = InverseStream
