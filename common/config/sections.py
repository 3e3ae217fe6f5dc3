"""The core's configuration sections: robot identity, network, clock, control, recording.

The leader and follower register their own sections (``[leader]``, ``[follower]``,
``[world]``) through the ``bipedtele.config.profile`` entry-point group.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from bipedtele.config.fields import param
from bipedtele.control.config import ControlConfig

__all__ = ["CORE_SECTIONS", "ROLE_LISTS", "ClockConfig", "NetworkConfig", "RecordConfig", "RobotConfig"]

_ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True)
class RobotConfig:
    """Which robot this profile talks to."""

    id: str = param("nao1", doc="robot id: the <robot_id> in key expressions bipedtele/<robot_id>/...")

    def __post_init__(self) -> None:
        if not _ROBOT_ID.match(self.id):
            raise ValueError(f"id = {self.id!r}: allowed: 1-64 characters of letters, digits, '_' or '-'")


#: The router's role lists (``[network]``), one role per user.
ROLE_LISTS = ("publishers_allowed", "followers_allowed", "observers_allowed")


@dataclass(frozen=True)
class NetworkConfig:
    """Zenoh session settings (see docs/network.md).

    Endpoints are Zenoh locators such as ``tcp/127.0.0.1:7447`` or ``tls/host:7447``.
    Multicast scouting is off by default: endpoints are always explicit.

    One profile can serve all three roles: each reads only its own settings. A router
    (``mode = "router"``, or ``bipedtele router``) reads ``listen``, the TLS server
    certificate, ``credentials_file`` and the ACL lists, and ignores the client login
    (``user``, ``password``, ``password_file``, ``message_key_file``); a client or peer
    reads ``connect``, its TLS certificate, ``user`` and ``password``/``password_file``
    and ignores ``credentials_file`` and the role lists (``ROLE_LISTS``).
    """

    mode: Literal["peer", "client", "router"] = param("peer", doc="Zenoh session mode")
    connect: list[str] = param(default_factory=list, doc="endpoints to connect to")
    listen: list[str] = param(default_factory=list, doc="endpoints to listen on")
    multicast_scouting: bool = param(False, doc="enable UDP multicast discovery")
    tls_root_ca: str = param("", path=True, doc="PEM file of the CA that signs the router's certificate")
    tls_cert: str = param(
        "",
        path=True,
        doc="PEM certificate of this process (the router's server certificate, or a client's for mutual TLS)",
    )
    tls_key: str = param("", path=True, doc="PEM private key matching tls_cert")
    tls_mutual: bool = param(False, doc="require and present client certificates")
    user: str = param("", doc="clients: user name for Zenoh user/password authentication")
    password: str = param("", secret=True, doc="clients: password (prefer password_file)")
    password_file: str = param("", path=True, doc="clients: file holding the password")
    message_key_file: str = param(
        "",
        path=True,
        doc="clients: file of 64 hex characters (a 32-byte key, mode 0600) shared by leader and "
        "follower: every message is signed (HMAC-SHA256) and must be; empty = off",
    )
    credentials_file: str = param(
        "", path=True, doc="router only: file of 'user:password' lines accepted by the router"
    )
    publishers_allowed: list[str] = param(
        default_factory=list,
        doc="router only: users with the leader role (may publish commands): 'user' (every robot) or "
        "'user@robot_id' (that robot only; repeat for more); with followers_allowed, turns on the deny-by-default ACL",
    )
    followers_allowed: list[str] = param(
        default_factory=list,
        doc="router only: users with the follower role (may publish feedback, video): 'user' (as any robot) or "
        "'user@robot_id' (as that robot only); with publishers_allowed, turns on the deny-by-default ACL",
    )
    observers_allowed: list[str] = param(
        default_factory=list,
        doc="router only: users with the observer role (receive video and status, put nothing): 'user' "
        "(every robot) or 'user@robot_id' (that robot only)",
    )
    routers_allowed: list[str] = param(
        default_factory=list,
        doc="router only: certificate common names of the other sites' routers linked to this one "
        "(router-<site>): they pass everything under bipedtele/** both ways (bipedtele setup sites)",
    )
    tls_user_certs: bool = param(
        False,
        doc="router only: each user's certificate names the user (CN = user): a role holds only for a session whose certificate names its user (setup fleet/sites)",
    )
    revoked: list[str] = param(
        default_factory=list, doc="router only: people refused (user and certificate name): no login, no role"
    )
    router_user: str = param("", doc="router only: user name of this router's login to the routers of connect")
    router_password_file: str = param("", path=True, doc="router only: file holding the password of router_user")
    watch_key_dir: str = param(
        "",
        path=True,
        doc="observers: folder of watch keys '<robot_id>.watch' (setup fleet writes them): verify the robots' "
        "video and status; leader and follower derive theirs from message_key_file",
    )
    timeout_s: float = param(10.0, lo=0.1, hi=600.0, unit="s", doc="session open timeout")
    links: Literal["single", "split", "split-tcp"] = param(
        "single",
        doc="single: one link per endpoint; split: control as UDP datagrams, status and video "
        "on links of their own (router: also listens on UDP); split-tcp: the same on TCP only "
        "(docs/network.md)",
    )

    def __post_init__(self) -> None:
        for ep in [*self.connect, *self.listen]:
            proto, sep, rest = ep.partition("/")
            if not sep or proto not in ("tcp", "tls", "udp", "quic", "ws", "unixsock-stream") or not rest:
                raise ValueError(f"endpoint {ep!r}: allowed: PROTO/HOST:PORT with PROTO in tcp, tls, udp, quic, ws")
        if bool(self.tls_cert) != bool(self.tls_key):
            raise ValueError("tls_cert and tls_key: allowed: both set or both empty")
        if self.password and self.password_file:
            raise ValueError("password and password_file: allowed: at most one of them")
        for key in ROLE_LISTS:
            for entry in getattr(self, key):
                user, at, robot = entry.partition("@")
                if not user or (at and not _ROBOT_ID.match(robot)):
                    raise ValueError(
                        f"{key}: {entry!r}: allowed: 'user' or 'user@robot_id' (robot id: 1-64 letters, digits, '_', '-')"
                    )
        seen: dict[str, str] = {}
        for key in ROLE_LISTS:
            for user in dict.fromkeys(e.partition("@")[0] for e in getattr(self, key)):
                if user in seen:
                    raise ValueError(
                        f"user {user!r} is in {seen[user]} and {key}: allowed: each user in at most one role"
                    )
                seen[user] = key


@dataclass(frozen=True)
class ClockConfig:
    """How each side estimates one-way delays and checks send times (see docs/network.md)."""

    mode: Literal["synced", "ntp"] = param(
        "synced", doc="synced: one clock (same host, chrony/PTP); ntp: ping exchange estimates the offset"
    )
    delay_window_s: float = param(1.0, lo=0.01, hi=60.0, unit="s", doc="moving-average window of the delay estimators")
    ping_rate_hz: float = param(4.0, lo=0.1, hi=100.0, unit="Hz", doc="ntp mode: ping rate")
    ping_window: int = param(16, lo=1, hi=1024, doc="ntp mode: pings kept for min-RTT filtering")
    conservative_split: bool = param(
        True,
        doc="ntp mode: use h1 = h2 = round trip for the stability conditions (the split is unknown)",
    )
    max_future_s: float = param(
        0.25,
        lo=0.001,
        hi=10.0,
        unit="s",
        doc="a received message stamped more than this ahead of the local clock (after ntp "
        "conversion) is dropped (counted as 'future')",
    )
    answer_rate_hz: float = param(
        20.0, lo=1.0, hi=1000.0, unit="Hz", doc="most clock pings answered per second (excess dropped)"
    )


@dataclass(frozen=True)
class RecordConfig:
    """MCAP recording of every message sent and received."""

    enabled: bool = param(True, doc="write an MCAP file per run")
    dir: str = param("runs", doc="folder for recordings")
    flush_s: float = param(1.0, lo=0.05, hi=10.0, unit="s", doc="flush period (max data lost on a crash)")
    foxglove: str = param(
        "",
        doc="[HOST:]PORT: also serve the recording's channels live on a Foxglove WebSocket (extra foxglove); empty: off",
    )
    foxglove_allow_remote: bool = param(
        False, doc="let the live view listen on a non-loopback address (--allow-remote)"
    )

    def __post_init__(self) -> None:
        if self.foxglove:
            from bipedtele.recording.foxglovelive import check_bind, parse_address

            check_bind(parse_address(self.foxglove), self.foxglove_allow_remote)  # ValueError naming what is allowed


CORE_SECTIONS: dict[str, type] = {
    "robot": RobotConfig,
    "network": NetworkConfig,
    "clock": ClockConfig,
    "control": ControlConfig,
    "record": RecordConfig,
}
