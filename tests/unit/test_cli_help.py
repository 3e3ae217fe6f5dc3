"""Every sub-command's --help prints and exits 0 (a stray % in a help text crashed `link-emu --help`)."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import entry_points

import pytest

COMMANDS = sorted(ep.name for ep in entry_points(group="bipedtele.commands"))


@pytest.mark.timeout(60)
@pytest.mark.parametrize("command", COMMANDS)
def test_help_of_every_sub_command(command: str) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", command, "--help"], capture_output=True, text=True, timeout=50, cwd="/"
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert "usage:" in res.stdout


_LOADED = """
import json, sys
from bipedtele.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)))
"""


@pytest.mark.timeout(60)
@pytest.mark.parametrize("args", [["--help"], [], ["no-such-command"]])
def test_the_command_list_loads_neither_pybullet_nor_a_role(args: list[str]) -> None:
    """Issue 22: `bipedtele --help` imported every plugin (pybullet printed its banner, the
    leader and the follower were loaded) only to print one help line each."""
    res = subprocess.run([sys.executable, "-c", _LOADED, *args], capture_output=True, text=True, timeout=50, cwd="/")
    loaded = json.loads(res.stdout.strip().splitlines()[-1])
    heavy = [m for m in loaded if m.split(".")[0] in ("pybullet", "scipy", "cv2", "aiohttp", "matplotlib")]
    roles = [m for m in loaded if m.startswith(("bipedtele.leader", "bipedtele.follower", "bipedtele.tools"))]
    assert heavy == [] and roles == [], (heavy, roles)
    if args:  # the help, or the unknown command's error, lists every command
        listing = res.stdout if args == ["--help"] else res.stderr
        for command in COMMANDS:
            assert command in listing, command
    if args == ["--help"]:  # with each command's help line, as its own parser says it
        assert "the simulated walker's own Poincare map next to the reduced model's" in " ".join(listing.split())
