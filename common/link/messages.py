"""Wire messages between leader and follower (msgspec Structs over msgpack, schema-versioned).

Every message is a msgpack map with an envelope::

    {"k": kind, "v": SCHEMA_VERSION, "sid": session id, "seq": n, "t": send time [s], ...fields}

Each message type is a frozen, tagged :class:`msgspec.Struct` (tag field ``k``) whose
fields carry their range constraints (``Annotated[float, Meta(ge=..., le=...)]``), so
decoding and validation are one step in msgspec's C code. Every float field is bounded
on both sides, which also refuses NaN and the infinities (no comparison with NaN holds).

``sid`` is a random 32-bit id chosen once per process start: a receiver that sees a new
``sid`` knows the peer restarted and resets its sequence gate (see
:class:`bipedtele.link.gate.SequenceGate`). ``t`` is the sender's clock (``time.time()`` on
the sender) at the moment of sending.

Speeds are in the paper's units: forward in cm/s, turn in deg/s. Positions in metres,
angles in radians, times in seconds.

:func:`decode` validates types, finiteness and ranges, and requires every field on the
wire (a field left out is an error, not its default); anything else raises
:class:`MessageError`, whose ``reason`` names the kind of problem for counters. The wire
is authenticated outside this module (:mod:`bipedtele.link.auth`).
"""

from __future__ import annotations

import functools
import os
import re
from typing import Annotated, Any, ClassVar, Final, Literal, TypeAlias, Union, get_type_hints

import msgspec
from msgspec import Meta, Struct, field

__all__ = [
    "MESSAGE_TYPES",
    "SCHEMA_VERSION",
    "ClockPing",
    "ClockPong",
    "Command",
    "Feedback",
    "Hello",
    "Message",
    "MessageError",
    "Status",
    "VideoFrame",
    "decode",
    "encode",
    "fit_counters",
    "message_fields",
    "new_session_id",
]

SCHEMA_VERSION: Final = 1
MAX_MESSAGE_BYTES: Final = 4 * 1024 * 1024
MAX_JPEG_BYTES: Final = 2 * 1024 * 1024
MAX_VIDEO_PARTS: Final = 64  # a frame cut into at most this many messages
MAX_SEQ: Final = 2**63 - 1
MAX_TEXT: Final = 1024
MAX_COUNTERS: Final = 64

# Sanity bounds on wire values (far beyond anything physical; they reject garbage).
MAX_SPEED: Final = 1000.0  # cm/s or deg/s
MAX_POS: Final = 1.0e6  # m
MAX_FORCE: Final = 1.0e3  # N
MAX_PARAM: Final = 1.0e6
MAX_WAVE: Final = 1.0e5  # wave variable, sqrt(N cm/s)
MAX_ENERGY: Final = 1.0e12  # N cm (N deg)
MAX_DELAY_S: Final = 60.0
MIN_TIME: Final = 0.0
MAX_TIME: Final = 1.0e11  # s (about year 5138)

FOLLOWER_STATES: Final = ("starting", "standing", "walking", "stopping", "fallen", "error")
LEADER_STATES: Final = ("starting", "running", "feedback_stale", "stopped", "error")


