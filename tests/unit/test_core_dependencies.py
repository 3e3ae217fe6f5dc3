"""The library runs on its core dependencies; the heavy ones are extras.

Each check runs in a fresh interpreter where the optional packages (the ``sim``, ``video``,
``cockpit``, ``plots``, ``progress``, ``naoqi`` and ``joystick`` extras) cannot be imported:
a meta path finder refuses them, as if they were not installed.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: Top-level names of the packages the extras install (pyproject.toml).
EXTRA_PACKAGES = ("pybullet", "cv2", "aiohttp", "matplotlib", "tqdm", "qi", "evdev")

BLOCK = r"""
import importlib.abc, sys
BLOCKED = set(sys.argv[1].split(","))
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)
        return None
sys.meta_path.insert(0, Refuse())
"""

CORE = (
    BLOCK
    + r"""
import importlib, json, pkgutil
import bipedtele
skip = ("bipedtele.tools", "bipedtele.leader", "bipedtele.follower", "bipedtele.studies")
names = ["bipedtele"]
for info in pkgutil.walk_packages(bipedtele.__path__, "bipedtele."):
    if not any(info.name == s or info.name.startswith(s + ".") for s in skip):
        names.append(info.name)
failed = {}
for name in names:
    try:
        importlib.import_module(name)
    except ImportError as exc:
        failed[name] = repr(exc)
print(json.dumps({"imported": names, "failed": failed,
                  "loaded": sorted({m.split(".")[0] for m in sys.modules} & BLOCKED)}))
"""
)

CLI = (
    BLOCK
    + r"""
from bipedtele.cli import main
sys.argv[0] = "bipedtele"
try:
    code = main(sys.argv[2:])
except SystemExit as exc:
    code = exc.code
sys.stdout.flush()
sys.exit(code)
"""
)


def _run(script: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", script, ",".join(EXTRA_PACKAGES), *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.timeout(180)
def test_every_core_module_imports_without_the_extras() -> None:
    out = _run(CORE)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(got["imported"]) > 20  # the whole core was walked
    assert "bipedtele.control.reduced" in got["imported"]
    assert got["failed"] == {}
    assert got["loaded"] == []


@pytest.mark.timeout(180)
def test_help_lists_every_command_without_the_extras() -> None:
    out = _run(CLI, "--help")
    assert out.returncode == 0, out.stderr[-3000:]
    for command in ("config", "demo", "follower", "leader", "report", "router", "health", "setup", "study"):
        assert f"    {command} " in out.stdout, command
    assert "Traceback" not in out.stderr


@pytest.mark.timeout(180)
def test_a_figure_without_matplotlib_is_one_line_naming_the_extra(tmp_path: pytest.TempPathFactory) -> None:
    out = _run(CLI, "report", str(tmp_path), "--plots", str(tmp_path))
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert "--plots" in lines[0] and "bipedtele[plots]" in lines[0]
