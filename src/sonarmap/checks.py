"""Checks on values read from configuration files, shared by the modules that read them."""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Callable, Mapping
from typing import Any

from .errors import ConfigError, quote

__all__ = ["MAX_MAP_CELLS", "as_number", "finite_number", "numbers_where_floats"]

#: Cells of a map read or built at most: 10^8 (10 000 x 10 000, a kilometre square at
#: 0.1 m), 800 MB for each float64 layer a method keeps. A map image's pixels and the
#: command line's grids are held to it; the library's :class:`~sonarmap.grid.Grid`
#: takes up to 2^31 cells for callers that know their memory.
MAX_MAP_CELLS = 100_000_000

# A decimal number as yaml-cpp and map_server read one: sign, digits, optional
# fraction and exponent (no underscores, no hexadecimal, no base 60).
_DECIMAL = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


def as_number(value: Any) -> float | None:
    """``value`` as a float if it is a number, or a string written as a decimal number.

    PyYAML reads YAML 1.1, where ``1e-3`` (no dot) and quoted ``"0.1"`` are strings;
    map_server's yaml-cpp reads both as numbers where a number is expected. Strings
    are accepted here, where a number is wanted, and nowhere else (a name ``1e5``
    stays a name).

    Parameters
    ----------
    value : Any
        A parsed configuration value.

    Returns
    -------
    float or None
        The value (possibly infinite or NaN: finiteness is the caller's check), or
        None if it is a bool, another type, or a string that is not a decimal number.
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        try:
            return float(value)
        except OverflowError:  # an int beyond the float range
            return math.inf
    if isinstance(value, str) and _DECIMAL.fullmatch(value.strip()):
        return float(value)
    return None


def _number_or_same(value: Any) -> Any:
    v = as_number(value) if isinstance(value, str) else None
    return value if v is None else v


def numbers_where_floats(params: Mapping[str, Any], fn: Callable[..., Any]) -> dict[str, Any]:
    """``params`` with the strings :func:`as_number` reads turned to floats, where
    ``fn`` takes a float.

    The keyword arguments a configuration file gives a function pass through here, so
    that ``1e-2`` read as a string by PyYAML is the number it was written as; the
    function's own checks then see a float. A parameter annotated ``float`` (alone,
    optional, or a sequence of floats) is converted, its list items one by one; any
    other parameter, and a string that is not a decimal number, is left as given, for
    the function's checks to refuse by name.

    Parameters
    ----------
    params : Mapping
        Keyword arguments for ``fn``, as parsed.
    fn : callable
        The function (or class) they are for; its annotations decide.

    Returns
    -------
    dict
        A new mapping, the same keys.
    """
    sig = inspect.signature(fn).parameters
    out = dict(params)
    for name, value in params.items():
        # Annotations are strings under postponed evaluation; an int is not a float.
        if name not in sig or "float" not in str(sig[name].annotation):
            continue
        if isinstance(value, list | tuple):
            out[name] = type(value)(_number_or_same(v) for v in value)
        else:
            out[name] = _number_or_same(value)
    return out


def finite_number(value: Any, where: str) -> float:
    """``value`` as a float if it is a finite number (:func:`as_number`).

    Parameters
    ----------
    value : Any
        A parsed configuration value.
    where : str
        Where it was read (e.g. ``"rig.sonars[0].x"``), for the error message.

    Returns
    -------
    float
        The value.

    Raises
    ------
    ConfigError
        If ``value`` is not a number (nor a string of one), is a bool, or is not finite.
    """
    v = as_number(value)
    if v is None:
        raise ConfigError(f"{where}: expected a number, got {quote(value)}")
    if not math.isfinite(v):
        raise ConfigError(f"{where}: expected a finite number, got {quote(value)}")
    return v
