"""Message sealing (AES-256-GCM): framing, tags over every byte, hidden fields, the key file's checks."""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import struct
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.auth import (
    MAC_MAGIC,
    MAC_OVERHEAD,
    MacError,
    MessageAuth,
    load_message_auth,
    write_message_key,
)
from bipedtele.link.messages import Command, MessageError, decode, encode
from cryptography.hazmat.primitives.ciphers.aead import AESGCM

KEY = bytes(range(32))
TOPIC = "bipedtele/nao1/cmd"


def _reason(fn: object) -> str:
    with pytest.raises(MacError) as info:
        fn()  # type: ignore[operator]
    return info.value.reason


def test_sign_verify_round_trip_and_framing() -> None:
    auth = MessageAuth(KEY)
    body = encode(Command(sid=7, seq=3, t=1.5e9, ref=[1.0, 2.0]))
    signed = auth.sign(body, TOPIC)
    assert signed.startswith(MAC_MAGIC) and len(signed) == len(body) + MAC_OVERHEAD
    assert auth.verify(signed, TOPIC) == body
    assert decode(auth.verify(signed, TOPIC)) == decode(body)
    # a receiver without the key never takes a signed payload for a message...
    with pytest.raises(MessageError) as info:
        decode(signed)
    assert info.value.reason == "not_msgpack"
    # ...and one with the key never takes an unsigned payload for a signed one
    assert _reason(lambda: auth.verify(body, TOPIC)) == "no_mac"
    assert _reason(lambda: auth.verify(b"", TOPIC)) == "no_mac"
    assert _reason(lambda: auth.verify(signed[: MAC_OVERHEAD - 1], TOPIC)) == "no_mac"


def test_tag_covers_every_byte_the_topic_and_the_key() -> None:
    auth = MessageAuth(KEY)
    body = encode(Command(sid=7, seq=3, t=1.5e9, ref=[1.0, 2.0], enable=True))
    signed = auth.sign(body, TOPIC)
    for i in range(len(MAC_MAGIC), len(signed)):  # every bit of the tag and of the body
        for bit in (0x01, 0x80):
            forged = bytearray(signed)
            forged[i] ^= bit
            assert _reason(lambda f=bytes(forged): auth.verify(f, TOPIC)) == "bad_mac", (i, bit)
    assert _reason(lambda: auth.verify(signed, "bipedtele/nao2/cmd")) == "bad_mac"  # another robot
    assert _reason(lambda: auth.verify(signed, "bipedtele/nao1/feedback")) == "bad_mac"  # another key
    other = MessageAuth(bytes(32))
    assert _reason(lambda: other.verify(signed, TOPIC)) == "bad_mac"
    assert _reason(lambda: auth.verify(other.sign(body, TOPIC), TOPIC)) == "bad_mac"
    # a payload with our magic but garbage after it is a wrong tag, not a crash
    assert _reason(lambda: auth.verify(MAC_MAGIC + os.urandom(100), TOPIC)) == "bad_mac"


def test_seal_is_aes_gcm_of_the_body_under_magic_key_id_and_topic() -> None:
    """The frame: MAGIC | key id | nonce | AES-256-GCM(key, nonce, body, MAGIC | key id | topic | 0)."""
    for key in (KEY, os.urandom(32)):
        auth = MessageAuth(key)
        kid = hmac.new(key, b"bipedtele key id", hashlib.sha256).digest()[:4]
        for body in (b"", b"\x80", os.urandom(317), os.urandom(70_000)):
            for topic in (TOPIC, "bipedtele/nao1/video", "bipedtele/\u00e9t\u00e9/status"):
                sealed = auth.sign(body, topic)
                assert sealed[:8] == MAC_MAGIC + kid and len(sealed) == len(body) + MAC_OVERHEAD
                aad = MAC_MAGIC + kid + topic.encode() + b"\0"
                assert AESGCM(key).decrypt(sealed[8:20], sealed[20:], aad) == body


