"""Why a client cannot reach its router: a short check before the Zenoh session opens.

A Zenoh client that is refused sees only "Unable to connect ... Timeout!", whatever the
cause. Before opening its session, a client checks each endpoint with the standard
library, as far as DNS, TCP and TLS let it know, and says which failure it is:

- ``unresolved``: the host name does not resolve;
- ``refused`` / ``unreachable``: nothing listens there, or no route / no answer;
- ``tls_unknown_ca``: the router's certificate is not signed by ``tls_root_ca``;
- ``tls_name``: the router's certificate does not name the host dialled (e.g. dialled
  by IP address when the certificate names only a DNS name);
- ``tls_expired``: the router's certificate is expired or not yet valid;
- ``tls_client_cert``: the router refused this client's certificate (mutual TLS: none
  presented, or not signed by the router's CA);
- ``not_tls``: the endpoint does not speak TLS.

When every check passes and Zenoh still cannot open the session, the router refused the
session itself: the user/password (see :func:`bipedtele.link.transport.open_session`).

In TLS 1.3 a client finishes its handshake before the server has checked the client's
certificate; the server's refusal arrives as an alert just after. So after the handshake
the check waits a few round trips for such an alert (a router sends nothing else before
the client speaks). See docs/network.md.
"""

from __future__ import annotations

import contextlib
import socket
import ssl
import threading
import time
from dataclasses import dataclass
from typing import Any

__all__ = ["EndpointCheck", "LinkError", "check_endpoint", "split_endpoint"]

#: Longest wait for a name lookup, a TCP connection or a TLS handshake [s].
STEP_TIMEOUT_S = 3.0
#: Wait for the router's verdict on our client certificate: this many round trips...
ALERT_WAIT_RTTS = 2.0
#: ...within these bounds [s].
ALERT_WAIT_MIN_S, ALERT_WAIT_MAX_S = 0.2, 1.0

# OpenSSL verify codes (X509_V_ERR_*)
_UNKNOWN_CA = {2, 18, 19, 20, 21, 27, 30}
_NAME = {62, 63, 64}
_EXPIRED = {9, 10}


