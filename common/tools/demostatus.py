"""The demo's live status line, read from the leader's recording as it is written.

The leader's recorder closes an MCAP chunk and flushes the file about once a second
(``[record] flush_s``). :class:`RecordingTail` reads only the complete records appended
since its last call (no re-reading, no seeking back), :class:`LiveStatus` folds them into
the figures of one line and :func:`format_status` writes it::

    passes 3/10 | 64 s | h1+h2 372 ms | falls 0 | contacts 0 | err fwd 0.71 cm/s, turn 5.20 deg/s | link ok: fb age 312 ms, loss 0.0 %, 850 kbit/s, video 9.8 fps q60, control udp

Figures (all from the leader's recording):

- passes: the ``pass`` events; the total from the first ``leader/state`` sample that
  carries the pilot's progress (``passes_done``) and the demo's ``--operator``;
- elapsed: wall time since the demo started its processes [s];
- h1 + h2: the latest ``leader/state`` sample's delay estimates [ms];
- falls, contacts: the follower's counters as the leader's samples carry them;
- errors: running means of ``|ref - eta|`` over the ``feedback/recv`` records since the
  operator's ``start`` event (forward [cm/s], turn [deg/s]): the instantaneous tracking
  error, the report's definition before the end-of-run report takes over;
- link (once a sample carries it; recordings before issue 19 have none and the line ends
  at ``err``): the latest sample's link state in words (``ok``, ``lossy``,
  ``capacity-limited``, ``stale``, ``link lost for 3.2 s``, ``no follower``, ``waiting``),
  the age of the newest feedback [ms], the feedback loss over the last 2 s [%], the goodput
  received [kbit/s], the video frames per second received with the follower's JPEG
  quality and, with a router, the link that carries control (``control udp``; ``tls
  (shared)`` when control moved onto the status link); an unknown figure shows as ``-``.
"""

from __future__ import annotations

import io
import logging
import math
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from bipedtele.recording.format import RecordDecoder
from bipedtele.telemetry import LeaderSample, link_words, sample_from_map
from mcap.stream_reader import StreamReader

__all__ = ["LiveStatus", "RecordingTail", "StatusPrinter", "format_status"]

LOG = logging.getLogger(__name__)

_MAGIC = b"\x89MCAP0\r\n"
_HEAD = 9  # opcode (1) + length (8)
_MAX_RECORD = 256 * 1024 * 1024


