"""A real Novint Falcon (USB 0403:cb48) as a leader device, through libftdi1.

``connect()`` opens the Falcon, loads Novint's firmware when the Falcon has none
(``falcon.firmware_file``; needed after each power-up), homes it (the operator moves the
handle all the way out and back in while the LED is red; green when homed), then starts
a 1 kHz I/O thread: each period it renders the latest force through the Falcon's motors
and reads the encoders, whose forward kinematics give the grip position.

Handle axes (the paper's two): axis 0 (forward speed) is pushing the grip away from the
operator (-z), axis 1 (turn, positive to the left) is moving it left (-x), both relative
to the workspace centre. The vertical axis (y) is held at the centre by a spring-damper.
Each force axis is clamped to 8 N. Where libftdi1, the device, the permission or the
firmware is missing, ``connect()`` raises :class:`DeviceError` saying what and how.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from bipedtele.config.profile import Config, resolve_section
from bipedtele.leader.device import (
    DeviceError,
    DeviceNotConnectedError,
    HandleState,
    LeaderDevice,
)
from bipedtele.leader.devices import falcon_protocol as fp
from bipedtele.leader.devices.falcon_usb import FalconUsb, load_libftdi
from bipedtele.leader.parts import FalconConfig

__all__ = ["FalconConfig", "FalconDevice"]

LOG = logging.getLogger(__name__)


class FalconDevice(LeaderDevice):
    """A Novint Falcon.

    Parameters
    ----------
    config : FalconConfig or Config, optional
        The ``[falcon]`` section or a whole profile.
    lib_loader : callable, optional
        ``() -> libftdi1`` (default :func:`load_libftdi`; tests pass a fake library).
    **overrides
        Fields of :class:`FalconConfig`.
    """

    name: ClassVar[str] = "falcon"

    def __init__(
        self,
        config: FalconConfig | Config | None = None,
        *,
        lib_loader: Callable[[], Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.config = resolve_section(config, FalconConfig, "falcon", overrides)
        self._lib_loader = lib_loader or load_libftdi
        self._usb: FalconUsb | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._force = np.zeros(2)
        self._p = np.array([0.0, 0.0, self.config.center_z_m])
        self._v = np.zeros(3)
        self._buttons = 0
        self._t_status = 0.0
        self._error: str | None = None
        self._t0 = 0.0
        self.loops = 0

    @property
    def is_connected(self) -> bool:
        """True between ``connect()`` and ``disconnect()``."""
        return self._usb is not None

    def connect(self) -> None:
        """Open, load firmware if needed, home, and start the 1 kHz I/O thread.

        Raises
        ------
        DeviceError
            libftdi1 missing, no Falcon, no permission, no firmware, or not homed in time.
        """
        if self._usb is not None:
            return
        usb = FalconUsb(self._lib_loader())
        usb.open()
        try:
            self._ensure_firmware(usb)
            self._home(usb)
        except BaseException:
            usb.close()
            raise
        self._usb, self._error, self._stop = usb, None, threading.Event()
        self._t0 = self._t_status = time.monotonic()
        self._thread = threading.Thread(target=self._io_loop, name="falcon-io", daemon=True)
        self._thread.start()
        LOG.info("falcon: homed, I/O at %.0f Hz", self.config.io_rate_hz)

    def disconnect(self) -> None:
        """Stop the I/O thread with zero force and close the USB link. Idempotent."""
        if self._usb is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        usb, self._usb, self._thread = self._usb, None, None
        try:
            usb.write(fp.encode_command(np.zeros(3)))  # motors off
        except DeviceError as exc:
            LOG.warning("%s", exc)
        usb.close()

    def read(self) -> HandleState:
        """Read the grip on the two handle axes [m] (within +-0.05 m)."""
        self._require()
        with self._lock:
            p, v, buttons, t = self._p.copy(), self._v.copy(), self._buttons, self._t_status
        w = self.limits.workspace_m
        x = np.clip([-(p[2] - self.config.center_z_m), -p[0]], -w, w)
        eb = self.config.enable_button
        order = [eb] + [i for i in range(fp.BUTTON_BITS) if i != eb] if eb >= 0 else []
        return HandleState(
            t=t - self._t0, x_m=x, dx_m=np.array([-v[2], -v[0]]), buttons=tuple(bool(buttons >> i & 1) for i in order)
        )

    def apply_force(self, force_n: np.ndarray) -> np.ndarray:
        """Set the force [N] the I/O thread renders (clamped to 8 N per axis)."""
        self._require()
        f = self.clamp_force(force_n)
        with self._lock:
            self._force = f
        return f.copy()

    def advance(self, dt: float) -> None:
        """Return at once: the I/O thread services the Falcon (raise if it failed)."""
        self._require()

    # ------------------------------------------------------------------ internals

    def _require(self) -> None:
        if self._usb is None:
            raise DeviceNotConnectedError("falcon: call connect() first")
        if self._error is not None:
            raise DeviceError(self._error)

    def _ensure_firmware(self, usb: FalconUsb) -> None:
        for _ in range(10):
            if usb.exchange(fp.encode_command(np.zeros(3)), 0.02) is not None:
                return  # firmware already running
        if not self.config.firmware_file:
            raise DeviceError(
                "falcon: the Falcon has no firmware loaded: set falcon.firmware_file to Novint's image (nvent_firmware.bin, shipped with libnifalcon)"
            )
        usb.load_firmware(self.config.firmware_file)
        if usb.exchange(fp.encode_command(np.zeros(3)), 0.1) is None:
            raise DeviceError("falcon: firmware loaded but the Falcon does not answer: power-cycle it and retry")

    def _home(self, usb: FalconUsb) -> None:
        LOG.warning("falcon: homing - move the handle all the way out, then all the way in (LED red until homed)")
        deadline = time.monotonic() + self.config.homing_timeout_s
        while time.monotonic() < deadline:
            status = usb.exchange(fp.encode_command(np.zeros(3), fp.LED_RED, homing=True))
            if status is not None and fp.decode_status(status)[1] == 0x7:
                usb.exchange(fp.encode_command(np.zeros(3), fp.LED_GREEN))
                return
        raise DeviceError(
            f"falcon: not homed within {self.config.homing_timeout_s:.0f} s: move the handle fully out and in, then connect again"
        )

    def _io_loop(self) -> None:
        usb = self._usb
        assert usb is not None
        period = 1.0 / self.config.io_rate_hz
        next_t = time.monotonic()
        p_prev, t_prev = self._p.copy(), time.monotonic()
        cfg = self.config
        while not self._stop.is_set():
            with self._lock:
                f2, p, v = self._force.copy(), self._p.copy(), self._v.copy()
            # Cartesian force: handle axes back to the Falcon frame, vertical spring-damper.
            fy = -cfg.hold_stiffness_n_m * p[1] - cfg.hold_damping_n_s_m * v[1]
            f3 = np.clip(np.array([-f2[1], fy, -f2[0]]), -self.limits.force_max_n, self.limits.force_max_n)
            try:
                efforts = fp.motor_efforts(p, f3, cfg.force_gain)
                status = usb.exchange(fp.encode_command(efforts, fp.LED_GREEN), period * 5)
                now = time.monotonic()
                if status is None:
                    if now - self._t_status > cfg.io_timeout_s:
                        raise DeviceError(f"falcon: no answer for {cfg.io_timeout_s} s: is it unplugged or unpowered?")
                else:
                    counts, _homed, buttons = fp.decode_status(status)
                    p_new = fp.position(fp.encoder_angles(counts), guess=p)
                    dt = max(now - t_prev, 1e-4)
                    v_new = 0.7 * v + 0.3 * (p_new - p_prev) / dt  # light low-pass on the difference
                    with self._lock:
                        self._p, self._v, self._buttons, self._t_status = p_new, v_new, buttons, now
                    p_prev, t_prev = p_new, now
                    self.loops += 1
            except (DeviceError, ValueError) as exc:
                self._error = str(exc) if isinstance(exc, DeviceError) else f"falcon: bad reading ({exc}): reconnect"
                LOG.error("%s", self._error)
                return
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()
