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
    json.dump(cfg.to_dict(), sys.stdout, indent=2, sort_keys=True)
    sys.stdout.write("\n")
    return 0


def add_config_parser(sub: Any) -> None:
    """``bipedtele config [--config F] [--set K=V]``: validate a profile and print it as JSON."""
    p = sub.add_parser("config", help="validate a config profile and print it as JSON")
    add_config_args(p)
    p.set_defaults(func=_run_config)
