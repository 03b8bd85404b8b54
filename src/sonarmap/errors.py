"""Errors raised by sonarmap.

Every error a user can cause derives from :class:`SonarmapError`, so a caller
catches one type. Messages name the place (file, line, field or parameter), the
bad value and what is allowed, in one line.
"""

from __future__ import annotations

from os import PathLike

__all__ = ["QUOTE_LIMIT", "ConfigError", "InputError", "OutputError", "SonarmapError", "quote"]

#: Characters of a bad value a message quotes at most: a 1 MB field must not become a
#: 1 MB line of a log.
QUOTE_LIMIT = 80


def quote(value: object, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)`` for a message, cut to ``limit`` characters with the full length said.

    Parameters
    ----------
    value : object
        The bad value, as read.
    limit : int
        Characters kept at most.

    Returns
    -------
    str
        E.g. ``'1111111111...' (1000000 characters)``.
    """
    text = repr(value)
    if len(text) <= limit:
        return text
    size = f" ({len(value)} characters)" if isinstance(value, str | bytes) else ""
    return f"{text[:limit]}...{size}"


class SonarmapError(Exception):
    """Base class of every error sonarmap raises on bad input or configuration."""


class InputError(SonarmapError, ValueError):
    """Bad input data: a file, a column, a value.

    Parameters
    ----------
    message : str
        What is wrong, e.g. ``"range is negative (-0.2)"``.
    path : str or path-like, optional
        The file the data came from.
    line : int, optional
        1-based line number in that file.
    field : str, optional
        Column, key or field name.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | PathLike[str] | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.field = field
        self.reason = message
        super().__init__(self._format())

    def _format(self) -> str:
        where = []
        if self.path is not None:
            where.append(self.path if self.line is None else f"{self.path}:{self.line}")
        elif self.line is not None:
            where.append(f"line {self.line}")
        if self.field is not None:
            where.append(f"field '{self.field}'")
        prefix = ", ".join(where)
        return f"{prefix}: {self.reason}" if prefix else self.reason


class ConfigError(SonarmapError, ValueError):
    """Bad configuration: an unknown method or parameter, a value out of its range.

    Parameters
    ----------
    message : str
        What is wrong, e.g. ``"store: pose_limit must be > 0, got 0"``.
    field : str, optional
        The config object's field at fault, so that a caller (the command line) can
        name its own option for it instead of parsing the message.
    """

    def __init__(self, message: str, *, field: str | None = None) -> None:
        self.field = field
        self.reason = message
        super().__init__(message)


class OutputError(SonarmapError, OSError):
    """An output that cannot be written: a directory in the way, no permission, no space.

    Parameters
    ----------
    message : str
        What went wrong.
    path : str or path-like
        The output.
    """

    def __init__(self, message: str, *, path: str | PathLike[str]) -> None:
        self.path = str(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}")
