"""Benchmark: how often, and how fast, a client session opens across the emulated intercontinental path.

    sudo .venv/bin/python bench/internet_open.py [--loss 5%] [--tries 12] [--links split|single|split-tcp]

``bench/internet.py``'s hosts (``bipedtele setup two-hosts``, TLS, logins, ACL): the router
behind ``bipedtele link-emu`` (the shipped trace's h1 and h2, ``--loss`` both ways), and in
the operator's namespace ``bipedtele health --role router`` run ``--tries`` times: each
opens a session as the leader does (endpoint checks, then the handshake tries) and closes
it. Prints each try's result and wall time (Python's start included, about 1.5 s) and a
JSON line at the end. It asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the bench's own modules beside it

from internet_hosts import CLI, copy_hosts, setup_two_hosts, start, topology


def main(argv: list[str] | None = None) -> int:
    """Open the session ``--tries`` times through the emulated path; 2 without root."""
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--loss", default="5%", help="loss each way (link-emu's --loss-forward/--loss-backward)")
    p.add_argument("--tries", type=int, default=12, help="sessions opened one after the other")
    p.add_argument("--links", default="split", choices=("single", "split", "split-tcp"))
    p.add_argument("--seed", type=int, default=3, help="the emulator's seed")
    args = p.parse_args(argv)
    if shutil.which("ip") is None or os.geteuid() != 0:
        sys.stderr.write("bench/internet_open.py: needs root and iproute2 (network namespaces)\n")
        return 2
    work = Path(tempfile.mkdtemp(prefix="bt-open-"))
    results: list[tuple[int, float, str]] = []
    try:
        commands = setup_two_hosts(work / "setup")
        homes = copy_hosts(work / "setup", work / "run", args.links)
        with topology("intercontinental", work / "linkemu.log", secrets.token_hex(2)) as top:
            router = start("router", commands["router"], netns=top.ns["router"], cwd=homes["router"], log_dir=work)
            try:
                router.wait_log(r"router: \S+ listening on", 60.0)
                emu = ["--forward", "trace:intercontinental:h1", "--backward", "trace:intercontinental:h2"]
                emu += ["--loss-forward", args.loss, "--loss-backward", args.loss, "--seed", str(args.seed)]
                top.link.start_emulator([*emu, "--t0", f"{time.time():.6f}"])
                for i in range(args.tries):
                    t0 = time.monotonic()
                    cmd = ["ip", "netns", "exec", top.ns["operator"], *CLI, "health"]
                    cmd += ["--config", "operator/bipedtele.toml", "--role", "router"]
                    r = subprocess.run(cmd, cwd=homes["operator"], capture_output=True, text=True, timeout=120)
                    out = (r.stdout + r.stderr).strip().splitlines()
                    results.append((r.returncode, round(time.monotonic() - t0, 1), out[-1][:200] if out else ""))
                    print(i, *results[-1], flush=True)
            finally:
                router.stop(5.0)
                top.link.stop_emulator()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    ok = sum(1 for rc, _, _ in results if rc == 0)
    print(
        json.dumps(
            {
                "loss": args.loss,
                "links": args.links,
                "opened": ok,
                "tries": len(results),
                "wall_s": [t for _, t, _ in results],
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
