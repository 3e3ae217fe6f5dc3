"""MkDocs hooks of bipedtele's documentation site (``mkdocs.yml``: ``hooks:``).

- ``cli.md``: the marker ``<!-- cli-reference -->`` becomes the reference of every
  sub-command, generated from the argument parsers that the ``bipedtele.commands`` entry
  points build (the same ones ``bipedtele`` runs), nested sub-commands included.
- The API pages: mkdocstrings reads the package's source statically (griffe); the installed
  name ``bipedtele`` maps to the repository's ``common/``, ``leader/``, ``follower/``, ``studies/`` and
  ``configs/`` folders (``[tool.setuptools] package-dir``), so a tree of links under
  ``build/api-src/bipedtele`` gives it the installed layout.
"""

from __future__ import annotations

import argparse
import os
import shutil
from importlib import metadata
from pathlib import Path
from typing import Any

from mkdocs.plugins import event_priority

ROOT = Path(__file__).resolve().parents[2]
API_SRC = ROOT / "build" / "api-src"
MARKER = "<!-- cli-reference -->"

#: The package-dir mapping of pyproject.toml: installed sub-package -> repository folder.
SUBPACKAGES = {"leader": "leader", "follower": "follower", "studies": "studies", "configs": "configs"}


@event_priority(100)  # before mkdocstrings reads its handler's paths (a fresh clone has none)
def on_config(config: Any) -> Any:
    """Lay out ``build/api-src/bipedtele`` as the installed package (links into the repository)."""
    pkg = API_SRC / "bipedtele"
    if API_SRC.exists():
        shutil.rmtree(API_SRC)
    pkg.mkdir(parents=True)
    for entry in sorted((ROOT / "common").iterdir()):
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    for name, folder in SUBPACKAGES.items():
        (pkg / name).symlink_to(ROOT / folder)
    return config


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Put the generated CLI reference in place of the marker of ``cli.md``."""
    if MARKER in markdown:
        markdown = markdown.replace(MARKER, cli_reference())
    return markdown


def _escape(text: str) -> str:
    """Text safe inside a markdown table cell."""
    return (
        " ".join(text.split())
        .replace("&", "&amp;")
        .replace("<", "&lt;")
        .replace(">", "&gt;")
        .replace("|", "\\|")
        .replace("*", "\\*")
        .replace("[", "\\[")
        .replace("]", "\\]")
    )


def _help(action: argparse.Action) -> str:
    """Return an action's help with argparse's ``%(default)s``-style fields filled in."""
    text = action.help or ""
    if "%" in text:
        params = {k: v for k, v in vars(action).items() if v is not argparse.SUPPRESS}
        if params.get("choices") is not None:
            params["choices"] = ", ".join(str(c) for c in params["choices"])
        text = text % params
    return text


def _value(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        return "{" + ",".join(str(c) for c in action.choices) + "}"
    metavar = action.metavar
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    return str(metavar or action.dest.upper())


def _default(action: argparse.Action) -> str:
    d = action.default
    if action.nargs == 0 or d is None or d is argparse.SUPPRESS or d == []:
        return ""
    return f"`{d}`"


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def _render(parser: argparse.ArgumentParser, name: str, help_line: str, level: int) -> list[str]:
    """One command's section: description, usage, options, then its own sub-commands."""
    out = [f"{'#' * level} `{name}`", ""]
    about = parser.description or help_line
    if about:
        out += [_escape(about), ""]
    out += ["```text", parser.format_usage().strip(), "```", ""]
    positionals = [a for a in parser._actions if not a.option_strings and not isinstance(a, argparse._SubParsersAction)]
    options = [a for a in parser._actions if a.option_strings and a.help is not argparse.SUPPRESS]
    rows = [(a, ", ".join(f"`{o}`" for o in a.option_strings)) for a in options]
    rows += [(a, f"`{a.metavar or a.dest}`") for a in positionals if a.help is not argparse.SUPPRESS]
    if rows:
        out += ["| option | value | default | what it does |", "| --- | --- | --- | --- |"]
        for action, names in rows:
            value = _value(action)
            out.append(
                f"| {names} | {_escape(value) if value else ''} | {_default(action)} | {_escape(_help(action))} |"
            )
        out.append("")
    sub = _subparsers(parser)
    if sub is not None:
        helps = {a.dest: a.help or "" for a in sub._choices_actions}
        for sub_name, sub_parser in sub.choices.items():
            out += _render(sub_parser, f"{name} {sub_name}", helps.get(sub_name, ""), min(level + 1, 6))
    return out


def command_parsers() -> list[tuple[str, str, argparse.ArgumentParser]]:
    """Every registered sub-command: (name, help line, its parser), by name."""
    from bipedtele.cli import OneLineParser

    result = []
    for ep in sorted(metadata.entry_points(group="bipedtele.commands"), key=lambda e: e.name):
        top = OneLineParser(prog="bipedtele")
        sub = top.add_subparsers(dest="command", parser_class=OneLineParser)
        ep.load()(sub)
        helps = {a.dest: a.help or "" for a in sub._choices_actions}
        result.append((ep.name, helps.get(ep.name, ""), sub.choices[ep.name]))
    return result


def cli_reference() -> str:
    """Return the markdown reference of ``bipedtele`` and every sub-command."""
    from bipedtele.cli import _build_parser

    os.environ["COLUMNS"] = "100"  # usage lines wrapped the same on every machine
    top = _build_parser(["--help"])
    out = ["## `bipedtele`", "", _escape(top.description or ""), "", "```text", top.format_usage().strip(), "```", ""]
    out += ["| option | value | default | what it does |", "| --- | --- | --- | --- |"]
    for action in top._actions:
        if action.option_strings and action.help is not argparse.SUPPRESS:
            names = ", ".join(f"`{o}`" for o in action.option_strings)
            out.append(f"| {names} | {_escape(_value(action))} | {_default(action)} | {_escape(_help(action))} |")
    out += ["", "| command | what it does |", "| --- | --- |"]
    commands = command_parsers()
    for name, help_line, _ in commands:
        out.append(f"| [`{name}`](#bipedtele-{name}) | {_escape(help_line)} |")
    out.append("")
    for name, help_line, parser in commands:
        out += _render(parser, f"bipedtele {name}", help_line, 2)
    return "\n".join(out) + "\n"
