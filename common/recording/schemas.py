"""JSON Schemas of the recorded channels, so that Foxglove shows typed plots and the video.

Every channel of a recording (:mod:`bipedtele.recording.recorder`) carries a schema with encoding
``jsonschema`` and its messages are JSON objects (message encoding ``json``), the JSON form
Foxglove's MCAP reader understands. The schemas come from three sources:

- **Wire messages** (:class:`bipedtele.link.messages.Message`): :func:`message_schema` is
  msgspec's JSON Schema of the message's Struct (:func:`msgspec.json.schema`), so the
  ranges, exact list lengths, string choices and lengths are the very constraints the
  decoder applies; every field is required (as on the wire) and the envelope ``v``
  (schema version) and ``k`` (kind) are constants. Any other dataclass written to a
  recorder: :func:`dataclass_schema` reads its field names and type hints (``float`` ->
  number, ``int`` -> integer, ``list[float]`` -> array of numbers, ``bytes`` -> base64
  string, ...). Schema name: ``bipedtele.<ClassName>``.
- **Video**: :func:`compressed_image_schema` is Foxglove's well-known
  ``foxglove.CompressedImage`` (``timestamp`` {sec, nsec}, ``frame_id``, ``data`` as base64,
  ``format``) with the :class:`~bipedtele.link.messages.VideoFrame` header fields beside them;
  frames recorded without their JPEG use :func:`video_header_schema`.
- **The leader's sample** (``leader/state``): msgspec's JSON Schema of
  :class:`bipedtele.telemetry.LeaderSample` (:data:`LEADER_STATE_FIELDS`, units in the
  descriptions).
- **Maps** (``events`` and any other topic written as a dict, ``leader/state`` written as a
  dict by tests and tools): a fixed table of keys (:data:`LEADER_STATE_FIELDS`, :data:`EVENT_FIELDS`)
  merged with :func:`sample_schema`, which types every other key from the first map
  written on the channel (number, integer, boolean, string, array of numbers, object;
  every one nullable). Keys that appear only later are still recorded (the schemas allow
  additional properties) but Foxglove offers only the typed ones for completion.

Numbers that are not finite (NaN, inf) are written as ``null``: JSON has no such values.
"""

from __future__ import annotations

import dataclasses
import functools
import types
from collections.abc import Mapping
from typing import Any, Final, Union, get_args, get_origin, get_type_hints

import msgspec
from bipedtele.link.messages import SCHEMA_VERSION, Message, VideoFrame, message_fields
from bipedtele.telemetry import LeaderSample

__all__ = [
    "COMPRESSED_IMAGE",
    "EVENTS",
    "EVENT_FIELDS",
    "JSON_SCHEMA_DRAFT",
    "LEADER_STATE",
    "LEADER_STATE_FIELDS",
    "SCHEMA_ENCODING",
    "VIDEO_HEADER",
    "compressed_image_schema",
    "dataclass_schema",
    "event_schema",
    "leader_state_schema",
    "message_schema",
    "sample_schema",
    "video_header_schema",
]

SCHEMA_ENCODING: Final = "jsonschema"
JSON_SCHEMA_DRAFT: Final = "https://json-schema.org/draft/2020-12/schema"
COMPRESSED_IMAGE: Final = "foxglove.CompressedImage"
VIDEO_HEADER: Final = "bipedtele.VideoFrameHeader"
LEADER_STATE: Final = "bipedtele.LeaderState"
EVENTS: Final = "bipedtele.Event"

Schema = dict[str, Any]

_NUMBER: Final[Schema] = {"type": "number"}
_BASE64: Final[Schema] = {"type": "string", "contentEncoding": "base64"}


def _nullable(schema: Schema) -> Schema:
    t = schema.get("type")
    if isinstance(t, str):
        return {**schema, "type": [t, "null"]}
    return dict(schema)


def _object(
    name: str, properties: Mapping[str, Schema], required: list[str], *, description: str = "", additional: bool = False
) -> Schema:
    out: Schema = {"$schema": JSON_SCHEMA_DRAFT, "title": name, "type": "object"}
    if description:
        out["description"] = description
    out["properties"] = dict(properties)
    out["required"] = required
    out["additionalProperties"] = additional
    return out


# ---------------------------------------------------------------------- dataclasses


def _hint_schema(hint: Any) -> Schema:
    """Return the JSON Schema of a Python type hint (the subset the messages and samples use)."""
    origin = get_origin(hint)
    if origin in (Union, types.UnionType):
        args = get_args(hint)
        subs = [_hint_schema(a) for a in args if a is not type(None)]
        if len(subs) == 1 and type(None) in args:
            return _nullable(subs[0])
        return {"anyOf": subs + ([{"type": "null"}] if type(None) in args else [])}
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"type": "number"}
    if hint is str:
        return {"type": "string"}
    if hint in (bytes, bytearray):
        return dict(_BASE64)
    if origin in (list, tuple):
        items = [a for a in get_args(hint) if a is not Ellipsis]
        out: Schema = {"type": "array"}
        if items:
            out["items"] = _hint_schema(items[0])
        return out
    if origin is dict or hint is dict:
        args = get_args(hint)
        out = {"type": "object"}
        if len(args) == 2:
            out["additionalProperties"] = _hint_schema(args[1])
        return out
    return {}  # Any or an unknown type: no constraint


