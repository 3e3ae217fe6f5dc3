"""``bipedtele setup``: what each host of a two-continent run needs, made in one go.

Sub-commands:

- ``bipedtele setup two-hosts --router-name NAME [--router-port 7447] [--out DIR]
  [--robot-id nao1]`` writes three self-contained folders, ``DIR/router/``,
  ``DIR/robot/`` and ``DIR/operator/``, one per host, each with a profile
  ``bipedtele.toml``, its certificates in ``certs/`` and its secrets in ``secrets/``; and
  the CA in ``DIR/ca-private/`` (keep it off the hosts). It prints which folder goes to
  which host and the one command to run on each (``docs/two-continents.md``).
- ``bipedtele setup certs OUT_DIR NAME [NAME ...]``: a CA and the router, leader and
  follower certificates (the same files as ``scripts/make-certs.sh``).
- ``bipedtele setup message-key FILE``: a key for end-to-end message authentication
  (32 random bytes as 64 hex characters, mode 0600; as ``scripts/make-message-key.sh``).

Certificates are made by the ``openssl`` command (OpenSSL 1.1.1 or later), so this works
from an installed package as well as from the repository. Paths in the written profiles
are relative to the profile's folder (see :mod:`bipedtele.config.profile`), so a folder can be
copied anywhere and used from any working folder.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import secrets
import shutil
import subprocess
import tempfile
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.link.auth import write_message_key

__all__ = [
    "FOLLOWER_USER",
    "LEADER_USER",
    "ROBOT_ID",
    "CertFiles",
    "TwoHosts",
    "check_router_name",
    "client_profile",
    "host_folder",
    "issue_router_cert",
    "keep_ca_only",
    "make_certs",
    "make_message_key",
    "make_password",
    "router_profile",
    "task_course",
    "tls_endpoint",
    "write_private",
    "write_profile",
    "write_two_hosts",
]

#: Who connects as which user, and whose certificate each host gets.
LEADER_USER = "leader"
FOLLOWER_USER = "follower"
HOSTS = ("router", "robot", "operator")
_CERT_OF_HOST = {"router": "router", "robot": FOLLOWER_USER, "operator": LEADER_USER}
_CA_DAYS = 3650
_CERT_DAYS = 825
_DNS_LABEL = r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_DNS_NAME = re.compile(rf"^{_DNS_LABEL}(?:\.{_DNS_LABEL})*\.?$")
ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


# --------------------------------------------------------------------------- secrets


def write_private(path: Path, text: str) -> None:
    """Create ``path`` (never overwriting) readable by its owner only (mode 0600)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.chmod(path, 0o600)  # whatever the umask


def make_message_key(path: str | Path) -> Path:
    """Write a new message key: 32 random bytes as 64 hex characters, mode 0600.

    Raises
    ------
    FileExistsError
        ``path`` exists (a key is never overwritten: both ends must hold the same one).
    """
    path = Path(path)
    write_message_key(path)  # the one writer of key files (bipedtele.link.auth reads them)
    return path


def make_password() -> str:
    """Return a random password: 32 characters of ``[A-Za-z0-9_-]`` (192 bits; no ``:``)."""
    return secrets.token_urlsafe(24)


# --------------------------------------------------------------------------- certificates


@dataclass(frozen=True)
class CertFiles:
    """Where :func:`make_certs` wrote the files.

    Attributes
    ----------
    ca_pem : Path
        The CA certificate (copy to every host).
    ca_key : Path
        The CA's private key, in its own folder: keep it off the hosts.
    pairs : dict
        ``"router" | "leader" | "follower"`` -> (certificate, key).
    """

    ca_pem: Path
    ca_key: Path
    pairs: Mapping[str, tuple[Path, Path]]


def _subject_alt_names(names: Sequence[str]) -> str:
    alt = []
    for name in names:
        try:
            ipaddress.ip_address(name)
            alt.append(f"IP:{name}")
        except ValueError:
            alt.append(f"DNS:{name}")
    return ",".join(alt)


def check_router_name(name: str) -> str:
    """``name`` if it is a DNS name or an IP address, else :class:`ConfigError`."""
    try:
        ipaddress.ip_address(name)
        return name
    except ValueError:
        pass
    if len(name) <= 253 and _DNS_NAME.match(name) and not name.replace(".", "").isdigit():
        return name
    raise ConfigError(f"--router-name {name!r}: allowed: the router's DNS name (router.example.org) or IP address")


