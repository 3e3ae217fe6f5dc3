"""Benchmark: issue 19's table, the README's two hosts on an emulated internet path.

    .venv/bin/python bench/internet.py [--seconds 90] [--links split|single|single,split]
        [--only trace,loss1,loss5,outage,lan600-video,lan600-novideo,lan300-video,lan300-novideo,
                tbf600-video,tbf600-novideo,tbf300-video,lte,3g]
        [--json F] [--workdir DIR] [--seed N] [--leader-status-hz HZ] [--camera-fps F]

What a field engineer would do: ``bipedtele setup two-hosts --router-name router.bt.test``
once, each of its three folders copied into the working folder of its own "host" (a network
namespace), and on each host exactly the README's command from that folder::

    bipedtele router   --config router/bipedtele.toml      # router host
    bipedtele follower --config robot/bipedtele.toml       # robot host (+ --set follower.camera_fps=0: video off)
    bipedtele leader   --config operator/bipedtele.toml --duration S   # operator host, the pilot

TLS, logins, the deny-by-default ACL and the end-to-end message key as written. The
per-packet link emulator (``bipedtele link-emu`` in ``EmulatedLink``'s middle namespace)
sits between one host and the other two, which share a bridge behind side B
(``EmulatedLink.add_host``); ``router.bt.test`` resolves to the router's address in every
namespace (``/etc/netns/NS/hosts``):

- intercontinental rows: operator | emulator | router + robot. Forward (operator -> router)
  ``trace:intercontinental:h1``, backward ``h2``; loss both directions (independent);
  the outage both directions at ``--outage-at`` s (default 40) of the emulator's origin,
  which is set just before the leader starts;
- LAN rows: robot | emulator | router + operator. No delay; the robot -> router direction
  capped (``--rate-forward``) with a 64 kB queue;
- kernel tbf rows: the same hosts, the emulator transparent, the robot's interface shaped by
  the kernel's token bucket (``tc qdisc add dev D root tbf rate R burst 16kb limit 64kb``:
  a modem's or a policer's shaper, whose burst lets a start or a probe overshoot);
- cellular rows: the same hosts, 40 ms each way, the robot -> router direction replaying a
  mahimahi capacity trace (``--rate-forward mahimahi:lte|3g``, the shipped synthetic ones)
  through a 256 kB drop-tail queue.

``--links single|split`` rewrites ``links`` in the three profiles (setup writes ``split``),
so the same bench shows the old single-connection transport beside the split one.

Per run (from the programs' logs and MCAP recordings; every namespace shares this
machine's clock, so a message's receive time minus its send stamp ``t`` is its **true**
one-way delay):

- passes (``pilot: pass N/10 done`` in the leader's log), falls;
- the follower's ``watchdog_stop`` / ``operator_stop`` events while the leader ran;
- commands dropped by the follower as too old / backlog / reordered (its last Status);
- h1 per command the follower's loop took (``cmd/recv``: receive time - ``t``; commands
  superseded between two ticks are not recorded), h2 per feedback the leader received
  (``feedback/recv``); p50/p99/max in ms;
- video frames/s received by the leader; the fraction of the leader's samples (``leader/state``)
  whose ``link`` is ``capacity-limited`` / ``lossy`` / ``lost``;
- outage rows: the robot's stop latency (path cut to the first feedback the follower sent
  in a state other than ``walking``), its restart latency (path back to the first feedback
  in ``walking``), and the commands sent before the path returned that the follower applied
  after it (count, oldest age);
- gaps of the feedback at the leader (over 1 s): the first feedback after each, split into
  (a) what was in flight when the gap began (sent before it; the leader refuses what is
  older than about 2 s) and (b) the first one sent during it, and when the first fresh one
  (at most 0.5 s old) arrived;
- cellular rows: the frame rate the trace's mean capacity allows after control, from the
  mean size of the frames the leader received (``allowance``), beside the frame rate, and
  the lesser of it and the follower's configured video rate (every camera: no path lets
  video send more; ``--camera-fps F`` sets the rate per camera in every row with video,
  ``--set follower.camera_fps=F`` on the robot host, 10 as setup writes it);
- the emulator's counters (``--stats-json``);
- the paper's Table 2 of the run (``bipedtele report``: completion time of the pilot's
  passes, speed errors, delays): with ``--only trace --seconds 220`` the pilot finishes
  its 10 passes, the two-host figures to set beside the demo's.

A markdown table at the end; ``--json F`` writes every figure. Everything is torn down
(processes, namespaces, ``/etc/netns`` entries) also on Ctrl-C. This script prints
figures; it asserts nothing (tests/e2e/test_internet.py asserts).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import secrets
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the bench's own modules beside it

from bipedtele.config.profile import load_config
from bipedtele.follower.config import FollowerConfig
from bipedtele.link.shapers import load_mahimahi, mahimahi_stats
from bipedtele.recording.format import Record, read_records
from bipedtele.tools.netns import NetnsError
from bipedtele.tools.report import compute_report
from internet_figures import (
    ESTIMATE_SETTLE_S,
    LINK_STATES,
    analyse,
    gap_figures,
    outage_figures,
    video_allowance,
)
from internet_hosts import (
    CLI,
    HOSTS,
    PORT,
    REPO,
    ROUTER_NAME,
    Proc,
    Topology,
    copy_hosts,
    operator_sockets,
    setup_two_hosts,
    shape_robot,
    start,
    topology,
)
from internet_print import emu_line, row_line, table

__all__ = [
    "CLI",
    "ESTIMATE_SETTLE_S",
    "HOSTS",
    "LINK_STATES",
    "PORT",
    "REPO",
    "ROUTER_NAME",
    "Condition",
    "analyse",
    "conditions",
    "emu_line",
    "gap_figures",
    "main",
    "outage_figures",
    "row_line",
    "run_condition",
    "setup_two_hosts",
    "table",
    "video_allowance",
]


@dataclass(frozen=True)
class Condition:
    """One row: where the emulator sits and what it does."""

    name: str
    label: str
    topology: str  # "intercontinental": operator | emu | router+robot; "lan": robot | emu | router+operator
    emulator: tuple[str, ...] = ()  # impairments besides the delays
    video: bool = True
    outage: tuple[float, float] | None = None  # (at, for) [s] of the emulator's origin, both directions
    tbf: tuple[str, ...] = ()  # the kernel's tbf on the robot's interface (`tc qdisc add ... root tbf` ARGS)
    camera_fps: float | None = None  # the follower's video rate per camera [Hz] (None: its profile's)


def conditions(outage_at: float = 40.0) -> dict[str, Condition]:
    """The issue's rows, by name."""
    both = lambda opt, v: (f"--{opt}-forward", v, f"--{opt}-backward", v)  # noqa: E731
    out = f"at={outage_at:g}s,for=3s"
    lan = lambda rate: ("--rate-forward", rate, "--queue-forward", "64kB")  # noqa: E731
    # the kernel's token bucket as a modem or a policer has it: 16 kB burst, 64 kB queue
    tbf = lambda rate: ("rate", rate, "burst", "16kb", "limit", "64kb")  # noqa: E731

    # a cellular uplink: a mahimahi capacity trace with a deep drop-tail queue, 40 ms each way
    def cell(name: str) -> tuple[str, ...]:
        return (
            "--forward",
            "const:40ms",
            "--backward",
            "const:40ms",
            "--rate-forward",
            f"mahimahi:{name}",
            "--queue-forward",
            "256kB",
        )

    rows = [
        Condition("trace", "shipped trace", "intercontinental"),
        Condition("loss1", "+ 1 % loss", "intercontinental", both("loss", "1%")),
        Condition("loss5", "+ 5 % loss", "intercontinental", both("loss", "5%")),
        Condition("outage", "+ 3 s outage", "intercontinental", both("outage", out), outage=(outage_at, 3.0)),
        Condition("lan600-video", "LAN 600 kbit/s uplink, video on", "lan", lan("600kbit")),
        Condition("lan600-novideo", "LAN 600 kbit/s uplink, video off", "lan", lan("600kbit"), video=False),
        Condition("lan300-video", "LAN 300 kbit/s uplink, video on", "lan", lan("300kbit")),
        Condition("lan300-novideo", "LAN 300 kbit/s uplink, video off", "lan", lan("300kbit"), video=False),
        Condition("tbf600-video", "kernel tbf 600 kbit/s (16 kB burst), video on", "lan", tbf=tbf("600kbit")),
        Condition(
            "tbf600-novideo", "kernel tbf 600 kbit/s (16 kB burst), video off", "lan", tbf=tbf("600kbit"), video=False
        ),
        Condition("tbf300-video", "kernel tbf 300 kbit/s (16 kB burst), video on", "lan", tbf=tbf("300kbit")),
        Condition("lte", "LTE trace (synthetic, 1.95 Mbit/s, 4 s gap), 40 ms", "lan", cell("lte")),
        Condition("3g", "3G trace (synthetic, 0.52 Mbit/s, 9 s near zero), 40 ms", "lan", cell("3g")),
    ]
    return {c.name: c for c in rows}


