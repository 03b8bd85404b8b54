"""The hit/miss counting model of the lecture slides (methods.md section 1).

Per cell, ``C`` counts the readings whose beam covers it and ``O`` sums their votes,
+1 from Omega_occ and -1 from Omega_free; the occupancy is ``(O + C) / (2 C)``, the
fraction of votes that said "occupied".

Defaults (no-echo readings ignored, a 2.5 cm band moved 0.75 of a cell behind the
echo): the highest mean quality (0.293, against 0.220 unmoved) of its 20 settings of
offset and half-width in ``sonarmap sweep sweeps/band.yaml``, on the training scenes
every method was tuned on; at 10 cm cells the best offset was 7.5 cm, 0.75 of a cell
again.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..readings import Readings
from ._base import Mapper, Progress, register
from ._checks import choice, number
from ._correlated import reading_weights

__all__ = ["CountingMapper"]


@register
class CountingMapper(Mapper):
    """Occupancy as the fraction of "occupied" votes among the readings covering a cell.

    Parameters
    ----------
    no_echo : {"free", "ignore"}
        A reading with no echo votes "free" over its beam up to ``r_max - dr`` or is skipped.
    dr : float or None
        Half-width of the Omega_occ band, metres; None uses the rasteriser default.
    band_offset : float or None
        How far behind the echo the Omega_occ band's centre lies, metres (>= 0); None
        (default): 0.75 of a cell. See :mod:`sonarmap.raster` for why.
    correlated : float
        Down-weighting of correlated readings (Konolige 1997), metres; 0 (default) is off.
        With c > 0 the n readings of one sonar from poses in the same c-metre bin (and
        10-degree heading bin) with ranges in the same c-metre bin each weigh 1 / n (see
        :func:`~sonarmap.mappers._correlated.correlation_weights`), and a cell's occupancy
        is the weighted fraction of "occupied" votes: a burst from one pose casts one vote.
        A weight depends on readings that come later, so :meth:`partial_fit` then keeps the
        readings and recounts all of them (still exactly one fit's map). Off by default: in
        ``sonarmap sweep sweeps/correlated.yaml`` (bins of 2, 5, 10 and 20 cm, the ten
        training scenes) no bin size beat off (quality 0.293; 2 cm 0.292, 5 cm 0.289,
        10 to 20 cm 0.18-0.19).
    """

    name = "counting"
    offset_cells = 0.75
    exact_streaming = True
    # Vote totals; float, so that weighted votes add up in the same arrays (whole
    # counts stay exact up to 2**53).
    _hits: npt.NDArray[np.float64]
    _seen: npt.NDArray[np.float64]

    def __init__(
        self,
        *,
        no_echo: str = "ignore",
        dr: float | None = 0.025,
        band_offset: float | None = None,
        correlated: float = 0.0,
    ) -> None:
        self.no_echo = no_echo
        self.dr = dr
        self.band_offset = band_offset
        self.correlated = correlated
        choice("no_echo", no_echo, ("free", "ignore"))
        if dr is not None:
            number("dr", dr, 0.0, None)
        if band_offset is not None:
            number("band_offset", band_offset, 0.0, None)
        number("correlated", correlated, 0.0, None)

    def _reset(self) -> None:
        self._hits = np.zeros(self.grid.size, dtype=np.float64)
        self._seen = np.zeros(self.grid.size, dtype=np.float64)

    def _add(self, readings: Readings, progress: Progress | None) -> None:
        if self.correlated > 0:
            # A reading's weight depends on the readings that repeat it, later ones
            # too: every reading so far is counted again, so that partial_fit still
            # gives one fit's map.
            readings = self._accumulate(readings)
            self._reset()
        if self.no_echo == "ignore":
            readings = self._echoes(readings)
        weights = None
        if self.correlated > 0:
            # The occupancy is a ratio of weighted votes, so any common scale cancels;
            # mean 1 keeps the totals in units of readings.
            weights = reading_weights(readings, self.correlated, self.sensor.r_max)
        n_cells = self.grid.size
        for a, fp in self._footprints(
            readings, dr=self.dr, offset=self.band_offset_for(self.grid), progress=progress
        ):
            if weights is None:
                self._seen += np.bincount(fp.free.cells, minlength=n_cells)
                occ = np.bincount(fp.occ.cells, minlength=n_cells)
            else:
                w = weights[a : a + fp.free.n_readings]
                wf, wo = np.repeat(w, fp.free.counts), np.repeat(w, fp.occ.counts)
                self._seen += np.bincount(fp.free.cells, weights=wf, minlength=n_cells)
                occ = np.bincount(fp.occ.cells, weights=wo, minlength=n_cells)
            self._seen += occ
            self._hits += occ

    def _occupancy(self) -> npt.NDArray[np.float32]:
        with np.errstate(invalid="ignore", divide="ignore"):
            # (O + C) / 2C with O = hits - misses and C = hits + misses is hits / C.
            p = self._hits / self._seen
        return p.astype(np.float32)