class MessageError(ValueError):
    """A received payload is not a valid message.

    Attributes
    ----------
    reason : str
        Short category for counters: ``too_large``, ``not_msgpack``, ``not_a_map``,
        ``bad_version``, ``unknown_kind``, ``bad_field``, ``missing_field``.
    detail : str
        What was wrong (msgspec's message, with the field's path).
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def new_session_id() -> int:
    """Return a random non-zero 32-bit session id for this process."""
    return int.from_bytes(os.urandom(4), "little") or 1


# --------------------------------------------------------------------------- field types


def _choice(*names: str) -> Meta:
    """Constrain a string to one of ``names`` (a regex, so the type stays ``str``)."""
    return Meta(pattern="^(?:" + "|".join(re.escape(n) for n in names) + ")$", extra_json_schema={"enum": list(names)})


SessionId: TypeAlias = Annotated[int, Meta(ge=0, le=2**32 - 1)]
Seq: TypeAlias = Annotated[int, Meta(ge=0, le=MAX_SEQ)]
Time: TypeAlias = Annotated[float, Meta(ge=MIN_TIME, le=MAX_TIME)]
Delay: TypeAlias = Annotated[float, Meta(ge=0.0, le=MAX_DELAY_S)]
Gain: TypeAlias = Annotated[float, Meta(ge=0.0, le=100.0)]
Speed: TypeAlias = Annotated[float, Meta(ge=-MAX_SPEED, le=MAX_SPEED)]
Position: TypeAlias = Annotated[float, Meta(ge=-MAX_POS, le=MAX_POS)]
Damping: TypeAlias = Annotated[float, Meta(ge=0.0, le=MAX_PARAM)]
Force: TypeAlias = Annotated[float, Meta(ge=-MAX_FORCE, le=MAX_FORCE)]
Range: TypeAlias = Annotated[float, Meta(ge=0.0, le=100.0)]
PAIR: Final = Meta(min_length=2, max_length=2)
Speeds: TypeAlias = Annotated[list[Speed], PAIR]
Positions: TypeAlias = Annotated[list[Position], PAIR]
Dampings: TypeAlias = Annotated[list[Damping], PAIR]
Forces: TypeAlias = Annotated[list[Force], PAIR]
Ranges: TypeAlias = Annotated[list[Range], PAIR]
Wave: TypeAlias = Annotated[float, Meta(ge=-MAX_WAVE, le=MAX_WAVE)]
Energy: TypeAlias = Annotated[float, Meta(ge=0.0, le=MAX_ENERGY)]
Waves: TypeAlias = Annotated[list[Wave], PAIR]
Energies: TypeAlias = Annotated[list[Energy], PAIR]
Pose: TypeAlias = Annotated[list[Position], Meta(min_length=3, max_length=3)]
Stamps: TypeAlias = Annotated[list[Time], PAIR]
Text: TypeAlias = Annotated[str, Meta(max_length=MAX_TEXT)]
#: An operator's name: its router login (``[network] user``); empty: none given.
OperatorName: TypeAlias = Annotated[str, Meta(max_length=64, pattern=r"^[A-Za-z0-9_-]*$")]
NONCE_BYTES: Final = 32
Nonce: TypeAlias = Annotated[bytes, Meta(min_length=NONCE_BYTES, max_length=NONCE_BYTES)]
ZERO_NONCE: Final = bytes(NONCE_BYTES)
#: A session's watch epoch (:class:`bipedtele.link.auth.WatchAuth`): 4 bytes; zeros: none announced.
EPOCH_BYTES: Final = 4
Epoch: TypeAlias = Annotated[bytes, Meta(min_length=EPOCH_BYTES, max_length=EPOCH_BYTES)]
ZERO_EPOCH: Final = bytes(EPOCH_BYTES)
Counters: TypeAlias = Annotated[
    dict[Annotated[str, Meta(max_length=64)], Annotated[int, Meta(ge=0, le=MAX_SEQ)]],
    Meta(max_length=MAX_COUNTERS),
]


# Default factories: C callables (no Python frame per field when a message is built).
_zeros2: Final[functools.partial[list[float]]] = functools.partial(list, (0.0, 0.0))
_zeros3: Final[functools.partial[list[float]]] = functools.partial(list, (0.0, 0.0, 0.0))


# --------------------------------------------------------------------------- messages


class Message(Struct, frozen=True, gc=False, tag_field="k", forbid_unknown_fields=True):
    """Envelope shared by every message.

    Attributes
    ----------
    v : int
        Schema version (:data:`SCHEMA_VERSION`; any other is refused).
    sid : int
        Sender's session id (random per process start).
    seq : int
        Sender's sequence number.
    t : float
        Send time, sender's clock [s].
    """

    KIND: ClassVar[str] = ""
    v: Literal[1] = SCHEMA_VERSION
    sid: SessionId = 0
    seq: Seq = 0
    t: Time = 0.0


class Command(Message, frozen=True, gc=False, tag="cmd"):
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
    wave : [float, float] or None
        Wave variable ``u_m`` (scheme ``wave``; None otherwise: a byte on the wire), sqrt(N cm/s).
    energy : [float, float] or None
        Energy that entered the link at the leader's port so far [N cm, N deg] (the
        follower's passivity observer, scheme ``tdpa``; None otherwise).
    operator : str
        Who sends it: the leader's router login (``[network] user``; empty: none). The
        robot's hand-over rule (docs/fleet.md, Hand-over) keys on it.
    release : bool
        True: the operator gives the robot up (with ``enable`` False): another operator
        may take it. A leader sends it when released in the cockpit and when it exits.
    fb_echo : [float, float] or None
        The newest Feedback the leader took: its send stamp ``t`` (the follower's clock)
        and when the leader received it (the leader's clock) [s]; None before the first.
        Their difference is the feedback's one-way delay plus the clocks' offset: the
        follower reads its rise, a queue in its uplink (follower/owdqueue.py).
    """

    KIND: ClassVar[str] = "cmd"
    ref: Speeds = field(default_factory=_zeros2)
    x_m: Positions = field(default_factory=_zeros2)
    dx_m: Positions = field(default_factory=_zeros2)
    h2_s: Delay = 0.0
    alpha_m: Dampings = field(default_factory=_zeros2)
    enable: bool = True
    wave: Waves | None = None
    energy: Energies | None = None
    operator: OperatorName = ""
    release: bool = False
    fb_echo: Stamps | None = None