# --------------------------------------------------------------------------- one run


def _cellular_allowance(
    cond: Condition, l_rec: list[Record], f_rec: list[Record], robot_profile: Path
) -> dict[str, Any] | None:
    """A cellular row's video allowance (:func:`video_allowance` over the pilot's run); None for other rows.

    ``robot_profile``: the follower's profile, for its configured video rate (every camera).
    """
    trace = next((x.split(":", 1)[1] for x in cond.emulator if x.startswith("mahimahi:")), None)
    sent = [r.t_recv for r in l_rec if r.topic == "cmd/sent"]
    if trace is None or not sent:
        return None
    fcfg = load_config(robot_profile).get(FollowerConfig)
    most = (fcfg.camera_fps if cond.camera_fps is None else cond.camera_fps) * len(fcfg.cameras)
    return video_allowance(l_rec, f_rec, mahimahi_stats(load_mahimahi(trace))["mean_bps"], sent[0], sent[-1], most)


def _emulate(top: Topology, base: list[str], cond: Condition, seed: int, stats: Path) -> float:
    """Start the emulator with ``cond``'s impairments, its origin now; return the origin [s, wall]."""
    t0 = time.time()
    top.link.start_emulator(
        [
            *base,
            *cond.emulator,
            "--t0",
            f"{t0:.6f}",
            "--seed",
            str(seed),
            "--stats-every",
            "10",
            "--stats-json",
            str(stats),
        ]
    )
    return t0


