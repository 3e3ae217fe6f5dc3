r"""``bipedtele setup fleet``: one router, several robots and operators, each bound to its robots.

::

    bipedtele setup fleet --router-name NAME --robot nao1 --robot nao2 \
        --operator alice=nao1 --operator bob=nao2,nao1 [--observer carol=nao1,nao2]
        [--router-port 7447] [--out fleet]

writes one folder per host (``DIR/router/``, ``DIR/robot-<id>/``, ``DIR/operator-<name>/``,
``DIR/observer-<name>/``)
and the CA in ``DIR/ca-private/`` (keep it off the hosts). What it sets up:

- **Per-robot authority in the router's ACL** (:mod:`bipedtele.acl`): each operator is a
  leader only of the robots named for it (``publishers_allowed = ["alice@nao1", ...]``),
  each robot logs in as its own user, a follower of its own keys only
  (``followers_allowed = ["nao1@nao1", ...]``). A leader cannot command, see or hear a
  robot it is not named for; a robot cannot publish as another.
- **One message key per robot**, held by the robot and by the operators named for it,
  never by the router: a leader cannot sign (so not command) another robot even through
  a compromised router. (Operators of the same robot share its key: which of them drives
  is the session handshake's business, ``docs/network.md``.)
- **Observers** (``observers_allowed = ["carol@nao1", ...]``): receive the video and
  status of their robots and put nothing; they hold each robot's *watch key*
  (``secrets/<id>.watch``, derived one-way from the robot's message key,
  :func:`bipedtele.auth.watch_key`), which verifies video and status and signs nothing a
  robot obeys. ``bipedtele status --config observer-carol/bipedtele.toml``: the fleet view.
- One profile per operator and robot: ``operator-alice/nao1.toml``. Every user has its own
  password; the TLS certificates are per role (``leader``, ``follower``), as in
  ``setup two-hosts``.

See docs/fleet.md.
"""

from __future__ import annotations

import argparse
import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bipedtele.auth import watch_key
from bipedtele.config import ConfigError
from bipedtele.tools.setup import (
    FOLLOWER_USER,
    LEADER_USER,
    ROBOT_ID,
    check_router_name,
    client_profile,
    make_certs,
    make_password,
    router_profile,
    write_private,
)

__all__ = ["Fleet", "add_fleet_parser", "parse_operator", "write_fleet"]

#: How many robots and operators one ``setup fleet`` writes at most.
MAX_MEMBERS = 64
_RESERVED = {"router", LEADER_USER, FOLLOWER_USER}
_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True)
class Fleet:
    """What :func:`write_fleet` wrote.

    Attributes
    ----------
    out : Path
        The folder holding the host folders and ``ca-private/``.
    folders : dict
        Host folder name (``router``, ``robot-nao1``, ``operator-alice``) -> its path.
    commands : dict
        Host folder name -> the commands to run there (from the folder holding it).
    ca_key : Path
        The CA's private key (keep it off the hosts).
    """

    out: Path
    folders: Mapping[str, Path]
    commands: Mapping[str, tuple[str, ...]]
    ca_key: Path


def parse_operator(spec: str, option: str = "--operator") -> tuple[str, tuple[str, ...]]:
    """``"alice=nao1,nao2"`` -> ``("alice", ("nao1", "nao2"))``.

    Raises
    ------
    ConfigError
        Not ``NAME=ROBOT[,ROBOT...]``.
    """
    name, eq, robots = spec.partition("=")
    ids = tuple(r.strip() for r in robots.split(",") if r.strip())
    if not eq or not name or not ids:
        raise ConfigError(f"{option} {spec!r}: allowed: NAME=ROBOT[,ROBOT...] (e.g. alice=nao1,nao2)")
    return name.strip(), ids


def _check(robots: Sequence[str], operators: Mapping[str, Sequence[str]],
           observers: Mapping[str, Sequence[str]]) -> None:  # fmt: skip
    if not robots:
        raise ConfigError("--robot: none given; allowed: one or more robot ids (--robot nao1 --robot nao2)")
    if not operators:
        raise ConfigError("--operator: none given; allowed: one or more NAME=ROBOT[,ROBOT...]")
    if len(robots) + len(operators) + len(observers) > MAX_MEMBERS:
        raise ConfigError(
            f"{len(robots)} robots, {len(operators)} operators, {len(observers)} observers: allowed: {MAX_MEMBERS} in all"
        )
    both = sorted(set(operators) & set(observers))
    if both:
        raise ConfigError(f"{both[0]!r} is an --operator and an --observer: allowed: each user one role")
    for r in robots:
        if not ROBOT_ID.match(r):
            raise ConfigError(f"--robot {r!r}: allowed: 1-64 characters of letters, digits, '_' or '-'")
    if len(set(robots)) != len(robots):
        raise ConfigError(
            f"--robot: {sorted(r for r in set(robots) if robots.count(r) > 1)} given twice; allowed: once each"
        )
    for opt, name, ids in [*(("--operator", n, i) for n, i in operators.items()),
                           *(("--observer", n, i) for n, i in observers.items())]:  # fmt: skip
        if not _NAME.match(name) or name in _RESERVED or name in robots:
            raise ConfigError(
                f"{opt} {name!r}: allowed: 1-64 characters of letters, digits, '_' or '-', "
                f"not a robot id nor one of {sorted(_RESERVED)} (each user one role)"
            )
        unknown = [r for r in ids if r not in robots]
        if unknown:
            raise ConfigError(f"{opt} {name}={','.join(ids)}: {unknown} not a --robot; allowed: {list(robots)}")
        if len(set(ids)) != len(ids):
            raise ConfigError(f"{opt} {name}={','.join(ids)}: a robot named twice; allowed: once each")