def test_the_seal_hides_every_field_and_never_repeats_a_nonce() -> None:
    """Issue 32, item 3: what a router or an on-path observer sees holds no field of the message."""
    auth, twin = MessageAuth(KEY), MessageAuth(KEY)  # two processes under one key (leader and follower)
    cmd = Command(sid=0x5EC2E7, seq=4242, t=1.5e9 + 0.123, ref=[0.0525, -0.0317], x_m=[0.011, 0.022])
    body = encode(cmd)
    # every field of 4 bytes or more as msgpack writes it (shorter ones occur in any random bytes)
    fields = [struct.pack(">d", v) for v in (cmd.t, *cmd.ref, *cmd.x_m)] + [b"\xa3ref", struct.pack(">I", cmd.sid)]
    assert all(f in body for f in fields)
    nonces = set()
    for a in (auth, twin):
        for _ in range(500):
            sealed = a.sign(body, TOPIC)
            assert not any(f in sealed for f in fields), sealed.hex()
            nonces.add(sealed[8:20])
    assert len(nonces) == 1000
    with pytest.raises(MessageError):
        decode(sealed)
    assert decode(twin.verify(sealed, TOPIC)) == cmd


def test_key_never_shown_and_length_checked() -> None:
    assert KEY.hex() not in repr(MessageAuth(KEY))
    for bad in (b"", bytes(31), bytes(33)):
        with pytest.raises(ValueError, match="32 bytes"):
            MessageAuth(bad)


def _net(path: Path) -> NetworkConfig:
    return NetworkConfig(message_key_file=str(path))


def _one_line(exc: pytest.ExceptionInfo[ConfigError]) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_load_message_auth(tmp_path: Path) -> None:
    assert load_message_auth(NetworkConfig()) is None
    key_file = tmp_path / "message.key"
    write_message_key(key_file)
    assert stat.S_IMODE(key_file.stat().st_mode) == 0o600
    auth = load_message_auth(_net(key_file))
    assert isinstance(auth, MessageAuth)
    key = bytes.fromhex(key_file.read_text().strip())
    assert auth.verify(MessageAuth(key).sign(b"\x80", TOPIC), TOPIC) == b"\x80"
    with pytest.raises(FileExistsError):
        write_message_key(key_file)  # never overwrites
    assert bytes.fromhex(key_file.read_text().strip()) == key


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o644, 0o660, 0o666])
def test_key_file_readable_by_others_is_refused(tmp_path: Path, mode: int) -> None:
    key_file = tmp_path / "message.key"
    write_message_key(key_file)
    key_file.chmod(mode)
    with pytest.raises(ConfigError) as info:
        load_message_auth(_net(key_file))
    text = _one_line(info)
    assert "network.message_key_file" in text and f"chmod 600 {key_file}" in text


@pytest.mark.parametrize(
    "content",
    [b"", b"00" * 31 + b"\n", b"00" * 33, b"zz" * 32, bytes(range(256)), b"0x" + b"00" * 31],
)
def test_malformed_key_file_is_refused(tmp_path: Path, content: bytes) -> None:
    key_file = tmp_path / "message.key"
    key_file.write_bytes(content)
    key_file.chmod(0o600)
    with pytest.raises(ConfigError) as info:
        load_message_auth(_net(key_file))
    text = _one_line(info)
    assert "64 hex characters" in text and "chmod 600" in text


def test_missing_or_unreadable_key_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_message_auth(_net(tmp_path / "none.key"))
    assert "cannot read" in _one_line(info)
    with pytest.raises(ConfigError) as info:
        load_message_auth(_net(tmp_path))  # a folder
    assert "not a regular file" in _one_line(info)


