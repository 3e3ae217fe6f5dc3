"""Run recordings: every message sent and received, the leader's loop state and events, in MCAP.

File format
-----------
An MCAP file (https://mcap.dev) written with the ``mcap`` library, which Foxglove opens
with typed channels (``docs/recording.md``):

- one channel per topic (``cmd/sent``, ``feedback/recv``, ``leader/state``, ...), message
  encoding ``json``, each with a JSON Schema (schema encoding ``jsonschema``, built by
  :mod:`bipedtele.schemas`); each payload is a JSON object;
- a wire message (:class:`bipedtele.messages.Message`) is stored as its fields plus
  ``"v"`` (schema version) and ``"k"`` (kind), i.e. the same map that went over the wire,
  with ``bytes`` as base64; a :class:`~bipedtele.messages.VideoFrame` on a ``video/`` topic
  is a ``foxglove.CompressedImage`` (Foxglove's Image panel shows it), and a frame whose
  JPEG was thinned out goes to the channel ``TOPIC/header`` (read back as ``TOPIC``);
- the MCAP ``publish_time`` holds ``t_recv`` (receive time for ``*/recv`` topics, send time
  for ``*/sent`` topics, computation time otherwise) and ``log_time`` holds ``t_log`` (when
  the recorder was called), both as integer nanoseconds of ``time.time()``;
- a metadata record ``bipedtele`` holds the caller's ``metadata`` (non-string values as JSON);
- zstd-compressed chunks, closed and flushed to the OS at least every ``flush_s`` seconds so
  that a killed process loses at most about ``flush_s`` seconds; :func:`read_records` reads a
  truncated file up to the last complete chunk.

:func:`read_records` returns the same maps for every topic as before the JSON encoding
(bytes restored, the video mapped back) and still reads the older files whose channels are
``msgpack`` without a schema.

File names and life
-------------------
:func:`new_recording_path` gives ``FOLDER/ROLE-YYYYmmdd-HHMMSS-mmm.mcap`` (local time to the
millisecond; ``-1``, ``-2``, ... appended when taken). :class:`Recorder` creates its file
exclusively (it never overwrites one) and, when closed without a single message recorded,
removes it, so a run that failed at start leaves no empty file behind.
:func:`open_recording` combines the two and retries with the next name if another process
took the same one in between.

Topics and fields used by the leader, the follower and ``bipedtele report`` are listed in
``docs/recording.md``.
"""

from __future__ import annotations

import base64
import collections
import dataclasses
import json
import logging
import math
import os
import re
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import msgpack
import msgspec
from bipedtele import __version__, schemas
from bipedtele.messages import SCHEMA_VERSION, Message, VideoFrame, message_fields
from bipedtele.telemetry import numpy_hook
from mcap.exceptions import McapError
from mcap.records import Channel, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

__all__ = [
    "LEGACY_ENCODING",
    "MESSAGE_ENCODING",
    "METADATA_NAME",
    "Record",
    "RecordDecoder",
    "Recorder",
    "RecordingError",
    "new_recording_path",
    "open_recording",
    "read_metadata",
    "read_records",
    "recording_for_run",
]

LOG = logging.getLogger("bipedtele.recording")

MESSAGE_ENCODING = "json"
LEGACY_ENCODING = "msgpack"  # files written before the channels had schemas
METADATA_NAME = "bipedtele"
PROFILE = "bipedtele"
TOPIC_KEY = "bipedtele.topic"  # channel metadata: the topic read_records reports
_CHUNK_BYTES = 256 * 1024
_RECORD_SIZE_LIMIT = 64 * 1024 * 1024
_YIELD_NS = 50_000  # the writer thread releases the GIL at least this often [ns]


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


_SCALARS = frozenset((float, int, str, bool, type(None)))


def _plain(value: Any) -> Any:
    """Return a copy of ``value`` made of plain values.

    Numpy values and arrays, tuples and paths are converted, containers copied.

    Raises
    ------
    TypeError
        For anything else.
    """
    cls = value.__class__
    if cls in _SCALARS or cls is bytes:
        return value
    if cls is list or cls is tuple:
        return [_plain(v) for v in value]
    if cls is dict:
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, bool | int | float | str | bytes):  # subclasses (numpy float64, ...)
        return value
    if isinstance(value, bytearray | memoryview):
        return bytes(value)
    if hasattr(value, "tolist"):
        return _plain(value.tolist())
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    raise TypeError(f"cannot record a {type(value).__name__}")