def _first_line(doc: str | None) -> str:
    return (doc or "").strip().splitlines()[0] if (doc or "").strip() else ""


@functools.cache
def message_schema(cls: type[Message]) -> Schema:
    """Return the JSON Schema of a wire message's recorded map, from its msgspec type.

    The map is the one that goes over the wire (:func:`bipedtele.recording.recorder.message_to_dict`):
    the constants ``v`` and ``k`` and the fields, all required, nothing else.

    Parameters
    ----------
    cls : type
        A :class:`~bipedtele.link.messages.Message` subclass.

    Returns
    -------
    dict
        An object schema titled ``bipedtele.<ClassName>``; no additional properties.
    """
    generated = msgspec.json.schema(cls)
    body = generated.get("$defs", {}).get(cls.__name__, generated)
    props: dict[str, Schema] = {
        "v": {"const": SCHEMA_VERSION, "description": "schema version"},
        "k": {"const": cls.KIND, "description": "message kind"},
    }
    for name in message_fields(cls):
        if name not in props:
            props[name] = {k: v for k, v in body["properties"][name].items() if k != "default"}
    return _object(f"bipedtele.{cls.__name__}", props, list(props), description=_first_line(cls.__doc__))


@functools.cache
def dataclass_schema(cls: type) -> Schema:
    """Return the JSON Schema of a recorded map: a wire message's or a typed sample's.

    A :class:`~bipedtele.link.messages.Message` subclass gets :func:`message_schema`; any
    other dataclass an object of its fields, typed from their hints, all required.

    Parameters
    ----------
    cls : type
        A message class or a dataclass.

    Returns
    -------
    dict
        An object schema titled ``bipedtele.<ClassName>``; no additional properties.

    Raises
    ------
    TypeError
        ``cls`` is neither.
    """
    if isinstance(cls, type) and issubclass(cls, Message):
        return message_schema(cls)
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"{cls!r} is not a message class or a dataclass")
    hints = get_type_hints(cls)
    props = {f.name: _hint_schema(hints[f.name]) for f in dataclasses.fields(cls)}
    return _object(f"bipedtele.{cls.__name__}", props, list(props), description=_first_line(cls.__doc__))


# ---------------------------------------------------------------------- video


def _video_header_properties() -> dict[str, Schema]:
    props = dict(dataclass_schema(VideoFrame)["properties"])
    del props["jpeg"]
    return props


@functools.cache
def compressed_image_schema() -> Schema:
    """``foxglove.CompressedImage`` (JSON form) plus the :class:`VideoFrame` header fields.

    ``timestamp`` is the frame's ``t_capture`` split in whole seconds and nanoseconds,
    ``frame_id`` the camera (``head``, ``scene``), ``data`` the JPEG in base64, ``format``
    ``"jpeg"``. Foxglove's Image panel reads these four and ignores the others.
    """
    header = _video_header_properties()
    props: dict[str, Schema] = {
        "timestamp": {
            "type": "object",
            "title": "time",
            "description": "when the image was captured (the frame's t_capture)",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
            },
            "required": ["sec", "nsec"],
        },
        "frame_id": {"type": "string", "description": "the camera"},
        "data": {**_BASE64, "description": "the JPEG file"},
        "format": {"type": "string", "enum": ["jpeg"], "description": "image format"},
        **header,
    }
    return _object(
        COMPRESSED_IMAGE,
        props,
        ["timestamp", "frame_id", "data", "format", *header],
        description="A compressed image (a VideoFrame with its JPEG)",
    )


@functools.cache
def video_header_schema() -> Schema:
    """Return the schema of a :class:`VideoFrame` recorded without its JPEG.

    ``jpeg_skipped``: thinned out by the recorder's ``jpeg_every``; false when the frame
    came without one.
    """
    header = _video_header_properties()
    props = {**header, "jpeg_skipped": {"type": "boolean"}}
    return _object(
        VIDEO_HEADER, props, [*header, "jpeg_skipped"], description="A video frame's header, recorded without its image"
    )


# ---------------------------------------------------------------------- maps


def _t(type_: str | list[str], description: str) -> Schema:
    return {"type": type_, "description": description}


_NUM_OR_NULL: Final = ["number", "null"]