def write_fleet(out: str | Path, router_name: str, robots: Sequence[str],
                operators: Mapping[str, Sequence[str]], router_port: int = 7447,
                observers: Mapping[str, Sequence[str]] | None = None) -> Fleet:  # fmt: skip
    """Write the router's, each robot's and each operator's folder into ``out``.

    Parameters
    ----------
    out : str or Path
        A new or empty folder. Everything is written beside it first and moved into place
        at the end, so a failure leaves nothing.
    router_name : str
        The router's DNS name or IP address, as the robots and operators reach it.
    robots : sequence of str
        Robot ids; each robot logs in as a user of the same name.
    operators : mapping
        Operator (user) name -> the robot ids it may drive.
    router_port : int
        The router's TLS port.
    observers : mapping, optional
        Observer (user) name -> the robot ids it may watch.

    Raises
    ------
    ConfigError
        ``out`` is not empty, a bad name, port, id or assignment, or ``openssl`` failed.
    """
    router_name = check_router_name(router_name)
    if not 1 <= int(router_port) <= 65535:
        raise ConfigError(f"--router-port {router_port}: allowed: 1 to 65535")
    robot_ids = list(robots)
    assigned = {k: tuple(v) for k, v in operators.items()}
    watching = {k: tuple(v) for k, v in (observers or {}).items()}
    _check(robot_ids, assigned, watching)
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: not an empty folder; allowed: a new or empty folder (nothing is overwritten)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        commands = _fill(tmp, router_name, int(router_port), robot_ids, assigned, watching)
        os.chmod(tmp, 0o700)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return Fleet(out, {name: out / name for name in commands}, commands, out / "ca-private" / "ca.key")


def _host_folder(root: Path, name: str, ca_pem: Path, cert: tuple[Path, Path]) -> Path:
    folder = root / name
    for sub in ("certs", "secrets"):
        (folder / sub).mkdir(parents=True)
        os.chmod(folder / sub, 0o700)
    os.chmod(folder, 0o700)
    pem, key = cert
    shutil.copyfile(ca_pem, folder / "certs" / "ca.pem")
    shutil.copyfile(pem, folder / "certs" / pem.name)
    write_private(folder / "certs" / key.name, key.read_text(encoding="utf-8"))
    for f in (folder / "certs" / "ca.pem", folder / "certs" / pem.name):
        os.chmod(f, 0o644)
    return folder


