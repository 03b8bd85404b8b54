"""A run served live over the Foxglove WebSocket protocol (the ``--live`` option).

:class:`LiveSink` is a :class:`~sonarmap.io.record.Sink`: it serves the messages a bag
would hold, on the same topics and in the same ROS 2 types (CDR bytes, ``ros2msg``
schemas), through the Foxglove SDK's WebSocket server (``foxglove-sdk``), so that
Foxglove (``Open connection``, ``ws://127.0.0.1:8765``) draws them as they come.

Choices:

- **Pace.** A simulation runs far faster than real time; a viewer would see only its
  end. The sink holds each message until ``t / rate`` wall seconds after the first
  (``rate`` simulated seconds per wall second), which paces the loop that publishes.
  A run that falls behind the pace by more than half a second (kernels compiling, a
  slow step) is not hurried to catch up: the pace starts again from there.
- **Late viewers.** The protocol keeps no message for a client that subscribes later,
  and a territory is published once. So the sink sends again the latest message of
  every topic not published for ``refresh`` wall seconds (2), with its own time stamp:
  a viewer that connects at any moment has every topic within that time.
- **Channels early.** The publishers declare their topics before the run's set-up
  (:meth:`LiveSink.declare`), so a viewer that connects is offered them in one
  advertisement rather than one by one as they first carry a message: the SDK's server
  can refuse a subscription that arrives just as its channel is advertised.
- **Where.** The server binds ``127.0.0.1`` unless told otherwise; the run's own
  :class:`foxglove.Context` keeps its channels apart from any other in the process.
- **Both protocol names.** The SDK's server takes only the subprotocol
  ``foxglove.sdk.v1``; clients that follow the protocol's spec offer only
  ``foxglove.websocket.v1``, the same protocol. So the SDK's server listens on a
  loopback port of its own, and a relay (:mod:`sonarmap.io.relay`) on the port asked
  for accepts either name and forwards frames unchanged both ways. The SDK's server
  remains the one that speaks the protocol; the relay parses nothing.
"""

from __future__ import annotations

import math
import time
from typing import Any

from ..errors import ConfigError
from .relay import Relay, listen
from .rosmsg import msgdef, serialize

__all__ = ["DEFAULT_PORT", "LiveSink"]

#: Foxglove's default WebSocket port.
DEFAULT_PORT = 8765


class LiveSink:
    """Serve a run's messages over the Foxglove WebSocket protocol while it goes.

    Parameters
    ----------
    port : int
        TCP port, 0 for any free one (:attr:`port` says which); default 8765. A client
        there may offer ``foxglove.sdk.v1`` or ``foxglove.websocket.v1``.
    host : str
        Address to bind; default ``127.0.0.1`` (this machine only).
    rate : float or None
        Simulated seconds per wall second the run is held to (> 0); None: no pacing.
    refresh : float
        Wall seconds after which a topic's latest message is sent again (> 0).
    name : str
        The server's name, shown by Foxglove.

    Raises
    ------
    ConfigError
        A rate or refresh that is not > 0, a port outside 0-65535.
        Also when the server cannot listen there (the port is taken, say).
    """

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        *,
        host: str = "127.0.0.1",
        rate: float | None = 1.0,
        refresh: float = 2.0,
        name: str = "sonarmap",
    ) -> None:
        if rate is not None and not (math.isfinite(rate) and rate > 0):
            raise ConfigError(f"live rate must be > 0 simulated seconds per second, got {rate}")
        if not (math.isfinite(refresh) and refresh > 0):
            raise ConfigError(f"refresh must be > 0 seconds, got {refresh}")
        if not 0 <= port <= 65535:
            raise ConfigError(f"live port must be in 0-65535, got {port}")
        import foxglove

        try:
            # Bound here, before anything starts, so that a taken port is one error now.
            sock = listen(host, port)
        except OSError as err:
            raise ConfigError(
                f"cannot serve on {host}:{port} ({err}); try another --live-port",
                field="live_port",
            ) from err
        self._foxglove = foxglove
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=name, host="127.0.0.1", port=0, context=self._context
            )
        except Exception as err:  # the SDK raises its own error types
            sock.close()
            raise ConfigError(f"cannot start the live server ({err})", field="live_port") from err
        try:
            self._relay = Relay(sock, f"ws://127.0.0.1:{int(self._server.port)}")
        except RuntimeError as err:
            self._server.stop()
            raise ConfigError(f"cannot serve on {host}:{port} ({err})", field="live_port") from err
        self.host = host
        self.port = self._relay.port
        self.rate = rate
        self.refresh = refresh
        #: Wall seconds behind the pace after which the pace starts again from now.
        self.slack = 0.5
        self.n_messages = 0
        self._channels: dict[str, Any] = {}
        # topic -> (wall time sent, bytes, log time ns)
        self._latest: dict[str, tuple[float, bytes, int]] = {}
        self._start: tuple[float, float] | None = None
        self._closed = False

    @property
    def url(self) -> str:
        """Where Foxglove connects."""
        return f"ws://{self.host}:{self.port}"

    def _channel(self, topic: str, msgtype: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            schema = self._foxglove.Schema(
                name=msgtype, encoding="ros2msg", data=msgdef(msgtype).encode()
            )
            ch = self._foxglove.Channel(
                topic, schema=schema, message_encoding="cdr", context=self._context
            )
            self._channels[topic] = ch
        return ch

    def declare(self, topic: str, msgtype: str) -> None:
        """Advertise ``topic`` now. A viewer that subscribes to a channel in the same
        moment the server advertises it can be refused (foxglove-sdk 0.30: "unknown
        channel"); channels made before it connects come in its first advertisement."""
        self._channel(topic, msgtype)

    def wait_until(self, t: float) -> None:
        """Hold the caller until simulated time ``t`` is due on the wall clock (no wait
        without a rate), sending stale topics again meanwhile."""
        now = time.perf_counter()
        if self._start is None:
            self._start = (now, t)
        if self.rate is None:
            return
        due = self._start[0] + (t - self._start[1]) / self.rate
        if now - due > self.slack:
            # Behind (kernels compiling, a slow step): keep the pace from here on rather
            # than rush through the run to catch up.
            self._start = (now, t)
            return
        while (left := due - time.perf_counter()) > 0:
            time.sleep(min(left, 0.2))
            self._send_stale()

    def publish(self, topic: str, msgtype: str, msg: Any, t: float) -> None:
        self.wait_until(t)
        data = serialize(msg, msgtype)
        stamp = max(0, round(t * 1e9))
        self._channel(topic, msgtype).log(data, log_time=stamp)
        self._latest[topic] = (time.perf_counter(), data, stamp)
        self.n_messages += 1
        self._send_stale()

    def _send_stale(self) -> None:
        now = time.perf_counter()
        for topic, (sent, data, stamp) in list(self._latest.items()):
            if now - sent >= self.refresh:
                self._channels[topic].log(data, log_time=stamp)
                self._latest[topic] = (now, data, stamp)

    def close(self) -> None:
        """Stop the relay, then the server (once)."""
        if self._closed:
            return
        self._closed = True
        self._relay.close()
        self._server.stop()
