"""The Novint Falcon's USB protocol and kinematics, without the USB (pure functions).

The Falcon is an FTDI serial device (USB 0403:cb48). After power-up it needs firmware
(Novint's, loaded at 140 kbaud by :func:`bipedtele.leader.devices.falcon_usb.load_firmware`);
the firmware then exchanges 16-byte packets at 1.456 Mbaud:

- host -> Falcon: ``'<'``, three motor efforts (signed 16 bit, each sent as four nibbles,
  least significant first), one nibble of flags (bit 0 homing mode, bits 1-3 the green,
  blue and red LEDs), ``'>'``; every nibble is offset by 0x41 (``'A'``).
- Falcon -> host: ``'<'``, three encoder counts (signed 16 bit, four nibbles each), one
  byte whose high nibble holds the homed flag of each motor and low nibble the grip's
  buttons, ``'>'``; same 0x41 offset.

Kinematics (parallel "delta" linkage, R. E. Stamper's model, with the link lengths
measured by the libnifalcon project): each arm i, rotated by phi_i about the handle
axis, has an upper arm ``a`` driven by its motor angle theta1 and a parallelogram shin
``b``; :func:`arm_angles` solves the inverse kinematics in closed form,
:func:`position` the forward kinematics by Newton iteration on it, and
:func:`angle_jacobian` the derivative d theta1 / d p. Motor efforts follow libnifalcon's
convention ``effort = -(d theta1 / d p) F`` (F in N, theta in rad, p in m).
Coordinates [m]: x to the operator's right, y up, z out of the device towards the
operator (z is about 0.11 m at the centre of the workspace).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "BUTTON_BITS",
    "LED_BLUE",
    "LED_GREEN",
    "LED_RED",
    "angle_jacobian",
    "arm_angles",
    "decode_status",
    "encode_command",
    "encoder_angles",
    "encoder_counts",
    "motor_efforts",
    "position",
]

LED_GREEN, LED_BLUE, LED_RED = 0x2, 0x4, 0x8
BUTTON_BITS = 4
_OFFSET = 0x41

# Link lengths [m] and arm placement (libnifalcon's measurements of the Falcon).
A, B, C, D, E, F = 0.060, 0.1025, 0.014, 0.01125, 0.01125, -0.025
R, S = 0.037233758, -0.027330909
_TILT = math.pi / 12  # each arm axis is 15 degrees off the desk plane
PHI = np.array([math.pi / 2 + _TILT, -math.pi / 6 + _TILT, -5 * math.pi / 6 + _TILT])
# Encoder: 320 slots x 4 edges on a 14.25 mm shaft driving a 110 mm arm sector (capstan).
DEG_PER_COUNT = (math.pi * 0.01425 / (320 * 4)) / (math.pi * 0.110 / 360.0)
THETA_OFFSET_DEG = 35.0  # arm angle at encoder count 0 (after homing)
CENTER = np.array([0.0, 0.0, 0.11])


def encode_command(efforts: np.ndarray, leds: int = 0, homing: bool = False) -> bytes:
    """Return the 16-byte host -> Falcon packet for three motor ``efforts`` (int16)."""
    out = bytearray(16)
    out[0], out[15] = ord("<"), ord(">")
    for i, v in enumerate(np.asarray(efforts).astype(np.int64)):
        u = int(v) & 0xFFFF
        for k in range(4):
            out[1 + 4 * i + k] = ((u >> (4 * k)) & 0xF) + _OFFSET
    out[13] = ((leds & 0xE) | (1 if homing else 0)) + _OFFSET
    out[14] = _OFFSET
    return bytes(out)


def decode_status(packet: bytes) -> tuple[np.ndarray, int, int]:
    """Return the encoder counts (int16 x 3), homed bits (bit i: motor i) and grip buttons of a packet.

    Raises
    ------
    ValueError
        Not a 16-byte ``<...>`` packet.
    """
    if len(packet) != 16 or packet[0] != ord("<") or packet[15] != ord(">"):
        raise ValueError(f"not a Falcon status packet: {bytes(packet)!r}")
    counts = np.zeros(3, dtype=np.int64)
    for i in range(3):
        u = 0
        for k in range(4):
            u |= ((packet[1 + 4 * i + k] - _OFFSET) & 0xF) << (4 * k)
        counts[i] = u - 0x10000 if u & 0x8000 else u
    flags = (packet[13] - _OFFSET) & 0xFF
    return counts, (flags >> 4) & 0x7, flags & 0xF


def encoder_angles(counts: np.ndarray) -> np.ndarray:
    """Motor arm angles theta1 [rad] from encoder counts."""
    return np.radians(DEG_PER_COUNT * np.asarray(counts, dtype=float) + THETA_OFFSET_DEG)


def encoder_counts(theta1: np.ndarray) -> np.ndarray:
    """Return the encoder counts (nearest integers) of arm angles theta1 [rad] (for fakes and tests)."""
    return np.rint((np.degrees(np.asarray(theta1, dtype=float)) - THETA_OFFSET_DEG) / DEG_PER_COUNT).astype(np.int64)


def arm_angles(p: np.ndarray) -> np.ndarray:
    """Inverse kinematics: the three motor angles theta1 [rad] that put the grip at ``p`` [m].

    Raises
    ------
    ValueError
        ``p`` is outside the reachable workspace.
    """
    x, y, z = (float(v) for v in p)
    cphi, sphi = np.cos(PHI), np.sin(PHI)
    pu = -R + cphi * x + sphi * y  # in the arm's own (u, v, w) frame
    pv = -S + cphi * y - sphi * x
    pw = z
    cos3 = (pv + F) / B
    if np.any(np.abs(cos3) > 1.0):
        raise ValueError(f"position {p!r} out of the Falcon's reach")
    s3 = np.sin(np.arccos(cos3))
    common = pw**2 + pu**2 + 2 * C * pu + A**2 + C**2 - D**2 - E**2 - B**2 * s3**2 - 2 * B * (D + E) * s3 - 2 * D * E
    l0 = common - 2 * A * pu - 2 * A * C
    l1 = -4 * A * pw
    l2 = common + 2 * A * pu + 2 * A * C
    disc = l1**2 - 4 * l2 * l0
    if np.any(disc < 0) or np.any(l2 == 0):
        raise ValueError(f"position {p!r} out of the Falcon's reach")
    t = -(np.sqrt(disc) + l1) / (2 * l2)  # tangent half-angle of theta1
    return 2.0 * np.arctan(t)


def angle_jacobian(p: np.ndarray, h: float = 1e-5) -> np.ndarray:
    """Return d theta1 / d p [rad/m] at ``p`` by central differences (3 x 3)."""
    jac = np.empty((3, 3))
    for j in range(3):
        dp = np.zeros(3)
        dp[j] = h
        jac[:, j] = (arm_angles(p + dp) - arm_angles(p - dp)) / (2 * h)
    return jac


def position(theta1: np.ndarray, guess: np.ndarray | None = None, tol_rad: float = 1e-7, iters: int = 20) -> np.ndarray:
    """Forward kinematics: the grip position [m] for motor angles ``theta1`` [rad].

    Newton iteration on :func:`arm_angles` from ``guess`` (the last position: one or two
    iterations at 1 kHz), or from the workspace centre.

    Raises
    ------
    ValueError
        No convergence (angles outside the mechanism's range).
    """
    p = np.array(CENTER if guess is None else guess, dtype=float)
    target = np.asarray(theta1, dtype=float)
    err = target - arm_angles(p)
    for _ in range(iters):
        if np.max(np.abs(err)) < tol_rad:
            return p
        step = np.linalg.solve(angle_jacobian(p), err)
        norm = float(np.linalg.norm(step))
        if norm > 0.01:  # at most 1 cm per iteration: stays inside the reachable set
            step *= 0.01 / norm
        for _ in range(10):  # halve until the trial point is reachable and no worse
            try:
                trial_err = target - arm_angles(p + step)
            except ValueError:
                step *= 0.5
                continue
            if np.max(np.abs(trial_err)) <= np.max(np.abs(err)):
                break
            step *= 0.5
        else:
            break
        p, err = p + step, trial_err
    if np.max(np.abs(err)) < tol_rad:
        return p
    raise ValueError(f"Falcon angles {target!r} rad: forward kinematics did not converge")


def motor_efforts(p: np.ndarray, force_n: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """Motor efforts (int16) rendering the Cartesian ``force_n`` [N] at ``p`` [m]."""
    tau = -gain * angle_jacobian(p) @ np.asarray(force_n, dtype=float)
    return np.clip(np.rint(tau), -32767, 32767).astype(np.int64)
