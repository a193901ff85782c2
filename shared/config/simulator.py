"""Settings of the simulator: the plant's vehicle, integration, actuation, sensors, seed.

The plant's vehicle is ``[vehicle]`` unless ``[simulator.vehicle]`` overrides it (resolved by
``shared.config.root``; a ``SimulatorSettings`` alone defaults to the F1TENTH gym's car).

Defaults follow the F1TENTH gym (``../shared/docs/vehicle-and-vesc.md``) where it has a value;
the rest are documented choices for a 1:10 car with a lidar localiser.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from shared.config.base import Section
from shared.config.vehicle import DynamicVehicleParams

NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Rate = Annotated[float, Field(gt=0.0, le=10000.0, allow_inf_nan=False)]

OffTrackPolicy = Literal["continue", "stop", "reset_to_centreline"]


class PoseSensorSettings(Section):
    """Pose as a lidar localiser delivers it: captured at `rate_hz`, released `latency_s` later.

    Each measurement is stamped with its capture time; noise is white Gaussian.
    """

    rate_hz: Rate = Field(40.0, description="capture rate [Hz]")
    latency_s: float = Field(0.02, ge=0.0, le=2.0, description="capture -> release delay [s]")
    position_noise_std_m: NonNeg = Field(0.01, description="std of x and y each [m]")
    yaw_noise_std_rad: NonNeg = Field(0.005, description="std of yaw [rad]")


class ImuSettings(Section):
    """IMU: yaw rate and body-frame longitudinal / lateral acceleration at the CoG."""

    rate_hz: Rate = Field(100.0, description="sample rate [Hz] (at most one per sim step)")
    yaw_rate_noise_std_radps: NonNeg = Field(0.01, description="std of yaw rate [rad/s]")
    accel_noise_std_mps2: NonNeg = Field(0.05, description="std of each acceleration [m/s^2]")


class OdometrySettings(Section):
    """Wheel odometry: wheel speed (``v cos(beta)``, longitudinal) and road-wheel angle."""

    rate_hz: Rate = Field(50.0, description="sample rate [Hz] (VESC core state)")
    speed_noise_std_mps: NonNeg = Field(0.02, description="std of the wheel speed [m/s]")
    steering_noise_std_rad: NonNeg = Field(0.0, description="std of the steering angle [rad]")


class LidarSettings(Section):
    """2-D lidar simulated by ray marching on the occupancy map (F1TENTH gym defaults)."""

    rate_hz: Rate = Field(20.0, description="scan rate [Hz]")
    beams: int = Field(1080, ge=2, le=100000, description="beams per scan")
    fov_rad: float = Field(4.7, gt=0.0, le=6.2832, description="field of view, centred ahead")
    range_max_m: float = Field(30.0, gt=0.0, le=1000.0, description="maximum range [m]")
    noise_std_m: NonNeg = Field(0.01, description="std of the range noise on hits [m]")
    mount_x_m: float = Field(
        0.0, ge=-2.0, le=2.0, description="sensor ahead of the CoG along the car's x axis [m]"
    )
    unknown_is_occupied: bool = Field(
        True, description="unknown map cells stop beams (False: they are free, like the gym)"
    )


class SimulatorSettings(Section):
    """The simulated plant: vehicle, integration, actuation, sensors, seed, off-track policy.

    Actuation path of a command (speed [m/s], steering [rad]) received at time t:
    both channels wait `actuation_delay_s` (transport, VESC serial, servo PWM frame); the
    steering channel additionally waits `steering_delay_s` (the gym's 2-step steering buffer
    at 10 ms). Then the speed and servo P-controllers of `vehicle` act. If no command newer
    than `command_timeout_s` has arrived (after the delay), the speed target is 0 (brake) and
    the servo holds its last target, like a VESC timeout.

    Where commands come from (`actuation`): "bus" (default) takes ``DriveCmd`` from
    ``cmd/drive``. "fake_vesc" runs the real actuation chain in simulation: the simulator
    owns a fake VESC on a pseudo-terminal reachable at the stable symlink `fake_vesc_link`,
    the vesc_driver service's ``[vesc] port`` points at that same path, and the car is driven
    by the SET_RPM / SET_SERVO_POS / brake frames the driver writes (converted back with the
    ``[vesc]`` gains); GET_VALUES is answered with the simulated wheel speed as ERPM, so the
    vesc_driver's ``vehicle/odom`` is the odometry (the simulator then publishes none).
    """

    vehicle: DynamicVehicleParams = Field(
        DynamicVehicleParams(),
        description="Optional: the car the simulator races when it is not [vehicle] (a "
        "model-mismatch experiment; the planners keep [vehicle]). Absent: [vehicle]. Its "
        "keys change [vehicle]'s; a preset given here starts from that preset instead. The "
        "defaults below are those of the preset f1tenth_gym",
    )
    integration_step_s: float = Field(
        0.01,
        gt=0.0,
        le=0.01,
        description="fixed RK4 step [s]; at most 0.01 s (split further only where the "
        "low-speed lateral dynamics would make RK4 unstable)",
    )
    steering_delay_s: float = Field(
        0.02, ge=0.0, le=1.0, description="extra steering delay [s] (gym: 2 steps of 10 ms)"
    )
    actuation_delay_s: float = Field(
        0.01,
        ge=0.0,
        le=1.0,
        description="delay of both channels [s]: Zenoh + VESC serial + servo PWM, ~1 period",
    )
    command_timeout_s: float = Field(
        0.1, gt=0.0, le=10.0, description="brake when the newest command is older [s] (VESC)"
    )
    timeout_brake_gain_per_s: float = Field(
        60.0,
        gt=0.0,
        le=1000.0,
        description="speed-loop gain [1/s] while braking for a command timeout (brake current: "
        "the acceleration limit acts down to ~ a_max / gain m/s)",
    )
    kinematic_below_mps: float = Field(
        0.5, gt=0.0, le=5.0, description="below this |v| the kinematic model applies [m/s]"
    )
    kinematic_blend_mps: float = Field(
        0.2,
        ge=0.0,
        le=5.0,
        description="width of the smooth kinematic -> dynamic blend above kinematic_below_mps "
        "[m/s]; 0 switches hard like the gym",
    )
    actuation: Literal["bus", "fake_vesc"] = Field(
        "bus",
        description='"bus": commands from cmd/drive; "fake_vesc": from the frames a '
        "vesc_driver writes to the simulator's fake VESC at fake_vesc_link",
    )
    fake_vesc_link: str = Field(
        "/tmp/racestack-fake-vesc",
        min_length=1,
        description="symlink the simulator points at its fake VESC's pty (actuation = "
        '"fake_vesc"); set [vesc] port to the same path. An existing symlink there is '
        "replaced, any other file is an error",
    )
    pose: PoseSensorSettings = PoseSensorSettings()
    imu: ImuSettings = ImuSettings()
    odometry: OdometrySettings = OdometrySettings()
    lidar: LidarSettings = LidarSettings()
    seed: int = Field(0, ge=0, description="seed of all sensor noise (numpy Generator)")
    off_track_policy: OffTrackPolicy = Field(
        "continue",
        description="what the simulator service does when the footprint leaves the track: "
        '"continue" drives on; "stop" ignores drive commands from then on (the command '
        'timeout brakes the car) until a sim/control "reset" or "resume"; '
        '"reset_to_centreline" puts the car back on the centreline at its projection, at '
        "rest. Each is counted and said on events/log (the bench's closed loop does not "
        "read it)",
    )
    contact_restitution: float = Field(
        0.3, ge=0.0, le=1.0, allow_inf_nan=False,
        description="several cars ([[cars]]): restitution of a car-to-car impact along the "
        "contact normal (0: plastic; services/simulator/collision.py)",
    )
    contact_speed_loss: float = Field(
        0.2, ge=0.0, lt=1.0, allow_inf_nan=False,
        description="several cars: fraction of each car's speed lost at an impact (a "
        "contact is never a free pass)",
    )

    @model_validator(mode="after")
    def _consistent(self) -> SimulatorSettings:
        if self.command_timeout_s <= self.integration_step_s:
            raise ValueError("command_timeout_s must exceed integration_step_s")
        return self