class Feedback(Message, frozen=True, gc=False, tag="fb"):
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
    wave : [float, float] or None
        Wave variable ``v_s`` (scheme ``wave``; None otherwise: a byte on the wire), sqrt(N cm/s).
    energy : [float, float] or None
        Energy that entered the link at the follower's port so far [N cm, N deg] (the
        leader's passivity observer, scheme ``tdpa``; None otherwise).
    """

    KIND: ClassVar[str] = "fb"
    z_e: Speeds = field(default_factory=_zeros2)
    z_r: Speeds = field(default_factory=_zeros2)
    eta: Speeds = field(default_factory=_zeros2)
    ref: Speeds = field(default_factory=_zeros2)
    pose: Pose = field(default_factory=_zeros3)
    sonar: Ranges = field(default_factory=_zeros2)
    f_v: Forces = field(default_factory=_zeros2)
    h1_s: Delay = 0.0
    s_e: Dampings = field(default_factory=_zeros2)
    s_r: Dampings = field(default_factory=_zeros2)
    T: Gain = 0.0
    eps: Gain = 0.0
    state: Annotated[str, _choice(*FOLLOWER_STATES)] = "starting"
    cmd_seq: Seq = 0
    wave: Waves | None = None
    energy: Energies | None = None


class VideoFrame(Message, frozen=True, gc=False, tag="video"):
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
        The JPEG file, or its part ``part`` of ``parts``.
    part, parts : int
        On a slow uplink a frame travels in ``parts`` messages paced apart (so that
        control never waits behind a whole frame); their ``seq`` run on from the first
        part's (``seq - part`` names the frame) and ``jpeg`` is the frame's bytes cut in
        order. 0 and 1: a whole frame. A receiver drops a part not below ``parts``.
    """

    KIND: ClassVar[str] = "video"
    camera: Annotated[str, _choice("head", "scene")] = "head"
    width: Annotated[int, Meta(ge=1, le=4096)] = 320
    height: Annotated[int, Meta(ge=1, le=4096)] = 240
    t_capture: Time = 0.0
    jpeg: Annotated[bytes, Meta(max_length=MAX_JPEG_BYTES)] = b""
    part: Annotated[int, Meta(ge=0, le=MAX_VIDEO_PARTS - 1)] = 0
    parts: Annotated[int, Meta(ge=1, le=MAX_VIDEO_PARTS)] = 1


class ClockPing(Message, frozen=True, gc=False, tag="ping"):
    """NTP-style ping: ``t`` is t1, the requester's send time."""

    KIND: ClassVar[str] = "ping"


class ClockPong(Message, frozen=True, gc=False, tag="pong"):
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
    ping_sid: SessionId = 0
    ping_seq: Seq = 0
    t1: Time = 0.0
    t2: Time = 0.0


