"""A WebSocket relay that lets clients reach the live server under either protocol name.

The Foxglove WebSocket protocol is named ``foxglove.websocket.v1`` in its spec and
``foxglove.sdk.v1`` by ``foxglove-sdk``, whose server takes only the new name (every
release; no option) and answers HTTP 400 to a client offering only the old one, as
older Foxglove Studio and ``@foxglove/ws-protocol`` clients do. Both names denote the
same protocol, so :class:`Relay` listens where the user asked, accepts a client under
either name, connects to the SDK's server (on a loopback port of its own) under the
name it takes, and passes every text and binary frame through unchanged both ways.

The relay neither parses nor speaks the protocol: the SDK's server answers every
message. It only forwards frames, and closes one side when the other closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from typing import Final

from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.frames import EXTERNAL_CLOSE_CODES, CloseCode
from websockets.typing import Subprotocol

__all__ = ["SUBPROTOCOLS", "UPSTREAM_SUBPROTOCOL", "Relay", "listen"]

#: The name ``foxglove-sdk``'s server takes.
UPSTREAM_SUBPROTOCOL: Final = Subprotocol("foxglove.sdk.v1")
#: Names a client may offer, the first offered one chosen: the SDK's names before the
#: spec's, so a client offering both is answered under the name the server speaks.
SUBPROTOCOLS: Final = (
    UPSTREAM_SUBPROTOCOL,
    Subprotocol("foxglove.sdk.v1.1"),
    Subprotocol("foxglove.websocket.v1"),
)
#: Largest message passed on, bytes: a 2000 x 2000 map is 4 MB; room for larger ones.
MAX_MESSAGE: Final = 64 * 2**20
#: Messages held per connection and direction before reading waits (back-pressure).
MAX_QUEUE: Final = 8


def listen(host: str, port: int) -> socket.socket:
    """Bind and listen on ``host:port`` now, so that a taken port fails at once.

    Parameters
    ----------
    host : str
        Address or name to bind.
    port : int
        TCP port, 0 for any free one.

    Returns
    -------
    socket.socket
        A listening socket.

    Raises
    ------
    OSError
        The address is unknown or the port is taken.
    """
    family, _, _, _, address = socket.getaddrinfo(
        host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
    )[0]
    return socket.create_server(address[:2], family=family)


def _close_code(code: int | None) -> int:
    """The code to close the other side with: the one received when it may be sent
    (1005, 1006 only say that none came or the connection broke), else 1000."""
    if code is not None and (code in EXTERNAL_CLOSE_CODES or 3000 <= code < 5000):
        return code
    return int(CloseCode.NORMAL_CLOSURE)


async def _pipe(
    src: ServerConnection | ClientConnection, dst: ServerConnection | ClientConnection
) -> None:
    """Send on ``dst`` every message from ``src`` until ``src`` closes; the iteration
    ends with the connection, and each send waits for ``dst`` to take it."""
    with contextlib.suppress(ConnectionClosed):
        async for message in src:
            await dst.send(message)


class Relay:
    """Forward WebSocket connections on a listening socket to ``upstream``, in a thread.

    Parameters
    ----------
    sock : socket.socket
        Listening socket (see :func:`listen`); the relay owns it from now on.
    upstream : str
        ``ws://`` URL of the server that speaks the protocol.
    timeout : float
        Seconds allowed to start, to connect upstream, and to stop.

    Raises
    ------
    RuntimeError
        The relay did not start within ``timeout``.
    """

    def __init__(self, sock: socket.socket, upstream: str, *, timeout: float = 5.0) -> None:
        self.upstream = upstream
        self.timeout = timeout
        self.port = int(sock.getsockname()[1])
        self._sock = sock
        self._loop = asyncio.new_event_loop()
        self._stop = asyncio.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="sonarmap-relay", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout) or self._error is not None:
            self.close()
            raise RuntimeError(f"the WebSocket relay did not start ({self._error})")

    def _run(self) -> None:
        try:
            self._loop.run_until_complete(self._main())
        finally:
            self._loop.close()

    async def _main(self) -> None:
        try:
            server = await serve(
                self._forward,
                sock=self._sock,
                subprotocols=list(SUBPROTOCOLS),
                max_size=MAX_MESSAGE,
                max_queue=MAX_QUEUE,
                # Frames pass as they come: compressing them again costs time for maps.
                compression=None,
            )
        except BaseException as err:
            self._error = err
            self._sock.close()
            raise
        finally:
            self._ready.set()
        await self._stop.wait()
        await self._shut(server)

    async def _shut(self, server: Server) -> None:
        server.close()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(server.wait_closed(), self.timeout / 2)
        # Handlers still running (a peer that does not answer the close) end here.
        rest = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for task in rest:
            task.cancel()
        if rest:
            await asyncio.wait(rest, timeout=self.timeout / 4)

    async def _forward(self, client: ServerConnection) -> None:
        try:
            upstream = await connect(
                self.upstream,
                subprotocols=[UPSTREAM_SUBPROTOCOL],
                max_size=MAX_MESSAGE,
                max_queue=MAX_QUEUE,
                compression=None,
                open_timeout=self.timeout,
            )
        except Exception as err:  # not listening, too slow, or refused the handshake
            await client.close(CloseCode.INTERNAL_ERROR, f"live server: {err}"[:120])
            return
        tasks = [
            asyncio.create_task(_pipe(client, upstream)),
            asyncio.create_task(_pipe(upstream, client)),
        ]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.wait(tasks, timeout=self.timeout)
            # Whichever side closed first, the other is closed with its code.
            first, second = (
                (client, upstream) if client.close_code is not None else (upstream, client)
            )
            await second.close(_close_code(first.close_code), first.close_reason or "")
            await first.close()

    def close(self) -> None:
        """Close every connection, stop the thread and wait for it (``timeout`` s)."""
        if self._loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):  # the loop has just ended
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(self.timeout)
