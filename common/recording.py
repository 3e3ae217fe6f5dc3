"""Run recordings: every message sent and received, the leader's loop state and events, in MCAP.

File format
-----------
An MCAP file (https://mcap.dev) written with the ``mcap`` library:

- one channel per topic (``cmd/sent``, ``feedback/recv``, ``leader/state``, ...), message
  encoding ``msgpack`` (no schema); each payload is a msgpack map;
- a wire message (:class:`bipedtele.messages.Message`) is stored as its fields plus
  ``"v"`` (schema version) and ``"k"`` (kind), i.e. the same map that went over the wire;
- the MCAP ``publish_time`` holds ``t_recv`` (receive time for ``*/recv`` topics, send time
  for ``*/sent`` topics, computation time otherwise) and ``log_time`` holds ``t_log`` (when
  the recorder was called), both as integer nanoseconds of ``time.time()``;
- a metadata record ``bipedtele`` holds the caller's ``metadata`` (non-string values as JSON);
- zstd-compressed chunks, closed and flushed to the OS at least every ``flush_s`` seconds so
  that a killed process loses at most about ``flush_s`` seconds; :func:`read_records` reads a
  truncated file up to the last complete chunk.

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
from bipedtele import __version__
from bipedtele.messages import SCHEMA_VERSION, Message
from mcap.exceptions import McapError
from mcap.records import Channel, Metadata
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

__all__ = [
    "MESSAGE_ENCODING",
    "METADATA_NAME",
    "Record",
    "Recorder",
    "RecordingError",
    "new_recording_path",
    "open_recording",
    "read_metadata",
    "read_records",
    "recording_for_run",
]

LOG = logging.getLogger("bipedtele.recording")

MESSAGE_ENCODING = "msgpack"
METADATA_NAME = "bipedtele"
PROFILE = "bipedtele"
_CHUNK_BYTES = 256 * 1024
_RECORD_SIZE_LIMIT = 64 * 1024 * 1024
_YIELD_EVERY = 32  # messages the writer thread adds before it releases the GIL


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
        The msgpack map that was recorded.
    t_log : float
        When the recorder was called [s].
    """

    topic: str
    t_recv: float
    data: dict[str, Any]
    t_log: float = 0.0


def _fields(cls: type[Message]) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


_FIELD_CACHE: dict[type[Message], tuple[str, ...]] = {}


def message_to_dict(msg: Message) -> dict[str, Any]:
    """The map a wire message is recorded as: its fields plus ``v`` and ``k``."""
    names = _FIELD_CACHE.get(type(msg))
    if names is None:
        names = _FIELD_CACHE.setdefault(type(msg), _fields(type(msg)))
    out: dict[str, Any] = {"v": SCHEMA_VERSION, "k": msg.KIND}
    for name in names:
        out[name] = getattr(msg, name)
    return out


