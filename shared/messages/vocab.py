"""The string vocabularies of the message contract as ``StrEnum``s, for the code that uses them.

The records validate these fields with ``Literal`` types (``shared.messages.records``:
``PlanStatus``, ``LapKind``, ``LogLevel``, ``SimAction``, ``VescStatus``); the enums below
name the same strings for code that produces or compares them, so no service spells a status
by hand::

    if plan.status == PlanStatusName.BRAKING: ...
    LapEvent(stamp_s=t, kind=LapKindName.START, lap=0, off_track_events=0)

A member IS its wire string (``LogLevelName.WARNING == "warning"``); records store the plain
string. Importing this module checks that every enum holds exactly its ``Literal``'s values,
in order, so the two can never drift apart.
"""

from __future__ import annotations

from enum import StrEnum

from shared.messages.records import (
    LAP_KINDS,
    LOG_LEVELS,
    PLAN_STATUSES,
    SIM_ACTIONS,
    VESC_STATUSES,
)


class PlanStatusName(StrEnum):
    """``Plan.status``: what the planner did this tick."""

    SOLVED = "solved"  #: the solver converged
    FALLBACK = "fallback"  #: the shifted previous plan (a failed solve)
    BRAKING = "braking"  #: speed 0 (failures in a row, stale or missing state)
    RECOVERING = "recovering"  #: the recovery rule drives the lost car back


class LapKindName(StrEnum):
    """``LapEvent.kind``: what the lap timer saw."""

    START = "start"  #: first crossing of the start line: timing starts
    LAP = "lap"  #: a lap completed
    OFF_TRACK = "off_track"  #: the first corner of the footprint left the track
    BACK_ON_TRACK = "back_on_track"  #: all four corners inside again


class LogLevelName(StrEnum):
    """``LogEvent.level`` (the ``logging`` level of the same name)."""

    DEBUG = "debug"
    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


class SimActionName(StrEnum):
    """``SimControl.action``: a request to the simulator."""

    RESET = "reset"  #: the car back to the start line, at rest
    PAUSE = "pause"  #: freeze the simulation
    RESUME = "resume"  #: go on (also releases an off-track "stop")


class VescStatusName(StrEnum):
    """``VescState.status``: the VESC driver's link status."""

    OK = "ok"
    FAULT = "fault"  #: the VESC reports a fault code
    STALE = "stale"  #: no GET_VALUES reply for a while
    DISCONNECTED = "disconnected"  #: no serial port


#: Each enum with the ``Literal`` values it must hold.
VOCABULARIES: tuple[tuple[type[StrEnum], tuple[str, ...]], ...] = (
    (PlanStatusName, PLAN_STATUSES),
    (LapKindName, LAP_KINDS),
    (LogLevelName, LOG_LEVELS),
    (SimActionName, SIM_ACTIONS),
    (VescStatusName, VESC_STATUSES),
)


def _check_vocabularies() -> None:
    for enum, values in VOCABULARIES:
        members = tuple(m.value for m in enum)
        if members != values:
            raise ImportError(
                f"{enum.__name__} {members} differs from its Literal {values} "
                "(shared/messages/records.py): change both"
            )


_check_vocabularies()
