"""Every sub-command's --help prints and exits 0 (a stray % in a help text crashed `link-emu --help`)."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import entry_points

import pytest

COMMANDS = sorted(ep.name for ep in entry_points(group="bipedtele.commands"))


@pytest.mark.timeout(60)
@pytest.mark.parametrize("command", COMMANDS)
def test_help_of_every_sub_command(command: str) -> None:
    res = subprocess.run([sys.executable, "-m", "bipedtele.cli", command, "--help"],
                         capture_output=True, text=True, timeout=50, cwd="/")  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert "usage:" in res.stdout
