"""Wire messages between leader and follower (msgpack, schema-versioned).

Every message is a msgpack map with an envelope::

    {"v": SCHEMA_VERSION, "k": kind, "sid": session id, "seq": n, "t": send time [s], ...fields}

``sid`` is a random 32-bit id chosen once per process start: a receiver that sees a new
``sid`` knows the peer restarted and resets its sequence gate (see
:class:`bipedtele.gate.SequenceGate`). ``t`` is the sender's clock (``time.time()`` on
the sender) at the moment of sending.

Speeds are in the paper's units: forward in cm/s, turn in deg/s. Positions in metres,
angles in radians, times in seconds.

:func:`decode` validates types, finiteness and ranges; anything else raises
:class:`MessageError`, whose ``reason`` names the kind of problem for counters.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any, ClassVar, Final, get_type_hints

import msgpack

__all__ = [
    "MESSAGE_TYPES",
    "SCHEMA_VERSION",
    "ClockPing",
    "ClockPong",
    "Command",
    "Feedback",
    "Message",
    "MessageError",
    "Status",
    "VideoFrame",
    "decode",
    "encode",
    "new_session_id",
]

SCHEMA_VERSION: Final = 1
MAX_MESSAGE_BYTES: Final = 4 * 1024 * 1024
MAX_JPEG_BYTES: Final = 2 * 1024 * 1024
MAX_SEQ: Final = 2**63 - 1
MAX_TEXT: Final = 1024

# Sanity bounds on wire values (far beyond anything physical; they reject garbage).
MAX_SPEED: Final = 1000.0  # cm/s or deg/s
MAX_POS: Final = 1.0e6  # m
MAX_FORCE: Final = 1.0e3  # N
MAX_PARAM: Final = 1.0e6
MAX_DELAY_S: Final = 60.0
MIN_TIME: Final = 0.0
MAX_TIME: Final = 1.0e11  # s (about year 5138)


class MessageError(ValueError):
    """A received payload is not a valid message.

    Attributes
    ----------
    reason : str
        Short category for counters: ``too_large``, ``not_msgpack``, ``not_a_map``,
        ``bad_version``, ``unknown_kind``, ``bad_field``, ``missing_field``.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def new_session_id() -> int:
    """A random non-zero 32-bit session id for this process."""
    return int.from_bytes(os.urandom(4), "little") or 1


# --------------------------------------------------------------------------- field specs


@dataclass(frozen=True)
class _Num:
    lo: float
    hi: float
    n: int = 0  # 0: scalar; otherwise a list of exactly n numbers


@dataclass(frozen=True)
class _Int:
    lo: int
    hi: int


@dataclass(frozen=True)
class _Str:
    choices: tuple[str, ...] = ()
    max_len: int = MAX_TEXT


@dataclass(frozen=True)
class _Bytes:
    max_len: int


@dataclass(frozen=True)
class _Counters:
    max_items: int = 64


def _spec(spec: object, default: Any = dataclasses.MISSING, **kw: Any) -> Any:
    if "default_factory" in kw:
        return field(default_factory=kw["default_factory"], metadata={"spec": spec})
    return field(default=default, metadata={"spec": spec})


def _number(spec: _Num, name: str, value: Any) -> float:
    """Validate one number against ``spec``'s range (the hot path of decoding)."""
    if value.__class__ is float:
        x = value
    elif isinstance(value, int | float) and not isinstance(value, bool):
        x = float(value)
    else:
        raise MessageError("bad_field", f"{name}: expected a number")
    if not spec.lo <= x <= spec.hi:  # also false for NaN
        if not math.isfinite(x):
            raise MessageError("bad_field", f"{name}: not finite")
        raise MessageError("bad_field", f"{name}: out of range [{spec.lo}, {spec.hi}]")
    return x


