"""The NAO guard (follower/naoqi/nao_guard.py): a watchdog that stops NAO when the
follower's heartbeats stop.

- Its source stays runnable by the robot's own Python: Python 2.7 (NAOqi 2.8) and
  Python 3 (NAOqi 2.9): checked on the syntax tree, and run under a Python 2.7 where one
  is installed.
- Against the fake NAOqi over real libqi, in separate processes: the guard registers
  ``BipedteleGuard``, stops the walking robot within its lapse of the last heartbeat,
  once per lapse, re-arms on the next heartbeat, does not fire after a release, and
  re-registers when NAOqi comes back.
- ``bipedtele nao-guard`` gives one-line errors (exit 2).
"""

from __future__ import annotations

import ast
import glob
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
GUARD = ROOT / "follower" / "naoqi" / "nao_guard.py"
sys.path.insert(0, str(ROOT / "tests"))

pytestmark = pytest.mark.timeout(90)

STDLIB_OK = {"argparse", "json", "logging", "os", "signal", "sys", "threading", "time", "qi", "__future__"}


# ---------------------------------------------------------------- runs on the robot's Python


def test_the_guard_is_one_file_python2_can_parse_with_only_qi_and_the_standard_library() -> None:
    tree = ast.parse(GUARD.read_text())
    futures = {
        a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module == "__future__" for a in n.names
    }
    assert {"print_function", "division", "absolute_import"} <= futures
    for node in ast.walk(tree):
        assert not isinstance(node, ast.JoinedStr), f"f-string at line {node.lineno}"
        assert not isinstance(node, ast.AnnAssign | ast.Nonlocal | ast.AsyncFunctionDef | ast.Await | ast.NamedExpr), (
            f"{type(node).__name__} at line {getattr(node, 'lineno', '?')}"
        )
        if isinstance(node, ast.FunctionDef):
            args = node.args
            assert node.returns is None and not args.kwonlyargs and not args.posonlyargs, (
                f"py3-only signature: {node.name}"
            )
            assert all(a.annotation is None for a in [*args.args, args.vararg, args.kwarg] if a is not None), node.name
        if isinstance(node, ast.Import):
            assert {a.name.split(".")[0] for a in node.names} <= STDLIB_OK, ast.dump(node)
        if isinstance(node, ast.ImportFrom):
            assert (node.module or "").split(".")[0] in STDLIB_OK, ast.dump(node)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            assert node.func.id not in ("breakpoint", "print"), node.func.id
        if isinstance(node, ast.List | ast.Tuple | ast.Set):  # [*a, b] is not Python 2
            assert not any(isinstance(e, ast.Starred) for e in node.elts), f"starred element at line {node.lineno}"


def _python27() -> str | None:
    candidates = [
        shutil.which("python2.7"),
        shutil.which("python2"),
        *sorted(glob.glob(os.path.expanduser("~/.pyenv/versions/2.7*/bin/python"))),
    ]
    for exe in candidates:
        if not exe:
            continue
        try:
            out = subprocess.run(
                [exe, "-c", "import sys; print(sys.version_info[:2])"], capture_output=True, text=True, timeout=20
            )
        except OSError:
            continue
        if out.returncode == 0 and out.stdout.strip() == "(2, 7)":
            return exe
    return None


def test_the_guard_logic_runs_under_python27() -> None:
    exe = _python27()
    if exe is None:
        pytest.skip("no Python 2.7 here (the syntax-tree check above still runs)")
    script = """
import json, nao_guard
t = [0.0]
stops = []
g = nao_guard.Guard(lambda: stops.append(t[0]), 0.5, clock=lambda: t[0])
assert g.heartbeat("a") == 0.5
t[0] = 0.45; assert not g.check()
t[0] = 0.51; assert g.check() and stops == [0.51]
t[0] = 2.0; assert not g.check() and stops == [0.51]      # once per lapse
g.heartbeat("a"); t[0] = 2.2; assert g.release("a")
t[0] = 5.0; assert not g.check() and stops == [0.51]      # released: no stop
print(nao_guard.GuardService(g).status())
args = nao_guard.build_parser().parse_args(["--pip", "10.0.0.2", "--pport", "9559"])
print(json.dumps(nao_guard.check_args(args)))
"""
    out = subprocess.run([exe, "-c", script], capture_output=True, text=True, timeout=30, cwd=GUARD.parent)
    assert out.returncode == 0, out.stderr
    status, url = out.stdout.strip().splitlines()
    assert json.loads(status)["stops"] == 1 and json.loads(url) == ["tcp://10.0.0.2:9559", 0.5]
    bad = subprocess.run([exe, str(GUARD), "--url", "http://nao"], capture_output=True, text=True, timeout=30)
    assert bad.returncode == 2 and "tcp://HOST:PORT" in bad.stderr


