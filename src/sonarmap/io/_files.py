"""Checks on input paths before a reader opens them."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def need_file(path: str | Path, what: str = "file") -> Path:
    """``path`` as a Path if it names a regular file; otherwise an InputError that says
    whether nothing or a directory is there."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"is a directory; expected a {what}", path=p)
    if not p.is_file():
        raise InputError("no such file", path=p)
    return p