def _default(obj: Any) -> Any:
    """msgpack fallback: numpy scalars/arrays, tuples inside containers, paths."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot record a {type(obj).__name__}")


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


_ROLE = re.compile(r"^[A-Za-z0-9_]+(?:-[A-Za-z0-9_]+)*$")
_MAX_SUFFIX = 10_000


def new_recording_path(folder: str | Path, role: str, *, now: float | None = None) -> Path:
    """A recording file name in ``folder`` that no file has yet.

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
    """A :class:`Recorder` on a new file :func:`new_recording_path` names in ``folder``.

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
    """The recording of one program run: ``record`` when given, else a new file in ``folder``.

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

    :meth:`write` only serialises the message (msgpack) and appends it to a queue; a
    background thread writes the queue into MCAP chunks and closes a chunk and flushes
    the file at least every ``flush_s`` seconds. Callers never wait on the disk.

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
                str(k): v if isinstance(v, str) else json.dumps(v, default=str)
                for k, v in (metadata or {}).items()
            }
            meta.setdefault("bipedtele_version", __version__)
            meta.setdefault("created_unix_s", repr(time.time()))
            self._writer.add_metadata(METADATA_NAME, meta)
            self._file.flush()
        except BaseException:  # a failed start leaves no file
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise
        self._channels: dict[str, int] = {}
        self._pending: collections.deque[tuple[str, bytes, int, int]] = collections.deque()
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
        """Counters: ``written``, ``dropped_full``, ``dropped_closed``,
        ``dropped_unencodable``, ``jpeg_skipped``, ``flushes``."""
        with self._lock:
            return dict(self._stats)

    def write(
        self,
        topic: str,
        msg: Message | Mapping[str, Any],
        t_recv: float,
        t_log: float | None = None,
    ) -> bool:
        """Queue one message for the file. Cheap, never blocks on I/O, never raises for data.

        Parameters
        ----------
        topic : str
            Channel name (``cmd/sent``, ``feedback/recv``, ``video/recv``, ``leader/state``,
            ``events``, ...; ``docs/recording.md`` lists those the programs write).
        msg : Message or dict
            A wire message or a map of msgpack-able values (numbers, strings, bytes, lists,
            dicts; numpy values are converted). The map is serialised at once, so the caller
            may reuse it afterwards.
        t_recv : float
            Receive time (send time for ``*/sent``) [s], ``time.time()`` clock.
        t_log : float, optional
            Recording time [s]; ``time.time()`` when omitted.

        Returns
        -------
        bool
            False when the message was dropped (closed recorder, full queue, value that
            cannot be serialised); drops are counted in :attr:`stats`.
        """
        if self._closed or self._failed:
            self._count("dropped_closed")
            return False
        if len(self._pending) >= self.max_pending:
            self._count("dropped_full")
            self._log_once("full", "recorder queue full: dropping messages")
            return False
        try:
            data = message_to_dict(msg) if isinstance(msg, Message) else dict(msg)
            if topic.startswith("video/") and "jpeg" in data:
                data = self._thin_video(topic, data)
            payload = msgpack.packb(data, use_bin_type=True, default=_default)
            t_l = time.time() if t_log is None else t_log
            item = (str(topic), payload, _ns(float(t_recv)), _ns(float(t_l)))
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

    def _thin_video(self, topic: str, data: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            n = self._video_count.get(topic, 0)
            self._video_count[topic] = n + 1
        keep = self.jpeg_every > 0 and n % self.jpeg_every == 0
        if keep:
            return data
        self._count("jpeg_skipped")
        data = dict(data)
        data["jpeg"] = b""
        data["jpeg_skipped"] = True
        return data

    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._writer.register_channel(
                topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=0
            )
            self._channels[topic] = cid
        return cid

    def _drain(self) -> int:
        n = 0
        while True:
            try:
                topic, payload, t_recv, t_log = self._pending.popleft()
            except IndexError:
                break
            self._writer.add_message(
                channel_id=self._channel(topic),
                log_time=t_log,
                data=payload,
                publish_time=t_recv,
            )
            n += 1
            if n % _YIELD_EVERY == 0:
                time.sleep(0)  # let the control loop have the GIL (it may be waiting)
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


def read_records(path: str | Path) -> Iterator[Record]:
    """Every message of a recording, in file order; a truncated file yields up to the cut.

    Parameters
    ----------
    path : str or Path
        An MCAP file written by :class:`Recorder` (possibly cut short by a crash).

    Yields
    ------
    Record
        Messages whose payload could not be decoded are skipped (and logged once).

    Raises
    ------
    RecordingError
        When the file is missing, unreadable or not an MCAP file (raised on the first
        ``next()``).
    """
    topics: dict[int, str] = {}
    bad = 0
    for rec in _iter_raw(path):
        if isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, McapMessage):
            topic = topics.get(rec.channel_id)
            if topic is None:
                bad += 1
                continue
            try:
                data = msgpack.unpackb(rec.data, raw=False, strict_map_key=False)
            except Exception:
                bad += 1
                continue
            if not isinstance(data, dict):
                bad += 1
                continue
            yield Record(topic, rec.publish_time / 1e9, data, rec.log_time / 1e9)
    if bad:
        LOG.warning("%s: skipped %d undecodable messages", path, bad)


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``bipedtele`` metadata map of a recording (empty when absent).

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
