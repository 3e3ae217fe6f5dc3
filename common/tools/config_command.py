"""Core sub-commands: ``config`` (show/validate a profile)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from bipedtele.cli import add_config_args, config_from_args

__all__ = ["add_config_parser"]


def _run_config(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    # Secrets (passwords, tokens, fields marked secret) are shown as "***": output like this
    # ends up in terminals, logs and issue reports.
    json.dump(cfg.to_dict(redact=True), sys.stdout, indent=2, sort_keys=True)
    sys.stdout.write("\n")
    return 0


def add_config_parser(sub: Any) -> None:
    """Add ``bipedtele config [--config F] [--set K=V]``.

    It validates a profile and prints it as JSON (secrets shown as ``"***"``; paths as
    resolved, see :mod:`bipedtele.config.profile`).
    """
    p = sub.add_parser("config", help="validate a config profile and print it as JSON (secrets shown as ***)")
    add_config_args(p)
    p.set_defaults(func=_run_config)
