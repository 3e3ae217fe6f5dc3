"""Transport configuration: key expressions and the Zenoh config built from [network]."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import zenoh
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.acl import access_control_json
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import zenoh_config


def test_keys() -> None:
    k = Keys("nao1")
    assert k.cmd == "bipedtele/nao1/cmd"
    assert k.all() == {n: f"bipedtele/nao1/{n}" for n in ("cmd", "feedback", "video", "clock", "status")}
    assert k.presence("leader") == "bipedtele/nao1/presence/leader"
    with pytest.raises(ValueError, match="allowed: leader"):
        k.presence("boss")
    for bad in ("", "a/b", "x*", "$y", "a b"):
        with pytest.raises(ConfigError, match="robot id"):
            Keys(bad)


def _get(conf: object, key: str) -> object:
    return json.loads(conf.get_json(key))  # type: ignore[attr-defined]


def test_zenoh_config_from_network(tmp_path: Path) -> None:
    pem = tmp_path / "c.pem"
    pem.write_text("x")
    pw = tmp_path / "pw"
    pw.write_text("secret\n")
    net = NetworkConfig(
        mode="client",
        connect=["tls/router:7447"],
        tls_root_ca=str(pem),
        tls_cert=str(pem),
        tls_key=str(pem),
        tls_mutual=True,
        user="leader",
        password_file=str(pw),
    )
    c = zenoh_config(net)
    assert _get(c, "mode") == "client"
    assert _get(c, "connect/endpoints") == ["tls/router:7447"]
    assert _get(c, "scouting/multicast/enabled") is False
    assert _get(c, "transport/link/tls/root_ca_certificate") == str(pem)
    assert _get(c, "transport/link/tls/enable_mtls") is True
    assert _get(c, "transport/link/tls/connect_certificate") == str(pem)
    assert _get(c, "transport/auth/usrpwd/user") == "leader"
    assert _get(c, "transport/auth/usrpwd/password") == "secret"
    peer = zenoh_config(NetworkConfig(listen=["tcp/127.0.0.1:7447"]), connect=[])
    assert _get(peer, "listen/endpoints") == ["tcp/127.0.0.1:7447"]


def test_zenoh_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"tls_root_ca.*no such file"):
        zenoh_config(NetworkConfig(tls_root_ca=str(tmp_path / "none.pem")))
    with pytest.raises(ConfigError, match="password_file"):
        zenoh_config(NetworkConfig(user="u", password_file=str(tmp_path / "none")))
    with pytest.raises(ConfigError, match="both a user and a password"):
        zenoh_config(NetworkConfig(user="u"))
    with pytest.raises(ConfigError, match="tls_mutual"):
        zenoh_config(NetworkConfig(tls_mutual=True))


def _allowed(acl: dict, user: str, flow: str, message: str, key: str) -> bool:
    """Zenoh's decision for a deny-by-default ACL: some allow rule of the user's policy,
    for this flow and message kind, has a key expression that includes ``key``."""
    subjects = {s["id"] for s in acl["subjects"] if user in s["usernames"]}
    rule_ids = {r for p in acl["policies"] if subjects & set(p["subjects"]) for r in p["rules"]}
    return any(
        zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key))
        for r in acl["rules"]
        if r["id"] in rule_ids and flow in r["flows"] and message in r["messages"] and r["permission"] == "allow"
        for k in r["key_exprs"]
    )


WILDCARD_CMD = ["**", "bipedtele/**", "bipedtele/*/*", "bipedtele/nao1/*", "bipedtele/*/cmd", "bipedtele/nao1/cmd"]


def test_access_control_roles_deny_by_default(tmp_path: Path) -> None:
    assert access_control_json(NetworkConfig()) is None
    creds = tmp_path / "c.txt"
    creds.write_text("# users\nleader:a\nfollower:b\nviewer:c\n")
    net = NetworkConfig(credentials_file=str(creds), publishers_allowed=["leader"], followers_allowed=["follower"])
    acl = access_control_json(net)
    assert acl is not None and acl["enabled"] is True and acl["default_permission"] == "deny"
    # every key expression in a rule is valid for Zenoh (exact or a wildcard pattern)
    for r in acl["rules"]:
        for k in r["key_exprs"]:
            zenoh.KeyExpr(k)
    root = "bipedtele/nao1"
    # only the leader may put a command, and only on the command keys (of one robot or
    # of every robot), never on a wildcard that also covers the follower's keys
    for key in WILDCARD_CMD:
        assert _allowed(acl, "leader", "ingress", "put", key) == key.endswith("/cmd"), key
        for user in ("follower", "viewer", "nobody"):
            assert not _allowed(acl, user, "ingress", "put", key), (user, key)
    roles = {
        "leader": (("cmd", "clock", "status"), ("feedback", "video", "status", "clock")),
        "follower": (("feedback", "video", "status", "clock"), ("cmd", "clock", "status")),
    }
    for user, (pub, sub) in roles.items():
        for name in ("cmd", "feedback", "video", "clock", "status"):
            key = f"{root}/{name}"
            assert _allowed(acl, user, "ingress", "put", key) == (name in pub), (user, name)
            assert _allowed(acl, user, "ingress", "declare_subscriber", key) == (name in sub), (user, name)
            assert _allowed(acl, user, "egress", "put", key) == (name in sub), (user, name)
            assert not _allowed(acl, user, "ingress", "delete", key)
        other = "follower" if user == "leader" else "leader"
        assert _allowed(acl, user, "ingress", "liveliness_token", f"{root}/presence/{user}/abc")
        assert not _allowed(acl, user, "ingress", "liveliness_token", f"{root}/presence/{other}/abc")
        assert _allowed(acl, user, "ingress", "declare_liveliness_subscriber", f"{root}/presence/{other}/*")
        assert _allowed(acl, user, "egress", "liveliness_token", f"{root}/presence/{other}/abc")
    for flow, message in (
        ("ingress", "put"),
        ("ingress", "declare_subscriber"),
        ("egress", "put"),
        ("ingress", "liveliness_token"),
        ("ingress", "declare_liveliness_subscriber"),
    ):
        for key in ("**", f"{root}/feedback", f"{root}/presence/leader/x", f"{root}/presence/*/*"):
            assert not _allowed(acl, "viewer", flow, message, key), (flow, message, key)
    # a leader-only ACL: the follower user has no role at all
    only = access_control_json(NetworkConfig(credentials_file=str(creds), publishers_allowed=["leader"]))
    assert only is not None and not _allowed(only, "follower", "ingress", "put", f"{root}/feedback")


def test_a_user_bound_to_a_robot_reaches_that_robot_only(tmp_path: Path) -> None:
    """Issue 23 (per-robot authority): ``publishers_allowed = ["alice@nao1"]`` lets alice command
    nao1 and nothing else; before, every leader of a router could command every robot on it."""
    creds = tmp_path / "c.txt"
    creds.write_text("alice:a\ncarol:c\ndave:d\nf1:x\nf2:y\n")
    net = NetworkConfig(
        credentials_file=str(creds),
        publishers_allowed=["alice@nao1", "carol@nao2", "carol@nao3", "dave"],
        followers_allowed=["f1@nao1", "f2@nao2"],
    )
    acl = access_control_json(net)
    assert acl is not None
    for r in acl["rules"]:
        for k in r["key_exprs"]:
            zenoh.KeyExpr(k)
    reach = {"alice": {"nao1"}, "carol": {"nao2", "nao3"}, "dave": {"nao1", "nao2", "nao3"}}
    for user, robots in reach.items():
        for robot in ("nao1", "nao2", "nao3"):
            mine = robot in robots
            assert _allowed(acl, user, "ingress", "put", f"bipedtele/{robot}/cmd") == mine, (user, robot)
            assert _allowed(acl, user, "egress", "put", f"bipedtele/{robot}/feedback") == mine, (user, robot)
            assert _allowed(acl, user, "ingress", "liveliness_token", f"bipedtele/{robot}/presence/leader/z") == mine
            assert _allowed(acl, user, "egress", "liveliness_token", f"bipedtele/{robot}/presence/follower/z") == mine
        for key in WILDCARD_CMD[:-1]:  # a bound user: no wildcard put at all; an unbound one: on */cmd only
            assert _allowed(acl, user, "ingress", "put", key) == (user == "dave" and key.endswith("/cmd")), (user, key)
    for user, robot in (("f1", "nao1"), ("f2", "nao2")):
        for other in ("nao1", "nao2", "nao3"):
            assert _allowed(acl, user, "ingress", "put", f"bipedtele/{other}/feedback") == (other == robot)
            assert _allowed(acl, user, "egress", "put", f"bipedtele/{other}/cmd") == (other == robot)
            assert not _allowed(acl, user, "ingress", "put", f"bipedtele/{other}/cmd")


@pytest.mark.parametrize(
    ("entry", "why"),
    [("@nao1", "'user' or 'user@robot_id'"), ("alice@", "'user' or 'user@robot_id'"), ("alice@na o1", "robot id")],
)
def test_a_bad_binding_is_one_line(entry: str, why: str) -> None:
    with pytest.raises(ValueError, match=re.escape(why)):
        NetworkConfig(publishers_allowed=[entry])
    with pytest.raises(ValueError, match="each user in at most one role"):
        NetworkConfig(publishers_allowed=["alice@nao1"], followers_allowed=["alice@nao2"])


def test_access_control_errors(tmp_path: Path) -> None:
    creds = tmp_path / "c.txt"
    creds.write_text("leader:a\nfollower:b\n")
    with pytest.raises(ConfigError, match=r"need network\.credentials_file"):
        access_control_json(NetworkConfig(publishers_allowed=["leader"]))
    with pytest.raises(ConfigError, match=r"need network\.credentials_file"):
        access_control_json(NetworkConfig(followers_allowed=["follower"]))
    with pytest.raises(ConfigError, match="publishers_allowed = 'boss': not a user"):
        access_control_json(NetworkConfig(credentials_file=str(creds), publishers_allowed=["boss"]))
    with pytest.raises(ConfigError, match="followers_allowed = 'robot': not a user"):
        access_control_json(NetworkConfig(credentials_file=str(creds), followers_allowed=["robot"]))
    with pytest.raises(ValueError, match="at most one role"):
        NetworkConfig(publishers_allowed=["leader"], followers_allowed=["leader"])
    creds.write_text("leader-without-password\n")
    with pytest.raises(ConfigError, match="line 1 is not user:password"):
        access_control_json(NetworkConfig(credentials_file=str(creds), publishers_allowed=["leader"]))


def _same(got: object, want: Path) -> bool:
    """Same file (profile paths may be resolved relative to the profile's folder)."""
    return isinstance(got, str) and Path(got).resolve() == want.resolve()


def _shared_profile(tmp_path: Path) -> Path:
    """The intercontinental profile's shape: one [network] for all three roles, with
    files that exist only on the host of the role that reads them."""
    text = (
        '[network]\nmode = "client"\nconnect = ["tls/router.example.org:7447"]\n'
        'tls_root_ca = "ca.pem"\ntls_cert = "me.pem"\ntls_key = "me.key"\ntls_mutual = true\n'
        'user = "leader"\npassword_file = "secrets/leader.pw"\nmessage_key_file = "secrets/message.key"\n'
        'credentials_file = "secrets/router-credentials.txt"\npublishers_allowed = ["leader"]\n'
        'followers_allowed = ["follower"]\n'
    )
    prof = tmp_path / "shared.toml"
    prof.write_text(text)
    return prof


def test_each_role_reads_only_its_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    prof = _shared_profile(tmp_path)
    for name in ("ca.pem", "me.pem", "me.key"):
        (tmp_path / name).write_text("x")
    (tmp_path / "secrets").mkdir()
    monkeypatch.chdir(tmp_path)
    net = load_config(prof).section("network")

    # router host: no client password file, no message key; its credentials file only
    (tmp_path / "secrets" / "router-credentials.txt").write_text("leader:a\nfollower:b\n")
    router = zenoh_config(net, mode="router", listen=["tls/0.0.0.0:7447"])
    assert _same(_get(router, "transport/auth/usrpwd/dictionary_file"), tmp_path / "secrets/router-credentials.txt")
    assert _get(router, "transport/auth/usrpwd/user") is None
    assert _same(_get(router, "transport/link/tls/listen_certificate"), tmp_path / "me.pem")
    assert _get(router, "access_control")["default_permission"] == "deny"

    # client hosts: no credentials file (router only), a password file of their own
    (tmp_path / "secrets" / "router-credentials.txt").unlink()
    (tmp_path / "secrets" / "leader.pw").write_text("a\n")
    client = zenoh_config(net)
    assert _get(client, "transport/auth/usrpwd/user") == "leader"
    assert _get(client, "transport/auth/usrpwd/password") == "a"
    assert _get(client, "transport/auth/usrpwd/dictionary_file") is None
    assert _get(client, "access_control/enabled") is False
    assert _same(_get(client, "transport/link/tls/connect_certificate"), tmp_path / "me.pem")
    assert _get(client, "transport/link/tls/listen_certificate") is None
    peer = zenoh_config(net, mode="peer", listen=[])
    assert _get(peer, "transport/auth/usrpwd/dictionary_file") is None
    assert _get(peer, "transport/auth/usrpwd/user") == "leader"

    # and each still reads its own: a router without its credentials file, a client
    # without its password file, fail on exactly that
    with pytest.raises(ConfigError, match=r"credentials_file.*cannot read"):
        zenoh_config(net, mode="router")
    (tmp_path / "secrets" / "leader.pw").unlink()
    with pytest.raises(ConfigError, match=r"password_file.*cannot read"):
        zenoh_config(net)


def test_router_listens_on_loopback_by_default_and_warns_when_exposed() -> None:
    from bipedtele.tools.router import DEFAULT_LISTEN, exposure_warnings, router_endpoints

    assert router_endpoints(NetworkConfig(), None) == DEFAULT_LISTEN == ["tcp/127.0.0.1:7447"]
    assert router_endpoints(NetworkConfig(listen=["tls/0.0.0.0:7447"]), None) == ["tls/0.0.0.0:7447"]
    assert router_endpoints(NetworkConfig(), ["tcp/[::1]:7447"]) == ["tcp/[::1]:7447"]
    assert exposure_warnings(NetworkConfig(), ["tcp/127.0.0.1:7447", "tcp/localhost:1", "tcp/[::1]:7447"]) == []
    plain = exposure_warnings(NetworkConfig(), ["tcp/0.0.0.0:7447"])
    assert len(plain) == 1 and "without TLS or user/password" in plain[0]
    tls_only = exposure_warnings(NetworkConfig(), ["tls/10.0.0.2:7447"])
    assert len(tls_only) == 1 and "TLS" not in tls_only[0].split("without")[1].split("(")[0]
    assert exposure_warnings(NetworkConfig(credentials_file="c.txt"), ["tls/router.example.org:7447"]) == []


def test_split_endpoint() -> None:
    from bipedtele.link.linkcheck import split_endpoint

    assert split_endpoint("tls/router.example.org:7447") == ("tls", "router.example.org", 7447)
    assert split_endpoint("tcp/[::1]:7447#iface=lo") == ("tcp", "::1", 7447)
    assert split_endpoint("tcp/10.0.0.1:7447?prio=1") == ("tcp", "10.0.0.1", 7447)
    assert split_endpoint("unixsock-stream//tmp/sock") is None


@pytest.mark.timeout(30)
def test_check_endpoint_tls_to_a_plain_tcp_server() -> None:
    """A tls/ endpoint whose server does not speak TLS (a loopback socket answering bytes)."""
    import socket
    import threading

    from bipedtele.link.linkcheck import check_endpoint

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def answer() -> None:
        conn, _ = server.accept()
        with conn:
            conn.recv(4096)
            conn.sendall(b"HTTP/1.0 400 not a zenoh router\r\n\r\n" * 4)

    t = threading.Thread(target=answer, daemon=True)
    t.start()
    try:
        got = check_endpoint(f"tls/127.0.0.1:{port}", timeout_s=5.0)
        assert got.kind == "not_tls", got
        plain = check_endpoint(f"tcp/127.0.0.1:{port}", timeout_s=5.0)  # TCP alone is accepted
        assert plain.ok, plain
    finally:
        server.close()
        t.join(5)


# Lines as Zenoh 1.x prints them (ANSI colours included), captured from a router.
_ZENOH_LINES = [
    "\x1b[2m2026-11-23T14:32:03.151493Z\x1b[0m \x1b[34mDEBUG\x1b[0m \x1b[1macc-0\x1b[0m ThreadId(05) "
    "\x1b[2mzenoh_link_tcp::unicast\x1b[0m\x1b[2m:\x1b[0m Accepted TCP connection on 127.0.0.1:17449: 127.0.0.1:58934",
    "2026-11-23T14:32:03.151948Z DEBUG acc-0 ThreadId(05) zenoh_transport::unicast::establishment::accept: "
    "UsrPwd extension - Recv OpenSyn. Invalid password. at /root/.cargo/git/checkouts/zenoh/io/zenoh-transport/"
    "src/unicast/establishment/ext/auth/usrpwd.rs:424.",
    "2026-11-23T14:31:21.117919Z DEBUG acc-0 ThreadId(05) zenoh_link_tls::unicast: Accepted TLS connection on "
    "127.0.0.1:17448: 127.0.0.1:47258. Common Name: leader.",
    "2026-11-23T14:31:21.118479Z DEBUG acc-0 ThreadId(05) zenoh_transport::unicast::establishment::accept: "
    "UsrPwd extension - Recv OpenSyn. Invalid user. at /x/usrpwd.rs:418.",
    "2026-11-23T14:31:23.143371Z  WARN acc-0 ThreadId(05) zenoh_link_tls::unicast: peer sent no certificates. "
    "Hint: increase the system open file limit.",
    "2026-11-23T14:31:25.172513Z  WARN acc-0 ThreadId(05) zenoh_link_tls::unicast: invalid peer certificate: "
    "BadSignature. Hint: increase the system open file limit.",
    "2026-11-23T14:31:26.000000Z  INFO net-0 ThreadId(03) zenoh::net::routing::interceptor::access_control: "
    "5f3a9c did not match any configured ACL subject. Default permission `Deny` will be applied on all messages",
    "2026-11-23T14:31:27.000000Z  WARN net-0 ThreadId(03) zenoh::net::runtime::orchestrator: Unable to connect to tcp/x:1",
]


def test_zenoh_log_lines_become_refusal_records(caplog: pytest.LogCaptureFixture) -> None:
    import logging

    from bipedtele.link.zenohlog import ZenohLogBridge, parse_line

    assert parse_line("not a zenoh line") is None
    level, thread, target, msg = parse_line(_ZENOH_LINES[1]) or (0, "", "", "")
    assert (level, thread, target) == (logging.DEBUG, "acc-0", "zenoh_transport::unicast::establishment::accept")
    assert msg == "UsrPwd extension - Recv OpenSyn. Invalid password."
    bridge = ZenohLogBridge()
    with caplog.at_level(logging.INFO, logger="bipedtele.zenoh"):
        for line in _ZENOH_LINES:
            bridge.handle(line)
    got = [(r.levelno, r.getMessage()) for r in caplog.records]
    assert got[0] == (logging.INFO, "refused a session from 127.0.0.1:58934: user/password refused: wrong password")
    assert got[1] == (
        logging.INFO,
        "refused a session from 127.0.0.1:47258 (Common Name: leader): user/password refused: unknown user",
    )
    assert got[2][1].startswith("refused a TLS connection: no client certificate presented")
    assert got[3][1].startswith("refused a TLS connection: client certificate not signed by this router's CA")
    assert "Hint" not in got[2][1] + got[3][1]
    assert got[4] == (
        logging.INFO,
        "session 5f3a9c has no ACL role (not in publishers_allowed or followers_allowed): it may do nothing",
    )
    assert got[5] == (logging.WARNING, "zenoh::net::runtime::orchestrator: Unable to connect to tcp/x:1")
    assert len(got) == 6 and bridge.refusals == 4


def test_an_observer_receives_video_and_status_and_puts_nothing(tmp_path: Path) -> None:
    """Issue 23's observer role, rule by rule: bound to nao1, 'carol' receives nao1's video and
    status (and its presence), nothing of nao2, and may put or declare a subscriber on no
    command, feedback or clock key at all."""
    creds = tmp_path / "c.txt"
    creds.write_text("alice:a\nnao1:b\ncarol:c\neve:d\n")
    net = NetworkConfig(
        credentials_file=str(creds),
        publishers_allowed=["alice@nao1"],
        followers_allowed=["nao1@nao1"],
        observers_allowed=["carol@nao1", "eve"],
    )
    acl = access_control_json(net)
    assert acl is not None
    for k in ("video", "status"):
        assert _allowed(acl, "carol", "egress", "put", f"bipedtele/nao1/{k}")
        assert _allowed(acl, "carol", "ingress", "declare_subscriber", f"bipedtele/nao1/{k}")
        assert not _allowed(acl, "carol", "egress", "put", f"bipedtele/nao2/{k}")
        assert _allowed(acl, "eve", "egress", "put", f"bipedtele/nao2/{k}")  # a plain name: every robot
    for user in ("carol", "eve"):
        for k in ("cmd", "feedback", "clock", "video", "status"):
            for key in (f"bipedtele/nao1/{k}", "bipedtele/**", "**"):
                assert not _allowed(acl, user, "ingress", "put", key), (user, key)
        for k in ("cmd", "feedback", "clock"):
            assert not _allowed(acl, user, "egress", "put", f"bipedtele/nao1/{k}")
            assert not _allowed(acl, user, "ingress", "declare_subscriber", f"bipedtele/nao1/{k}")
    assert _allowed(acl, "carol", "egress", "liveliness_token", "bipedtele/nao1/presence/follower/abc")
    assert not _allowed(acl, "carol", "ingress", "liveliness_token", "bipedtele/nao1/presence/leader/abc")
    with pytest.raises(ValueError, match="'carol' is in publishers_allowed and observers_allowed"):
        NetworkConfig(publishers_allowed=["carol"], observers_allowed=["carol@nao1"])
    with pytest.raises(ConfigError, match="observers_allowed: set without"):
        access_control_json(NetworkConfig(credentials_file=str(creds), observers_allowed=["carol"]))
    with pytest.raises(ConfigError, match="observers_allowed = 'mallory': not a user"):
        access_control_json(
            NetworkConfig(credentials_file=str(creds), publishers_allowed=["alice"], observers_allowed=["mallory"])
        )
