"""Benchmark: the follower's control loop and the leader's damping under network attacks.

    .venv/bin/python bench/adversary.py [--baseline-s 10] [--flood-rate 10000] [--flood-s 5]

Processes on loopback, as in an intercontinental run (``[clock] mode = "ntp"`` on both
sides): router, delay proxy (h1 = 100 ms, h2 = 150 ms), the sim follower (client of the
router, recording), the scripted leader (5 cm/s, client through the proxy, recording), and
the attacker of the adversary tests (``tests/e2e/adversary_support.py``, a client of the
router). One run, phases in this order:

1. **baseline** (``--baseline-s``): no attack;
2. **ping flood**: ClockPings at ``--flood-rate`` per second for ``--flood-s`` (bounded);
3. **future-stamped**: one Feedback and one Command stamped 1 s ahead (the real sender's
   sid, the next seq), then a forged leader stream stamped 1 s ahead (50 Hz, 3 s);
4. **forged clock answers** (6 s): answers to every ping seen (real t1, forged t2/t3: the
   peer's clock 5 s ahead, a round trip of about 4 ms) and to pings never sent.

In ``ntp`` mode with the conservative split the control laws use the round trip, so a
future stamp does not reach them; the crash it causes in ``synced`` mode is shown by the
adversary tests, not here.

Printed per phase: the follower's loop period p50/p99 [ms], from the times of its
``feedback/sent`` records (feedback is asked at 1 kHz, so it goes out at every tick of the
50 Hz loop), and p99 / baseline p99 (goal: within 1.2); the pings the follower and the
leader answered during the flood; the leader's smallest alpha_m [N s/m] in the commands it
sent during phase 3 (and after) against what (40) requires for the proxy's true delays
(``schedule_damping(h1, h2)``, with the configured margin). A phase a process did not
survive is reported as such. Figures are what they are; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
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
from bipedtele.config.profile import load_config
from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import schedule_damping
from bipedtele.recording.format import RecordingError, read_records

CLI = [sys.executable, "-m", "bipedtele.cli"]
REPO = Path(__file__).resolve().parent.parent
ATTACKER = [sys.executable, str(REPO / "tests" / "e2e" / "adversary_support.py")]
FWD_S, BWD_S = 0.100, 0.150
NTP = ["--set", 'clock.mode="ntp"']


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Run:
    """The processes of one run, each in its own process group, logs in ``folder``."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        with open(self.folder / f"{name}.log", "wb") as log:
            p = subprocess.Popen(
                argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                cwd=self.folder,
            )
        self.procs[name] = p
        return p

    def log(self, name: str) -> str:
        return (self.folder / f"{name}.log").read_text(errors="replace")

    def wait_log(self, name: str, text: str, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        while text not in self.log(name):
            if self.procs[name].poll() is not None or time.monotonic() > end:
                raise SystemExit(f"{name} did not start:\n{self.log(name)[-2000:]}")
            time.sleep(0.1)

    def attack(self, name: str, args: list[str], timeout_s: float = 60.0) -> dict[str, Any]:
        p = self.start(name, [*ATTACKER, *args])
        p.wait(timeout=timeout_s)
        lines = [x for x in self.log(name).splitlines() if x.startswith("{")]
        return json.loads(lines[-1]) if lines else {"error": self.log(name)[-500:]}

    def alive(self, name: str) -> bool:
        return self.procs[name].poll() is None

    def close(self) -> None:
        for p in reversed(list(self.procs.values())):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=5)


def _records(path: Path) -> list[Any]:
    try:
        return list(read_records(path))
    except (RecordingError, OSError):
        return []


def _walking(path: Path) -> bool:
    fbs = [r.data["state"] for r in _records(path) if r.topic == "feedback/sent"]
    return len(fbs) > 50 and fbs[-50:].count("walking") == 50


def _periods(ts: list[float], t0: float, t1: float) -> np.ndarray:
    t = np.array([x for x in ts if t0 <= x <= t1])
    return np.diff(t) * 1000.0 if len(t) > 2 else np.array([])


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--baseline-s", type=float, default=10.0)
    ap.add_argument("--flood-rate", type=float, default=10_000.0)
    ap.add_argument("--flood-s", type=float, default=5.0)
    ap.add_argument("--keep", action="store_true", help="keep the run folder (logs, recordings)")
    a = ap.parse_args(argv)
    if not (1 <= a.baseline_s <= 60 and 1 <= a.flood_s <= 10 and 1 <= a.flood_rate <= 20_000):
        ap.error("--baseline-s 1-60, --flood-s 1-10, --flood-rate 1-20000")
    return a


