"""The ``bipedtele`` command line.

Sub-commands are plugins registered in the ``bipedtele.commands`` entry-point group: each
entry point is a function ``add_parser(subparsers)`` that adds one sub-parser and sets its
``func`` default to ``func(args) -> int``. The core thereby runs the leader and follower
programs without importing them.

Every bad argument or config value ends the program with one line on stderr naming what is
wrong and what is allowed, and exit code 2. A network link that cannot be set up (no
router, TLS or user/password refused: :class:`bipedtele.link.linkcheck.LinkError`) is not a
config error: one line saying which failure it is, and exit code 1.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
import logging
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any, NoReturn

from bipedtele import __version__
from bipedtele.config.profile import Config, ConfigError, load_config
from bipedtele.link.linkcheck import LinkError

__all__ = [
    "EXTRAS",
    "PYTHON_311_EXTRAS",
    "OneLineParser",
    "add_config_args",
    "add_foxglove_arg",
    "config_from_args",
    "main",
    "missing_extra_message",
]

LOG = logging.getLogger("bipedtele")


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (no usage dump) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        """Exit with code 2 and one line naming what is wrong."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_config_args(parser: argparse.ArgumentParser, default: str = "default") -> None:
    """Add ``--config`` and ``--set`` to a sub-command parser."""
    parser.add_argument(
        "--config",
        default=default,
        metavar="PROFILE|FILE",
        help=f"profile name from configs/ or a TOML file (default: {default})",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one config value (repeatable; TOML syntax)",
    )


def config_from_args(args: argparse.Namespace) -> Config:
    """Load the profile named by ``--config`` with ``--set`` overrides (and ``--foxglove``, where offered)."""
    overrides = list(args.overrides)
    foxglove = getattr(args, "foxglove", None)
    if foxglove:
        overrides.append("record.foxglove=" + json.dumps(foxglove))
    if getattr(args, "allow_remote", False):
        overrides.append("record.foxglove_allow_remote=true")
    return load_config(args.config, overrides)


