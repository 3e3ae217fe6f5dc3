r"""End-to-end message sealing: AES-256-GCM with a key the router never sees.

Leader and follower share a 32-byte key (``[network] message_key_file``: 64 hex
characters, mode 0600). Every payload a process sends is sealed (encrypted and
authenticated, an AEAD) and framed as::

    MAGIC (4 bytes: c1 'B' 'T' 03) | key id (4) | nonce (12) | AES-256-GCM(key, nonce, body, aad) (len(body) + 16)

with ``aad = MAGIC | key id | key expression | 0x00``: the ciphertext hides the whole
encoded message (envelope ``sid``, ``seq``, ``t`` and every field: a router or an on-path
observer reads nothing of it), and its 16-byte tag covers it and the key expression it was
published on, so a message cannot be altered, forged, read, or moved to another key or
robot by anyone without the key (a compromised router included). The key id
(``HMAC-SHA256(key, "bipedtele key id")[:4]``) names the key, not the message: a receiver
tells a payload under another key (``bad_mac``: the two sides hold different keys; or, for
a session key, an earlier session's, :mod:`bipedtele.link.session`) from an altered one. Nonces
are 8 random bytes per sealer and a 4-byte counter (the random part is drawn again before
the counter wraps), so two processes sealing under one key never reuse a nonce. Replays
of whole valid messages are stopped by the receivers' sequence gate and send-time checks,
not by the seal.

The first byte 0xc1 is the one byte msgpack never uses, so a sealed payload is never
taken for a message by a receiver without the key (it is dropped as ``mac_unexpected``,
whose line says that the peer has a key and this side none) and an unsealed one is never
taken for a sealed one (``no_mac``: the peer has no key). The names (``MessageAuth``,
``sign``, ``verify``, the ``*_mac`` reasons) are those of the HMAC this replaced. See
docs/network.md.

Examples
--------
>>> auth = MessageAuth(bytes(32))
>>> sealed = auth.sign(b"\x80", "bipedtele/nao1/cmd")
>>> b"\x80" in sealed[4:], auth.verify(sealed, "bipedtele/nao1/cmd")
(False, b'\x80')
"""

from __future__ import annotations

import hashlib
import hmac
import itertools
import os
import stat
import threading
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Final

from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig
from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import AESGCM

__all__ = [
    "BAD_MAC_LINE",
    "KEY_BYTES",
    "KEY_REASONS",
    "MAC_MAGIC",
    "MAC_OVERHEAD",
    "NO_MAC_LINE",
    "SESSION_MAGIC",
    "UNEXPECTED_MAC_LINE",
    "WATCH_MAGIC",
    "MacError",
    "MessageAuth",
    "WatchAuth",
    "hkdf_sha256",
    "is_signed",
    "load_message_auth",
    "load_watch_auths",
    "read_key_file",
    "session_watch_key",
    "watch_key",
    "write_message_key",
]

MAC_MAGIC: Final = b"\xc1BT\x03"
#: Magic of a payload sealed with a session key (:mod:`bipedtele.link.session`), not the master key.
SESSION_MAGIC: Final = b"\xc1BT\x04"
#: Magic of a payload sealed with a session's watch key (:class:`WatchAuth`); its key id
#: field carries the sealing session's watch epoch.
WATCH_MAGIC: Final = b"\xc1BT\x05"
#: HKDF ``info`` of a session's watch key (:func:`session_watch_key`).
WATCH_SESSION_INFO: Final = b"bipedtele watch session v1"
#: Watch epochs a receiver keeps derived keys for (the ones that opened a payload).
WATCH_EPOCHS_KEPT: Final = 8
KID_BYTES: Final = 4
NONCE_BYTES: Final = 12
TAG_BYTES: Final = 16
HEADER_BYTES: Final = len(MAC_MAGIC) + KID_BYTES + NONCE_BYTES
MAC_OVERHEAD: Final = HEADER_BYTES + TAG_BYTES
KEY_BYTES: Final = 32
_COUNTER_MAX: Final = 1 << 32


