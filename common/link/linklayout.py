"""Which Zenoh links carry which traffic: one link, or control, status and video apart.

Over one reliable TCP/TLS connection a lost segment stalls everything behind it (commands,
feedback, clock, status, video) for a retransmission at the path's real round trip, and a
video frame in the send buffer delays the feedback behind it. Zenoh 1.x can open several
links to its router in one session and pick a link per message from its priority and
reliability (endpoint metadata ``?prio=A-B;rel=0|1``). ``[network] links`` chooses:

``single``
    The endpoints as written: one link (what a TCP relay such as ``bipedtele delay-proxy``
    can carry).
``split``
    For each ``tls/HOST:PORT`` (``tcp/HOST:PORT``) endpoint three links to the same router:

    * **control** ``udp/HOST:PORT?prio=1-2;rel=0``: commands, feedback and clock pings,
      published best effort at real-time priority, travel as plain UDP datagrams, never
      retransmitted and never held back by a congestion window: a lost one costs one
      sample, the next one is newer anyway. They are not encrypted (Zenoh has no TLS for
      UDP); the end-to-end HMAC with the per-session key (``message_key_file``) keeps them
      authentic and unreplayable, and the login and the router's ACL hold as on every link;
    * **status** ``tls/HOST:PORT?prio=0-4;rel=1``: status, declarations, presence;
    * **video** ``tls/HOST:PORT?prio=5-7;rel=1#so_sndbuf=N``: video frames, with a small
      kernel send buffer so that a slow uplink's backlog stays in Zenoh's queue, where
      the video publisher's drop-on-congestion discards it, not in the kernel.

    The router listens on ``udp/ADDR:PORT`` beside each ``tls/ADDR:PORT`` (``tcp``).
    Measured on the packet emulator (docs/links.md): QUIC datagrams (``quic/...?rel=0``,
    encrypted) were tried first and rejected: QUIC's congestion control holds datagrams
    back after a loss, so at 1 % loss on the intercontinental trace h1 p50 rose from 192
    to 405 ms with 11 watchdog stops in 90 s; on UDP it stays at 186 ms with none.
``split-tcp``
    Where only TCP passes a firewall: the same three links, the control one a
    ``tls``/``tcp`` connection of its own with a small send buffer (a lost segment
    still stalls control for a retransmission, but never behind video or status).

User/password and the router's ACL apply to every link (each link runs the session's
handshake); mutual TLS to the status and video links. docs/links.md has the measurements
behind the choice.
"""

from __future__ import annotations

from typing import Any, Final, Literal

__all__ = [
    "CONTROL_PRIORITIES",
    "CONTROL_SNDBUF_BYTES",
    "LAYOUTS",
    "MAX_LINKS",
    "STATUS_PRIORITIES",
    "VIDEO_PRIORITIES",
    "VIDEO_SNDBUF_BYTES",
    "Layout",
    "client_endpoints",
    "router_listen_endpoints",
]

Layout = Literal["single", "split", "split-tcp"]
LAYOUTS: Final = ("single", "split", "split-tcp")

#: Zenoh priorities (1 = real time ... 7 = background; 0 = Zenoh's own control) per link.
CONTROL_PRIORITIES: Final = "1-2"
STATUS_PRIORITIES: Final = "0-4"
VIDEO_PRIORITIES: Final = "5-7"
#: The video link's kernel send buffer [bytes] (Linux doubles it). At the intercontinental
#: round trip (about 0.4 s) it still lets about 2.5 Mbit/s of video through, and at a
#: 300 kbit/s uplink it holds at most about 3 s, which the follower's budget keeps empty.
VIDEO_SNDBUF_BYTES: Final = 65536
#: The control link's send buffer in ``split-tcp`` [bytes]: a few feedback messages.
CONTROL_SNDBUF_BYTES: Final = 4096

#: Most links one client opens to its router (``transport/unicast/max_links``).
MAX_LINKS: Final = 4

_DATAGRAM = {"tls": "udp", "tcp": "udp"}


def _split(endpoint: str) -> tuple[str, str, str]:
    """Return (protocol, address, config) of ``PROTO/ADDR[?meta][#config]`` (metadata dropped)."""
    proto, _, rest = endpoint.partition("/")
    rest, _, config = rest.partition("#")
    address = rest.partition("?")[0]
    return proto, address, config


def _join(proto: str, address: str, meta: str, config: str = "") -> str:
    return f"{proto}/{address}?{meta}" + (f"#{config}" if config else "")


def _with(config: str, key: str, value: int) -> str:
    parts = [p for p in config.split(";") if p and not p.startswith(f"{key}=")]
    return ";".join(sorted([*parts, f"{key}={value}"]))


def client_endpoints(connect: list[str], layout: Layout) -> list[Any]:
    """Return the ``connect/endpoints`` value of a client for ``layout``.

    Parameters
    ----------
    connect : list of str
        The profile's endpoints (``tls/router.example.org:7447``).
    layout : {"single", "split", "split-tcp"}
        See the module docstring.

    Returns
    -------
    list
        ``connect`` unchanged for ``single`` or for endpoints other than tcp/tls;
        otherwise, for each endpoint, one Zenoh ``allOf`` group of its three links (a
        client connects to one group: all of its links, to one router).
    """
    if layout == "single":
        return list(connect)
    out: list[Any] = []
    for ep in connect:
        proto, address, config = _split(ep)
        if proto not in _DATAGRAM:
            out.append(ep)
            continue
        if layout == "split":
            control = _join(_DATAGRAM[proto], address, f"prio={CONTROL_PRIORITIES};rel=0")
        else:
            control = _join(
                proto, address, f"prio={CONTROL_PRIORITIES};rel=0", _with(config, "so_sndbuf", CONTROL_SNDBUF_BYTES)
            )
        links = [
            _join(proto, address, f"prio={STATUS_PRIORITIES};rel=1", config),
            control,
            _join(proto, address, f"prio={VIDEO_PRIORITIES};rel=1", _with(config, "so_sndbuf", VIDEO_SNDBUF_BYTES)),
        ]
        out.append({"strategy": "allOf", "locators": links})
    return out


def router_listen_endpoints(listen: list[str], layout: Layout) -> list[str]:
    """Return a router's listen endpoints for ``layout``: a datagram listener beside each tcp/tls one.

    ``split`` adds ``udp/ADDR:PORT`` for each ``tls/ADDR:PORT`` or ``tcp/ADDR:PORT``,
    the same port number on UDP; ``single`` and ``split-tcp`` need no other
    listener. A router with the extra listener still serves single-link clients.
    """
    out = list(listen)
    if layout != "split":
        return out
    for ep in listen:
        proto, address, _ = _split(ep)
        if proto in _DATAGRAM:
            extra = f"{_DATAGRAM[proto]}/{address}"
            if extra not in out:
                out.append(extra)
    return out