def _json_default(obj: Any) -> Any:
    if isinstance(obj, bytes | bytearray | memoryview):
        return base64.b64encode(obj).decode("ascii")
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"cannot record a {type(obj).__name__}")


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no NaN or inf)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


_JSON = json.JSONEncoder(allow_nan=False, separators=(",", ":"), check_circular=False, default=_json_default)


def _dataclass_dict(obj: Any) -> dict[str, Any]:
    if isinstance(obj, Message):
        return message_to_dict(obj)
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


_ROLE = re.compile(r"^[A-Za-z0-9_]+(?:-[A-Za-z0-9_]+)*$")
_MAX_SUFFIX = 10_000


def new_recording_path(folder: str | Path, role: str, *, now: float | None = None) -> Path:
    """Return a recording file name in ``folder`` that no file has yet.

    ``FOLDER/ROLE-YYYYmmdd-HHMMSS-mmm.mcap`` (local time, milliseconds); when that name
    is taken, ``-1``, ``-2``, ... is appended before ``.mcap``. The file is not created:
    :class:`Recorder` creates it exclusively, so two processes that got the same name
    cannot overwrite each other (the second gets ``FileExistsError``; see
    :func:`open_recording`, which then takes the next name).

    Parameters
    ----------
    folder : str or Path
        Folder of the recordings (need not exist yet).
    role : str
        ``leader``, ``follower``, ...: letters, digits, ``_`` and inner ``-``.
    now : float, optional
        The time to stamp [s since the epoch]; ``time.time()`` when omitted.

    Raises
    ------
    ValueError
        ``role`` is not a plain name.
    """
    if not _ROLE.match(role):
        raise ValueError(f"role {role!r}: allowed: letters, digits, '_' and inner '-'")
    t = time.time() if now is None else now
    ms = int((t % 1.0) * 1000)
    stem = f"{role}-{time.strftime('%Y%m%d-%H%M%S', time.localtime(t))}-{ms:03d}"
    folder = Path(folder)
    path = folder / f"{stem}.mcap"
    n = 0
    while path.exists():
        n += 1
        if n > _MAX_SUFFIX:
            raise FileExistsError(f"{folder}: {_MAX_SUFFIX} recordings named {stem}-*.mcap")
        path = folder / f"{stem}-{n}.mcap"
    return path


def open_recording(folder: str | Path, role: str, **kwargs: Any) -> Recorder:
    """Return a :class:`Recorder` on a new file :func:`new_recording_path` names in ``folder``.

    Creates ``folder`` if needed. If another process creates the same name between the
    choice and the exclusive creation, the next free name is taken.

    Parameters
    ----------
    folder : str or Path
        Folder of the recordings.
    role : str
        The file name's prefix (``leader``, ``follower``).
    **kwargs
        :class:`Recorder` parameters (``flush_s``, ``metadata``, ``jpeg_every``, ...).

    Raises
    ------
    OSError
        The folder or the file cannot be created.
    """
    Path(folder).mkdir(parents=True, exist_ok=True)
    for _ in range(100):
        try:
            return Recorder(new_recording_path(folder, role), **kwargs)
        except FileExistsError:
            continue
    raise FileExistsError(f"{folder}: no free recording name for {role!r} after 100 tries")


def recording_for_run(record: Path | None, folder: str | Path, role: str, **kwargs: Any) -> Recorder:
    """Return the recording of one program run: ``record`` when given, else a new file in ``folder``.

    Parameters
    ----------
    record : Path or None
        The file the user asked for (``--record``); it must not exist.
    folder : str or Path
        Folder of the recordings (``[record] dir``) when ``record`` is None.
    role : str
        The new file's name prefix (``leader``, ``follower``).
    **kwargs
        :class:`Recorder` parameters.

    Raises
    ------
    ConfigError
        ``record`` exists, or the folder or file cannot be created (one line, exit 2).
    """
    from bipedtele.config import ConfigError

    try:
        if record is not None:
            record.parent.mkdir(parents=True, exist_ok=True)
            return Recorder(record, **kwargs)
        return open_recording(folder, role, **kwargs)
    except FileExistsError:
        raise ConfigError(f"--record {record}: the file exists; allowed: a new file (never overwritten)") from None
    except OSError as exc:
        raise ConfigError(
            f"recording {record or folder}: cannot create ({exc.strerror or exc}); allowed: a writable folder"
        ) from None


