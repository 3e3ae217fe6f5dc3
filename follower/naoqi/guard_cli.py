"""``bipedtele nao-guard``: run the NAO guard on this host (where one cannot install on NAO).

The guard itself is the single file :mod:`bipedtele.follower.naoqi.nao_guard` (which also
runs with the robot's own Python); this sub-command gives it the profile's ``[naoqi]``
settings as defaults (URL, user, password file) and the usual one-line errors (exit 2).
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.follower.naoqi import nao_guard
from bipedtele.follower.naoqi.config import NaoqiConfig

__all__ = ["add_nao_guard_parser"]

LOG = logging.getLogger(__name__)


def _run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    ncfg = cfg.get(NaoqiConfig)
    if args.url is None and args.pip is None and args.pport is None:
        args.url = ncfg.url
    try:
        url, lapse = nao_guard.check_args(args)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    user = args.user or ncfg.user
    if args.password_file:
        try:
            password = nao_guard._read_password(args.password_file)
        except OSError as exc:
            raise ConfigError(f"--password-file {args.password_file!r}: cannot read ({exc.strerror})") from None
    else:
        password = ncfg.resolved_password()
    try:
        import qi  # noqa: F401
    except ImportError:
        raise ConfigError("the qi package (libqi-python) is missing: allowed: pip install 'bipedtele[naoqi]'") from None
    if args.log_file:
        handler = logging.FileHandler(args.log_file)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        logging.getLogger().addHandler(handler)
    LOG.info("NAO guard for %s on this host: it stops NAO only while this host can reach it", url)
    return int(nao_guard.serve(url, lapse, user, password))


def add_nao_guard_parser(sub: Any) -> None:
    """``bipedtele nao-guard``: the watchdog that stops NAO when the follower's heartbeats stop."""
    p = sub.add_parser(
        "nao-guard",
        help="watchdog beside a real NAO: stopMove when the follower's heartbeats stop (docs/hardware.md)",
    )
    add_config_args(p)
    nao_guard.build_parser(p)
    p.set_defaults(func=_run)
