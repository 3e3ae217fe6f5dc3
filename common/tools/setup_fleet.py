r"""``bipedtele setup fleet``: one router, several robots and operators, each bound to its robots.

::

    bipedtele setup fleet --router-name NAME --robot nao1 --robot nao2 \
        --operator alice=nao1 --operator bob=nao2,nao1 [--observer carol=nao1,nao2]
        [--router-port 7447] [--out fleet]

writes one folder per host (``DIR/router/``, ``DIR/robot-<id>/``, ``DIR/operator-<name>/``,
``DIR/observer-<name>/``)
and the CA in ``DIR/ca-private/`` (keep it off the hosts). What it sets up:

- **Per-robot authority in the router's ACL** (:mod:`bipedtele.link.acl`): each operator is a
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
  :func:`bipedtele.link.auth.watch_key`), which verifies video and status and signs nothing a
  robot obeys. ``bipedtele observe --config observer-carol/bipedtele.toml``: their video
  and status in the cockpit; ``bipedtele status --config ...``: the fleet view.
- One profile per operator and robot: ``operator-alice/nao1.toml``. Every user has its own
  password and its own certificate, named after the user (``certs/alice.pem``); the router
  gives a role only to a session whose certificate names its user (``tls_user_certs``), so
  one person is revoked alone: add the name to the router's ``[network] revoked`` and
  restart it (their login and every right are refused; Zenoh's TLS reads no revocation
  list, so the router's own list is the revocation).

See docs/fleet.md.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.link.auth import watch_key
from bipedtele.tools.setup import (
    FOLLOWER_USER,
    LEADER_USER,
    ROBOT_ID,
    CertFiles,
    check_router_name,
    client_profile,
    host_folder,
    issue_person_cert,
    issue_router_cert,
    keep_ca_only,
    make_certs,
    make_password,
    router_profile,
    tls_endpoint,
    write_private,
    write_profile,
)

__all__ = ["Fleet", "parse_at", "parse_operator", "write_fleet", "write_sites"]

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


def _check(
    robots: Sequence[str], operators: Mapping[str, Sequence[str]], observers: Mapping[str, Sequence[str]]
) -> None:
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
    for opt, name, ids in [
        *(("--operator", n, i) for n, i in operators.items()),
        *(("--observer", n, i) for n, i in observers.items()),
    ]:
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


def write_fleet(
    out: str | Path,
    router_name: str,
    robots: Sequence[str],
    operators: Mapping[str, Sequence[str]],
    router_port: int = 7447,
    observers: Mapping[str, Sequence[str]] | None = None,
) -> Fleet:
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
    plan = _Plan(
        {"": router_name},
        dict.fromkeys(robot_ids, ""),
        {k: ("", v) for k, v in assigned.items()},
        {k: ("", v) for k, v in watching.items()},
    )
    return _write(Path(out), plan, int(router_port))


def parse_at(spec: str, option: str) -> tuple[str, str]:
    """``"nao1@lab1"`` -> ``("nao1", "lab1")``; ``"alice@lab1=nao1,nao2"``: use :func:`parse_operator` on the rest.

    Raises
    ------
    ConfigError
        Not ``NAME@SITE``.
    """
    name, at, site = spec.partition("@")
    if not at or not name.strip() or not site.strip():
        raise ConfigError(f"{option} {spec!r}: allowed: NAME@SITE (e.g. nao1@lab1)")
    return name.strip(), site.strip()


def write_sites(
    out: str | Path,
    sites: Mapping[str, str],
    robots: Mapping[str, str],
    operators: Mapping[str, tuple[str, Sequence[str]]],
    router_port: int = 7447,
    observers: Mapping[str, tuple[str, Sequence[str]]] | None = None,
) -> Fleet:
    """Write one router per site, linked over TLS, and each robot's, operator's and observer's folder.

    Parameters
    ----------
    out : str or Path
        A new or empty folder (written beside it first, moved into place at the end).
    sites : mapping
        Site name -> its router's DNS name or IP address. Each site's router links to the
        routers of the sites named before it (a full mesh), logging in as ``site-<name>``;
        each accepts the others by their certificates (``router-<site>``).
    robots : mapping
        Robot id -> its site (a client of that site's router).
    operators, observers : mapping
        Name -> (its site, the robot ids it may drive or watch: of any site).
    router_port : int
        Every router's TLS port.

    Raises
    ------
    ConfigError
        ``out`` is not empty, a bad name, port, id, site or assignment, or ``openssl`` failed.
    """
    if not 2 <= len(sites) <= 16:
        raise ConfigError(f"--site given {len(sites)} times; allowed: 2 to 16 sites (one site: setup fleet)")
    for site, router in sites.items():
        if not _NAME.match(site):
            raise ConfigError(f"--site {site!r}: allowed: 1-64 characters of letters, digits, '_' or '-'")
        check_router_name(router)
    if not 1 <= int(router_port) <= 65535:
        raise ConfigError(f"--router-port {router_port}: allowed: 1 to 65535")
    ops = {k: (st, tuple(v)) for k, (st, v) in operators.items()}
    obs = {k: (st, tuple(v)) for k, (st, v) in (observers or {}).items()}
    for opt, members in (
        ("--robot", {r: (st, ()) for r, st in robots.items()}),
        ("--operator", ops),
        ("--observer", obs),
    ):
        for name, (site, _) in members.items():
            if site not in sites:
                raise ConfigError(f"{opt} {name}@{site}: no such --site; allowed: {', '.join(sites)}")
    _check(list(robots), {k: v for k, (_, v) in ops.items()}, {k: v for k, (_, v) in obs.items()})
    taken = sorted({f"site-{s}" for s in sites} & {*robots, *ops, *obs})
    if taken:
        raise ConfigError(f"{taken[0]!r}: a name of a site's router login; allowed: any other name")
    return _write(Path(out), _Plan(dict(sites), dict(robots), ops, obs), int(router_port))


def _write(out: Path, plan: _Plan, port: int) -> Fleet:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: not an empty folder; allowed: a new or empty folder (nothing is overwritten)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        commands = _fill(tmp, plan, port)
        os.chmod(tmp, 0o700)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return Fleet(out, {name: out / name for name in commands}, commands, out / "ca-private" / "ca.key")


def _head(what: str, router_name: str, port: int, command: str, setup: str = "fleet") -> str:
    return (
        f"# bipedtele profile for {what}, written by `bipedtele setup {setup}`\n"
        f"# for the router {router_name}:{port}. Relative paths are read relative to this\n"
        f"# file's folder. Run:  {command}\n\n"
    )


@dataclass(frozen=True)
class _Plan:
    """Who is where: site -> its router's name; each robot's, operator's and observer's site."""

    routers: dict[str, str]  # site -> router name ("" : the one site of a fleet)
    robot_site: dict[str, str]
    operators: dict[str, tuple[str, tuple[str, ...]]]  # name -> (site, robots)
    observers: dict[str, tuple[str, tuple[str, ...]]]

    def router_folder(self, site: str) -> str:
        return "router" if site == "" else f"router-{site}"


def _fill(root: Path, plan: _Plan, port: int) -> dict[str, tuple[str, ...]]:
    first = next(iter(plan.routers.values()))
    certs = make_certs(root / "ca-private" / "issued", [first], ca_dir=root / "ca-private")
    sites = list(plan.routers)
    robots = list(plan.robot_site)
    users = [*robots, *plan.operators, *plan.observers]
    # one certificate per person and robot, named after its user: revoked one by one
    issued = root / "ca-private" / "issued" / "people"
    issued.mkdir()
    person = {u: issue_person_cert(issued, u, certs.ca_pem, root / "ca-private" / "ca.key") for u in users}
    links = {s: f"site-{s}" for s in sites[1:]}  # a later site's router logs in to the earlier ones
    passwords = {u: make_password() for u in [*users, *links.values()]}
    keys = {r: secrets.token_hex(32) + "\n" for r in robots}
    commands: dict[str, tuple[str, ...]] = {}
    setup = "fleet" if len(sites) == 1 else "sites"

    def head(what: str, router: str, cmd: str) -> str:
        return _head(what, router, port, cmd, setup)

    commands.update(_write_routers(root, plan, port, certs, passwords, head))

    for r in robots:
        name, router = f"robot-{r}", plan.routers[plan.robot_site[r]]
        folder = host_folder(root, name, certs.ca_pem, person[r])
        write_private(folder / "secrets" / f"{r}.pw", passwords[r] + "\n")
        write_private(folder / "secrets" / "message.key", keys[r])
        cmd = f"bipedtele follower --config {name}/bipedtele.toml"
        write_profile(
            folder / "bipedtele.toml",
            client_profile(head(f"robot {r}", router, cmd), "robot", router, port, r, r, r, "secrets/message.key"),
        )
        commands[name] = (cmd,)

    for op, (site, ids) in plan.operators.items():
        name, router = f"operator-{op}", plan.routers[site]
        folder = host_folder(root, name, certs.ca_pem, person[op])
        write_private(folder / "secrets" / f"{op}.pw", passwords[op] + "\n")
        cmds = []
        for r in ids:
            write_private(folder / "secrets" / f"{r}.key", keys[r])
            cmd = f"bipedtele leader --config {name}/{r}.toml"
            write_profile(
                folder / f"{r}.toml",
                client_profile(
                    head(f"operator {op} driving robot {r}", router, cmd),
                    "operator",
                    router,
                    port,
                    r,
                    op,
                    op,
                    f"secrets/{r}.key",
                ),
            )
            cmds.append(cmd)
        commands[name] = tuple(cmds)

    commands.update(_write_observers(root, plan, port, certs.ca_pem, (person, passwords, keys), head))

    keep_ca_only(root, certs, "fleet")
    return commands


def _write_observers(
    root: Path,
    plan: _Plan,
    port: int,
    ca_pem: Path,
    secrets_of: tuple[dict[str, tuple[Path, Path]], dict[str, str], dict[str, str]],
    head: Callable[[str, str, str], str],
) -> dict[str, tuple[str, ...]]:
    """Write each observer's folder (certificate, password, the watch keys of its robots, profile); its commands."""
    person, passwords, keys = secrets_of
    commands: dict[str, tuple[str, ...]] = {}
    for obs, (site, ids) in plan.observers.items():
        name, router = f"observer-{obs}", plan.routers[site]
        folder = host_folder(root, name, ca_pem, person[obs])
        write_private(folder / "secrets" / f"{obs}.pw", passwords[obs] + "\n")
        for r in ids:
            write_private(folder / "secrets" / f"{r}.watch", watch_key(bytes.fromhex(keys[r].strip())).hex() + "\n")
        cmd = f"bipedtele observe --config {name}/bipedtele.toml"
        fleet = f"bipedtele status --config {name}/bipedtele.toml"
        write_profile(
            folder / "bipedtele.toml",
            client_profile(
                head(f"observer {obs} watching {', '.join(ids)}", router, cmd),
                "observer",
                router,
                port,
                ids[0],
                obs,
                obs,
                "secrets",
            ),
        )
        commands[name] = (cmd, fleet)
    return commands


def _write_routers(
    root: Path,
    plan: _Plan,
    port: int,
    certs: CertFiles,
    passwords: dict[str, str],
    head: Callable[[str, str, str], str],
) -> dict[str, tuple[str, ...]]:
    """Each site's router folder: certificate, credentials, links to the earlier sites, the ACL."""
    sites, robots = list(plan.routers), list(plan.robot_site)
    users = [*robots, *plan.operators, *plan.observers]
    links = {s: f"site-{s}" for s in sites[1:]}
    commands: dict[str, tuple[str, ...]] = {}
    for i, site in enumerate(sites):
        name = plan.router_folder(site)
        if site == "":
            cert, cn = certs.pairs["router"], "router"
        else:
            cn = f"router-{site}"
            cert = issue_router_cert(
                certs.ca_pem.parent, cn, [plan.routers[site]], certs.ca_pem, root / "ca-private" / "ca.key"
            )
        folder = host_folder(root, name, certs.ca_pem, cert)
        local = [u for u in users if _site_of(plan, u) == site] + [links[s] for s in sites[i + 1 :]]
        write_private(folder / "secrets" / "router-credentials.txt", "".join(f"{u}:{passwords[u]}\n" for u in local))
        mesh: dict[str, Any] = {}
        if len(sites) > 1:
            mesh["connect"] = [tls_endpoint(plan.routers[s], port) for s in sites[:i]]
            if i > 0:
                write_private(folder / "secrets" / "router.pw", passwords[links[site]] + "\n")
                mesh.update(router_user=links[site], router_password_file="secrets/router.pw")
            mesh["routers_allowed"] = [f"router-{s}" for s in sites if s != site]
        cmd = f"bipedtele router --config {name}/bipedtele.toml"
        leaders_here = [f"{n}@{r}" for n, (st, ids) in plan.operators.items() if st == site for r in ids]
        observers_here = [f"{n}@{r}" for n, (st, ids) in plan.observers.items() if st == site for r in ids]
        write_profile(
            folder / "bipedtele.toml",
            router_profile(
                head(f"the router of site {site}" if site else "the fleet's router", plan.routers[site], cmd),
                plan.routers[site],
                port,
                next((r for r in robots if plan.robot_site[r] == site), robots[0]),
                leaders_here,
                [f"{r}@{r}" for r in robots if plan.robot_site[r] == site],
                observers_here,
                cert=cn,
                mesh=mesh,
                user_certs=True,
            ),
        )
        commands[name] = (cmd,)
    return commands


def _site_of(plan: _Plan, user: str) -> str:
    if user in plan.robot_site:
        return plan.robot_site[user]
    return (plan.operators.get(user) or plan.observers[user])[0]
