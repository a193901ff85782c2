"""The VESC serial protocol (firmware 3+), shared by the vesc_driver and the simulator.

Pure modules, no I/O (the caller passes bytes and times):

* ``crc``: CRC-16/XMODEM (``crc16_xmodem``, ``binascii.crc_hqx``);
* ``protocol``: command ids, frame layout and the command encoders / value decoder;
* ``decoder``: the streaming frame decoder (``FrameDecoder``);
* ``values``: the COMM_GET_VALUES reply layout, ``parse_values`` and ``encode_values_payload``;
* ``imu``: COMM_GET_IMU_DATA (request mask, reply layout, float32_auto) and the mounting
  rotation of the board in the car (``imu_in_car``);
* ``conversions``: m/s <-> ERPM and rad <-> servo position;
* ``fake``: the firmware side of a fake VESC (``FakeVescModel``).

``shared.vesc.fake_pty`` is the one module with I/O: ``FakeVesc`` puts the fake model on a
pseudo-terminal (test and simulation infrastructure; import it explicitly).
"""

from shared.vesc.conversions import (
    erpm_to_speed,
    servo_to_steering,
    speed_to_erpm,
    steering_to_servo,
    yaw_rate_from,
)
from shared.vesc.crc import crc16_xmodem
from shared.vesc.decoder import DecoderCounters, Frame, FrameDecoder
from shared.vesc.fake import (
    DEFAULT_VALUES,
    FakeEvent,
    FakeImu,
    FakeMotorState,
    FakeVescModel,
    ReplyImuHook,
    ReplyValuesHook,
    default_reply_values,
)
from shared.vesc.imu import (
    DRIVER_MASK,
    CarImu,
    ImuField,
    VescImu,
    encode_get_imu_data,
    encode_imu_payload,
    imu_in_car,
    is_imu_reply,
    parse_imu,
    rotation_from_rpy,
)
from shared.vesc.protocol import (
    TIMEOUT_RESETTING_COMMANDS,
    CommandId,
    decode_command_value,
    encode_alive,
    encode_frame,
    encode_get_values,
    encode_set_current,
    encode_set_current_brake,
    encode_set_duty,
    encode_set_rpm,
    encode_set_servo_pos,
)
from shared.vesc.values import VescValues, encode_values_payload, is_values_reply, parse_values

__all__ = [
    "DEFAULT_VALUES",
    "DRIVER_MASK",
    "TIMEOUT_RESETTING_COMMANDS",
    "CarImu",
    "CommandId",
    "DecoderCounters",
    "FakeEvent",
    "FakeImu",
    "FakeMotorState",
    "FakeVescModel",
    "Frame",
    "FrameDecoder",
    "ImuField",
    "ReplyImuHook",
    "ReplyValuesHook",
    "VescImu",
    "VescValues",
    "crc16_xmodem",
    "decode_command_value",
    "default_reply_values",
    "encode_alive",
    "encode_frame",
    "encode_get_imu_data",
    "encode_get_values",
    "encode_imu_payload",
    "encode_set_current",
    "encode_set_current_brake",
    "encode_set_duty",
    "encode_set_rpm",
    "encode_set_servo_pos",
    "encode_values_payload",
    "erpm_to_speed",
    "imu_in_car",
    "is_imu_reply",
    "is_values_reply",
    "parse_imu",
    "parse_values",
    "rotation_from_rpy",
    "servo_to_steering",
    "speed_to_erpm",
    "steering_to_servo",
    "yaw_rate_from",
]