@dataclass
class _Run:
    """One run's programs and what was seen while they ran."""

    leader: Proc
    t0: float
    leader_rc: int | None
    sockets: dict[str, int] | None


def _drive(
    cond: Condition,
    top: Topology,
    homes: dict[str, Path],
    commands: dict[str, list[str]],
    run_dir: Path,
    procs: list[Proc],
    *,
    base: list[str],
    seconds: float,
    seed: int,
    say: Any,
    leader_extra: tuple[str, ...],
) -> _Run:
    """Start the router, the follower and the leader in their hosts, and wait for the pilot's run to end."""
    stats = run_dir / "linkemu.json"

    def go(host: str, name: str, extra: list[str]) -> Proc:
        p = start(name, [*commands[host], *extra], netns=top.ns[host], cwd=homes[host], log_dir=run_dir)
        procs.append(p)
        return p

    if cond.tbf:
        shape_robot(top, cond.tbf)
    router = go("router", "router", [])
    router.wait_log(r"router: \S+ listening on", 60.0)
    t0 = _emulate(top, base, cond, seed, stats) if cond.topology == "lan" else None  # the robot's path crosses it
    fps = 0.0 if not cond.video else cond.camera_fps
    follower = go("robot", "follower", [] if fps is None else ["--set", f"follower.camera_fps={fps:g}"])
    follower.wait_log(r"follower \S+ ready", 120.0)
    if t0 is None:  # the origin of the trace and the outage: just before the leader starts
        t0 = _emulate(top, base, cond, seed, stats)
    leader = go("operator", "leader", ["--duration", f"{seconds:g}", *leader_extra])
    deadline = time.monotonic() + seconds + 180.0  # bounded: start-up through the path, then S
    t_ss: float | None = time.monotonic() + min(10.0, seconds / 2)
    sockets = None
    while leader.alive() and time.monotonic() < deadline:
        if t_ss is not None and time.monotonic() > t_ss:  # which links the operator's host holds
            t_ss, sockets = None, operator_sockets(top.ns["operator"], run_dir / "ss-operator.txt")
        if not follower.alive():
            say(f"  follower exited early:\n{follower.tail()}")
            break
        time.sleep(0.5)
    leader_rc = leader.stop(15.0)
    follower.stop(15.0)
    router.stop(10.0)
    return _Run(leader, t0, leader_rc, sockets)


