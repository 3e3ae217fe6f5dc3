"""What the cockpit and a browser say to each other: telemetry as JSON, the browser's messages checked.

The websocket's messages both ways (served by :mod:`bipedtele.leader.cockpit.feed`):

Websocket protocol
------------------
Server to browser:

- text ``{"type": "hello", "telemetry_hz": f, "keys": [...], "course": [[x, y, r], ...]}``
  on connect (``course``: the task's obstacles for the map, metres; empty when unknown);
- text ``{"type": "samples", "samples": [sample, ...]}``: new telemetry samples (a late
  client first gets the last ``history_s`` seconds); non-finite numbers are sent as null;
- binary video frame: ``b"VF"``, u8 name length, camera name (ASCII), f64 capture time [s]
  (little endian), u32 frame number, then the JPEG bytes.

Browser to server: text ``{"type": "joy", "x": x, "y": y}`` with x, y in [-1, 1]; x is
right-positive, y is up-positive (up = forward). The page re-sends the held position every
100 ms and sends (0, 0) on release. Text ``{"type": "hand", "release": true|false}``: the
buttons Release (give the robot up: another operator may take it) and Take (drive it
again, once it is free; docs/fleet.md, Hand-over). Anything else (binary, not JSON, unknown type, bad or
out-of-range numbers, over 1 KiB) is dropped and counted (:attr:`CockpitServer.stats`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from bipedtele.telemetry import LeaderSample, sample_to_json

#: Telemetry keys the page plots or shows (others are shown as text). Units in docs/cockpit.md.
SAMPLE_KEYS: tuple[str, ...] = (
    "t", "ref_v", "ref_w", "z_e_v", "z_e_w", "eta_v", "eta_w", "force_v", "force_w",
    "h1_ms", "h2_ms", "alpha_m_v", "alpha_m_w", "s_r_v", "s_r_w", "T", "eps",
    "state", "link", "link_lost_s", "fb_age_ms", "loss_pct", "rx_kbps", "tx_kbps", "video_fps", "video_quality",
    "watchdog", "falls", "passes_done",
    "pose_x", "pose_y", "pose_yaw", "pred_x", "pred_y", "pred_yaw", "ahead_x", "ahead_y", "ahead_yaw", "ahead_dt",
)  # fmt: skip

_MAX_IN_TEXT = 1024
_VIDEO_MAGIC = b"VF"


def _clean(value: Any) -> Any:
    """Copy a telemetry value into JSON-safe form (non-finite -> None, unknown -> str)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if hasattr(value, "tolist"):
        return _clean(value.tolist())
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value[:64]]
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in list(value.items())[:64]}
    return str(value)[:200]


class EncodedSample(str):
    """A telemetry sample already encoded as JSON text (the cockpit process is fed these)."""


def _sample_json(sample: LeaderSample | EncodedSample | dict[str, Any]) -> str:
    """Return one telemetry sample as JSON text (non-finite numbers as null)."""
    if isinstance(sample, EncodedSample):
        return str(sample)
    if isinstance(sample, LeaderSample):
        return sample_to_json(sample).decode()
    return json.dumps({str(k): _clean(v) for k, v in sample.items()}, allow_nan=False)


#: Where a ``pad`` message comes from (the page's Gamepad API, or its keyboard).
PAD_SOURCES = ("gamepad", "keyboard")


def _parse_pad(msg: dict[str, Any]) -> tuple[str, float, float, bool]:
    """Validate a ``pad`` message's fields: ``(src, x, y, held)``; ValueError(reason) when bad."""
    src = msg.get("src")
    if src not in PAD_SOURCES:
        raise ValueError("bad_pad")
    held = msg.get("held")
    if not isinstance(held, bool):
        raise ValueError("bad_pad")
    x, y = _numbers(msg)
    return str(src), x, y, held


def _numbers(msg: dict[str, Any]) -> tuple[float, float]:
    out = []
    for key in ("x", "y"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError("bad_number")
        if not -1.0 <= v <= 1.0:
            raise ValueError("out_of_range")
        out.append(float(v))
    return out[0], out[1]


def _parse_in(text: str) -> tuple[float, float] | bool | tuple[str, float, float, bool]:
    """Validate one browser message.

    Returns ``(x, y)`` of a joystick one, the flag of a hand one, ``(src, x, y, held)`` of a
    pad one. Raises ValueError(reason) when it is bad.
    """
    if len(text) > _MAX_IN_TEXT:
        raise ValueError("too_long")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        raise ValueError("not_json") from None
    if isinstance(msg, dict) and msg.get("type") == "pad":
        return _parse_pad(msg)
    if isinstance(msg, dict) and msg.get("type") == "hand":
        release = msg.get("release")
        if not isinstance(release, bool):
            raise ValueError("bad_hand")
        return release
    if not isinstance(msg, dict) or msg.get("type") != "joy":
        raise ValueError("unknown_type")
    return _numbers(msg)