class RecordingTail:
    """Reads an MCAP file that another process is still writing, a complete record at a time.

    Parameters
    ----------
    path : Path
        The recording (it may not exist yet).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._pos = 0
        self._decoder = RecordDecoder()  # JSON channels with schemas, or older msgpack ones
        self.broken = False

    def poll(self) -> list[tuple[str, dict[str, Any]]]:
        """``(topic, payload)`` of every message completed since the last call."""
        if self.broken:
            return []
        try:
            with open(self.path, "rb") as f:
                f.seek(self._pos)
                data = f.read()
        except OSError:
            return []
        start = 0
        if self._pos == 0:
            if len(data) < len(_MAGIC):
                return []
            if data[: len(_MAGIC)] != _MAGIC:
                self.broken = True
                LOG.warning("%s: not an MCAP file; no live status", self.path)
                return []
            start = len(_MAGIC)
        end = start
        while end + _HEAD <= len(data):  # complete records only
            (length,) = struct.unpack_from("<Q", data, end + 1)
            if length > _MAX_RECORD:
                self.broken = True
                return []
            if end + _HEAD + length > len(data):
                break
            end += _HEAD + length
        self._pos += end
        if end == start:
            return []
        return list(self._decode(io.BytesIO(data[start:end])))

    def _decode(self, stream: IO[bytes]) -> Any:
        reader = StreamReader(stream, skip_magic=True)
        try:
            for rec in reader.records:
                got = self._decoder.feed(rec)  # a bad payload is skipped, as by read_records
                if got is not None:
                    yield got
        except Exception as exc:  # the end of the complete records (EOF) or a damaged chunk
            LOG.debug("%s: tail stops at %s", self.path, type(exc).__name__)


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


@dataclass
class LiveStatus:
    """The running figures of a demo (module docstring)."""

    passes: int = 0
    passes_total: int | None = None
    delay_ms: float | None = None
    falls: int = 0
    contacts: int = 0
    started: bool = False
    link: str | None = None
    link_lost_s: float | None = None
    fb_age_ms: float | None = None
    loss_pct: float | None = None
    rx_kbps: float | None = None
    video_fps: float | None = None
    video_quality: int | None = None
    control_link: str | None = None
    _err_sum: tuple[float, float] = (0.0, 0.0)
    _err_n: int = 0

    def add(self, topic: str, d: dict[str, Any]) -> None:
        """Fold one recorded message in."""
        if topic == "events":
            event = d.get("event")
            if event == "start":
                self.started = True
            elif event == "pass" and isinstance(d.get("n"), int):
                self.passes = max(self.passes, int(d["n"]))
        elif topic == "leader/state":
            sample = sample_from_map(d)
            if sample is not None:
                self._add_sample(sample)
        elif topic == "feedback/recv" and self.started:
            ref, eta = d.get("ref"), d.get("eta")
            if isinstance(ref, list) and isinstance(eta, list) and len(ref) >= 2 and len(eta) >= 2:
                vals = [_num(x) for x in (ref[0], ref[1], eta[0], eta[1])]
                if all(v is not None for v in vals):
                    r0, r1, e0, e1 = (float(v) for v in vals)  # type: ignore[arg-type]
                    s0, s1 = self._err_sum
                    self._err_sum = (s0 + abs(r0 - e0), s1 + abs(r1 - e1))
                    self._err_n += 1

    def _add_sample(self, sample: LeaderSample) -> None:
        h1, h2 = _num(sample.h1_ms), _num(sample.h2_ms)
        if h1 is not None and h2 is not None:
            self.delay_ms = h1 + h2
        if sample.falls is not None:
            self.falls = max(self.falls, sample.falls)
        if sample.collisions is not None:
            self.contacts = max(self.contacts, sample.collisions)
        if sample.passes_done is not None:
            self.passes = max(self.passes, sample.passes_done)
        if sample.link is not None:  # the link's figures as of the latest sample that has them
            self.link, self.link_lost_s = sample.link, _num(sample.link_lost_s)
            self.fb_age_ms, self.loss_pct = _num(sample.fb_age_ms), _num(sample.loss_pct)
            self.rx_kbps, self.video_fps = _num(sample.rx_kbps), _num(sample.video_fps)
            self.video_quality = sample.video_quality
            self.control_link = sample.control_link

    @property
    def errors(self) -> tuple[float, float] | None:
        """Running mean ``|ref - eta|``: (forward [cm/s], turn [deg/s]); None before data."""
        if self._err_n == 0:
            return None
        return self._err_sum[0] / self._err_n, self._err_sum[1] / self._err_n


def format_status(st: LiveStatus, elapsed_s: float) -> str:
    """One status line (module docstring); unknown figures show as ``-``."""
    total = "?" if st.passes_total is None else str(st.passes_total)
    delay = "-" if st.delay_ms is None else f"{st.delay_ms:.0f} ms"
    err = st.errors
    err_text = "-" if err is None else f"fwd {err[0]:.2f} cm/s, turn {err[1]:.2f} deg/s"
    line = (
        f"passes {st.passes}/{total} | {elapsed_s:.0f} s | h1+h2 {delay} | falls {st.falls} | "
        f"contacts {st.contacts} | err {err_text}"
    )
    if st.link is None:
        return line
    age = "-" if st.fb_age_ms is None else f"{st.fb_age_ms:.0f} ms"
    loss = "-" if st.loss_pct is None else f"{st.loss_pct:.1f} %"
    rx = "-" if st.rx_kbps is None else f"{st.rx_kbps:.0f} kbit/s"
    video = "-" if st.video_fps is None else f"{st.video_fps:.1f} fps"
    if st.video_quality is not None:
        video += f" q{st.video_quality}"
    words = link_words(st.link, st.link_lost_s)
    words = words if words.startswith("link ") else f"link {words}"
    control = "" if st.control_link is None else f", control {st.control_link}"
    return f"{line} | {words}: fb age {age}, loss {loss}, {rx}, video {video}{control}"


class StatusPrinter:
    """Writer of the status, about once a second.

    On a terminal one line rewritten in place, otherwise plain lines at most every
    ``plain_every_s`` seconds.

    Parameters
    ----------
    record : Path
        The leader's recording.
    passes_total : int or None
        Passes the operator will make (None: unknown).
    out : file, optional
        Where to write (``sys.stdout``).
    tty : bool, optional
        Whether ``out`` is a terminal (asked of ``out`` when omitted).
    plain_every_s : float
        Period of the plain lines [s].
    clock : callable
        Monotonic time [s].
    """

    def __init__(
        self,
        record: Path,
        passes_total: int | None,
        out: IO[str] | None = None,
        tty: bool | None = None,
        plain_every_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.tail = RecordingTail(record)
        self.status = LiveStatus(passes_total=passes_total)
        self.out = out or sys.stdout
        self.tty = self.out.isatty() if tty is None else tty
        self.period_s = 1.0 if self.tty else float(plain_every_s)
        self.clock = clock
        self.t0 = clock()
        self._next = self.t0 + self.period_s
        self._shown = False

    def update(self, force: bool = False) -> str | None:
        """Read what the recording gained and write the line when one is due (or ``force``).

        Returns the line written, if any.
        """
        now = self.clock()
        if not force and now < self._next:
            return None
        self._next = max(self._next + self.period_s, now)  # on a grid: no drift
        for topic, payload in self.tail.poll():
            self.status.add(topic, payload)
        line = format_status(self.status, now - self.t0)
        if self.tty:
            self.out.write("\r" + line + "\x1b[K")
        else:
            self.out.write(line + "\n")
        self.out.flush()
        self._shown = True
        return line

    def finish(self) -> None:
        """End the rewritten line (a terminal) before other output follows."""
        if self.tty and self._shown:
            self.out.write("\n")
            self.out.flush()
