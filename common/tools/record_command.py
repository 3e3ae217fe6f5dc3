"""Sub-command ``record``: ``record repair F.mcap`` makes a cut recording readable by any MCAP tool."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.recording.format import RecordingError
from bipedtele.recording.repair import repair

__all__ = ["add_record_parser"]

LOG = logging.getLogger("bipedtele.tools.record")


def _run_repair(args: argparse.Namespace) -> int:
    try:
        got = repair(args.file, args.output)
    except (RecordingError, OSError) as exc:
        raise ConfigError(f"record repair {args.file}: {exc}; allowed: an MCAP recording") from None
    if got.complete:
        sys.stdout.write(f"{got.source}: complete already (footer and summary): nothing to repair\n")
    else:
        kept = f" (the cut file kept as {got.kept_as})" if got.kept_as is not None else ""
        sys.stdout.write(
            f"{got.source}: {got.messages} messages on {got.channels} channels written to {got.output}{kept}\n"
        )
    return 0


def add_record_parser(sub: Any) -> None:
    """Add ``bipedtele record repair F.mcap [--output OUT]``."""
    p = sub.add_parser("record", help="work on recordings: repair one cut short by a crash")
    rsub = p.add_subparsers(dest="record_command", required=True, metavar="COMMAND")
    r = rsub.add_parser("repair", help="rewrite a recording cut by a crash (kill -9) as a complete MCAP file")
    r.add_argument("file", help="the recording (.mcap); repaired in place, the cut file kept as FILE.cut")
    r.add_argument("--output", "-o", default=None, help="write the repaired file here instead (a new file)")
    r.set_defaults(func=_run_repair)