def _check(spec: object, name: str, value: Any) -> Any:
    """Validate one field; return it in canonical Python form."""

    def bad(why: str) -> MessageError:
        return MessageError("bad_field", f"{name}: {why}")

    if isinstance(spec, _Num):
        if spec.n:
            if not isinstance(value, list | tuple) or len(value) != spec.n:
                raise bad(f"expected a list of {spec.n} numbers")
            return [_number(spec, f"{name}[{i}]", v) for i, v in enumerate(value)]
        return _number(spec, name, value)
    if isinstance(spec, _Int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("expected an integer")
        if not spec.lo <= value <= spec.hi:
            raise bad(f"out of range [{spec.lo}, {spec.hi}]")
        return value
    if isinstance(spec, _Str):
        if not isinstance(value, str):
            raise bad("expected a string")
        if len(value) > spec.max_len:
            raise bad("too long")
        if spec.choices and value not in spec.choices:
            raise bad(f"expected one of {', '.join(spec.choices)}")
        return value
    if isinstance(spec, _Bytes):
        if not isinstance(value, bytes | bytearray | memoryview):
            raise bad("expected bytes")
        if len(value) > spec.max_len:
            raise bad("too long")
        return bytes(value)
    if isinstance(spec, _Counters):
        if not isinstance(value, dict) or len(value) > spec.max_items:
            raise bad("expected a small map of counters")
        out = {}
        for k, v in value.items():
            if not isinstance(k, str) or len(k) > 64:
                raise bad("counter names must be short strings")
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_SEQ:
                raise bad("counter values must be non-negative integers")
            out[k] = v
        return out
    if spec is bool:
        if not isinstance(value, bool):
            raise bad("expected true or false")
        return value
    raise TypeError(f"unknown spec {spec!r}")  # pragma: no cover - programming error


_SPEED2 = _Num(-MAX_SPEED, MAX_SPEED, 2)
_PAIR_POS = _Num(-MAX_POS, MAX_POS, 2)
_PARAM = _Num(-MAX_PARAM, MAX_PARAM)
_DELAY = _Num(0.0, MAX_DELAY_S)
_TIME = _Num(MIN_TIME, MAX_TIME)

FOLLOWER_STATES: Final = ("starting", "standing", "walking", "stopping", "fallen", "error")
LEADER_STATES: Final = ("starting", "running", "feedback_stale", "stopped", "error")


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class Message:
    """Envelope shared by every message."""

    KIND: ClassVar[str] = ""
    sid: int = _spec(_Int(0, 2**32 - 1), 0)
    seq: int = _spec(_Int(0, MAX_SEQ), 0)
    t: float = _spec(_TIME, 0.0)


@dataclass(frozen=True)
class Command(Message):
    """Leader -> follower: the reference ``k_g x_m`` and the leader's state.

    Attributes
    ----------
    ref : [float, float]
        Reference forward speed [cm/s] and turn speed [deg/s], ``k_g x_m`` (eq. 7, 11).
    x_m, dx_m : [float, float]
        Handle position [m] and velocity [m/s] on the two axes.
    h2_s : float
        Leader's 1 s moving-average estimate of the backward delay h2 [s].
    alpha_m : [float, float]
        Leader damping in force [N s/m] (eq. 31, 40).
    enable : bool
        False asks the follower to stop and stand (operator released the device).
    """

    KIND: ClassVar[str] = "cmd"
    ref: list[float] = _spec(_SPEED2, default_factory=lambda: [0.0, 0.0])
    x_m: list[float] = _spec(_PAIR_POS, default_factory=lambda: [0.0, 0.0])
    dx_m: list[float] = _spec(_PAIR_POS, default_factory=lambda: [0.0, 0.0])
    h2_s: float = _spec(_DELAY, 0.0)
    alpha_m: list[float] = _spec(_Num(0.0, MAX_PARAM, 2), default_factory=lambda: [0.0, 0.0])
    enable: bool = _spec(bool, True)


@dataclass(frozen=True)
class Feedback(Message):
    """Follower -> leader: what the operator feels and sees in the plots.

    Attributes
    ----------
    z_e : [float, float]
        Equivalent follower speeds [cm/s, deg/s] (eq. 29): what the leader's force uses.
    z_r : [float, float]
        Observer estimate of the real speeds [cm/s, deg/s] (eq. 12).
    eta : [float, float]
        Measured speeds: v_hip [cm/s] (eq. 8) and turn rate [deg/s].
    ref : [float, float]
        Reference the follower is applying now (the delayed, clamped command).
    pose : [float, float, float]
        x [m], y [m], yaw [rad] of the torso in the world (or odometry) frame.
    sonar : [float, float]
        Left and right sonar ranges [m]; the sensor's maximum when nothing is seen.
    f_v : [float, float]
        Fictitious force: tangential and normal components (Sec. 3.2.1).
    h1_s : float
        Follower's 1 s moving-average estimate of the forward delay h1 [s].
    s_e, s_r : [float, float]
        Equivalent and real damping in use.
    T : float
        Walking cycle time in use [s].
    eps : float
        Joint-servo gain in use [s].
    state : str
        One of ``FOLLOWER_STATES``.
    cmd_seq : int
        Sequence number of the last command applied.
    """

    KIND: ClassVar[str] = "fb"
    z_e: list[float] = _spec(_SPEED2, default_factory=lambda: [0.0, 0.0])
    z_r: list[float] = _spec(_SPEED2, default_factory=lambda: [0.0, 0.0])
    eta: list[float] = _spec(_SPEED2, default_factory=lambda: [0.0, 0.0])
    ref: list[float] = _spec(_SPEED2, default_factory=lambda: [0.0, 0.0])
    pose: list[float] = _spec(_Num(-MAX_POS, MAX_POS, 3), default_factory=lambda: [0.0, 0.0, 0.0])
    sonar: list[float] = _spec(_Num(0.0, 100.0, 2), default_factory=lambda: [0.0, 0.0])
    f_v: list[float] = _spec(_Num(-MAX_FORCE, MAX_FORCE, 2), default_factory=lambda: [0.0, 0.0])
    h1_s: float = _spec(_DELAY, 0.0)
    s_e: list[float] = _spec(_Num(0.0, MAX_PARAM, 2), default_factory=lambda: [0.0, 0.0])
    s_r: list[float] = _spec(_Num(0.0, MAX_PARAM, 2), default_factory=lambda: [0.0, 0.0])
    T: float = _spec(_Num(0.0, 100.0), 0.0)
    eps: float = _spec(_Num(0.0, 100.0), 0.0)
    state: str = _spec(_Str(FOLLOWER_STATES), "starting")
    cmd_seq: int = _spec(_Int(0, MAX_SEQ), 0)


@dataclass(frozen=True)
class VideoFrame(Message):
    """Follower -> leader: one JPEG image (latest only; receivers may drop any frame).

    Attributes
    ----------
    camera : str
        ``head`` (NAO top camera) or ``scene`` (fixed lab camera).
    width, height : int
        Image size [px].
    t_capture : float
        When the image was rendered/captured (sender's clock) [s].
    jpeg : bytes
        The JPEG file.
    """

    KIND: ClassVar[str] = "video"
    camera: str = _spec(_Str(("head", "scene")), "head")
    width: int = _spec(_Int(1, 4096), 320)
    height: int = _spec(_Int(1, 4096), 240)
    t_capture: float = _spec(_TIME, 0.0)
    jpeg: bytes = _spec(_Bytes(MAX_JPEG_BYTES), b"")


@dataclass(frozen=True)
class ClockPing(Message):
    """NTP-style ping: ``t`` is t1, the requester's send time."""

    KIND: ClassVar[str] = "ping"


@dataclass(frozen=True)
class ClockPong(Message):
    """Answer to a :class:`ClockPing`.

    Attributes
    ----------
    ping_sid, ping_seq : int
        Which ping this answers.
    t1 : float
        The ping's send time (requester's clock) [s].
    t2 : float
        When the ping arrived (responder's clock) [s]. The envelope's ``t`` is t3.
    """

    KIND: ClassVar[str] = "pong"
    ping_sid: int = _spec(_Int(0, 2**32 - 1), 0)
    ping_seq: int = _spec(_Int(0, MAX_SEQ), 0)
    t1: float = _spec(_TIME, 0.0)
    t2: float = _spec(_TIME, 0.0)


@dataclass(frozen=True)
class Status(Message):
    """Either side: coarse state and counters, about 2 Hz.

    Attributes
    ----------
    role : str
        ``leader`` or ``follower``.
    state : str
        One of ``FOLLOWER_STATES`` or ``LEADER_STATES``.
    counters : dict[str, int]
        Dropped messages by reason, falls, watchdog stops, ...
    text : str
        Human-readable detail (last error, clock-mode note).
    """

    KIND: ClassVar[str] = "status"
    role: str = _spec(_Str(("leader", "follower")), "follower")
    state: str = _spec(_Str(FOLLOWER_STATES + LEADER_STATES), "starting")
    counters: dict[str, int] = _spec(_Counters(), default_factory=dict)
    text: str = _spec(_Str(max_len=MAX_TEXT), "")


MESSAGE_TYPES: Final[dict[str, type[Message]]] = {
    cls.KIND: cls for cls in (Command, Feedback, VideoFrame, ClockPing, ClockPong, Status)
}

_FIELDS: dict[type[Message], list[tuple[str, object]]] = {
    cls: [(f.name, f.metadata["spec"]) for f in dataclasses.fields(cls)]
    for cls in MESSAGE_TYPES.values()
}
# Ensure every field has a spec (a programming error otherwise).
for _cls in MESSAGE_TYPES.values():
    get_type_hints(_cls)

# Decoding plan per class: (name, spec, fast kind, lo, hi, n). The fast kinds accept the
# common, valid case inline (a float in range, a list of n floats in range, an int in
# range); anything else goes through :func:`_check`, which gives the same result or the
# same error. Decoding runs once per message from cold caches, where each Python call
# and f-string costs several times its tight-loop time, so the happy path makes none.
_FLOAT, _FLOATS, _INTEGER, _OTHER = 0, 1, 2, 3


def _plan(spec: object) -> tuple[int, Any, Any, int]:
    if isinstance(spec, _Num):
        return (_FLOATS if spec.n else _FLOAT), spec.lo, spec.hi, spec.n
    if isinstance(spec, _Int):
        return _INTEGER, spec.lo, spec.hi, 0
    return _OTHER, None, None, 0


_PLANS: dict[type[Message], list[tuple[str, object, int, Any, Any, int]]] = {
    cls: [(name, spec, *_plan(spec)) for name, spec in fields] for cls, fields in _FIELDS.items()
}
# Classes built without running __init__ (every field is validated and present, and none
# has a __post_init__): frozen dataclasses only guard __setattr__, not __dict__.
_DIRECT = {cls for cls in MESSAGE_TYPES.values() if not hasattr(cls, "__post_init__")}


# --------------------------------------------------------------------------- codec


def encode(msg: Message) -> bytes:
    """Serialise a message to msgpack bytes (envelope plus fields)."""
    data: dict[str, Any] = {"v": SCHEMA_VERSION, "k": msg.KIND}
    for name, _ in _FIELDS[type(msg)]:
        data[name] = getattr(msg, name)
    return msgpack.packb(data, use_bin_type=True)


def decode(payload: bytes | bytearray | memoryview, expect: type[Message] | None = None) -> Message:
    """Parse and validate a payload.

    Parameters
    ----------
    payload : bytes
        What came off the network.
    expect : type, optional
        If given, any other message kind is rejected (``unknown_kind``).

    Raises
    ------
    MessageError
        For anything that is not a valid message of the expected kind. Nothing else
        is raised, whatever the bytes.
    """
    if len(payload) > MAX_MESSAGE_BYTES:
        raise MessageError("too_large", f"{len(payload)} bytes")
    try:
        data = msgpack.unpackb(
            payload if payload.__class__ is bytes else bytes(payload),
            raw=False,
            strict_map_key=True,
            max_str_len=MAX_TEXT * 4,
            max_bin_len=MAX_JPEG_BYTES,
            max_array_len=64,
            max_map_len=128,
            max_ext_len=0,
        )
    except Exception as exc:  # msgpack raises many types (ValueError, ExtraData, ...)
        raise MessageError("not_msgpack", type(exc).__name__) from None
    if not isinstance(data, dict):
        raise MessageError("not_a_map", type(data).__name__)
    if data.get("v") != SCHEMA_VERSION:
        raise MessageError("bad_version", f"v={data.get('v')!r}, expected {SCHEMA_VERSION}")
    kind = data.get("k")
    cls = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None or (expect is not None and cls is not expect):
        raise MessageError("unknown_kind", f"k={kind!r}")
    kwargs: dict[str, Any] = {}
    for name, spec, fast, lo, hi, n in _PLANS[cls]:
        if name not in data:
            raise MessageError("missing_field", name)
        value = data[name]
        if fast == _FLOAT:
            if value.__class__ is float and lo <= value <= hi:
                kwargs[name] = value
                continue
        elif fast == _FLOATS:
            if value.__class__ is list and len(value) == n:
                for x in value:
                    if x.__class__ is not float or not lo <= x <= hi:
                        break
                else:
                    kwargs[name] = value  # a fresh list from msgpack, not shared
                    continue
        elif fast == _INTEGER and value.__class__ is int and lo <= value <= hi:
            kwargs[name] = value
            continue
        kwargs[name] = _check(spec, name, value)
    if cls in _DIRECT:
        msg = object.__new__(cls)
        msg.__dict__.update(kwargs)
        return msg
    return cls(**kwargs)
