"""COMM_GET_IMU_DATA: the VESC's own IMU, request and reply, and its mounting in the car.

Pure functions, no I/O. Facts from the firmware (vedderb/bldc, read at commit b9d287b3):

* ``COMM_GET_IMU_DATA = 65`` in the ``COMM_PACKET_ID`` enum (``datatypes.h``).
* Request payload: ``[65, mask (uint16, big endian)]`` (``comm/commands.c`` reads the mask
  with ``buffer_get_uint16``).
* Reply payload: ``[65, mask (uint16 BE), one float32_auto per set bit in bit order,
  controller_id (uint8)]``. The bits (``ImuField``)::

       0..2   roll, pitch, yaw [rad]         (imu_get_rpy, the firmware's AHRS)
       3..5   acc x, y, z [g]                (imu_get_accel)
       6..8   gyro x, y, z [deg/s]           (imu_get_gyro)
       9..11  mag x, y, z [uT]               (imu_get_mag)
      12..15  quaternion q0..q3 [-]          (imu_get_quaternions)

  Accelerations and rates are already rotated by the VESC's own IMU rotation settings
  (``imu.c``: ZYX rotation by ``rot_roll``/``rot_pitch``/``rot_yaw``) and offset-corrected.
* ``float32_auto`` (``util/buffer.c``, ``buffer_append_float32_auto``): a 32-bit big-endian
  word ``sign << 31 | e << 23 | sig`` with ``e`` and ``sig`` from ``frexpf``; for every
  normal float this is the IEEE-754 single bit pattern, and |x| < 1.5e-38 is sent as 0. The
  decoder (``buffer_get_float32_auto``) gives ``0`` for ``e == 0 and sig == 0`` and else
  ``(sig / 2**24 + 0.5) * 2**(e - 126)`` with the sign (so it is not IEEE for ``e == 0`` or
  ``e == 255``: no subnormals, no inf/NaN). Both are implemented here from those formulas.

The mounting rotation ``R`` (3x3) takes a vector from the VESC board frame (after the
firmware's own rotation) to the car frame (x forward, y left, z up): ``v_car = R v_board``;
``rotation_from_rpy(roll, pitch, yaw)`` = ``Rz(yaw) Ry(pitch) Rx(roll)`` is the board's
orientation in the car. The car-frame reading is::

    omega_car = R (pi / 180) gyro_dps       a_car = R g0 acc_g      (g0 = 9.80665 m/s^2)
    yaw_rate = omega_car[2]; ax, ay = a_car[0], a_car[1]
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntFlag

import numpy as np

from shared.vesc.protocol import CommandId, encode_frame

#: Standard gravity [m/s^2]: the accelerometer's unit g in SI.
STANDARD_GRAVITY_MPS2 = 9.80665
#: Below this magnitude the firmware sends 0 (``buffer_append_float32_auto``).
FLOAT32_AUTO_ZERO_BELOW = 1.5e-38


class ImuField(IntFlag):
    """Bits of the COMM_GET_IMU_DATA mask (uint16), in wire order."""

    ROLL = 1 << 0
    PITCH = 1 << 1
    YAW = 1 << 2
    ACC_X = 1 << 3
    ACC_Y = 1 << 4
    ACC_Z = 1 << 5
    GYRO_X = 1 << 6
    GYRO_Y = 1 << 7
    GYRO_Z = 1 << 8
    MAG_X = 1 << 9
    MAG_Y = 1 << 10
    MAG_Z = 1 << 11
    Q0 = 1 << 12
    Q1 = 1 << 13
    Q2 = 1 << 14
    Q3 = 1 << 15


RPY = ImuField.ROLL | ImuField.PITCH | ImuField.YAW
ACCEL = ImuField.ACC_X | ImuField.ACC_Y | ImuField.ACC_Z
GYRO = ImuField.GYRO_X | ImuField.GYRO_Y | ImuField.GYRO_Z
MAG = ImuField.MAG_X | ImuField.MAG_Y | ImuField.MAG_Z
QUAT = ImuField.Q0 | ImuField.Q1 | ImuField.Q2 | ImuField.Q3
#: What the driver asks for: the full acceleration and rate vectors (the mounting rotation
#: needs all three axes of each), 0x01F8.
DRIVER_MASK = ACCEL | GYRO
ALL_FIELDS = RPY | ACCEL | GYRO | MAG | QUAT

#: Groups of the reply: (attribute of ``VescImu``, its bits in order).
_GROUPS: tuple[tuple[str, tuple[ImuField, ...]], ...] = (
    ("rpy_rad", (ImuField.ROLL, ImuField.PITCH, ImuField.YAW)),
    ("accel_g", (ImuField.ACC_X, ImuField.ACC_Y, ImuField.ACC_Z)),
    ("gyro_dps", (ImuField.GYRO_X, ImuField.GYRO_Y, ImuField.GYRO_Z)),
    ("mag", (ImuField.MAG_X, ImuField.MAG_Y, ImuField.MAG_Z)),
    ("quat", (ImuField.Q0, ImuField.Q1, ImuField.Q2, ImuField.Q3)),
)
#: Every bit in wire order with (group attribute, index in the group).
_BITS: tuple[tuple[ImuField, str, int], ...] = tuple(
    (bit, name, i) for name, bits in _GROUPS for i, bit in enumerate(bits)
)


# --------------------------------------------------------------------------- float32_auto
def float32_auto_encode(value: float) -> int:
    """The firmware's ``buffer_append_float32_auto`` word (uint32) for ``value``.

    Raises:
        ValueError: ``value`` is not finite (the firmware's encoding has no inf/NaN).
    """
    if not math.isfinite(value):
        raise ValueError(f"float32_auto cannot carry {value!r}")
    if abs(value) < FLOAT32_AUTO_ZERO_BELOW:
        value = 0.0
    try:
        value = struct.unpack(">f", struct.pack(">f", value))[0]  # round to single precision
    except OverflowError:
        raise ValueError(f"float32_auto cannot carry {value!r} (beyond float32)") from None
    sig, e = math.frexp(value)
    sig_abs = abs(sig)
    sig_i = 0
    if sig_abs >= 0.5:
        sig_i = int((sig_abs - 0.5) * 2.0 * 8388608.0)
        e += 126
    res = ((e & 0xFF) << 23) | (sig_i & 0x7FFFFF)
    if sig < 0:
        res |= 1 << 31
    return res


def float32_auto_decode(word: int) -> float:
    """The firmware's ``buffer_get_float32_auto`` of a uint32 ``word``."""
    e = (word >> 23) & 0xFF
    sig_i = word & 0x7FFFFF
    neg = bool(word & (1 << 31))
    sig = 0.0
    if e != 0 or sig_i != 0:
        sig = sig_i / (8388608.0 * 2.0) + 0.5
        e -= 126
    if neg:
        sig = -sig
    return math.ldexp(sig, e)


# --------------------------------------------------------------------------- request
def encode_get_imu_data(mask: int = DRIVER_MASK) -> bytes:
    """The COMM_GET_IMU_DATA request frame for ``mask`` (uint16, ``ImuField`` bits).

    ``encode_get_imu_data(0x01F8)`` = ``02 03 41 01 f8 <crc16> 03``.
    """
    if not 0 <= mask <= 0xFFFF:
        raise ValueError(f"mask must be a uint16, got {mask!r}")
    return encode_frame(struct.pack(">BH", CommandId.GET_IMU_DATA, mask))


def imu_request_mask(payload: bytes) -> int | None:
    """The mask of a COMM_GET_IMU_DATA request payload (None: not such a request)."""
    if len(payload) != 3 or payload[0] != CommandId.GET_IMU_DATA:
        return None
    return int(struct.unpack_from(">H", payload, 1)[0])


# --------------------------------------------------------------------------- reply
@dataclass(frozen=True, slots=True)
class VescImu:
    """One COMM_GET_IMU_DATA reply (board frame); a group is None when its bits were not
    all requested.

    Attributes:
        mask: the mask the reply carries.
        rpy_rad: (3,) roll, pitch, yaw [rad] of the firmware's AHRS.
        accel_g: (3,) specific force [g] (about +1 on z at rest, board level).
        gyro_dps: (3,) angular rate [deg/s].
        mag: (3,) magnetic field [uT].
        quat: (4,) attitude quaternion q0 (w), q1, q2, q3.
        controller_id: CAN id of the controller (None: not sent, older firmware).
    """

    mask: int
    rpy_rad: tuple[float, float, float] | None = None
    accel_g: tuple[float, float, float] | None = None
    gyro_dps: tuple[float, float, float] | None = None
    mag: tuple[float, float, float] | None = None
    quat: tuple[float, float, float, float] | None = None
    controller_id: int | None = None


def imu_reply_len(mask: int, with_controller_id: bool = True) -> int:
    """Payload length [bytes] of a reply to ``mask``: 1 + 2 + 4 popcount(mask) (+ 1)."""
    return 3 + 4 * bin(mask & 0xFFFF).count("1") + (1 if with_controller_id else 0)


def is_imu_reply(payload: bytes) -> bool:
    """True if the payload is a COMM_GET_IMU_DATA reply (by its command id)."""
    return len(payload) > 0 and payload[0] == CommandId.GET_IMU_DATA


def parse_imu(payload: bytes) -> VescImu | None:
    """Parse a COMM_GET_IMU_DATA reply payload (id first); never raises.

    Returns None (malformed) when the id is not GET_IMU_DATA, the payload is shorter than
    its mask says (or longer by more than the controller id), or a value is not finite.
    Groups whose bits are only partly present are left None.
    """
    if not is_imu_reply(payload) or len(payload) < 3:
        return None
    (mask,) = struct.unpack_from(">H", payload, 1)
    n = len(payload)
    if n not in (imu_reply_len(mask, True), imu_reply_len(mask, False)):
        return None
    values: dict[str, list[float | None]] = {name: [None] * len(bits) for name, bits in _GROUPS}
    pos = 3
    for bit, name, i in _BITS:
        if mask & bit:
            (word,) = struct.unpack_from(">I", payload, pos)
            pos += 4
            x = float32_auto_decode(word)
            if not math.isfinite(x):
                return None
            values[name][i] = x
    groups = {
        name: tuple(v) if all(x is not None for x in v) else None for name, v in values.items()
    }
    cid = payload[pos] if n > pos else None
    return VescImu(mask=int(mask), controller_id=cid, **groups)  # type: ignore[arg-type]


def encode_imu_payload(
    mask: int,
    *,
    rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
    accel_g: tuple[float, float, float] = (0.0, 0.0, 1.0),
    gyro_dps: tuple[float, float, float] = (0.0, 0.0, 0.0),
    mag: tuple[float, float, float] = (0.0, 0.0, 0.0),
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
    controller_id: int | None = 0,
) -> bytes:
    """A COMM_GET_IMU_DATA reply payload (what the firmware sends; the fake VESC's answer).

    Raises:
        ValueError: the mask is not a uint16 or a requested value is not finite.
    """
    if not 0 <= mask <= 0xFFFF:
        raise ValueError(f"mask must be a uint16, got {mask!r}")
    src = {"rpy_rad": rpy_rad, "accel_g": accel_g, "gyro_dps": gyro_dps, "mag": mag, "quat": quat}
    out = bytearray(struct.pack(">BH", CommandId.GET_IMU_DATA, mask))
    for bit, name, i in _BITS:
        if mask & bit:
            out += struct.pack(">I", float32_auto_encode(float(src[name][i])))
    if controller_id is not None:
        out.append(controller_id & 0xFF)
    return bytes(out)


# --------------------------------------------------------------------------- mounting
def rotation_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """(3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)``: the board's orientation in the car frame
    (``v_car = R v_board``) [angles in rad]."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


@dataclass(frozen=True, slots=True)
class CarImu:
    """An IMU reading in the car frame (x forward, y left, z up).

    Attributes:
        yaw_rate_radps: rate about z [rad/s], counter-clockwise positive.
        ax_mps2, ay_mps2: specific force along x (forward) and y (left) [m/s^2].
    """

    yaw_rate_radps: float
    ax_mps2: float
    ay_mps2: float


def imu_in_car(imu: VescImu, rotation: np.ndarray) -> CarImu | None:
    """The car-frame reading of a reply (see the module docstring); None without both the
    full acceleration and the full rate vector."""
    if imu.accel_g is None or imu.gyro_dps is None:
        return None
    omega = rotation @ np.radians(np.asarray(imu.gyro_dps, dtype=float))
    acc = rotation @ (STANDARD_GRAVITY_MPS2 * np.asarray(imu.accel_g, dtype=float))
    return CarImu(yaw_rate_radps=float(omega[2]), ax_mps2=float(acc[0]), ay_mps2=float(acc[1]))


def board_reading(
    car: CarImu, rotation: np.ndarray, az_mps2: float = STANDARD_GRAVITY_MPS2
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The inverse of ``imu_in_car`` for a fake VESC: the board's (accel [g], gyro [deg/s])
    of a car-frame reading on level ground (``az_mps2``: specific force along the car's z,
    +g at rest; roll and pitch rates 0)."""
    rt = rotation.T
    acc = rt @ np.array([car.ax_mps2, car.ay_mps2, az_mps2]) / STANDARD_GRAVITY_MPS2
    gyro = np.degrees(rt @ np.array([0.0, 0.0, car.yaw_rate_radps]))
    return (
        (float(acc[0]), float(acc[1]), float(acc[2])),
        (float(gyro[0]), float(gyro[1]), float(gyro[2])),
    )
