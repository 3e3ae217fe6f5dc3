"""Benchmark: how many leader-robot pairs one router and this machine hold at 100 Hz (issue 23).

    .venv/bin/python bench/fleet.py [--pairs 1,2,4] [--seconds 20] [--rate-hz 100]
        [--camera-fps 10] [--json F] [--keep]

For each N of ``--pairs``: ``bipedtele setup fleet`` with robots ``nao1..naoN`` and
operators ``op1..opN`` (``opK=naoK``) and an observer of all, on 127.0.0.1 as written (TLS with mutual
certificates, a password per user, the per-robot ACL, one message key per robot); then
the router, the N sim followers (control and feedback at ``--rate-hz``, the head camera at
``--camera-fps``, recording) and the N scripted leaders (5 cm/s forward and 5 deg/s
turn, cockpit off, recording), each from its written profile, all on this machine. After
a 5 s warm-up, ``--seconds`` of steady walking are measured:

- per pair: the follower's control ticks per second and the robot time it gave up or
  caught up (its Status counters ``ticks``, ``steps_dropped``, ``steps_caught_up`` of the
  real-time stepper, read from its ``status/sent`` records at both ends of the window: a
  robot that cannot run in real time gives up robot time rather than lag); feedback sent
  per second (ticks, plus one per command applied between ticks); h1 (a command's receipt
  on the follower minus its send stamp; one clock, so the true one-way delay) and h2 (a
  feedback's receipt on the leader minus its stamp), p50/p99 [ms]; commands the leader
  sent per second; the leader's haptic loop rate and p99 period error (its closing line);
- CPU of every process [% of one core] over the measured window (user + system, the
  process and its children), and the machine's load;
- a verdict per N, by a rule fixed here, not tuned: **holds** when every follower ticked
  at least 98 % of ``--rate-hz`` and gave up no robot time, every leader sent at least
  98 % of its 100 commands per second, and every h1 and h2 p99 stayed under 20 ms.

After the window, ``bipedtele status`` as the observer (its fleet view) is printed.

A run whose processes did not all start (or walk) is reported as such. Figures are what
they are; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from bipedtele.recording.format import RecordingError, read_records
from bipedtele.tools.setup_fleet import write_fleet

CLI = [sys.executable, "-m", "bipedtele.cli"]
WARMUP_S = 5.0
CMD_RATE_HZ = 100.0  # the leader's default command rate
CLK_TCK = os.sysconf("SC_CLK_TCK")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _tree(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
        except OSError:
            continue
    return out


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its live descendants."""
    total = 0
    for p in _tree(pid):
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])  # utime, stime (fields 14, 15)
        except (OSError, IndexError, ValueError):
            continue
    return total / CLK_TCK


class Procs:
    """Processes of one run, each in its own process group, logs in ``folder``."""

    def __init__(self, folder: Path, cwd: Path) -> None:
        self.folder, self.cwd = folder, cwd
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, argv: list[str]) -> None:
        with open(self.folder / f"{name}.log", "wb") as log:
            self.procs[name] = subprocess.Popen(
                argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                cwd=self.cwd,
            )

    def log(self, name: str) -> str:
        return (self.folder / f"{name}.log").read_text(errors="replace")

    def wait_log(self, name: str, text: str, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        while text not in self.log(name):
            if self.procs[name].poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"{name} did not start:\n{self.log(name)[-1500:]}")
            time.sleep(0.1)

    def stop(self, name: str) -> None:
        p = self.procs[name]
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGINT)
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=5)

    def close(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name)


def _records(path: Path) -> list[Any]:
    try:
        return list(read_records(path))
    except (RecordingError, OSError):
        return []


def _ms(xs: list[float] | np.ndarray) -> dict[str, float | None]:
    a = np.asarray(xs, dtype=float) * 1000.0
    if a.size == 0:
        return {"p50": None, "p99": None}
    return {"p50": round(float(np.percentile(a, 50)), 2), "p99": round(float(np.percentile(a, 99)), 2)}


def _walking(path: Path) -> bool:
    states = [r.data.get("state") for r in _records(path) if r.topic == "feedback/sent"][-20:]
    return len(states) == 20 and all(s == "walking" for s in states)


def _leader_loop(log: str) -> dict[str, float | None]:
    m = re.findall(r"loop ([\d.]+) Hz, p99 period error ([\d.]+) ms", log)
    return {"haptic_hz": float(m[-1][0]), "haptic_err_p99_ms": float(m[-1][1])} if m else {"haptic_hz": None}


def _counters_at(frs: list[Any], t: float) -> tuple[float, dict[str, int]] | None:
    """The follower's last ``status/sent`` at or before ``t``: (its time, its counters)."""
    best = None
    for r in frs:
        if r.topic == "status/sent" and r.t_recv <= t:
            best = (r.t_recv, dict(r.data["counters"]))
    return best