def _build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="bipedtele",
        description="Bilateral teleoperation of a biped (NAO) robot under time-varying delays.",
    )
    parser.add_argument("--version", action="version", version=f"bipedtele {__version__}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="logging level (default: INFO)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True
    eps = sorted(metadata.entry_points(group="bipedtele.commands"), key=lambda e: e.name)
    # Load only the plugin of the sub-command named on the command line (a health check
    # or the router then imports neither pybullet nor scipy); all of them for --help, a
    # missing or an unknown command, so the usage lists every choice.
    words = list(sys.argv[1:] if argv is None else argv)
    chosen = next((w for w in words if w in {ep.name for ep in eps}), None)
    for ep in eps:
        if chosen is None:
            # --help, no or an unknown command: list every command with its help line, read
            # from its module's source; nothing of it is imported (no pybullet, no role)
            sub.add_parser(ep.name, help=_command_help(ep.value), add_help=False)
        elif ep.name == chosen:
            try:
                add_parser = ep.load()
            except ModuleNotFoundError as exc:
                if (exc.name or "").split(".")[0] == "bipedtele":
                    raise  # a broken install, not a missing extra
                _add_missing_parser(sub, ep.name, exc)
            else:
                add_parser(sub)
    return parser


def _command_help(target: str) -> str | None:
    """Return a sub-command's help line without importing its module (None: not found).

    ``target`` is the entry point's ``module:function``. The line is the constant ``help=``
    of the function's ``add_parser`` call, else the first line of the module's docstring.
    The module's file is found through its role's package (``bipedtele.leader``) without
    running that package either.
    """
    module, _, func = target.partition(":")
    parts = module.split(".")
    try:
        spec = importlib.util.find_spec(".".join(parts[:2]))  # runs bipedtele's __init__ at most
        if spec is None:
            return None
        if len(parts) == 2:
            path = Path(spec.origin or "")
        else:
            base = Path(next(iter(spec.submodule_search_locations or [])), *parts[2:])
            path = base / "__init__.py" if base.is_dir() else base.with_suffix(".py")
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (OSError, SyntaxError, ValueError, ImportError, StopIteration):
        return None
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and node.name == func:
            for call in ast.walk(node):
                if (
                    isinstance(call, ast.Call)
                    and isinstance(call.func, ast.Attribute)
                    and call.func.attr == "add_parser"
                ):
                    for kw in call.keywords:
                        if kw.arg == "help" and isinstance(kw.value, ast.Constant) and isinstance(kw.value.value, str):
                            return kw.value.value
    doc = ast.get_docstring(tree)
    return doc.strip().splitlines()[0] if doc else None


#: The optional extra (pyproject.toml) that provides each third-party package a sub-command may need.
EXTRAS = {
    "pybullet": "sim",
    "cv2": "video",
    "aiohttp": "cockpit",
    "matplotlib": "plots",
    "tqdm": "progress",
    "foxglove": "foxglove",
    "qi": "naoqi",
    "evdev": "joystick",
}


#: The robot side's extras: their packages (pybullet, qi) ship wheels for Python 3.11 only.
PYTHON_311_EXTRAS = frozenset({"sim", "naoqi"})


def add_foxglove_arg(parser: argparse.ArgumentParser) -> None:
    """Add ``--foxglove [HOST:]PORT`` (sets ``[record] foxglove``; see :func:`config_from_args`)."""
    parser.add_argument(
        "--foxglove",
        metavar="[HOST:]PORT",
        help="also serve the recording's channels live on a Foxglove WebSocket (e.g. 8765; extra foxglove)",
    )
    parser.add_argument("--allow-remote", action="store_true", help="let --foxglove listen on a non-loopback address")


def missing_extra_message(exc: ModuleNotFoundError) -> str:
    """Return one line naming the package a sub-command could not import and how to install it.

    Parameters
    ----------
    exc : ModuleNotFoundError
        The error raised while importing the sub-command's module.
    """
    top = (exc.name or "").split(".")[0]
    extra = EXTRAS.get(top)
    if extra is None:
        return f"the python package {top or '?'} is missing"
    if extra in PYTHON_311_EXTRAS and sys.version_info[:2] != (3, 11):
        return (
            f"the python package {top} is missing: it ships wheels for Python 3.11 only: allowed: "
            f"pip install 'bipedtele[{extra}]' in a Python 3.11 environment (this is Python {sys.version_info[0]}."
            f"{sys.version_info[1]})"
        )
    return f"the python package {top} is missing: allowed: pip install 'bipedtele[{extra}]' (or 'bipedtele[all]')"


def _add_missing_parser(sub: Any, name: str, exc: ModuleNotFoundError) -> None:
    """Register ``name`` as a sub-command that says which extra it needs (exit 2) when run."""
    message = missing_extra_message(exc)
    # No option prefix: every word, --help included, is taken, and the command says the line.
    p = sub.add_parser(name, help=f"(not available: {message})", add_help=False, prefix_chars="\0")
    p.add_argument("rest", nargs=argparse.REMAINDER)

    def _missing(args: argparse.Namespace) -> int:
        raise ConfigError(message)

    p.set_defaults(func=_missing)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``bipedtele`` console script."""
    parser = _build_parser(argv)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    func: Any = args.func
    try:
        return int(func(args) or 0)
    except ConfigError as exc:
        sys.stderr.write(f"bipedtele {args.command}: config error: {exc}\n")
        return 2
    except LinkError as exc:
        sys.stderr.write(f"bipedtele {args.command}: link error: {exc}\n")
        return 1
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] not in EXTRAS:
            raise  # a broken install, not a missing extra
        # a part built on demand (bipedtele.parts.lazy) whose extra is missing
        sys.stderr.write(f"bipedtele {args.command}: config error: {missing_extra_message(exc)}\n")
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
