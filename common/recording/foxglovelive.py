"""The live view: the recording's channels served on a Foxglove WebSocket while the run goes.

``bipedtele leader --foxglove 127.0.0.1:8765`` (and the follower; ``[record] foxglove``)
starts a Foxglove WebSocket server (:mod:`bipedtele.recording.foxglovews`, extra ``foxglove``) and
the run's :class:`~bipedtele.recording.recorder.Recorder` hands every message it encodes to it as
well as to the MCAP file: the same topics, the same JSON Schemas and the same JSON
payloads as the recording (docs/recording.md), so a layout made on a recording works live.

It is guarded like the cockpit: a per-run token, printed once
(``foxglove live view on ws://127.0.0.1:8765/?token=TOKEN``; Foxglove, *Open connection*,
that address), Host and Origin checks, and a bind on loopback only unless
``--allow-remote`` (``[record] foxglove_allow_remote``) says otherwise: a non-loopback
address without it is refused in one line (:func:`check_bind`).

The server runs in its own thread; :meth:`LiveView.log` only queues a message there
(never blocks on a client). Messages are logged with their recording time.
"""

from __future__ import annotations

import ipaddress
import logging
import secrets
from typing import Any

__all__ = ["LiveView", "check_bind", "parse_address"]

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


def _loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind(address: tuple[str, int], allow_remote: bool) -> tuple[str, int]:
    """Return ``address`` if the live view may listen there.

    Raises
    ------
    ValueError
        A non-loopback address (another machine could watch the robot) without
        ``allow_remote``: one line naming both ways out.
    """
    host, port = address
    if not allow_remote and not _loopback(host):
        raise ValueError(
            f"{host}:{port}: not a loopback address (the network could watch the robot); allowed: "
            "127.0.0.1, localhost or ::1, or another address with --allow-remote "
            "(record.foxglove_allow_remote = true; the token still guards it)"
        )
    return address


class LiveView:
    """A guarded Foxglove WebSocket server fed with the recorder's channels.

    Parameters
    ----------
    host : str
        Listen address (``127.0.0.1``: this machine only).
    port : int
        TCP port (0: any free port; see :attr:`port`).
    name : str
        Server name shown in Foxglove.
    allow_remote : bool
        Allow a non-loopback ``host`` (:func:`check_bind`).
    token : str, optional
        The access token (a random one, ``secrets.token_urlsafe(24)``, when omitted).

    Raises
    ------
    ModuleNotFoundError
        aiohttp is not installed (``pip install 'bipedtele[foxglove]'``).
    ValueError
        A non-loopback ``host`` without ``allow_remote``.
    OSError
        The server cannot listen (the port is taken).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        name: str = "bipedtele",
        allow_remote: bool = False,
        token: str | None = None,
    ) -> None:
        from bipedtele.recording.foxglovews import LiveServer

        check_bind((host, port), allow_remote)
        self.token = token or secrets.token_urlsafe(24)
        self._server: Any = LiveServer(host, port, name, self.token)
        self.host = host
        self.logged = 0
        shown = f"[{host}]" if ":" in host else host
        LOG.info(
            "foxglove live view on ws://%s:%d/?token=%s (Foxglove: Open connection, this address)",
            shown,
            self.port,
            self.token,
        )
        if not _loopback(host):
            LOG.warning(
                "foxglove live view: listening on %s (--allow-remote): anyone with the token on the network "
                "can watch the robot",
                host,
            )

    @property
    def url(self) -> str:
        """The address to open in Foxglove (``ws://HOST:PORT/?token=TOKEN``)."""
        shown = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{shown}:{self.port}/?token={self.token}"

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port) if self._server is not None else 0

    @property
    def counters(self) -> dict[str, int]:
        """Refusals by reason (``refused_token``, ``refused_origin``, ...), clients ``served``, frames ``dropped``."""
        return dict(self._server.counters) if self._server is not None else {}

    def add_channel(self, cid: int, topic: str, schema_name: str, schema_encoding: str, schema: bytes) -> None:
        """Advertise channel ``cid`` (the recorder's id) on ``topic`` with its JSON Schema."""
        if self._server is not None:
            self._server.add_channel(
                {
                    "id": cid,
                    "topic": topic,
                    "encoding": "json",
                    "schemaName": schema_name,
                    "schema": schema.decode("utf-8"),
                    "schemaEncoding": schema_encoding,
                }
            )

    def log(self, cid: int, payload: bytes, log_time_ns: int) -> None:
        """Send one JSON payload on channel ``cid`` to the subscribed clients."""
        if self._server is not None:
            self._server.publish(cid, payload, log_time_ns)
            self.logged += 1

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if self._server is not None:
            self._server.stop()
            self._server = None
