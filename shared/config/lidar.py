"""Settings of the Hokuyo lidar driver (``[lidar_driver]``): where the sensor is, what to ask
for, how its beams sit in the car frame, and the timeouts that keep the driver alive.

``port`` is a serial device (the USB UTM-30LX, baud rate ignored by USB ACM) or
``tcp://HOST:PORT`` for the Ethernet models (UST-10LX, UTM-30LX-EW: port 10940). The default
``/dev/sensors/hokuyo`` is a stable name made by a udev rule (the README's "The real car" has
it: the Hokuyo's USB id 15d1:0000), distinct from the VESC's ``/dev/sensors/vesc``;
``/dev/serial/by-id/usb-Hokuyo_...`` works as well, a bare ``/dev/ttyACMn`` may swap with the
VESC's between boots. The user needs the ``dialout`` group.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, model_validator

from shared.config.base import Section

__all__ = ["LidarDriverSettings"]


class LidarDriverSettings(Section):
    """The lidar driver's settings (units in the names)."""

    port: str = Field(
        "/dev/sensors/hokuyo",
        min_length=1,
        description=(
            "serial device (the udev link /dev/sensors/hokuyo, /dev/serial/by-id/...) or "
            "tcp://host:port"
        ),
    )
    baudrate: int = Field(115200, gt=0, le=4_000_000, description="serial baud rate [bit/s]")
    intensity: bool = Field(False, description="ask for intensities (ME instead of MD)")
    first_step: int | None = Field(None, ge=0, le=9999, description="None: the sensor's AMIN")
    last_step: int | None = Field(None, ge=0, le=9999, description="None: the sensor's AMAX")
    cluster: int = Field(1, ge=1, le=99, description="steps merged into one beam")
    skip: int = Field(0, ge=0, le=9, description="scans skipped between two sent ones")
    mount_yaw_rad: float = Field(
        0.0, ge=-math.pi, le=math.pi, allow_inf_nan=False, description="sensor yaw in the car"
    )
    upside_down: bool = Field(False, description="mounted upside down (beams turn clockwise)")
    range_min_m: float = Field(
        0.02, ge=0.0, le=100.0, allow_inf_nan=False, description="shorter -> +inf"
    )
    range_max_m: float = Field(
        30.0, gt=0.0, le=1000.0, allow_inf_nan=False, description="longer -> +inf"
    )
    stamp_source: Literal["tm", "min_filter", "host"] = Field(
        "tm", description="scan stamps: TM offset at connect, receipt min-filter, or receipt"
    )
    time_sync_window_s: float = Field(
        10.0, gt=0.0, le=3600.0, allow_inf_nan=False, description="min-filter window"
    )
    tm_samples: int = Field(5, ge=1, le=50, description="TM1 round trips at connect")
    reconnect_period_s: float = Field(
        1.0, gt=0.0, le=60.0, allow_inf_nan=False, description="retry period of a lost link"
    )
    silence_timeout_s: float = Field(
        0.5, gt=0.0, le=60.0, allow_inf_nan=False, description="no scan for this -> reconnect"
    )
    reply_timeout_s: float = Field(
        1.0, gt=0.0, le=60.0, allow_inf_nan=False, description="wait for one handshake reply"
    )
    handshake_attempts: int = Field(3, ge=1, le=100, description="tries of a handshake step")
    event_interval_s: float = Field(
        1.0, ge=0.0, le=600.0, allow_inf_nan=False, description="rate limit of event lines"
    )

    @model_validator(mode="after")
    def _check(self) -> LidarDriverSettings:
        if self.range_min_m >= self.range_max_m:
            raise ValueError("range_min_m must be < range_max_m")
        if (
            self.first_step is not None
            and self.last_step is not None
            and self.first_step > self.last_step
        ):
            raise ValueError("first_step must be <= last_step")
        if self.port.startswith("tcp://"):
            host, sep, port = self.port[6:].rpartition(":")
            if not (sep and host and port.isdigit() and 0 < int(port) < 65536):
                raise ValueError(f"port {self.port!r}: expected tcp://HOST:PORT")
        return self
