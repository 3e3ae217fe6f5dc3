"""Dependencies point to the core, and no role loads the other's modules.

Each check imports every module of one part in a fresh interpreter and reads
``sys.modules``: the core library (``bipedtele`` without ``tools``/``leader``/``follower``)
must load neither role nor the tools; the tools (``bipedtele.tools``) reach the roles only
through entry points, so they load neither either; every module of the follower must not
load the leader, and the reverse.
The sub-commands each role registers run the same way (``bipedtele follower``,
``bipedtele leader``), so this is also what those programs import.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

PROBE = r"""
import importlib, json, pkgutil, sys
root, skip = sys.argv[1], sys.argv[2:]
names = [root]
def walk(path, prefix):
    # pkgutil.walk_packages would import the skipped packages to look inside them.
    for info in pkgutil.iter_modules(path, prefix):
        if any(info.name == s or info.name.startswith(s + ".") for s in skip):
            continue
        names.append(info.name)
        mod = importlib.import_module(info.name)
        if info.ispkg:
            walk(mod.__path__, info.name + ".")
walk(importlib.import_module(root).__path__, root + ".")
print(json.dumps({"imported": names, "loaded": sorted(m for m in sys.modules if m.startswith("bipedtele"))}))
"""


def _probe(root: str, *skip: str) -> dict[str, list[str]]:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, root, *skip], capture_output=True, text=True, timeout=240, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _under(modules: list[str], pkg: str) -> list[str]:
    return [m for m in modules if m == pkg or m.startswith(pkg + ".")]


@pytest.mark.timeout(300)
def test_the_core_imports_neither_role_nor_the_tools() -> None:
    got = _probe("bipedtele", "bipedtele.tools", "bipedtele.leader", "bipedtele.follower")
    assert len(got["imported"]) > 20  # the whole core was walked
    assert "bipedtele.control.study" in got["imported"]
    assert _under(got["imported"], "bipedtele.tools") == []
    assert _under(got["loaded"], "bipedtele.leader") == []
    assert _under(got["loaded"], "bipedtele.follower") == []
    assert _under(got["loaded"], "bipedtele.tools") == []
    # The command-line tools live in bipedtele.tools, not beside the library.
    for tool in ("demo", "demostatus", "report", "delayproxy", "netem", "router", "health", "setup", "commands"):
        assert f"bipedtele.{tool}" not in got["imported"], tool


@pytest.mark.timeout(300)
def test_control_is_pure() -> None:
    got = _probe("bipedtele.control")
    assert "bipedtele.control.study" in got["imported"]
    assert "bipedtele.control.commands" not in got["imported"]  # no sub-commands in control
    assert "bipedtele.cli" not in got["loaded"]  # no argument parsing


@pytest.mark.timeout(300)
def test_the_tools_import_neither_role() -> None:
    got = _probe("bipedtele.tools")
    assert "bipedtele.tools.demo" in got["imported"]
    assert _under(got["loaded"], "bipedtele.leader") == []
    assert _under(got["loaded"], "bipedtele.follower") == []


@pytest.mark.timeout(300)
def test_the_follower_never_loads_the_leader() -> None:
    got = _probe("bipedtele.follower")
    assert "bipedtele.follower.app" in got["imported"]
    assert _under(got["loaded"], "bipedtele.leader") == []


@pytest.mark.timeout(300)
def test_the_leader_never_loads_the_follower() -> None:
    got = _probe("bipedtele.leader")
    assert "bipedtele.leader.app" in got["imported"]
    assert _under(got["loaded"], "bipedtele.follower") == []
