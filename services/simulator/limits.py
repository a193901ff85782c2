"""The simulator's output within the message contract: wrapped angles, state limits.

Pure functions of the car's state (no transport, no clock): the service wraps every angle it
publishes (``shared.angles.wrap_angle``) and resets the car when its state leaves the contract
(``state_fault``), so nothing it publishes is ever refused by the records' validation.
"""

from __future__ import annotations

import math

from services.simulator.state import VehicleState
from shared.messages.records import (
    MAX_POS_M,
    MAX_SPEED_MPS,
    MAX_STEER_RAD,
    MAX_YAW_RATE_RADPS,
)


def state_fault(st: VehicleState) -> tuple[str, str] | None:
    """Why the car's state is outside the message contract, as (reason, detail), or None.

    Checked: every element finite, position within ``MAX_POS_M`` [m], speed within
    ``MAX_SPEED_MPS`` [m/s], yaw rate within ``MAX_YAW_RATE_RADPS`` [rad/s], steering within
    ``MAX_STEER_RAD`` [rad]. Yaw and slip are angles: the records wrap them, so they are not
    checked here.
    """
    vals = st.as_tuple()
    if not all(math.isfinite(v) for v in vals):
        return "not_finite", f"non-finite state {vals}"
    if abs(st.x_m) > MAX_POS_M or abs(st.y_m) > MAX_POS_M:
        return "position_out_of_range", (
            f"position ({st.x_m:.1f}, {st.y_m:.1f}) m beyond {MAX_POS_M:g} m"
        )
    if abs(st.v_mps) > MAX_SPEED_MPS:
        return "speed_out_of_range", f"speed {st.v_mps:.2f} m/s beyond {MAX_SPEED_MPS:g} m/s"
    if abs(st.yaw_rate_radps) > MAX_YAW_RATE_RADPS:
        return "yaw_rate_out_of_range", (
            f"yaw rate {st.yaw_rate_radps:.2f} rad/s beyond {MAX_YAW_RATE_RADPS:g} rad/s"
        )
    if abs(st.delta_rad) > MAX_STEER_RAD:
        return "steering_out_of_range", (
            f"steering {st.delta_rad:.3f} rad beyond {MAX_STEER_RAD:g} rad"
        )
    return None
