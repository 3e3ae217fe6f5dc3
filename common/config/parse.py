"""A profile section's table checked against its dataclass: :func:`parse_section`.

From each dataclass's annotations and :func:`~bipedtele.config.fields.param` ranges a
validator type is built once (``Annotated[float, msgspec.Meta(ge=..., le=...)]``,
``Literal``, lists, nested tables) and the table is converted with ``msgspec.convert`` in
strict mode; numbers must also be finite, and a whole float (``2.0``) is taken for an
integer field. A failure is one :class:`~bipedtele.config.fields.ConfigError` line naming
the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal, TypeVar, get_args, get_origin, get_type_hints

import msgspec
from bipedtele.config.fields import ConfigError

__all__ = ["dataclass_of", "fmt_value", "parse_section"]

T = TypeVar("T")


def fmt_value(value: Any) -> str:
    """``repr(value)``, cut to 60 characters (for one-line errors)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _allowed_range(meta: Mapping[str, Any]) -> str:
    lo, hi, unit = meta.get("lo"), meta.get("hi"), meta.get("unit") or ""
    unit = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        left = "(" if meta.get("lo_open") else "["
        return f"a number in {left}{lo}, {hi}]{unit}"
    if lo is not None:
        return f"a number {'>' if meta.get('lo_open') else '>='} {lo}{unit}"
    if hi is not None:
        return f"a number <= {hi}{unit}"
    return f"a number{unit}"


def _type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in get_args(tp))
    if origin in (list, tuple, Sequence):
        args = [a for a in get_args(tp) if a is not Ellipsis]
        inner = _type_name(args[0]) if args else "value"
        return f"a list of {inner}"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in get_args(tp))
    if tp is type(None):
        return "absent"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        tp, getattr(tp, "__name__", str(tp))
    )


# A section is checked by msgspec: each dataclass gets a validator Struct built once from its
# fields' types and param() metadata (ranges as msgspec.Meta, Literal, lists, nested tables as
# nested validators). Every field defaults to UNSET, so only the keys a file gives are checked
# and the dataclass's own defaults apply to the rest. msgspec names the failing place as a path
# ("$.legs[0].size[1]"); the one-line error is written from that path, the raw value there and
# the field's metadata. Two checks msgspec has no constraint for are done after it: numbers must
# be finite, and an integer field takes a whole float (2.0) as that integer.


@dataclass(frozen=True)
class _Field:
    """One dataclass field: its annotation and its param() metadata."""

    tp: Any
    meta: Mapping[str, Any]


@dataclass(frozen=True)
class _Plan:
    """How one section dataclass is validated: its fields and its msgspec validator type."""

    fields: dict[str, _Field]
    validator: type[msgspec.Struct]


_PLANS: dict[type, _Plan] = {}
_SEQUENCES = (list, tuple, Sequence)


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _elements(tp: Any) -> Any:
    """Return the element type of a list, tuple or sequence annotation (Any if not given)."""
    args = [a for a in get_args(tp) if a is not Ellipsis]
    return args[0] if args else Any


def _plan(cls: type) -> _Plan:
    """Return the validation plan of a section dataclass (built on first use, then reused)."""
    plan = _PLANS.get(cls)
    if plan is None:
        hints = get_type_hints(cls)
        fields = {f.name: _Field(hints[f.name], f.metadata) for f in dataclasses.fields(cls)}
        spec = [
            (name, typing.Union[_spec(f.tp, f.meta), msgspec.UnsetType], msgspec.UNSET)  # noqa: UP007
            for name, f in fields.items()
        ]
        validator = msgspec.defstruct(f"{cls.__name__}Check", spec, forbid_unknown_fields=True)
        plan = _PLANS[cls] = _Plan(fields, validator)
    return plan


def _bounds(meta: Mapping[str, Any], integer: bool) -> dict[str, Any]:
    """``msgspec.Meta`` keyword arguments for the range in ``meta`` (whole bounds if ``integer``)."""
    lo, hi = meta.get("lo"), meta.get("hi")
    out: dict[str, Any] = {}
    if lo is not None:
        if integer:  # v > lo (or >= lo) for a whole v is v >= the next whole number
            out["ge"] = math.floor(lo) + 1 if meta.get("lo_open") else math.ceil(lo)
        else:
            out["gt" if meta.get("lo_open") else "ge"] = lo
    if hi is not None:
        out["le"] = math.floor(hi) if integer else hi
    return out


def _spec(tp: Any, meta: Mapping[str, Any]) -> Any:
    """Return the msgspec type that checks a value of annotation ``tp`` and the range in ``meta``."""
    origin = get_origin(tp)
    if origin is Literal or tp in (Any, bool, str, type(None)):
        return tp
    if origin in (typing.Union, types.UnionType):
        return typing.Union[tuple(_spec(a, meta) for a in get_args(tp))]  # noqa: UP007
    if _is_dataclass_type(tp):
        return _plan(tp).validator
    if origin in _SEQUENCES:
        elem = _spec(_elements(tp), meta)
        return tuple[elem, ...] if origin is tuple else list[elem]  # type: ignore[valid-type]
    if tp is float:
        bounds = _bounds(meta, integer=False)
        return Annotated[float, msgspec.Meta(**bounds)] if bounds else float
    if tp is int:  # a whole float is accepted too (and made an int after the check)
        ints, floats = _bounds(meta, integer=True), _bounds(meta, integer=False)
        return typing.Union[  # noqa: UP007
            Annotated[int, msgspec.Meta(**ints)] if ints else int,
            Annotated[float, msgspec.Meta(**floats)] if floats else float,
        ]
    raise TypeError(f"unsupported config field type {tp!r}")


