"""Clean shutdown on SIGINT and SIGTERM for long-running programs."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

__all__ = ["shutdown_on_signals"]


@contextmanager
def shutdown_on_signals() -> Iterator[threading.Event]:
    """Yield an event that is set on SIGINT or SIGTERM; restore the old handlers on exit.

    Must be entered from the main thread. Programs loop ``while not stop.is_set()`` and
    leave their ``with`` blocks normally, so every session and device closes cleanly.
    """
    stop = threading.Event()

    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for s, h in old.items():
            signal.signal(s, h)
