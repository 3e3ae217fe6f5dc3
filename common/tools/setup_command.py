"""``bipedtele setup``: the command line of :mod:`bipedtele.tools.setup` and :mod:`bipedtele.tools.setup_fleet`.

``two-hosts``, ``certs``, ``message-key`` (:mod:`bipedtele.tools.setup`) and ``fleet``
(:mod:`bipedtele.tools.setup_fleet`).
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from bipedtele.config import ConfigError
from bipedtele.tools.setup import HOSTS, TwoHosts, make_certs, make_message_key, write_two_hosts
from bipedtele.tools.setup_fleet import add_fleet_parser, add_sites_parser

__all__ = ["add_setup_parser"]


def _instructions(result: TwoHosts, router_name: str, port: int) -> str:
    o = result.out
    role = {
        "router": f"the router host (reachable as {router_name}:{port} from both others)",
        "robot": "the robot host (runs the follower; the NAO's network for a real robot)",
        "operator": "the operator host (runs the leader and its cockpit)",
    }
    lines = [
        f"setup: wrote {o}/ for the router {router_name}:{port}",
        "",
        "1. Copy each folder to its host (keep the modes: scp -rp, rsync -a):",
    ]
    width = max(len(f"{o / h}/") for h in HOSTS)
    lines += [f"     {f'{o / h}/':<{width}}  ->  {role[h]}" for h in HOSTS]
    lines += ["", "2. On each host, in the folder that holds the copied folder, run:"]
    lines += [f"     {h + ':':<10} {result.commands[h]}" for h in HOSTS]
    lines += [
        "",
        f"Keep {result.ca_key} off the hosts (it signs certificates).",
        "Real NAO: add --robot naoqi --naoqi-url tcp://NAO:9559 to the robot's command.",
        "Check the run: docs/two-continents.md.",
    ]
    return "\n".join(lines) + "\n"


def _run_two_hosts(args: argparse.Namespace) -> int:
    names: list[str] = args.router_name
    if len(names) != 1:
        raise ConfigError(f"--router-name given {len(names)} times; allowed: once")
    result = write_two_hosts(args.out, names[0], args.router_port, args.robot_id)
    os.write(1, _instructions(result, names[0], args.router_port).encode())
    return 0


def _run_certs(args: argparse.Namespace) -> int:
    files = make_certs(args.out_dir, args.names)
    os.write(1, (
        f"setup: wrote CA, router, leader and follower certificates to {args.out_dir}\n"
        f"  {files.ca_key}: the CA's key; keep it off the hosts\n"
    ).encode())  # fmt: skip
    return 0


def _run_message_key(args: argparse.Namespace) -> int:
    try:
        path = make_message_key(args.file)
    except FileExistsError:
        raise ConfigError(f"{args.file}: exists; allowed: a new file (a key is never overwritten)") from None
    except OSError as exc:
        raise ConfigError(f"{args.file}: cannot create ({exc.strerror}); allowed: a writable folder") from None
    os.write(
        1, f"setup: wrote a message key to {path} (mode 0600); copy it to the robot and operator hosts only\n".encode()
    )
    return 0


def add_setup_parser(sub: Any) -> None:
    """``bipedtele setup two-hosts|certs|message-key|fleet|sites``: files for a two-continent run or a fleet."""
    p = sub.add_parser("setup", help="make certificates, secrets and per-host profiles for a two-host run")
    ss = p.add_subparsers(dest="setup_command", metavar="WHAT", parser_class=type(p))
    ss.required = True
    t = ss.add_parser("two-hosts", help="three folders (router, robot, operator) and the command for each")
    t.add_argument("--router-name", action="append", required=True, metavar="NAME",
                   help="the router's DNS name or IP address, as the robot and operator reach it")  # fmt: skip
    t.add_argument("--router-port", type=int, default=7447, metavar="PORT", help="the router's TLS port (default 7447)")
    t.add_argument(
        "--out", default="two-hosts", metavar="DIR", help="new or empty folder to write (default: two-hosts)"
    )
    t.add_argument("--robot-id", default="nao1", metavar="ID", help="robot id (default nao1)")
    t.set_defaults(func=_run_two_hosts)
    c = ss.add_parser("certs", help="a CA and router/leader/follower certificates (as scripts/make-certs.sh)")
    c.add_argument("out_dir", metavar="OUT_DIR", help="folder for the certificates (CA key in OUT_DIR/ca-private/)")
    c.add_argument("names", nargs="+", metavar="NAME", help="the router's DNS names and/or IP addresses")
    c.set_defaults(func=_run_certs)
    m = ss.add_parser("message-key", help="a key for message authentication (mode 0600)")
    m.add_argument("file", metavar="FILE", help="new file to write")
    m.set_defaults(func=_run_message_key)
    add_fleet_parser(ss)
    add_sites_parser(ss)
