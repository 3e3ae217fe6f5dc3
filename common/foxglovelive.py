"""The live view: the recording's channels served on a Foxglove WebSocket while the run goes.

``bipedtele leader --foxglove 127.0.0.1:8765`` (and the follower; ``[record] foxglove``)
starts a Foxglove WebSocket server (the ``foxglove-sdk`` package, extra ``foxglove``) and
the run's :class:`~bipedtele.recording.Recorder` hands every message it encodes to it as
well as to the MCAP file: the same topics, the same JSON Schemas and the same JSON
payloads as the recording (docs/recording.md), so a layout made on a recording works live.
Open Foxglove, *Open connection*, ``ws://HOST:PORT``.

The server runs in the SDK's own threads; :meth:`LiveView.log` only queues a message
there (never blocks on a client). Messages are logged with their recording time.
"""

from __future__ import annotations

import logging
from typing import Any

__all__ = ["LiveView", "parse_address"]

LOG = logging.getLogger("bipedtele.foxglove")


def parse_address(text: str) -> tuple[str, int]:
    """Return ``(host, port)`` of ``[HOST:]PORT`` (host 127.0.0.1 when left out).

    Raises
    ------
    ValueError
        Not ``[HOST:]PORT`` with a port in 0-65535 (0: any free port).
    """
    host, sep, port = text.rpartition(":")
    host = host.strip("[]") if sep else "127.0.0.1"
    try:
        n = int(port)
    except ValueError:
        n = -1
    if not host or not 0 <= n <= 65535:
        raise ValueError(f"{text!r}: allowed: [HOST:]PORT with a port 0-65535 (0: any free port)")
    return host, n


class LiveView:
    """A Foxglove WebSocket server fed with the recorder's channels.

    Parameters
    ----------
    host : str
        Listen address (``127.0.0.1``: this machine only).
    port : int
        TCP port (0: any free port; see :attr:`port`).
    name : str
        Server name shown in Foxglove.

    Raises
    ------
    ModuleNotFoundError
        ``foxglove-sdk`` is not installed (``pip install 'bipedtele[foxglove]'``).
    RuntimeError
        The server cannot listen (the port is taken).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, name: str = "bipedtele") -> None:
        import foxglove

        self._fg: Any = foxglove
        self._context = foxglove.Context()
        self._server: Any = foxglove.start_server(name=name, host=host, port=port, context=self._context)
        self._channels: dict[int, Any] = {}
        self.host = host
        self.logged = 0
        LOG.info("foxglove live view on ws://%s:%d (Foxglove: Open connection)", host, self.port)

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port) if self._server is not None else 0

    def add_channel(self, cid: int, topic: str, schema_name: str, schema_encoding: str, schema: bytes) -> None:
        """Advertise channel ``cid`` (the recorder's id) on ``topic`` with its JSON Schema."""
        fg = self._fg
        self._channels[cid] = fg.Channel(
            topic, schema=fg.Schema(name=schema_name, encoding=schema_encoding, data=schema),
            message_encoding="json", context=self._context,
        )  # fmt: skip

    def log(self, cid: int, payload: bytes, log_time_ns: int) -> None:
        """Send one JSON payload on channel ``cid`` to the subscribed clients."""
        channel = self._channels.get(cid)
        if channel is not None:
            channel.log(payload, log_time=log_time_ns)
            self.logged += 1

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if self._server is not None:
            self._server.stop()
            self._server = None