class Recorder:
    """Thread-safe MCAP writer of everything a leader or follower sends and receives.

    :meth:`write` only takes a snapshot of the message (a wire message by reference, a map
    copied) and appends it to a queue; a background thread encodes it (JSON, with the
    channel's schema registered on first use), writes the queue into MCAP chunks and closes
    a chunk and flushes the file at least every ``flush_s`` seconds. Callers never wait on
    the disk and never pay for the encoding.

    Parameters
    ----------
    path : str or Path
        Output file; created exclusively: an existing file is never overwritten
        (``FileExistsError``). Use :func:`new_recording_path` or :func:`open_recording`
        for a fresh name. Removed again by :meth:`close` when nothing was recorded.
    flush_s : float
        Longest time between two flushes [s]; a killed process loses at most about this
        much (plus 0.1 s).
    metadata : dict, optional
        Run description (config, role, robot id, ...) stored as MCAP metadata
        ``bipedtele``; values that are not strings are stored as JSON.
    jpeg_every : int
        On topics starting with ``video/``, keep the JPEG of every ``jpeg_every``-th frame
        and only the header (``jpeg`` emptied, ``jpeg_skipped`` true) of the others; 1 keeps
        every frame, 0 keeps none.
    max_pending : int
        Most messages waiting for the writer thread; beyond it new messages are dropped and
        counted (``stats["dropped_full"]``).

    Raises
    ------
    FileExistsError
        ``path`` exists already.
    OSError
        The file cannot be created.
    ValueError
        A parameter is out of range.

    Examples
    --------
    >>> with Recorder("run.mcap", metadata={"role": "leader"}) as rec:  # doctest: +SKIP
    ...     rec.write("events", {"event": "task_start"}, time.time())
    """

    def __init__(
        self,
        path: str | Path,
        flush_s: float = 1.0,
        metadata: Mapping[str, Any] | None = None,
        *,
        jpeg_every: int = 1,
        max_pending: int = 200_000,
    ) -> None:
        if not (math.isfinite(flush_s) and flush_s > 0):
            raise ValueError(f"flush_s must be > 0 s, got {flush_s!r}")
        if jpeg_every < 0:
            raise ValueError(f"jpeg_every must be >= 0, got {jpeg_every!r}")
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1, got {max_pending!r}")
        self.path = Path(path)
        self.flush_s = float(flush_s)
        self.jpeg_every = int(jpeg_every)
        self.max_pending = int(max_pending)
        #: True once :meth:`close` removed the file because nothing was recorded.
        self.removed = False
        self._file: IO[bytes] = open(self.path, "xb")  # noqa: SIM115 - closed in close()
        try:
            self._writer = Writer(
                self._file,
                chunk_size=_CHUNK_BYTES,
                compression=CompressionType.ZSTD,
            )
            self._writer.start(profile=PROFILE, library=f"bipedtele {__version__}")
            meta = {
                str(k): v if isinstance(v, str) else json.dumps(v, default=str) for k, v in (metadata or {}).items()
            }
            meta.setdefault("bipedtele_version", __version__)
            meta.setdefault("created_unix_s", repr(time.time()))
            self._writer.add_metadata(METADATA_NAME, meta)
            self._file.flush()
        except BaseException:  # a failed start leaves no file
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise
        self._channels: dict[tuple[str, Any], int] = {}
        self._schema_ids: dict[tuple[str, bytes], int] = {}
        self._pending: collections.deque[tuple[str, Any, int, int]] = collections.deque()
        self._lock = threading.Lock()  # counters and the video frame counts
        self._video_count: dict[str, int] = {}
        self._closed = False
        self._failed = False
        self._stats = {
            "written": 0,
            "dropped_full": 0,
            "dropped_closed": 0,
            "dropped_unencodable": 0,
            "jpeg_skipped": 0,
            "nonfinite_nulled": 0,
            "flushes": 0,
        }
        self._logged_bad: set[str] = set()
        self._stop = threading.Event()
        self._wake = min(0.1, self.flush_s / 2)
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ public

    @property
    def stats(self) -> dict[str, int]:
        """Counters of the writer.

        ``written``, ``dropped_full``, ``dropped_closed``, ``dropped_unencodable``,
        ``jpeg_skipped``, ``nonfinite_nulled`` (messages in which a NaN or inf was written
        as null), ``flushes``.
        """
        with self._lock:
            return dict(self._stats)

    def write(
        self,
        topic: str,
        msg: Message | msgspec.Struct | Mapping[str, Any],
        t_recv: float,
        t_log: float | None = None,
    ) -> bool:
        """Queue one message for the file. Cheap, never blocks on I/O, never raises for data.

        Parameters
        ----------
        topic : str
            Channel name (``cmd/sent``, ``feedback/recv``, ``video/recv``, ``leader/state``,
            ``events``, ...; ``docs/recording.md`` lists those the programs write).
        msg : Message, msgspec Struct, dataclass or dict
            A wire message (kept by reference: messages are values, never changed after
            sending), another msgspec Struct such as the leader's
            :class:`~bipedtele.telemetry.LeaderSample` (copied, recorded as its map on the
            channel's schema), another frozen dataclass, or a map of plain values (numbers, strings,
            None, bytes, lists, dicts; numpy values are converted). A map is copied at once
            (a flat map of scalars with one dict copy, anything else deeply), so the caller
            may reuse it afterwards.
        t_recv : float
            Receive time (send time for ``*/sent``) [s], ``time.time()`` clock.
        t_log : float, optional
            Recording time [s]; ``time.time()`` when omitted.

        Returns
        -------
        bool
            False when the message was dropped (closed recorder, full queue, a map value
            that cannot be recorded); drops are counted in :attr:`stats`. A message the
            writer thread then fails to encode is dropped there and counted as well
            (``dropped_unencodable``). Map keys are recorded as strings (JSON).
        """
        if self._closed or self._failed:
            self._count("dropped_closed")
            return False
        if len(self._pending) >= self.max_pending:
            self._count("dropped_full")
            self._log_once("full", "recorder queue full: dropping messages")
            return False
        try:
            if isinstance(msg, Message):
                obj: Any = msg
            elif isinstance(msg, msgspec.Struct):
                obj = msgspec.structs.replace(msg)  # the leader's sample: a shallow copy (scalars)
            elif msg.__class__ is dict and _SCALARS.issuperset(map(type, msg.values())):
                obj = dict(msg)  # a flat map: one C-level copy
            elif dataclasses.is_dataclass(msg) and not isinstance(msg, type):
                params = getattr(type(msg), "__dataclass_params__", None)
                obj = msg if params is not None and params.frozen else _plain(_dataclass_dict(msg))
            elif isinstance(msg, Mapping):
                obj = _plain(msg)
            else:
                raise TypeError(f"a message or a map, not a {type(msg).__name__}")
            t_l = time.time() if t_log is None else t_log
            item = (str(topic), obj, _ns(float(t_recv)), _ns(float(t_l)))
        except (TypeError, ValueError, OverflowError) as exc:
            self._count("dropped_unencodable")
            self._log_once(f"bad:{topic}", f"cannot record a message on {topic!r}: {exc}")
            return False
        self._pending.append(item)
        return True

    @property
    def written(self) -> int:
        """Messages written to the file so far."""
        with self._lock:
            return self._stats["written"]

    def close(self) -> None:
        """Write what is queued, finish the MCAP summary and close the file. Idempotent.

        A recording in which no message was written is removed (:attr:`removed` becomes
        True): a run that ended before recording anything leaves no file behind.
        """
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join()
        try:
            if not self._failed:
                self._drain()
                self._writer.finish()
        except Exception:
            LOG.exception("recorder: finishing %s failed", self.path)
        finally:
            self._file.close()
            if self.written == 0:
                try:
                    os.unlink(self.path)
                    self.removed = True
                    LOG.info("recorder: nothing recorded, removed %s", self.path)
                except OSError as exc:
                    LOG.warning("recorder: cannot remove the empty %s (%s)", self.path, exc)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    def _count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._stats[key] += n

    def _log_once(self, key: str, text: str) -> None:
        if key not in self._logged_bad:
            self._logged_bad.add(key)
            LOG.warning("%s (further ones counted, not logged)", text)

    def _keep_jpeg(self, topic: str) -> bool:
        """Whether this frame of ``topic`` keeps its JPEG (every ``jpeg_every``-th one)."""
        n = self._video_count.get(topic, 0)  # the writer thread alone counts
        self._video_count[topic] = n + 1
        keep = self.jpeg_every > 0 and n % self.jpeg_every == 0
        if not keep:
            self._count("jpeg_skipped")
        return keep

    def _register(self, key: tuple[str, Any], topic: str, schema: dict[str, Any],
                  metadata: dict[str, str] | None = None) -> int:  # fmt: skip
        """Register the channel ``key`` (its schema once per distinct schema)."""
        blob = json.dumps(schema, separators=(",", ":")).encode()
        name = str(schema["title"])
        sid = self._schema_ids.get((name, blob))
        if sid is None:
            sid = self._writer.register_schema(name=name, encoding=schemas.SCHEMA_ENCODING, data=blob)
            self._schema_ids[(name, blob)] = sid
        cid = self._writer.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=sid, metadata=metadata or {}
        )
        self._channels[key] = cid
        return cid

    def _video(self, topic: str, frame: VideoFrame) -> tuple[int, dict[str, Any]]:
        """Return a frame as ``foxglove.CompressedImage``, or its header alone when thinned out."""
        header = message_to_dict(frame)
        del header["jpeg"]
        if self._keep_jpeg(topic) and frame.jpeg:
            key: tuple[str, Any] = (topic, schemas.COMPRESSED_IMAGE)
            cid = self._channels.get(key)
            if cid is None:
                cid = self._register(key, topic, schemas.compressed_image_schema())
            t = max(0.0, frame.t_capture)
            sec = int(t)
            data = {
                "timestamp": {"sec": sec, "nsec": min(999_999_999, round((t - sec) * 1e9))},
                "frame_id": frame.camera, "data": base64.b64encode(frame.jpeg).decode("ascii"),
                "format": "jpeg", **header,
            }  # fmt: skip
            return cid, data
        key = (topic, schemas.VIDEO_HEADER)
        cid = self._channels.get(key)
        if cid is None:
            cid = self._register(key, f"{topic}/header", schemas.video_header_schema(), {TOPIC_KEY: topic})
        header["jpeg_skipped"] = bool(frame.jpeg)
        return cid, header

    def _map_channel(self, topic: str, data: dict[str, Any]) -> int:
        key = (topic, dict)
        cid = self._channels.get(key)
        if cid is None:
            if topic == "leader/state":
                schema = schemas.leader_state_schema(data)
            elif topic == "events":
                schema = schemas.event_schema(data)
            else:
                schema = schemas.sample_schema("bipedtele.Map", data, description=f"maps on {topic}")
            cid = self._register(key, topic, schema)
        return cid

    def _encode(self, topic: str, obj: Any) -> tuple[int, bytes]:
        """Return the channel and the JSON payload of one queued message (writer thread)."""
        if isinstance(obj, msgspec.Struct) and not isinstance(obj, Message):
            obj = msgspec.to_builtins(obj, enc_hook=numpy_hook)  # e.g. a LeaderSample: its map
        if isinstance(obj, dict):
            data = obj
            if topic.startswith("video/") and "jpeg" in data and not self._keep_jpeg(topic):
                data = {**data, "jpeg": b"", "jpeg_skipped": True}
            cid = self._map_channel(topic, data)
        elif isinstance(obj, VideoFrame) and topic.startswith("video/"):
            cid, data = self._video(topic, obj)
        else:
            key = (topic, type(obj))
            known = self._channels.get(key)
            cls: type = type(obj)
            cid = known if known is not None else self._register(key, topic, schemas.dataclass_schema(cls))
            data = _dataclass_dict(obj)
        try:
            text = _JSON.encode(data)
        except ValueError:  # NaN or inf somewhere: null in JSON
            text = _JSON.encode(_finite(data))
            self._count("nonfinite_nulled")
        return cid, text.encode()

    def _drain(self) -> int:
        n = 0
        last_yield = time.perf_counter_ns()
        while True:
            try:
                topic, obj, t_recv, t_log = self._pending.popleft()
            except IndexError:
                break
            try:
                cid, payload = self._encode(topic, obj)
            except (TypeError, ValueError, OverflowError, RecursionError) as exc:
                self._count("dropped_unencodable")
                self._log_once(f"bad:{topic}", f"cannot record a message on {topic!r}: {exc}")
                continue
            self._writer.add_message(channel_id=cid, log_time=t_log, data=payload, publish_time=t_recv)
            n += 1
            now = time.perf_counter_ns()
            if now - last_yield >= _YIELD_NS:
                time.sleep(0)  # let the control loop have the GIL (it may be waiting)
                last_yield = time.perf_counter_ns()
        if n:
            self._count("written", n)
        return n

    def _run(self) -> None:
        last_flush = time.monotonic()
        dirty = False
        while not self._stop.wait(self._wake):
            try:
                dirty |= self._drain() > 0
                now = time.monotonic()
                if dirty and now - last_flush >= self.flush_s - self._wake:
                    self._writer.flush()
                    self._count("flushes")
                    dirty = False
                    last_flush = now
            except Exception:  # disk full, ...: keep the program alive, say it once
                LOG.exception("recorder: writing %s failed; recording stops", self.path)
                self._failed = True
                return


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
        :class:`~bipedtele.messages.VideoFrame` map, on its own topic). Messages whose
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
