"""``bipedtele demo``: the whole teleoperation on one machine, with emulated delay.

Starts four processes and wires them like an intercontinental run::

    leader (client) --tcp--> delay proxy (h1 forward / h2 backward) --tcp--> router <-- follower (client)

Both sides are Zenoh clients of the router, so all their traffic crosses the proxy and
nothing bypasses the delay.

``--delay-backend netem`` (root, a kernel with ``sch_netem``) replaces the proxy by the
kernel: two network namespaces joined by a veth pair, the leader in one, the follower and
the router in the other, h1 as netem on the leader's end and h2 on the follower's, a trace
replayed by ``tc qdisc change`` at its own sample rate (:mod:`bipedtele.tools.netem_trace`);
the namespaces go on exit, also on Ctrl-C. ``--delay-backend packet`` (root, no netem
needed) puts the per-packet link emulator (``bipedtele link-emu``, docs/linkemu.md) between
a leader namespace and a router + follower namespace (:class:`EmulatedLink`): h1 forward,
h2 backward, plus ``--loss``, ``--rate-up``/``--rate-down`` and ``--outage`` if given; its
counters land in ``RUN_DIR/linkemu.json``. ``auto`` takes netem where it can and the
proxy otherwise, and says which. ``--dry-run`` prints the plan (the processes, and for
netem every ``ip``/``tc`` command with its time) and starts nothing. The demo prints the cockpit URL, waits for the operator to
finish the task (or ``--duration``), stops every process cleanly (SIGTERM, then SIGKILL
after a grace period), and prints the Table 2 report computed from the leader's
recording (the same JSON keys as ``bipedtele report``).

The core starts the leader and follower by command name, so it imports neither.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import IO, Any

from bipedtele.cli import OneLineParser, add_config_args
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.link.delaymodels import (
    MAX_DELAY_S,
    ConstDelay,
    DelayModel,
    NormalDelay,
    TraceDelay,
    UniformDelay,
    parse_delay_model,
)
from bipedtele.link.impairments import parse_loss, parse_outage, parse_rate
from bipedtele.parts import PART_GROUPS
from bipedtele.recording.foxglovelive import parse_address
from bipedtele.shutdown import shutdown_on_signals
from bipedtele.tools.demoplan import DemoPlan
from bipedtele.tools.demostatus import StatusPrinter
from bipedtele.tools.netem import netem_available
from bipedtele.tools.netem_trace import NetemReplayer, impairment_args
from bipedtele.tools.netns import (
    FOLLOWER,
    LEADER,
    SIDE_A,
    CockpitRelay,
    EmulatedLink,
    NetnsError,
    VethLink,
)

__all__ = ["DemoPlan", "add_demo_parser", "parse_delay_scale", "run_demo", "scale_delay_spec"]

LOG = logging.getLogger(__name__)

DEFAULT_DELAY = ("trace:intercontinental:h1", "trace:intercontinental:h2")
BACKENDS = ("proxy", "netem", "packet", "auto")
#: The leader reads its cockpit token from this variable (see docs/cockpit.md).
COCKPIT_TOKEN_ENV = "BIPEDTELE_COCKPIT_TOKEN"


def _say(line: str) -> None:
    """CLI output (not logging: this is what the user asked the command for)."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


@dataclass
class _Proc:
    name: str
    popen: subprocess.Popen[bytes]
    log: IO[bytes]


@contextlib.contextmanager
def _processes(plan: DemoPlan) -> Iterator[dict[str, _Proc]]:
    """Start the processes (each in its own process group); stop them all on exit."""
    procs: dict[str, _Proc] = {}
    try:
        for name, cmd in plan.commands().items():
            # 0600: the leader's log holds the cockpit token (its address), the others stay private too.
            fd = os.open(plan.run_dir / f"{name}.log", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.fchmod(fd, 0o600)  # an existing file keeps its mode through O_CREAT
            log = open(fd, "wb")  # noqa: SIM115 - closed below
            LOG.debug("starting %s: %s", name, " ".join(cmd))
            env = {**os.environ, COCKPIT_TOKEN_ENV: plan.cockpit_token} if name == "leader" else None
            popen = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=env)
            procs[name] = _Proc(name, popen, log)
            time.sleep(0.3 if name in ("router", "proxy") else 0.0)
        yield procs
    finally:
        # Leader first (it releases the robot), then follower, proxy, router.
        for name in ("leader", "follower", "proxy", "router"):
            p = procs.get(name)
            if p is not None and p.popen.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.popen.pid, signal.SIGTERM)
        deadline = time.monotonic() + 10.0
        for p in procs.values():
            try:
                p.popen.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                LOG.warning("%s did not stop on SIGTERM: killing it", p.name)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.popen.pid, signal.SIGKILL)
                p.popen.wait(timeout=5.0)
            p.log.close()


