"""``bipedtele health``: check that a router is reachable or a leader or follower present.

Used by the docker compose healthchecks and handy by hand. Opens a short-lived Zenoh
session from the profile's ``[network]`` section (as a client when it names endpoints to
connect to, with the client settings of the profile: its certificate and login; a shared
profile's router-only settings are ignored) and checks:

- ``--role router``: the session opens, i.e. the router answers on the configured
  endpoints (a Zenoh client cannot open a session without one);
- ``--role leader|follower``: a liveliness token of that role appears within ``--timeout``.

Exit code 0 when healthy, 1 when not (one line says why: for an unreachable or refusing
router, which failure it is), 2 for bad arguments or configuration.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig, RobotConfig
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.transport import Keys, PresenceWatcher
from bipedtele.link.zenohsession import open_session

__all__ = ["add_health_parser", "check_health"]


def check_health(cfg: Any, role: str, timeout_s: float) -> tuple[bool, str]:
    """``(healthy, reason)`` for ``role`` on the network of profile ``cfg``.

    Raises
    ------
    ConfigError
        The profile's files or settings are bad (not a health verdict).
    """
    net = cfg.get(NetworkConfig)
    mode = "client" if net.connect else "peer"
    keys = Keys(cfg.get(RobotConfig).id)
    try:
        with open_session(net, mode=mode, listen=[]) as session:
            if role == "router":
                return True, f"router reachable at {', '.join(net.connect) or '(local)'}"
            with PresenceWatcher(session, keys, role) as watcher:
                if watcher.wait(alive=True, timeout=timeout_s):
                    return True, f"{role} present on {keys.presence(role)}"
                return False, f"no {role} present on {keys.presence(role)} within {timeout_s:g} s"
    except LinkError as exc:
        return False, str(exc)


def _run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    if args.timeout <= 0:
        raise ConfigError(f"--timeout {args.timeout}: allowed: a number of seconds > 0")
    ok, why = check_health(cfg, args.role, args.timeout)
    (sys.stdout if ok else sys.stderr).write(f"{'healthy' if ok else 'unhealthy'}: {why}\n")
    return 0 if ok else 1


def add_health_parser(sub: Any) -> None:
    """``bipedtele health --role ROLE``."""
    p = sub.add_parser("health", help="check that a router is reachable or a leader/follower is present")
    add_config_args(p)
    p.add_argument("--role", required=True, choices=["router", "leader", "follower"], help="what to check")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S", help="seconds to wait (default 3)")
    p.set_defaults(func=_run)
