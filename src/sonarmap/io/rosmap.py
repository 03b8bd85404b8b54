"""Occupancy maps in the ROS map_server format (YAML + PGM/PNG), plus a float ``.npy``.

The YAML keys follow map_server: ``image`` (path relative to the YAML file),
``resolution`` (metres per pixel), ``origin`` ``[x, y, yaw]`` of the lower-left pixel,
``negate``, ``occupied_thresh``, ``free_thresh`` and ``mode`` (``trinary``, ``scale``
or ``raw``). Image row 0 is the top of the map. A pixel value ``v`` becomes
``p = (255 - v) / 255`` (or ``v / 255`` with ``negate: 1``); colour pixels use the mean
of their channels, and 16-bit grey pixels ``v / 257``, as map_server does.

sonarmap writes ``NAME.yaml``, ``NAME.pgm`` (0 occupied, 254 free, 205 unknown: the
values map_saver writes) and ``NAME.npy`` (float32 occupancy in [0, 1], NaN where
unknown, same orientation as the image). The image holds the map's classes
(:meth:`OccupancyMap.classes`), the same ones every score and picture uses, and the
YAML's thresholds are map_saver's, which read those three pixel values back as written.
When reading ``NAME.yaml`` and a ``NAME.npy`` lies beside it, its exact occupancy is
used instead of the thresholded image (``use_npy=False`` reads the image only); an array
that cannot be read, or is not float occupancy of the image's shape, is an error naming it.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image, UnidentifiedImageError

from ..checks import MAX_MAP_CELLS, as_number
from ..errors import InputError, quote
from ..files import atomic_outputs, dump_yaml, need_file, read_yaml
from ..grid import Grid

__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "OccupancyMap",
    "classify",
    "read_map",
    "read_plan",
    "write_map",
]

F32 = npt.NDArray[np.float32]

OCCUPIED_PIXEL = 0
FREE_PIXEL = 254
UNKNOWN_PIXEL = 205
_MODES = ("trinary", "scale", "raw")

#: The three classes of a cell (:func:`classify`).
OCCUPIED, FREE, UNKNOWN = 1, 0, -1


def classify(occupancy: npt.ArrayLike) -> npt.NDArray[np.int8]:
    """Classes of occupancy values: 1 occupied, 0 free, -1 unknown.

    A cell is occupied when its value is above 0.5, free below, and unknown when NaN or
    exactly 0.5: a cell the evidence left at even odds (a log-odds sum of 0, a tie of
    votes, EM's posterior with no term, a forward-model cell no step moved) is no more
    free than occupied. Every method's values share this boundary: the inverse, counting
    and EM values are probabilities, the gradient method's cell values are binarised at
    0.5 as the research does, and the stochastic search's are 0 or 1.

    Examples
    --------
    >>> classify(np.array([0.9, 0.5, 0.2, np.nan])).tolist()
    [1, -1, 0, -1]
    """
    occ = np.asarray(occupancy, dtype=np.float64)
    out = np.full(occ.shape, UNKNOWN, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        out[occ > 0.5] = OCCUPIED
        out[occ < 0.5] = FREE
    return out


_IMAGE_MODES = ("L", "LA", "RGB", "RGBA", "P", "1")
#: 16-bit grey modes: Pillow's for a 16-bit PNG, and for a PGM of maxval above 255 ("I",
#: its values scaled by Pillow to 0..65535 whatever the maxval).
_DEEP_MODES = ("I;16", "I;16B", "I;16L")
#: 65535 / 255: a 16-bit grey value to the 8-bit scale the thresholds are read on.
_DEEP_SCALE = 257.0


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """Occupancy values over a grid.

    Attributes
    ----------
    grid : Grid
        Geometry.
    occupancy : ndarray of float32, shape ``grid.shape``
        Probability of occupancy in [0, 1], NaN where unknown; row 0 is the top.
    """

    grid: Grid
    occupancy: F32

    def __post_init__(self) -> None:
        occ = np.asarray(self.occupancy, dtype=np.float32)
        if occ.shape != self.grid.shape:
            raise InputError(f"occupancy has shape {occ.shape}, grid has {self.grid.shape}")
        finite = occ[np.isfinite(occ)]
        if np.any(np.isinf(occ)) or np.any((finite < 0) | (finite > 1)):
            raise InputError("occupancy values must lie in [0, 1] or be NaN")
        object.__setattr__(self, "occupancy", occ)

    def classes(self) -> npt.NDArray[np.int8]:
        """Per cell 1 occupied, 0 free, -1 unknown (:func:`classify`)."""
        return classify(self.occupancy)


def _key(d: Mapping[str, Any], key: str, path: Path) -> Any:
    if key not in d:
        raise InputError(f"missing key '{key}'", path=path, field=key)
    return d[key]


def _num(value: Any, path: Path, field: str) -> float:
    v = as_number(value)
    if v is None:
        raise InputError(f"expected a number, got {quote(value)}", path=path, field=field)
    if not math.isfinite(v):
        raise InputError(f"expected a finite number, got {quote(value)}", path=path, field=field)
    return v


#: map_server's default thresholds, used where a map does not state its own and written
#: with every map (so map_server reads our classes back).
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196

#: Pixels of a map image read at most, checked from the image's header before its
#: pixels are decoded: the command line's own map limit (10^8, 10 000 x 10 000).
MAX_PIXELS = MAX_MAP_CELLS
#: Metres a map may span, and its origin lie from 0, at most: 10 000 km (UTM
#: coordinates fit; a resolution meant as centimetres but read as metres does not
#: overflow the geometry that follows).
MAX_EXTENT = 1e7

#: Suffixes read as a bare image (a floor plan without its YAML).
IMAGE_SUFFIXES = (".png", ".pgm", ".bmp", ".jpg", ".jpeg", ".gif", ".tif", ".tiff")


def read_plan(
    path: str | Path, resolution: float | None, origin: tuple[float, float]
) -> OccupancyMap:
    """A plan as every ``--map`` takes one: :func:`read_map` of a map_server YAML (which
    has its own resolution and origin, so ``resolution`` and ``origin`` are not used),
    or of a bare image with ``resolution`` (metres per pixel) and ``origin`` (metres)."""
    if Path(path).suffix.lower() in IMAGE_SUFFIXES:
        return read_map(path, resolution=resolution, origin=origin)
    return read_map(path)


def read_map(
    path: str | Path,
    *,
    use_npy: bool = True,
    resolution: float | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
) -> OccupancyMap:
    """Read a map_server map (YAML and its image), or a bare image.

    Parameters
    ----------
    path : str or Path
        The YAML file; or an image (:data:`IMAGE_SUFFIXES`), read as map_server would
        read it with the default thresholds (dark occupied, light free, grey unknown) --
        the research's simulator took its floor plans so, 0.1 m per pixel.
    resolution : float, optional
        Metres per pixel of a bare image (required for one; a YAML has its own).
    origin : (float, float)
        World position of a bare image's lower-left corner, metres.

    Returns
    -------
    OccupancyMap
        In trinary mode cells are 1 (occupied), 0 (free) or NaN (unknown); in scale mode
        cells between the thresholds keep a graded value; in raw mode ``v / 100`` with
        values above 100 unknown.
    """
    if Path(path).suffix.lower() in IMAGE_SUFFIXES:
        return _read_bare_image(Path(path), resolution, origin)
    if resolution is not None:
        raise InputError(
            "a resolution is given only with a bare image; the YAML has its own", path=path
        )
    p = Path(path)
    meta = read_yaml(p, "map file")
    if not isinstance(meta, Mapping):
        raise InputError("expected a YAML mapping with image, resolution and origin", path=p)
    image_name = _key(meta, "image", p)
    if not isinstance(image_name, str) or not image_name:
        raise InputError("expected an image file name", path=p, field="image")
    resolution = _num(_key(meta, "resolution", p), p, "resolution")
    if resolution <= 0:
        raise InputError(f"must be > 0, got {resolution}", path=p, field="resolution")
    origin = _key(meta, "origin", p)
    if not isinstance(origin, list) or len(origin) not in (2, 3):
        raise InputError(f"expected [x, y, yaw], got {origin!r}", path=p, field="origin")
    ox, oy = (_num(v, p, "origin") for v in origin[:2])
    if len(origin) == 3 and (yaw := _num(origin[2], p, "origin")) != 0.0:
        raise InputError(
            f"rotated maps (origin yaw {yaw:g} rad, not 0) are not supported",
            path=p,
            field="origin",
        )
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise InputError(f"must be 0 or 1, got {negate!r}", path=p, field="negate")
    occ_t = _num(meta.get("occupied_thresh", OCCUPIED_THRESH), p, "occupied_thresh")
    free_t = _num(meta.get("free_thresh", FREE_THRESH), p, "free_thresh")
    if not (0.0 <= free_t < occ_t <= 1.0):
        raise InputError(
            f"thresholds need 0 <= free_thresh ({free_t}) < occupied_thresh ({occ_t}) <= 1",
            path=p,
            field="occupied_thresh",
        )
    mode = meta.get("mode", "trinary")
    if mode not in _MODES:
        raise InputError(f"unknown mode {mode!r}; valid: {', '.join(_MODES)}", path=p, field="mode")

    image_path = Path(image_name) if Path(image_name).is_absolute() else p.parent / image_name
    value, alpha, deep = _read_image(
        image_path, lambda shape: _check_extent(shape, resolution, (ox, oy), p)
    )
    prob = value / 255.0 if negate else (255.0 - value) / 255.0
    occ = np.full(value.shape, np.nan, dtype=np.float64)
    if mode == "raw":
        if deep:
            # Nav2 takes a 16-bit pixel's value in raw mode as round(v / 257).
            value = np.rint(value)
        ok = value <= 100
        occ[ok] = value[ok] / 100.0
    else:
        occ[prob > occ_t] = 1.0
        occ[prob < free_t] = 0.0
        if mode == "scale":
            mid = (prob >= free_t) & (prob <= occ_t)
            occ[mid] = (prob[mid] - free_t) / (occ_t - free_t)
            if alpha is not None:
                occ[alpha == 0] = np.nan
    grid = Grid(resolution=resolution, origin=(ox, oy), shape=(value.shape[0], value.shape[1]))
    exact = p.with_suffix(".npy")
    if use_npy and exact.is_file():
        return OccupancyMap(grid, _read_exact(exact, (value.shape[0], value.shape[1])))
    return OccupancyMap(grid, occ.astype(np.float32))


def _read_exact(path: Path, shape: tuple[int, int]) -> F32:
    """The ``.npy`` beside a map's YAML: float occupancy of the image's shape, in [0, 1]
    or NaN; anything else is an error naming the file (a stale or foreign array would
    otherwise be used, or dropped, without a word)."""
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as err:
        # numpy reports a damaged header in many ways (ValueError, OSError, EOFError,
        # tokenize.TokenError, SyntaxError, ...): at this boundary each is the file's fault.
        reason = " ".join(str(err).split())
        raise InputError(
            f"cannot read occupancy array ({type(err).__name__}: {reason[:80]})", path=path
        ) from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind != "f":
        kind = type(arr).__name__ if not isinstance(arr, np.ndarray) else str(arr.dtype)
        raise InputError(f"expected a float occupancy array, got {kind}", path=path)
    if arr.shape != shape:
        raise InputError(
            f"array of shape {arr.shape} beside an image of {shape[0]} x {shape[1]} pixels: "
            "remove it or write the map again",
            path=path,
        )
    bad = ~np.isnan(arr) & ~((arr >= 0.0) & (arr <= 1.0))
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(
            f"occupancy must be in [0, 1] or NaN, got {arr[r, c]} at row {r}, column {c}",
            path=path,
        )
    return arr.astype(np.float32)


def _read_bare_image(
    path: Path, resolution: float | None, origin: tuple[float, float]
) -> OccupancyMap:
    if resolution is None:
        raise InputError("a bare image needs --resolution (metres per pixel)", path=path)
    if not (math.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be > 0 metres per pixel, got {resolution}", path=path)
    if not all(math.isfinite(v) for v in origin):
        raise InputError(f"origin must be finite, got {origin}", path=path)
    value, _, _ = _read_image(
        need_file(path, "map image"), lambda shape: _check_extent(shape, resolution, origin, path)
    )
    prob = (255.0 - value) / 255.0
    occ = np.full(value.shape, np.nan, dtype=np.float32)
    occ[prob > OCCUPIED_THRESH] = 1.0
    occ[prob < FREE_THRESH] = 0.0
    grid = Grid(resolution=resolution, origin=origin, shape=(value.shape[0], value.shape[1]))
    return OccupancyMap(grid, occ)


def _check_extent(
    shape: tuple[int, ...], resolution: float, origin: tuple[float, float], path: Path
) -> None:
    """Refuse a map whose world size or origin is beyond :data:`MAX_EXTENT` metres."""
    span = max(shape[0], shape[1]) * resolution
    if span > MAX_EXTENT:
        raise InputError(
            f"resolution {resolution:g} m per pixel makes the map {span:.3g} m across "
            f"(at most {MAX_EXTENT:.0e} m)",
            path=path,
            field="resolution",
        )
    if max(abs(origin[0]), abs(origin[1])) > MAX_EXTENT:
        raise InputError(
            f"origin ({origin[0]:g}, {origin[1]:g}) lies more than {MAX_EXTENT:.0e} m from 0",
            path=path,
            field="origin",
        )


def _read_image(
    path: Path, check_shape: Callable[[tuple[int, int]], None]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8] | None, bool]:
    """Grey values on 0..255 (16-bit ones divided by 257), the alpha channel if any,
    and whether the image was 16-bit; ``check_shape((rows, cols))`` is called from the
    header, before the pixels are decoded."""
    try:
        with warnings.catch_warnings():
            # Pillow warns of a large image on opening; the size check below says more.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
        with im:
            width, height = im.size
            if width * height > MAX_PIXELS:
                raise InputError(
                    f"image of {width} x {height} pixels; at most {MAX_PIXELS:.0e} pixels",
                    path=path,
                )
            check_shape((height, width))
            im.load()
            if im.mode in _DEEP_MODES or (im.mode == "I" and im.format == "PPM"):
                # map_server (Nav2) reads a 16-bit grey image on its own scale.
                return np.asarray(im, dtype=np.float64) / _DEEP_SCALE, None, True
            if im.mode not in _IMAGE_MODES:
                raise InputError(
                    f"unsupported image mode '{im.mode}'; expected 8-bit grey or colour "
                    f"({', '.join(_IMAGE_MODES)}) or 16-bit grey",
                    path=path,
                )
            if im.mode == "P":
                arr = np.asarray(im.convert("RGBA"))
            elif im.mode == "1":
                arr = np.asarray(im.convert("L"))
            else:
                arr = np.asarray(im)
    except InputError:
        raise
    except FileNotFoundError as err:
        raise InputError("map image not found", path=path) from err
    except IsADirectoryError as err:
        raise InputError("map image is a folder, not an image file", path=path) from err
    except (
        UnidentifiedImageError,
        OSError,
        ValueError,
        SyntaxError,
        Image.DecompressionBombError,
    ) as err:
        # Pillow reports malformed headers and truncated pixel data in several ways.
        raise InputError(f"cannot read image ({type(err).__name__}: {err})", path=path) from err
    if arr.ndim == 2:
        return arr.astype(np.float64), None, False
    alpha = arr[..., -1] if arr.shape[-1] in (2, 4) else None
    colour = arr[..., :1] if arr.shape[-1] <= 2 else arr[..., :3]
    return colour.astype(np.float64).mean(axis=-1), alpha, False


def map_paths(stem: str | Path) -> tuple[Path, Path, Path]:
    """The ``.yaml``, ``.pgm`` and ``.npy`` paths of an output stem (a suffix is dropped)."""
    s = Path(stem)
    if s.suffix in (".yaml", ".yml", ".pgm", ".npy"):
        s = s.with_suffix("")
    return s.with_name(s.name + ".yaml"), s.with_name(s.name + ".pgm"), s.with_name(s.name + ".npy")


def to_pixels(occupancy: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """Trinary map_saver pixels of the classes: 0 occupied, 254 free, 205 unknown."""
    cls = classify(occupancy)
    px = np.full(cls.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    px[cls == OCCUPIED] = OCCUPIED_PIXEL
    px[cls == FREE] = FREE_PIXEL
    return px


def write_map(m: OccupancyMap, stem: str | Path, *, exact: bool = True) -> tuple[Path, ...]:
    """Write ``STEM.yaml``, ``STEM.pgm`` and ``STEM.npy`` atomically.

    The image holds the map's classes (:meth:`OccupancyMap.classes`); map_server, reading
    it with the thresholds written to the YAML, gets those classes back.

    Parameters
    ----------
    m : OccupancyMap
        The map.
    stem : str or Path
        Output path without suffix.
    exact : bool
        Also write the float values (``.npy``); a floor plan, whose classes say all,
        needs none.

    Returns
    -------
    tuple of Path
        The files written.
    """
    yaml_path, pgm_path, npy_path = map_paths(stem)
    meta = {
        "image": pgm_path.name,
        "mode": "trinary",
        "resolution": m.grid.resolution,
        "origin": [m.grid.origin[0], m.grid.origin[1], 0.0],
        "negate": 0,
        # map_saver's values: they classify 0 / 254 / 205 pixels back as written.
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
    }
    pixels = to_pixels(m.occupancy)
    paths = (yaml_path, pgm_path, npy_path) if exact else (yaml_path, pgm_path)
    with atomic_outputs(*paths) as temps:
        temps[0].write_text(dump_yaml(meta))
        Image.fromarray(pixels).save(temps[1], format="PPM")
        if exact:
            with temps[2].open("wb") as f:
                np.save(f, m.occupancy.astype(np.float32), allow_pickle=False)
    return paths