def test_the_watch_key_verifies_video_and_status_and_signs_nothing_the_robot_obeys(tmp_path: Path) -> None:
    """An observer's key (issue 23): derived one-way from the message key, different from it;
    what it signs fails the master key's check, and a leader's and a follower's derivations agree."""
    from bipedtele.link.auth import WatchAuth, load_watch_auths, read_key_file, watch_key

    master = MessageAuth(KEY)
    wk = watch_key(KEY)
    assert len(wk) == 32 and wk != KEY and watch_key(wk) != KEY
    assert watch_key(bytes(KEY)) == wk  # deterministic: both ends derive the same
    body = encode(Command(sid=1, seq=1, t=1.0))
    watch = master.watch()
    assert WatchAuth(wk).verify(watch.sign(body, "bipedtele/nao1/status"), "bipedtele/nao1/status") == body
    assert _reason(lambda: master.verify(MessageAuth(wk).sign(body, TOPIC), TOPIC)) == "bad_mac"
    assert _reason(lambda: watch.verify(master.sign(body, TOPIC), TOPIC)) == "bad_mac"
    assert "hidden" in repr(watch)
    d = tmp_path / "w"
    d.mkdir()
    (d / "nao1.watch").write_text(wk.hex() + "\n")
    os.chmod(d / "nao1.watch", 0o600)
    auths = load_watch_auths(NetworkConfig(watch_key_dir=str(d)), ["nao1", "nao2"])
    assert sorted(auths) == ["nao1"] and read_key_file(str(d / "nao1.watch"), "watch_key_dir") == wk
    os.chmod(d / "nao1.watch", 0o644)
    with pytest.raises(ConfigError, match=r"network\.watch_key_dir = .*nao1\.watch.*chmod 600"):
        load_watch_auths(NetworkConfig(watch_key_dir=str(d)), ["nao1"])


def test_each_session_seals_video_under_a_watch_key_of_its_own() -> None:
    """Per-session watch keys (key schedule in docs/network.md): a session's frames name its
    epoch in clear and open under HKDF(watch key, epoch); the watch key's holder (an observer)
    opens every session's, one session's key opens that session's only, and a leader pinned
    to its bound follower's epoch refuses an earlier session's frames as ``old_session``."""
    from bipedtele.link.auth import WATCH_MAGIC, WatchAuth, session_watch_key, watch_key

    topic = "bipedtele/nao1/video"
    master = MessageAuth(KEY)
    earlier, now = master.watch(), master.watch()  # two follower processes
    assert earlier.epoch != now.epoch
    body = encode(Command(sid=1, seq=1, t=1.0))
    old_frame, new_frame = earlier.sign(body, topic), now.sign(body, topic)
    assert old_frame[:8] == WATCH_MAGIC + earlier.epoch and body not in old_frame
    observer = WatchAuth(watch_key(KEY))
    assert observer.verify(old_frame, topic) == body and observer.verify(new_frame, topic) == body
    one_session = MessageAuth(session_watch_key(watch_key(KEY), now.epoch), WATCH_MAGIC, kid=now.epoch)
    assert one_session.verify(new_frame, topic) == body
    assert _reason(lambda: one_session.verify(old_frame, topic)) == "bad_mac"
    leader = master.watch()
    bound: list[bytes | None] = [None]
    video = leader.pinned(lambda: bound[0])
    assert video.verify(old_frame, topic) == body  # no follower bound yet: the age bound and the gate decide
    bound[0] = now.epoch
    assert video.verify(new_frame, topic) == body
    assert _reason(lambda: video.verify(old_frame, topic)) == "old_session"
    assert video.verify(leader.sign(body, topic), topic) == body  # its own session's (status on a shared key)
    assert _reason(lambda: video.verify(master.sign(body, topic), topic)) == "bad_mac"  # another kind of key
    forged = bytearray(new_frame)
    forged[-1] ^= 1
    assert _reason(lambda: video.verify(bytes(forged), topic)) == "bad_mac"
    other_robot = WatchAuth(watch_key(bytes(32)), now.epoch)
    assert _reason(lambda: other_robot.verify(new_frame, topic)) == "bad_mac"