def run_demo(
    plan: DemoPlan, *, json_path: Path | None = None, quiet: bool = False, passes_total: int | None = None
) -> int:
    """Run the demo described by ``plan``; print the report. Returns the exit code.

    Unless ``quiet``, a live status line (:mod:`bipedtele.tools.demostatus`: passes k/
    ``passes_total``, elapsed, h1 + h2, falls, contacts, running speed errors) is written
    about once a second while the leader runs.
    """
    from bipedtele.recording.format import read_records
    from bipedtele.tools.report import compute_report, format_report

    plan.run_dir.mkdir(parents=True, exist_ok=True)
    plan.run_dir.chmod(0o700)  # its leader.log holds the cockpit token
    plan.t0 = time.time()  # origin of trace delay models (recorded for later checks)
    _write_plan(plan)
    with shutdown_on_signals() as stop, contextlib.ExitStack() as network:
        failed = _enter_network(plan, network)
        if failed is not None:
            return failed
        procs = network.enter_context(_processes(plan))
        if not plan.headless:
            _say(f"cockpit: http://127.0.0.1:{plan.cockpit_port}/?token={plan.cockpit_token}")
        _say(f"run folder: {plan.run_dir}  (logs and recordings)")
        leader = procs["leader"].popen
        _watch(plan, procs, stop, None if quiet else StatusPrinter(plan.record, passes_total))
        leader_rc = leader.poll()
    if not plan.record.exists():
        sys.stderr.write(f"bipedtele demo: no recording at {plan.record}; see the logs in {plan.run_dir}\n")
        return 1
    f_rec = plan.run_dir / "follower.mcap"  # its footfalls give the per-step speed errors
    report = compute_report(read_records(plan.record), follower=read_records(f_rec) if f_rec.exists() else None)
    _say(format_report(report))
    if json_path is not None:
        json_path.write_text(json.dumps(report, indent=2) + "\n")
    return 0 if leader_rc in (0, None) else 1


def _write_plan(plan: DemoPlan) -> None:
    """Write ``plan.json`` into the run folder: the delays, the backend and the command lines."""
    (plan.run_dir / "plan.json").write_text(
        json.dumps(
            {
                "t0": plan.t0,
                "forward": plan.forward,
                "backward": plan.backward,
                "backend": plan.backend,
                "commands": plan.commands(),
            },
            indent=2,
        )
        + "\n"
    )


def _enter_network(plan: DemoPlan, network: contextlib.ExitStack) -> int | None:
    """Set up the netem or packet backend's namespaces (and the cockpit relay) on ``network``.

    Returns
    -------
    int or None
        1 when the backend cannot be set up (said on stderr), else None.
    """
    if plan.backend == "netem" and isinstance(plan.link, VethLink):
        # Exits in reverse: processes stop, the replay stops, the namespaces go.
        try:
            network.enter_context(plan.link)
            network.enter_context(
                NetemReplayer(
                    plan.link,
                    parse_delay_model(plan.forward),
                    parse_delay_model(plan.backward),
                    plan.t0,
                    extra=plan.netem_extra,
                )
            )
        except (NetnsError, RuntimeError) as exc:
            sys.stderr.write(f"bipedtele demo: netem backend: {exc}\n")
            return 1
        if not plan.headless:
            network.enter_context(CockpitRelay(plan.link, plan.cockpit_port))
    elif plan.backend == "packet" and isinstance(plan.link, EmulatedLink):
        plan.link.emulator_args = plan.emulator_args()
        plan.link.log_path = plan.run_dir / "linkemu.log"
        try:
            network.enter_context(plan.link)
        except NetnsError as exc:
            sys.stderr.write(f"bipedtele demo: packet backend: {exc}\n")
            return 1
        if not plan.headless:
            network.enter_context(CockpitRelay(plan.link, plan.cockpit_port, side=SIDE_A))
    return None


