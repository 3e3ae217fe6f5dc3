"""The router's log of links lost while their session stays up (a forged or undecodable datagram?).

A Zenoh session between a client and the router ends as a whole: all its links close
together. With ``[network] links = "split"`` one of them is plain UDP, and Zenoh's UDP
link has no authentication of its own: an undecodable datagram with a client's address as
its source makes the router drop that client's UDP link (control then moves onto a TLS
link), and a forged Close to the client's UDP port ends the client's side of the session
while the router keeps the UDP link. Either leaves the session with some of its links:
:class:`RouterLinkLog` logs that, once per client per ``log_every_s``, with what it means.
The client notices too and reopens its session (:mod:`bipedtele.link.relink`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

__all__ = ["RouterLinkLog"]

LOG = logging.getLogger("bipedtele.tools.router")


def _proto(link: Any) -> str:
    return str(link.dst).partition("/")[0]


class RouterLinkLog:
    """Logs the links a router's clients lose while their sessions stay up.

    Parameters
    ----------
    session : zenoh.Session
        The router's session.
    settle_s : float
        How long after a link closes its client's other links are looked at [s]: a
        session that ends closes all of them within it, and a client that lost a link
        reopens its session not much later (then nothing is left to see).
    log_every_s : float
        At most one line per client per this long [s].
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        settle_s: float = 0.3,
        log_every_s: float = 5.0,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self._session = session
        self.settle_s = settle_s
        self.log_every_s = log_every_s
        self._mono = monotonic
        self._lock = threading.Lock()
        self._lost: dict[str, list[str]] = {}  # client zid -> protocols of the links it lost
        self._last: dict[str, float] = {}
        self.lines = 0
        self._listener = session.info.declare_link_events_listener(self._on_link, history=False)

    def _on_link(self, event: Any) -> None:
        if event.kind != zenoh.SampleKind.DELETE:
            return
        zid = str(event.link.zid)
        with self._lock:
            first = zid not in self._lost
            self._lost.setdefault(zid, []).append(_proto(event.link))
        if first:
            timer = threading.Timer(self.settle_s, self._judge, args=(zid,))
            timer.daemon = True
            timer.start()

    def _judge(self, zid: str) -> None:
        with self._lock:
            lost = self._lost.pop(zid, [])
        try:
            left = [_proto(link) for link in self._session.info.links() if str(link.zid) == zid]
        except zenoh.ZError:
            return
        if not left or not lost:
            return  # the session ended (or nothing to say)
        now = self._mono()
        if now - self._last.get(zid, -float("inf")) < self.log_every_s:
            return
        self._last[zid] = now
        self.lines += 1
        if "udp" in lost:
            why = (
                "the router dropped it on a datagram it could not decode or a Close on UDP: an unauthenticated "
                "packet with the client's address? Its control moves onto TLS until it reopens its session"
            )
        else:
            why = (
                "the client closed them: a Close sent to its UDP port with the router's address (an "
                "unauthenticated packet?) or a lost path; it reopens its session"
            )
        LOG.warning(
            "client %s lost its %s link(s) while its %s link(s) stay up: %s",
            zid,
            "+".join(sorted(set(lost))),
            "+".join(sorted(set(left))),
            why,
        )

    def close(self) -> None:
        """Stop listening."""
        with contextlib.suppress(zenoh.ZError):
            self._listener.undeclare()

    def __enter__(self) -> RouterLinkLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
