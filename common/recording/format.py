"""The recording format: the maps messages are recorded as, their JSON payloads, and reading them back.

File format
-----------
An MCAP file (https://mcap.dev) written by :class:`bipedtele.recording.recorder.Recorder` with the
``mcap`` library, which Foxglove opens with typed channels (``docs/recording.md``):

- one channel per topic (``cmd/sent``, ``feedback/recv``, ``leader/state``, ...), message
  encoding ``json``, each with a JSON Schema (schema encoding ``jsonschema``, built by
  :mod:`bipedtele.recording.schemas`); each payload is a JSON object (:data:`PAYLOAD_JSON`, a NaN or
  inf written as null);
- a wire message (:class:`bipedtele.link.messages.Message`) is stored as its fields plus
  ``"v"`` (schema version) and ``"k"`` (kind), i.e. the same map that went over the wire
  (:func:`message_to_dict`), with ``bytes`` as base64; a
  :class:`~bipedtele.link.messages.VideoFrame` on a ``video/`` topic is a
  ``foxglove.CompressedImage`` (Foxglove's Image panel shows it), and a frame whose JPEG
  was thinned out goes to the channel ``TOPIC/header`` (read back as ``TOPIC``);
- the MCAP ``publish_time`` holds ``t_recv`` (receive time for ``*/recv`` topics, send time
  for ``*/sent`` topics, computation time otherwise) and ``log_time`` holds ``t_log`` (when
  the recorder was called), both as integer nanoseconds of ``time.time()``;
- a metadata record ``bipedtele`` holds the caller's ``metadata`` (non-string values as JSON);
- zstd-compressed chunks, closed and flushed to the OS at least every ``flush_s`` seconds so
  that a killed process loses at most about ``flush_s`` seconds; :func:`read_records` reads a
  truncated file up to the last complete chunk.

Reading
-------
:func:`read_records` returns the same maps for every topic as before the JSON encoding
(bytes restored, the video mapped back) and still reads the older files whose channels are
``msgpack`` without a schema; :class:`RecordDecoder` does the same record by record, for
readers that follow a file as it is written.
"""

from __future__ import annotations

import base64
import json
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import msgpack
from bipedtele.link.messages import SCHEMA_VERSION, Message, message_fields
from bipedtele.recording import schemas
from mcap.exceptions import McapError
from mcap.records import Channel, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader

__all__ = [
    "LEGACY_ENCODING",
    "MESSAGE_ENCODING",
    "METADATA_NAME",
    "PAYLOAD_JSON",
    "TOPIC_KEY",
    "Record",
    "RecordDecoder",
    "RecordingError",
    "message_to_dict",
    "null_nonfinite",
    "read_metadata",
    "read_records",
]

LOG = logging.getLogger("bipedtele.recording.recorder")  # the name these log lines always had

MESSAGE_ENCODING = "json"
LEGACY_ENCODING = "msgpack"  # files written before the channels had schemas
METADATA_NAME = "bipedtele"
TOPIC_KEY = "bipedtele.topic"  # channel metadata: the topic read_records reports
_RECORD_SIZE_LIMIT = 64 * 1024 * 1024


class RecordingError(Exception):
    """A recording cannot be read at all (missing, empty, not an MCAP file)."""


@dataclass(frozen=True)
class Record:
    """One recorded message.

    Attributes
    ----------
    topic : str
        Channel name, e.g. ``feedback/recv``.
    t_recv : float
        Receive (or send, for ``*/sent``) time [s], ``time.time()`` clock of the recorder.
    data : dict
        The map that was recorded (bytes fields as bytes, whatever the file's encoding).
    t_log : float
        When the recorder was called [s].
    """

    topic: str
    t_recv: float
    data: dict[str, Any]
    t_log: float = 0.0


def _fields(cls: type[Message]) -> tuple[str, ...]:
    return message_fields(cls)


_FIELD_CACHE: dict[type[Message], tuple[str, ...]] = {}


def message_to_dict(msg: Message) -> dict[str, Any]:
    """Return the map a wire message is recorded as: its fields plus ``v`` and ``k``."""
    names = _FIELD_CACHE.get(type(msg))
    if names is None:
        names = _FIELD_CACHE.setdefault(type(msg), _fields(type(msg)))
    out: dict[str, Any] = {"v": SCHEMA_VERSION, "k": msg.KIND}
    for name in names:
        out[name] = getattr(msg, name)
    return out


def _json_default(obj: Any) -> Any:
    if isinstance(obj, bytes | bytearray | memoryview):
        return base64.b64encode(obj).decode("ascii")
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"cannot record a {type(obj).__name__}")


def null_nonfinite(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no NaN or inf)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: null_nonfinite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [null_nonfinite(v) for v in value]
    return value


#: The encoder of the JSON payloads: compact, bytes as base64, numpy values as lists; raises
#: ValueError on a NaN or inf (the writer then encodes :func:`null_nonfinite` of the map).
PAYLOAD_JSON = json.JSONEncoder(allow_nan=False, separators=(",", ":"), check_circular=False, default=_json_default)


# ---------------------------------------------------------------------- reading


def _open_stream(path: str | Path) -> IO[bytes]:
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed by the caller
    except OSError as exc:
        raise RecordingError(f"cannot open {path}: {exc.strerror or exc}") from None
    head = f.read(8)
    f.seek(0)
    if head != b"\x89MCAP0\r\n":
        f.close()
        raise RecordingError(f"{path} is not an MCAP recording (bad or missing header)")
    return f