class Status(Message, frozen=True, gc=False, tag="status"):
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
    operator : str
        A leader's: its operator (``[network] user``; empty: none given).
    held_by : str
        A follower's: the operator who holds the robot now (empty: free, or operators
        without names); see docs/fleet.md, Hand-over.
    """

    KIND: ClassVar[str] = "status"
    role: Annotated[str, _choice("leader", "follower")] = "follower"
    state: Annotated[str, _choice(*dict.fromkeys(FOLLOWER_STATES + LEADER_STATES))] = "starting"
    counters: Counters = field(default_factory=dict)
    text: Text = ""
    operator: OperatorName = ""
    held_by: OperatorName = ""


class Hello(Message, frozen=True, gc=False, tag="hello"):
    """Either side, with the message key only: the session handshake (:mod:`bipedtele.link.session`).

    Signed with the master key, sent on the clock key. The session key of a leader and a
    follower session is derived from both nonces; a Hello completes a handshake only when
    it echoes the receiver's current nonce.

    Attributes
    ----------
    role : str
        ``leader`` or ``follower``.
    nonce : bytes
        The sender's fresh random nonce for this pairing (32 bytes).
    peer_sid : int
        The peer session this Hello answers or is bound to (0: none).
    peer_nonce : bytes
        The peer's nonce echoed (32 zero bytes: none).
    watch : bytes
        The sender's watch epoch: its video and status are sealed under that session's
        watch key (:func:`bipedtele.link.auth.session_watch_key`; 4 zero bytes: none announced).
    """

    KIND: ClassVar[str] = "hello"
    role: Annotated[str, _choice("leader", "follower")] = "leader"
    nonce: Nonce = ZERO_NONCE
    peer_sid: SessionId = 0
    peer_nonce: Nonce = ZERO_NONCE
    watch: Epoch = ZERO_EPOCH


MESSAGE_TYPES: Final[dict[str, type[Message]]] = {
    cls.KIND: cls for cls in (Command, Feedback, VideoFrame, ClockPing, ClockPong, Status, Hello)
}


def message_fields(cls: type[Message]) -> tuple[str, ...]:
    """Return the names of a message type's fields, envelope first (``v``, ``sid``, ...)."""
    return cls.__struct_fields__


# --------------------------------------------------------------------------- codec
#
# On the wire every field is required, while the classes give every field a default (so
# that code builds messages field by field). msgspec fills a field left out with its
# default, so :func:`decode` counts the map's keys (the msgpack header, read in O(1)):
# unknown keys are refused by msgspec (``forbid_unknown_fields``), so a map with fewer
# keys than the class has fields lacks one. A twin of each class with the same fields
# and tag but no defaults then names it (error path only). Decoding straight into the
# public classes keeps the happy path to one C call: a conversion step from the twins
# would cost more than msgspec's decoding itself, once per message from cold caches.


def _wire_twin(cls: type[Message]) -> type[Struct]:
    hints = get_type_hints(cls, include_extras=True)
    fields = [(name, hints[name]) for name in cls.__struct_fields__]
    return msgspec.defstruct(
        f"_Wire{cls.__name__}", fields, frozen=True, gc=False, tag_field="k", tag=cls.KIND, module=__name__
    )


for _cls in MESSAGE_TYPES.values():
    if _cls.__struct_config__.tag != _cls.KIND:  # pragma: no cover - programming error
        raise TypeError(f"{_cls.__name__}: tag {_cls.__struct_config__.tag!r} is not KIND {_cls.KIND!r}")

_ENCODER: Final = msgspec.msgpack.Encoder()
_DECODER: Final[msgspec.msgpack.Decoder[Any]] = msgspec.msgpack.Decoder(Union[tuple(MESSAGE_TYPES.values())])  # noqa: UP007
_TWIN_DECODER: Final[msgspec.msgpack.Decoder[Any]] = msgspec.msgpack.Decoder(
    Union[tuple(_wire_twin(c) for c in MESSAGE_TYPES.values())]  # noqa: UP007
)
#: Keys of a complete map of each class: the tag ``k`` and every field.
_KEYS: Final[dict[type[Message], int]] = {c: 1 + len(c.__struct_fields__) for c in MESSAGE_TYPES.values()}
_PATH = re.compile(r"`\$\.(\w+)")
_MISSING = re.compile(r"missing required field `(\w+)`")
_UNKNOWN = re.compile(r"unknown field `")


def encode(msg: Message) -> bytes:
    """Serialise a message to msgpack bytes (envelope plus fields)."""
    return _ENCODER.encode(msg)


