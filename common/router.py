"""``bipedtele router``: a Zenoh router (the zenoh library in router mode) from a profile.

For internet runs: leader and follower connect as clients to the router, which can
require TLS (mutual where configured) and user/password authentication
(``[network] credentials_file``) and restrict who may publish commands
(``[network] publishers_allowed``, enforced with Zenoh access control).
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config import ConfigError
from bipedtele.sections import NetworkConfig
from bipedtele.shutdown import shutdown_on_signals
from bipedtele.transport import open_session

__all__ = ["add_router_parser", "router_endpoints"]

LOG = logging.getLogger("bipedtele.router")
DEFAULT_LISTEN = ["tcp/0.0.0.0:7447"]


def router_endpoints(net: NetworkConfig, cli_listen: list[str] | None) -> list[str]:
    """Listen endpoints: the command line's, else the profile's, else ``tcp/0.0.0.0:7447``."""
    eps = list(cli_listen or net.listen or DEFAULT_LISTEN)
    try:
        NetworkConfig(listen=eps)  # same validation as the profile
    except ValueError as exc:
        raise ConfigError(f"--listen: {exc}") from None
    return eps


def run(args: argparse.Namespace) -> int:
    """Run the router until SIGINT/SIGTERM."""
    cfg = config_from_args(args)
    net: NetworkConfig = cfg.section("network")
    listen = router_endpoints(net, args.listen)
    connect = list(args.connect) if args.connect else list(net.connect)
    with shutdown_on_signals() as stop, open_session(net, mode="router", listen=listen, connect=connect) as s:
        LOG.info("zenoh router %s listening on %s", s.zid(), ", ".join(listen))
        if net.publishers_allowed:
            LOG.info("only %s may publish on bipedtele/*/cmd", ", ".join(net.publishers_allowed))
        print(f"router: {s.zid()} listening on {' '.join(listen)}", flush=True)  # noqa: T201 (CLI output)
        while not stop.wait(0.5):
            pass
        LOG.info("router shutting down")
    return 0


def add_router_parser(sub: Any) -> None:
    """Register ``bipedtele router``."""
    p = sub.add_parser("router", help="run a Zenoh router from a profile's [network] section")
    add_config_args(p)
    p.add_argument(
        "--listen", action="append", metavar="ENDPOINT", help="listen endpoint (repeatable), e.g. tcp/0.0.0.0:7447"
    )
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="other routers to connect to")
    p.set_defaults(func=run)