def pair_figures(f_rec: Path, l_rec: Path, t0: float, t1: float, rate_hz: float) -> dict[str, Any]:
    """One pair's figures over the wall-clock window [t0, t1]."""
    frs, lrs = _records(f_rec), _records(l_rec)
    a, b = _counters_at(frs, t0), _counters_at(frs, t1)
    tick: dict[str, Any] = {"follower_hz": None, "steps_dropped": None, "steps_caught_up": None}
    if a is not None and b is not None and b[0] > a[0] and "ticks" in b[1]:
        span_s = b[0] - a[0]
        tick = {
            "follower_hz": round((b[1]["ticks"] - a[1].get("ticks", 0)) / span_s, 1),
            "steps_dropped": b[1]["steps_dropped"] - a[1].get("steps_dropped", 0),
            "steps_caught_up": b[1]["steps_caught_up"] - a[1].get("steps_caught_up", 0),
        }
    h1 = [r.t_recv - r.data["t"] for r in frs if r.topic == "cmd/recv" and t0 <= r.t_recv <= t1]
    h2 = [r.t_recv - r.data["t"] for r in lrs if r.topic == "feedback/recv" and t0 <= r.t_recv <= t1]
    sent = sum(1 for r in lrs if r.topic == "cmd/sent" and t0 <= r.t_recv <= t1)
    fb = sum(1 for r in frs if r.topic == "feedback/sent" and t0 <= r.data["t"] <= t1)
    span = t1 - t0
    return {
        **tick,
        "feedback_hz": round(fb / span, 1),
        "h1_ms": _ms(h1),
        "h2_ms": _ms(h2),
        "cmd_hz": round(sent / span, 1),
    }


def holds(pairs: list[dict[str, Any]], rate_hz: float) -> dict[str, bool]:
    """The verdict's rule (module docstring), in its two parts: ``rate`` and ``delay``."""
    rate = all(
        p["follower_hz"] is not None
        and p["follower_hz"] >= 0.98 * rate_hz
        and not p["steps_dropped"]
        and p["cmd_hz"] >= 0.98 * CMD_RATE_HZ
        for p in pairs
    )
    delay = all(
        p["h1_ms"]["p99"] is not None
        and p["h2_ms"]["p99"] is not None
        and p["h1_ms"]["p99"] < 20.0
        and p["h2_ms"]["p99"] < 20.0
        for p in pairs
    )
    return {"rate": rate, "delay": delay, "holds": rate and delay}


def _start_pairs(procs: Procs, robots: list[str], port: int, logs: Path, rates: tuple[float, float]) -> None:
    """The router, every robot's follower, then every operator's walking scripted leader (each ready)."""
    rate_hz, camera_fps = rates
    procs.start(
        "router",
        [*CLI, "router", "--config", "router/bipedtele.toml", "--set", f'network.listen=["tls/127.0.0.1:{port}"]'],
    )
    procs.wait_log("router", "listening", 30)
    for k, r in enumerate(robots, 1):
        rate = ["--set", f"follower.control_rate_hz={rate_hz:g}", "--set", f"follower.feedback_rate_hz={rate_hz:g}"]
        camera = ["--set", f"follower.camera_fps={camera_fps:g}", "--record", str(logs / f"follower{k}.mcap")]
        procs.start(f"follower{k}", [*CLI, "follower", "--config", f"robot-{r}/bipedtele.toml", *rate, *camera])
    for k in range(1, len(robots) + 1):
        procs.wait_log(f"follower{k}", "ready", 90)
    script = ["--set", "leader.script=[[0, 5, 5], [3600, 5, 5]]", "--set", 'leader.script_interp="step"']
    for k, r in enumerate(robots, 1):
        rest = ["--set", "leader.cockpit=false", "--record", str(logs / f"leader{k}.mcap")]
        procs.start(
            f"leader{k}",
            [*CLI, "leader", "--config", f"operator-op{k}/{r}.toml", "--operator", "scripted", *script, *rest],
        )
    for k in range(1, len(robots) + 1):
        procs.wait_log(f"leader{k}", "leader ready", 60)


