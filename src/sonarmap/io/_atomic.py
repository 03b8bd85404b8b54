"""Write files so that a failure leaves no half-written output.

Each output is written to a temporary file beside its destination and renamed into
place only when every output of the operation has been written.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from ..errors import OutputError

__all__ = [
    "atomic_folder",
    "atomic_outputs",
    "atomic_write_text",
    "check_writable",
    "live_outputs",
]


def check_writable(path: Path) -> None:
    """Refuse, before any work is done, an output that could not be written: the
    nearest existing folder above it must be a folder this process may write in."""
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

    On an exception the temporary files are removed and no destination is touched; a
    destination that is a directory, or a place that cannot be written, is an
    :class:`~sonarmap.errors.OutputError` before anything is written. With
    ``keep_suffix`` the temporary names end like their destinations (for writers that
    choose the format by the file name).
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
    """Write ``text`` to ``path`` atomically."""
    with atomic_outputs(path) as (tmp,):
        tmp.write_text(text)


def atomic_write(path: Path, writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and move the result to ``path``."""
    with atomic_outputs(path) as (tmp,):
        writer(tmp)


@contextlib.contextmanager
def atomic_folder(path: Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success move every file written
    there into ``path`` (created if needed), on an exception delete it all."""
    if path.exists() and not path.is_dir():
        raise OutputError("is a file; give a folder", path=path)
    with _as_output_error(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for src in sorted(tmp.rglob("*")):
        if src.is_file():
            dst = path / src.relative_to(tmp)
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)
    shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def live_outputs(folder: Path) -> Iterator[list[Path]]:
    """For files a long job writes straight into ``folder`` as it goes, so they can be
    looked at while it runs (each one written atomically by the job).

    Yields a list to which the job appends every file it writes. If the block raises,
    those files are removed, and so are the folders this call created, leaving what was
    there before.
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
