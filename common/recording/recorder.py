"""Run recordings: every message sent and received, the leader's loop state and events, in MCAP.

:class:`Recorder` writes one recording: a caller queues each message without waiting; a
background thread encodes it on its channel (a JSON Schema registered on first use) and
writes MCAP chunks, flushed at least every ``flush_s`` seconds. The file format, and
reading a recording back (:func:`read_records`, :func:`read_metadata`,
:class:`RecordDecoder`, re-exported here), are in :mod:`bipedtele.recording.format`.

File names and opening a run's file: :mod:`bipedtele.recording.files`. A recorder creates its
file exclusively (it never overwrites one) and, when closed without a single message
recorded, removes it. With a live view (:mod:`bipedtele.recording.foxglovelive`) it also hands every
encoded message to it, or only to it (no file).

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
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import msgspec
from bipedtele import __version__
from bipedtele.link.messages import Message, VideoFrame
from bipedtele.recording import schemas
from bipedtele.recording.format import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    PAYLOAD_JSON,
    TOPIC_KEY,
    Record,
    RecordDecoder,
    RecordingError,
    message_to_dict,
    null_nonfinite,
    read_metadata,
    read_records,
)
from bipedtele.recording.foxglovelive import LiveView
from bipedtele.telemetry import numpy_hook
from mcap.writer import CompressionType, Writer

__all__ = [  # the reading API re-exported (docs/recording.md names it here)
    "Record",
    "RecordDecoder",
    "Recorder",
    "RecordingError",
    "message_to_dict",
    "read_metadata",
    "read_records",
]

LOG = logging.getLogger("bipedtele.recording.recorder")

PROFILE = "bipedtele"
_CHUNK_BYTES = 256 * 1024
_YIELD_NS = 50_000  # the writer thread releases the GIL at least this often [ns]


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


def _dataclass_dict(obj: Any) -> dict[str, Any]:
    if isinstance(obj, Message):
        return message_to_dict(obj)
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


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
    live : LiveView, optional
        Also hand every encoded message, on the same channel and schema, to this live
        view (:mod:`bipedtele.recording.foxglovelive`). With ``path`` None only to it: no file.

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
        path: str | Path | None,
        flush_s: float = 1.0,
        metadata: Mapping[str, Any] | None = None,
        *,
        jpeg_every: int = 1,
        max_pending: int = 200_000,
        live: LiveView | None = None,
    ) -> None:
        if not (math.isfinite(flush_s) and flush_s > 0):
            raise ValueError(f"flush_s must be > 0 s, got {flush_s!r}")
        if jpeg_every < 0:
            raise ValueError(f"jpeg_every must be >= 0, got {jpeg_every!r}")
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1, got {max_pending!r}")
        if path is None and live is None:
            raise ValueError("path: allowed: a file, or None with a live view")
        self.path = Path(path) if path is not None else None
        self.flush_s = float(flush_s)
        self.jpeg_every = int(jpeg_every)
        self.max_pending = int(max_pending)
        self.live = live
        #: True once :meth:`close` removed the file because nothing was recorded.
        self.removed = False
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        if self.path is not None:
            self._open_file(self.path, metadata)
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

    def _open_file(self, path: Path, metadata: Mapping[str, Any] | None) -> None:
        self._file = file = open(path, "xb")  # noqa: SIM115 - closed in close()
        try:
            self._writer = writer = Writer(
                file,
                chunk_size=_CHUNK_BYTES,
                compression=CompressionType.ZSTD,
            )
            writer.start(profile=PROFILE, library=f"bipedtele {__version__}")
            meta = {
                str(k): v if isinstance(v, str) else json.dumps(v, default=str) for k, v in (metadata or {}).items()
            }
            meta.setdefault("bipedtele_version", __version__)
            meta.setdefault("created_unix_s", repr(time.time()))
            writer.add_metadata(METADATA_NAME, meta)
            file.flush()
        except BaseException:  # a failed start leaves no file
            file.close()
            path.unlink(missing_ok=True)
            raise

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
                if self._writer is not None:
                    self._writer.finish()
        except Exception:
            LOG.exception("recorder: finishing %s failed", self.path)
        finally:
            if self.live is not None:
                self.live.close()
            if self._file is not None and self.path is not None:
                self._close_file(self._file, self.path)

    def _close_file(self, file: IO[bytes], path: Path) -> None:
        file.close()
        if self.written == 0:
            try:
                os.unlink(path)
                self.removed = True
                LOG.info("recorder: nothing recorded, removed %s", path)
            except OSError as exc:
                LOG.warning("recorder: cannot remove the empty %s (%s)", path, exc)

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

    def _register(
        self, key: tuple[str, Any], topic: str, schema: dict[str, Any], metadata: dict[str, str] | None = None
    ) -> int:
        """Register the channel ``key`` (its schema once per distinct schema)."""
        blob = json.dumps(schema, separators=(",", ":")).encode()
        name = str(schema["title"])
        if self._writer is not None:
            sid = self._schema_ids.get((name, blob))
            if sid is None:
                sid = self._writer.register_schema(name=name, encoding=schemas.SCHEMA_ENCODING, data=blob)
                self._schema_ids[(name, blob)] = sid
            cid = self._writer.register_channel(
                topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=sid, metadata=metadata or {}
            )
        else:
            cid = len(self._channels) + 1
        if self.live is not None:
            self.live.add_channel(cid, topic, name, schemas.SCHEMA_ENCODING, blob)
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
                "frame_id": frame.camera,
                "data": base64.b64encode(frame.jpeg).decode("ascii"),
                "format": "jpeg",
                **header,
            }
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
            text = PAYLOAD_JSON.encode(data)
        except ValueError:  # NaN or inf somewhere: null in JSON
            text = PAYLOAD_JSON.encode(null_nonfinite(data))
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
            if self._writer is not None:
                self._writer.add_message(channel_id=cid, log_time=t_log, data=payload, publish_time=t_recv)
            if self.live is not None:
                self.live.log(cid, payload, t_log)
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
                if dirty and now - last_flush >= self.flush_s - self._wake and self._writer is not None:
                    self._writer.flush()
                    self._count("flushes")
                    dirty = False
                    last_flush = now
            except Exception:  # disk full, ...: keep the program alive, say it once
                LOG.exception("recorder: writing %s failed; recording stops", self.path)
                self._failed = True
                return