# ---------------------------------------------------------------- against the fake NAOqi

qi = pytest.importorskip("qi")
from fakes.fake_naoqi import FakeNaoqi  # noqa: E402


def start_guard(url: str, log: Path, *extra: str) -> subprocess.Popen[bytes]:
    """The guard as the robot runs it (the file alone), logging to ``log``."""
    with open(log, "wb") as fh:
        return subprocess.Popen([sys.executable, str(GUARD), "--url", url, *extra], stdout=fh, stderr=subprocess.STDOUT)


def guard_proxy(session: Any, timeout_s: float = 20.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return session.service("BipedteleGuard")
        except RuntimeError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def heartbeat_for(guard: Any, seconds: float, owner: str = "test") -> float:
    """Heartbeat at 20 Hz for ``seconds``; the wall time of the last acknowledged one."""
    last = 0.0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        assert guard.heartbeat(owner) == pytest.approx(0.5)
        last = time.time()
        time.sleep(0.05)
    return last


def test_the_guard_stops_a_walking_nao_once_per_lapse_of_the_heartbeats(tmp_path: Path) -> None:
    with FakeNaoqi() as fake:
        proc = start_guard(fake.url, tmp_path / "guard.log")
        session = qi.Session()
        try:
            session.connect(fake.url)
            guard = guard_proxy(session)
            assert guard.version() == "bipedtele-guard 1"
            motion = session.service("ALMotion")
            motion.wakeUp()
            motion.move(0.05, 0.0, 0.0, [])
            time.sleep(1.0)
            assert fake.calls("stopMove") == []  # not armed before the first heartbeat
            last = heartbeat_for(guard, 1.0)
            time.sleep(1.5)
            stops = [c[3] for c in fake.calls("stopMove")]
            assert len(stops) == 1, stops  # once per lapse
            assert 0.45 <= stops[0] - last <= 0.6, stops[0] - last
            assert fake.state()["vel"] == [0.0, 0.0, 0.0]
            status = json.loads(guard.status())
            assert status["stops"] == 1 and not status["armed"] and status["owner"] == "test"

            motion.move(0.05, 0.0, 0.0, [])  # a second walk, a second lapse
            last = heartbeat_for(guard, 0.5, owner="other")
            time.sleep(1.0)
            stops = [c[3] for c in fake.calls("stopMove")]
            assert len(stops) == 2 and 0.45 <= stops[1] - last <= 0.6

            heartbeat_for(guard, 0.3, owner="other")  # a clean goodbye: no stop
            assert guard.release("other")
            time.sleep(1.0)
            assert len(fake.calls("stopMove")) == 2
        finally:
            session.close()
            proc.terminate()
            assert proc.wait(10) == 0, (tmp_path / "guard.log").read_text()
    log = (tmp_path / "guard.log").read_text()
    assert "no heartbeat from test" in log and "released by other" in log


def test_the_guard_registers_again_when_naoqi_comes_back(tmp_path: Path) -> None:
    fake = FakeNaoqi()
    fake.start()
    proc = start_guard(fake.url, tmp_path / "guard.log")
    try:
        s1 = qi.Session()
        s1.connect(fake.url)
        guard_proxy(s1).version()
        s1.close()
        fake.kill()
        time.sleep(0.5)
        fake.start()
        s2 = qi.Session()
        s2.connect(fake.url)
        guard = guard_proxy(s2, timeout_s=30.0)
        motion = s2.service("ALMotion")
        motion.wakeUp()
        motion.move(0.05, 0.0, 0.0, [])
        last = heartbeat_for(guard, 0.5)
        time.sleep(1.0)
        stops = [c[3] for c in fake.calls("stopMove")]
        assert len(stops) == 1 and stops[0] - last <= 0.6
        s2.close()
    finally:
        proc.terminate()
        proc.wait(10)
        fake.kill()
    assert "lost NAOqi" in (tmp_path / "guard.log").read_text()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--naoqi-url", "http://nao:9559"], "tcp://HOST:PORT"),
        (["--naoqi-url", "tcp://127.0.0.1:9559", "--lapse", "0"], "--lapse"),
    ],
)
def test_nao_guard_command_errors_are_one_line(args: list[str], needle: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "nao-guard", *args], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], proc.stderr