def run_fleet(n: int, seconds: float, rate_hz: float, camera_fps: float, work: Path) -> dict[str, Any]:
    """Set up and run ``n`` pairs; return every figure."""
    port = free_port()
    robots = [f"nao{k}" for k in range(1, n + 1)]
    fleet = write_fleet(
        work / "fleet",
        "127.0.0.1",
        robots,
        {f"op{k}": (f"nao{k}",) for k in range(1, n + 1)},
        port,
        {"watcher": tuple(robots)},
    )
    logs = work / "logs"
    logs.mkdir()
    procs = Procs(logs, fleet.out)
    out: dict[str, Any] = {"pairs": n}
    try:
        _start_pairs(procs, robots, port, logs, (rate_hz, camera_fps))
        end = time.monotonic() + 90
        while not all(_walking(logs / f"follower{k}.mcap") for k in range(1, n + 1)):
            if time.monotonic() > end:
                raise RuntimeError("the robots did not all walk within 90 s")
            time.sleep(0.5)
        time.sleep(WARMUP_S)
        cpu0 = {name: cpu_s(p.pid) for name, p in procs.procs.items()}
        load0 = os.getloadavg()[0]
        t0 = time.time()
        time.sleep(seconds)
        t1 = time.time()
        cpu1 = {name: cpu_s(p.pid) for name, p in procs.procs.items()}
        out["cpu_pct"] = {name: round(100.0 * (cpu1[name] - cpu0[name]) / (t1 - t0), 1) for name in cpu0}
        out["load1"] = round(max(load0, os.getloadavg()[0]), 2)
        out["alive"] = {name: p.poll() is None for name, p in procs.procs.items()}
        # the fleet view, as an observer sees it (after the measured window)
        view = subprocess.run(
            [*CLI, "status", "--config", "observer-watcher/bipedtele.toml"],
            cwd=fleet.out,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        out["status_view"] = view.stdout if view.returncode == 0 else f"(failed: {view.stderr.strip()[-300:]})"
    except RuntimeError as exc:
        out["error"] = str(exc)
        return out
    finally:
        procs.close()
    out["pair"] = [
        {
            **pair_figures(logs / f"follower{k}.mcap", logs / f"leader{k}.mcap", t0, t1, rate_hz),
            **_leader_loop(procs.log(f"leader{k}")),
        }
        for k in range(1, n + 1)
    ]
    out.update(holds(out["pair"], rate_hz))
    return out


def _print(res: dict[str, Any], rate_hz: float) -> None:
    n = res["pairs"]
    if "error" in res:
        print(f"\n{n} pair(s): did not run: {res['error'][:600]}")
        return
    print(
        f"\n{n} pair(s) on one router, follower at {rate_hz:g} Hz: holds = {res['holds']} (rate {res['rate']}, "
        f"h1/h2 p99 < 20 ms {res['delay']}; load {res['load1']})"
    )
    print(
        "  pair | ticks/s | robot steps given up / caught up | feedback/s | h1 p50/p99 ms | h2 p50/p99 ms | "
        "cmd/s | haptic Hz | CPU follower/leader %"
    )
    for k, p in enumerate(res["pair"], 1):
        h1, h2 = p["h1_ms"], p["h2_ms"]
        cpu = res["cpu_pct"]
        print(
            f"  {k:4d} | {p['follower_hz']} | {p['steps_dropped']} / {p['steps_caught_up']} | {p['feedback_hz']} | "
            f"{h1['p50']}/{h1['p99']} | {h2['p50']}/{h2['p99']} | {p['cmd_hz']:5.1f} | {p.get('haptic_hz')} | "
            f"{cpu[f'follower{k}']}/{cpu[f'leader{k}']}"
        )
    print(f"  router CPU {res['cpu_pct']['router']} %; all alive: {all(res['alive'].values())}")
    print("  bipedtele status (the observer's fleet view, after the window):")
    print("".join(f"    {line}\n" for line in res.get("status_view", "").splitlines()), end="")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--pairs", default="1,2,4", help="comma-separated pair counts (1-8 each)")
    ap.add_argument("--seconds", type=float, default=20.0, help="measured window per run (5-120)")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="follower control and feedback rate (10-500)")
    ap.add_argument("--camera-fps", type=float, default=10.0, help="head camera rate (0: no video; 0-30)")
    ap.add_argument("--json", help="write every figure to this file")
    ap.add_argument("--keep", action="store_true", help="keep the run folders (logs, recordings)")
    a = ap.parse_args(argv)
    try:
        counts = [int(x) for x in a.pairs.split(",")]
    except ValueError:
        ap.error(f"--pairs {a.pairs!r}: allowed: comma-separated integers 1-8")
    if not all(1 <= c <= 8 for c in counts) or not 5 <= a.seconds <= 120 or not 10 <= a.rate_hz <= 500:
        ap.error("allowed: --pairs 1-8 each, --seconds 5-120, --rate-hz 10-500")
    if not 0 <= a.camera_fps <= 30:
        ap.error("allowed: --camera-fps 0-30")
    results = []
    for n in counts:
        work = Path(tempfile.mkdtemp(prefix=f"bt-fleet{n}-"))
        res = run_fleet(n, a.seconds, a.rate_hz, a.camera_fps, work)
        res["folder"] = str(work) if a.keep else None
        _print(res, a.rate_hz)
        results.append(res)
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    for key, what in (("holds", "held (rate and delay)"), ("rate", "held the rate")):
        held = [r["pairs"] for r in results if r.get(key)]
        print(f"most pairs that {what} at {a.rate_hz:g} Hz: {max(held) if held else 0} (of {counts})")
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
