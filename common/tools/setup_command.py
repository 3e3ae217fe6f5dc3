"""``bipedtele setup``: the command line of :mod:`bipedtele.tools.setup` and :mod:`bipedtele.tools.setup_fleet`.

``two-hosts``, ``certs``, ``message-key`` (:mod:`bipedtele.tools.setup`) and ``fleet``
(:mod:`bipedtele.tools.setup_fleet`).
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.tools.setup import HOSTS, TwoHosts, make_certs, make_message_key, write_two_hosts
from bipedtele.tools.setup_fleet import Fleet, parse_at, parse_operator, write_fleet, write_sites

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
    os.write(
        1,
        (
            f"setup: wrote CA, router, leader and follower certificates to {args.out_dir}\n"
            f"  {files.ca_key}: the CA's key; keep it off the hosts\n"
        ).encode(),
    )
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
    t.add_argument(
        "--router-name",
        action="append",
        required=True,
        metavar="NAME",
        help="the router's DNS name or IP address, as the robot and operator reach it",
    )
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


def _fleet_instructions(fleet: Fleet, what: str) -> str:
    lines = [f"setup: wrote {fleet.out}/ for the {what}", ""]
    lines.append("1. Copy each folder to its host (keep the modes: scp -rp, rsync -a); 2. there, run:")
    for name, cmds in fleet.commands.items():
        lines += [f"     {name + ':':<24} {c}" for c in cmds]
    lines += [
        "",
        f"Keep {fleet.ca_key} off the hosts (it signs certificates).",
        "Each operator drives only the robots named for it; docs/fleet.md.",
    ]
    return "\n".join(lines) + "\n"


def _run_fleet(args: argparse.Namespace) -> int:
    names: list[str] = args.router_name
    if len(names) != 1:
        raise ConfigError(f"--router-name given {len(names)} times; allowed: once")
    members = {opt: {k: ids for k, (_, ids) in m.items()} for opt, m in _members(args, at=False).items()}
    fleet = write_fleet(
        args.out, names[0], args.robot or [], members["--operator"], args.router_port, members["--observer"]
    )
    os.write(1, _fleet_instructions(fleet, f"router {names[0]}:{args.router_port}").encode())
    return 0


def _members(args: argparse.Namespace, at: bool) -> dict[str, dict[str, tuple[str, tuple[str, ...]]]]:
    """--operator/--observer specs -> {option: {name: (site, robots)}} (site "" without ``@``)."""
    members: dict[str, dict[str, tuple[str, tuple[str, ...]]]] = {"--operator": {}, "--observer": {}}
    for opt, specs in (("--operator", args.operator), ("--observer", args.observer)):
        for spec in specs or []:
            who, ids = parse_operator(spec, opt)
            name, site = parse_at(who, opt) if at else (who, "")
            if name in members[opt]:
                raise ConfigError(f"{opt} {name!r} given twice; allowed: once, with all its robots (NAME=R1,R2)")
            members[opt][name] = (site, ids)
    return members


def _run_sites(args: argparse.Namespace) -> int:
    sites: dict[str, str] = {}
    for spec in args.site or []:
        site, eq, router = spec.partition("=")
        if not eq or not site or not router:
            raise ConfigError(f"--site {spec!r}: allowed: SITE=ROUTER_NAME (e.g. lab1=router1.example.org)")
        if site in sites:
            raise ConfigError(f"--site {site!r} given twice; allowed: once each")
        sites[site] = router
    robots: dict[str, str] = {}
    for spec in args.robot or []:
        r, site = parse_at(spec, "--robot")
        if r in robots:
            raise ConfigError(f"--robot {r!r} given twice; allowed: once each")
        robots[r] = site
    members = _members(args, at=True)
    fleet = write_sites(args.out, sites, robots, members["--operator"], args.router_port, members["--observer"])
    where = ", ".join(f"{s} {r}:{args.router_port}" for s, r in sites.items())
    os.write(1, _fleet_instructions(fleet, f"sites {where}").encode())
    return 0


def add_sites_parser(ss: Any) -> None:
    """``bipedtele setup sites``, under the ``setup`` sub-command parser ``ss``."""
    f = ss.add_parser("sites", help="one router per site, linked over TLS; robots and operators at their sites")
    f.add_argument(
        "--site",
        action="append",
        metavar="SITE=ROUTER_NAME",
        help="a site and its router's DNS name or IP address (repeat; each links to those before)",
    )
    f.add_argument(
        "--router-port", type=int, default=7447, metavar="PORT", help="every router's TLS port (default 7447)"
    )
    f.add_argument("--robot", action="append", metavar="ID@SITE", help="a robot and its site (repeat)")
    f.add_argument(
        "--operator",
        action="append",
        metavar="NAME@SITE=ROBOT[,ROBOT...]",
        help="an operator, its site and the robots it may drive, of any site (repeat)",
    )
    f.add_argument(
        "--observer",
        action="append",
        metavar="NAME@SITE=ROBOT[,ROBOT...]",
        help="an observer, its site and the robots it may watch (repeat)",
    )
    f.add_argument("--out", default="sites", metavar="DIR", help="new or empty folder to write (default: sites)")
    f.set_defaults(func=_run_sites)


def add_fleet_parser(ss: Any) -> None:
    """``bipedtele setup fleet``, under the ``setup`` sub-command parser ``ss``."""
    f = ss.add_parser("fleet", help="one router, several robots and operators, each operator bound to its robots")
    f.add_argument(
        "--router-name",
        action="append",
        required=True,
        metavar="NAME",
        help="the router's DNS name or IP address, as robots and operators reach it",
    )
    f.add_argument("--router-port", type=int, default=7447, metavar="PORT", help="the router's TLS port (default 7447)")
    f.add_argument("--robot", action="append", metavar="ID", help="a robot id (repeat for each robot)")
    f.add_argument(
        "--operator",
        action="append",
        metavar="NAME=ROBOT[,ROBOT...]",
        help="an operator and the robots it may drive (repeat for each operator)",
    )
    f.add_argument(
        "--observer",
        action="append",
        metavar="NAME=ROBOT[,ROBOT...]",
        help="an observer and the robots it may watch (video, status; puts nothing)",
    )
    f.add_argument("--out", default="fleet", metavar="DIR", help="new or empty folder to write (default: fleet)")
    f.set_defaults(func=_run_fleet)