#: What each side says when the two ends do not hold the same key (one line, both sides).
NO_MAC_LINE: Final = (
    "the peer's messages carry no MAC but this side has a message_key_file "
    "(set network.message_key_file on both sides, or forged messages)"
)
BAD_MAC_LINE: Final = "MAC mismatch: the two sides hold different message keys (or the messages were altered)"
UNEXPECTED_MAC_LINE: Final = (
    "the peer's messages carry a MAC but this side has no message_key_file (set network.message_key_file on both sides)"
)
#: Drop reasons that say the two ends' keys differ (or someone forges).
KEY_REASONS: Final = ("no_mac", "bad_mac", "mac_unexpected")


def is_signed(payload: bytes) -> bool:
    """Return whether ``payload`` is framed as a sealed message (a keyless receiver refuses it by name)."""
    return payload[:4] in (MAC_MAGIC, SESSION_MAGIC, WATCH_MAGIC) and len(payload) >= MAC_OVERHEAD


def hkdf_sha256(ikm: bytes, salt: bytes, info: bytes, length: int = 32) -> bytes:
    """Return ``length`` bytes of HKDF-SHA256 (RFC 5869): extract with ``salt``, expand with ``info``.

    Examples
    --------
    RFC 5869, test case 1:

    >>> hkdf_sha256(bytes.fromhex("0b" * 22), bytes.fromhex("000102030405060708090a0b0c"),
    ...             bytes.fromhex("f0f1f2f3f4f5f6f7f8f9"), 42).hex()[:16]
    '3cb25f25faacd57a'
    """
    if not 0 < length <= 255 * 32:
        raise ValueError(f"length = {length!r}: allowed: 1 .. {255 * 32} bytes")
    prk = hmac.new(salt or bytes(32), ikm, hashlib.sha256).digest()
    out, block, i = b"", b"", 1
    while len(out) < length:
        block = hmac.new(prk, block + info + bytes([i]), hashlib.sha256).digest()
        out += block
        i += 1
    return out[:length]


def key_id(key: bytes) -> bytes:
    """Return the 4-byte id of ``key`` (``HMAC-SHA256(key, "bipedtele key id")[:4]``): names it, hides it."""
    return hmac.new(bytes(key), b"bipedtele key id", hashlib.sha256).digest()[:KID_BYTES]


