"""Checks on values read from configuration files, shared by the modules that read them."""

from __future__ import annotations

import math
from typing import Any

from .errors import ConfigError, quote

__all__ = ["finite_number"]


def finite_number(value: Any, where: str) -> float:
    """``value`` as a float if it is a finite int or float (not a bool).

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
        If ``value`` is not a number, is a bool, or is not finite.
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: expected a number, got {quote(value)}")
    v = float(value)
    if not math.isfinite(v):
        raise ConfigError(f"{where}: expected a finite number, got {quote(value)}")
    return v