def _watch(plan: DemoPlan, procs: dict[str, _Proc], stop: threading.Event, status: StatusPrinter | None) -> None:
    """Wait until the leader exits, another process dies or a signal stops the demo; show the status line."""
    leader = procs["leader"].popen
    try:
        while not stop.is_set():
            if leader.poll() is not None:
                break
            dead = [n for n, p in procs.items() if n != "leader" and p.popen.poll() is not None]
            if dead:
                LOG.error("%s exited early; see %s", dead[0], plan.run_dir / f"{dead[0]}.log")
                break
            if status is not None:
                status.update()
            time.sleep(0.2)
    finally:
        if status is not None:
            status.finish()


def parse_delay_scale(text: str) -> float:
    """``--delay-scale K``: a number in [0, 10] (ConfigError otherwise)."""
    try:
        k = float(text)
    except ValueError:
        k = math.nan
    if not (math.isfinite(k) and 0.0 <= k <= 10.0):
        raise ConfigError(f"--delay-scale {text!r}: allowed: a number from 0 to 10 (every delay is multiplied by it)")
    return k


def scale_delay_spec(spec: str, k: float, folder: Path, name: str) -> str:
    """Return a delay model spec whose delays are ``k`` times those of ``spec``.

    Constant, uniform and normal models get their times scaled; a trace is written,
    scaled, to ``folder/delay-NAME-xK.csv`` (its times kept) and named by its path.

    Raises
    ------
    ConfigError
        When a scaled delay exceeds the largest a model allows (60 s).
    """
    model: DelayModel = parse_delay_model(spec)
    biggest = max(model.d) if isinstance(model, TraceDelay) else model.mean_s
    if isinstance(model, UniformDelay):
        biggest = model.mean + model.half_width
    if k * biggest > MAX_DELAY_S:
        raise ConfigError(
            f"--delay-scale {k:g}: {spec} becomes longer than {MAX_DELAY_S:g} s; allowed: a smaller scale"
        )
    ms = lambda s: f"{1e3 * k * s:.6g}ms"  # noqa: E731
    if isinstance(model, ConstDelay):
        return f"const:{ms(model.delay)}"
    if isinstance(model, UniformDelay):
        return f"uniform:{ms(model.mean)}:{ms(model.half_width)}"
    if isinstance(model, NormalDelay):
        return f"normal:{ms(model.mean)}:{ms(model.std)}"
    if isinstance(model, TraceDelay):
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"delay-{name}-x{k:g}.csv"
        rows = ["t_s,h1_ms,h2_ms"] + [
            f"{t:.6f},{1e3 * k * d:.6f},{1e3 * k * d:.6f}" for t, d in zip(model.t, model.d, strict=True)
        ]
        path.write_text("\n".join(rows) + "\n", encoding="utf-8")
        return f"trace:{path.resolve()}:h1"
    raise ConfigError(f"--delay-scale: cannot scale the delay model {spec!r}")  # pragma: no cover


def _parse_delay(text: str) -> tuple[str, str]:
    parts = text.split(",")
    if len(parts) != 2:
        raise ConfigError(f"--delay {text!r}: allowed: FORWARD,BACKWARD models, e.g. const:150ms,const:220ms")
    for p in parts:
        parse_delay_model(p)
    return parts[0], parts[1]


def _netem_usable() -> tuple[bool, str]:
    """Whether this machine can run the netem backend, and why (one line)."""
    if os.geteuid() != 0:
        return False, "network namespaces and qdiscs need root"
    ok, why = netem_available()
    return ok, (why if ok else f"netem unavailable: {why}")


def _backend(requested: str, dry_run: bool) -> str:
    """Return the backend to use: ``auto`` resolved (and said), ``netem`` checked."""
    if requested == "auto":
        ok, why = _netem_usable()
        chosen = "netem" if ok else "proxy"
        _say(f"delay backend: {chosen} ({why})")
        return chosen
    if requested == "netem" and not dry_run:
        ok, why = _netem_usable()
        if not ok:
            raise ConfigError(f"--delay-backend netem: {why}; allowed here: proxy, or auto (or packet, as root)")
    if requested == "packet" and not dry_run and os.geteuid() != 0:
        raise ConfigError(
            "--delay-backend packet: network namespaces and raw sockets need root; allowed here: proxy, or auto"
        )
    return requested