def _openssl(*args: str) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise ConfigError("openssl: not found; allowed: install it (apt-get install openssl)")
    res = subprocess.run([exe, *args], capture_output=True, text=True, timeout=60, check=False)
    if res.returncode != 0:
        last = (res.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise ConfigError(f"openssl {args[0]}: failed ({last}); allowed: OpenSSL 1.1.1 or later")


def make_certs(out_dir: str | Path, router_names: Sequence[str], ca_dir: str | Path | None = None) -> CertFiles:
    """Make a private CA, the router's server certificate and the two client certificates.

    The same files as ``scripts/make-certs.sh``: EC P-256 keys; the CA (10 years) with
    ``CA:TRUE``; ``router`` (825 days) with ``router_names`` as subjectAltName (DNS names
    and IP addresses) and server+client use; ``leader`` and ``follower`` (client+server
    use, names ``DNS:leader`` / ``DNS:follower``) for mutual TLS.

    Parameters
    ----------
    out_dir : str or Path
        Receives ``ca.pem`` and ``NAME.pem`` / ``NAME.key`` (keys mode 0600).
    router_names : sequence of str
        DNS names and/or IP addresses by which the clients reach the router.
    ca_dir : str or Path, optional
        Folder of the CA's key ``ca.key`` (default ``out_dir/ca-private``), kept apart so
        that copying ``out_dir``'s files to a host never copies it.

    Raises
    ------
    ConfigError
        No name, a bad name, no ``openssl``, or ``openssl`` failed.
    """
    if not router_names:
        raise ConfigError("router names: none given; allowed: one or more DNS names or IP addresses")
    names = [check_router_name(n) for n in router_names]
    out = Path(out_dir)
    ca_folder = Path(ca_dir) if ca_dir is not None else out / "ca-private"
    out.mkdir(parents=True, exist_ok=True)
    ca_folder.mkdir(parents=True, exist_ok=True)
    os.chmod(ca_folder, 0o700)
    ca_pem, ca_key = out / "ca.pem", ca_folder / "ca.key"
    for taken in (ca_pem, ca_key):
        if taken.exists():
            raise ConfigError(f"{taken}: exists; allowed: a folder without certificates (never overwritten)")
    old_umask = os.umask(0o077)
    try:
        _openssl(
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-days",
            str(_CA_DAYS),
            "-keyout",
            str(ca_key),
            "-out",
            str(ca_pem),
            "-subj",
            "/CN=bipedtele CA",
            "-addext",
            "basicConstraints=critical,CA:TRUE",
            "-addext",
            "keyUsage=critical,keyCertSign,cRLSign",
        )
        pairs = {
            "router": _issue(out, "router", _subject_alt_names(names), "serverAuth,clientAuth", ca_pem, ca_key),
            LEADER_USER: _issue(out, LEADER_USER, f"DNS:{LEADER_USER}", "clientAuth,serverAuth", ca_pem, ca_key),
            FOLLOWER_USER: _issue(out, FOLLOWER_USER, f"DNS:{FOLLOWER_USER}", "clientAuth,serverAuth", ca_pem, ca_key),
        }
    finally:
        os.umask(old_umask)
    for pem in (ca_pem, *(p for p, _ in pairs.values())):
        os.chmod(pem, 0o644)
    for key in (ca_key, *(k for _, k in pairs.values())):
        os.chmod(key, 0o600)
    return CertFiles(ca_pem, ca_key, pairs)


def _issue(out: Path, name: str, alt: str, eku: str, ca_pem: Path, ca_key: Path) -> tuple[Path, Path]:
    pem, key = out / f"{name}.pem", out / f"{name}.key"
    with tempfile.TemporaryDirectory(prefix="bipedtele-cert-") as tmp:
        csr, ext = Path(tmp) / f"{name}.csr", Path(tmp) / f"{name}.ext"
        _openssl(
            "req",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-keyout",
            str(key),
            "-out",
            str(csr),
            "-subj",
            f"/CN={name}",
        )
        ext.write_text(
            "basicConstraints=CA:FALSE\n"
            "keyUsage=critical,digitalSignature,keyEncipherment\n"
            f"extendedKeyUsage={eku}\n"
            f"subjectAltName={alt}\n",
            encoding="utf-8",
        )
        _openssl(
            "x509",
            "-req",
            "-in",
            str(csr),
            "-CA",
            str(ca_pem),
            "-CAkey",
            str(ca_key),
            "-set_serial",
            f"0x{secrets.token_hex(16)}",
            "-days",
            str(_CERT_DAYS),
            "-out",
            str(pem),
            "-extfile",
            str(ext),
        )
    return pem, key


# --------------------------------------------------------------------------- profiles


def task_course() -> dict[str, Any]:
    """Return the paper's task course: the ``[world]`` table of the shipped ``localhost-delay`` profile."""
    text = resources.files("bipedtele.configs").joinpath("localhost-delay.toml").read_text(encoding="utf-8")
    world = tomllib.loads(text).get("world")
    if not isinstance(world, dict) or not world.get("obstacles"):
        raise RuntimeError("configs/localhost-delay.toml has no [world] obstacles")  # a packaging bug
    return world


def demo_control() -> dict[str, Any]:
    """Return the demo's control tuning: the ``[control]`` table of the shipped ``localhost-delay`` profile."""
    text = resources.files("bipedtele.configs").joinpath("localhost-delay.toml").read_text(encoding="utf-8")
    control = tomllib.loads(text).get("control")
    if not isinstance(control, dict) or not control:
        raise RuntimeError("configs/localhost-delay.toml has no [control] table")  # a packaging bug
    return control


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string for printable text
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write a {type(value).__name__} to TOML")


def _toml_table(name: str, table: Mapping[str, Any], comments: Mapping[str, str] | None = None) -> str:
    """``[name]`` with its scalar keys, then its arrays of tables (``[[name.key]]``)."""
    comments = comments or {}
    lines = [f"[{name}]"]
    subtables = []
    for key, value in table.items():
        if isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
            subtables.append((key, value))
            continue
        line = f"{key} = {_toml_value(value)}"
        if key in comments:
            line = f"{line:<48} # {comments[key]}"
        lines.append(line)
    for key, items in subtables:
        for item in items:
            lines += ["", f"[[{name}.{key}]]", *(f"{k} = {_toml_value(v)}" for k, v in item.items())]
    return "\n".join(lines) + "\n"


def tls_endpoint(name: str, port: int) -> str:
    """``tls/NAME:PORT`` (an IPv6 address in brackets)."""
    try:
        if ipaddress.ip_address(name).version == 6:
            return f"tls/[{name}]:{port}"
    except ValueError:
        pass
    return f"tls/{name}:{port}"


_CLOCK = {"mode": "ntp", "delay_window_s": 1.0, "ping_rate_hz": 4.0, "ping_window": 16, "conservative_split": True}
_CLOCK_NOTE = (
    "# The two hosts' clocks differ: ntp mode estimates the offset with a ping exchange; the\n"
    "# round trip is exact, its split only up to the path's asymmetry, so the stability\n"
    "# conditions use the safe bound h1 = h2 = round trip (conservative_split).\n"
)
_CONTROL_NOTE = (
    "# The demo's control tuning (configs/localhost-delay.toml): the handle's reach mapped to\n"
    "# the walker's speed range, and the reduced model of (30) calibrated on the walker.\n"
)
_WORLD_NOTE = (
    "# The paper's task course (Sec. 5, Fig. 10), as in configs/localhost-delay.toml: the\n"
    "# follower builds it in the simulator and the pilot operator steers around it, so both\n"
    "# hosts' profiles carry the same table.\n"
)


def router_profile(
    head: str,
    router_name: str,
    port: int,
    robot_id: str,
    publishers: Sequence[str],
    followers: Sequence[str],
    observers: Sequence[str] = (),
    *,
    cert: str = "router",
    mesh: Mapping[str, Any] | None = None,
    user_certs: bool = False,
) -> str:
    """Return the router's profile: TLS listener, credentials and the ACL's roles.

    ``publishers``, ``followers`` and ``observers`` are ``publishers_allowed`` /
    ``followers_allowed`` / ``observers_allowed`` entries (a user, or ``user@robot_id`` for
    one robot); ``cert`` names ``certs/<cert>.pem``; ``mesh`` adds the links to other
    sites' routers (``connect``, ``router_user``, ``router_password_file``,
    ``routers_allowed``); ``user_certs``: every client holds a certificate named after its
    user (``tls_user_certs``).
    """
    net = _toml_table(
        "network",
        {
            "mode": "router",
            "listen": [f"tls/0.0.0.0:{port}"],
            "multicast_scouting": False,
            "tls_root_ca": "certs/ca.pem",
            "tls_cert": f"certs/{cert}.pem",
            "tls_key": f"certs/{cert}.key",
            "tls_mutual": True,
            **({"tls_user_certs": True} if user_certs else {}),
            "credentials_file": "secrets/router-credentials.txt",
            **({"revoked": []} if user_certs else {}),
            "publishers_allowed": list(publishers),
            "followers_allowed": list(followers),
            **({"observers_allowed": list(observers)} if observers else {}),
            **dict(mesh or {}),
            "links": "split",
            "timeout_s": 20.0,
        },
        {
            "links": "also listens on UDP at the same port: the clients' control link",
            "tls_mutual": "clients must show a certificate of this CA",
            "tls_user_certs": "each person's certificate names its user: a role only with one's own",
            "revoked": "people refused (login and certificate name): add one, restart the router",
            "credentials_file": "user:password lines (leaders, followers)",
            "publishers_allowed": "users with the leader's role (commands); user@robot: that robot only",
            "followers_allowed": "users with the follower's role (feedback, video); user@robot: as that robot only",
            "observers_allowed": "users who receive video and status and put nothing",
            "connect": "the other sites' routers this one links to",
            "routers_allowed": "the other sites' routers, by certificate name",
        },
    )
    return "".join([head, _toml_table("robot", {"id": robot_id}), "\n", net])


def issue_person_cert(out: Path, user: str, ca_pem: Path, ca_key: Path) -> tuple[Path, Path]:
    """Issue ``out/<user>.pem`` and ``.key``: one person's (or robot's) client certificate, named ``user``.

    With ``[network] tls_user_certs`` the router gives a role only to a session whose
    certificate names its user, so each person can be revoked alone (``[network] revoked``).
    """
    return _issue(out, user, f"DNS:{user}", "clientAuth,serverAuth", ca_pem, ca_key)


def issue_router_cert(out: Path, cn: str, names: Sequence[str], ca_pem: Path, ca_key: Path) -> tuple[Path, Path]:
    """Issue ``out/<cn>.pem`` and ``.key``: a router certificate named ``cn`` for ``names`` (DNS or IP)."""
    return _issue(
        out, cn, _subject_alt_names([check_router_name(n) for n in names]), "serverAuth,clientAuth", ca_pem, ca_key
    )


def client_profile(
    head: str, host: str, router_name: str, port: int, robot_id: str, user: str, cert: str, key_file: str
) -> str:
    """Return a robot's (``host="robot"``), an operator's or an observer's profile, a client of the router.

    ``user`` logs in with ``secrets/<user>.pw``; ``cert`` names ``certs/<cert>.pem`` and
    ``.key``; ``key_file`` is the message key shared with the other end (an observer's:
    the folder of its watch keys).
    """
    keys: dict[str, Any] = {"message_key_file": key_file} if host != "observer" else {"watch_key_dir": key_file}
    net = _toml_table(
        "network",
        {
            "mode": "client",
            "connect": [tls_endpoint(router_name, port)],
            "listen": [],
            "multicast_scouting": False,
            "tls_root_ca": "certs/ca.pem",
            "tls_cert": f"certs/{cert}.pem",
            "tls_key": f"certs/{cert}.key",
            "tls_mutual": True,
            "user": user,
            "password_file": f"secrets/{user}.pw",
            **keys,
            "links": "split",
            "timeout_s": 20.0,
        },
        {
            "links": "control as UDP datagrams (HMAC, not encrypted); status and video on TLS links",
            "connect": "the router's name, as in its certificate",
            "message_key_file": "the same key on robot and operator; never on the router",
            "watch_key_dir": "<robot>.watch files: verify video and status, sign nothing",
        },
    )
    if host == "observer":
        return "".join([head, _toml_table("robot", {"id": robot_id}), "\n", net])
    parts = [head, _toml_table("robot", {"id": robot_id}), "\n", net, "\n", _CLOCK_NOTE, _toml_table("clock", _CLOCK)]
    parts += ["\n", _CONTROL_NOTE, _toml_table("control", demo_control())]
    if host == "operator":
        parts += ["\n", _toml_table("leader", {"operator": "pilot"}, {"operator": "walks the course below"})]
    parts += ["\n", _WORLD_NOTE, _toml_table("world", task_course())]
    return "".join(parts)


def _profile_text(host: str, router_name: str, port: int, robot_id: str) -> str:
    cmd = {"router": "router", "robot": "follower", "operator": "leader"}[host]
    head = (
        f"# bipedtele profile for the {host} host, written by `bipedtele setup two-hosts`\n"
        f"# for the router {router_name}:{port}. Relative paths are read relative to this\n"
        f"# file's folder. Run:  bipedtele {cmd} --config {host}/bipedtele.toml\n\n"
    )
    if host == "router":
        # the certificates leader and follower name the users leader and follower
        return router_profile(head, router_name, port, robot_id, [LEADER_USER], [FOLLOWER_USER], user_certs=True)
    user = FOLLOWER_USER if host == "robot" else LEADER_USER
    return client_profile(head, host, router_name, port, robot_id, user, user, "secrets/message.key")


@dataclass(frozen=True)
class TwoHosts:
    """What :func:`write_two_hosts` wrote.

    Attributes
    ----------
    out : Path
        The folder holding ``router/``, ``robot/``, ``operator/`` and ``ca-private/``.
    folders : dict
        Host name (``router``, ``robot``, ``operator``) -> its folder.
    commands : dict
        Host name -> the one command to run there (from the folder holding the host's
        folder; ``--config`` may also be given any path to the profile).
    ca_key : Path
        The CA's private key (keep it off the hosts).
    """

    out: Path
    folders: Mapping[str, Path]
    commands: Mapping[str, str]
    ca_key: Path


def write_two_hosts(out: str | Path, router_name: str, router_port: int = 7447, robot_id: str = "nao1") -> TwoHosts:
    """Write the router's, the robot's and the operator's folders into ``out``.

    ``out`` must not exist or be an empty folder. Everything is written into a temporary
    folder beside it first and moved into place at the end, so a failure leaves nothing.

    Raises
    ------
    ConfigError
        ``out`` is not empty, a bad name, port or robot id, or ``openssl`` failed.
    """
    router_name = check_router_name(router_name)
    if not 1 <= int(router_port) <= 65535:
        raise ConfigError(f"--router-port {router_port}: allowed: 1 to 65535")
    if not ROBOT_ID.match(robot_id):
        raise ConfigError(f"--robot-id {robot_id!r}: allowed: 1-64 characters of letters, digits, '_' or '-'")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: not an empty folder; allowed: a new or empty folder (nothing is overwritten)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        _fill(tmp, router_name, int(router_port), robot_id)
        os.chmod(tmp, 0o700)
        os.replace(tmp, out)  # atomic; an empty `out` is replaced too
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    folders = {h: out / h for h in HOSTS}
    cmd = {"router": "router", "robot": "follower", "operator": "leader"}
    commands = {h: f"bipedtele {cmd[h]} --config {h}/bipedtele.toml" for h in HOSTS}
    return TwoHosts(out, folders, commands, out / "ca-private" / "ca.key")


def host_folder(root: Path, name: str, ca_pem: Path, cert: tuple[Path, Path]) -> Path:
    """Make ``root/name`` (mode 0700) with ``certs/`` (the CA and ``cert``'s pair) and ``secrets/``."""
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


def write_profile(path: Path, text: str) -> None:
    """Write a profile (mode 0644: it names files, it holds no secret)."""
    path.write_text(text, encoding="utf-8")
    os.chmod(path, 0o644)


def _fill(root: Path, router_name: str, port: int, robot_id: str) -> None:
    certs = make_certs(root / "ca-private" / "issued", [router_name], ca_dir=root / "ca-private")
    passwords = {LEADER_USER: make_password(), FOLLOWER_USER: make_password()}
    key_hex = secrets.token_hex(32) + "\n"
    for host in HOSTS:
        folder = host_folder(root, host, certs.ca_pem, certs.pairs[_CERT_OF_HOST[host]])
        if host == "router":
            lines = "".join(f"{u}:{p}\n" for u, p in passwords.items())
            write_private(folder / "secrets" / "router-credentials.txt", lines)
        else:
            user = FOLLOWER_USER if host == "robot" else LEADER_USER
            write_private(folder / "secrets" / f"{user}.pw", passwords[user] + "\n")
            write_private(folder / "secrets" / "message.key", key_hex)
        write_profile(folder / "bipedtele.toml", _profile_text(host, router_name, port, robot_id))
    keep_ca_only(root, certs, "deployment")


def keep_ca_only(root: Path, certs: CertFiles, what: str) -> None:
    """Leave only the CA's certificate and key in ``root/ca-private/`` (the hosts have their copies)."""
    os.replace(certs.ca_pem, root / "ca-private" / "ca.pem")
    shutil.rmtree(certs.ca_pem.parent)
    (root / "ca-private" / "README.txt").write_text(
        f"ca.key signs the certificates of this {what}. Keep it off the router, robot and\n"
        "operator hosts (offline); it is needed only to issue new certificates.\n",
        encoding="utf-8",
    )
