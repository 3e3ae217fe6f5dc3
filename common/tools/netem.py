"""``bipedtele netem``: per-interface egress delay with Linux netem (``tc``).

netem delays what *leaves* an interface. For asymmetric delays between two hosts,
apply h1 on the leader's interface and h2 on the follower's (or, on one host, use
network namespaces with a veth pair: one qdisc per end). Needs root and a kernel with
``sch_netem``; many CI and container kernels lack it — then use ``bipedtele
delay-proxy``, which works everywhere without root.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.tools.netem_trace import impairment_args

__all__ = ["add_netem_parser", "netem_available", "tc_commands"]

_TIME = re.compile(r"^[0-9]*\.?[0-9]+(us|ms|s)$")
_LOSS = re.compile(r"^[0-9]*\.?[0-9]+%$")
_DEV = re.compile(r"^[A-Za-z0-9_.:@-]{1,15}$")
DISTRIBUTIONS = ("uniform", "normal", "pareto", "paretonormal")
FALLBACK = "use `bipedtele delay-proxy` (user-space, no root) instead"


def tc_commands(
    action: str,
    dev: str,
    delay: str | None = None,
    jitter: str | None = None,
    distribution: str | None = None,
    loss: str | None = None,
    rate: str | None = None,
    queue: str | None = None,
) -> list[list[str]]:
    """Return the ``tc`` command lines for an action.

    Parameters
    ----------
    action : str
        ``apply`` (replace the root qdisc by netem), ``clear`` or ``show``.
    dev : str
        Network interface.
    delay, jitter : str
        Like ``150ms``, ``20ms`` (apply only).
    distribution : str
        Jitter distribution, one of ``DISTRIBUTIONS`` (needs a jitter).
    loss : str
        Like ``0.1%`` (random), or a Gilbert-Elliott burst model ``ge:p=1%,r=30%`` (the
        packet emulator's specs, :mod:`bipedtele.link.impairments`).
    rate, queue : str
        A rate cap like ``600kbit`` and its queue like ``64kB`` (netem's ``rate`` and
        ``limit`` in packets of 1500 bytes).

    Raises
    ------
    ConfigError
        One line naming the bad value and what is allowed.
    """
    if not _DEV.match(dev):
        raise ConfigError(f"--dev {dev!r}: allowed: an interface name (1-15 characters)")
    if action == "show":
        return [["tc", "qdisc", "show", "dev", dev]]
    if action == "clear":
        return [["tc", "qdisc", "del", "dev", dev, "root"]]
    if action != "apply":
        raise ConfigError(f"action {action!r}: allowed: apply, clear, show")
    if delay is None or not _TIME.match(delay):
        raise ConfigError(f"--delay {delay!r}: allowed: a time like 150ms, 0.15s or 500us")
    cmd = ["tc", "qdisc", "replace", "dev", dev, "root", "netem", "delay", delay]
    if jitter is not None:
        if not _TIME.match(jitter):
            raise ConfigError(f"--jitter {jitter!r}: allowed: a time like 20ms")
        cmd.append(jitter)
    if distribution is not None:
        if jitter is None:
            raise ConfigError(f"--distribution {distribution!r}: allowed only with --jitter")
        if distribution not in DISTRIBUTIONS:
            raise ConfigError(f"--distribution {distribution!r}: allowed: {', '.join(DISTRIBUTIONS)}")
        cmd += ["distribution", distribution]
    if loss is not None:
        if _LOSS.match(loss):
            cmd += ["loss", loss]
        elif loss.startswith("ge:"):
            cmd += impairment_args(loss=loss)
        else:
            raise ConfigError(
                f"--loss {loss!r}: allowed: a percentage like 0.1%, or ge:p=1%,r=30%[,bad=100%][,good=0%]"
            )
    cmd += impairment_args(rate=rate, queue=queue)
    return [cmd]


def netem_available(
    proc_modules: Path = Path("/proc/modules"),
    sys_module: Path = Path("/sys/module/sch_netem"),
    modules_dir: Path | None = None,
) -> tuple[bool, str]:
    """Whether this kernel can run netem, and why not.

    Checks, in order: ``tc`` is installed; ``sch_netem`` is loaded (``/proc/modules``,
    ``/sys/module``); it is built into the kernel (``modules.builtin``); it can be
    loaded (``modprobe -n sch_netem``).

    Returns
    -------
    (bool, str)
        Availability and a one-line reason.
    """
    if shutil.which("tc") is None:
        return False, "the `tc` command (iproute2) is not installed"
    try:
        if any(line.split()[:1] == ["sch_netem"] for line in proc_modules.read_text().splitlines()):
            return True, "sch_netem is loaded"
    except OSError:
        pass
    if sys_module.exists():
        return True, "sch_netem is loaded"
    release = platform.release()
    mdir = modules_dir or Path("/lib/modules") / release
    try:
        builtin = (mdir / "modules.builtin").read_text()
        if "sch_netem.ko" in builtin:
            return True, "sch_netem is built into the kernel"
    except OSError:
        pass
    modprobe = shutil.which("modprobe")
    if modprobe is not None:
        res = subprocess.run([modprobe, "-n", "sch_netem"], capture_output=True, text=True, timeout=10, check=False)
        if res.returncode == 0:
            return True, "sch_netem can be loaded"
    return False, f"kernel {release} has no sch_netem module (not loaded, not built in, not loadable)"


def run(args: argparse.Namespace) -> int:
    """``bipedtele netem apply|clear|show``."""
    cmds = tc_commands(
        args.action, args.dev, args.delay, args.jitter, args.distribution, args.loss, args.rate, args.queue
    )
    if args.dry_run:
        for c in cmds:
            print(" ".join(c))  # noqa: T201 (CLI output)
        return 0
    if args.action != "show":
        ok, why = netem_available()
        if not ok:
            sys.stderr.write(f"bipedtele netem: netem unavailable: {why}; {FALLBACK}\n")
            return 1
        if os.geteuid() != 0:
            sys.stderr.write(f"bipedtele netem: changing qdiscs needs root (run with sudo); or {FALLBACK}\n")
            return 1
    elif shutil.which("tc") is None:
        sys.stderr.write(f"bipedtele netem: the `tc` command (iproute2) is not installed; {FALLBACK}\n")
        return 1
    for c in cmds:
        res = subprocess.run(c, capture_output=True, text=True, timeout=30, check=False)
        sys.stdout.write(res.stdout)
        if res.returncode != 0:
            err = (res.stderr.strip().splitlines() or ["failed"])[0]
            sys.stderr.write(f"bipedtele netem: `{' '.join(c)}`: {err}; {FALLBACK}\n")
            return 1
    return 0


def add_netem_parser(sub: Any) -> None:
    """Register ``bipedtele netem``."""
    p = sub.add_parser(
        "netem",
        help="egress delay with Linux netem (root, kernel sch_netem)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("action", choices=["apply", "clear", "show"])
    p.add_argument("--dev", required=True, help="network interface (e.g. eth0, veth-l)")
    p.add_argument("--delay", help="mean delay, e.g. 150ms (apply)")
    p.add_argument("--jitter", help="jitter, e.g. 20ms")
    p.add_argument("--distribution", help=f"jitter distribution: {', '.join(DISTRIBUTIONS)}")
    p.add_argument("--loss", help="random loss, e.g. 0.1%%, or bursts ge:p=1%%,r=30%%[,bad=100%%][,good=0%%]")
    p.add_argument("--rate", help="rate cap, e.g. 600kbit")
    p.add_argument("--queue", help="queue of the rate cap, e.g. 64kB (netem limit, 1500-byte packets)")
    p.add_argument("--dry-run", action="store_true", help="print the tc commands, change nothing")
    p.set_defaults(func=run)
