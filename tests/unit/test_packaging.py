"""The wheel installs one top-level name, `bipedtele`, with its profiles and data."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FOLDERS = {
    "common": "bipedtele",
    "leader": "bipedtele/leader",
    "follower": "bipedtele/follower",
    "configs": "bipedtele/configs",
    "studies": "bipedtele/studies",
}


@pytest.fixture(scope="module")
def wheel_names(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for folder in FOLDERS:
        shutil.copytree(ROOT / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    out = tmp_path_factory.mktemp("dist")
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), str(src)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    wheels = list(out.glob("bipedtele-*.whl"))
    assert len(wheels) == 1
    with zipfile.ZipFile(wheels[0]) as z:
        return z.namelist()


@pytest.mark.timeout(300)
def test_only_bipedtele_top_level(wheel_names: list[str]) -> None:
    top = {n.split("/")[0] for n in wheel_names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"bipedtele"}
    assert not any(n.startswith(("common/", "leader/", "follower/", "configs/")) for n in wheel_names)


@pytest.mark.timeout(300)
def test_data_and_profiles_inside(wheel_names: list[str]) -> None:
    assert "bipedtele/configs/default.toml" in wheel_names
    assert "bipedtele/data/intercontinental_delay.csv" in wheel_names
    for profile in ("localhost-delay", "intercontinental", "docker"):
        assert f"bipedtele/configs/{profile}.toml" in wheel_names


@pytest.mark.timeout(300)
def test_every_subpackage_packaged(wheel_names: list[str]) -> None:
    """A folder with __init__.py missing from pyproject's packages list would be lost."""
    missing = []
    for folder, pkg in FOLDERS.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.relative_to(ROOT / folder).as_posix()
            if f"{pkg}/{rel}" not in wheel_names:
                missing.append(f"{folder}/{rel}")
    assert not missing, f"add these packages to pyproject.toml [tool.setuptools] packages: {missing}"
