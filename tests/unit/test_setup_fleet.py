"""``bipedtele setup fleet`` (issue 23): one router, robots and operators, each operator bound to its robots."""

from __future__ import annotations

import stat
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.config.sections import NetworkConfig, RobotConfig
from bipedtele.link.acl import access_control_json, login_file
from bipedtele.link.auth import load_message_auth
from bipedtele.link.zenohsession import zenoh_config
from bipedtele.tools.setup_fleet import parse_operator, write_fleet

pytestmark = pytest.mark.timeout(120)

NAME = "router.example.org"
ROBOTS = ["nao1", "nao2"]
OPERATORS = {"alice": ("nao1",), "bob": ("nao2", "nao1")}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("setup") / "fleet"
    write_fleet(out, NAME, ROBOTS, OPERATORS, 7451)
    return out


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}


def _key(path: Path) -> str:
    return path.read_text(encoding="utf-8").strip()


def test_each_host_folder_holds_its_own_files_only(fleet: Path) -> None:
    certs = {"certs/ca.pem"}
    assert {p.name for p in fleet.iterdir()} == {
        "router",
        "robot-nao1",
        "robot-nao2",
        "operator-alice",
        "operator-bob",
        "ca-private",
    }
    assert _files(fleet / "router") == certs | {
        "certs/router.pem",
        "certs/router.key",
        "secrets/router-credentials.txt",
        "bipedtele.toml",
    }
    for r in ROBOTS:
        assert _files(fleet / f"robot-{r}") == certs | {
            f"certs/{r}.pem",
            f"certs/{r}.key",
            f"secrets/{r}.pw",
            "secrets/message.key",
            "bipedtele.toml",
        }
    assert _files(fleet / "operator-alice") == certs | {
        "certs/alice.pem",
        "certs/alice.key",
        "secrets/alice.pw",
        "secrets/nao1.key",
        "nao1.toml",
    }
    assert _files(fleet / "operator-bob") == certs | {
        "certs/bob.pem",
        "certs/bob.key",
        "secrets/bob.pw",
        "secrets/nao1.key",
        "secrets/nao2.key",
        "nao1.toml",
        "nao2.toml",
    }
    assert _files(fleet / "ca-private") == {"ca.key", "ca.pem", "README.txt"}


def test_one_message_key_per_robot_held_by_its_operators_only(fleet: Path) -> None:
    k1, k2 = _key(fleet / "robot-nao1/secrets/message.key"), _key(fleet / "robot-nao2/secrets/message.key")
    assert k1 != k2 and len(k1) == len(k2) == 64
    assert _key(fleet / "operator-alice/secrets/nao1.key") == k1
    assert _key(fleet / "operator-bob/secrets/nao1.key") == k1
    assert _key(fleet / "operator-bob/secrets/nao2.key") == k2
    for secret in fleet.rglob("secrets/*"):
        assert stat.S_IMODE(secret.stat().st_mode) == 0o600, secret
    creds = (fleet / "router/secrets/router-credentials.txt").read_text().splitlines()
    users = dict(line.split(":", 1) for line in creds)
    assert sorted(users) == ["alice", "bob", "nao1", "nao2"]
    assert len(set(users.values())) == 4  # a password each
    for user in users:
        folder = next(fleet.glob(f"*-{user}"))
        assert _key(folder / "secrets" / f"{user}.pw") == users[user]


def test_router_acl_binds_each_operator_to_its_robots(fleet: Path) -> None:
    net = load_config(fleet / "router" / "bipedtele.toml").get(NetworkConfig)
    assert net.publishers_allowed == ["alice@nao1", "bob@nao2", "bob@nao1"]
    assert net.followers_allowed == ["nao1@nao1", "nao2@nao2"]
    acl = access_control_json(net)
    assert acl is not None and acl["default_permission"] == "deny"
    text = str(acl)
    assert "bipedtele/*/" not in text  # no router-wide role left
    subjects = {s["id"]: s for s in acl["subjects"]}
    policies = acl["policies"]
    rules = {r["id"]: r for r in acl["rules"]}

    def keys_of(user: str) -> set[str]:
        ids = {sid for sid, s in subjects.items() if user in s.get("usernames", [])}
        rule_ids = {rid for p in policies if set(p["subjects"]) & ids for rid in p["rules"]}
        return {k for rid in rule_ids for k in rules[rid]["key_exprs"]}

    assert {k.split("/")[1] for k in keys_of("alice")} == {"nao1"}
    assert {k.split("/")[1] for k in keys_of("bob")} == {"nao1", "nao2"}
    assert {k.split("/")[1] for k in keys_of("nao2")} == {"nao2"}


