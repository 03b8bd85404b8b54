"""File-system helpers every layer may use: atomic writes, input checks, YAML and JSON.

Outputs are written to a temporary file beside their destination and renamed into
place only when every output of the operation has been written, so a failure leaves
no half-written file. Inputs are checked before a reader opens them, and errors name
the file (and, for YAML, the line).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import InputError, OutputError

__all__ = [
    "atomic_folder",
    "atomic_outputs",
    "atomic_write",
    "atomic_write_text",
    "check_writable",
    "dump_yaml",
    "json_dumps",
    "live_outputs",
    "need_file",
    "read_text",
    "read_yaml",
]


def check_writable(path: Path) -> None:
    """Refuse, before any work is done, an output that could not be written.

    Parameters
    ----------
    path : Path
        The intended output; it need not exist.

    Raises
    ------
    OutputError
        If the nearest existing folder above ``path`` is a file, or a folder this
        process may not write in.
    """
    p = Path(path).absolute()
    for above in p.parents:
        if above.exists():
            if not above.is_dir():
                raise OutputError(f"cannot write: {above} is a file, not a folder", path=path)
            if not os.access(above, os.W_OK | os.X_OK):
                raise OutputError(f"cannot write: no permission in {above}", path=path)
            return


@contextlib.contextmanager
def atomic_outputs(*paths: Path, keep_suffix: bool = False) -> Iterator[list[Path]]:
    """Yield temporary paths for ``paths``; rename them all into place on success.

    Parameters
    ----------
    *paths : Path
        The destinations. Missing parent folders are created.
    keep_suffix : bool, default False
        If true the temporary names end like their destinations (for writers that
        choose the format by the file name); otherwise they end in ``.tmp``.

    Yields
    ------
    list of Path
        One temporary path per destination, in the same order, each beside its
        destination with the usual umask-based mode.

    Raises
    ------
    OutputError
        Before anything is written, if a destination is a directory or a place that
        cannot be written. On any exception in the block the temporary files are
        removed and no destination is touched.
    """
    for p in paths:
        if p.is_dir():
            raise OutputError("is a directory; give a file name", path=p)
    temps: list[Path] = []
    try:
        for p in paths:
            with _as_output_error(p.parent):
                p.parent.mkdir(parents=True, exist_ok=True)
            suffix = p.suffix if keep_suffix else ".tmp"
            with _as_output_error(p):
                fd, name = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=suffix, dir=p.parent)
            os.close(fd)
            # mkstemp makes owner-only files; outputs get the usual umask-based mode.
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(name, 0o666 & ~umask)
            temps.append(Path(name))
        yield temps
        for t, p in zip(temps, paths, strict=True):
            with _as_output_error(p):
                os.replace(t, p)
    except BaseException:
        for t in temps:
            t.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def _as_output_error(path: Path) -> Iterator[None]:
    """Turn the operating system's refusal to write ``path`` into an OutputError."""
    try:
        yield
    except OSError as err:
        if isinstance(err, OutputError):
            raise
        check_writable(path)  # names a file in the way, or a folder without permission
        raise OutputError(f"cannot write ({err.strerror or err})", path=path) from err


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_outputs`).

    Parameters
    ----------
    path : Path
        The destination file.
    text : str
        Its whole content, encoded with the locale's default encoding.
    """
    with atomic_outputs(path) as (tmp,):
        tmp.write_text(text)


def atomic_write(path: Path, writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and move the file it wrote to ``path``.

    Parameters
    ----------
    path : Path
        The destination file.
    writer : callable
        Writes the whole output to the temporary path it is given.
    """
    with atomic_outputs(path) as (tmp,):
        writer(tmp)


@contextlib.contextmanager
def atomic_folder(path: Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``path`` whose files move into ``path`` on success.

    Parameters
    ----------
    path : Path
        The destination folder, created if needed; files already there and not
        written again are kept.

    Yields
    ------
    Path
        The temporary folder. On success every file written under it is moved to the
        same relative place under ``path``; on an exception it is all deleted, and so
        are the parent folders this call created (a failed run leaves nothing behind).

    Raises
    ------
    OutputError
        If ``path`` is a file, or its parent cannot be written.
    """
    if path.exists() and not path.is_dir():
        raise OutputError("is a file; give a folder", path=path)
    made = [p for p in [path.parent, *path.parent.parents] if not p.exists()]
    with _as_output_error(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for folder in made:  # deepest first; one another job filled since stays
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    for src in sorted(tmp.rglob("*")):
        if src.is_file():
            dst = path / src.relative_to(tmp)
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)
    shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def live_outputs(folder: Path) -> Iterator[list[Path]]:
    """Track the files a long job writes straight into ``folder`` as it goes.

    The files can then be looked at while the job runs; the job writes each one
    atomically itself.

    Parameters
    ----------
    folder : Path
        Where the job writes.

    Yields
    ------
    list of Path
        A list to which the job appends every file it writes. If the block raises,
        those files are removed, and so are the folders that did not exist when the
        block began, leaving what was there before.

    Raises
    ------
    OutputError
        If ``folder`` is a file.
    """
    if folder.exists() and not folder.is_dir():
        raise OutputError("is a file; give a folder", path=folder)
    created = [d for d in (folder, *folder.parents) if not d.exists()]
    written: list[Path] = []
    try:
        yield written
    except BaseException:
        for f in written:
            f.unlink(missing_ok=True)
        for d in created:  # deepest first
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


def need_file(path: str | Path, what: str = "file") -> Path:
    """Check that ``path`` names a regular file before a reader opens it.

    Parameters
    ----------
    path : str or Path
        The input.
    what : str, default "file"
        What the file is, for the error message.

    Returns
    -------
    Path
        ``path`` as a Path.

    Raises
    ------
    InputError
        Saying whether nothing or a directory is there.
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(f"is a directory; expected a {what}", path=p)
    if not p.is_file():
        raise InputError("no such file", path=p)
    return p


def read_text(path: str | Path, what: str = "file") -> str:
    """The text of a file, or one :class:`InputError` naming it.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str, default "file"
        What the file is, for the error message.

    Raises
    ------
    InputError
        If the file cannot be read or is not text.
    """
    p = Path(path)
    try:
        return p.read_text()
    except OSError as err:
        raise InputError(f"cannot read {what} ({err.strerror or err})", path=p) from err
    except UnicodeDecodeError as err:
        raise InputError(f"{what} is not text ({err.reason})", path=p) from err


class _Dumper(yaml.SafeDumper):
    """The safe dumper, also quoting strings in exponent form such as ``2e1``."""


# PyYAML's YAML 1.1 reads ``2e1`` (no dot) as a string, yaml-cpp (map_server) as a
# number: quoted, a name "2e1" reads back a string in both.
_Dumper.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def dump_yaml(data: Any) -> str:
    """``data`` as YAML text, keys in their order, that :func:`read_yaml` reads back equal.

    Strings that a YAML 1.2 reader such as yaml-cpp would take for numbers (``2e1``)
    are quoted, so other readers see the same strings.

    Parameters
    ----------
    data : Any
        Plain data: mappings, lists, strings, numbers, booleans, None.

    Returns
    -------
    str
    """
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False)


def read_yaml(path: str | Path, what: str = "file") -> Any:
    """Parse a YAML file with PyYAML's safe loader (YAML 1.1).

    Values such as ``1e-3`` (no dot) are strings in YAML 1.1; the number checks
    (:func:`sonarmap.checks.as_number`) accept numeric strings, so they read as
    numbers where a number is expected and stay strings (names, paths) elsewhere.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str, default "file"
        What the file is, for the error message.

    Returns
    -------
    Any
        The parsed document (``None`` for an empty file).

    Raises
    ------
    InputError
        If the file cannot be read, is not text, or is not valid YAML; the message
        gives the line of a syntax error.
    """
    p = Path(path)
    text = read_text(p, what)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        problem = getattr(err, "problem", None) or type(err).__name__
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"not valid YAML ({problem}{where})", path=p) from err


def _clean(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def json_dumps(data: Any) -> str:
    """Strict JSON text for ``data``, indented by two spaces.

    Parameters
    ----------
    data : Any
        Dicts (keys turned into strings), lists, tuples, numpy scalars and plain
        values.

    Returns
    -------
    str
        Standard JSON: NaN and infinities become ``null``, numpy scalars plain
        numbers.
    """
    return json.dumps(_clean(data), indent=2, allow_nan=False)
