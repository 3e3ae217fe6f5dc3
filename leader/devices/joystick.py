"""A joystick or gamepad through Linux evdev, with force feedback where it has some.

Two stick axes give the handle's two axes, mapped like the Falcon's: full deflection is
the Falcon's workspace edge (+-0.05 m), axis 0 (forward speed) from the stick's forward
push, axis 1 (turn, positive to the left) from its left push. The leader's force is
rendered as

- ``FF_CONSTANT`` (a constant-force effect whose direction and level follow the force),
  where the device supports it;
- else ``FF_RUMBLE`` with a strength proportional to ``|f|`` (no direction);
- else nothing (logged once at connect).

Effects are re-uploaded at most ``ff_rate_hz`` times a second (USB devices cannot take
1 kHz updates); closing the device stops them (the kernel drops a closed file's effects).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable
from typing import Any, ClassVar

import numpy as np
from bipedtele.config.profile import Config, resolve_section
from bipedtele.leader.device import (
    DeviceError,
    DeviceNotConnectedError,
    HandleState,
    LeaderDevice,
)
from bipedtele.leader.parts import JoystickConfig

__all__ = ["JoystickConfig", "JoystickDevice", "ff_direction"]

LOG = logging.getLogger(__name__)


def ff_direction(force_n: np.ndarray) -> int:
    """Linux force-feedback direction (0..0xFFFF) of a handle force.

    The kernel's convention: 0x0000 pulls the stick down (towards the user), 0x4000
    left, 0x8000 up (away), 0xC000 right. Axis 0 (forward) is "up", axis 1 (turn,
    positive left) is "left".
    """
    up, left = float(force_n[0]), float(force_n[1])
    angle = math.atan2(left, -up) % (2.0 * math.pi)
    return round(angle / (2.0 * math.pi) * 0x10000) & 0xFFFF


def _import_evdev() -> Any:
    try:
        import evdev
    except ImportError:
        raise DeviceError(
            "joystick: the python evdev package is missing: pip install 'bipedtele[joystick]' (Linux only)"
        ) from None
    return evdev


class JoystickDevice(LeaderDevice):
    """A Linux evdev joystick as a two-axis leader device.

    Parameters
    ----------
    config : JoystickConfig or Config, optional
        The ``[joystick]`` section or a whole profile.
    opener : callable, optional
        ``path -> InputDevice`` (default ``evdev.InputDevice``).
    lister : callable, optional
        ``() -> list of paths`` (default ``evdev.list_devices``).
    **overrides
        Fields of :class:`JoystickConfig`, e.g. ``device="/dev/input/event5"``.
    """

    name: ClassVar[str] = "joystick"

    def __init__(
        self,
        config: JoystickConfig | Config | None = None,
        *,
        opener: Callable[[str], Any] | None = None,
        lister: Callable[[], Iterable[str]] | None = None,
        **overrides: Any,
    ) -> None:
        self.config = resolve_section(config, JoystickConfig, "joystick", overrides)
        self._opener, self._lister = opener, lister
        self._dev: Any = None
        self._ecodes: Any = None
        self._ff_mod: Any = None
        self._axes: dict[int, tuple[float, float, float]] = {}  # code -> (center, half range, flat fraction)
        self._raw: dict[int, int] = {}
        self._keys: list[int] = []
        self._pressed: set[int] = set()
        self.ff_mode: str = "none"
        self._effect_id = -1
        self._force = np.zeros(2)
        self._ff_sent: tuple[int, int] | None = None
        self._ff_last = -math.inf
        self._t0 = 0.0
        self._last: HandleState | None = None

    # ---------------------------------------------------------------- connection

    @property
    def is_connected(self) -> bool:
        """True between ``connect()`` and ``disconnect()``."""
        return self._dev is not None

    def connect(self) -> None:
        """Find and open the joystick, read its axis ranges and set up force feedback.

        Raises
        ------
        DeviceError
            evdev missing, no matching device, no permission, or the device lacks the axes.
        """
        if self._dev is not None:
            return
        evdev = _import_evdev()
        self._ecodes = evdev.ecodes
        self._ff_mod = evdev.ff
        opener = self._opener or evdev.InputDevice
        lister = self._lister or evdev.list_devices
        codes = [self._code(self.config.axis_forward), self._code(self.config.axis_turn)]
        dev = self._find(opener, lister, codes)
        try:
            caps = dev.capabilities(absinfo=False)
            for code in codes:
                info = dev.absinfo(code)
                lo, hi = float(info.min), float(info.max)
                if hi <= lo:
                    raise DeviceError(f"joystick {dev.name!r}: axis {code} has an empty range [{lo}, {hi}]")
                half = (hi - lo) / 2.0
                self._axes[code] = ((hi + lo) / 2.0, half, max(self.config.deadzone, float(info.flat) / half))
                self._raw[code] = int(info.value)
            # Button 0 is the loop's dead-man switch: report buttons only when one is set.
            keys = sorted(caps.get(self._ecodes.EV_KEY, []))
            self._keys = []
            if self.config.enable_button:
                button = self._code(self.config.enable_button)
                if button not in keys:
                    raise DeviceError(f"joystick {dev.name!r} has no button {self.config.enable_button}")
                self._keys = [button] + [k for k in keys if k != button]
            self._dev = dev
            self._setup_ff(caps.get(self._ecodes.EV_FF, []))
        except BaseException:
            self._dev = None
            dev.close()
            raise
        self._t0 = time.monotonic()
        self._last = None
        LOG.info("joystick %r at %s connected; force feedback: %s", dev.name, dev.path, self.ff_mode)

    def disconnect(self) -> None:
        """Stop and erase the effect, close the device. Idempotent."""
        if self._dev is None:
            return
        dev, self._dev = self._dev, None
        try:
            if self._effect_id >= 0:
                dev.write(self._ecodes.EV_FF, self._effect_id, 0)
                dev.erase_effect(self._effect_id)
        except OSError as exc:
            LOG.warning("joystick: stopping force feedback: %s", exc)
        finally:
            self._effect_id, self._ff_sent = -1, None
            self._force = np.zeros(2)
            dev.close()

    # ---------------------------------------------------------------- contract

    def read(self) -> HandleState:
        """Drain pending events and return the handle (positions in [-0.05, 0.05] m)."""
        self._require()
        self._drain()
        t = time.monotonic() - self._t0
        w = self.limits.workspace_m
        fwd = self._norm(self._code(self.config.axis_forward)) * (-1.0 if self.config.invert_forward else 1.0)
        turn = self._norm(self._code(self.config.axis_turn)) * (-1.0 if self.config.invert_turn else 1.0)
        x = np.array([fwd, turn]) * w
        dx = np.zeros(2)
        if self._last is not None and t > self._last.t:
            dx = (x - self._last.x_m) / (t - self._last.t)
        state = HandleState(t=t, x_m=x, dx_m=dx, buttons=tuple(k in self._pressed for k in self._keys))
        self._last = state
        return state

    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        """Clamp the force to 8 N per axis and render it (constant force, rumble or none)."""
        self._require()
        self._force = self.clamp_force(force_n)
        self._push_ff(force=False)
        return self._force.copy()

    def advance(self, dt: float) -> None:
        """Service the device: drain events, push a due effect update. Returns at once."""
        self._require()
        self._drain()
        self._push_ff(force=False)

    # ---------------------------------------------------------------- internals

    def _require(self) -> None:
        if self._dev is None:
            raise DeviceNotConnectedError("joystick: call connect() first")

    def _code(self, name: str) -> int:
        code = getattr(self._ecodes, name, None) if self._ecodes is not None else None
        if not isinstance(code, int):
            raise DeviceError(f"joystick: unknown evdev code {name!r} (e.g. ABS_X, ABS_Y, ABS_RX, BTN_SOUTH)")
        return code

    def _find(self, opener: Callable[[str], Any], lister: Callable[[], Iterable[str]], codes: list[int]) -> Any:
        want = self.config.device
        hint = "plug it in, and check /dev/input/event* permissions (add your user to the 'input' group)"
        if want.startswith("/"):
            try:
                return opener(want)
            except FileNotFoundError:
                raise DeviceError(f"joystick: no device at {want}: {hint}") from None
            except PermissionError:
                raise DeviceError(
                    f"joystick: no permission to open {want}: add your user to the 'input' group"
                ) from None
        denied = 0
        for path in lister():
            try:
                dev = opener(path)
            except PermissionError:
                denied += 1
                continue
            except OSError:
                continue
            axes = {
                c if isinstance(c, int) else c[0] for c in dev.capabilities(absinfo=False).get(self._ecodes.EV_ABS, [])
            }
            if all(c in axes for c in codes) and want.lower() in str(dev.name).lower():
                return dev
            dev.close()
        what = f"named like {want!r} " if want else ""
        extra = f" ({denied} input devices could not be opened: permissions)" if denied else ""
        raise DeviceError(
            f"joystick: no joystick {what}with axes {self.config.axis_forward}/{self.config.axis_turn} found{extra}: {hint}"
        )

    def _setup_ff(self, ff_caps: list[int]) -> None:
        e = self._ecodes
        want = self.config.force_feedback
        has_const, has_rumble = e.FF_CONSTANT in ff_caps, e.FF_RUMBLE in ff_caps
        if want in ("auto", "constant") and has_const:
            self.ff_mode = "constant"
        elif want in ("auto", "rumble") and has_rumble:
            self.ff_mode = "rumble"
        else:
            self.ff_mode = "none"
            if want != "none":
                LOG.warning(
                    "joystick %r has no %s force feedback: the leader's force is not rendered",
                    self._dev.name,
                    "usable" if want == "auto" else want,
                )
            return
        if e.FF_GAIN in ff_caps:
            self._dev.write(e.EV_FF, e.FF_GAIN, 0xFFFF)
        self._push_ff(force=True)
        self._dev.write(e.EV_FF, self._effect_id, 1)  # play (the effect is updated in place)

    def _push_ff(self, force: bool) -> None:
        if self.ff_mode == "none" or self._dev is None:
            return
        now = time.monotonic()
        if not force and now - self._ff_last < 1.0 / self.config.ff_rate_hz:
            return
        magnitude = float(np.hypot(*self._force)) / self.limits.force_max_n
        level = min(0x7FFF, round(magnitude * 0x7FFF))
        direction = ff_direction(self._force) if self.ff_mode == "constant" else 0
        if not force and self._ff_sent == (level, direction):
            return
        ff = self._ff_mod
        e = self._ecodes
        if self.ff_mode == "constant":
            kind = e.FF_CONSTANT
            effect_type = ff.EffectType(ff_constant_effect=ff.Constant(level, ff.Envelope(0, 0, 0, 0)))
        else:
            kind = e.FF_RUMBLE
            strength = min(0xFFFF, 2 * level)
            effect_type = ff.EffectType(ff_rumble_effect=ff.Rumble(strength, strength))
        effect = ff.Effect(kind, self._effect_id, direction, ff.Trigger(0, 0), ff.Replay(0xFFFF, 0), effect_type)
        try:
            self._effect_id = int(self._dev.upload_effect(effect))
        except OSError as exc:
            raise DeviceError(
                f"joystick {self._dev.name!r}: force feedback upload failed ({exc}); set joystick.force_feedback = 'none'"
            ) from None
        self._ff_sent, self._ff_last = (level, direction), now

    def _drain(self) -> None:
        e = self._ecodes
        try:
            for _ in range(10_000):  # bounded: a flood of events cannot stall the loop
                ev = self._dev.read_one()
                if ev is None:
                    break
                if ev.type == e.EV_ABS and ev.code in self._axes:
                    self._raw[ev.code] = int(ev.value)
                elif ev.type == e.EV_KEY:
                    if ev.value:
                        self._pressed.add(ev.code)
                    else:
                        self._pressed.discard(ev.code)
        except OSError as exc:  # unplugged
            dev, self._dev = self._dev, None
            dev.close()
            raise DeviceError(
                f"joystick {getattr(dev, 'name', '?')!r} is gone ({exc}): plug it back in and reconnect"
            ) from None

    def _norm(self, code: int) -> float:
        center, half, flat = self._axes[code]
        n = max(-1.0, min(1.0, (self._raw[code] - center) / half))
        if abs(n) <= flat:
            return 0.0
        return math.copysign((abs(n) - flat) / (1.0 - flat), n)