def test_each_profile_names_its_robot_user_and_key(fleet: Path, tmp_path: Path) -> None:
    cases = [
        ("robot-nao1/bipedtele.toml", "nao1", "nao1"),
        ("robot-nao2/bipedtele.toml", "nao2", "nao2"),
        ("operator-alice/nao1.toml", "nao1", "alice"),
        ("operator-bob/nao1.toml", "nao1", "bob"),
        ("operator-bob/nao2.toml", "nao2", "bob"),
    ]
    robot_key = {r: _key(fleet / f"robot-{r}/secrets/message.key") for r in ROBOTS}
    for profile, robot, user in cases:
        cfg = load_config(fleet / profile)  # from another working folder: paths are the profile's
        net = cfg.get(NetworkConfig)
        assert cfg.get(RobotConfig).id == robot and net.user == user, profile
        assert net.connect == [f"tls/{NAME}:7451"] and net.tls_mutual
        assert Path(net.message_key_file).read_text().strip() == robot_key[robot], profile
        assert load_message_auth(net) is not None
        assert tomllib.loads((fleet / profile).read_text())["network"]["password_file"] == f"secrets/{user}.pw"


def test_refuses_bad_assignments(tmp_path: Path) -> None:
    bad = [
        (["nao1"], {"alice": ("nao2",)}, r"\['nao2'\] not a --robot"),
        (["nao1"], {"nao1": ("nao1",)}, "not a robot id"),
        (["nao1"], {"leader": ("nao1",)}, "not a robot id nor one of"),
        (["nao1", "nao1"], {"alice": ("nao1",)}, "given twice"),
        (["nao 1"], {"alice": ("nao 1",)}, "--robot 'nao 1'"),
        ([], {"alice": ("nao1",)}, "--robot: none given"),
        (["nao1"], {}, "--operator: none given"),
        (["nao1"], {"alice": ("nao1", "nao1")}, "a robot named twice"),
    ]
    for robots, operators, match in bad:
        with pytest.raises(ConfigError, match=match):
            write_fleet(tmp_path / "n", NAME, robots, operators)
    assert not (tmp_path / "n").exists()
    for spec in ("alice", "alice=", "=nao1", "alice=,"):
        with pytest.raises(ConfigError, match="NAME=ROBOT"):
            parse_operator(spec)
    assert parse_operator("bob=nao2, nao1") == ("bob", ("nao2", "nao1"))


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=cwd,
    )