def _iter_raw(path: str | Path) -> Iterator[Any]:
    """MCAP records of a file, stopping quietly (with a log line) at a cut or corruption."""
    f = _open_stream(path)
    with f:
        reader = StreamReader(f, validate_crcs=True, record_size_limit=_RECORD_SIZE_LIMIT)
        try:
            yield from reader.records
        except (McapError, ValueError, EOFError, MemoryError, OSError) as exc:
            LOG.info("%s: read up to byte %d (%s: truncated?)", path, f.tell(), type(exc).__name__)
        except Exception as exc:  # zstd errors and the like from a cut chunk
            LOG.info("%s: read up to byte %d (%s)", path, f.tell(), type(exc).__name__)


@dataclass(frozen=True)
class _ChannelCodec:
    """How to turn one channel's payloads back into the recorded maps."""

    topic: str  # the topic read_records reports
    encoding: str
    image: bool = False  # foxglove.CompressedImage of a VideoFrame
    header: bool = False  # a VideoFrame header recorded without its JPEG
    base64_keys: tuple[str, ...] = ()


def _codec(channel: Channel, schema: Schema | None) -> _ChannelCodec:
    topic = channel.metadata.get(TOPIC_KEY, channel.topic)
    if channel.message_encoding != MESSAGE_ENCODING or schema is None:
        return _ChannelCodec(topic, channel.message_encoding)
    b64: tuple[str, ...] = ()
    try:
        props = json.loads(schema.data).get("properties", {})
        b64 = tuple(k for k, v in props.items() if isinstance(v, dict) and v.get("contentEncoding") == "base64")
    except (ValueError, AttributeError):
        LOG.info("channel %s: schema %s is not JSON; bytes fields stay base64", topic, schema.name)
    if schema.name == schemas.COMPRESSED_IMAGE:
        return _ChannelCodec(topic, MESSAGE_ENCODING, image=True, base64_keys=tuple(k for k in b64 if k != "data"))
    return _ChannelCodec(topic, MESSAGE_ENCODING, header=schema.name == schemas.VIDEO_HEADER, base64_keys=b64)


def _decode(codec: _ChannelCodec, payload: bytes) -> dict[str, Any] | None:
    if codec.encoding == LEGACY_ENCODING:
        data = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        return data if isinstance(data, dict) else None
    if codec.encoding != MESSAGE_ENCODING:
        return None
    data = json.loads(payload)
    if not isinstance(data, dict):
        return None
    for key in codec.base64_keys:
        value = data.get(key)
        if isinstance(value, str):
            data[key] = base64.b64decode(value, validate=True)
    if codec.image and data.get("k") == "video":  # back to the VideoFrame map
        data.pop("timestamp", None)
        data.pop("frame_id", None)
        data.pop("format", None)
        data["jpeg"] = base64.b64decode(data.pop("data", ""), validate=True)
    elif codec.header:
        data["jpeg"] = b""
        if not data.get("jpeg_skipped"):
            data.pop("jpeg_skipped", None)
    return data


class RecordDecoder:
    """Turns the MCAP records of a recording, in file order, into ``(topic, map)`` pairs.

    Reads both the JSON channels with schemas that :class:`Recorder` writes and the
    ``msgpack`` channels of older files; used by :func:`read_records` and by readers that
    follow a file as it is written.

    Attributes
    ----------
    bad : int
        Messages skipped so far (unknown channel or encoding, undecodable payload).

    Examples
    --------
    >>> dec = RecordDecoder()  # doctest: +SKIP
    >>> for rec in StreamReader(f).records:  # doctest: +SKIP
    ...     got = dec.feed(rec)  # (topic, data) for a message, None for other records
    """

    def __init__(self) -> None:
        self._schemas: dict[int, Schema] = {}
        self._codecs: dict[int, _ChannelCodec] = {}
        self.bad = 0

    def feed(self, rec: Any) -> tuple[str, dict[str, Any]] | None:
        """Take one MCAP record; for a decodable message, its topic and map."""
        if isinstance(rec, McapMessage):
            codec = self._codecs.get(rec.channel_id)
            if codec is None:
                self.bad += 1
                return None
            try:
                data = _decode(codec, rec.data)
            except Exception:  # garbage: JSON, base64 and msgpack raise many types
                data = None
            if data is None:
                self.bad += 1
                return None
            return codec.topic, data
        if isinstance(rec, Schema):
            self._schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            self._codecs[rec.id] = _codec(rec, self._schemas.get(rec.schema_id))
        return None


def read_records(path: str | Path) -> Iterator[Record]:
    """Every message of a recording, in file order; a truncated file yields up to the cut.

    Parameters
    ----------
    path : str or Path
        An MCAP file written by :class:`Recorder` (possibly cut short by a crash), JSON
        with schemas or, from before, msgpack.

    Yields
    ------
    Record
        The maps as they were recorded (bytes as bytes; a video frame as its
        :class:`~bipedtele.link.messages.VideoFrame` map, on its own topic). Messages whose
        payload could not be decoded are skipped (and logged once).

    Raises
    ------
    RecordingError
        When the file is missing, unreadable or not an MCAP file (raised on the first
        ``next()``).
    """
    dec = RecordDecoder()
    for rec in _iter_raw(path):
        got = dec.feed(rec)
        if got is not None:
            yield Record(got[0], rec.publish_time / 1e9, got[1], rec.log_time / 1e9)
    if dec.bad:
        LOG.warning("%s: skipped %d undecodable messages", path, dec.bad)


def read_metadata(path: str | Path) -> dict[str, str]:
    """Return the ``bipedtele`` metadata map of a recording (empty when absent).

    Raises
    ------
    RecordingError
        When the file is missing or not an MCAP file.
    """
    out: dict[str, str] = {}
    for rec in _iter_raw(path):
        if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
            out.update(rec.metadata)
            break
        if isinstance(rec, McapMessage):
            break
    return out
