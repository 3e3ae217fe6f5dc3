"""Zenoh's own log lines (Rust ``tracing``) in our log, for the router's refusals.

zenoh-python can only print the library's log to the process's standard output
(:func:`zenoh.init_log_from_env_or`); it has no bridge to Python's :mod:`logging`. The
router therefore points file descriptor 1 at a pipe, keeps Python's ``sys.stdout`` on
the original output, and a thread turns each Zenoh line into a record of the
``bipedtele.zenoh`` logger. Lines that say a session was refused become one INFO line
with the reason and, where Zenoh reported it, the peer's address:

- user/password refused: Zenoh logs ``Invalid user`` / ``Invalid password`` without the
  address, just after the link layer logged the accepted connection with it on the same
  thread: the address is taken from there;
- TLS refusals (no client certificate, certificate from another CA, the client did not
  accept ours): Zenoh's TLS listener logs the reason but not the address.

The filter enables only the few modules that say this (connection accepted, handshake
refused, ACL subject not matched) plus every warning; ``RUST_LOG``, when set, replaces it.
See docs/network.md.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import threading
import time
from typing import IO

import zenoh

__all__ = ["ROUTER_LOG_FILTER", "ZenohLogBridge", "parse_line"]

LOG = logging.getLogger("bipedtele.zenoh")

ROUTER_LOG_FILTER = ",".join(
    [
        "warn",
        "zenoh_link_tcp::unicast=debug",
        "zenoh_link_tls::unicast=debug",
        "zenoh_transport::unicast::establishment::accept=debug",
        "zenoh::net::routing::interceptor::access_control=info",
    ]
)

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_LINE = re.compile(
    r"^\S+\s+(?P<level>TRACE|DEBUG|INFO|WARN|ERROR)\s+(?:(?P<thread>\S+)\s+)?ThreadId\(\d+\)\s+"
    r"(?P<target>[\w:]+):\s(?P<msg>.*)$"
)
_SRC = re.compile(r"\s+at \S+\.rs:\d+\.?$")
_ACCEPTED = re.compile(r"Accepted (?:TCP|TLS) connection on \S+: (?P<peer>\S+?)(?:\.\s+(?P<id>.*?))?\.?$")
_HINT = ". Hint: increase the system open file limit."
_LEVELS = {
    "TRACE": logging.DEBUG,
    "DEBUG": logging.DEBUG,
    "INFO": logging.INFO,
    "WARN": logging.WARNING,
    "ERROR": logging.ERROR,
}

_TLS_REASONS = (
    ("peer sent no certificates", "no client certificate presented (the router requires mutual TLS)"),
    ("invalid peer certificate", "client certificate not signed by this router's CA"),
    ("UnknownCA", "the client does not trust this router's CA (its tls_root_ca is another CA)"),
    ("BadCertificate", "the client rejected this router's certificate (it does not name the host the client dialled?)"),
    ("DecryptError", "the client rejected this router's certificate (it does not trust this router's CA?)"),
    ("CertificateExpired", "a certificate is expired"),
)


def parse_line(line: str) -> tuple[int, str, str, str] | None:
    """``(level, thread, target, message)`` of one Zenoh log line, or None."""
    m = _LINE.match(_ANSI.sub("", line).rstrip())
    if m is None:
        return None
    msg = _SRC.sub("", m["msg"]).replace(_HINT, "")
    return _LEVELS[m["level"]], m["thread"] or "", m["target"], msg


class ZenohLogBridge:
    """Routes Zenoh's log to :mod:`logging`; refusals become clear INFO lines.

    Start it once, before the first Zenoh session, in a process whose standard output is
    not needed by anything but Python's ``sys.stdout`` (the router).

    Attributes
    ----------
    refusals : int
        Sessions refused so far (user/password or TLS).
    """

    def __init__(self) -> None:
        self.refusals = 0
        self._peers: dict[str, tuple[str, str, float]] = {}  # thread -> (peer, identity, when)
        self._thread: threading.Thread | None = None

    def start(self, filter_: str = ROUTER_LOG_FILTER) -> ZenohLogBridge:
        """Redirect fd 1 into the bridge and initialise Zenoh's log with ``filter_``."""
        sys.stdout.flush()
        saved = os.dup(1)
        rfd, wfd = os.pipe()
        os.dup2(wfd, 1)
        os.close(wfd)
        sys.stdout = open(saved, "w", buffering=1, encoding="utf-8", closefd=True)  # noqa: SIM115
        reader = open(rfd, encoding="utf-8", errors="replace")  # noqa: SIM115
        self._thread = threading.Thread(target=self._pump, args=(reader,), name="zenoh-log", daemon=True)
        self._thread.start()
        os.environ.setdefault("NO_COLOR", "1")
        zenoh.init_log_from_env_or(filter_)
        return self

    def _pump(self, reader: IO[str]) -> None:
        for line in reader:
            try:
                self.handle(line)
            except Exception:  # a log line must never end the router
                LOG.debug("unparsed zenoh log line: %r", line)

    def handle(self, line: str) -> None:
        """Turn one Zenoh log line into zero or one of our records."""
        parsed = parse_line(line)
        if parsed is None:
            if line.strip():
                LOG.info("%s", _ANSI.sub("", line).rstrip())
            return
        level, thread, target, msg = parsed
        if target.startswith(("zenoh_link_tcp", "zenoh_link_tls")):
            m = _ACCEPTED.search(msg)
            if m is not None:
                self._peers[thread] = (m["peer"], m["id"] or "", time.monotonic())
                LOG.debug("link from %s %s", m["peer"], m["id"] or "")
                return
            if target.startswith("zenoh_link_tls") and level >= logging.WARNING:
                why = next((text for needle, text in _TLS_REASONS if needle in msg), msg)
                self.refusals += 1
                LOG.info("refused a TLS connection: %s [zenoh: %s; Zenoh does not report the peer's address]", why, msg)
                return
        if target.endswith("establishment::accept") and "UsrPwd" in msg:
            peer, ident, when = self._peers.pop(thread, ("", "", 0.0))
            who = f" from {peer}" if peer and time.monotonic() - when < 5.0 else ""
            ident = f" ({ident})" if who and ident and ident != "None" else ""
            why = "unknown user" if "Invalid user" in msg else "wrong password" if "Invalid password" in msg else msg
            self.refusals += 1
            LOG.info("refused a session%s%s: user/password refused: %s", who, ident, why)
            return
        if "did not match any configured ACL subject" in msg:
            zid = msg.split(" ", 1)[0]
            LOG.info(
                "session %s has no ACL role (not in publishers_allowed or followers_allowed): it may do nothing", zid
            )
            return
        LOG.log(level if level >= logging.WARNING else logging.DEBUG, "%s: %s", target, msg)
