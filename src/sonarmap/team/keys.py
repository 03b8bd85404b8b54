"""A team's key (issue 38): the CURVE key pairs that admit a robot to its team over
ZeroMQ, one per robot id.

A team key file holds one CURVE key pair (ZeroMQ's Curve25519, z85 text) per robot id
0..N-1, as JSON::

    {"v": 1, "kind": "sonarmap team key", "robots": [{"id": 0, "public": "...",
     "secret": "..."}, ...]}

It is written owner-only (mode 0600). A node given the file encrypts every connection
with CURVE and admits only a peer that proves it holds one of the file's secret keys;
that key, not the routing identity the peer picks, says which robot it is (see
:class:`~.transport.ZmqTransport`). Every robot's secret is in the one file: whoever
holds it can join the team as any robot. It keeps out everyone else.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import zmq
from zmq.utils import z85

from ..errors import ConfigError, InputError
from ..files import atomic_write

__all__ = [
    "KEY_KIND",
    "KEY_VERSION",
    "ZAP_DOMAIN",
    "KeyGate",
    "TeamKey",
    "make_team_key",
    "read_team_key",
]

#: The file's ``kind``.
KEY_KIND = "sonarmap team key"
#: The file's version, ``v``.
KEY_VERSION = 1
#: Characters of a z85 CURVE key.
_Z85_LENGTH = 40
#: Robots one key file may hold at most.
_MAX_ROBOTS = 4096


@dataclass(frozen=True)
class TeamKey:
    """Each robot's CURVE key pair (z85 bytes), by robot id 0..N-1."""

    public: Mapping[int, bytes]
    secret: Mapping[int, bytes]

    def __post_init__(self) -> None:
        if sorted(self.public) != list(range(len(self.public))) or set(self.secret) != set(
            self.public
        ):
            raise ConfigError("team key: one key pair per robot id 0..N-1 expected")

    @property
    def robots(self) -> int:
        """Robots the key admits (ids 0..robots-1)."""
        return len(self.public)

    def robot_of(self, public: bytes) -> int | None:
        """The robot whose public key (z85) this is; None for a stranger's."""
        for robot, key in self.public.items():
            if key == public:
                return robot
        return None

    def write(self, path: Path) -> None:
        """Write the key file, owner-only (mode 0600), atomically."""
        doc = {
            "v": KEY_VERSION,
            "kind": KEY_KIND,
            "robots": [
                {"id": i, "public": self.public[i].decode(), "secret": self.secret[i].decode()}
                for i in range(self.robots)
            ],
        }
        text = json.dumps(doc, indent=1) + "\n"

        def write(tmp: Path) -> None:
            # Owner-only before the secret is in it.
            os.chmod(tmp, 0o600)
            with open(tmp, "w") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())

        atomic_write(Path(path), write)


def make_team_key(robots: int) -> TeamKey:
    """A new team key for robots 0..robots-1 (fresh CURVE key pairs from libsodium)."""
    if isinstance(robots, bool) or not isinstance(robots, int) or not 1 <= robots <= _MAX_ROBOTS:
        raise ConfigError(f"team key: robots must be an int in 1..{_MAX_ROBOTS}, got {robots!r}")
    if not zmq.has("curve"):
        raise ConfigError("team key: this libzmq has no CURVE security")
    pairs = [zmq.curve_keypair() for _ in range(robots)]
    return TeamKey(
        {i: p for i, (p, _) in enumerate(pairs)}, {i: s for i, (_, s) in enumerate(pairs)}
    )


def _z85_key(v: object, where: str, path: Path) -> bytes:
    if not isinstance(v, str) or len(v) != _Z85_LENGTH or not v.isascii():
        raise InputError(f"{where}: a {_Z85_LENGTH}-character z85 key expected", path=path)
    try:
        z85.decode(v)
    except (ValueError, KeyError, IndexError, TypeError):
        raise InputError(f"{where}: not z85 text", path=path) from None
    return v.encode()


