"""Repairing a recording cut short (``kill -9``, power loss) so that any MCAP tool opens it.

A recording cut mid-write has no footer and no summary, and its last chunk is partial: the
project's own reader (:func:`bipedtele.recording.format.read_records`) reads it up to the last
complete chunk, but the standard MCAP reader and tools that rely on the summary (Foxglove)
may open it with no message at all. :func:`repair` reads every complete record in file
order (CRCs checked, stopping quietly at the cut) and writes them into a new, complete
MCAP file: the same header profile, schemas, channels, messages (times, sequence numbers
and payloads unchanged), metadata and attachments, then the summary and the footer.

``bipedtele record repair F.mcap`` keeps the cut file as ``F.mcap.cut`` and writes the
repaired one at ``F.mcap`` (``--output`` for another name); a complete file is left as it
is.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

from bipedtele.recording.format import RecordingError, _iter_raw
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

__all__ = ["RepairResult", "is_complete", "repair"]

LOG = logging.getLogger("bipedtele.recording.recorder")
_CHUNK_BYTES = 256 * 1024


@dataclass(frozen=True)
class RepairResult:
    """What :func:`repair` did: the files and what it kept."""

    source: Path
    output: Path
    kept_as: Path | None  # the cut file's new name (in-place repair), else None
    messages: int
    channels: int
    complete: bool  # the source was complete already: nothing written


def is_complete(path: str | Path) -> bool:
    """Return whether ``path`` ends with a footer and a readable summary (what tools need)."""
    try:
        with open(path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:  # a cut file: no footer, or garbage where it should be
        return False


def _copy(source: Path, out: Path) -> tuple[int, int]:
    """Write every complete record of ``source`` into a new MCAP file ``out``; return (messages, channels)."""
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    messages = 0
    with open(out, "xb") as f:
        writer = Writer(f, chunk_size=_CHUNK_BYTES, compression=CompressionType.ZSTD)
        started = False
        for rec in _iter_raw(source):
            if isinstance(rec, Header):
                writer.start(profile=rec.profile, library=rec.library or "bipedtele record repair")
                started = True
                continue
            if not started:
                raise RecordingError(f"{source}: no MCAP header record")
            if isinstance(rec, Schema) and rec.id not in schema_ids:
                schema_ids[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in channel_ids:
                sid = schema_ids.get(rec.schema_id, 0)
                channel_ids[rec.id] = writer.register_channel(rec.topic, rec.message_encoding, sid, dict(rec.metadata))
            elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                writer.add_message(channel_ids[rec.channel_id], rec.log_time, rec.data, rec.publish_time, rec.sequence)
                messages += 1
            elif isinstance(rec, Metadata):
                writer.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Attachment):
                writer.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
        if not started:
            raise RecordingError(f"{source}: no MCAP header record")
        writer.finish()
        f.flush()
        os.fsync(f.fileno())
    return messages, len(channel_ids)


def repair(source: str | Path, output: str | Path | None = None) -> RepairResult:
    """Make a complete MCAP file of a cut recording (see the module docstring).

    Parameters
    ----------
    source : str or Path
        The recording (cut or not).
    output : str or Path, optional
        Where to write the repaired file (must not exist). None: in place, the cut file
        kept as ``SOURCE.cut``.

    Raises
    ------
    RecordingError
        ``source`` is not an MCAP recording, or the output (or ``SOURCE.cut``) exists.
    """
    src = Path(source)
    if is_complete(src):
        return RepairResult(src, src, None, 0, 0, complete=True)
    in_place = output is None
    out = src.with_name(src.name + ".repairing") if in_place else Path(output)  # type: ignore[arg-type]
    kept = src.with_name(src.name + ".cut") if in_place else None
    for p in (out, kept):
        if p is not None and p.exists():
            raise RecordingError(f"{p} exists; allowed: a new file (never overwritten)")
    try:
        messages, channels = _copy(src, out)
    except FileExistsError:
        raise RecordingError(f"{out} exists; allowed: a new file (never overwritten)") from None
    except BaseException:
        out.unlink(missing_ok=True)
        raise
    if kept is not None:
        os.replace(src, kept)
        os.replace(out, src)
        out = src
    LOG.info("%s: %d messages on %d channels written to %s", src, messages, channels, out)
    return RepairResult(src, out, kept, messages, channels, complete=False)
