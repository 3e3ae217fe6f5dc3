"""Transport configuration: key expressions and the Zenoh config built from [network]."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from bipedtele.config import ConfigError
from bipedtele.sections import NetworkConfig
from bipedtele.transport import Keys, access_control_json, zenoh_config


def test_keys() -> None:
    k = Keys("nao1")
    assert k.cmd == "bipedtele/nao1/cmd"
    assert k.all() == {
        n: f"bipedtele/nao1/{n}" for n in ("cmd", "feedback", "video", "clock", "status")
    }
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


def test_access_control(tmp_path: Path) -> None:
    assert access_control_json(NetworkConfig()) is None
    creds = tmp_path / "c.txt"
    creds.write_text("# users\nleader:a\nfollower:b\nviewer:c\n")
    acl = access_control_json(NetworkConfig(credentials_file=str(creds), publishers_allowed=["leader"]))
    assert acl is not None and acl["enabled"] is True
    assert acl["subjects"] == [{"id": "not_leaders", "usernames": ["follower", "viewer"]}]
    assert acl["rules"][0]["key_exprs"] == ["bipedtele/*/cmd"] and acl["rules"][0]["flows"] == ["ingress"]
    with pytest.raises(ConfigError, match=r"needs network\.credentials_file"):
        access_control_json(NetworkConfig(publishers_allowed=["leader"]))
    with pytest.raises(ConfigError, match="'boss': not a user"):
        access_control_json(NetworkConfig(credentials_file=str(creds), publishers_allowed=["boss"]))
    creds.write_text("leader-without-password\n")
    with pytest.raises(ConfigError, match="line 1 is not user:password"):
        access_control_json(NetworkConfig(credentials_file=str(creds), publishers_allowed=["leader"]))