def _impairments(args: argparse.Namespace, backend: str) -> list[str]:
    """Return the ``link-emu`` arguments of ``--loss``, ``--rate-up/down``, ``--outage`` (checked)."""
    given = [
        f
        for f, v in (
            ("--loss", args.loss),
            ("--rate-up", args.rate_up),
            ("--rate-down", args.rate_down),
            ("--outage", args.outage),
        )
        if v
    ]
    if backend == "netem" and args.outage:
        raise ConfigError("--outage: allowed only with --delay-backend packet (netem has no outage schedule)")
    if given and backend not in ("packet", "netem"):
        raise ConfigError(
            f"{given[0]}: allowed only with --delay-backend packet or netem (the delay {backend} carries no loss, rate or outage)"
        )
    out: list[str] = []
    if args.loss:
        parse_loss(args.loss)
        out += ["--loss-forward", args.loss, "--loss-backward", args.loss]
    for value, name in ((args.rate_up, "forward"), (args.rate_down, "backward")):
        if value:
            parse_rate(value)
            out += [f"--rate-{name}", value]
    for spec in args.outage:
        parse_outage(spec)
        out += ["--outage-forward", spec, "--outage-backward", spec]
    return out


def _netem_extra(args: argparse.Namespace) -> dict[str, list[str]]:
    """Return the netem options per end of ``--loss`` and ``--rate-up/down`` (netem backend)."""
    return {
        LEADER: impairment_args(loss=args.loss, rate=args.rate_up, queue="64kB" if args.rate_up else None),
        FOLLOWER: impairment_args(loss=args.loss, rate=args.rate_down, queue="64kB" if args.rate_down else None),
    }


def _dry_run(plan: DemoPlan) -> int:
    """Print what the demo would start and, for netem, every ``ip``/``tc`` command."""
    for name, cmd in plan.commands().items():
        _say(f"# process {name}: {shlex.join(cmd)}")
    if plan.backend == "packet":
        for line in plan.packet_plan():
            _say(line)
    if plan.backend == "netem":
        forward, backward = parse_delay_model(plan.forward), parse_delay_model(plan.backward)
        traces = [m for m in (forward, backward) if isinstance(m, TraceDelay)]
        t_end = plan.duration_s if plan.duration_s is not None else max((m.period for m in traces), default=0.0)
        for line in plan.netem_plan(t_end):
            _say(line)
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.delay_trace and args.delay:
        raise ConfigError("--delay-trace and --delay: allowed: at most one of them")
    if args.delay_trace:
        path = Path(args.delay_trace)
        forward, backward = f"trace:{path}:h1", f"trace:{path}:h2"
        parse_delay_model(forward)
    elif args.delay:
        forward, backward = _parse_delay(args.delay)
    else:
        forward, backward = DEFAULT_DELAY
    scale = parse_delay_scale(args.delay_scale)
    if args.scheme is not None:
        from bipedtele.control.schemes import scheme_names

        if args.scheme not in scheme_names():
            raise ConfigError(f"--scheme {args.scheme}: allowed: {', '.join(scheme_names())}")
        # leader and follower read the same profile: they run the same scheme
        args.overrides = [*args.overrides, f'control.scheme="{args.scheme}"']
    if args.robot is not None and args.robot not in _robot_names():
        raise ConfigError(f"--robot {args.robot}: allowed: {', '.join(_robot_names())}")
    cfg = load_config(args.config, args.overrides)  # fail early, before any process starts
    if args.duration is not None and args.duration <= 0:
        raise ConfigError(f"--duration {args.duration}: allowed: a number of seconds > 0")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    run_dir = Path(args.run_dir or Path("runs") / f"demo-{stamp}")
    if scale != 1.0:
        forward = scale_delay_spec(forward, scale, run_dir, "forward")
        backward = scale_delay_spec(backward, scale, run_dir, "backward")
    record = Path(args.record) if args.record else run_dir / "leader.mcap"
    backend = _backend(args.delay_backend, args.dry_run)
    impairments = _impairments(args, backend)
    netem_extra = _netem_extra(args) if backend == "netem" else {}
    link: VethLink | EmulatedLink | None = None
    if backend == "netem":
        link = VethLink()
    elif backend == "packet":
        link = EmulatedLink()
    plan = DemoPlan(
        run_dir=run_dir,
        profile=args.config,
        overrides=list(args.overrides),
        forward=forward,
        backward=backward,
        operator=args.operator,
        duration_s=args.duration,
        headless=args.headless,
        record=record,
        backend=backend,
        link=link,
        impairments=impairments if backend == "packet" else [],
        netem_extra=netem_extra,
    )
    if args.robot is not None:
        plan.follower_args += ["--robot", args.robot]
    if args.foxglove:
        plan.leader_args += ["--foxglove", args.foxglove]
        plan.follower_args += ["--foxglove", _next_port(args.foxglove, backend)]
    if args.dry_run:
        return _dry_run(plan)
    leader = cfg.sections.get("leader")
    passes = getattr(leader, "pilot_passes", None) if args.operator == "pilot" else None
    return run_demo(plan, json_path=Path(args.json) if args.json else None, quiet=args.quiet, passes_total=passes)


