"""Wire messages: round trips of every type; garbage only ever raises MessageError."""

from __future__ import annotations

import contextlib
import math

import msgpack
import msgspec
import msgspec.inspect as mi
import pytest
from bipedtele.link.messages import (
    MAX_COUNTERS,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    ClockPong,
    Command,
    Feedback,
    Message,
    MessageError,
    Status,
    VideoFrame,
    decode,
    encode,
    fit_counters,
    message_fields,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.timeout(120)
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _field_strategy(t: mi.Type) -> st.SearchStrategy:
    """Valid values of one field, read from its msgspec type and constraints."""
    if isinstance(t, mi.Metadata):
        return _field_strategy(t.type)
    if isinstance(t, mi.FloatType):
        return st.floats(min_value=t.ge, max_value=t.le, allow_nan=False, allow_infinity=False)
    if isinstance(t, mi.IntType):
        return st.integers(t.ge, t.le)
    if isinstance(t, mi.ListType):
        return st.lists(_field_strategy(t.item_type), min_size=t.min_length, max_size=t.max_length)
    if isinstance(t, mi.StrType):
        if t.pattern:
            return st.from_regex(t.pattern, fullmatch=True)
        return st.text(max_size=min(50, t.max_length or 50))
    if isinstance(t, mi.BytesType):
        return st.binary(min_size=t.min_length or 0, max_size=min(256, t.max_length or 256))
    if isinstance(t, mi.DictType):
        return st.dictionaries(st.text(max_size=10), st.integers(0, 2**40), max_size=5)
    if isinstance(t, mi.BoolType):
        return st.booleans()
    if isinstance(t, mi.LiteralType):
        return st.sampled_from(t.values)
    if isinstance(t, mi.UnionType):
        return st.one_of(*[_field_strategy(u) for u in t.types])
    if isinstance(t, mi.NoneType):
        return st.none()
    raise AssertionError(t)


def _message(cls: type[Message]) -> st.SearchStrategy:
    info = mi.type_info(cls)
    assert isinstance(info, mi.StructType)
    return st.builds(cls, **{f.name: _field_strategy(f.type) for f in info.fields})


any_message = st.one_of(*[_message(c) for c in MESSAGE_TYPES.values()])


@FAST
@given(any_message)
def test_round_trip_every_type(msg: Message) -> None:
    back = decode(encode(msg))
    assert type(back) is type(msg)
    assert back == msg
    assert decode(encode(msg), type(msg)) == msg


def test_every_type_covered_and_expect() -> None:
    assert set(MESSAGE_TYPES) == {"cmd", "fb", "video", "ping", "pong", "status", "hello"}
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
        name: _mp_value for name in ("sid", "seq", "t", "ref", "z_e", "jpeg", "counters", "state", "t1", "enable")
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


def _float_paths(cls: type[Message]) -> list[tuple[str, int | None]]:
    """Every float on the wire of ``cls``: (field, index in its list or None)."""
    info = mi.type_info(cls)
    assert isinstance(info, mi.StructType)
    out: list[tuple[str, int | None]] = []
    for f in info.fields:
        ts = f.type.types if isinstance(f.type, mi.UnionType) else (f.type,)  # an optional field: its value type
        for t in ts:
            if isinstance(t, mi.FloatType):
                out.append((f.name, None))
            elif isinstance(t, mi.ListType) and isinstance(t.item_type, mi.FloatType):
                out.extend((f.name, i) for i in range(t.min_length or 0))
    return out


_EVERY_FLOAT = [(cls, name, i) for cls in MESSAGE_TYPES.values() for name, i in _float_paths(cls)]


def test_every_float_field_is_found() -> None:
    """The parametrisation below covers the float fields (Command's 16, Feedback's 27, ...)."""
    counts = {cls.KIND: sum(1 for c, _, _ in _EVERY_FLOAT if c is cls) for cls in MESSAGE_TYPES.values()}
    assert counts == {"cmd": 16, "fb": 27, "video": 2, "ping": 1, "pong": 3, "status": 1, "hello": 1}


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize(("cls", "name", "index"), _EVERY_FLOAT, ids=lambda x: getattr(x, "KIND", str(x)))
def test_non_finite_refused_in_every_float(cls: type[Message], name: str, index: int | None, bad: float) -> None:
    """msgspec's float constraints alone would let NaN through an unbounded float: every float
    field is bounded on both sides, so NaN and the infinities are refused wherever they are."""
    data = msgpack.unpackb(encode(cls()))
    if index is None:
        data[name] = bad
    else:
        if data[name] is None:  # an optional pair sent as none: send one
            data[name] = [0.0, 0.0]
        data[name][index] = bad
    with pytest.raises(MessageError) as exc:
        decode(msgpack.packb(data, use_bin_type=True))
    assert exc.value.reason == "bad_field"
    assert f"$.{name}" in exc.value.detail


def test_every_float_field_is_bounded_both_sides() -> None:
    """The reason NaN is refused: no float type is open on either side."""

    def floats(t: mi.Type) -> list[mi.FloatType]:
        if isinstance(t, mi.Metadata):
            return floats(t.type)
        if isinstance(t, mi.FloatType):
            return [t]
        if isinstance(t, mi.ListType):
            return floats(t.item_type)
        if isinstance(t, mi.UnionType):
            return [ft for u in t.types for ft in floats(u)]
        return []

    for cls in MESSAGE_TYPES.values():
        info = mi.type_info(cls)
        assert isinstance(info, mi.StructType)
        for f in info.fields:
            for ft in floats(f.type):
                assert (ft.ge is not None or ft.gt is not None) and (ft.le is not None or ft.lt is not None), (
                    cls,
                    f.name,
                )


def test_every_field_is_required_on_the_wire() -> None:
    """A field left out is an error (``missing_field``), not its default, for every field."""
    for cls in MESSAGE_TYPES.values():
        good = msgpack.unpackb(encode(cls()))
        for name in message_fields(cls):
            with pytest.raises(MessageError) as exc:
                decode(msgpack.packb({k: v for k, v in good.items() if k != name}, use_bin_type=True))
            want = "bad_version" if name == "v" else "missing_field"
            assert exc.value.reason == want, (cls, name)
        missing_kind = {k: v for k, v in good.items() if k != "k"}
        with pytest.raises(MessageError) as exc:
            decode(msgpack.packb(missing_kind, use_bin_type=True))
        assert exc.value.reason == "unknown_kind"


def test_deep_nesting_in_an_unknown_field() -> None:
    """Unknown keys are skipped, but a value nested far too deep is a MessageError."""
    head = msgpack.packb({"k": "ping", "v": SCHEMA_VERSION, "sid": 1, "seq": 1, "t": 1.0})
    body = b"\x86" + head[1:] + b"\xa2zz" + b"\x91" * 200_000 + b"\xc0"
    with pytest.raises(MessageError) as exc:
        decode(body)
    assert exc.value.reason == "not_msgpack"


def test_messages_are_frozen_and_replaceable() -> None:
    c = Command(sid=1, seq=2, t=3.0)
    with pytest.raises(AttributeError):
        c.seq = 5  # type: ignore[misc]
    d = msgspec.structs.replace(c, seq=5)
    assert d.seq == 5 and c.seq == 2 and decode(encode(d)) == d


def test_counters_past_the_bound_sum_the_rarest_drops_in_drop_other() -> None:
    small = {"ticks": 5, "drop_stale": 2}
    assert fit_counters(small) is small
    own = {f"c{k:02d}": k for k in range(MAX_COUNTERS - 4)}
    many = own | {"drop_a": 9, "drop_b": 1, "drop_c": 7, "drop_d": 3, "drop_other": 4}
    fitted = fit_counters(many)
    assert len(fitted) == MAX_COUNTERS and fitted == own | {"drop_a": 9, "drop_c": 7, "drop_d": 3, "drop_other": 5}
    st = Status(sid=1, seq=1, t=1.0, counters=fitted)
    assert decode(encode(st), Status) == st
    with pytest.raises(ValueError, match="besides the drops"):
        fit_counters({f"c{k}": k for k in range(MAX_COUNTERS + 1)})
