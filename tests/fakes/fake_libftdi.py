"""A fake libftdi1 with a Novint Falcon behind it (the boundary FalconUsb calls through ctypes).

Same C functions and return conventions as libftdi1 (negative = error, read/write return
byte counts, ``ftdi_usb_open`` -3 when no device, -8 on permission). The simulated Falcon
answers the firmware-mode handshake (9600 baud ``0a 43 0d`` -> 4 bytes, 140 kbaud ``A``
-> 2 bytes), echoes firmware bytes, and once firmware runs answers each 16-byte command
at 1.456 Mbaud with a status packet whose encoder counts put the grip at
:attr:`FakeFalconLib.grip` (the operator's hand; inverse kinematics of the real link
lengths). Homing completes after ``homing_packets`` packets in homing mode. Efforts
received are recorded.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
from bipedtele.leader.devices import falcon_protocol as fp


class FakeFalconLib:
    def __init__(
        self, present: bool = True, firmware_loaded: bool = True, homing_packets: int = 20, permission: bool = True
    ) -> None:
        self.present, self.permission = present, permission
        self.firmware_running = firmware_loaded
        self.homing_packets = homing_packets
        self.homing_count = 0
        self.homed = 0
        self.grip = fp.CENTER.copy()
        self.buttons = 0
        self.baud = 0
        self.dtr: list[int] = []
        self.stage = "idle"
        self.firmware = bytearray()
        self.out = bytearray()
        self.efforts: list[np.ndarray] = []
        self.leds: list[int] = []
        self.homing_flags: list[bool] = []
        self.unplugged = False
        self.opened = False

    # -- libftdi1 functions
    def ftdi_new(self) -> int:
        return 1

    def ftdi_free(self, ctx: Any) -> None:
        pass

    def ftdi_usb_open(self, ctx: Any, vid: int, pid: int) -> int:
        if not self.present or (vid, pid) != (0x0403, 0xCB48):
            return -3
        if not self.permission:
            return -8
        self.opened = True
        return 0

    def ftdi_usb_close(self, ctx: Any) -> int:
        self.opened = False
        return 0

    def ftdi_usb_reset(self, ctx: Any) -> int:
        self.stage, self.firmware_running = "reset", False
        return 0

    def ftdi_usb_purge_buffers(self, ctx: Any) -> int:
        self.out.clear()
        return 0

    def ftdi_set_latency_timer(self, ctx: Any, ms: int) -> int:
        return 0

    def ftdi_set_baudrate(self, ctx: Any, baud: int) -> int:
        self.baud = baud
        if baud == 1456312 and self.stage == "loading" and self.firmware:
            self.firmware_running, self.stage = True, "running"
        return 0

    def ftdi_set_line_property(self, ctx: Any, bits: int, stop: int, parity: int) -> int:
        return 0

    def ftdi_setflowctrl(self, ctx: Any, flow: int) -> int:
        return 0

    def ftdi_setrts(self, ctx: Any, v: int) -> int:
        return 0

    def ftdi_setdtr(self, ctx: Any, v: int) -> int:
        self.dtr.append(v)
        return 0

    def ftdi_get_error_string(self, ctx: Any) -> bytes:
        return b"USB transfer failed" if self.unplugged else b"fake error"

    def ftdi_write_data(self, ctx: Any, data: bytes, size: int) -> int:
        if self.unplugged:
            return -666
        data = bytes(data[:size])
        if self.baud == 9600 and data == b"\x0a\x43\x0d":
            self.stage = "handshake"
            self.out += b"\x0a\x44\x2c\x0d"
        elif self.baud == 140000 and self.stage == "handshake" and data == b"A":
            self.stage = "loading"
            self.out += b"\x13\x41"
        elif self.baud == 140000 and self.stage == "loading":
            self.firmware += data
            self.out += data  # the Falcon echoes each firmware byte
        elif self.baud == 1456312 and self.firmware_running and len(data) == 16:
            self._command(data)
        return size

    def ftdi_read_data(self, ctx: Any, buf: Any, size: int) -> int:
        if self.unplugged:
            return -666
        n = min(size, len(self.out))
        ctypes.memmove(buf, bytes(self.out[:n]), n)
        del self.out[:n]
        return n

    # -- the simulated Falcon
    def _command(self, packet: bytes) -> None:
        efforts = np.zeros(3, dtype=np.int64)
        for i in range(3):
            u = sum(((packet[1 + 4 * i + k] - 0x41) & 0xF) << (4 * k) for k in range(4))
            efforts[i] = u - 0x10000 if u & 0x8000 else u
        flags = packet[13] - 0x41
        homing = bool(flags & 1)
        self.efforts.append(efforts)
        self.leds.append(flags & 0xE)
        self.homing_flags.append(homing)
        if homing and self.homed != 0x7:
            self.homing_count += 1
            if self.homing_count >= self.homing_packets:
                self.homed = 0x7
        counts = fp.encoder_counts(fp.arm_angles(self.grip)) if self.homed == 0x7 else np.zeros(3, dtype=np.int64)
        out = bytearray(16)
        out[0], out[15] = ord("<"), ord(">")
        for i, c in enumerate(counts):
            u = int(c) & 0xFFFF
            for k in range(4):
                out[1 + 4 * i + k] = ((u >> (4 * k)) & 0xF) + 0x41
        out[13] = ((self.homed << 4) | (self.buttons & 0xF)) + 0x41
        out[14] = 0x41
        self.out += out

    def cartesian_force(self, gain: float = 1.0) -> np.ndarray:
        """The Cartesian force [N] the last efforts render at the grip (inverting the mapping)."""
        jac = fp.angle_jacobian(self.grip)
        return np.linalg.solve(jac, -np.asarray(self.efforts[-1], dtype=float) / gain)
