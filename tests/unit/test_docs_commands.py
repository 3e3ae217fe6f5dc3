"""The ``bipedtele`` commands shown in the quick starts still work.

Every ``bipedtele`` command in a fenced block of the README and of the quick-start pages
parses with the real parser (every option it shows exists, every value it shows is allowed),
its sub-command's ``--help`` runs, and the profile it runs with (the one it names or its
default, with its ``--set`` overrides) passes ``bipedtele config``. Profiles that
``bipedtele setup two-hosts`` writes (``router/bipedtele.toml``, ...) are checked in the
folders that command writes.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from bipedtele.cli import _build_parser

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

ROOT = Path(__file__).resolve().parents[2]
PAGES = [
    "README.md",
    "docs/index.md",
    "docs/install.md",
    "docs/one-machine.md",
    "docs/two-continents.md",
    "docs/reproduce.md",
]
BIPEDTELE = [sys.executable, "-m", "bipedtele.cli"]


def quick_start_commands() -> list[tuple[str, list[str]]]:
    """Return (page, argv after ``bipedtele``) for every command in the pages' fenced blocks."""
    found: list[tuple[str, list[str]]] = []
    for page in PAGES:
        text = (ROOT / page).read_text()
        for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M):
            for line in block.replace("\\\n", " ").splitlines():
                for part in re.split(r"&&|;|\|(?!\|)", line):
                    try:
                        words = shlex.split(part, comments=True)
                    except ValueError:
                        continue
                    words = [w for w in words if w not in {"&", "sudo"}]
                    if words and words[0].split("/")[-1] in {"bipedtele", "$B"} and len(words) > 1:
                        found.append((page, words[1:]))
    return found


COMMANDS = quick_start_commands()


def _id(item: tuple[str, list[str]]) -> str:
    return f"{item[0]}: {' '.join(item[1])[:70]}"


def test_the_quick_starts_show_commands() -> None:
    assert {page for page, _ in COMMANDS} == set(PAGES)
    assert {"demo", "router", "delay-proxy", "follower", "leader", "setup"} <= {argv[0] for _, argv in COMMANDS}


@pytest.fixture(scope="module")
def two_hosts(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folders ``bipedtele setup two-hosts`` writes, as the quick start makes them."""
    where = tmp_path_factory.mktemp("setup")
    proc = subprocess.run(
        [*BIPEDTELE, "setup", "two-hosts", "--router-name", "router.example.org"],
        cwd=where,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return where / "two-hosts"


@pytest.mark.parametrize("item", COMMANDS, ids=[_id(c) for c in COMMANDS])
def test_a_quick_start_command_parses_and_its_profile_validates(item: tuple[str, list[str]], two_hosts: Path) -> None:
    page, argv = item
    try:
        args = _build_parser(argv).parse_args(argv)
    except SystemExit as exc:
        if exc.code == 0 and argv == ["--version"]:
            return
        pytest.fail(f"{page}: `bipedtele {' '.join(argv)}` does not parse (exit {exc.code})")
    if hasattr(args, "config") and hasattr(args, "overrides"):
        config = ["config", "--config", args.config]
        for override in args.overrides:
            config += ["--set", override]
        proc = subprocess.run([*BIPEDTELE, *config], cwd=two_hosts, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, f"{page}: bipedtele {' '.join(config)}: {proc.stderr}"


@pytest.mark.parametrize("command", sorted({argv[0] for _, argv in COMMANDS if not argv[0].startswith("-")}))
def test_a_quick_start_sub_command_has_help(command: str) -> None:
    proc = subprocess.run([*BIPEDTELE, command, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"usage: bipedtele {command}"), proc.stdout[:200]