def _robot_names() -> list[str]:
    """Return the registered robots' names (their entry points: no role is imported)."""
    return sorted({ep.name for ep in metadata.entry_points(group=PART_GROUPS["robot"])})


def _next_port(address: str, backend: str) -> str:
    """Return the follower's live view: the leader's ``[HOST:]PORT`` with the next port (0: any)."""
    try:
        host, port = parse_address(address)
    except ValueError as exc:
        raise ConfigError(f"--foxglove {exc}") from None
    if backend != "proxy":
        raise ConfigError(f"--foxglove with --delay-backend {backend}: allowed: with the delay proxy (the default)")
    if port == 65535:
        raise ConfigError("--foxglove 65535: allowed: a port below 65535 (the follower takes the next one)")
    return f"{host}:{port + 1 if port else 0}"


def add_demo_parser(sub: Any) -> None:
    """``bipedtele demo``: router, follower, leader and delay proxy on this machine."""
    p: OneLineParser = sub.add_parser(
        "demo", help="run the whole teleoperation on this machine with an intercontinental delay"
    )
    add_config_args(p, default="localhost-delay")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after S seconds (default: when the task is done)",
    )
    p.add_argument(
        "--delay-trace",
        default=None,
        metavar="F",
        help="CSV trace t_s,h1_ms,h2_ms (default: the shipped intercontinental trace)",
    )
    p.add_argument("--delay", default=None, metavar="FWD,BWD", help="delay models, e.g. const:150ms,const:220ms")
    p.add_argument(
        "--operator", default="pilot", choices=["pilot", "scripted", "browser"], help="who drives (default: pilot)"
    )
    p.add_argument("--headless", action="store_true", help="no cockpit server")
    p.add_argument(
        "--robot",
        default=None,
        metavar="NAME",
        help="the follower's robot (default: the profile's [follower] robot; e.g. sim, sim-torque)",
    )
    p.add_argument("--record", default=None, metavar="F.mcap", help="leader recording (default: RUN_DIR/leader.mcap)")
    p.add_argument("--json", default=None, metavar="F", help="write the report as JSON")
    p.add_argument("--run-dir", default=None, metavar="DIR", help="folder for logs and recordings")
    p.add_argument(
        "--scheme",
        default=None,
        metavar="NAME",
        help="control scheme of both sides (default: the profile's, the paper's; docs/schemes.md lists them)",
    )
    p.add_argument("--quiet", action="store_true", help="no live status line while the demo runs")
    p.add_argument(
        "--foxglove",
        default=None,
        metavar="[HOST:]PORT",
        help="watch live in Foxglove: the leader on PORT, the follower on PORT+1 (extra foxglove)",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="print the plan (processes, netem commands over time); start nothing"
    )
    _add_link_args(p)
    p.set_defaults(func=_run)


def _add_link_args(p: OneLineParser) -> None:
    """Add the emulated link's options: backend, loss, rate caps, outages, delay scale."""
    p.add_argument(
        "--delay-backend",
        default="proxy",
        choices=BACKENDS,
        help="proxy (user space, default), netem (root, kernel sch_netem: two namespaces and a "
        "veth pair), packet (root: the per-packet link emulator between two namespaces, see "
        "docs/linkemu.md) or auto (netem where available, else the proxy)",
    )
    p.add_argument(
        "--loss", default=None, metavar="SPEC", help="packet or netem backend: loss each way (1%%, ge:p=1%%,r=30%%)"
    )
    p.add_argument(
        "--rate-up",
        default=None,
        metavar="RATE",
        help="packet or netem backend: leader -> follower rate cap (e.g. 2mbit)",
    )
    p.add_argument(
        "--rate-down",
        default=None,
        metavar="RATE",
        help="packet or netem backend: follower -> leader rate cap (e.g. 8mbit)",
    )
    p.add_argument(
        "--outage",
        action="append",
        default=[],
        metavar="SPEC",
        help="packet backend: outage both ways, at=30s,for=3s[,every=60s] (repeatable)",
    )
    p.add_argument(
        "--delay-scale",
        default="1",
        metavar="K",
        help="multiply every delay of the chosen models by K (0 to 10; e.g. 2: the trace with its delays doubled)",
    )