def run_condition(
    cond: Condition,
    links: str | None,
    seconds: float,
    setup_out: Path,
    commands: dict[str, list[str]],
    run_dir: Path,
    *,
    seed: int = 1,
    startup_s: float = 5.0,
    say: Any = print,
    tag: str | None = None,
    leader_extra: tuple[str, ...] = (),
) -> dict[str, Any]:
    """One run of ``cond`` with ``links`` (None: as setup wrote); return its figures (``leader_extra``: more leader arguments)."""
    run_dir.mkdir(parents=True)
    homes = copy_hosts(setup_out, run_dir, links)
    procs: list[Proc] = []
    models = ("const:0ms", "const:0ms")
    if cond.topology == "intercontinental":
        models = ("trace:intercontinental:h1", "trace:intercontinental:h2")
    with topology(cond.topology, run_dir / "linkemu.log", tag) as top:
        try:
            run = _drive(
                cond,
                top,
                homes,
                commands,
                run_dir,
                procs,
                base=["--forward", models[0], "--backward", models[1]],
                seconds=seconds,
                seed=seed,
                say=say,
                leader_extra=leader_extra,
            )
        finally:
            for p in procs:
                p.stop(5.0)
            top.link.stop_emulator()
    return _figures(cond, links, run, homes, run_dir, models, startup_s)


def _figures(
    cond: Condition,
    links: str | None,
    run: _Run,
    homes: dict[str, Path],
    run_dir: Path,
    models: tuple[str, str],
    startup_s: float,
) -> dict[str, Any]:
    """Every figure of a run that ended, from its recordings and logs (written to ``run_dir/result.json``)."""
    leader, t0 = run.leader, run.t0
    res: dict[str, Any] = {
        "condition": cond.name,
        "label": cond.label,
        "links": links or "as written",
        "leader_rc": run.leader_rc,
        "run_dir": str(run_dir),
        "operator_sockets": run.sockets,
        "leader_summary": _summary(leader),
    }
    l_path, f_path = _recording(homes["operator"], "leader"), _recording(homes["robot"], "follower")
    if l_path is None or f_path is None:
        res["error"] = f"no recording (leader {l_path}, follower {f_path}); leader log:\n{leader.tail()}"
        return res
    # forward is operator -> router (h1) across the ocean, robot -> router (h2) on the LAN
    h_models = models if cond.topology == "intercontinental" else models[::-1]
    outage = (t0 + cond.outage[0], t0 + cond.outage[0] + cond.outage[1]) if cond.outage else None
    l_rec, f_rec = list(read_records(l_path)), list(read_records(f_path))
    res.update(analyse(l_rec, f_rec, leader.log(), outage_wall=outage, startup_s=startup_s, emulated=(*h_models, t0)))
    # Table 2 of the run (`bipedtele report`): completion time and speed errors, as the demo prints
    res["table2"] = compute_report(l_rec, f_rec)
    res["allowance"] = _cellular_allowance(cond, l_rec, f_rec, homes["robot"] / "robot" / "bipedtele.toml")
    try:
        res["linkemu"] = json.loads((run_dir / "linkemu.json").read_text())
    except (OSError, ValueError):
        res["linkemu"] = None
    res["emulator_t0"] = t0
    (run_dir / "result.json").write_text(json.dumps(res, indent=2, default=str) + "\n")
    return res


def _summary(leader: Proc) -> str:
    """The leader's result line (or the end of its log)."""
    summary = [ln for ln in leader.log().splitlines() if ln.startswith("leader:")]
    return summary[-1] if summary else leader.tail(3)


def _recording(home: Path, role: str) -> Path | None:
    """The newest MCAP recording of ``role`` in a host's ``runs/`` (None: none)."""
    files = sorted((home / "runs").glob(f"{role}-*.mcap"))
    return files[-1] if files else None


# --------------------------------------------------------------------------- main


def _leader_extra(p: argparse.ArgumentParser, hz: float | None) -> tuple[str, ...]:
    """The leader's extra arguments for ``--leader-status-hz`` (exits 2 naming the range when out of it)."""
    if hz is not None and not (math.isfinite(hz) and 0.1 <= hz <= 50.0):
        p.error(f"--leader-status-hz {hz!r}: allowed: 0.1 to 50")
    return () if hz is None else ("--set", f"leader.status_rate_hz={hz:g}")


