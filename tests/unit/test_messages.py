"""Wire messages: round trips of every type; garbage only ever raises MessageError."""

from __future__ import annotations

import contextlib
import dataclasses
import math

import msgpack
import pytest
from bipedtele.messages import (
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    ClockPong,
    Command,
    Feedback,
    Message,
    MessageError,
    Status,
    VideoFrame,
    _Bytes,
    _Counters,
    _Int,
    _Num,
    _Str,
    decode,
    encode,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.timeout(120)
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _num(spec: _Num) -> st.SearchStrategy:
    one = st.floats(min_value=spec.lo, max_value=spec.hi, allow_nan=False, allow_infinity=False)
    return st.lists(one, min_size=spec.n, max_size=spec.n) if spec.n else one


def _field_strategy(spec: object) -> st.SearchStrategy:
    if isinstance(spec, _Num):
        return _num(spec)
    if isinstance(spec, _Int):
        return st.integers(spec.lo, spec.hi)
    if isinstance(spec, _Str):
        return st.sampled_from(spec.choices) if spec.choices else st.text(max_size=50)
    if isinstance(spec, _Bytes):
        return st.binary(max_size=256)
    if isinstance(spec, _Counters):
        return st.dictionaries(st.text(max_size=10), st.integers(0, 2**40), max_size=5)
    if spec is bool:
        return st.booleans()
    raise AssertionError(spec)


def _message(cls: type[Message]) -> st.SearchStrategy:
    return st.builds(
        cls,
        **{f.name: _field_strategy(f.metadata["spec"]) for f in dataclasses.fields(cls)},
    )


any_message = st.one_of(*[_message(c) for c in MESSAGE_TYPES.values()])


@FAST
@given(any_message)
def test_round_trip_every_type(msg: Message) -> None:
    back = decode(encode(msg))
    assert type(back) is type(msg)
    assert back == msg
    assert decode(encode(msg), type(msg)) == msg


def test_every_type_covered_and_expect() -> None:
    assert set(MESSAGE_TYPES) == {"cmd", "fb", "video", "ping", "pong", "status"}
    payload = encode(Command(sid=1, seq=2, t=3.0))
    with pytest.raises(MessageError) as exc:
        decode(payload, Feedback)
    assert exc.value.reason == "unknown_kind"


@FAST
@given(st.binary(max_size=512))
def test_random_bytes_only_message_error(data: bytes) -> None:
    try:
        decode(data)
    except MessageError as exc:
        assert exc.reason


_mp_scalar = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),
    st.floats(),
    st.text(max_size=20),
    st.binary(max_size=20),
)
_mp_value = st.recursive(
    _mp_scalar,
    lambda inner: st.one_of(
        st.lists(inner, max_size=5),
        st.dictionaries(st.one_of(st.text(max_size=8), st.integers()), inner, max_size=5),
    ),
    max_leaves=20,
)


@FAST
@given(_mp_value)
def test_random_msgpack_only_message_error(obj: object) -> None:
    try:
        data = msgpack.packb(obj, use_bin_type=True)
    except (ValueError, OverflowError, TypeError):
        return
    with contextlib.suppress(MessageError):
        decode(data)


_envelopes = st.fixed_dictionaries(
    {"v": st.just(SCHEMA_VERSION), "k": st.sampled_from(sorted(MESSAGE_TYPES))},
    optional={
        name: _mp_value
        for name in ("sid", "seq", "t", "ref", "z_e", "jpeg", "counters", "state", "t1", "enable")
    },
)


@FAST
@given(_envelopes)
def test_random_fields_only_message_error(obj: dict) -> None:
    try:
        data = msgpack.packb(obj, use_bin_type=True)
    except (ValueError, OverflowError, TypeError):
        return
    with contextlib.suppress(MessageError):
        decode(data)


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [
        (lambda d: {**d, "v": 2}, "bad_version"),
        (lambda d: {**d, "k": "x"}, "unknown_kind"),
        (lambda d: {k: v for k, v in d.items() if k != "ref"}, "missing_field"),
        (lambda d: {**d, "ref": [math.nan, 0.0]}, "bad_field"),
        (lambda d: {**d, "ref": [math.inf, 0.0]}, "bad_field"),
        (lambda d: {**d, "ref": [1.0]}, "bad_field"),
        (lambda d: {**d, "ref": [5000.0, 0.0]}, "bad_field"),
        (lambda d: {**d, "seq": -1}, "bad_field"),
        (lambda d: {**d, "seq": True}, "bad_field"),
        (lambda d: {**d, "enable": 1}, "bad_field"),
        (lambda d: {**d, "t": "now"}, "bad_field"),
    ],
)
def test_malformed_reasons(mutate, reason: str) -> None:
    good = msgpack.unpackb(encode(Command(sid=1, seq=2, t=3.0)))
    with pytest.raises(MessageError) as exc:
        decode(msgpack.packb(mutate(good), use_bin_type=True))
    assert exc.value.reason == reason


def test_other_reasons() -> None:
    for data, reason in [
        (b"\xc1", "not_msgpack"),
        (msgpack.packb([1, 2]), "not_a_map"),
        (b"\x00" * (4 * 1024 * 1024 + 1), "too_large"),
        (encode(Command())[:-2], "not_msgpack"),
    ]:
        with pytest.raises(MessageError) as exc:
            decode(data)
        assert exc.value.reason == reason
    bad_state = msgpack.unpackb(encode(Feedback()))
    bad_state["state"] = "dancing"
    with pytest.raises(MessageError, match="state"):
        decode(msgpack.packb(bad_state))
    st_ = msgpack.unpackb(encode(Status(counters={"x": 1})))
    st_["counters"] = {"x": -1}
    with pytest.raises(MessageError):
        decode(msgpack.packb(st_))
    v = msgpack.unpackb(encode(VideoFrame(jpeg=b"abc")))
    v["jpeg"] = "not bytes"
    with pytest.raises(MessageError):
        decode(msgpack.packb(v, use_bin_type=True))
    p = ClockPong(ping_sid=1, ping_seq=2, t1=1.0, t2=2.0)
    assert decode(encode(p)) == p