def _write_profile(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")
    os.chmod(path, 0o644)


def _head(what: str, router_name: str, port: int, command: str) -> str:
    return (
        f"# bipedtele profile for {what}, written by `bipedtele setup fleet`\n"
        f"# for the router {router_name}:{port}. Relative paths are read relative to this\n"
        f"# file's folder. Run:  {command}\n\n"
    )


def _fill(root: Path, router_name: str, port: int, robots: list[str], operators: dict[str, tuple[str, ...]],
          observers: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:  # fmt: skip
    certs = make_certs(root / "ca-private" / "issued", [router_name], ca_dir=root / "ca-private")
    users = [*robots, *operators, *observers]
    passwords = {u: make_password() for u in users}
    keys = {r: secrets.token_hex(32) + "\n" for r in robots}
    commands: dict[str, tuple[str, ...]] = {}

    folder = _host_folder(root, "router", certs.ca_pem, certs.pairs["router"])
    write_private(folder / "secrets" / "router-credentials.txt", "".join(f"{u}:{passwords[u]}\n" for u in users))
    cmd = "bipedtele router --config router/bipedtele.toml"
    publishers = [f"{name}@{r}" for name, ids in operators.items() for r in ids]
    _write_profile(folder / "bipedtele.toml", router_profile(
        _head("the fleet's router", router_name, port, cmd), router_name, port, robots[0],
        publishers, [f"{r}@{r}" for r in robots],
        [f"{name}@{r}" for name, ids in observers.items() for r in ids]))  # fmt: skip
    commands["router"] = (cmd,)

    for r in robots:
        name = f"robot-{r}"
        folder = _host_folder(root, name, certs.ca_pem, certs.pairs[FOLLOWER_USER])
        write_private(folder / "secrets" / f"{r}.pw", passwords[r] + "\n")
        write_private(folder / "secrets" / "message.key", keys[r])
        cmd = f"bipedtele follower --config {name}/bipedtele.toml"
        _write_profile(folder / "bipedtele.toml", client_profile(
            _head(f"robot {r}", router_name, port, cmd), "robot", router_name, port, r,
            r, FOLLOWER_USER, "secrets/message.key"))  # fmt: skip
        commands[name] = (cmd,)

    for op, ids in operators.items():
        name = f"operator-{op}"
        folder = _host_folder(root, name, certs.ca_pem, certs.pairs[LEADER_USER])
        write_private(folder / "secrets" / f"{op}.pw", passwords[op] + "\n")
        cmds = []
        for r in ids:
            write_private(folder / "secrets" / f"{r}.key", keys[r])
            cmd = f"bipedtele leader --config {name}/{r}.toml"
            _write_profile(folder / f"{r}.toml", client_profile(
                _head(f"operator {op} driving robot {r}", router_name, port, cmd), "operator",
                router_name, port, r, op, LEADER_USER, f"secrets/{r}.key"))  # fmt: skip
            cmds.append(cmd)
        commands[name] = tuple(cmds)

    for obs, ids in observers.items():
        name = f"observer-{obs}"
        folder = _host_folder(root, name, certs.ca_pem, certs.pairs[LEADER_USER])
        write_private(folder / "secrets" / f"{obs}.pw", passwords[obs] + "\n")
        for r in ids:
            write_private(folder / "secrets" / f"{r}.watch", watch_key(bytes.fromhex(keys[r].strip())).hex() + "\n")
        cmd = f"bipedtele status --config {name}/bipedtele.toml"
        _write_profile(folder / "bipedtele.toml", client_profile(
            _head(f"observer {obs} watching {', '.join(ids)}", router_name, port, cmd), "observer",
            router_name, port, ids[0], obs, LEADER_USER, "secrets"))  # fmt: skip
        commands[name] = (cmd,)

    os.replace(certs.ca_pem, root / "ca-private" / "ca.pem")
    shutil.rmtree(certs.ca_pem.parent)
    (root / "ca-private" / "README.txt").write_text(
        "ca.key signs the certificates of this fleet. Keep it off the router, robot and\n"
        "operator hosts (offline); it is needed only to issue new certificates.\n",
        encoding="utf-8",
    )
    return commands


def _instructions(fleet: Fleet, router_name: str, port: int) -> str:
    lines = [f"setup: wrote {fleet.out}/ for the router {router_name}:{port}", ""]
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
    members: dict[str, dict[str, tuple[str, ...]]] = {"--operator": {}, "--observer": {}}
    for opt, specs in (("--operator", args.operator), ("--observer", args.observer)):
        for spec in specs or []:
            name, ids = parse_operator(spec, opt)
            if name in members[opt]:
                raise ConfigError(f"{opt} {name!r} given twice; allowed: once, with all its robots (NAME=R1,R2)")
            members[opt][name] = ids
    fleet = write_fleet(args.out, names[0], args.robot or [], members["--operator"], args.router_port,
                        members["--observer"])  # fmt: skip
    os.write(1, _instructions(fleet, names[0], args.router_port).encode())
    return 0


def add_fleet_parser(ss: Any) -> None:
    """``bipedtele setup fleet``, under the ``setup`` sub-command parser ``ss``."""
    f = ss.add_parser("fleet", help="one router, several robots and operators, each operator bound to its robots")
    f.add_argument("--router-name", action="append", required=True, metavar="NAME",
                   help="the router's DNS name or IP address, as robots and operators reach it")  # fmt: skip
    f.add_argument("--router-port", type=int, default=7447, metavar="PORT", help="the router's TLS port (default 7447)")
    f.add_argument("--robot", action="append", metavar="ID", help="a robot id (repeat for each robot)")
    f.add_argument("--operator", action="append", metavar="NAME=ROBOT[,ROBOT...]",
                   help="an operator and the robots it may drive (repeat for each operator)")  # fmt: skip
    f.add_argument("--observer", action="append", metavar="NAME=ROBOT[,ROBOT...]",
                   help="an observer and the robots it may watch (video, status; puts nothing)")  # fmt: skip
    f.add_argument("--out", default="fleet", metavar="DIR", help="new or empty folder to write (default: fleet)")
    f.set_defaults(func=_run_fleet)