def _start_nodes(run: Run, r_port: int, p_port: int, f_rec: Path, l_rec: Path) -> None:
    """Router, delay proxy (leader side), follower and a walking scripted leader."""
    r_ep = f"tcp/127.0.0.1:{r_port}"
    client = ["--set", 'network.mode="client"', "--set", "network.listen=[]"]
    run.start("router", [*CLI, "router", "--listen", r_ep])
    run.wait_log("router", "listening on", 30)
    delays = ["--forward", f"const:{FWD_S * 1000:g}ms", "--backward", f"const:{BWD_S * 1000:g}ms"]
    run.start(
        "proxy", [*CLI, "delay-proxy", "--listen", f"127.0.0.1:{p_port}", "--target", f"127.0.0.1:{r_port}", *delays]
    )
    run.wait_log("proxy", "listening on", 30)
    follower = ["--set", "follower.camera_fps=0", "--set", "follower.feedback_rate_hz=1000", "--record", str(f_rec)]
    run.start("follower", [*CLI, "follower", *client, "--set", f'network.connect=["{r_ep}"]', *NTP, *follower])
    script = ["--set", "leader.script=[[0, 5, 0], [600, 5, 0]]", "--set", 'leader.script_interp="step"']
    leader = ["--operator", "scripted", *script, "--set", "leader.cockpit=false", "--record", str(l_rec)]
    run.start(
        "leader", [*CLI, "leader", *client, "--set", f'network.connect=["tcp/127.0.0.1:{p_port}"]', *NTP, *leader]
    )


def _attacks(run: Run, a: argparse.Namespace, r_ep: str, marks: dict[str, float], reports: dict[str, Any]) -> None:
    """The flood, future-stamped messages and forged clock answers, one after the other; ``marks`` and ``reports`` filled."""
    marks["flood"] = time.time()
    flood = ["flood", "--connect", r_ep, "--rate", f"{a.flood_rate:g}", "--seconds", f"{a.flood_s:g}"]
    reports["flood"] = run.attack("flood", flood)
    marks["flood_end"] = marks["flood"] + float(reports["flood"].get("elapsed_s", a.flood_s))
    time.sleep(2.0)
    marks["future"] = time.time()
    future = ["future", "--connect", r_ep, "--targets", "feedback,cmd", "--gap", "0.5", "--seconds", "5"]
    reports["future"] = run.attack("future", future)
    if run.alive("follower"):
        stream = ["stream", "--connect", r_ep, "--kind", "cmd", "--shift", "1.0", "--rate", "50", "--seconds", "3"]
        reports["stream"] = run.attack("stream", stream)
    marks["future_end"] = time.time()
    time.sleep(1.0)
    marks["forged"] = time.time()
    if run.alive("follower") and run.alive("leader"):
        forge = ["clock-forge", "--connect", r_ep, "--offset", "5", "--back-s", f"{BWD_S:g}", "--seconds", "6"]
        reports["forged"] = run.attack("forge", [*forge, "--rate", "4"])
    marks["forged_end"] = time.time()


def _attack_run(
    a: argparse.Namespace, folder: Path, f_rec: Path, l_rec: Path
) -> tuple[dict[str, float], dict[str, Any], dict[str, bool]]:
    """Router, delay proxy, follower and a walking leader; then the flood, future-stamped messages and forged clock answers.

    Returns the phases' wall-clock marks, the attackers' reports and who survived.
    """
    run = Run(folder)
    r_port, p_port = free_port(), free_port()
    marks: dict[str, float] = {}
    reports: dict[str, dict[str, Any]] = {}
    survived: dict[str, bool] = {}
    try:
        _start_nodes(run, r_port, p_port, f_rec, l_rec)
        end = time.monotonic() + 60
        while not _walking(f_rec):
            if time.monotonic() > end or not (run.alive("follower") and run.alive("leader")):
                raise SystemExit(f"the robot did not walk:\n{run.log('follower')[-1500:]}\n{run.log('leader')[-1500:]}")
            time.sleep(0.5)
        time.sleep(1.0)
        marks["baseline"] = time.time()
        time.sleep(a.baseline_s)
        _attacks(run, a, f"tcp/127.0.0.1:{r_port}", marks, reports)
        time.sleep(1.0)
        marks["end"] = time.time()
        survived = {n: run.alive(n) for n in ("follower", "leader")}
    finally:
        run.close()
    return marks, reports, survived


