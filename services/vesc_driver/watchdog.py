"""Command watchdog (pure: the caller passes ``now`` [s]; nothing here reads a clock).

While commands are fresh the driver sends the motor command and ALIVE; once no command has
arrived for ``timeout_s`` it sends the brake current on every tick and holds the brake until
a new command arrives. The firmware's own timeout is only kept reset while commands are
fresh or braking, so if the driver's process hangs the VESC releases the motor by itself.
"""

from __future__ import annotations

from enum import Enum


class WatchdogState(Enum):
    """Whether the last command is recent enough to act on."""

    NO_COMMAND = "no_command"  # never got a command: brake
    FRESH = "fresh"
    EXPIRED = "expired"  # the last command is older than the timeout: brake


class CommandWatchdog:
    """Tracks the age of the last command against ``timeout_s`` [s]."""

    def __init__(self, timeout_s: float) -> None:
        """Create a watchdog; ``timeout_s`` [s] must be > 0."""
        if not timeout_s > 0.0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s!r}")
        self.timeout_s = timeout_s
        self.last_command_s: float | None = None
        #: How many times a fresh command expired (edges FRESH -> EXPIRED).
        self.expiries = 0
        self._was_fresh = False

    def feed(self, now: float) -> None:
        """Record a fresh command at time ``now`` [s]."""
        self.last_command_s = now
        self._was_fresh = True

    def state(self, now: float) -> WatchdogState:
        """The state at time ``now`` [s]; counts an expiry on the first call that sees it."""
        if self.last_command_s is None:
            return WatchdogState.NO_COMMAND
        if now - self.last_command_s < self.timeout_s:
            return WatchdogState.FRESH
        if self._was_fresh:
            self._was_fresh = False
            self.expiries += 1
        return WatchdogState.EXPIRED

    def is_fresh(self, now: float) -> bool:
        """True while the last command is younger than the timeout."""
        return self.state(now) is WatchdogState.FRESH

    def deadline(self) -> float | None:
        """Time [s] at which the current command expires (None without a command)."""
        if self.last_command_s is None:
            return None
        return self.last_command_s + self.timeout_s