def _allowed(tp: Any, value: Any, meta: Mapping[str, Any]) -> str:
    """Say what a field of annotation ``tp`` allows, as the error message words it."""
    if _is_dataclass_type(tp):
        return f"a table of {tp.__name__} fields"
    if tp is float:
        return _allowed_range(meta)
    if tp is int:
        whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
        return _allowed_range(meta) if whole and not isinstance(value, bool) else "an integer"
    return _type_name(tp)


def _fail(where: str, tp: Any, value: Any, meta: Mapping[str, Any]) -> ConfigError:
    shown = int(value) if tp is int and isinstance(value, float) and value.is_integer() else value
    return ConfigError(f"{where} = {fmt_value(shown)}: allowed: {_allowed(tp, value, meta)}")


def _pick(tp: Any, step: str | int) -> Any:
    """Return the member of an optional/union annotation that a path step goes into."""
    if get_origin(tp) not in (typing.Union, types.UnionType):
        return tp
    for arg in get_args(tp):
        if (isinstance(step, int) and get_origin(arg) in _SEQUENCES) or (
            isinstance(step, str) and _is_dataclass_type(arg)
        ):
            return arg
    return tp


_AT = re.compile(r" - at `\$([^`]*)`$")
_STEP = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


def _explain(cls: type, data: Mapping[str, Any], where: str, exc: msgspec.ValidationError) -> ConfigError:
    """Return the one-line error for a msgspec validation failure of ``data`` as ``cls``."""
    text = str(exc)
    found = _AT.search(text)
    path = found.group(1) if found else ""
    tp: Any = cls
    value: Any = data
    meta: Mapping[str, Any] = {}
    for m in _STEP.finditer(path):
        name, index = m.group(1), m.group(2)
        if name is not None:
            tp = _pick(tp, name)
            f = _plan(tp).fields[name]
            tp, meta, value = f.tp, f.meta, value[name]
        else:
            tp = _elements(_pick(tp, int(index)))
            value = value[int(index)]
    if text.startswith("Object contains unknown field") and _is_dataclass_type(tp):
        fields = _plan(tp).fields
        key = next(k for k in value if k not in fields)
        allowed = ", ".join(sorted(fields)) or "(none)"
        return ConfigError(f"{where}{path}.{key}: unknown key; allowed keys: {allowed}")
    return _fail(f"{where}{path}", tp, value, meta)


def _build(tp: Any, value: Any, meta: Mapping[str, Any], where: str) -> Any:
    """Return a checked value as the field holds it: tables built, numbers finite, ints whole."""
    if value is None:
        return None
    if get_origin(tp) in (typing.Union, types.UnionType):
        tp = next(
            (
                a
                for a in get_args(tp)
                if (isinstance(value, msgspec.Struct) and _is_dataclass_type(a))
                or (isinstance(value, list | tuple) and get_origin(a) in _SEQUENCES)
                or (isinstance(value, float) and a is float)
                or (not isinstance(value, msgspec.Struct | list | tuple) and a is not type(None))
            ),
            Any,
        )
    if _is_dataclass_type(tp):
        return _make(tp, value, where)
    origin = get_origin(tp)
    if origin in _SEQUENCES:
        items = [_build(_elements(tp), v, meta, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if tp is float and not math.isfinite(value):
        raise _fail(where, tp, value, meta)
    if tp is int and isinstance(value, float):
        if not value.is_integer():
            raise _fail(where, tp, value, meta)
        return int(value)
    return value


def _make(cls: type[T], checked: msgspec.Struct, where: str) -> T:
    """Build the dataclass ``cls`` from its validator's instance (keys not given keep defaults)."""
    kwargs: dict[str, Any] = {}
    for name, f in _plan(cls).fields.items():
        value = getattr(checked, name)
        if value is not msgspec.UNSET:
            kwargs[name] = _build(f.tp, value, f.meta, f"{where}.{name}")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:  # __post_init__ cross-field checks
        raise ConfigError(f"{where}: {exc}") from None


def parse_section(cls: type[T], data: Mapping[str, Any], where: str) -> T:
    """Build the dataclass ``cls`` from a mapping, validating every key.

    Unknown keys are errors (they are usually typos). ``where`` prefixes error messages,
    e.g. ``"configs/default.toml: leader"``. Keys not given keep the dataclass's defaults.
    """
    plan = _plan(cls)
    try:
        checked = msgspec.convert(dict(data), type=plan.validator, strict=True)
    except msgspec.ValidationError as exc:
        raise _explain(cls, data, where, exc) from None
    return _make(cls, checked, where)


def dataclass_of(tp: Any) -> type | None:
    """Return the dataclass a field holds, directly or as list elements (for nested tables)."""
    if _is_dataclass_type(tp):
        return typing.cast(type, tp)
    if get_origin(tp) in _SEQUENCES and _is_dataclass_type(_elements(tp)):
        return typing.cast(type, _elements(tp))
    return None
