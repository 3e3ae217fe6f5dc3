"""``bipedtele router``: a Zenoh router (the zenoh library in router mode) from a profile.

For internet runs: leader and follower connect as clients to the router, which can
require TLS (mutual where configured) and user/password authentication
(``[network] credentials_file``) and give each user a role (``publishers_allowed``:
leaders, ``followers_allowed``: followers) enforced by a deny-by-default Zenoh access
control (:mod:`bipedtele.link.acl`). The router reads only the router settings of a profile
(the client login of a shared profile is ignored).

With no ``--listen`` and no ``listen`` in the profile it listens on
``tcp/127.0.0.1:7447`` only (this host). Listening on another address without TLS and
user/password authentication logs a warning. Each refused session is logged with its
reason and, where Zenoh reports it, the peer's address (:mod:`bipedtele.link.zenohlog`).
See docs/network.md.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.linkcheck import split_endpoint
from bipedtele.link.linkevents import RouterLinkLog
from bipedtele.link.zenohlog import ZenohLogBridge
from bipedtele.link.zenohsession import open_session
from bipedtele.shutdown import shutdown_on_signals

__all__ = ["DEFAULT_LISTEN", "add_router_parser", "exposure_warnings", "router_endpoints"]

LOG = logging.getLogger("bipedtele.tools.router")
DEFAULT_LISTEN = ["tcp/127.0.0.1:7447"]


def router_endpoints(net: NetworkConfig, cli_listen: list[str] | None) -> list[str]:
    """Listen endpoints: the command line's, else the profile's, else ``tcp/127.0.0.1:7447``."""
    eps = list(cli_listen or net.listen or DEFAULT_LISTEN)
    try:
        NetworkConfig(listen=eps)  # same validation as the profile
    except ValueError as exc:
        raise ConfigError(f"--listen: {exc}") from None
    return eps


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: assume reachable from elsewhere


def exposure_warnings(net: NetworkConfig, listen: list[str]) -> list[str]:
    """One warning per endpoint reachable from other hosts without TLS and credentials."""
    out = []
    for ep in listen:
        parts = split_endpoint(ep)
        if parts is None or _loopback(parts[1]):
            continue
        missing = []
        if parts[0] != "tls":
            missing.append("TLS")
        if not net.credentials_file:
            missing.append("user/password authentication (network.credentials_file)")
        if missing:
            out.append(
                f"listening on {ep} without {' or '.join(missing)}: anyone who reaches this address can "
                "join, read the robot's data and command it (fine inside a private network; see docs/network.md)"
            )
    return out


def run(args: argparse.Namespace) -> int:
    """Run the router until SIGINT/SIGTERM."""
    cfg = config_from_args(args)
    net: NetworkConfig = cfg.get(NetworkConfig)
    listen = router_endpoints(net, args.listen)
    connect = list(args.connect) if args.connect else list(net.connect)
    for text in exposure_warnings(net, listen):
        LOG.warning("%s", text)
    bridge = ZenohLogBridge().start()
    with (
        shutdown_on_signals() as stop,
        open_session(net, mode="router", listen=listen, connect=connect) as s,
        RouterLinkLog(s),
    ):
        where = ", ".join(listen)
        if not args.listen and not net.listen:
            where += " (the default: this host only; --listen tcp/0.0.0.0:7447 for every interface)"
        LOG.info("zenoh router %s listening on %s", s.zid(), where)
        if net.publishers_allowed or net.followers_allowed:
            LOG.info(
                "access control (deny by default): leaders %s; followers %s; observers %s; every other user may "
                "do nothing",
                ", ".join(net.publishers_allowed) or "(none)",
                ", ".join(net.followers_allowed) or "(none)",
                ", ".join(net.observers_allowed) or "(none)",
            )
            if net.tls_user_certs:
                LOG.info("a role only with the certificate named after its user (tls_user_certs)")
            if net.revoked:
                LOG.info("revoked (login and every right refused): %s", ", ".join(net.revoked))
            if net.routers_allowed:  # a site's router: its robots or operators may be elsewhere
                LOG.info("linked routers (by certificate): %s", ", ".join(net.routers_allowed))
            else:
                if not net.followers_allowed:
                    LOG.warning("network.followers_allowed is empty: no user may act as the follower")
                if not net.publishers_allowed:
                    LOG.warning("network.publishers_allowed is empty: no user may command the robot")
        print(f"router: {s.zid()} listening on {' '.join(listen)}", flush=True)  # noqa: T201 (CLI output)
        while not stop.wait(0.5):
            pass
        LOG.info("router shutting down (%d session(s) refused)", bridge.refusals)
    return 0


def add_router_parser(sub: Any) -> None:
    """Register ``bipedtele router``."""
    p = sub.add_parser(
        "router",
        help="run a Zenoh router from a profile's [network] section (default: tcp/127.0.0.1:7447, this host only)",
    )
    add_config_args(p)
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="listen endpoint (repeatable), e.g. tls/0.0.0.0:7447; default: the profile's "
        "network.listen, else tcp/127.0.0.1:7447 (this host only)",
    )
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="other routers to connect to")
    p.set_defaults(func=run)
