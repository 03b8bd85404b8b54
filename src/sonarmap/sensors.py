"""Sonar models: beam shape, range limits, sensitivity diagram and noise.

A beam or a sensitivity zone is a :class:`Region` of the sensor frame (x forward,
y to the left, metres): the intersection of half-planes and a disc around the
sensor. A cone of aperture < 180 degrees and a convex polygon are both of this
kind, so the rasteriser handles them with one code path.

The sensitivity diagram follows the research notes (methods.md, section 2): nested
zones, each with the smallest detectable obstacle size ``L_vis``; a cell of area
``s`` at a point whose smallest detectable area is ``S = L_vis**2`` gets the
weight ``w0 = min(s / S, 1)``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from .checks import finite_number
from .errors import ConfigError, InputError, quote

__all__ = [
    "SENSOR_PRESETS",
    "Noise",
    "Region",
    "SensorModel",
    "get_sensor",
    "load_sensor",
    "sensor_from_dict",
]


@dataclass(frozen=True, eq=False)
class Region:
    """A convex region of the sensor frame: half-planes ``a x + b y <= c`` and ``|p| <= radius``.

    Build one with :meth:`cone` or :meth:`polygon`.

    Attributes
    ----------
    halfplanes : ndarray, shape (K, 3)
        Rows ``(a, b, c)`` with ``(a, b)`` a unit outward normal.
    radius : float
        Largest distance from the sensor (``inf`` for a polygon, bounded by its vertices).
    outline : ndarray, shape (M, 2)
        Points tracing the boundary, for drawing.
    kind : str
        ``"cone"`` or ``"polygon"``.
    """

    halfplanes: npt.NDArray[np.float64]
    radius: float
    outline: npt.NDArray[np.float64]
    kind: str

    @classmethod
    def cone(cls, aperture_deg: float, radius: float) -> Region:
        """A cone symmetric about the x axis, full opening ``aperture_deg`` (0, 180).

        Examples
        --------
        >>> r = Region.cone(30.0, 5.0)
        >>> bool(r.contains(np.array([[4.0, 1.0]]))[0]), bool(r.contains(np.array([[4.0, 1.2]]))[0])
        (True, False)
        """
        if not (0.0 < aperture_deg < 180.0):
            raise ConfigError(f"cone aperture_deg must be in (0, 180), got {aperture_deg}")
        if not (math.isfinite(radius) and radius > 0):
            raise ConfigError(f"cone radius must be a positive number of metres, got {radius}")
        half = math.radians(aperture_deg) / 2.0
        # Upper edge at +half: outward normal points up-left; lower edge mirrored.
        planes = np.array(
            [
                [-math.sin(half), math.cos(half), 0.0],
                [-math.sin(half), -math.cos(half), 0.0],
            ]
        )
        arc = np.linspace(-half, half, 33)
        outline = np.vstack([[0.0, 0.0], np.c_[radius * np.cos(arc), radius * np.sin(arc)]])
        return cls(halfplanes=planes, radius=float(radius), outline=outline, kind="cone")

    @classmethod
    def polygon(cls, vertices: npt.ArrayLike) -> Region:
        """A convex polygon given by its vertices in order (either orientation).

        Examples
        --------
        >>> sq = Region.polygon([[0, -1], [2, -1], [2, 1], [0, 1]])
        >>> sq.contains(np.array([[1.0, 0.0], [2.5, 0.0]])).tolist()
        [True, False]
        """
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise ConfigError(f"polygon needs at least 3 vertices as [x, y] pairs, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ConfigError("polygon vertices must be finite numbers")
        edges = np.roll(v, -1, axis=0) - v
        area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
        if abs(area2) < 1e-12:
            raise ConfigError("polygon has zero area")
        if area2 < 0:
            v = v[::-1].copy()
            edges = np.roll(v, -1, axis=0) - v
        cross = edges[:, 0] * np.roll(edges[:, 1], -1) - edges[:, 1] * np.roll(edges[:, 0], -1)
        if np.any(cross < -1e-12):
            raise ConfigError("polygon is not convex (beams and zones must be convex)")
        lengths = np.hypot(edges[:, 0], edges[:, 1])
        keep = lengths > 1e-12
        # For a counter-clockwise polygon the outward normal of edge (dx, dy) is (dy, -dx).
        normals = np.c_[edges[keep, 1], -edges[keep, 0]] / lengths[keep, None]
        offsets = np.einsum("ij,ij->i", normals, v[keep])
        planes = np.c_[normals, offsets]
        radius = float(np.max(np.hypot(v[:, 0], v[:, 1])))
        outline = np.vstack([v, v[:1]])
        return cls(halfplanes=planes, radius=radius, outline=outline, kind="polygon")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Region):
            return NotImplemented
        return (
            self.kind == other.kind
            and self.radius == other.radius
            and np.array_equal(self.halfplanes, other.halfplanes)
        )

    def __hash__(self) -> int:
        return hash((self.kind, self.radius, self.halfplanes.tobytes()))

    def __repr__(self) -> str:
        return (
            f"Region(kind={self.kind!r}, halfplanes={len(self.halfplanes)}, radius={self.radius})"
        )

    def contains(self, points: npt.ArrayLike, tol: float = 1e-9) -> npt.NDArray[np.bool_]:
        """Whether points ``(N, 2)`` of the sensor frame lie in the region (boundary included)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        inside = np.all(p @ self.halfplanes[:, :2].T <= self.halfplanes[:, 2] + tol, axis=1)
        near = np.hypot(p[:, 0], p[:, 1]) <= self.radius + tol
        return np.asarray(inside & near, dtype=np.bool_)


