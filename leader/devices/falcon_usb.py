"""The Falcon's USB link through libftdi1 (ctypes): open, firmware, 16-byte packet I/O.

libnifalcon (the open Falcon driver) is C++ without a C ABI and is not packaged by
Debian, so this module speaks to the Falcon's FTDI chip directly through libftdi1
(``apt-get install libftdi1-2``), following the same sequence as libnifalcon's libftdi
back end. The library is reached through :func:`load_libftdi`; tests pass a fake with the
same C functions instead.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import time
from pathlib import Path
from typing import Any

from bipedtele.leader.device import DeviceError

__all__ = ["FALCON_PID", "FALCON_VID", "FalconUsb", "load_libftdi"]

LOG = logging.getLogger(__name__)

FALCON_VID, FALCON_PID = 0x0403, 0xCB48
_BITS_8, _STOP_BIT_1, _PARITY_NONE, _SIO_DISABLE_FLOW_CTRL = 8, 0, 0, 0x0
_FIRMWARE_BAUD, _NORMAL_BAUD = 140000, 1456312
_INSTALL_HINT = "apt-get install libftdi1-2 (Debian/Ubuntu; libftdi on other systems)"


def load_libftdi() -> Any:
    """libftdi1 through ctypes, with argument/return types set.

    Raises
    ------
    DeviceError
        The library is not installed; the message says how to get it.
    """
    name = ctypes.util.find_library("ftdi1") or "libftdi1.so.2"
    try:
        lib = ctypes.CDLL(name)
    except OSError:
        raise DeviceError(f"falcon: libftdi1 is missing (the Falcon's USB chip driver): {_INSTALL_HINT}") from None
    vp, c_int, buf = ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p
    for fname, args, res in (
        ("ftdi_new", [], vp),
        ("ftdi_free", [vp], None),
        ("ftdi_usb_open", [vp, c_int, c_int], c_int),
        ("ftdi_usb_close", [vp], c_int),
        ("ftdi_usb_reset", [vp], c_int),
        ("ftdi_usb_purge_buffers", [vp], c_int),
        ("ftdi_set_latency_timer", [vp, ctypes.c_ubyte], c_int),
        ("ftdi_set_baudrate", [vp, c_int], c_int),
        ("ftdi_set_line_property", [vp, c_int, c_int, c_int], c_int),
        ("ftdi_setflowctrl", [vp, c_int], c_int),
        ("ftdi_setrts", [vp, c_int], c_int),
        ("ftdi_setdtr", [vp, c_int], c_int),
        ("ftdi_write_data", [vp, buf, c_int], c_int),
        ("ftdi_read_data", [vp, buf, c_int], c_int),
        ("ftdi_get_error_string", [vp], ctypes.c_char_p),
    ):
        fn = getattr(lib, fname)
        fn.argtypes, fn.restype = args, res
    return lib


class FalconUsb:
    """One Falcon's FTDI link.

    Parameters
    ----------
    lib : object
        libftdi1 (from :func:`load_libftdi`) or a fake with the same functions.
    """

    def __init__(self, lib: Any) -> None:
        self.lib = lib
        self.ctx: Any = None
        self._rx = bytearray()

    def _check(self, rc: int, what: str) -> int:
        if rc < 0:
            err = self.lib.ftdi_get_error_string(self.ctx)
            text = err.decode(errors="replace") if isinstance(err, bytes) else str(err)
            raise DeviceError(f"falcon: {what} failed ({rc}: {text})")
        return rc

    def open(self) -> None:
        """Open the first Falcon (USB 0403:cb48) and put it in normal (1.456 Mbaud) mode."""
        self.ctx = self.lib.ftdi_new()
        if not self.ctx:
            raise DeviceError("falcon: libftdi could not allocate a context")
        rc = self.lib.ftdi_usb_open(self.ctx, FALCON_VID, FALCON_PID)
        if rc < 0:
            self.lib.ftdi_free(self.ctx)
            self.ctx = None
            if rc == -8:
                raise DeviceError(
                    "falcon: no permission on the Falcon's USB device: install the udev rule (docs/hardware.md) and replug it"
                )
            raise DeviceError(
                "falcon: no Novint Falcon (USB 0403:cb48) found: plug it in and power it (the power brick, not only USB)"
            )
        self.normal_mode()

    def close(self) -> None:
        """Close the USB device and free the context. Idempotent."""
        if self.ctx is not None:
            self.lib.ftdi_usb_close(self.ctx)
            self.lib.ftdi_free(self.ctx)
            self.ctx = None

    def normal_mode(self) -> None:
        """Set the normal-mode link: 1 ms latency timer, the normal baud rate."""
        self._check(self.lib.ftdi_set_latency_timer(self.ctx, 1), "set latency timer")
        self._check(self.lib.ftdi_set_baudrate(self.ctx, _NORMAL_BAUD), "set baud rate")

    def write(self, data: bytes) -> None:
        """Write ``data`` to the Falcon; raise :class:`DeviceError` unless all of it went."""
        n = self._check(self.lib.ftdi_write_data(self.ctx, data, len(data)), "USB write")
        if n != len(data):
            raise DeviceError(f"falcon: USB write sent {n} of {len(data)} bytes")

    def read(self, size: int) -> bytes:
        """Read at most ``size`` bytes (what is there now)."""
        buf = ctypes.create_string_buffer(size)
        n = self._check(self.lib.ftdi_read_data(self.ctx, buf, size), "USB read")
        return buf.raw[:n]

    def read_exact(self, size: int, timeout_s: float) -> bytes:
        """Read ``size`` bytes, or fewer if ``timeout_s`` [s] passes first."""
        out = bytearray()
        deadline = time.monotonic() + timeout_s
        while len(out) < size and time.monotonic() < deadline:
            out += self.read(size - len(out))
        return bytes(out)

    def load_firmware(self, path: str, timeout_s: float = 2.0) -> None:
        """Load Novint's firmware file into the Falcon (needed once per power-up).

        Raises
        ------
        DeviceError
            The file cannot be read or the Falcon does not echo it back.
        """
        try:
            image = Path(path).read_bytes()
        except OSError as exc:
            raise DeviceError(
                f"falcon: cannot read firmware file {path!r} ({exc.strerror}); set falcon.firmware_file"
            ) from None
        lib, ctx = self.lib, self.ctx
        self._check(lib.ftdi_usb_purge_buffers(ctx), "purge")
        self._check(lib.ftdi_usb_reset(ctx), "reset")
        self._check(lib.ftdi_set_latency_timer(ctx, 16), "set latency timer")
        self._check(lib.ftdi_set_baudrate(ctx, 9600), "set baud rate")
        self._check(lib.ftdi_set_line_property(ctx, _BITS_8, _STOP_BIT_1, _PARITY_NONE), "set 8N1")
        self._check(lib.ftdi_setflowctrl(ctx, _SIO_DISABLE_FLOW_CTRL), "disable flow control")
        self._check(lib.ftdi_setrts(ctx, 0), "RTS low")
        self._check(lib.ftdi_setdtr(ctx, 0), "DTR low")
        self._check(lib.ftdi_setdtr(ctx, 1), "DTR high")
        self.write(b"\x0a\x43\x0d")
        if len(self.read_exact(4, timeout_s)) != 4:
            raise DeviceError("falcon: no answer to the firmware-mode request: power-cycle the Falcon and retry")
        self._check(lib.ftdi_setdtr(ctx, 0), "DTR low")
        self._check(lib.ftdi_set_baudrate(ctx, _FIRMWARE_BAUD), "set baud rate")
        self.write(b"A")
        if len(self.read_exact(2, timeout_s)) != 2:
            raise DeviceError("falcon: the Falcon did not enter firmware mode: power-cycle it and retry")
        for i in range(0, len(image), 128):
            chunk = image[i : i + 128]
            self.write(chunk)
            if self.read_exact(len(chunk), timeout_s) != chunk:
                raise DeviceError(f"falcon: firmware echo mismatch at byte {i}: power-cycle the Falcon and retry")
        self.normal_mode()
        self._rx.clear()
        LOG.info("falcon: firmware %s loaded (%d bytes)", path, len(image))

    def exchange(self, packet: bytes, timeout_s: float = 0.01) -> bytes | None:
        """Send one 16-byte command, return the next complete 16-byte status (None on timeout)."""
        self.write(packet)
        deadline = time.monotonic() + timeout_s
        while True:
            self._rx += self.read(64)
            start = self._rx.find(b"<")
            if start > 0:
                del self._rx[:start]
            if len(self._rx) >= 16 and self._rx[0] == ord("<"):
                status, self._rx = bytes(self._rx[:16]), self._rx[16:]
                if status[15] == ord(">"):
                    return status
                continue  # torn packet: resync on the next '<'
            if time.monotonic() >= deadline:
                return None