class LinkError(RuntimeError):
    """The network link to the router could not be set up (not a configuration error).

    The message is one line saying which failure it is and what to check. The CLI prints
    it and exits with code 1.

    Attributes
    ----------
    kind : str
        ``unresolved``, ``refused``, ``unreachable``, ``tls_unknown_ca``, ``tls_name``,
        ``tls_expired``, ``tls_client_cert``, ``not_tls``, ``tls``, ``credentials``
        (the router refused the session after TLS), ``links`` (the router accepted the login
        on one link, the session's links did not open) or ``open`` (Zenoh failed otherwise).
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class EndpointCheck:
    """The result of :func:`check_endpoint`.

    Attributes
    ----------
    endpoint : str
        The endpoint checked.
    kind : str
        ``ok`` or a :class:`LinkError` kind.
    detail : str
        What failed, in words (empty when ok).
    rtt_s : float
        Longest round trip seen (TCP connect or TLS handshake) [s]; 0 when unknown.
    """

    endpoint: str
    kind: str
    detail: str = ""
    rtt_s: float = 0.0

    @property
    def ok(self) -> bool:
        """Whether the link came up."""
        return self.kind == "ok"


def split_endpoint(endpoint: str) -> tuple[str, str, int] | None:
    """``(proto, host, port)`` of a ``PROTO/HOST:PORT`` endpoint, or None if it has no port.

    Zenoh's endpoint options (``#...``) and metadata (``?...``) are ignored; IPv6 hosts
    are written ``[addr]``.
    """
    proto, _, rest = endpoint.partition("/")
    rest = rest.split("#", 1)[0].split("?", 1)[0]
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return proto, host.strip("[]"), int(port)


def _resolve(host: str, port: int, timeout_s: float) -> list[tuple[int, tuple[object, ...]]] | str:
    """Addresses of ``host`` (family, sockaddr), or a reason string; bounded in time."""
    out: list[list[Any] | OSError] = []

    def lookup() -> None:
        try:
            out.append(socket.getaddrinfo(host, port, type=socket.SOCK_STREAM))
        except OSError as exc:
            out.append(exc)

    t = threading.Thread(target=lookup, name="linkcheck-dns", daemon=True)
    t.start()
    t.join(timeout_s)
    if not out:
        return f"the name lookup of {host!r} did not finish within {timeout_s:g} s"
    res = out[0]
    if isinstance(res, OSError):
        return f"the name {host!r} does not resolve ({getattr(res, 'strerror', None) or res})"
    return [(fam, addr) for fam, _, _, _, addr in res]


def _connect(
    addrs: list[tuple[int, tuple[object, ...]]], timeout_s: float
) -> tuple[socket.socket, float] | tuple[str, str]:
    """Return a connected socket and the connect time [s], or ``(kind, detail)``."""
    kind, detail = "unreachable", "no address"
    for fam, addr in addrs:
        s = socket.socket(fam, socket.SOCK_STREAM)
        s.settimeout(timeout_s)
        t0 = time.monotonic()
        try:
            s.connect(addr)
            return s, time.monotonic() - t0
        except ConnectionRefusedError:
            kind, detail = (
                "refused",
                f"connection refused by {addr[0]}:{addr[1]} (is the router running and listening there?)",
            )
        except TimeoutError:
            kind, detail = (
                "unreachable",
                f"no answer from {addr[0]}:{addr[1]} within {timeout_s:g} s (host down, or a firewall drops the packets)",
            )
        except OSError as exc:
            kind, detail = "unreachable", f"{addr[0]}:{addr[1]} is unreachable ({exc.strerror or exc})"
        s.close()
    return kind, detail


def _tls_context(root_ca: str, cert: str, key: str) -> ssl.SSLContext:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # verifies the chain and the host name
    if root_ca:
        ctx.load_verify_locations(root_ca)
    else:
        ctx.load_default_certs()
    if cert and key:
        ctx.load_cert_chain(cert, key)
    return ctx


def _classify_verify(exc: ssl.SSLCertVerificationError, host: str) -> tuple[str, str]:
    code, msg = exc.verify_code, exc.verify_message
    if code in _UNKNOWN_CA:
        return "tls_unknown_ca", (
            f"TLS: the router's certificate is signed by a CA we do not trust ({msg}); "
            "check network.tls_root_ca: it must be the ca.pem that signed the router's certificate"
        )
    if code in _NAME:
        return "tls_name", (
            f"TLS: the router's certificate does not name {host!r}, the host dialled ({msg}); "
            "dial the router by a name in its certificate (the ROUTER_NAME given to make-certs.sh) "
            "or make a certificate that names this host or IP"
        )
    if code in _EXPIRED:
        return "tls_expired", f"TLS: the router's certificate is not valid now ({msg}); check both clocks or renew it"
    return "tls", f"TLS: the router's certificate was rejected ({msg})"


def _classify_alert(exc: ssl.SSLError, has_cert: bool) -> tuple[str, str]:
    reason = (exc.reason or str(exc)).lower()
    if "certificate_required" in reason or not has_cert:
        return "tls_client_cert", (
            "TLS: the router requires a client certificate (mutual TLS) and we presented none; "
            "set network.tls_cert and network.tls_key"
        )
    return "tls_client_cert", (
        f"TLS: the router refused our client certificate ({exc.reason or exc}); it must be signed by the "
        "router's CA (network.tls_cert, network.tls_key from the same make-certs.sh run)"
    )


def _tls_check(
    sock: socket.socket, host: str, root_ca: str, cert: str, key: str, timeout_s: float, rtt_s: float
) -> tuple[str, str, float]:
    """TLS handshake and wait for a refusal alert: ``(kind, detail, handshake time)``."""
    try:
        ctx = _tls_context(root_ca, cert, key)
    except (OSError, ssl.SSLError) as exc:
        return "tls", f"TLS: cannot load the CA or client certificate ({exc})", 0.0
    sock.settimeout(timeout_s)
    t0 = time.monotonic()
    try:
        tls = ctx.wrap_socket(sock, server_hostname=host)
    except ssl.SSLCertVerificationError as exc:
        return (*_classify_verify(exc, host), 0.0)
    except ssl.SSLError as exc:
        reason = (exc.reason or "").lower()
        if "wrong_version" in reason or "record_layer" in reason or "packet_length" in reason:
            return "not_tls", "the endpoint does not speak TLS (a tcp/ router dialled as tls/?)", 0.0
        if "alert" in reason:
            return (*_classify_alert(exc, bool(cert)), 0.0)
        return "tls", f"TLS handshake failed ({exc.reason or exc})", 0.0
    except TimeoutError:
        return "tls", f"TLS: no handshake within {timeout_s:g} s (is it a Zenoh router?)", 0.0
    except OSError as exc:
        return (
            "tls",
            f"TLS: the connection broke during the handshake ({exc.strerror or exc}); the router may require a client certificate",
            0.0,
        )
    handshake = time.monotonic() - t0
    wait = min(ALERT_WAIT_MAX_S, max(ALERT_WAIT_MIN_S, ALERT_WAIT_RTTS * max(rtt_s, handshake)))
    try:
        tls.settimeout(wait)
        data = tls.recv(1)
        if not data:
            return (
                "tls_client_cert",
                (
                    "TLS: the router closed the connection right after the handshake: it refused our client "
                    "certificate (network.tls_cert, tls_key)"
                ),
                handshake,
            )
    except TimeoutError:
        pass  # the router waits for us to speak: the TLS link is accepted
    except ssl.SSLError as exc:
        return (*_classify_alert(exc, bool(cert)), handshake)
    except OSError:
        pass  # reset after we stop: says nothing about the certificate
    finally:
        with contextlib.suppress(OSError):
            tls.close()
    return "ok", "", handshake


def check_endpoint(
    endpoint: str,
    *,
    root_ca: str = "",
    cert: str = "",
    key: str = "",
    timeout_s: float = STEP_TIMEOUT_S,
) -> EndpointCheck:
    """Check that a router endpoint resolves, accepts TCP and (``tls/``) our TLS.

    Parameters
    ----------
    endpoint : str
        ``tcp/HOST:PORT`` or ``tls/HOST:PORT`` (other protocols are not checked: ok).
    root_ca, cert, key : str
        The CA file that must sign the router's certificate, and this client's
        certificate and key (mutual TLS), as in ``[network]``.
    timeout_s : float
        Longest wait of each step (lookup, connect, handshake) [s].

    Returns
    -------
    EndpointCheck
        ``kind`` is ``ok`` or one of :class:`LinkError`'s kinds. Never raises for
        network errors.
    """
    parts = split_endpoint(endpoint)
    if parts is None or parts[0] not in ("tcp", "tls"):
        return EndpointCheck(endpoint, "ok")
    proto, host, port = parts
    addrs = _resolve(host, port, timeout_s)
    if isinstance(addrs, str):
        kind = "unresolved" if "does not resolve" in addrs else "unreachable"
        return EndpointCheck(endpoint, kind, addrs)
    got = _connect(addrs, timeout_s)
    if isinstance(got[0], str):
        return EndpointCheck(endpoint, got[0], str(got[1]))
    sock, rtt = got
    assert isinstance(sock, socket.socket) and isinstance(rtt, float)
    try:
        if proto != "tls":
            return EndpointCheck(endpoint, "ok", rtt_s=rtt)
        kind, detail, handshake = _tls_check(sock, host, root_ca, cert, key, timeout_s, rtt)
        return EndpointCheck(endpoint, kind, detail, max(rtt, handshake))
    finally:
        sock.close()
