"""Validators for mapper parameters: one line naming the parameter and its range."""

from __future__ import annotations

import math
from collections.abc import Sequence

from ..errors import ConfigError, quote


def number(
    name: str,
    value: object,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """``value`` as a float inside the given bounds, or ConfigError."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"parameter '{name}' must be a finite number, got {quote(value)}")
    v = float(value)
    below = lo is not None and (v <= lo if lo_open else v < lo)
    above = hi is not None and (v >= hi if hi_open else v > hi)
    if below or above:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        rng = f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{right}"
        raise ConfigError(f"parameter '{name}' must be in {rng}, got {quote(value)}")
    return v


def choice(name: str, value: object, options: Sequence[str]) -> str:
    if value not in options:
        raise ConfigError(
            f"parameter '{name}' must be one of {', '.join(options)}; got {quote(value)}"
        )
    return str(value)


def integer(name: str, value: object, lo: int | None = None) -> int:
    """``value`` as an int >= ``lo``, or ConfigError."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"parameter '{name}' must be an integer, got {quote(value)}")
    if lo is not None and value < lo:
        raise ConfigError(f"parameter '{name}' must be >= {lo}, got {quote(value)}")
    return value