class MacError(ValueError):
    """A payload failed authentication.

    Attributes
    ----------
    reason : str
        ``no_mac`` (not a sealed payload) or ``bad_mac`` (sealed, but under another key,
        for another key expression, or altered).
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


class MessageAuth:
    """Seals and opens payloads with one shared key (AES-256-GCM).

    Parameters
    ----------
    key : bytes
        The 32-byte shared key.
    magic : bytes
        :data:`MAC_MAGIC` (the message key), :data:`SESSION_MAGIC` (a session key) or
        :data:`WATCH_MAGIC` (a session's watch key, :class:`WatchAuth`).
    kid : bytes, optional
        The 4-byte key id field; default :func:`key_id` of ``key`` (a :class:`WatchAuth`
        puts its watch epoch there).

    Notes
    -----
    Thread-safe (the nonce counter is taken under a lock). ``repr`` never shows the key.
    """

    __slots__ = ("_aead", "_counter", "_key", "_lock", "_prefix", "kid", "magic")

    def __init__(self, key: bytes, magic: bytes = MAC_MAGIC, kid: bytes | None = None) -> None:
        if not isinstance(key, bytes | bytearray) or len(key) != KEY_BYTES:
            raise ValueError(f"key: allowed: {KEY_BYTES} bytes")
        if magic not in (MAC_MAGIC, SESSION_MAGIC, WATCH_MAGIC):
            raise ValueError("magic: allowed: MAC_MAGIC, SESSION_MAGIC or WATCH_MAGIC")
        if kid is not None and len(kid) != KID_BYTES:
            raise ValueError(f"kid: allowed: {KID_BYTES} bytes")
        self.magic = magic
        self._key = bytes(key)
        self.kid = key_id(self._key) if kid is None else bytes(kid)
        self._aead = AESGCM(self._key)
        self._lock = threading.Lock()
        self._prefix = os.urandom(8)
        self._counter = itertools.count()

    def _nonce(self) -> bytes:
        with self._lock:
            n = next(self._counter)
            if n >= _COUNTER_MAX:  # never reached in practice (2^32 messages): a new random part
                self._prefix, self._counter, n = os.urandom(8), itertools.count(1), 0
            return self._prefix + n.to_bytes(4, "big")

    def _aad(self, topic: str) -> bytes:
        return self.magic + self.kid + topic.encode("utf-8") + b"\0"

    def sign(self, body: bytes, topic: str) -> bytes:
        """Return ``body`` sealed and framed (``MAGIC | key id | nonce | ciphertext | tag``) for ``topic``."""
        nonce = self._nonce()
        return self.magic + self.kid + nonce + self._aead.encrypt(nonce, body, self._aad(topic))

    def derive(self, salt: bytes, info: bytes) -> MessageAuth:
        """Return the session key ``HKDF-SHA256(this key, salt, info)`` (framed with :data:`SESSION_MAGIC`)."""
        return MessageAuth(hkdf_sha256(self._key, salt, info), SESSION_MAGIC)

    def holds(self, payload: bytes) -> bool:
        """Return whether ``payload`` is framed under this key (its magic and key id; not yet opened)."""
        return payload[:4] == self.magic and payload[4:8] == self.kid and len(payload) >= MAC_OVERHEAD

    def verify(self, payload: bytes, topic: str) -> bytes:
        """Return the body of a sealed payload received on ``topic``, if it opens.

        Raises
        ------
        MacError
            ``no_mac`` if the payload is not framed, ``bad_mac`` if it is under another
            key or does not open (altered, or sealed for another key expression).
        """
        if payload[:4] != self.magic or len(payload) < MAC_OVERHEAD:
            raise MacError("no_mac", f"{NO_MAC_LINE} (unsealed payload of {len(payload)} bytes on {topic})")
        if payload[4:8] != self.kid:
            raise MacError("bad_mac", f"{BAD_MAC_LINE} (sealed under another key on {topic})")
        return self.open_framed(payload, topic)

    def open_framed(self, payload: bytes, topic: str) -> bytes:
        """Open a payload already known to be framed under this key (:meth:`holds`).

        Raises
        ------
        MacError
            ``bad_mac``: it does not open (altered, or sealed for another key expression).
        """
        try:
            return self._aead.decrypt(payload[8:HEADER_BYTES], payload[HEADER_BYTES:], self._aad(topic))
        except InvalidTag:
            raise MacError("bad_mac", f"{BAD_MAC_LINE} (wrong tag on {topic})") from None

    def watch(self) -> WatchAuth:
        """Return a :class:`WatchAuth` of this key's watch key (:func:`watch_key`), with a fresh epoch."""
        return WatchAuth(watch_key(self._key))

    def __repr__(self) -> str:
        return "MessageAuth(<key hidden>)" if self.magic == MAC_MAGIC else "MessageAuth(<session key hidden>)"


def session_watch_key(watch: bytes, epoch: bytes) -> bytes:
    """Return a session's watch key: HKDF-SHA256 of the robot's watch key, salt = the session's epoch.

    ``info`` is :data:`WATCH_SESSION_INFO`. Each process that seals video or status draws a
    4-byte random *epoch* at start and seals under this key; the epoch travels in clear in
    the frame's key id field, so a holder of the robot's watch key (an observer) derives the
    key of any session it sees, and a holder of one session's key reads that session only.
    """
    if len(epoch) != KID_BYTES:
        raise ValueError(f"epoch: allowed: {KID_BYTES} bytes")
    return hkdf_sha256(bytes(watch), bytes(epoch), WATCH_SESSION_INFO)


class WatchAuth(MessageAuth):
    """Video and status: sealed under a watch key per session, opened under any (or one) session's.

    The key schedule (docs/network.md, Watch keys): the robot's watch key ``W`` is
    :func:`watch_key` of the message key; a process seals under
    :func:`session_watch_key` ``(W, epoch)`` with its own random ``epoch`` (framed with
    :data:`WATCH_MAGIC`, the epoch in the key id field). A receiver holding ``W`` derives
    the key of the epoch a frame names. ``pin`` narrows that: the leader pins its video to
    the epoch its bound follower announced in the session handshake (sealed under the
    message key), so an earlier session's frames, replayed, do not open there
    (``old_session``) whatever their age.

    Parameters
    ----------
    watch : bytes
        The robot's 32-byte watch key ``W``.
    epoch : bytes, optional
        This session's 4-byte epoch (default: 4 random bytes).
    pin : callable, optional
        ``pin()``: the one epoch (besides this session's own) whose frames open, or None
        for any epoch.
    """

    __slots__ = ("_epochs", "_pin", "_watch", "epoch")

    def __init__(self, watch: bytes, epoch: bytes | None = None, pin: Callable[[], bytes | None] | None = None) -> None:
        if not isinstance(watch, bytes | bytearray) or len(watch) != KEY_BYTES:
            raise ValueError(f"watch: allowed: {KEY_BYTES} bytes")
        epoch = os.urandom(KID_BYTES) if epoch is None else bytes(epoch)
        super().__init__(session_watch_key(watch, epoch), WATCH_MAGIC, kid=epoch)
        self._watch = bytes(watch)
        self.epoch = epoch
        self._pin = pin
        self._epochs: OrderedDict[bytes, MessageAuth] = OrderedDict()

    def pinned(self, pin: Callable[[], bytes | None]) -> WatchAuth:
        """Return an opener of the same session that takes, besides its own, only the epoch ``pin()`` names."""
        return WatchAuth(self._watch, self.epoch, pin)

    def _opener(self, epoch: bytes) -> MessageAuth:
        if epoch == self.epoch:
            return self
        with self._lock:
            got = self._epochs.get(epoch)
            if got is not None:
                self._epochs.move_to_end(epoch)
                return got
        return MessageAuth(session_watch_key(self._watch, epoch), WATCH_MAGIC, kid=epoch)

    def _kept(self, epoch: bytes, opener: MessageAuth) -> None:
        with self._lock:  # only epochs that opened a payload: forged ones never evict a live one
            self._epochs[epoch] = opener
            self._epochs.move_to_end(epoch)
            while len(self._epochs) > WATCH_EPOCHS_KEPT:
                self._epochs.popitem(last=False)

    def holds(self, payload: bytes) -> bool:
        """Return whether ``payload`` is framed under a session watch key (any epoch)."""
        return payload[:4] == WATCH_MAGIC and len(payload) >= MAC_OVERHEAD

    def verify(self, payload: bytes, topic: str) -> bytes:
        """Return the body of a payload sealed under a session's watch key, if it opens.

        Raises
        ------
        MacError
            ``no_mac`` (not sealed), ``bad_mac`` (sealed under another key kind, or it
            does not open: another robot's watch key, altered) or ``old_session``
            (pinned: another session's epoch than the pinned one).
        """
        if not self.holds(payload):
            if payload[:4] in (MAC_MAGIC, SESSION_MAGIC) and len(payload) >= MAC_OVERHEAD:
                raise MacError("bad_mac", f"{BAD_MAC_LINE} (sealed under a message or session key on {topic})")
            raise MacError("no_mac", f"{NO_MAC_LINE} (unsealed payload of {len(payload)} bytes on {topic})")
        epoch = payload[4:8]
        if self._pin is not None and epoch != self.epoch:
            want = self._pin()
            if want is not None and epoch != want:
                raise MacError(
                    "old_session",
                    f"{topic}: sealed under another session's watch key than the "
                    "bound peer's (an earlier session's frames replayed?)",
                )
        opener = self._opener(epoch)
        body = opener.open_framed(payload, topic)
        if opener is not self:
            self._kept(epoch, opener)
        return body

    def watch(self) -> WatchAuth:
        """Return a :class:`WatchAuth` of the same watch key with a fresh epoch."""
        return WatchAuth(self._watch)

    def __repr__(self) -> str:
        return f"WatchAuth(<key hidden>, epoch {self.epoch.hex()})"


def _key_error(field: str, path: str, why: str) -> ConfigError:
    return ConfigError(f"network.{field} = {path!r}: {why}")


def read_key_file(path: str, field: str = "message_key_file") -> bytes:
    """Return the 32-byte key of a key file (64 hex characters, mode 0600).

    Raises
    ------
    ConfigError
        One line naming ``network.<field>`` if the file cannot be read, is readable or
        writable by group or others (fix: ``chmod 600 FILE``), or does not hold exactly 64
        hex characters.
    """
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise _key_error(field, path, "not a regular file; allowed: a file of 64 hex characters")
        if st.st_mode & 0o077:
            raise _key_error(
                field,
                path,
                f"readable by group or others (mode {stat.S_IMODE(st.st_mode):04o}); fix: chmod 600 {path}",
            )
        text = Path(path).read_text(encoding="ascii").strip()
    except OSError as exc:
        raise _key_error(
            field, path, f"cannot read ({exc.strerror}); allowed: a readable file of 64 hex characters"
        ) from None
    except UnicodeDecodeError:
        text = ""
    try:
        if len(text) != 2 * KEY_BYTES:
            raise ValueError
        return bytes.fromhex(text)
    except ValueError:
        raise _key_error(
            field,
            path,
            f"not a key; allowed: exactly {2 * KEY_BYTES} hex characters (32 random bytes, e.g. "
            f"python3 -c 'import secrets; print(secrets.token_hex(32))' > {path}; chmod 600 {path})",
        ) from None


def load_message_auth(net: NetworkConfig) -> MessageAuth | None:
    """Return the :class:`MessageAuth` of ``[network] message_key_file``, or None when it is empty.

    Raises
    ------
    ConfigError
        As :func:`read_key_file`.
    """
    return MessageAuth(read_key_file(net.message_key_file)) if net.message_key_file else None


def watch_key(master: bytes) -> bytes:
    """Return a robot's watch key: HKDF-SHA256 of its message key (``info`` ``bipedtele watch v1``).

    Video and status are sealed under a key per session derived from the watch key
    (:func:`session_watch_key`, :class:`WatchAuth`; leader and follower derive the watch key
    from the message key). An observer holds only the watch key: it opens what it watches, and
    since HKDF is one-way it can neither complete a session handshake nor open or seal a
    command, feedback or clock message (the master key seals those, or session keys
    derived from it). The router's ACL keeps it from putting anything at all.
    """
    return hkdf_sha256(bytes(master), b"bipedtele", b"bipedtele watch v1")


def load_watch_auths(net: NetworkConfig, robots: list[str]) -> dict[str, MessageAuth]:
    """Return each robot's :class:`WatchAuth`, for an observer (``bipedtele status``): it opens every session's.

    From ``[network] watch_key_dir`` (files ``<robot_id>.watch``, as ``setup fleet`` writes
    them); a robot without a file there, or without ``watch_key_dir``, is left out.

    Raises
    ------
    ConfigError
        A watch key file that is not a key (as :func:`read_key_file`).
    """
    out: dict[str, MessageAuth] = {}
    if net.watch_key_dir:
        for robot in robots:
            path = Path(net.watch_key_dir) / f"{robot}.watch"
            if path.exists():
                out[robot] = WatchAuth(read_key_file(str(path), "watch_key_dir"))
    return out


def write_message_key(path: Path) -> None:
    """Write a new random key file (64 hex characters, mode 0600); never overwrites.

    Raises
    ------
    FileExistsError
        If ``path`` exists.
    """
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as f:
        f.write(os.urandom(KEY_BYTES).hex() + "\n")
