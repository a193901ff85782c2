"""What a scan must satisfy before the particle filter uses it (on top of the message's own
validation in ``shared.messages.Scan``: finite angles, non-zero increment, ranges >= 0 or
+inf). Maths only.

A scan is dropped (and counted under the returned reason) when:

- ``angle_increment_not_positive``: beams must turn counter-clockwise (increment > 0);
- ``fov_over_2pi``: ``(n - 1) * increment`` exceeds a full turn;
- ``range_nan`` / ``range_negative``: a NaN or negative range (the bus rejects them; a
  scan built in process, e.g. the bench's, is checked here);
- ``wrong_length`` / ``wrong_angles``: the beam count or the first angle / increment
  differs from the first accepted scan's (``ScanLayout``): one lidar, one layout;
- ``too_few_returns``: fewer than ``MIN_RETURNS`` finite ranges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.messages import Scan

#: A scan needs at least this many beams with a return.
MIN_RETURNS = 8
#: Angles of one lidar's scans agree to this [rad].
ANGLE_TOL_RAD = 1e-6


@dataclass(frozen=True, slots=True)
class ScanLayout:
    """Beam count, first angle [rad] and increment [rad] of the accepted scans."""

    beams: int
    angle_min_rad: float
    angle_increment_rad: float

    @classmethod
    def of(cls, scan: Scan) -> ScanLayout:
        """The layout of `scan`."""
        return cls(len(scan.ranges_m), scan.angle_min_rad, scan.angle_increment_rad)


def scan_problem(scan: Scan, layout: ScanLayout | None) -> str | None:
    """Why `scan` cannot be used (a reason of the module docstring), or None if it can;
    `layout`: the first accepted scan's (None: no scan accepted yet)."""
    inc = scan.angle_increment_rad
    r = np.asarray(scan.ranges_m)
    if not (math.isfinite(inc) and inc > 0.0):
        return "angle_increment_not_positive"
    if (r.shape[0] - 1) * inc > 2.0 * math.pi + ANGLE_TOL_RAD:
        return "fov_over_2pi"
    if r.ndim != 1:
        return "wrong_length"
    if np.isnan(r).any():
        return "range_nan"
    if (r < 0.0).any():
        return "range_negative"
    if layout is not None:
        if r.shape[0] != layout.beams:
            return "wrong_length"
        if (
            abs(scan.angle_min_rad - layout.angle_min_rad) > ANGLE_TOL_RAD
            or abs(inc - layout.angle_increment_rad) > ANGLE_TOL_RAD
        ):
            return "wrong_angles"
    if int(np.isfinite(r).sum()) < MIN_RETURNS:
        return "too_few_returns"
    return None
