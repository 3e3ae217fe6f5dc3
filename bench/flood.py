"""Benchmark: genuine command and feedback age, memory and drops under a flood of fake-signed payloads.

    .venv/bin/python bench/flood.py [--size 16777216] [--flood-rate 4] [--flood-s 10]
                                    [--baseline-s 10] [--json F] [--keep]

Issue 20, finding 3. Processes on loopback: a router, the sim follower (client of the
router, recording) and the scripted leader (5 cm/s, client, recording), both with a
message key and ``[clock] mode = "synced"`` (one machine, one clock); then an attacker, a
plain Zenoh client of the router (no login: the router has no ACL), started by this file
(``--attack``). One run, two phases:

1. **baseline** (``--baseline-s``): no attack;
2. **flood** (``--flood-s``): the attacker puts ``--flood-rate`` payloads per second on each
   of ``bipedtele/nao1/cmd`` and ``bipedtele/nao1/feedback`` (``--target video``: on
   ``bipedtele/nao1/video``, with ``--video-fps`` genuine frames beside), each ``--size``
   bytes long and framed as a genuine payload of its key: the 8 bytes in clear (magic, key
   id) of one seen on the wire, else a session key's magic and a random key id; then random
   bytes.

Printed per phase, side by side: the genuine command age at the follower (its ``cmd/recv``
records: receive time minus the command's send stamp ``t``, one clock) and the genuine
feedback age at the leader (``feedback/recv``), p50/p99/max [ms]; the commands the follower
accepted per second; the leader's haptic ticks missed per second; the largest resident memory (VmRSS, sampled every 0.5 s) of the
follower, the leader and the router [MB]; the drop counters that grew during the phase, by
reason, from each side's ``status/sent`` records. A second useful run is ``--size 100000``:
a payload Zenoh delivers, which the receivers should drop by size (``too_large``) before
the MAC. Figures are what they are; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import math
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
from bipedtele.recording.format import RecordingError, read_records

CLI = [sys.executable, "-m", "bipedtele.cli"]
ROBOT = "nao1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _sniff_prefix(session: Any, key: str, seconds: float) -> bytes | None:
    """The first 8 bytes (magic and key id, in clear) of a genuine payload on ``key``, or None."""
    got: list[bytes] = []
    sub = session.declare_subscriber(key, lambda sample: got.append(sample.payload.to_bytes()[:8]))
    end = time.monotonic() + seconds
    while not got and time.monotonic() < end:
        time.sleep(0.05)
    sub.undeclare()
    return got[0] if got else None


def attack(endpoint: str, size: int, rate: float, seconds: float, target: str = "cmd,feedback") -> dict[str, Any]:
    """The attacker: fake-signed payloads of ``size`` bytes on the ``target`` keys (bounded).

    Each is framed as a genuine payload of its key: the magic and key id of one seen on the
    wire (they are in clear), else a session key's magic and a random key id; then random bytes.
    """
    import zenoh
    from bipedtele.link import auth

    magic = getattr(auth, "SESSION_MAGIC", auth.MAC_MAGIC)  # what genuine commands carry

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    body = os.urandom(max(0, size - auth.MAC_OVERHEAD))
    keys = [f"bipedtele/{ROBOT}/{k}" for k in target.split(",")]
    n_max, sent = math.ceil(rate * seconds), 0
    with zenoh.open(conf) as session:
        heads = {k: _sniff_prefix(session, k, 3.0) for k in keys}
        pubs = [session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK) for k in keys]
        time.sleep(0.5)  # let the publishers' routes settle
        t_first = time.time()
        t0 = time.monotonic()
        for i in range(n_max):
            if time.monotonic() > t0 + seconds + 5.0:  # a put that blocks cannot stretch the flood
                break
            for k, pub in zip(keys, pubs, strict=True):
                head = heads[k] or magic + os.urandom(4)
                pub.put(head + os.urandom(auth.MAC_OVERHEAD - 8) + body)
                sent += 1
            time.sleep(max(0.0, t0 + (i + 1) / rate - time.monotonic()))
        t_last = time.time()
        time.sleep(0.5)
    return {"sent": sent, "bytes": sent * size, "t_first": t_first, "t_last": t_last}


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

    def rss_mb(self, name: str) -> float:
        """Resident memory of one process [MB] (0 once it has exited)."""
        try:
            for line in Path(f"/proc/{self.procs[name].pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
        except OSError:
            pass
        return 0.0

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


def _ages(records: list[Any], topic: str, t0: float, t1: float) -> dict[str, float]:
    """Count and p50/p99/max age [ms] of the ``topic`` records received in [t0, t1]."""
    a = np.array([(r.t_recv - r.data["t"]) * 1000.0 for r in records if r.topic == topic and t0 <= r.t_recv <= t1])
    if not len(a):
        return {"n": 0, "p50": math.nan, "p99": math.nan, "max": math.nan}
    return {"n": len(a), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def _drops(records: list[Any], t0: float, t1: float) -> dict[str, int]:
    """Growth of the ``drop_*`` counters of the ``status/sent`` records from t0 to t1."""
    st = [(r.t_recv, r.data["counters"]) for r in records if r.topic == "status/sent"]
    before = next((c for t, c in reversed(st) if t <= t0), {})
    after = next((c for t, c in reversed(st) if t <= t1), {})
    grew = {k[5:]: v - before.get(k, 0) for k, v in after.items() if k.startswith("drop_")}
    return {k: v for k, v in grew.items() if v}


def _grew(records: list[Any], counter: str, t0: float, t1: float) -> int:
    """Growth of one counter of the ``status/sent`` records from t0 to t1."""
    st = [(r.t_recv, r.data["counters"]) for r in records if r.topic == "status/sent"]
    before = next((c for t, c in reversed(st) if t <= t0), {})
    after = next((c for t, c in reversed(st) if t <= t1), {})
    return int(after.get(counter, 0) - before.get(counter, 0))


def sample(run: Run, until: float, peak: dict[str, float]) -> None:
    """Sample the resident memory every 0.5 s until ``until`` (time.monotonic()), keeping each max."""
    while time.monotonic() < until:
        for name in peak:
            peak[name] = max(peak[name], run.rss_mb(name))
        time.sleep(min(0.5, max(0.0, until - time.monotonic())))


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--size", type=int, default=16 * 1024 * 1024, help="payload size [bytes]")
    ap.add_argument("--flood-rate", type=float, default=4.0, help="payloads per second on each key")
    ap.add_argument("--flood-s", type=float, default=10.0)
    ap.add_argument("--baseline-s", type=float, default=10.0)
    ap.add_argument("--target", choices=["cmd,feedback", "video"], default="cmd,feedback", help="keys flooded")
    ap.add_argument("--video-fps", type=float, default=0.0, help="the follower's genuine video (head camera) [fps]")
    ap.add_argument("--json", type=Path, help="write the figures to this file")
    ap.add_argument("--keep", action="store_true", help="keep the run folder (logs, recordings)")
    ap.add_argument("--attack", metavar="ENDPOINT", help=argparse.SUPPRESS)  # the attacker process
    a = ap.parse_args(argv)
    if not (64 <= a.size <= 64 << 20 and 0 < a.flood_rate <= 50 and 1 <= a.flood_s <= 30 and 1 <= a.baseline_s <= 60):
        ap.error("--size 64 B-64 MiB, --flood-rate 0-50, --flood-s 1-30, --baseline-s 1-60")
    return a


def _flood_run(a: argparse.Namespace, folder: Path, f_rec: Path, l_rec: Path) -> dict[str, Any]:
    """Router, follower and a walking leader; the baseline sampled, then the attacker's flood.

    Returns the attacker's report, the phases' wall-clock marks, the VmRSS peaks and who survived.
    """
    run = Run(folder)
    key = folder / "message.key"
    ep = f"tcp/127.0.0.1:{free_port()}"
    common = ["--set", 'network.mode="client"', "--set", f'network.connect=["{ep}"]', "--set", "network.listen=[]"]
    common += ["--set", f'network.message_key_file="{key}"', "--set", 'clock.mode="synced"']
    names = ("follower", "leader", "router")
    got: dict[str, Any] = {"report": {}, "marks": {}, "peaks": {}}
    try:
        subprocess.run([*CLI, "setup", "message-key", str(key)], check=True, capture_output=True, timeout=30)
        run.start("router", [*CLI, "router", "--listen", ep])
        run.wait_log("router", "listening on", 30)
        camera = ["--set", f"follower.camera_fps={a.video_fps:g}", "--set", 'follower.cameras=["head"]']
        run.start("follower", [*CLI, "follower", *common, *camera, "--record", str(f_rec)])
        script = ["--set", "leader.script=[[0, 5, 0], [600, 5, 0]]", "--set", 'leader.script_interp="step"']
        leader = ["--operator", "scripted", *script, "--set", "leader.cockpit=false", "--record", str(l_rec)]
        run.start("leader", [*CLI, "leader", *common, *leader])
        end = time.monotonic() + 90
        while not _walking(f_rec):
            if time.monotonic() > end or any(run.procs[n].poll() is not None for n in ("follower", "leader")):
                raise SystemExit(f"the robot did not walk:\n{run.log('follower')[-1500:]}\n{run.log('leader')[-1500:]}")
            time.sleep(0.5)
        time.sleep(1.0)
        marks, peaks = got["marks"], got["peaks"]
        marks["baseline"] = time.time()
        peaks["baseline"] = dict.fromkeys(names, 0.0)
        sample(run, time.monotonic() + a.baseline_s, peaks["baseline"])
        marks["baseline_end"] = time.time()
        peaks["flood"] = dict.fromkeys(names, 0.0)
        flood = ["--size", str(a.size), "--flood-rate", f"{a.flood_rate:g}", "--flood-s", f"{a.flood_s:g}"]
        attacker = run.start("attacker", [sys.executable, __file__, "--attack", ep, *flood, "--target", a.target])
        end = time.monotonic() + a.flood_s + 30.0
        while attacker.poll() is None and time.monotonic() < end:
            sample(run, time.monotonic() + 0.5, peaks["flood"])
        lines = [x for x in run.log("attacker").splitlines() if x.startswith("{")]
        got["report"] = json.loads(lines[-1]) if lines else {"error": run.log("attacker")[-500:]}
        time.sleep(2.0)  # the last status records
        got["survived"] = {n: run.procs[n].poll() is None for n in names}
    finally:
        run.close()
    return got


def _figures(a: argparse.Namespace, f_rec: Path, l_rec: Path, got: dict[str, Any]) -> dict[str, Any]:
    """Command and feedback ages, accepted commands, VmRSS and drops of the baseline and the flood."""
    report, marks, peaks = got["report"], got["marks"], got["peaks"]
    f_recs, l_recs = _records(f_rec), _records(l_rec)
    phases = {
        "baseline": (marks["baseline"], marks["baseline_end"]),
        "flood": (report.get("t_first", math.nan), report.get("t_last", math.nan)),
    }
    out: dict[str, Any] = {"size": a.size, "flood_rate": a.flood_rate, "attacker": report, "survived": got["survived"]}
    for name, (t0, t1) in phases.items():
        cmd = _ages(f_recs, "cmd/recv", t0, t1)
        t_drops = t1 + (1.0 if name == "flood" else 0.0)  # status at 2 Hz: the last payloads' drops
        out[name] = {
            "s": t1 - t0,
            "cmd_age_ms": cmd,
            "fb_age_ms": _ages(l_recs, "feedback/recv", t0, t1),
            "cmd_accepted_per_s": cmd["n"] / (t1 - t0) if t1 > t0 else math.nan,
            "rss_max_mb": peaks[name],
            "drops": {"follower": _drops(f_recs, t0, t_drops), "leader": _drops(l_recs, t0, t_drops)},
            "leader_missed_ticks": _grew(l_recs, "missed_ticks", t0, t1),
        }
    return out


def _print_figures(a: argparse.Namespace, out: dict[str, Any], folder: Path) -> None:
    report, phases = out["attacker"], ("baseline", "flood")
    sent_mb = report.get("bytes", 0) / 2**20
    print(
        f"flood: {report.get('sent', 0)} payloads of {a.size} bytes ({sent_mb:.0f} MiB) on {a.target}, "
        f"{a.flood_rate:g}/s per key; run folder {folder}"
    )
    print(f"{'':40s} {'baseline':>24s} {'flood':>24s}")
    for label, key_ in (
        ("cmd age at follower p50/p99/max", "cmd_age_ms"),
        ("fb age at leader p50/p99/max", "fb_age_ms"),
    ):
        cells = [f"{out[p][key_]['p50']:.1f}/{out[p][key_]['p99']:.1f}/{out[p][key_]['max']:.1f}" for p in phases]
        print(f"{label + ' [ms]':40s} {cells[0]:>24s} {cells[1]:>24s}")
    print(f"{'commands accepted [1/s]':40s} " + " ".join(f"{out[p]['cmd_accepted_per_s']:>24.1f}" for p in phases))
    ticks = " ".join(f"{out[p]['leader_missed_ticks'] / max(out[p]['s'], 1e-9):>24.1f}" for p in phases)
    print(f"{'leader haptic ticks missed [1/s]':40s} {ticks}")
    for who in ("follower", "leader", "router"):
        print(f"{f'{who} VmRSS max [MB]':40s} " + " ".join(f"{out[p]['rss_max_mb'][who]:>24.0f}" for p in phases))
    for who in ("follower", "leader"):
        for p in phases:
            print(f"{who} drops during {p}: {out[p]['drops'][who] or 'none'}")
    print(f"survived the run: {out['survived']}")


def main(argv: list[str] | None = None) -> int:
    a = _parse(argv)
    if a.attack:
        print(json.dumps(attack(a.attack, a.size, a.flood_rate, a.flood_s, a.target)), flush=True)
        return 0
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a kill tears the processes down too
    folder = Path(tempfile.mkdtemp(prefix="bench-flood-"))
    f_rec, l_rec = folder / "follower.mcap", folder / "leader.mcap"
    out = _figures(a, f_rec, l_rec, _flood_run(a, folder, f_rec, l_rec))
    _print_figures(a, out, folder)
    if a.json:
        a.json.write_text(json.dumps(out, indent=2) + "\n")
    if not a.keep:
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