def test_command_prints_each_host_and_its_commands(tmp_path: Path) -> None:
    res = _cli(
        "setup",
        "fleet",
        "--router-name",
        NAME,
        "--robot",
        "nao1",
        "--robot",
        "nao2",
        "--operator",
        "alice=nao1",
        "--operator",
        "bob=nao2,nao1",
        "--out",
        "f",
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr
    for cmd in (
        "bipedtele router --config router/bipedtele.toml",
        "bipedtele follower --config robot-nao2/bipedtele.toml",
        "bipedtele leader --config operator-alice/nao1.toml",
        "bipedtele leader --config operator-bob/nao2.toml",
        "bipedtele leader --config operator-bob/nao1.toml",
    ):
        assert cmd in res.stdout, res.stdout
    for args, match in (
        (["--operator", "alice=nao3"], "not a --robot"),
        (["--operator", "alice=nao1", "--operator", "alice=nao1"], "given twice"),
        (["--operator", "alice"], "NAME=ROBOT"),
    ):
        bad = _cli("setup", "fleet", "--router-name", NAME, "--robot", "nao1", *args, "--out", "g", cwd=tmp_path)
        assert bad.returncode == 2 and bad.stdout == "", bad.stdout
        assert len(bad.stderr.strip().splitlines()) == 1 and match in bad.stderr, bad.stderr
    assert not (tmp_path / "g").exists()


def test_observers_get_watch_keys_only(tmp_path: Path) -> None:
    from bipedtele.link.auth import read_key_file, watch_key

    out = write_fleet(tmp_path / "f", NAME, ROBOTS, {"alice": ("nao1",)}, 7451, {"carol": ("nao1", "nao2")}).out
    folder = out / "observer-carol"
    assert _files(folder) == {
        "certs/ca.pem",
        "certs/carol.pem",
        "certs/carol.key",
        "secrets/carol.pw",
        "secrets/nao1.watch",
        "secrets/nao2.watch",
        "bipedtele.toml",
    }
    for r in ROBOTS:
        master = read_key_file(str(out / f"robot-{r}/secrets/message.key"))
        assert read_key_file(str(folder / f"secrets/{r}.watch"), "watch_key_dir") == watch_key(master)
    net = load_config(folder / "bipedtele.toml").get(NetworkConfig)
    assert net.user == "carol" and not net.message_key_file and Path(net.watch_key_dir) == folder / "secrets"
    router = load_config(out / "router/bipedtele.toml").get(NetworkConfig)
    assert router.observers_allowed == ["carol@nao1", "carol@nao2"]
    with pytest.raises(ConfigError, match="'alice' is an --operator and an --observer"):
        write_fleet(tmp_path / "g", NAME, ROBOTS, {"alice": ("nao1",)}, 7451, {"alice": ("nao2",)})
    with pytest.raises(ConfigError, match=r"--observer carol=nao9: \['nao9'\] not a --robot"):
        write_fleet(tmp_path / "g", NAME, ROBOTS, {"alice": ("nao1",)}, 7451, {"carol": ("nao9",)})


def test_sites_write_a_router_each_linked_to_the_sites_before(tmp_path: Path) -> None:
    from bipedtele.tools.setup_fleet import write_sites

    sites = {"lab1": "r1.example.org", "lab2": "r2.example.org", "lab3": "10.0.0.3"}
    out = write_sites(
        tmp_path / "s",
        sites,
        {"nao1": "lab1", "nao2": "lab2"},
        {"alice": ("lab1", ["nao1"]), "bob": ("lab3", ["nao2", "nao1"])},
        7460,
        {"carol": ("lab2", ["nao1"])},
    ).out
    nets = {s: load_config(out / f"router-{s}" / "bipedtele.toml").get(NetworkConfig) for s in sites}
    assert nets["lab1"].connect == [] and not nets["lab1"].router_user
    assert nets["lab2"].connect == ["tls/r1.example.org:7460"] and nets["lab2"].router_user == "site-lab2"
    assert nets["lab3"].connect == ["tls/r1.example.org:7460", "tls/r2.example.org:7460"]
    assert nets["lab1"].routers_allowed == ["router-lab2", "router-lab3"]
    assert nets["lab1"].publishers_allowed == ["alice@nao1"] and nets["lab1"].followers_allowed == ["nao1@nao1"]
    assert nets["lab3"].publishers_allowed == ["bob@nao2", "bob@nao1"] and nets["lab3"].followers_allowed == []
    assert nets["lab2"].observers_allowed == ["carol@nao1"]
    users = {s: [ln.split(":")[0] for ln in Path(nets[s].credentials_file).read_text().splitlines()] for s in sites}
    assert users == {
        "lab1": ["nao1", "alice", "site-lab2", "site-lab3"],
        "lab2": ["nao2", "carol", "site-lab3"],
        "lab3": ["bob"],
    }
    lab1_creds = dict(ln.split(":", 1) for ln in Path(nets["lab1"].credentials_file).read_text().splitlines())
    assert Path(nets["lab2"].router_password_file).read_text().strip() == lab1_creds["site-lab2"]
    for s in sites:
        pem = out / f"router-{s}" / "certs" / f"router-{s}.pem"
        text = subprocess.run(
            ["openssl", "x509", "-in", str(pem), "-noout", "-subject", "-ext", "subjectAltName"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        assert f"CN = router-{s}" in text and sites[s] in text, text
    bob = load_config(out / "operator-bob" / "nao2.toml").get(NetworkConfig)
    assert bob.connect == ["tls/10.0.0.3:7460"]  # his own site's router, whatever the robot's site
    acl = access_control_json(nets["lab2"])
    assert acl is not None and {"id": "routers", "cert_common_names": ["router-lab1", "router-lab3"]} in acl["subjects"]


def test_sites_refusals(tmp_path: Path) -> None:
    from bipedtele.tools.setup_fleet import write_sites

    ok_sites = {"lab1": "r1.example.org", "lab2": "r2.example.org"}
    bad = [
        ({"lab1": "r1.example.org"}, {"nao1": "lab1"}, {"a": ("lab1", ["nao1"])}, "2 to 16 sites"),
        ({"la b": "r", "lab2": "r2"}, {"nao1": "lab2"}, {"a": ("lab2", ["nao1"])}, "--site 'la b'"),
        (ok_sites, {"nao1": "lab9"}, {"a": ("lab1", ["nao1"])}, r"--robot nao1@lab9: no such --site"),
        (ok_sites, {"nao1": "lab1"}, {"a": ("lab7", ["nao1"])}, r"--operator a@lab7: no such --site"),
        (ok_sites, {"nao1": "lab1"}, {"site-lab1": ("lab1", ["nao1"])}, "a name of a site's router login"),
    ]
    for sites, robots, ops, match in bad:
        with pytest.raises(ConfigError, match=match):
            write_sites(tmp_path / "n", sites, robots, ops)
    assert not (tmp_path / "n").exists()
    res = _cli(
        "setup",
        "sites",
        "--site",
        "lab1=r1.example.org",
        "--site",
        "lab2=r2.example.org",
        "--robot",
        "nao1",
        "--operator",
        "alice@lab1=nao1",
        "--out",
        "x",
        cwd=tmp_path,
    )
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "NAME@SITE" in res.stderr
    with pytest.raises(ConfigError, match="router_user/router_password_file: allowed: both"):
        zenoh_config(NetworkConfig(mode="router", router_user="site-lab2"))


def _subject(pem: Path) -> str:
    out = subprocess.run(
        ["openssl", "x509", "-in", str(pem), "-noout", "-subject", "-fingerprint"],
        capture_output=True,
        text=True,
        check=True,
        timeout=30,
    ).stdout
    return out.strip()


def test_a_certificate_per_person_and_one_revoked_alone(tmp_path: Path) -> None:
    """People, not roles: alice and dave get certificates of their own; dave's revocation leaves alice hers."""
    out = tmp_path / "fleet"
    write_fleet(out, NAME, ["nao1"], {"alice": ("nao1",), "dave": ("nao1",)}, 7451)
    alice, dave = _subject(out / "operator-alice/certs/alice.pem"), _subject(out / "operator-dave/certs/dave.pem")
    assert "CN = alice" in alice and "CN = dave" in dave and alice.splitlines()[1] != dave.splitlines()[1]
    assert "CN = nao1" in _subject(out / "robot-nao1/certs/nao1.pem")
    router = load_config(out / "router" / "bipedtele.toml").get(NetworkConfig)
    assert router.tls_user_certs and router.revoked == []
    for who in ("alice", "dave"):
        net = load_config(out / f"operator-{who}" / "nao1.toml").get(NetworkConfig)
        assert Path(net.tls_cert).name == f"{who}.pem" and net.user == who

    # each role asks for the certificate named after its user: dave's with alice's password matches nothing
    acl = access_control_json(router)
    assert acl is not None
    subjects = [s for s in acl["subjects"] if "usernames" in s]
    assert all(s["usernames"] == s["cert_common_names"] for s in subjects), subjects
    revoked = NetworkConfig(**{**vars(router), "revoked": ["dave"]})
    acl = access_control_json(revoked)
    assert acl is not None
    named = {n for s in acl["subjects"] for n in s.get("usernames", []) + s.get("cert_common_names", [])}
    assert "dave" not in named and "alice" in named
    logins = Path(login_file(revoked)).read_text().splitlines()
    assert [ln.split(":")[0] for ln in logins] == ["nao1", "alice"]