def _print_periods(a: argparse.Namespace, folder: Path, marks: dict[str, float], fb_t: list[float]) -> None:
    """The follower loop's period per phase, against the baseline's p99."""
    phases = {
        "baseline": (marks["baseline"], marks["flood"]),
        f"ping flood {a.flood_rate:g}/s": (marks["flood"], marks["flood_end"]),
        "future-stamped msgs": (marks["future"], marks["future_end"]),
        "forged clock answers": (marks["forged"], marks["forged_end"]),
    }
    print(f"follower loop period [ms] (50 Hz nominal: 20 ms); run folder {folder}")
    print(f"{'phase':24s} {'ticks':>6s} {'p50':>7s} {'p99':>7s} {'max':>7s} {'p99/base':>9s}")
    base_p99 = None
    for name, (t0, t1) in phases.items():
        p = _periods(fb_t, t0, t1)
        if len(p) < 10:
            print(f"{name:24s} {'-':>6s}  follower published no feedback (exited or stalled)")
            continue
        p50, p99, mx = np.percentile(p, 50), np.percentile(p, 99), p.max()
        base_p99 = base_p99 or p99
        print(f"{name:24s} {len(p):6d} {p50:7.2f} {p99:7.2f} {mx:7.2f} {p99 / base_p99:9.2f}")


def _print_effects(marks: dict[str, float], reports: dict[str, Any], f_recs: list[Any], l_recs: list[Any]) -> None:
    """Who answered the pings, what the forged clock answers did to alpha_m, the follower's counters."""
    fl = reports.get("flood", {})
    print(f"flood: {fl.get('sent', 0)} pings in {fl.get('elapsed_s', 0):.2f} s; answers by sid {fl.get('answered')}")
    sids = {
        "leader": next((r.data["sid"] for r in l_recs if r.topic == "cmd/sent"), None),
        "follower": next((r.data["sid"] for r in f_recs if r.topic == "feedback/sent"), None),
    }
    for who, sid in sids.items():
        print(f"  answered by the {who}: {fl.get('answered', {}).get(str(sid), 0)}")
    need = schedule_damping(FWD_S, BWD_S, load_config().get(ControlConfig)).alpha_m
    sent = [r.data for r in l_recs if r.topic == "cmd/sent" and r.data["enable"]]
    before = [d["alpha_m"] for d in sent if marks["baseline"] <= d["t"] < marks["forged"]]
    during = [d["alpha_m"] for d in sent if marks["forged"] <= d["t"] <= marks["end"]]
    if before and during:
        b, m = np.min(before, axis=0), np.min(during, axis=0)
        print(
            f"leader alpha_m [N s/m]: min before {b[0]:.2f}/{b[1]:.2f}, min under forged answers "
            f"{m[0]:.2f}/{m[1]:.2f}; (40) requires {need[0]:.2f}/{need[1]:.2f} for h1={FWD_S:g} s, h2={BWD_S:g} s "
            f"-> {'held' if all(m >= need) else 'BROKEN'}"
        )
    st = [
        r.data["counters"] for r in f_recs if r.topic == "status/sent" and marks["forged"] <= r.t_recv <= marks["end"]
    ]
    if len(st) >= 2:
        print(
            f"follower during forged answers: cmd_accepted +{st[-1]['cmd_accepted'] - st[0]['cmd_accepted']}, "
            f"cmd_too_old +{st[-1]['cmd_too_old'] - st[0]['cmd_too_old']}"
        )
    last = [r.data["counters"] for r in f_recs if r.topic == "status/sent"]
    if last:
        print(f"follower drops: { {k: v for k, v in last[-1].items() if k.startswith('drop_')} }")


def main(argv: list[str] | None = None) -> int:
    a = _parse(argv)
    folder = Path(tempfile.mkdtemp(prefix="bench-adversary-"))
    f_rec, l_rec = folder / "follower.mcap", folder / "leader.mcap"
    marks, reports, survived = _attack_run(a, folder, f_rec, l_rec)
    f_recs, l_recs = _records(f_rec), _records(l_rec)
    _print_periods(a, folder, marks, [r.data["t"] for r in f_recs if r.topic == "feedback/sent"])
    _print_effects(marks, reports, f_recs, l_recs)
    print(f"survived the run: {survived}")
    if not a.keep:
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