def read_team_key(path: Path) -> TeamKey:
    """The team key in ``path``; :class:`InputError` naming the file if it is not one,
    or if others than its owner may read it."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except OSError as e:
        raise InputError(f"cannot read the team key: {e.strerror or e}", path=path) from None
    if mode & 0o077:
        raise InputError(
            f"the team key is readable by others (mode {mode & 0o777:o}): chmod 600 it",
            path=path,
        )
    try:
        doc = json.loads(text)
    except ValueError:
        raise InputError("not a team key (not JSON)", path=path) from None
    if not isinstance(doc, dict) or doc.get("kind") != KEY_KIND:
        raise InputError(f"not a team key (kind is not {KEY_KIND!r})", path=path)
    if doc.get("v") != KEY_VERSION:
        raise InputError(f"team key version {doc.get('v')!r}, expected {KEY_VERSION}", path=path)
    rows = doc.get("robots")
    if not isinstance(rows, list) or not 0 < len(rows) <= _MAX_ROBOTS:
        raise InputError(f"robots: a list of 1..{_MAX_ROBOTS} key pairs expected", path=path)
    public: dict[int, bytes] = {}
    secret: dict[int, bytes] = {}
    for k, row in enumerate(rows):
        where = f"robots[{k}]"
        if not isinstance(row, dict) or set(row) != {"id", "public", "secret"}:
            raise InputError(f"{where}: id, public and secret expected", path=path)
        if row["id"] != k or isinstance(row["id"], bool):
            raise InputError(f"{where}: id {row['id']!r}, expected {k}", path=path)
        public[k] = _z85_key(row["public"], f"{where}.public", path)
        secret[k] = _z85_key(row["secret"], f"{where}.secret", path)
        if zmq.curve_public(secret[k]) != public[k]:
            raise InputError(f"{where}: the public key is not the secret's", path=path)
    if len(set(public.values())) != len(public):
        raise InputError("two robots have the same key", path=path)
    return TeamKey(public, secret)


#: The ZAP domain a keyed socket asks its gate about.
ZAP_DOMAIN = b"sonarmap"
_ZAP_ENDPOINT = "inproc://zeromq.zap.01"
_ZAP_VERSION = b"1.0"


class KeyGate(threading.Thread):
    """ZeroMQ's authentication handler (ZAP, RFC 27) for a team key, on one context.

    Admits a CURVE handshake whose client key is one of the team's public keys and
    gives the connection that robot's id (decimal) as its User-Id, which every message
    received on it carries (``zmq.Frame.get("User-Id")``); denies any other (counted in
    :attr:`denied`). One gate per context: ZAP has one endpoint per context.

    Parameters
    ----------
    context : zmq.Context
    key : TeamKey
    """

    def __init__(self, context: zmq.Context[zmq.Socket[bytes]], key: TeamKey) -> None:
        super().__init__(daemon=True, name="sonarmap-zap")
        self.key = key
        #: Handshakes denied so far (a stranger's key, or not CURVE).
        self.denied = 0
        self._halt = threading.Event()
        self._sock: zmq.Socket[bytes] = context.socket(zmq.REP)
        self._sock.setsockopt(zmq.LINGER, 0)
        try:
            self._sock.bind(_ZAP_ENDPOINT)
        except zmq.ZMQError as e:
            self._sock.close(linger=0)
            raise ConfigError(f"team key: this context has a ZAP handler already ({e})") from None

    def run(self) -> None:
        sock = self._sock
        try:
            while not self._halt.is_set():
                if sock.poll(100, zmq.POLLIN):
                    sock.send_multipart(self._answer(sock.recv_multipart()))
        except zmq.ZMQError:
            pass  # the context is ending
        finally:
            sock.close(linger=0)

    def _answer(self, request: list[bytes]) -> list[bytes]:
        rid = request[1] if len(request) > 1 else b""
        if len(request) != 7 or request[0] != _ZAP_VERSION or request[5] != b"CURVE":
            self.denied += 1
            return [_ZAP_VERSION, rid, b"400", b"a team key's CURVE handshake expected", b"", b""]
        robot = self.key.robot_of(z85.encode(request[6]))
        if robot is None:
            self.denied += 1
            return [_ZAP_VERSION, rid, b"400", b"not a key of this team", b"", b""]
        return [_ZAP_VERSION, rid, b"200", b"OK", str(robot).encode(), b""]

    def stop(self) -> None:
        """End the handler (before its context is terminated)."""
        self._halt.set()
        if self.is_alive():
            self.join(timeout=2.0)
        else:
            self._sock.close(linger=0)
