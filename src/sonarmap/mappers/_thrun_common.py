"""Parameter handling shared by the two mappers of Thrun's model."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..readings import Readings
from ._base import Mapper
from ._thrun import BeamIndex, build_index


def model_sigma(mapper: Mapper, sigma: float | None) -> float:
    """The model's range noise: given, or half a cell or the sensor's range resolution,
    whichever is larger (a Gaussian narrower than a cell cannot be told apart on the
    grid). Never the noise a simulation used: that is not the mapper's to know."""
    if sigma is not None:
        return sigma
    return max(mapper.grid.resolution / 2, mapper.sensor.range_resolution)


def index_readings(mapper: Mapper, readings: Readings, sigma: float) -> BeamIndex:
    """Rasterise with a band of 3 sigma about the range moved by the mapper's
    ``band_offset``, and index the result (a cell at distance d then stands for a
    surface at d - offset)."""
    offset = mapper._band_offset(mapper.grid)
    fps = mapper._kept_footprints(readings, dr=3.0 * sigma, offset=offset)
    r = np.minimum(readings.range, mapper.sensor.r_max)
    return build_index(fps, np.asarray(r, dtype=np.float64), offset)


def scatter(
    index: BeamIndex, values: npt.NDArray[np.float64], size: int
) -> npt.NDArray[np.float32]:
    """Local cell values onto a flat grid, NaN elsewhere."""
    out = np.full(size, np.nan, dtype=np.float32)
    out[index.cells] = values
    return out
