"""The core's configuration sections: robot identity, network, clock, control, recording.

The leader and follower register their own sections (``[leader]``, ``[follower]``,
``[world]``) through the ``bipedtele.config`` entry-point group.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from bipedtele.config import param
from bipedtele.control.config import ControlConfig

__all__ = ["CORE_SECTIONS", "ClockConfig", "NetworkConfig", "RecordConfig", "RobotConfig"]

_ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True)
class RobotConfig:
    """Which robot this profile talks to."""

    id: str = param("nao1", doc="robot id: the <robot_id> in key expressions bipedtele/<robot_id>/...")

    def __post_init__(self) -> None:
        if not _ROBOT_ID.match(self.id):
            raise ValueError(
                f"id = {self.id!r}: allowed: 1-64 characters of letters, digits, '_' or '-'"
            )


@dataclass(frozen=True)
class NetworkConfig:
    """Zenoh session settings (see DESIGN section 6).

    Endpoints are Zenoh locators such as ``tcp/127.0.0.1:7447`` or ``tls/host:7447``.
    Multicast scouting is off by default: endpoints are always explicit.
    """

    mode: Literal["peer", "client", "router"] = param("peer", doc="Zenoh session mode")
    connect: list[str] = param(default_factory=list, doc="endpoints to connect to")
    listen: list[str] = param(default_factory=list, doc="endpoints to listen on")
    multicast_scouting: bool = param(False, doc="enable UDP multicast discovery")
    tls_root_ca: str = param("", doc="PEM file of the CA that signs the router's certificate")
    tls_cert: str = param("", doc="PEM certificate of this process (for mutual TLS or a router)")
    tls_key: str = param("", doc="PEM private key matching tls_cert")
    tls_mutual: bool = param(False, doc="require and present client certificates")
    user: str = param("", doc="user name for Zenoh user/password authentication")
    password: str = param("", doc="password (prefer password_file)")
    password_file: str = param("", doc="file holding the password")
    credentials_file: str = param(
        "", doc="router only: file of 'user:password' lines accepted by the router"
    )
    publishers_allowed: list[str] = param(
        default_factory=list,
        doc="router only: user names allowed to publish commands (access control); empty = all",
    )
    timeout_s: float = param(10.0, lo=0.1, hi=600.0, unit="s", doc="session open timeout")

    def __post_init__(self) -> None:
        for ep in [*self.connect, *self.listen]:
            proto, sep, rest = ep.partition("/")
            if not sep or proto not in ("tcp", "tls", "udp", "quic", "ws", "unixsock-stream") or not rest:
                raise ValueError(
                    f"endpoint {ep!r}: allowed: PROTO/HOST:PORT with PROTO in tcp, tls, udp, quic, ws"
                )
        if bool(self.tls_cert) != bool(self.tls_key):
            raise ValueError("tls_cert and tls_key: allowed: both set or both empty")
        if self.password and self.password_file:
            raise ValueError("password and password_file: allowed: at most one of them")


@dataclass(frozen=True)
class ClockConfig:
    """How each side estimates one-way delays (DESIGN section 3)."""

    mode: Literal["synced", "ntp"] = param(
        "synced", doc="synced: one clock (same host, chrony/PTP); ntp: ping exchange estimates the offset"
    )
    delay_window_s: float = param(
        1.0, lo=0.01, hi=60.0, unit="s", doc="moving-average window of the delay estimators"
    )
    ping_rate_hz: float = param(4.0, lo=0.1, hi=100.0, unit="Hz", doc="ntp mode: ping rate")
    ping_window: int = param(16, lo=1, hi=1024, doc="ntp mode: pings kept for min-RTT filtering")
    conservative_split: bool = param(
        True,
        doc="ntp mode: use h1 = h2 = round trip for the stability conditions (the split is unknown)",
    )


@dataclass(frozen=True)
class RecordConfig:
    """MCAP recording of every message sent and received."""

    enabled: bool = param(True, doc="write an MCAP file per run")
    dir: str = param("runs", doc="folder for recordings")
    flush_s: float = param(1.0, lo=0.05, hi=10.0, unit="s", doc="flush period (max data lost on a crash)")


CORE_SECTIONS: dict[str, type] = {
    "robot": RobotConfig,
    "network": NetworkConfig,
    "clock": ClockConfig,
    "control": ControlConfig,
    "record": RecordConfig,
}