@dataclass(frozen=True)
class Noise:
    """The simulator's sonar model (Thrun 2003; methods.md section 3).

    Parameters
    ----------
    p_rand : float
        Probability that a reading is an outlier, uniform on ``[r_min, r_max]``. In [0, 1].
    p_hit : float
        Probability that each occupied cell in the beam, nearest first, reflects. In (0, 1].
    sigma : float
        Standard deviation of the range noise, metres, >= 0.
    """

    p_rand: float = 0.0
    p_hit: float = 1.0
    sigma: float = 0.0

    def __post_init__(self) -> None:
        for name in ("p_rand", "p_hit", "sigma"):
            v = getattr(self, name)
            # A string of a number is for the configuration readers to convert.
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise ConfigError(f"{name} must be a number, got {quote(v)}")
        if not (0.0 <= self.p_rand <= 1.0):
            raise ConfigError(f"p_rand must be in [0, 1], got {self.p_rand}")
        if not (0.0 < self.p_hit <= 1.0):
            raise ConfigError(f"p_hit must be in (0, 1], got {self.p_hit}")
        if not (math.isfinite(self.sigma) and self.sigma >= 0.0):
            raise ConfigError(f"sigma must be >= 0 metres, got {self.sigma}")


@dataclass(frozen=True)
class SensorModel:
    """A range sensor with a wide beam.

    Parameters
    ----------
    name : str
        Identifier.
    beam : Region
        Where the sensor can see, in its own frame (x forward).
    r_min, r_max : float
        Range limits in metres; a reading ``>= r_max`` means no echo.
    range_resolution : float
        Range quantum in metres; the default half-width of the Omega_occ band.
    min_size : float
        Smallest detectable obstacle size (metres) anywhere in the beam outside ``zones``;
        0 means every cell counts fully.
    zones : tuple of (Region, float)
        Inner sensitivity zones with their smallest detectable sizes, smallest size first.
    noise : Noise
        Simulator noise.
    """

    name: str
    beam: Region
    r_min: float
    r_max: float
    range_resolution: float
    min_size: float = 0.0
    zones: tuple[tuple[Region, float], ...] = ()
    noise: Noise = field(default_factory=Noise)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.r_min) and self.r_min >= 0):
            raise ConfigError(f"sensor '{self.name}': r_min must be >= 0, got {self.r_min}")
        if not (math.isfinite(self.r_max) and self.r_max > self.r_min):
            raise ConfigError(
                f"sensor '{self.name}': r_max must be finite and > r_min ({self.r_min}), "
                f"got {self.r_max}"
            )
        if not (math.isfinite(self.range_resolution) and self.range_resolution > 0):
            raise ConfigError(
                f"sensor '{self.name}': range_resolution must be > 0, got {self.range_resolution}"
            )
        if not (math.isfinite(self.min_size) and self.min_size >= 0):
            raise ConfigError(f"sensor '{self.name}': min_size must be >= 0, got {self.min_size}")
        for i, (_, size) in enumerate(self.zones):
            if not (math.isfinite(size) and size >= 0):
                raise ConfigError(
                    f"sensor '{self.name}': zones[{i}].min_size must be >= 0, got {size}"
                )
        object.__setattr__(self, "zones", tuple(sorted(self.zones, key=lambda z: z[1])))

    def with_noise(self, **changes: float) -> SensorModel:
        """A copy with some noise parameters changed (``p_rand``, ``p_hit``, ``sigma``)."""
        unknown = set(changes) - {"p_rand", "p_hit", "sigma"}
        if unknown:
            raise ConfigError(
                f"unknown noise parameter(s) {sorted(unknown)}; valid: p_rand, p_hit, sigma"
            )
        return replace(self, noise=replace(self.noise, **changes))

    def sensitivity(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Smallest detectable obstacle size (metres) at points ``(N, 2)`` of the sensor frame."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        out = np.full(len(p), self.min_size)
        # Zones are sorted smallest size first: the first zone that holds a point wins.
        for region, size in reversed(self.zones):
            out[region.contains(p)] = size
        return out

    def to_dict(self) -> dict[str, Any]:
        """The YAML-ready description :func:`sensor_from_dict` reads back."""

        def region_dict(r: Region) -> dict[str, Any]:
            if r.kind == "cone":
                half = math.atan2(-r.halfplanes[0, 0], r.halfplanes[0, 1])
                return {"cone": {"aperture_deg": round(math.degrees(2 * half), 9)}}
            return {"polygon": r.outline[:-1].round(9).tolist()}

        return {
            "name": self.name,
            "beam": region_dict(self.beam),
            "r_min": self.r_min,
            "r_max": self.r_max,
            "range_resolution": self.range_resolution,
            "min_size": self.min_size,
            "zones": [{**region_dict(r), "min_size": s} for r, s in self.zones],
            "noise": {
                "p_rand": self.noise.p_rand,
                "p_hit": self.noise.p_hit,
                "sigma": self.noise.sigma,
            },
        }


def _symmetric(upper: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """A polygon symmetric about the x axis from the sensor origin and its upper outline.

    ``upper`` lists points ``(forward, left)`` from the sensor outwards and ends on the axis.
    """
    if upper[-1][1] != 0.0:
        raise ConfigError("a symmetric outline must end on the beam axis")
    lower = [(x, -y) for x, y in upper[:-1]]
    return [(0.0, 0.0), *lower, upper[-1], *reversed(upper[:-1])]


_INCH = 0.0254
_FOOT = 12 * _INCH

# LV-MaxSonar-EZ1 (MaxBotix data sheet, "Beam Characteristics", 5 V supply, plotted on a
# 12-inch grid). The data sheet draws detection zones for (A) a 6.1 mm (0.25 in) dowel,
# (B) a 2.54 cm (1 in) dowel and (C) an 8.89 cm (3.5 in) rod. The outlines below are our
# reading of those plots, to about half a grid square (15 cm), simplified to convex
# polygons as the research does; points are (forward, left) in metres.
# Range limits and resolution are the data sheet's: 0 to 254 in (6.45 m) sensed, ranges
# reported from 6 in (0.1524 m) with 1 in resolution.
_EZ1_ZONE_A = _symmetric([(0.30, 0.12), (1.20, 0.25), (2.00, 0.15), (2.30, 0.0)])
_EZ1_ZONE_B = _symmetric([(0.30, 0.20), (1.50, 0.55), (3.00, 0.60), (4.00, 0.35), (4.30, 0.0)])
_EZ1_ZONE_C = _symmetric([(0.30, 0.30), (2.00, 0.95), (4.00, 1.10), (5.50, 0.70), (6.10, 0.0)])


def _maxsonar_ez1() -> SensorModel:
    return SensorModel(
        name="maxsonar-ez1",
        beam=Region.polygon(_EZ1_ZONE_C),
        r_min=6 * _INCH,
        r_max=254 * _INCH,
        range_resolution=_INCH,
        min_size=0.0889,
        zones=(
            (Region.polygon(_EZ1_ZONE_A), 0.0061),
            (Region.polygon(_EZ1_ZONE_B), 0.0254),
        ),
    )


def _hc_sr04() -> SensorModel:
    # HC-SR04 data sheet: ranging 2 cm to 400 cm, resolution 0.3 cm, "measuring angle 15
    # degrees", read here as 15 degrees either side of the axis (a 30-degree cone), the
    # usual reading in measurements of the module. No sensitivity diagram is published.
    return SensorModel(
        name="hc-sr04",
        beam=Region.cone(30.0, 4.0),
        r_min=0.02,
        r_max=4.0,
        range_resolution=0.003,
    )


def _polaroid_6500() -> SensorModel:
    # Polaroid 6500 ranging module with the 600-series electrostatic transducer, the sonar
    # of the Pioneer and Nomad rings: 15 cm to 10.7 m (6 in to 35 ft); the main lobe is
    # taken as a 30-degree cone, the width used by MRPT and most sonar mapping papers.
    return SensorModel(
        name="polaroid-6500",
        beam=Region.cone(30.0, 10.7),
        r_min=0.15,
        r_max=10.7,
        range_resolution=0.01,
    )


SENSOR_PRESETS: Mapping[str, Any] = {
    "maxsonar-ez1": _maxsonar_ez1,
    "hc-sr04": _hc_sr04,
    "polaroid-6500": _polaroid_6500,
}


def get_sensor(name: str) -> SensorModel:
    """A preset sensor model by name.

    Examples
    --------
    >>> get_sensor("hc-sr04").r_max
    4.0
    """
    try:
        return SENSOR_PRESETS[name]()  # type: ignore[no-any-return]
    except KeyError:
        raise ConfigError(
            f"unknown sensor preset '{name}'; valid: {', '.join(SENSOR_PRESETS)}"
        ) from None


def _region_from_dict(d: Any, where: str, r_max: float) -> Region:
    if not isinstance(d, Mapping):
        raise ConfigError(f"{where}: expected a mapping with 'cone' or 'polygon'")
    if "cone" in d:
        cone = d["cone"]
        if not isinstance(cone, Mapping) or "aperture_deg" not in cone:
            raise ConfigError(f"{where}.cone: missing key 'aperture_deg'")
        return Region.cone(finite_number(cone["aperture_deg"], f"{where}.cone.aperture_deg"), r_max)
    if "polygon" in d:
        try:
            return Region.polygon(d["polygon"])
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}.polygon: {err}") from err
    raise ConfigError(f"{where}: expected key 'cone' or 'polygon', got {sorted(d)}")


def sensor_from_dict(d: Any, where: str = "sensor") -> SensorModel:
    """A sensor model from a parsed YAML mapping, or from a preset name.

    Keys: ``name``, ``beam`` (``{cone: {aperture_deg: A}}`` or ``{polygon: [[x, y], ...]}``),
    ``r_max``, ``range_resolution``, optional ``r_min`` (default 0), ``min_size``, ``zones``
    (list of regions each with ``min_size``) and ``noise`` (``p_rand``, ``p_hit``, ``sigma``). A
    mapping ``{preset: NAME, ...}`` starts from a preset and overrides the keys given.
    """
    if isinstance(d, str):
        return get_sensor(d)
    if not isinstance(d, Mapping):
        raise ConfigError(f"{where}: expected a preset name or a mapping")
    known = {
        "preset",
        "name",
        "beam",
        "r_min",
        "r_max",
        "range_resolution",
        "min_size",
        "zones",
        "noise",
    }
    unknown = set(d) - known
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; valid: {sorted(known)}")
    base = get_sensor(str(d["preset"])) if "preset" in d else None
    if base is None:
        for key in ("beam", "r_max", "range_resolution"):
            if key not in d:
                raise ConfigError(f"{where}: missing key '{key}'")
    r_max = finite_number(d["r_max"], f"{where}.r_max") if "r_max" in d else base.r_max  # type: ignore[union-attr]
    kwargs: dict[str, Any] = {"name": str(d.get("name", base.name if base else "custom"))}
    kwargs["beam"] = (
        _region_from_dict(d["beam"], f"{where}.beam", r_max)
        if "beam" in d
        else (base.beam if base else None)
    )
    kwargs["r_max"] = r_max
    for key in ("r_min", "range_resolution", "min_size"):
        if key in d:
            kwargs[key] = finite_number(d[key], f"{where}.{key}")
        elif base is not None:
            kwargs[key] = getattr(base, key)
    kwargs.setdefault("r_min", 0.0)
    if "zones" in d:
        zones = d["zones"] or []
        if not isinstance(zones, list):
            raise ConfigError(f"{where}.zones: expected a list")
        parsed = []
        for i, z in enumerate(zones):
            if not isinstance(z, Mapping) or "min_size" not in z:
                raise ConfigError(f"{where}.zones[{i}]: missing key 'min_size'")
            parsed.append(
                (
                    _region_from_dict(z, f"{where}.zones[{i}]", r_max),
                    finite_number(z["min_size"], f"{where}.zones[{i}].min_size"),
                )
            )
        kwargs["zones"] = tuple(parsed)
    elif base is not None:
        kwargs["zones"] = base.zones
    noise = base.noise if base is not None else Noise()
    if "noise" in d:
        nd = d["noise"]
        if not isinstance(nd, Mapping):
            raise ConfigError(f"{where}.noise: expected a mapping")
        bad = set(nd) - {"p_rand", "p_hit", "sigma"}
        if bad:
            raise ConfigError(
                f"{where}.noise: unknown key(s) {sorted(bad)}; valid: p_hit, p_rand, sigma"
            )
        noise = Noise(**{k: finite_number(v, f"{where}.noise.{k}") for k, v in nd.items()})
    kwargs["noise"] = noise
    return SensorModel(**kwargs)


def load_sensor(path: str | Path) -> SensorModel:
    """Read a sensor model from a YAML file (see :func:`sensor_from_dict`)."""
    from .files import read_yaml

    p = Path(path)
    data = read_yaml(p)
    try:
        return sensor_from_dict(data)
    except ConfigError as err:
        raise InputError(str(err), path=p) from err
