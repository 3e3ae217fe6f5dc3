"""The operator's side on a second Python (3.12 or newer) besides the project's 3.11.

A fresh virtual environment on that interpreter installs ``.[cockpit]`` from this checkout
and runs what an operator runs: the leader's help with the keyboard device, a router that
starts and listens, and ``bipedtele compare`` on the reduced model. Installing ``.[sim]``
there names Python 3.11 in one line, and the operator side's unit tests pass on it.

The interpreter: ``BIPEDTELE_SECOND_PYTHON``, else ``python3.13``/``python3.12`` on the PATH,
else pyenv's. None found: the tests skip with one line, except in CI (``CI=true``), where
that is a failure.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.compute, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parents[2]

#: The operator side's unit tests: leader, devices, operators, cockpit, the wire, the control
#: core and schemes, recordings, the delay models and the demo's command line; nothing of
#: the robot side (pybullet, qi), which needs Python 3.11.
OPERATOR_TESTS = [
    "test_auth.py",
    "test_clock.py",
    "test_clocklink.py",
    "test_cockpit.py",
    "test_cockpit_guard.py",
    "test_command_reach.py",
    "test_config_validation.py",
    "test_control_core.py",
    "test_delaymodels.py",
    "test_demo_cli.py",
    "test_drops.py",
    "test_gate.py",
    "test_gate_rollback.py",
    "test_gate_rules.py",
    "test_impairments.py",
    "test_leader_device.py",
    "test_leader_linkquality.py",
    "test_leader_operators.py",
    "test_messages.py",
    "test_operator_contract.py",
    "test_pacer.py",
    "test_pad_device.py",
    "test_recording.py",
    "test_schemes.py",
    "test_secrets.py",
    "test_session.py",
    "test_telemetry.py",
    "test_transport_config.py",
]


def _version(python: str) -> tuple[int, int] | None:
    try:
        out = subprocess.run(
            [python, "-c", "import sys; print(sys.version_info[0], sys.version_info[1])"],
            capture_output=True,
            text=True,
            timeout=30,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    major, minor = out.split()
    return int(major), int(minor)


def second_python() -> str | None:
    """Return an interpreter of Python 3.12 or newer other than this one, or None."""
    candidates: list[str] = []
    if os.environ.get("BIPEDTELE_SECOND_PYTHON"):
        candidates.append(os.environ["BIPEDTELE_SECOND_PYTHON"])
    for name in ("python3.13", "python3.12"):
        found = shutil.which(name)
        if found:
            candidates.append(found)
    pyenv = Path(os.environ.get("PYENV_ROOT", Path.home() / ".pyenv")) / "versions"
    if pyenv.is_dir():
        candidates += [str(p / "bin" / "python") for p in sorted(pyenv.glob("3.1[2-9]*"), reverse=True)]
    for python in candidates:
        version = _version(python)
        if version is not None and version >= (3, 12) and version != sys.version_info[:2]:
            return python
    return None


@pytest.fixture(scope="module")
def second_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv on the second Python with ``.[cockpit]`` installed from this checkout."""
    python = second_python()
    if python is None:
        message = "no Python 3.12 or newer found (set BIPEDTELE_SECOND_PYTHON): the operator side's second-Python tests"
        if os.environ.get("CI") == "true":
            pytest.fail(message + " cannot be skipped in CI")
        pytest.skip(message + " skipped")
    venv = tmp_path_factory.mktemp("second-python") / "venv"
    subprocess.run([python, "-m", "venv", str(venv)], check=True, timeout=120)
    _pip(venv, "install", f"{ROOT}[cockpit]")
    return venv


def _pip(venv: Path, *args: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "--disable-pip-version-check", *args],
        capture_output=True,
        text=True,
        timeout=400,
    )
    assert proc.returncode == 0, f"pip {' '.join(args)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def _bipedtele(venv: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(venv / "bin" / "bipedtele"), *args], capture_output=True, text=True, timeout=timeout)


def test_the_second_python_is_not_3_11(second_venv: Path) -> None:
    out = subprocess.run(
        [str(second_venv / "bin" / "python"), "-c", "import sys, bipedtele; print(sys.version_info[:2] >= (3, 12))"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout
    assert out.strip() == "True"


def test_leader_help_with_the_keyboard(second_venv: Path) -> None:
    proc = _bipedtele(second_venv, "leader", "--device", "keyboard", "--help")
    assert proc.returncode == 0, proc.stderr
    assert "--device" in proc.stdout and "keyboard" in proc.stdout


def test_router_starts_and_listens(second_venv: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [str(second_venv / "bin" / "bipedtele"), "router", "--listen", f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 60
        seen = []
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            seen.append(line)
            if "listening on" in line:
                break
        assert any(f"listening on tcp/127.0.0.1:{port}" in ln for ln in seen), "".join(seen)
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # the router accepts a TCP connection
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_compare_on_the_reduced_model(second_venv: Path, tmp_path: Path) -> None:
    out = tmp_path / "compare.json"
    proc = _bipedtele(second_venv, "compare", "--walker-runs", "0", "--runs", "2", "--json", str(out), timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(out.read_text())
    text = json.dumps(result)
    for scheme in ("paper", "pd-worst-case", "wave", "tdpa"):
        assert f'"{scheme}"' in text


def test_the_robot_side_extras_name_python_3_11(second_venv: Path) -> None:
    for extra in ("sim", "naoqi"):
        proc = _pip(second_venv, "install", "--dry-run", f"{ROOT}[{extra}]")
        lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if "needs-python-3-11" in ln]
        assert len(lines) == 1, proc.stdout + proc.stderr
        assert re.search(rf"does not provide the extra '{extra}-needs-python-3-11'", lines[0]), lines[0]
        would = " ".join(ln for ln in proc.stdout.splitlines() if ln.startswith("Would install"))
        assert "pybullet" not in would and " qi-" not in would, would


def test_a_robot_side_command_names_python_3_11(second_venv: Path) -> None:
    proc = _bipedtele(second_venv, "poincare", "--help")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "pybullet" in lines[0] and "Python 3.11" in lines[0], proc.stderr


def test_operator_unit_tests_pass_on_the_second_python(second_venv: Path) -> None:
    _pip(second_venv, "install", f"{ROOT}[test-operator]")
    files = [str(ROOT / "tests" / "unit" / name) for name in OPERATOR_TESTS]
    missing = [f for f in files if not Path(f).is_file()]
    assert not missing, missing
    proc = subprocess.run(
        [
            str(second_venv / "bin" / "python"),
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-m",
            "not compute",
            "--timeout",
            "300",
            *files,
        ],
        capture_output=True,
        text=True,
        timeout=500,
        cwd=ROOT,
    )
    tail = proc.stdout[-4000:] + proc.stderr[-2000:]
    assert proc.returncode == 0, tail
    summary = proc.stdout.strip().splitlines()[-1]
    assert re.search(r"\d+ passed", summary) and "failed" not in summary, summary
