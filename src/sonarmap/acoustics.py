"""A sonar simulated from the physics of its echoes, not from any mapper's model.

The mappers explain a reading with the cells of a polygon beam and a band at the
reading's range, on their own grid. Readings simulated that way would fit them by
construction. This model shares none of it:

- **Geometry** is a raster at least five times finer than the maps (1 cm by default;
  :func:`surfaces`), or the vector floor plan it was drawn from. Rays are cast through
  it cell edge by cell edge (Amanatides & Woo's traversal), so a range is the distance
  to an obstacle's *surface*, not to a cell centre.
- **Beam**: the far-field pattern of a circular piston transducer,
  ``D(phi) = |2 J1(ka sin phi) / (ka sin phi)|`` (Kuc & Siegel 1987), with its side
  lobes; ``ka`` puts the first null at the sensor's nominal half-aperture. A ray at
  ``phi`` off the axis carries ``D(phi)**2`` of the on-axis power, out and back.
- **Echo strength**: ``A = D(phi)**2 rho (R / d)**2`` for a surface at ``d`` metres,
  where ``R = reach * r_max`` is the range at which a wall met head-on on the axis is
  just heard; an echo is heard when ``A >= 1``. A smooth wall reflects like a mirror,
  ``rho = (1 - roughness) exp(-(alpha / specular)**2) + roughness cos(alpha)`` for an
  incidence angle ``alpha``, so walls met obliquely return nothing (the specular
  misses of real sonars); a concave corner returns the pulse whatever the angle (a
  corner reflector, ``corner_gain``) and a convex edge diffracts a weak echo
  (``edge_gain``). The reading is the first echo heard: the nearest surface over the
  rays whose echo is strong enough.
- **Errors**: Gaussian range noise ``sigma + sigma_rel * d``; a per-sonar scale error
  (speed of sound, clock) of ``scale_sigma``; readings quantised to the sensor's range
  resolution; spurious readings (crosstalk) uniform on ``[r_min, r_max]`` with
  probability ``p_rand``. No echo gives ``r_max``.

What it leaves out: multiple reflections (the pulse a wall mirrors away may come back
by another wall, later), the robot's own body, and sound speed varying in the room.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt
from scipy import ndimage, special

from .checks import numbers_where_floats
from .errors import ConfigError
from .grid import Grid
from .io.rosmap import OCCUPIED, OccupancyMap
from .sensors import SensorModel

__all__ = ["AcousticModel", "Surfaces", "beam_pattern", "half_aperture", "surfaces"]

F64 = npt.NDArray[np.float64]

#: First zero of the Bessel function J1: the piston pattern's first null.
_J1_ZERO = 3.8317059702075125

#: Surface kinds on the fine raster.
FLAT, EDGE, CORNER = 0, 1, 2


@dataclass(frozen=True)
class AcousticModel:
    """Parameters of the acoustic sonar (see the module notes).

    Parameters
    ----------
    sigma : float
        Range noise at zero range, metres (0.01).
    sigma_rel : float
        Range noise growing with range, per metre (0.01: 1 cm more at 1 m).
    p_rand : float
        Probability of a spurious reading uniform on ``[r_min, r_max]`` (0.01).
    scale_sigma : float
        Per-sonar range scale error, drawn once per run (0.005: half a percent).
    reach : float
        Fraction of ``r_max`` at which a wall met head-on on the axis is just heard (1).
    specular_deg : float
        Angular width of a smooth wall's mirror reflection, degrees (8).
    roughness : float
        Diffusely scattered share of a wall's echo, in [0, 1) (0.03).
    corner_gain : float
        Echo strength of a concave corner, any angle (1).
    edge_gain : float
        Echo strength of a convex edge, any angle (0.05).
    null_deg : float or None
        Angle of the beam pattern's first null, degrees; default the sensor's nominal
        half-aperture.
    ray_step_deg : float
        Angle between rays, degrees (0.5).
    max_cell : float
        Coarsest geometry the rays are cast through, metres; a coarser map is
        subdivided (0.01).
    """

    sigma: float = 0.01
    sigma_rel: float = 0.01
    p_rand: float = 0.01
    scale_sigma: float = 0.005
    reach: float = 1.0
    specular_deg: float = 8.0
    roughness: float = 0.03
    corner_gain: float = 1.0
    edge_gain: float = 0.05
    null_deg: float | None = None
    ray_step_deg: float = 0.5
    max_cell: float = 0.01

    def __post_init__(self) -> None:
        def check(name: str, lo: float, hi: float | None, *, lo_open: bool = False) -> None:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ConfigError(f"acoustic model: {name} must be a number, got {v!r}")
            bad_lo = v <= lo if lo_open else v < lo
            if bad_lo or (hi is not None and v > hi):
                rng = f"{'(' if lo_open else '['}{lo}, {hi if hi is not None else 'inf'}]"
                raise ConfigError(f"acoustic model: {name} must be in {rng}, got {v}")

        for name in ("sigma", "sigma_rel", "scale_sigma", "corner_gain", "edge_gain"):
            check(name, 0.0, None)
        check("p_rand", 0.0, 1.0)
        check("reach", 0.0, None, lo_open=True)
        check("specular_deg", 0.0, 90.0, lo_open=True)
        check("roughness", 0.0, 0.999)
        check("ray_step_deg", 0.0, 10.0, lo_open=True)
        check("max_cell", 0.0, None, lo_open=True)
        if self.null_deg is not None:
            check("null_deg", 0.0, 90.0, lo_open=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "acoustic model") -> AcousticModel:
        """The model from keyword values; unknown names are an error that lists the valid."""
        valid = [f.name for f in fields(cls)]
        bad = sorted(set(d) - set(valid))
        if bad:
            raise ConfigError(f"{where}: unknown parameter(s) {bad}; valid: {', '.join(valid)}")
        return cls(**numbers_where_floats(d, cls))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def half_aperture(sensor: SensorModel) -> float:
    """The nominal half-aperture of a sensor's beam (radians): the largest angle off the
    axis of its outline."""
    pts = sensor.beam.outline
    ahead = pts[pts[:, 0] > 1e-9]
    return float(np.max(np.abs(np.arctan2(ahead[:, 1], ahead[:, 0]))))


def beam_pattern(model: AcousticModel, sensor: SensorModel) -> tuple[F64, F64]:
    """The rays of one reading: angles off the axis (radians) and their amplitude
    ``D(phi)``, nearest the axis first, keeping those that can hear anything beyond
    ``r_min``."""
    null = math.radians(model.null_deg) if model.null_deg is not None else half_aperture(sensor)
    ka = _J1_ZERO / math.sin(null)
    n = math.floor(90.0 / model.ray_step_deg + 1e-9)
    phi = np.radians(np.arange(-n, n + 1) * model.ray_step_deg)
    x = ka * np.sin(phi)
    with np.errstate(invalid="ignore", divide="ignore"):
        amp = np.where(np.abs(x) < 1e-12, 1.0, np.abs(2.0 * special.j1(x) / x))
    loudest = max(1.0, model.corner_gain, model.edge_gain)
    reach = model.reach * sensor.r_max * amp * math.sqrt(loudest)
    keep = reach > sensor.r_min
    order = np.argsort(np.abs(phi[keep]), kind="stable")
    return phi[keep][order], amp[keep][order]


@dataclass(frozen=True, eq=False)
class Surfaces:
    """Obstacle geometry prepared for ray casting, rows from the bottom up.

    Attributes
    ----------
    grid : Grid
        The fine grid (its rows are stored bottom-up here).
    occupied : ndarray of bool
    kind : ndarray of int8
        Per cell :data:`FLAT`, :data:`EDGE` (convex) or :data:`CORNER` (concave).
    nx, ny : ndarray of float64
        Outward surface normal at obstacle cells (0 where undefined).
    """

    grid: Grid
    occupied: npt.NDArray[np.bool_]
    kind: npt.NDArray[np.int8]
    nx: F64
    ny: F64


def surfaces(world: OccupancyMap, max_cell: float = 0.01) -> Surfaces:
    """Prepare a floor plan for ray casting, subdivided to cells of at most ``max_cell``.

    Normals come from the gradient of the occupancy smoothed over about 1.5 cells (so a
    staircase of cells drawing a slanted wall faces the way the wall does). A cell's
    kind comes from the obstacle share of the 5 x 5 cells around it: about 0.6 on a
    straight wall, 0.36 at a convex edge, 0.84 in a concave corner.
    """
    h = world.grid.resolution
    k = max(1, math.ceil(h / max_cell - 1e-9))
    occ = world.classes() == OCCUPIED
    if k > 1:
        occ = np.repeat(np.repeat(occ, k, axis=0), k, axis=1)
    fine = Grid(h / k, world.grid.origin, (world.grid.rows * k, world.grid.cols * k))
    up = np.ascontiguousarray(occ[::-1])
    smooth = ndimage.gaussian_filter(up.astype(np.float64), 1.5, mode="nearest")
    gy, gx = np.gradient(smooth)
    norm = np.hypot(gx, gy)
    with np.errstate(invalid="ignore", divide="ignore"):
        nx = np.where(norm > 1e-9, -gx / norm, 0.0)
        ny = np.where(norm > 1e-9, -gy / norm, 0.0)
    share = ndimage.uniform_filter(up.astype(np.float64), size=5, mode="nearest")
    kind = np.full(up.shape, FLAT, dtype=np.int8)
    kind[share < 0.45] = EDGE
    kind[share > 0.75] = CORNER
    return Surfaces(fine, up, kind, nx, ny)


@nb.njit(cache=True, parallel=True)
def first_echoes(
    occ: npt.NDArray[np.bool_],
    kind: npt.NDArray[np.int8],
    nx: F64,
    ny: F64,
    ox: float,
    oy: float,
    h: float,
    sx: F64,
    sy: F64,
    st: F64,
    phi: F64,
    amp: F64,
    far: float,
    r_max: float,
    cos_spec: F64,
    roughness: float,
    edge_gain: float,
    corner_gain: float,
) -> F64:
    """Per sensor pose, the distance of the first echo heard (``r_max`` for none).

    ``cos_spec`` tabulates the mirror reflection ``exp(-(alpha / specular)**2)`` over
    ``alpha`` in [0, pi / 2] (index ``round(alpha / (pi / 2) * (len - 1))``).
    """
    rows, cols = occ.shape
    n = sx.shape[0]
    out = np.full(n, r_max)
    n_tab = cos_spec.shape[0] - 1
    loud = max(1.0, corner_gain, edge_gain)
    for i in nb.prange(n):
        px = (sx[i] - ox) / h
        py = (sy[i] - oy) / h
        j0 = math.floor(px)
        i0 = math.floor(py)
        if not (0 <= i0 < rows and 0 <= j0 < cols):
            continue
        if occ[i0, j0]:
            out[i] = 0.0
            continue
        best = r_max
        for k in range(phi.shape[0]):
            d_max = min(far * amp[k] * math.sqrt(loud), best)
            if d_max <= 0.0:
                continue
            a = st[i] + phi[k]
            dx = math.cos(a)
            dy = math.sin(a)
            step_x = 1 if dx > 0 else -1
            step_y = 1 if dy > 0 else -1
            t_dx = abs(1.0 / dx) if dx != 0.0 else math.inf
            t_dy = abs(1.0 / dy) if dy != 0.0 else math.inf
            t_x = ((j0 + 1 - px) if dx > 0 else (px - j0)) * t_dx if dx != 0.0 else math.inf
            t_y = ((i0 + 1 - py) if dy > 0 else (py - i0)) * t_dy if dy != 0.0 else math.inf
            ci = i0
            cj = j0
            limit = d_max / h
            while True:
                if t_x < t_y:
                    t = t_x
                    t_x += t_dx
                    cj += step_x
                    fx = -float(step_x)
                    fy = 0.0
                else:
                    t = t_y
                    t_y += t_dy
                    ci += step_y
                    fx = 0.0
                    fy = -float(step_y)
                if t > limit or not (0 <= ci < rows and 0 <= cj < cols):
                    break
                if not occ[ci, cj]:
                    continue
                mx = nx[ci, cj]
                my = ny[ci, cj]
                c = -(dx * mx + dy * my)
                if c <= 0.0:  # no usable normal (a one-cell sliver): the face crossed
                    mx = fx
                    my = fy
                    c = -(dx * mx + dy * my)
                c = min(max(c, 0.0), 1.0)
                alpha = math.acos(c)
                rho = (1.0 - roughness) * cos_spec[round(alpha / (math.pi / 2) * n_tab)]
                rho += roughness * c
                kd = kind[ci, cj]
                if kd == 1:
                    rho = max(rho, edge_gain)
                elif kd == 2:
                    rho = max(rho, corner_gain)
                d = t * h
                if amp[k] * amp[k] * rho * (far / d) ** 2 >= 1.0 and d < best:
                    best = d
                break
        out[i] = best
    return out
