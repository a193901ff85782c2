"""The sensor's millisecond counter mapped to the host clock (pure: the caller passes times).

The Hokuyo stamps each scan with a 24-bit counter [ms] that starts at power-on and wraps
every 2**24 ms (4.66 h). ``SensorClock`` unwraps it (a step back of more than half the range
is a wrap; any other step back means the sensor restarted: the estimate starts again) and
estimates the offset ``o`` with ``host_s = sensor_s + o``, two ways:

* ``TM`` round trips at connect (``add_round_trip``): the host notes the send time
  ``t_tx`` and receive time ``t_rx`` of a ``TM1`` request and its answer ``T``; assuming the
  two directions take equally long, ``o = (t_tx + t_rx) / 2 - T``, with an error of at most
  half the round trip. The sample with the shortest round trip is kept.
* A min-filter over the scans (``add_receipt``): every scan arrives after its stamp, so
  ``host_receive - sensor_s = o + delay`` with ``delay >= delay_min``; the smallest value over
  the last ``window_s`` seconds estimates ``o + delay_min`` (late by the shortest transfer
  time of a scan, a constant; the window follows the drift of the two clocks, ~1e-4).

``stamp`` uses the TM offset when there is one (``prefer_round_trip``), else the min-filter,
and never returns a time later than the scan's receipt (``stamp(..., not_after_s=...)``).
"""

from __future__ import annotations

import collections
import math

__all__ = ["WRAP_MS", "SensorClock"]

#: Period of the sensor's counter [ms].
WRAP_MS = 1 << 24
_HALF = WRAP_MS // 2


class SensorClock:
    """Unwraps the 24-bit sensor time and maps it to the host clock (module docstring).

    Args:
        window_s: time span [s] of the min-filter.
        prefer_round_trip: use the TM estimate when there is one (else the min-filter).
    """

    def __init__(self, window_s: float = 10.0, *, prefer_round_trip: bool = True) -> None:
        if not (math.isfinite(window_s) and window_s > 0.0):
            raise ValueError("window_s must be finite and > 0")
        self.window_s = window_s
        self.prefer_round_trip = prefer_round_trip
        self.wraps = 0  #: counter wraps seen
        self.restarts = 0  #: steps back that are not wraps (sensor restarted)
        self._last_raw: int | None = None
        self._base_ms = 0  # added to the raw value: wraps * 2**24
        self._rt_offset_s: float | None = None
        self._rt_best_s = math.inf
        self._lags: collections.deque[tuple[float, float]] = collections.deque()

    def reset(self) -> None:
        """Forget everything (a new connection or a restarted sensor)."""
        self._last_raw = None
        self._base_ms = 0
        self._rt_offset_s = None
        self._rt_best_s = math.inf
        self._lags.clear()

    def unwrap_s(self, raw_ms: int) -> float:
        """The sensor time [s] of a raw 24-bit stamp, continued across wraps."""
        raw = int(raw_ms) % WRAP_MS
        last = self._last_raw
        if last is not None:
            step = raw - last
            if step < -_HALF:
                self._base_ms += WRAP_MS
                self.wraps += 1
            elif step < -1000:  # back by more than a second and no wrap: a restart
                self.restarts += 1
                self.reset()
        self._last_raw = raw
        return (self._base_ms + raw) * 1e-3

    def add_round_trip(self, t_tx_s: float, t_rx_s: float, raw_ms: int) -> None:
        """One ``TM1`` exchange: host send / receive times [s] and the sensor's answer."""
        rtt = t_rx_s - t_tx_s
        sensor_s = self.unwrap_s(raw_ms)
        if 0.0 <= rtt < self._rt_best_s:
            self._rt_best_s = rtt
            self._rt_offset_s = 0.5 * (t_tx_s + t_rx_s) - sensor_s

    @property
    def round_trip_s(self) -> float | None:
        """The shortest TM round trip [s] (the TM offset's error bound is half of it)."""
        return None if self._rt_offset_s is None else self._rt_best_s

    def add_receipt(self, host_rx_s: float, sensor_s: float) -> None:
        """A scan stamped ``sensor_s`` (unwrapped [s]) received at ``host_rx_s`` [s]."""
        lag = host_rx_s - sensor_s
        q = self._lags
        while q and q[-1][1] >= lag:
            q.pop()
        q.append((host_rx_s, lag))
        while q[0][0] < host_rx_s - self.window_s:
            q.popleft()

    def offset_s(self) -> float | None:
        """The offset [s] in use (host = sensor + offset), None before any estimate."""
        if self._rt_offset_s is not None and (self.prefer_round_trip or not self._lags):
            return self._rt_offset_s
        return self._lags[0][1] if self._lags else None

    def stamp(self, sensor_s: float, *, not_after_s: float) -> float:
        """The host time [s] of the unwrapped sensor time ``sensor_s``, at most
        ``not_after_s`` (the receipt); ``not_after_s`` itself before any estimate."""
        off = self.offset_s()
        if off is None:
            return not_after_s
        return min(sensor_s + off, not_after_s)
