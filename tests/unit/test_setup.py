"""``bipedtele setup two-hosts``: three self-contained host folders, valid certificates,
private secrets, profiles that load from any working folder, and no overwriting."""

from __future__ import annotations

import os
import socket
import ssl
import stat
import subprocess
import sys
import threading
import tomllib
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.link.auth import load_message_auth
from bipedtele.tools.setup import make_certs, task_course, write_two_hosts

pytestmark = pytest.mark.timeout(120)

NAME = "router.example.org"


@pytest.fixture(scope="module")
def hosts(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("setup") / "two-hosts"
    write_two_hosts(out, NAME, 7450, "nao7")
    return out


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _toml(path: Path) -> dict:
    return tomllib.loads(path.read_text(encoding="utf-8"))


# ----------------------------------------------------------------- what goes where


def test_each_host_folder_holds_its_own_files_only(hosts: Path) -> None:
    expect = {
        "router": {
            "bipedtele.toml",
            "certs/ca.pem",
            "certs/router.pem",
            "certs/router.key",
            "secrets/router-credentials.txt",
        },
        "robot": {
            "bipedtele.toml",
            "certs/ca.pem",
            "certs/follower.pem",
            "certs/follower.key",
            "secrets/follower.pw",
            "secrets/message.key",
        },
        "operator": {
            "bipedtele.toml",
            "certs/ca.pem",
            "certs/leader.pem",
            "certs/leader.key",
            "secrets/leader.pw",
            "secrets/message.key",
        },
    }
    assert {p.name for p in hosts.iterdir()} == {"router", "robot", "operator", "ca-private"}
    for host, files in expect.items():
        got = {str(p.relative_to(hosts / host)) for p in (hosts / host).rglob("*") if p.is_file()}
        assert got == files, host
    # The CA's key is only in ca-private/, never in a folder that goes to a host.
    assert [p.relative_to(hosts) for p in hosts.rglob("ca.key")] == [Path("ca-private/ca.key")]
    for host in ("router", "robot", "operator"):
        text = "".join(p.read_text() for p in (hosts / host).rglob("*") if p.is_file())
        ca_key = (hosts / "ca-private" / "ca.key").read_text().strip()
        assert ca_key not in text


def test_secrets_are_private_and_consistent(hosts: Path) -> None:
    secret_files = [
        p for p in hosts.rglob("*") if p.is_file() and (p.suffix in (".key", ".pw") or p.parent.name == "secrets")
    ]
    # 4 TLS keys (the CA's and 3 hosts'), 2 message keys, 2 passwords, 1 credentials file.
    assert len(secret_files) == 9
    for p in secret_files:
        assert _mode(p) == 0o600, p
    for host in ("router", "robot", "operator"):
        assert _mode(hosts / host / "secrets") == 0o700
        assert _mode(hosts / host / "certs" / "ca.pem") == 0o644
    key_robot = (hosts / "robot" / "secrets" / "message.key").read_text().strip()
    key_operator = (hosts / "operator" / "secrets" / "message.key").read_text().strip()
    assert key_robot == key_operator
    assert len(key_robot) == 64 and bytes.fromhex(key_robot)
    leader_pw = (hosts / "operator" / "secrets" / "leader.pw").read_text().strip()
    follower_pw = (hosts / "robot" / "secrets" / "follower.pw").read_text().strip()
    assert len(leader_pw) >= 32 and len(follower_pw) >= 32 and leader_pw != follower_pw
    creds = (hosts / "router" / "secrets" / "router-credentials.txt").read_text().splitlines()
    assert creds == [f"leader:{leader_pw}", f"follower:{follower_pw}"]
    # Nothing of the router's gets the message key (the router never sees it).
    assert key_robot not in "".join(p.read_text() for p in (hosts / "router").rglob("*") if p.is_file())


def test_profiles_name_the_router_and_the_roles(hosts: Path) -> None:
    router = _toml(hosts / "router" / "bipedtele.toml")
    robot = _toml(hosts / "robot" / "bipedtele.toml")
    operator = _toml(hosts / "operator" / "bipedtele.toml")
    for prof in (router, robot, operator):
        assert prof["robot"]["id"] == "nao7"
    net = router["network"]
    assert net["mode"] == "router" and net["listen"] == ["tls/0.0.0.0:7450"]
    assert net["tls_mutual"] is True and net["tls_cert"] == "certs/router.pem"
    assert net["credentials_file"] == "secrets/router-credentials.txt"
    assert net["publishers_allowed"] == ["leader"] and net["followers_allowed"] == ["follower"]
    assert "message_key_file" not in net and "password_file" not in net
    for prof, user in ((robot, "follower"), (operator, "leader")):
        net = prof["network"]
        assert net["mode"] == "client" and net["connect"] == [f"tls/{NAME}:7450"]
        assert net["user"] == user and net["password_file"] == f"secrets/{user}.pw"
        assert net["tls_cert"] == f"certs/{user}.pem" and net["tls_mutual"] is True
        assert net["message_key_file"] == "secrets/message.key"
        assert "credentials_file" not in net
        assert prof["clock"]["mode"] == "ntp"
        # The paper's course, the same table as the shipped localhost-delay profile.
        assert prof["world"] == task_course() == _toml_shipped("localhost-delay")["world"]
    assert operator["leader"]["operator"] == "pilot"


def _toml_shipped(name: str) -> dict:
    from importlib import resources

    return tomllib.loads(resources.files("bipedtele.configs").joinpath(f"{name}.toml").read_text())


def test_each_profile_loads_from_any_working_folder(
    hosts: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # not the folder holding the host folders
    course = load_config("localhost-delay").section("world").obstacles
    for host, user in (("router", ""), ("robot", "follower"), ("operator", "leader")):
        cfg = load_config(hosts / host / "bipedtele.toml")
        net = cfg.section("network")
        assert net.user == user
        for field in ("tls_root_ca", "tls_cert", "tls_key", "password_file", "credentials_file", "message_key_file"):
            value = getattr(net, field)
            if value:  # every file the profile names is found from here
                assert Path(value).is_file(), (host, field, value)
        if host != "router":
            assert cfg.section("world").obstacles == course
            assert load_message_auth(net) is not None  # the key file passes the loader's checks
    assert load_config(hosts / "operator" / "bipedtele.toml").section("leader").operator == "pilot"


# ----------------------------------------------------------------- certificates


def _ctx_server(folder: Path, name: str) -> ssl.SSLContext:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(folder / "certs" / f"{name}.pem", folder / "certs" / f"{name}.key")
    ctx.load_verify_locations(folder / "certs" / "ca.pem")
    ctx.verify_mode = ssl.CERT_REQUIRED  # mutual TLS
    return ctx


def _ctx_client(folder: Path, name: str, ca: Path) -> ssl.SSLContext:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # checks the name and the chain
    ctx.load_cert_chain(folder / "certs" / f"{name}.pem", folder / "certs" / f"{name}.key")
    ctx.load_verify_locations(ca)
    return ctx


def _handshake(server: ssl.SSLContext, client: ssl.SSLContext, server_name: str) -> str | None:
    """None when a mutual-TLS handshake over loopback succeeds, else the client's error."""
    lsock = socket.create_server(("127.0.0.1", 0))
    port = lsock.getsockname()[1]
    seen: list[str] = []

    def serve() -> None:
        conn, _ = lsock.accept()
        try:
            with server.wrap_socket(conn, server_side=True) as tls:
                seen.append(tls.getpeercert()["subject"][0][0][1])
                tls.sendall(b"ok")
        except (ssl.SSLError, OSError):
            conn.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        with (
            socket.create_connection(("127.0.0.1", port), timeout=10) as raw,
            client.wrap_socket(raw, server_hostname=server_name) as tls,
        ):
            assert tls.recv(2) == b"ok"
        return None
    except (ssl.SSLError, ssl.CertificateError, OSError) as exc:
        return str(exc)
    finally:
        t.join(10)
        lsock.close()


def test_certificates_make_a_mutual_tls_session_with_the_router_name(hosts: Path, tmp_path: Path) -> None:
    server = _ctx_server(hosts / "router", "router")
    for host, user in (("robot", "follower"), ("operator", "leader")):
        client = _ctx_client(hosts / host, user, hosts / host / "certs" / "ca.pem")
        assert _handshake(server, client, NAME) is None
        wrong = _handshake(server, client, "other.example.org")
        assert wrong is not None and "match" in wrong.lower()  # the name is checked
    # A client certificate from another deployment's CA is refused.
    other = write_two_hosts(tmp_path / "other", NAME).out
    foreign = _ctx_client(other / "robot", "follower", hosts / "robot" / "certs" / "ca.pem")
    assert _handshake(server, foreign, NAME) is not None


def test_router_named_by_ip_gets_an_ip_certificate(tmp_path: Path) -> None:
    out = write_two_hosts(tmp_path / "ip", "127.0.0.1", 7447).out
    assert _toml(out / "robot" / "bipedtele.toml")["network"]["connect"] == ["tls/127.0.0.1:7447"]
    text = subprocess.run(
        ["openssl", "x509", "-in", str(out / "router" / "certs" / "router.pem"), "-noout", "-text"],
        capture_output=True,
        text=True,
        check=True,
        timeout=30,
    ).stdout
    assert "IP Address:127.0.0.1" in text
    server = _ctx_server(out / "router", "router")
    client = _ctx_client(out / "operator", "leader", out / "operator" / "certs" / "ca.pem")
    assert _handshake(server, client, "127.0.0.1") is None
    v6 = write_two_hosts(tmp_path / "ip6", "2001:db8::7", 7447).out
    assert _toml(v6 / "robot" / "bipedtele.toml")["network"]["connect"] == ["tls/[2001:db8::7]:7447"]


def test_make_certs_keeps_the_ca_key_apart(tmp_path: Path) -> None:
    files = make_certs(tmp_path / "certs", ["router.example.org", "192.0.2.1"])
    assert files.ca_key == tmp_path / "certs" / "ca-private" / "ca.key"
    assert sorted(p.name for p in (tmp_path / "certs").iterdir() if p.is_file()) == [
        "ca.pem",
        "follower.key",
        "follower.pem",
        "leader.key",
        "leader.pem",
        "router.key",
        "router.pem",
    ]
    assert _mode(files.ca_key) == 0o600 and _mode(files.ca_key.parent) == 0o700
    with pytest.raises(ConfigError, match="exists"):
        make_certs(tmp_path / "certs", ["router.example.org"])  # never overwritten


# ----------------------------------------------------------------- refusals and the command line


def test_refuses_a_non_empty_folder_and_bad_arguments(tmp_path: Path) -> None:
    out = tmp_path / "busy"
    out.mkdir()
    (out / "mine.txt").write_text("keep me")
    with pytest.raises(ConfigError, match=r"--out .*busy: not an empty folder"):
        write_two_hosts(out, NAME)
    assert [p.name for p in out.iterdir()] == ["mine.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert (write_two_hosts(empty, NAME).out / "router" / "bipedtele.toml").is_file()
    for bad in ("", "bad name", "-x.org", "a..b", "1.2.3"):
        with pytest.raises(ConfigError, match="--router-name"):
            write_two_hosts(tmp_path / "n", bad)
    with pytest.raises(ConfigError, match="--router-port"):
        write_two_hosts(tmp_path / "n", NAME, 0)
    with pytest.raises(ConfigError, match="--robot-id"):
        write_two_hosts(tmp_path / "n", NAME, 7447, "nao 1")
    assert not (tmp_path / "n").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no leftovers


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=cwd,
    )


def test_command_prints_one_folder_and_one_command_per_host(tmp_path: Path) -> None:
    res = _cli("setup", "two-hosts", "--router-name", NAME, "--out", "deploy", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    out = res.stdout
    for host in ("router", "robot", "operator"):
        assert f"deploy/{host}/" in out
    commands = [
        line.split(":", 1)[1].strip()
        for line in out.splitlines()
        if line.strip().startswith(("router:", "robot:", "operator:"))
    ]
    assert commands == [
        "bipedtele router --config router/bipedtele.toml",
        "bipedtele follower --config robot/bipedtele.toml",
        "bipedtele leader --config operator/bipedtele.toml",
    ]
    assert "ca-private/ca.key" in out
    again = _cli("setup", "two-hosts", "--router-name", NAME, "--out", "deploy", cwd=tmp_path)
    assert again.returncode == 2 and again.stdout == ""
    assert len(again.stderr.strip().splitlines()) == 1 and "not an empty folder" in again.stderr
    missing = _cli("setup", "two-hosts", cwd=tmp_path)
    assert missing.returncode == 2 and "--router-name" in missing.stderr


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_router_and_health_run_from_the_written_folders(tmp_path: Path) -> None:
    """The router's command as printed, and a robot-side health check through it (TLS,
    mutual certificates, password), each from its own working folder."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = write_two_hosts(tmp_path / "deploy", "127.0.0.1", port).out
    router_host, robot_host = tmp_path / "router-host", tmp_path / "robot-host"
    for host, place in (("router", router_host), ("robot", robot_host)):
        place.mkdir()
        os.rename(out / host, place / host)
    router = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bipedtele.cli",
            "router",
            "--config",
            "router/bipedtele.toml",
            "--set",
            f'network.listen=["tls/127.0.0.1:{port}"]',
        ],
        cwd=router_host,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None
        line = router.stdout.readline()
        assert "listening" in line, router.stderr.read() if router.stderr else line
        res = _cli("health", "--config", "robot/bipedtele.toml", "--role", "router", cwd=robot_host)
        assert res.returncode == 0, res.stdout + res.stderr
        # From elsewhere, with the path to the profile: the same.
        res = _cli("health", "--config", str(robot_host / "robot" / "bipedtele.toml"), "--role", "router", cwd=tmp_path)
        assert res.returncode == 0, res.stdout + res.stderr
    finally:
        router.terminate()
        router.wait(10)
