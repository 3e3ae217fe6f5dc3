"""A fake evdev input device: the part of ``evdev.InputDevice`` the joystick driver uses.

Same methods, arguments and answer types as python-evdev's ``InputDevice``:
``capabilities(verbose=False, absinfo=True)`` -> ``{EV_*: [codes or (code, AbsInfo)]}``,
``absinfo(code)`` -> ``AbsInfo``, ``read_one()`` -> ``InputEvent`` or ``None``,
``upload_effect(effect)`` -> effect id (the kernel assigns one when ``effect.id == -1``,
and updates in place otherwise), ``erase_effect(id)``, ``write(type, code, value)``,
``close()``. The test moves the stick with :meth:`FakeInputDevice.move` and reads what the
driver uploaded and played.
"""

from __future__ import annotations

import time
from typing import Any

from evdev import AbsInfo, InputEvent, ecodes


class FakeInputDevice:
    """A two-axis pad (ABS_X/ABS_Y 0..255 centred at 128, or -32768..32767) with buttons."""

    def __init__(
        self,
        name: str = "Fake Pad",
        path: str = "/dev/input/event99",
        ff: tuple[int, ...] = (ecodes.FF_CONSTANT, ecodes.FF_GAIN),
        lo: int = 0,
        hi: int = 255,
        flat: int = 0,
        buttons: tuple[int, ...] = (ecodes.BTN_SOUTH, ecodes.BTN_EAST),
    ) -> None:
        self.name, self.path = name, path
        center = (lo + hi) // 2 + (1 if (lo + hi) % 2 else 0)
        self._abs = {
            c: AbsInfo(value=center, min=lo, max=hi, fuzz=0, flat=flat, resolution=0)
            for c in (ecodes.ABS_X, ecodes.ABS_Y)
        }
        self._buttons = list(buttons)
        self._ff = list(ff)
        self.queue: list[InputEvent] = []
        self.effects: dict[int, Any] = {}
        self.uploads: list[Any] = []
        self.writes: list[tuple[int, int, int]] = []
        self.closed = False
        self.fail_reads = False

    # -- the InputDevice interface
    def capabilities(self, verbose: bool = False, absinfo: bool = True) -> dict[int, list[Any]]:
        caps: dict[int, list[Any]] = {
            ecodes.EV_SYN: [ecodes.SYN_REPORT],
            ecodes.EV_KEY: list(self._buttons),
            ecodes.EV_ABS: [(c, i) if absinfo else c for c, i in self._abs.items()],
        }
        if self._ff:
            caps[ecodes.EV_FF] = list(self._ff)
        return caps

    def absinfo(self, axis_num: int) -> AbsInfo:
        return self._abs[axis_num]

    def read_one(self) -> InputEvent | None:
        self._check()
        if self.fail_reads:
            raise OSError(19, "No such device")
        return self.queue.pop(0) if self.queue else None

    def upload_effect(self, effect: Any) -> int:
        self._check()
        if effect.type not in self._ff:
            raise OSError(22, "Invalid argument")
        eid = effect.id if effect.id >= 0 else len(self.effects)
        self.effects[eid] = effect
        self.uploads.append(effect)
        return eid

    def erase_effect(self, ff_id: int) -> None:
        self._check()
        del self.effects[ff_id]

    def write(self, etype: int, code: int, value: int) -> None:
        self._check()
        self.writes.append((etype, code, value))

    def close(self) -> None:
        self.closed = True

    # -- test side
    def move(self, code: int, value: int) -> None:
        """Queue an axis or button event followed by SYN_REPORT."""
        now = time.time()
        etype = ecodes.EV_ABS if code in self._abs else ecodes.EV_KEY
        self.queue.append(InputEvent(int(now), int(now % 1 * 1e6), etype, code, value))
        self.queue.append(InputEvent(int(now), int(now % 1 * 1e6), ecodes.EV_SYN, ecodes.SYN_REPORT, 0))

    def _check(self) -> None:
        if self.closed:
            raise OSError(9, "Bad file descriptor")
