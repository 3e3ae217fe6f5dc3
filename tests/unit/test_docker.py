"""docker/: Docker cannot run on this machine, so check what can be checked without it:
the compose file parses, every service runs an existing `bipedtele` sub-command whose
arguments parse, every `--config`/`--set` validates, and the Dockerfile is sane."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "docker" / "compose.yaml"
DOCKERFILE = ROOT / "docker" / "Dockerfile"


def _bipedtele(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", *args], capture_output=True, text=True, timeout=60
    )


def _services() -> dict[str, dict]:
    data = yaml.safe_load(COMPOSE.read_text())
    return data["services"]


def test_compose_has_the_three_roles_with_healthchecks() -> None:
    services = _services()
    for name in ("router", "follower", "leader"):
        assert name in services, name
        check = services[name]["healthcheck"]["test"]
        assert check[:3] == ["CMD", "bipedtele", "health"]
    assert "8080:8080" in services["leader"]["ports"]
    assert services["netem"]["cap_add"] == ["NET_ADMIN"]


def _config_args(cmd: list[str]) -> list[str]:
    """The --config/--set arguments of a service command."""
    out = []
    for i, arg in enumerate(cmd):
        if arg in ("--config", "--set"):
            out += [arg, cmd[i + 1]]
    return out


@pytest.mark.parametrize("service", ["router", "delay", "follower", "leader", "netem"])
def test_service_command_exists_and_its_config_validates(service: str) -> None:
    cmd = _services()[service]["command"]
    sub = cmd[0]
    helped = _bipedtele(sub, "--help")
    assert helped.returncode == 0, helped.stderr
    cfg_args = _config_args(cmd)
    if cfg_args:
        checked = _bipedtele("config", *cfg_args)
        assert checked.returncode == 0, checked.stderr


@pytest.mark.parametrize("service", ["router", "follower", "leader"])
def test_healthcheck_arguments_are_valid(service: str) -> None:
    test = _services()[service]["healthcheck"]["test"]
    args = test[2:]
    checked = _bipedtele("config", *_config_args(args))
    assert checked.returncode == 0, checked.stderr
    helped = _bipedtele(*args[:1], "--help")
    assert "--role" in helped.stdout


def test_dockerfile_uses_slim_python_and_a_non_root_user() -> None:
    text = DOCKERFILE.read_text()
    assert text.startswith("#") and "FROM python:3.11-slim" in text
    assert "\nUSER bipedtele" in text
    for folder in ("common", "leader", "follower", "configs"):
        assert f"COPY {folder} ./{folder}" in text
        assert (ROOT / folder).is_dir()
