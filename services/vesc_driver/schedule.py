"""When the VESC serial loop ticks (pure: the caller passes the clock [s]; no I/O, no sleep).

``VescDriver.loop`` asks ``TickScheduler.due`` on every wake-up and, when nothing is due,
sleeps until ``wake_at``. A tick is due for any of three reasons (``TickReason``, a flag):

* ``SCHEDULED``: the fixed-rate tick, every ``period_s`` from ``start_s`` (after a stall the
  missed ticks are skipped, never sent as a burst);
* ``EXPIRY``: the command watchdog's deadline passed since the last tick, so the brake
  follows the last command by ``command_timeout_s`` plus scheduling delay, not up to one
  period later;
* ``COMMAND``: with ``write_on_command``, a new command waits to be written and the last
  command-triggered tick is at least ``min_command_gap_s`` ago (a command reaches the wire
  without waiting for the next fixed tick; at most 1 / ``min_command_gap_s`` extra writes
  per second).
"""

from __future__ import annotations

import math
from enum import Flag, auto

#: Shortest interval between two extra writes triggered by new commands [s] (<= 200 Hz).
MIN_COMMAND_WRITE_GAP_S = 0.005
#: Slack added to timed waits so a wake-up is not a hair early [s].
WAKE_SLACK_S = 0.0005


class TickReason(Flag):
    """Why a tick is due (empty = not due; several may hold at once)."""

    SCHEDULED = auto()
    EXPIRY = auto()
    COMMAND = auto()


NOT_DUE = TickReason(0)


class TickScheduler:
    """Decides when the serial loop ticks (see the module docstring)."""

    def __init__(
        self,
        period_s: float,
        start_s: float,
        *,
        write_on_command: bool = False,
        min_command_gap_s: float = MIN_COMMAND_WRITE_GAP_S,
    ) -> None:
        """Create a schedule whose first fixed tick is at ``start_s`` [s].

        Args:
            period_s: fixed tick period [s] (1 / ``command_rate_hz``), > 0.
            start_s: clock time [s] of the first fixed tick.
            write_on_command: allow extra ticks right after new commands.
            min_command_gap_s: shortest interval [s] between two such extra ticks.
        """
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s!r}")
        self.period_s = period_s
        self.write_on_command = write_on_command
        self.min_command_gap_s = min_command_gap_s
        self.next_tick_s = start_s  #: clock time [s] of the next fixed tick
        self.last_tick_s = -math.inf  #: clock time [s] of the last tick of any kind
        self.last_command_tick_s = -math.inf  #: of the last command-only tick

    def due(self, now: float, deadline_s: float | None, command_pending: bool) -> TickReason:
        """Why a tick is due at ``now`` [s] (``NOT_DUE`` when none is).

        Args:
            now: the clock [s].
            deadline_s: the watchdog's expiry time [s] (None without a command).
            command_pending: a command arrived that no tick has sent yet.
        """
        reason = NOT_DUE
        if now >= self.next_tick_s:
            reason |= TickReason.SCHEDULED
        if deadline_s is not None and self.last_tick_s < deadline_s <= now:
            reason |= TickReason.EXPIRY
        if (
            self.write_on_command
            and command_pending
            and now >= self.last_command_tick_s + self.min_command_gap_s
        ):
            reason |= TickReason.COMMAND
        return reason

    def ticked(self, now: float, reason: TickReason) -> None:
        """Record that a tick for ``reason`` ran at ``now`` [s]."""
        self.last_tick_s = now
        if TickReason.SCHEDULED in reason:
            self.next_tick_s += self.period_s
            if self.next_tick_s <= now:  # fell behind: skip, do not burst
                self.next_tick_s = now + self.period_s
        elif TickReason.COMMAND in reason:
            self.last_command_tick_s = now

    def wake_at(self, deadline_s: float | None, command_pending: bool) -> float:
        """The clock time [s] by which the loop must check again (the earliest due time)."""
        wake = self.next_tick_s
        if deadline_s is not None and self.last_tick_s < deadline_s < wake:
            wake = deadline_s
        if self.write_on_command and command_pending:
            wake = min(wake, self.last_command_tick_s + self.min_command_gap_s)
        return wake