def _parser(all_conds: dict[str, Condition]) -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    p = argparse.ArgumentParser(
        description=(__doc__ or "").split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--seconds", type=float, default=90.0, help="the pilot's run per condition (leader --duration)")
    p.add_argument("--only", default=",".join(all_conds), help=f"conditions, comma-separated: {','.join(all_conds)}")
    p.add_argument(
        "--links", default="split", help="single, split, or both as 'single,split' (profiles' [network] links)"
    )
    p.add_argument(
        "--outage-at", type=float, default=40.0, help="outage start [s] of the emulator's origin (leader start)"
    )
    p.add_argument("--seed", type=int, default=1, help="the emulator's seed")
    p.add_argument("--leader-status-hz", type=float, default=None, help="[leader] status_rate_hz (default: setup's)")
    p.add_argument(
        "--camera-fps", type=float, default=None, help="the follower's video rate per camera in rows with video [Hz]"
    )
    p.add_argument("--tag", default="", help="prefix of the namespaces' 4-character tag (random hex after it)")
    p.add_argument("--json", default=None, metavar="F", help="write every figure to F")
    p.add_argument(
        "--workdir", default=None, metavar="DIR", help="keep logs and recordings here (default: a temp dir, removed)"
    )
    return p


def _rows(
    args: argparse.Namespace,
    conds: dict[str, Condition],
    names: list[str],
    links: list[str],
    work: Path,
    leader_extra: tuple[str, ...],
) -> list[dict[str, Any]]:
    """Run every row asked for, printing each as it ends; return their figures (so far, on Ctrl-C)."""
    rows: list[dict[str, Any]] = []
    try:
        setup_out = work / f"setup-{secrets.token_hex(2)}"
        commands = setup_two_hosts(setup_out)
        print(
            f"setup two-hosts: {setup_out}; commands: "
            + "; ".join(f"{h}: bipedtele {' '.join(c)}" for h, c in commands.items())
        )
        for name in names:
            for lk in links:
                cond = conds[name]
                t_start = time.monotonic()
                print(f"--- {cond.label} [{lk}] ({args.seconds:g} s) ...", flush=True)
                try:
                    r = run_condition(
                        cond,
                        lk,
                        args.seconds,
                        setup_out,
                        commands,
                        work / f"{name}-{lk}-{secrets.token_hex(2)}",
                        seed=args.seed,
                        tag=args.tag + secrets.token_hex(2)[: 4 - len(args.tag)],
                        leader_extra=leader_extra,
                    )
                except (RuntimeError, NetnsError) as exc:
                    r = {"condition": name, "label": cond.label, "links": lk, "error": str(exc)}
                r["wall_s"] = round(time.monotonic() - t_start, 1)
                rows.append(r)
                print(row_line(r))
                print("  " + emu_line(r.get("linkemu")))
                if "leader_summary" in r:
                    print("  " + r["leader_summary"])
                sys.stdout.flush()
    except KeyboardInterrupt:
        print("interrupted: torn down", file=sys.stderr)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the rows asked for (module docstring); 2 without root or iproute2."""
    p = _parser(conditions())
    args = p.parse_args(argv)
    conds = conditions(args.outage_at)
    if args.camera_fps is not None:
        if not (math.isfinite(args.camera_fps) and 0 < args.camera_fps <= 30):
            p.error(f"--camera-fps {args.camera_fps!r}: allowed: above 0, at most 30 (frames/s per camera)")
        conds = {
            k: replace(c, camera_fps=args.camera_fps, label=f"{c.label}, camera {args.camera_fps:g} fps")
            if c.video
            else c
            for k, c in conds.items()
        }
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    bad = [n for n in names if n not in conds]
    links = [x.strip() for x in args.links.split(",") if x.strip()]
    if bad or not names or any(x not in ("single", "split", "split-tcp") for x in links):
        p.error(f"--only {args.only!r} / --links {args.links!r}: allowed: {', '.join(conds)}; single, split, split-tcp")
    if os.geteuid() != 0 or shutil.which("ip") is None:
        sys.stderr.write("bench/internet.py: needs root and iproute2 (network namespaces, raw sockets)\n")
        return 2

    def on_term(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    for sig in (signal.SIGTERM, signal.SIGINT):  # SIGINT too: a background job may have it ignored
        signal.signal(sig, on_term)
    leader_extra = _leader_extra(p, args.leader_status_hz)
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="bt-internet-"))
    work.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    try:
        rows = _rows(args, conds, names, links, work, leader_extra)
    finally:
        if rows:
            print()
            print(table(rows))
        if args.json:
            Path(args.json).write_text(
                json.dumps({"seconds": args.seconds, "rows": rows}, indent=2, default=str) + "\n"
            )
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
