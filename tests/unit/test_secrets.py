"""Certificates and keys made by the scripts: from any working folder, the CA's key apart,
IP names, keys mode 0600, nothing overwritten; git ignores where secrets are written."""

from __future__ import annotations

import stat
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]
MAKE_CERTS = ROOT / "scripts" / "make-certs.sh"
MAKE_KEY = ROOT / "scripts" / "make-message-key.sh"


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=60)


def _openssl(*args: str) -> str:
    return subprocess.run(["openssl", *args], capture_output=True, text=True, check=True, timeout=30).stdout


def test_make_certs_from_another_folder_keeps_the_ca_key_off_the_copied_files(tmp_path: Path) -> None:
    """Issue 10 item 11: ca.key was written beside the files one copies to the hosts."""
    res = _run([str(MAKE_CERTS), "certs", "router.example.org", "192.0.2.7"], cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    out = tmp_path / "certs"
    hosts_files = sorted(p.name for p in out.iterdir() if p.is_file())
    assert hosts_files == [
        "ca.pem",
        "follower.key",
        "follower.pem",
        "leader.key",
        "leader.pem",
        "router.key",
        "router.pem",
    ]
    ca_key = out / "ca-private" / "ca.key"
    assert ca_key.is_file() and _mode(ca_key) == 0o600 and _mode(ca_key.parent) == 0o700
    assert "keep it off the hosts" in res.stdout
    for name in ("router", "leader", "follower"):
        assert _mode(out / f"{name}.key") == 0o600
        assert _openssl("verify", "-CAfile", str(out / "ca.pem"), str(out / f"{name}.pem")).strip().endswith("OK")
    san = _openssl("x509", "-in", str(out / "router.pem"), "-noout", "-ext", "subjectAltName")
    assert "DNS:router.example.org" in san and "IP Address:192.0.2.7" in san
    again = _run([str(MAKE_CERTS), "certs", "other.example.org"], cwd=tmp_path)
    assert again.returncode == 2 and "exists" in again.stderr  # nothing overwritten
    assert "DNS:router.example.org" in _openssl(
        "x509", "-in", str(out / "router.pem"), "-noout", "-ext", "subjectAltName"
    )


def test_make_certs_usage_names_ips_and_rejects_bad_names(tmp_path: Path) -> None:
    res = _run([str(MAKE_CERTS)], cwd=tmp_path)
    assert res.returncode == 2 and "IP addresses" in res.stderr
    res = _run([str(MAKE_CERTS), "c", "bad name"], cwd=tmp_path)
    assert res.returncode == 2 and "allowed: a DNS name" in res.stderr


def test_script_and_setup_command_make_the_same_kind_of_certificates(tmp_path: Path) -> None:
    from bipedtele.tools.setup import make_certs

    _run([str(MAKE_CERTS), "sh", "r.example.org"], cwd=tmp_path)
    make_certs(tmp_path / "py", ["r.example.org"])

    def shape(folder: Path, name: str) -> list[str]:
        text = _openssl("x509", "-in", str(folder / f"{name}.pem"), "-noout", "-text")
        keep = (
            "Public Key Algorithm",
            "ASN1 OID",
            "CA:TRUE",
            "CA:FALSE",
            "Digital Signature",
            "TLS Web",
            "DNS:",
            "Issuer:",
            "Subject:",
        )
        # (not any line starting "CA:": a key identifier's hex is such a line 1 time in 256)
        return [line.strip() for line in text.splitlines() if line.strip().startswith(keep)]

    for name in ("ca", "router", "leader", "follower"):
        assert shape(tmp_path / "sh", name) == shape(tmp_path / "py", name), name


@pytest.mark.parametrize("how", ["script", "command"])
def test_message_key_is_64_hex_mode_0600_never_overwritten(tmp_path: Path, how: str) -> None:
    key = tmp_path / "secrets" / "message.key"
    cmd = (
        [str(MAKE_KEY), str(key)]
        if how == "script"
        else [sys.executable, "-m", "bipedtele.cli", "setup", "message-key", str(key)]
    )
    if how == "command":
        key.parent.mkdir()
    res = _run(cmd, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    text = key.read_text()
    assert text.endswith("\n") and len(text.strip()) == 64 and len(bytes.fromhex(text.strip())) == 32
    assert _mode(key) == 0o600
    again = _run(cmd, cwd=tmp_path)
    assert again.returncode == 2 and "exists" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    assert key.read_text() == text
    from bipedtele.config.sections import NetworkConfig
    from bipedtele.link.auth import load_message_auth

    assert load_message_auth(NetworkConfig(message_key_file=str(key))) is not None


def test_git_ignores_certificates_secrets_and_setup_output() -> None:
    """Issue 10 item 11: .gitignore did not cover certs/ or secrets/."""
    paths = ["certs/ca.pem", "certs/ca-private/ca.key", "secrets/leader.pw", "two-hosts/robot/secrets/message.key"]
    res = subprocess.run(["git", "check-ignore", *paths], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert sorted(res.stdout.split()) == sorted(paths)
