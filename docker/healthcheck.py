#!/opt/venv/bin/python
"""bipedtele-health: ``bipedtele health`` for the compose healthchecks, same arguments.

``bipedtele health --role ROLE`` builds the whole command line first, which imports every
sub-command (the simulator, the control study: about 1.7 s of CPU); a healthcheck runs
every few seconds in every container, so this entry point registers only ``health`` (about
0.25 s). Exit code 0 healthy, 1 not (one line says why), 2 bad arguments.
"""

from __future__ import annotations

import sys

from bipedtele.cli import OneLineParser
from bipedtele.config import ConfigError
from bipedtele.tools.health import add_health_parser


def main(argv: list[str]) -> int:
    parser = OneLineParser(prog="bipedtele-health")
    add_health_parser(parser.add_subparsers(parser_class=OneLineParser))
    args = parser.parse_args(["health", *argv])
    try:
        return int(args.func(args))
    except ConfigError as exc:
        sys.stderr.write(f"bipedtele-health: config error: {exc}\n")
        return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
