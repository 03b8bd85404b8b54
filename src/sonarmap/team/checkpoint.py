"""A node's checkpoint file and the lock on its state folder (issue 38).

The file is a msgpack map (never pickle) around the state's own msgpack bytes::

    {"format": "sonarmap node state", "v": 2, "sha256": hex digest, "state": bytes}

:func:`write_state` writes it to a temporary file, fsyncs it, renames it into place and
fsyncs the folder, so a crash or a full disk leaves the previous checkpoint whole; a
write that fails is one :class:`~sonarmap.errors.OutputError`. :func:`read_state`
checks the format, the version and the checksum before anything is decoded: a damaged
file is one :class:`~sonarmap.errors.InputError` (the node does not resume from it, and
leaves it as it is). :class:`StateLock` holds an exclusive ``flock`` on the folder's
``lock`` file while a node runs, so a second process on the same folder (the same robot
started twice) fails at once with one line; the kernel releases it when the process
dies, however it dies.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import os
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import msgpack

from ..errors import InputError, OutputError
from ..files import atomic_write
from .records import UnpackError, unpack_strict

__all__ = ["LOCK_FILE", "STATE_FORMAT", "STATE_VERSION", "StateLock", "read_state", "write_state"]

#: The file's ``format``.
STATE_FORMAT = "sonarmap node state"
#: The file's version ``v`` (1: the bare state, with no checksum).
STATE_VERSION = 2
#: The lock's file name in a state folder.
LOCK_FILE = "lock"


def _pack(d: Any) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_state(path: Path, state: bytes) -> None:
    """Write the state's msgpack bytes as a checkpoint at ``path``, durably.

    Raises
    ------
    OutputError
        The file cannot be written (no space, no permission...): one line; the previous
        checkpoint, if any, is left whole.
    """
    path = Path(path)
    data = _pack(
        {
            "format": STATE_FORMAT,
            "v": STATE_VERSION,
            "sha256": hashlib.sha256(state).hexdigest(),
            "state": state,
        }
    )

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())

    try:
        atomic_write(path, write)
        _fsync_folder(path.parent)
    except OutputError as e:
        raise OutputError(f"cannot write the checkpoint ({e.reason})", path=path) from None
    except OSError as e:
        why = e.strerror or str(e)
        raise OutputError(
            f"cannot write the checkpoint ({why}); the previous one is kept", path=path
        ) from None


def read_state(path: Path) -> Any:
    """The state a checkpoint at ``path`` holds, decoded (msgpack); :class:`InputError`
    naming the file if it is damaged, of another format or version, or unreadable."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read the checkpoint: {e.strerror or e}", path=path) from None
    n = len(data)
    try:
        d = unpack_strict(data, max_bin=n, max_str=64, max_array=8, max_map=8)
    except UnpackError:
        d = None
    if not isinstance(d, dict) or d.get("format") != STATE_FORMAT:
        raise InputError(
            "not a node checkpoint, or a damaged one (delete the state folder to start over)",
            path=path,
        )
    if d.get("v") != STATE_VERSION:
        raise InputError(
            f"a node checkpoint of version {d.get('v')!r}, this sonarmap reads {STATE_VERSION}",
            path=path,
        )
    state, digest = d.get("state"), d.get("sha256")
    if not isinstance(state, bytes) or hashlib.sha256(state).hexdigest() != digest:
        raise InputError(
            "the checkpoint is damaged (its SHA-256 does not match); it is left as it is",
            path=path,
        )
    try:
        return unpack_strict(state, max_bin=n, max_str=n, max_array=n, max_map=n)
    except UnpackError as e:
        raise InputError(f"cannot decode the checkpoint's state: {e}", path=path) from None


class StateLock:
    """An exclusive lock on a state folder for as long as it is held (``with``).

    Parameters
    ----------
    folder : Path
        The state folder (created if needed).
    owner : str
        Who holds it, as the message to a second process names it (e.g. "robot 1").

    Raises
    ------
    InputError
        On entry, if another process holds the folder: one line naming ``owner``.
    """

    def __init__(self, folder: Path, owner: str) -> None:
        self.folder = Path(folder)
        self.owner = owner
        self._fd: int | None = None

    def __enter__(self) -> Self:
        path = self.folder / LOCK_FILE
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise OutputError(
                f"cannot lock the state folder ({e.strerror or e})", path=path
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            held = os.read(fd, 200).decode(errors="replace").strip()
            os.close(fd)
            if e.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise OutputError(
                    f"cannot lock the state folder ({e.strerror})", path=path
                ) from None
            raise InputError(
                f"the state folder is in use by {held or 'another process'}: {self.owner} "
                "started twice? (each robot id runs once, on its own state folder)",
                path=self.folder,
            ) from None
        # Who holds it, for the message a second process gets.
        os.ftruncate(fd, 0)
        os.write(fd, f"{self.owner} (process {os.getpid()})".encode())
        self._fd = fd
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._fd is not None:
            os.close(self._fd)  # releases the lock
            self._fd = None
