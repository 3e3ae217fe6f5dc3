"""Joining a video frame sent in parts (``VideoFrame.part`` of ``parts``).

On a slow uplink the follower cuts each JPEG into parts paced apart (docs/follower.md,
Capacity), so that its feedback never queues behind a whole frame. The parts of one frame
carry consecutive ``seq`` (``seq - part`` names the frame), the same header fields, and the
JPEG's bytes in order. :class:`FrameAssembler` joins them; latest only, like the video key:
one frame is joined at a time per camera, and a part of a newer frame abandons it.

A part that does not fit the frame being joined (not below ``parts``, its header differs,
it skips a part, or the frame grows past ``MAX_JPEG_BYTES``) is dropped and counted with its frame, never a
crash; so is a frame that a newer one overtook before all its parts came.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import MAX_JPEG_BYTES, VideoFrame

__all__ = ["FrameAssembler"]


@dataclass
class _Joining:
    """A frame whose parts are coming: its first part and the JPEG bytes so far."""

    first: VideoFrame
    pieces: list[bytes] = field(default_factory=list)
    size: int = 0  # bytes of JPEG so far


class FrameAssembler:
    """Join video parts into whole frames.

    Parameters
    ----------
    drops : DropCounter
        Counts ``video_incomplete`` (a frame overtaken before all its parts came) and
        ``video_bad_part`` (a part that does not continue its frame).

    Notes
    -----
    Not thread-safe: called from the one receiver callback of the video key.
    """

    def __init__(self, drops: DropCounter) -> None:
        self.drops = drops
        self._joining: dict[str, _Joining] = {}  # by camera

    def add(self, msg: VideoFrame) -> VideoFrame | None:
        """Take one accepted VideoFrame; return a whole frame when ``msg`` completes one.

        A whole frame (``parts`` 1) is returned as it came; a joined one as a VideoFrame
        with the first part's envelope (``sid``, ``seq``, ``t``) and header, ``part`` 0,
        ``parts`` 1 and the joined JPEG.
        """
        if msg.part >= msg.parts or msg.part > msg.seq:
            self.drops.drop("video_bad_part", f"seq={msg.seq}: part {msg.part} of {msg.parts}")
            return None
        cur = self._joining.get(msg.camera)
        frame_seq = msg.seq - msg.part
        if cur is not None and (cur.first.sid != msg.sid or cur.first.seq != frame_seq):
            del self._joining[msg.camera]
            self.drops.drop(
                "video_incomplete",
                f"frame seq={cur.first.seq}: {len(cur.pieces)} of {cur.first.parts} parts, then seq={msg.seq}",
            )
            cur = None
        if msg.parts == 1:
            return msg
        if cur is None:
            if msg.part != 0:
                self.drops.drop(
                    "video_bad_part", f"seq={msg.seq}: part {msg.part} of {msg.parts} without its first part"
                )
                return None
            cur = self._joining[msg.camera] = _Joining(msg)
        else:
            head = cur.first
            same = (msg.parts, msg.width, msg.height, msg.t_capture) == (
                head.parts,
                head.width,
                head.height,
                head.t_capture,
            )
            if not same or msg.part != len(cur.pieces) or cur.size + len(msg.jpeg) > MAX_JPEG_BYTES:
                del self._joining[msg.camera]
                self.drops.drop(
                    "video_bad_part",
                    f"seq={msg.seq}: part {msg.part} of {msg.parts} does not continue "
                    f"frame seq={head.seq} ({len(cur.pieces)} parts, {cur.size} bytes)",
                )
                return None
        cur.pieces.append(msg.jpeg)
        cur.size += len(msg.jpeg)
        if len(cur.pieces) < cur.first.parts:
            return None
        del self._joining[msg.camera]
        head = cur.first
        return VideoFrame(
            sid=head.sid,
            seq=head.seq,
            t=head.t,
            camera=head.camera,
            width=head.width,
            height=head.height,
            t_capture=head.t_capture,
            jpeg=b"".join(cur.pieces),
        )
