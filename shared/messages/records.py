"""The message records of racestack (one frozen, validated msgspec Struct per message type).

Units are in the field names (``_m``, ``_rad``, ``_mps``, ``_radps``, ``_mps2``, ``_s``,
``_ms``, ``_a``, ``_v``, ``_c``). Every record also has ``stamp_s`` (the sender's clock [s])
and ``seq`` (stamped by the bus publisher); all fields are keyword-only. The ranges below
are plausibility limits that keep garbage away from the maths, not the car's actuator limits.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Annotated, Literal, get_args

import msgspec
import numpy as np
from msgspec import Meta

from shared.config.methods import planner_methods
from shared.messages.codec import (
    MAX_STAMP_S,
    MAX_STR_LEN,
    Array,
    Message,
    MessageError,
    _field_error,
    _plain,
    coerce_arrays,
)

#: |x|, |y| limit of positions [m].
MAX_POS_M = 1e4
#: |angle| limit [rad] of headings (unwrapped headings are allowed, NaN/inf are not).
MAX_ANGLE_RAD = 1e4
#: |speed| limit [m/s].
MAX_SPEED_MPS = 50.0
#: |steering angle| limit [rad].
MAX_STEER_RAD = 1.0
#: |yaw rate| limit [rad/s].
MAX_YAW_RATE_RADPS = 50.0
#: |acceleration| limit [m/s^2].
MAX_ACCEL_MPS2 = 500.0
#: Progress limit [m] (predicted progress may exceed the lap length).
MAX_S_M = 1e6
#: |contour error| limit [m].
MAX_E_CON_M = 1e3
#: Longest plan horizon N accepted (stages).
MAX_HORIZON = 1000
#: Most beams of a scan.
MAX_BEAMS = 100_000
#: Longest name of a log source [characters].
MAX_SOURCE_LEN = 64
#: Most tracks in one ``Opponents`` record.
MAX_OPPONENTS = 64
#: Largest opponent footprint side ``length_m`` / ``width_m`` [m].
MAX_CAR_SIZE_M = 10.0
#: Smallest opponent footprint side [m].
MIN_CAR_SIZE_M = 0.01
#: Largest variance of an opponent track (position [m^2], speed [m^2/s^2]).
MAX_TRACK_VAR = 1e6


# Field types: a float (an int is accepted and stored as a float) or an int in a range, bounds
# included; msgspec enforces them in C.
Pos = Annotated[float, Meta(ge=-MAX_POS_M, le=MAX_POS_M)]
Angle = Annotated[float, Meta(ge=-MAX_ANGLE_RAD, le=MAX_ANGLE_RAD)]
Speed = Annotated[float, Meta(ge=-MAX_SPEED_MPS, le=MAX_SPEED_MPS)]
Steer = Annotated[float, Meta(ge=-MAX_STEER_RAD, le=MAX_STEER_RAD)]
YawRate = Annotated[float, Meta(ge=-MAX_YAW_RATE_RADPS, le=MAX_YAW_RATE_RADPS)]
Accel = Annotated[float, Meta(ge=-MAX_ACCEL_MPS2, le=MAX_ACCEL_MPS2)]
Progress = Annotated[float, Meta(ge=-MAX_S_M, le=MAX_S_M)]
ECon = Annotated[float, Meta(ge=-MAX_E_CON_M, le=MAX_E_CON_M)]
Stamp = Annotated[float, Meta(ge=0.0, le=MAX_STAMP_S)]
Temp = Annotated[float, Meta(ge=-100.0, le=300.0)]
Current = Annotated[float, Meta(ge=-1000.0, le=1000.0)]
Count = Annotated[int, Meta(ge=0, le=10**9)]
Byte = Annotated[int, Meta(ge=0, le=255)]


class PoseAxis(IntEnum):
    """Row/column of ``Pose.cov``: covariance of [x_m, y_m, yaw_rad]."""

    X = 0
    Y = 1
    YAW = 2


class HorizonCol(IntEnum):
    """Column of ``Plan.horizon``: the predicted model state [X, Y, phi, s]."""

    X = 0
    Y = 1
    PHI = 2
    PROGRESS = 3


class InputCol(IntEnum):
    """Column of ``Plan.inputs``: the planned inputs [v_l, delta, v_p]."""

    V_L = 0
    DELTA = 1
    V_P = 2


# The allowed strings of the choice fields (msgspec rejects any other value); code names them
# with the StrEnums of shared.messages.vocab (checked against these at import).
PlanStatus = Literal["solved", "fallback", "braking", "recovering"]
#: The methods a plan may come from: the planner service's (the registry, shared.config.methods).
PlanMethod = Literal[planner_methods()]  # type: ignore[valid-type]
LapKind = Literal["start", "lap", "off_track", "back_on_track"]
LogLevel = Literal["debug", "info", "warning", "error"]
SimAction = Literal["reset", "pause", "resume"]
VescStatus = Literal["ok", "fault", "stale", "disconnected"]
PLAN_STATUSES: tuple[str, ...] = get_args(PlanStatus)
PLAN_METHODS: tuple[str, ...] = get_args(PlanMethod)
LAP_KINDS: tuple[str, ...] = get_args(LapKind)
LOG_LEVELS: tuple[str, ...] = get_args(LogLevel)
SIM_ACTIONS: tuple[str, ...] = get_args(SimAction)
VESC_STATUSES: tuple[str, ...] = get_args(VescStatus)


_COV = Array("<f8", ndim=2, cols=len(PoseAxis), min_len=len(PoseAxis), max_len=len(PoseAxis))
_RANGES = Array("<f4", ndim=1, min_len=1, max_len=MAX_BEAMS, lo=0.0, allow_pos_inf=True)


def _bad(record: Message, text: str) -> MessageError:
    return MessageError("bad_value", f"{type(record).__name__}: {text}")


class Pose(Message):
    """Pose of the car from a localiser or the simulator (map frame).

    Attributes:
        x_m, y_m: position [m].
        yaw_rad: heading [rad], counter-clockwise from the map x axis.
        cov: optional 3x3 covariance of [x_m, y_m, yaw_rad] ([m^2], [m rad], [rad^2];
            index with ``PoseAxis``), symmetric with a non-negative diagonal; None if unknown.
    """

    TYPE = "pose"

    x_m: Pos
    y_m: Pos
    yaw_rad: Angle
    cov: Annotated[np.ndarray, _COV] | None = None

    def __post_init__(self) -> None:
        coerce_arrays(self)
        c = self.cov
        if c is not None:
            if np.any(np.diag(c) < 0.0):
                raise _bad(self, "cov has a negative variance")
            if not np.allclose(c, c.T, rtol=1e-6, atol=1e-9):
                raise _bad(self, "cov is not symmetric")


class Imu(Message):
    """IMU reading in the car frame.

    Attributes:
        yaw_rate_radps: yaw rate [rad/s], counter-clockwise positive.
        ax_mps2, ay_mps2: longitudinal and lateral acceleration [m/s^2] (forward, left).
    """

    TYPE = "imu"

    yaw_rate_radps: YawRate
    ax_mps2: Accel
    ay_mps2: Accel


class Odom(Message):
    """Wheel odometry from the VESC driver or the simulator.

    Attributes:
        speed_mps: longitudinal speed [m/s] (negative when reversing).
        steering_rad: front steering angle [rad], left positive.
        yaw_rate_radps: yaw rate [rad/s] if the source knows it, else None.
    """

    TYPE = "odom"

    speed_mps: Speed
    steering_rad: Steer
    yaw_rate_radps: YawRate | None = None


class Scan(Message):
    """A 2D lidar scan; beam i points at ``angle_min_rad + i * angle_increment_rad``.

    Attributes:
        angle_min_rad: angle of the first beam [rad] in the car frame (finite, |.| <= 2 pi).
        angle_increment_rad: angle between beams [rad] (non-zero, |.| <= pi).
        ranges_m: float32 (n,) measured ranges [m], >= 0; ``+inf`` means no return (NaN is
            rejected). n >= 1.
    """

    TYPE = "scan"

    angle_min_rad: Annotated[float, Meta(ge=-2 * math.pi, le=2 * math.pi)]
    angle_increment_rad: Annotated[float, Meta(ge=-math.pi, le=math.pi)]
    ranges_m: Annotated[np.ndarray, _RANGES]

    def __post_init__(self) -> None:
        coerce_arrays(self)
        if self.angle_increment_rad == 0.0:
            raise _bad(self, "angle_increment_rad is zero")

    def angles_rad(self) -> np.ndarray:
        """(n,) float64 beam angles [rad]."""
        n = self.ranges_m.shape[0]
        return self.angle_min_rad + self.angle_increment_rad * np.arange(n, dtype=float)


class State(Message):
    """The fused state of the car (localization bridge), what the planner starts from.

    Attributes:
        x_m, y_m: position [m]; yaw_rad: heading [rad].
        speed_mps: longitudinal speed [m/s]; yaw_rate_radps: yaw rate [rad/s].
        steering_rad: current steering angle [rad].
        source_stamp_s: ``stamp_s`` of the newest input it was built from [s].
        valid: False while the bridge has no trustworthy estimate (planner must not race).
    """

    TYPE = "state"

    x_m: Pos
    y_m: Pos
    yaw_rad: Angle
    speed_mps: Speed
    yaw_rate_radps: YawRate
    steering_rad: Steer
    source_stamp_s: Stamp
    valid: bool


class DriveCmd(Message):
    """What the planner commands: speed [m/s] and front steering angle [rad] (left +)."""

    TYPE = "drive_cmd"
    RELIABLE = True

    speed_mps: Speed
    steering_rad: Steer


_HORIZON = Array(
    "<f8", ndim=2, cols=len(HorizonCol), min_len=2, max_len=MAX_HORIZON + 1, lo=-MAX_S_M, hi=MAX_S_M
)
_INPUTS = Array(
    "<f8",
    ndim=2,
    cols=len(InputCol),
    min_len=1,
    max_len=MAX_HORIZON,
    lo=-MAX_SPEED_MPS,
    hi=MAX_SPEED_MPS,
)
_BETA = Array("<f8", ndim=1, min_len=1, max_len=MAX_HORIZON, lo=0.0, hi=1.0)


class Plan(Message):
    """One planner tick: the predicted horizon, the inputs, beta and solver statistics.

    Attributes:
        horizon: float64 (N+1, 4) predicted states [X m, Y m, phi rad, s m] (``HorizonCol``).
        inputs: float64 (N, 3) planned inputs [v_l m/s, delta rad, v_p m/s] (``InputCol``).
        beta: float64 (N,) curvature weight beta in [0, 1] of each stage (a single beta is
            sent repeated N times).
        status: "solved" | "fallback" (shifted previous plan) | "braking" | "recovering"
            (the car is lost: the recovery rule drives, see services/planner/recovery.py).
        solver_status: the solver back-end's own status text (<= 200 chars).
        iterations: solver iterations; solve_time_ms: wall time of the solve [ms].
        method: "cimpcc" | "mpcc" | "raceline".
        s_m: the car's progress [m]; e_con_m: its contour error [m] (right of centreline +).
        source_stamp_s: ``stamp_s`` of the State the plan was computed from [s].
        consecutive_failures: failed solves in a row, this one included.
    """

    TYPE = "plan"

    horizon: Annotated[np.ndarray, _HORIZON]
    inputs: Annotated[np.ndarray, _INPUTS]
    beta: Annotated[np.ndarray, _BETA]
    status: PlanStatus
    solver_status: Annotated[str, Meta(max_length=200)]
    iterations: Annotated[int, Meta(ge=0, le=10**7)]
    solve_time_ms: Annotated[float, Meta(ge=0.0, le=1e6)]
    method: PlanMethod
    s_m: Progress
    e_con_m: ECon
    source_stamp_s: Stamp
    consecutive_failures: Count

    def __post_init__(self) -> None:
        coerce_arrays(self)
        n = self.inputs.shape[0]
        if self.horizon.shape[0] != n + 1:
            raise _bad(self, f"horizon has {self.horizon.shape[0]} rows, inputs {n}: need N+1")
        if self.beta.shape[0] != n:
            raise _bad(self, f"beta has {self.beta.shape[0]} values for N = {n} stages")
        xy = self.horizon[:, [HorizonCol.X, HorizonCol.Y]]
        if np.abs(xy).max() > MAX_POS_M:
            raise MessageError("out_of_range", f"Plan.horizon: a position beyond {MAX_POS_M} m")
        if np.abs(self.horizon[:, HorizonCol.PHI]).max() > MAX_ANGLE_RAD:
            raise MessageError("out_of_range", "Plan.horizon: a heading beyond the limit")
        if np.abs(self.inputs[:, InputCol.DELTA]).max() > MAX_STEER_RAD:
            raise MessageError("out_of_range", f"Plan.inputs: |delta| > {MAX_STEER_RAD} rad")

    @property
    def n(self) -> int:
        """The horizon length N (stages)."""
        return int(self.inputs.shape[0])


class LapEvent(Message):
    """A lap event of the lap counter (the simulator's lap timer).

    Attributes:
        kind: "start" (timing started), "lap" (a lap completed), "off_track" (the car left
            the track), "back_on_track".
        lap: number of completed laps (for "lap": the one just completed, 1-based).
        lap_time_s: time of the completed lap [s] ("lap" only, else None).
        mean_speed_mps: mean speed over that lap [m/s] (or None).
        off_track_events: off-track events during the lap so far.
        max_abs_e_con_m: largest |contour error| during the lap so far [m] (or None).
    """

    TYPE = "lap_event"
    RELIABLE = True

    kind: LapKind
    lap: Count
    lap_time_s: Annotated[float, Meta(ge=0.0, le=1e6)] | None = None
    mean_speed_mps: Speed | None = None
    off_track_events: Count
    max_abs_e_con_m: Annotated[float, Meta(ge=0.0, le=MAX_E_CON_M)] | None = None

    def __post_init__(self) -> None:
        if self.kind == "lap" and self.lap_time_s is None:
            raise _bad(self, 'a "lap" event needs lap_time_s')


class VescState(Message):
    """Motor controller values (VESC COMM_GET_VALUES); None where unknown or not reported.

    Attributes:
        temp_fet_c, temp_motor_c, temp_mos1_c..temp_mos3_c: temperatures [deg C].
        avg_motor_current_a, avg_input_current_a, avg_id_a, avg_iq_a: currents [A].
        duty: duty cycle [-1, 1]; erpm: electrical rpm [1/min].
        v_in_v: input voltage [V]; avg_vd_v, avg_vq_v: d/q voltages [V].
        amp_hours, amp_hours_charged: charge [Ah]; watt_hours, watt_hours_charged: [Wh].
        tachometer, tachometer_abs: tachometer counts (signed and absolute).
        pid_pos_deg: PID position [deg]; controller_id: CAN id of the controller.
        fault_code: mc_fault_code (0 = none).
        status: the driver's link status: "ok" | "fault" | "stale" | "disconnected".
    """

    TYPE = "vesc_state"

    status: VescStatus
    temp_fet_c: Temp | None = None
    temp_motor_c: Temp | None = None
    avg_motor_current_a: Current | None = None
    avg_input_current_a: Current | None = None
    avg_id_a: Current | None = None
    avg_iq_a: Current | None = None
    duty: Annotated[float, Meta(ge=-1.0, le=1.0)] | None = None
    erpm: Annotated[float, Meta(ge=-1e6, le=1e6)] | None = None
    v_in_v: Annotated[float, Meta(ge=0.0, le=200.0)] | None = None
    amp_hours: Annotated[float, Meta(ge=0.0, le=1e6)] | None = None
    amp_hours_charged: Annotated[float, Meta(ge=0.0, le=1e6)] | None = None
    watt_hours: Annotated[float, Meta(ge=0.0, le=1e7)] | None = None
    watt_hours_charged: Annotated[float, Meta(ge=0.0, le=1e7)] | None = None
    tachometer: Annotated[int, Meta(ge=-(2**31), le=2**31 - 1)] | None = None
    tachometer_abs: Annotated[int, Meta(ge=0, le=2**32 - 1)] | None = None
    fault_code: Byte | None = None
    pid_pos_deg: Annotated[float, Meta(ge=-1e6, le=1e6)] | None = None
    controller_id: Byte | None = None
    temp_mos1_c: Temp | None = None
    temp_mos2_c: Temp | None = None
    temp_mos3_c: Temp | None = None
    avg_vd_v: Current | None = None
    avg_vq_v: Current | None = None


class SimTruth(Message):
    """Simulator ground truth (full dynamic state and track-relative quantities).

    Attributes:
        x_m, y_m, yaw_rad: pose [m, m, rad]; speed_mps: speed at the centre of gravity [m/s].
        yaw_rate_radps: yaw rate [rad/s]; slip_rad: side slip angle at the CoG [rad].
        steering_rad: actual front steering angle [rad].
        s_m: progress along the centreline [m]; e_con_m: contour error [m] (right +).
        off_track: True while the car is outside the track bounds.
        lap: completed laps.
    """

    TYPE = "sim_truth"

    x_m: Pos
    y_m: Pos
    yaw_rad: Angle
    speed_mps: Speed
    yaw_rate_radps: YawRate
    slip_rad: Annotated[float, Meta(ge=-math.pi, le=math.pi)]
    steering_rad: Steer
    s_m: Progress
    e_con_m: ECon
    off_track: bool
    lap: Count


class LogEvent(Message):
    """A warning or text log record of any service.

    Attributes:
        level: "debug" | "info" | "warning" | "error".
        source: the emitting service (<= 64 chars).
        text: the message (<= 8192 chars; senders truncate longer text).
    """

    TYPE = "log_event"
    RELIABLE = True

    level: LogLevel
    source: Annotated[str, Meta(max_length=MAX_SOURCE_LEN)]
    text: Annotated[str, Meta(max_length=MAX_STR_LEN)]


class SimControl(Message):
    """A request to the simulator: action "reset" | "pause" | "resume"."""

    TYPE = "sim_control"
    RELIABLE = True

    action: SimAction


class Teleport(Message):
    """The car was put somewhere else at `stamp_s`: a simulator reset, the simulator's
    off-track marshal, or an operator placing the car on the track.

    A pose filter re-initialises at this pose at once instead of gating the jump; poses,
    odometry and IMU readings stamped at or before `stamp_s` describe the car before the
    teleport.

    Attributes:
        x_m, y_m: REAR-AXLE position after the teleport [m] (as ``Pose``, map frame).
        yaw_rad: heading after the teleport [rad].
        speed_mps: speed after the teleport [m/s] (0: placed at rest).
    """

    TYPE = "teleport"
    RELIABLE = True

    x_m: Pos
    y_m: Pos
    yaw_rad: Angle
    speed_mps: Speed = 0.0


Variance = Annotated[float, Meta(ge=0.0, le=MAX_TRACK_VAR)]
CarSize = Annotated[float, Meta(ge=MIN_CAR_SIZE_M, le=MAX_CAR_SIZE_M)]
OpponentFrame = Literal["map"]


class _CheckedStructMeta(msgspec.StructMeta):
    """A nested record's validating constructor: keyword arguments converted by msgspec (the
    same rules as on decoding), ``MessageError`` if one is broken."""

    def __call__(cls, *args: object, **kwargs: object) -> object:  # noqa: N805
        if args:
            raise TypeError(f"{cls.__name__}() takes keyword arguments only")
        plain = {k: _plain(v) for k, v in kwargs.items()}
        try:
            return msgspec.convert(plain, cls)
        except msgspec.ValidationError as exc:
            raise _field_error(cls, exc, plain.get) from None  # type: ignore[arg-type]


class OpponentTrack(msgspec.Struct, metaclass=_CheckedStructMeta, frozen=True, kw_only=True,
                    forbid_unknown_fields=False):
    """One tracked opponent of an ``Opponents`` record (map frame; not a message itself).

    Attributes:
        id: the track's id, kept for its life (1, 2, ... in birth order per tracker).
        x_m, y_m: centre of the opponent's footprint [m].
        vx_mps, vy_mps: its velocity [m/s].
        yaw_rad: heading of the footprint's long axis [rad] (from the box fit; the
            velocity's direction tells front from back).
        length_m, width_m: footprint [m] (0.01 .. 10).
        cov_xx_m2, cov_xy_m2, cov_yy_m2: position covariance [m^2] (variances >= 0,
            |xy| <= sqrt(xx yy) up to rounding).
        speed_var_m2ps2: variance of the speed along the velocity [m^2/s^2] (>= 0).
        age_s: time since the track was born [s]; hits: detections associated so far.
    """

    id: Count
    x_m: Pos
    y_m: Pos
    vx_mps: Speed
    vy_mps: Speed
    yaw_rad: Angle
    length_m: CarSize
    width_m: CarSize
    cov_xx_m2: Variance
    cov_xy_m2: Annotated[float, Meta(ge=-MAX_TRACK_VAR, le=MAX_TRACK_VAR)]
    cov_yy_m2: Variance
    speed_var_m2ps2: Variance
    age_s: Annotated[float, Meta(ge=0.0, le=MAX_STAMP_S)]
    hits: Count


class Opponents(Message):
    """The opponents one lidar scan shows (the localization bridge's detector and tracker).

    Attributes:
        source_stamp_s: ``stamp_s`` of the scan the tracks were updated with [s].
        frame: "map" (every position, velocity and heading is in the map frame).
        tracks: the confirmed tracks (<= 64, ``MAX_OPPONENTS``), ``OpponentTrack`` each;
            empty when no opponent is seen. Ids are unique within one record.
    """

    TYPE = "opponents"

    source_stamp_s: Stamp
    frame: OpponentFrame = "map"
    tracks: Annotated[list[OpponentTrack], Meta(max_length=MAX_OPPONENTS)] = []  # noqa: RUF012

    def __post_init__(self) -> None:
        ids = [t.id for t in self.tracks]
        if len(set(ids)) != len(ids):
            raise _bad(self, f"track ids repeat: {sorted(ids)}")


#: Every message class, in contract order.
MESSAGE_TYPES: tuple[type[Message], ...] = (
    Pose,
    Imu,
    Odom,
    Scan,
    State,
    DriveCmd,
    Plan,
    LapEvent,
    VescState,
    SimTruth,
    LogEvent,
    SimControl,
    Teleport,
    Opponents,
)
