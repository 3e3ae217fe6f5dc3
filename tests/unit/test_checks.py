"""The static checks CI runs can fail (issue 22): errors planted where they look are found.

``scripts/typecheck.sh`` is ``mypy -p bipedtele`` on the package as installed; before it,
``mypy common leader follower`` resolved none of the 255 ``bipedtele.*`` imports and turned
them into ``Any`` (it could not fail on them). ruff runs with the project's rules.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def test_the_type_check_fails_on_a_planted_type_error_and_a_missing_internal_import(tmp_path: Path) -> None:
    plant = tmp_path / "plant.py"
    plant.write_text(
        "from bipedtele.link.messages import Command, no_such_name\n"
        "from bipedtele.no_such_module import thing\n"
        "\n"
        "def speed(cmd: Command) -> int:\n"
        "    return cmd.ref  # a list of floats, not an int\n"
    )
    env = {**os.environ, "TYPECHECK_PLANT": str(plant), "TYPECHECK_STAGE": str(tmp_path / "stage")}
    res = subprocess.run(
        ["bash", "scripts/typecheck.sh", "--cache-dir", str(tmp_path / "cache")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=280,
    )
    out = res.stdout + res.stderr
    assert res.returncode == 1, out
    assert 'Module "bipedtele.link.messages" has no attribute "no_such_name"' in out, out
    assert 'module named "bipedtele.no_such_module"' in out, out
    assert "Incompatible return value type" in out, out
    assert "common/_planted.py:5" in out, out  # named as the repository's file
    assert "Found 3 errors in 1 file" in out, out  # the package itself is clean


def test_ruff_lint_and_format_fail_on_planted_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text('"""A module."""\n\nimport os\n')
    ugly = tmp_path / "ugly.py"
    ugly.write_text('"""A module."""\n\nx = {  "a":1 }\n')
    res = subprocess.run(
        [
            str(Path(sys.executable).parent / "ruff"),
            "format",
            "--check",
            "--config",
            str(ROOT / "pyproject.toml"),
            str(ugly),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 1 and "would be reformatted" in res.stdout, res.stdout + res.stderr
    res = subprocess.run(
        [str(Path(sys.executable).parent / "ruff"), "check", "--config", str(ROOT / "pyproject.toml"), str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 1 and "F401" in res.stdout, res.stdout + res.stderr