def _reason(error: str) -> str:
    """Return the counter reason of a msgspec validation error message."""
    if _UNKNOWN.search(error) is not None:
        return "bad_field"
    missing = _MISSING.search(error)
    if missing is not None:
        name = missing.group(1)
        return {"k": "unknown_kind", "v": "bad_version"}.get(name, "missing_field")
    path = _PATH.search(error)
    if path is None:
        return "not_a_map"  # only the top level has no path: "Expected `object`, got ..."
    return {"k": "unknown_kind", "v": "bad_version"}.get(path.group(1), "bad_field")


def decode(payload: bytes | bytearray | memoryview, expect: type[Message] | None = None) -> Message:
    """Parse and validate a payload.

    Parameters
    ----------
    payload : bytes
        What came off the network.
    expect : type, optional
        If given, any other message kind is rejected (``unknown_kind``).

    Returns
    -------
    Message
        An instance of one of :data:`MESSAGE_TYPES` (of ``expect`` if given).

    Raises
    ------
    MessageError
        For anything that is not a valid message of the expected kind. Nothing else
        is raised, whatever the bytes.
    """
    if len(payload) > MAX_MESSAGE_BYTES:
        raise MessageError("too_large", f"{len(payload)} bytes")
    try:
        msg: Message = _DECODER.decode(payload)
    except msgspec.ValidationError as exc:
        # msgspec stops at the first wrong value; bytes that are not one whole msgpack
        # object at all count as not_msgpack however early they went wrong (error path only)
        try:
            msgspec.msgpack.decode(payload)
        except Exception as bad:  # DecodeError, UnicodeDecodeError, RecursionError, ...
            raise MessageError("not_msgpack", f"{type(bad).__name__}: {bad}") from None
        raise MessageError(_reason(str(exc)), str(exc)) from None
    except Exception as exc:  # DecodeError, UnicodeDecodeError, RecursionError, ...
        raise MessageError("not_msgpack", f"{type(exc).__name__}: {exc}") from None
    cls = msg.__class__
    if expect is not None and cls is not expect:
        raise MessageError("unknown_kind", f"k={cls.KIND!r}, expected {expect.KIND!r}")
    # a successful decode saw a map: fixmap (0x80-0x8f), map16 (0xde) or map32 (0xdf)
    head = payload[0]
    n = head & 0x0F if head < 0xDE else int.from_bytes(payload[1:3] if head == 0xDE else payload[1:5], "big")
    if n != _KEYS[cls]:
        raise _incomplete(payload, n, _KEYS[cls])
    return msg


def fit_counters(counters: dict[str, int]) -> dict[str, int]:
    """Return a Status's ``counters`` within :data:`MAX_COUNTERS` keys, so that its receiver takes it.

    Drop counters (``drop_<reason>``) come with each new reason a peer's messages show; past
    the bound the most frequent reasons keep their keys and the rest are summed in
    ``drop_other`` (a Status over it is refused whole, ``bad_field``: counting bad
    messages must not silence the sender's Status). ``counters`` itself is returned when it fits.

    Raises
    ------
    ValueError
        When the counters other than the drops alone do not fit (a programming error).
    """
    if len(counters) <= MAX_COUNTERS:
        return counters
    out = {k: v for k, v in counters.items() if not k.startswith("drop_")}
    room = MAX_COUNTERS - len(out) - 1  # one key for drop_other
    if room < 0:
        raise ValueError(f"{len(out)} counters besides the drops: allowed: at most {MAX_COUNTERS - 1}")
    drops = sorted(((v, k) for k, v in counters.items() if k.startswith("drop_") and k != "drop_other"), reverse=True)
    out.update({k: v for v, k in drops[:room]})
    out["drop_other"] = min(MAX_SEQ, counters.get("drop_other", 0) + sum(v for v, _ in drops[room:]))
    return out


def _incomplete(payload: bytes | bytearray | memoryview, n: int, want: int) -> MessageError:
    """Return the error of a map with the wrong number of keys (the twin names a missing field)."""
    try:
        _TWIN_DECODER.decode(payload)
    except msgspec.ValidationError as exc:
        return MessageError(_reason(str(exc)), str(exc))
    return MessageError("bad_field", f"{n} keys for {want} fields: a key appears twice")