def _type_list(prop: Schema) -> Schema:
    """Write msgspec's ``anyOf: [{type: X}, {type: null}]`` as ``type: [X, "null"]``.

    Foxglove and most JSON Schema readers handle the type list better; the default
    (None for every optional field) is dropped, as for the wire messages.
    """
    out = {k: v for k, v in prop.items() if k != "default"}
    alts = out.get("anyOf")
    if isinstance(alts, list) and all(isinstance(a, dict) and set(a) == {"type"} for a in alts):
        del out["anyOf"]
        out["type"] = [a["type"] for a in alts]
    return out


def _leader_state_fields() -> dict[str, Schema]:
    generated = msgspec.json.schema(LeaderSample)
    body = generated.get("$defs", {}).get(LeaderSample.__name__, generated)
    return {name: _type_list(prop) for name, prop in body["properties"].items()}


#: Property schemas of the leader's ``leader/state`` sample, from the msgspec type
#: :class:`bipedtele.telemetry.LeaderSample` (units in each ``description``): every field
#: but ``t`` is nullable (a delay estimate is null until it is warm, a non-finite value is
#: written as null, an older recording may lack a key).
LEADER_STATE_FIELDS: Final[dict[str, Schema]] = _leader_state_fields()

#: Keys of ``events`` maps (``docs/recording.md``, Events) and their JSON types.
EVENT_FIELDS: Final[dict[str, Schema]] = {
    "event": _t("string", "event name (start, pass, done, stop, fall, collision, ...)"),
    "t": _t(_NUM_OR_NULL, "when it happened [s]"),
    "operator": _t(["string", "null"], "operator model (start)"),
    "n": _t("integer", "pass number (pass), fall count (fall), step count (footfall)"),
    "side": _t("string", "left or right (pass)"),
    "elapsed_s": _t(_NUM_OR_NULL, "run length (done, stop) [s]"),
    "commands": _t("integer", "commands sent (commands_not_reaching)"),
    "tilt_rad": _t(_NUM_OR_NULL, "torso tilt (fall) [rad]"),
    "pose": {"type": "array", "items": _NUMBER, "description": "robot pose x, y, yaw (collision)"},
    "why": _t("string", "reason (watchdog_stop, operator_stop, walk_refused)"),
    "robot_t": _t(_NUM_OR_NULL, "robot (simulation) time (footfall) [s]"),
    "step_s": _t(_NUM_OR_NULL, "length of the step just ended (footfall) [s]"),
    "ref": {"type": "array", "items": _NUMBER, "description": "reference in use (footfall) [cm/s, deg/s]"},
}


def _value_schema(value: Any) -> Schema:
    """Return the (nullable) schema of one recorded value, judged from the value itself."""
    if value is None:
        return {}
    if isinstance(value, bool):
        return {"type": ["boolean", "null"]}
    if isinstance(value, int | float):
        return {"type": ["number", "null"]}
    if isinstance(value, str):
        return {"type": ["string", "null"]}
    if isinstance(value, bytes | bytearray | memoryview):
        return {**_BASE64, "type": ["string", "null"]}
    if isinstance(value, list | tuple):
        if value and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            return {"type": ["array", "null"], "items": {"type": ["number", "null"]}}
        return {"type": ["array", "null"]}
    if isinstance(value, dict):
        return {"type": ["object", "null"]}
    return {}


def sample_schema(
    name: str,
    sample: Mapping[str, Any],
    known: Mapping[str, Schema] | None = None,
    required: list[str] | None = None,
    description: str = "",
) -> Schema:
    """Return the schema of a channel of maps.

    ``known`` keys as given, every other key of ``sample`` (the first map written) typed
    from its value, all nullable.

    Parameters
    ----------
    name : str
        Schema name (its ``title``).
    sample : Mapping
        The first map written on the channel (plain values: numbers, strings, booleans,
        None, bytes, lists, dicts).
    known : Mapping, optional
        Fixed property schemas, e.g. :data:`LEADER_STATE_FIELDS`; they win over ``sample``.
    required : list of str, optional
        Keys every map has.
    description : str
        The schema's description.

    Returns
    -------
    dict
        An object schema that allows additional properties.
    """
    props = dict(known or {})
    for key, value in sample.items():
        if str(key) not in props:
            props[str(key)] = _value_schema(value)
    return _object(name, props, list(required or []), description=description, additional=True)


def leader_state_schema(sample: Mapping[str, Any] | None = None) -> Schema:
    """``bipedtele.LeaderState``: the :class:`~bipedtele.telemetry.LeaderSample` fields.

    Plus, for a channel written as maps, the first map's other keys (typed from their
    values); ``t`` is required, other keys are allowed.
    """
    return sample_schema(
        LEADER_STATE, sample or {}, LEADER_STATE_FIELDS, ["t"], description="The leader loop's sample (one per command)"
    )


def event_schema(sample: Mapping[str, Any]) -> Schema:
    """``bipedtele.Event``: :data:`EVENT_FIELDS` plus the first event's other keys."""
    return sample_schema(EVENTS, sample, EVENT_FIELDS, ["event"], description="A run event: {event: NAME, ...details}")
