"""The design of racestack's built-in tracks, made here from straights and circular arcs.

Each design is a list of segments driven counter-clockwise from the origin heading +x:
``("straight", length_m)`` or ``("arc", radius_m, turn_deg)`` (positive turn = left). The
curvature ramps over ``TRANSITION_M`` between segments (as on real tracks), and two straights
marked ``"close"`` get the lengths that make the loop close.

``python -m shared.track.builtin_design`` rewrites ``shared/track/builtin/*_centerline.csv``
(F1TENTH format) from these designs; a test checks the shipped files match.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

#: Point spacing of the generated centrelines [m] (like map416's 4 cm).
SPACING_M = 0.04

#: Like the paper's track (map416: tightest radius ~0.9 m): ~42 m, 1.2 m wide, seven sharp
#: turns of radius 0.9-1.1 m (one a 180 deg hairpin), straights of 1-12 m between them.
PAPERLIKE = {
    "half_width_m": 0.6,
    "segments": [
        ("straight", "close"),
        ("arc", 1.0, 90.0),
        ("straight", 2.5),
        ("arc", 0.9, 90.0),
        ("straight", 3.0),
        ("arc", 1.1, -90.0),
        ("straight", 1.5),
        ("arc", 1.0, 180.0),
        ("straight", "close"),
        ("arc", 1.0, -90.0),
        ("straight", 6.0),
        ("arc", 0.9, 90.0),
        ("straight", 1.0),
        ("arc", 1.1, 90.0),
    ],
}

#: A gentler track: ~55 m oval-ish circuit, 1.6 m wide, radii 2.5-4 m.
GENTLE = {
    "half_width_m": 0.8,
    "segments": [
        ("straight", "close"),
        ("arc", 3.0, 90.0),
        ("straight", "close"),
        ("arc", 4.0, 60.0),
        ("arc", 2.5, 30.0),
        ("straight", 14.0),
        ("arc", 3.0, 90.0),
        ("straight", 4.0),
        ("arc", 3.0, 90.0),
    ],
}

DESIGNS = {"paperlike": PAPERLIKE, "gentle": GENTLE}


def loop_end(segments: list, closing: tuple[float, float]) -> tuple[np.ndarray, float]:
    """Walk the segments (exact arcs, no ramps) from the origin heading +x; return the end
    position [m] and the end heading [rad]; `closing` gives the two ``"close"`` lengths [m]."""
    pos = np.zeros(2)
    heading = 0.0
    k = 0
    for seg in segments:
        if seg[0] == "straight":
            length = closing[k] if seg[1] == "close" else seg[1]
            k += seg[1] == "close"
            pos = pos + length * np.array([np.cos(heading), np.sin(heading)])
        else:
            _, radius, turn_deg = seg
            turn = np.radians(turn_deg)
            centre = pos + radius * np.sign(turn) * np.array([-np.sin(heading), np.cos(heading)])
            heading_new = heading + turn
            pos = centre - radius * np.sign(turn) * np.array(
                [-np.sin(heading_new), np.cos(heading_new)]
            )
            heading = heading_new
    return pos, heading


def solve_closure(segments: list) -> tuple[float, float]:
    """Lengths of the two ``"close"`` straights that make the loop end where it began."""
    base, heading = loop_end(segments, (0.0, 0.0))
    if abs(heading - 2 * np.pi) > 1e-9:
        raise ValueError(f"turns must add to +360 deg, got {np.degrees(heading):.1f}")
    e1, _ = loop_end(segments, (1.0, 0.0))
    e2, _ = loop_end(segments, (0.0, 1.0))
    A = np.stack([e1 - base, e2 - base], axis=1)
    lengths = np.linalg.solve(A, -base)
    if np.any(lengths <= 0):
        raise ValueError(f"closing straights would be negative: {lengths}")
    return float(lengths[0]), float(lengths[1])


#: Length over which the curvature ramps between straights and arcs [m] (clothoid-like
#: transitions, as on real tracks: a car cannot follow a curvature step).
TRANSITION_M = 1.0


def _segment_curvature(segments: list, closing: tuple[float, float]) -> list[tuple[float, float]]:
    """(length [m], curvature [1/m]) of each segment (left turns positive)."""
    out, k = [], 0
    for seg in segments:
        if seg[0] == "straight":
            length = closing[k] if seg[1] == "close" else seg[1]
            k += seg[1] == "close"
            out.append((float(length), 0.0))
        else:
            _, radius, turn_deg = seg
            out.append((radius * abs(np.radians(turn_deg)), float(np.sign(turn_deg)) / radius))
    return out


def _integrate(pieces: list[tuple[float, float]], spacing_m: float) -> np.ndarray:
    """(n + 1, 2) points of the loop with its curvature smoothed over TRANSITION_M.

    The piecewise-constant curvature is averaged over each step, smoothed with a
    periodic moving average (which keeps the total turn of 360 deg), and integrated:
    heading by the sum of curvature x step, position by steps along the midpoint heading.
    The last point is where the loop ends (equal to the first when it closes).
    """
    lengths = np.array([p[0] for p in pieces])
    total = float(lengths.sum())
    n = round(total / spacing_m)
    h = total / n
    # exact mean curvature of each step (from the piecewise-linear cumulative turn), so the
    # loop depends smoothly on the segment lengths
    bounds = np.concatenate([[0.0], np.cumsum(lengths)])
    turn = np.concatenate([[0.0], np.cumsum([p[0] * p[1] for p in pieces])])
    kappa = np.diff(np.interp(np.arange(n + 1) * h, bounds, turn)) / h
    w = max(1, round(TRANSITION_M / h)) | 1
    half = w // 2
    padded = np.concatenate([kappa[-half:], kappa, kappa[:half]]) if half else kappa
    kappa = np.convolve(padded, np.ones(w) / w, mode="valid")
    heading_start = np.concatenate([[0.0], np.cumsum(kappa * h)[:-1]])
    heading_mid = heading_start + 0.5 * kappa * h
    steps = h * np.column_stack([np.cos(heading_mid), np.sin(heading_mid)])
    return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])


def solve_closure_smooth(segments: list, spacing_m: float = SPACING_M) -> tuple[float, float]:
    """Closing straight lengths for the smoothed loop (Newton from the exact-arc solution)."""
    lengths = np.array(solve_closure(segments))
    for _ in range(8):
        end = _integrate(_segment_curvature(segments, tuple(lengths)), spacing_m)[-1]
        if np.hypot(*end) < 1e-9:
            break
        J = np.empty((2, 2))
        for j in range(2):
            d = np.zeros(2)
            d[j] = 1e-4
            e2 = _integrate(_segment_curvature(segments, tuple(lengths + d)), spacing_m)[-1]
            J[:, j] = (e2 - end) / 1e-4
        lengths = lengths - np.linalg.solve(J, end)
    return float(lengths[0]), float(lengths[1])


def sample_design(design: dict, spacing_m: float = SPACING_M) -> np.ndarray:
    """(n, 4) rows ``x_m, y_m, w_tr_right_m, w_tr_left_m`` sampled every ~`spacing_m`.

    Straights and arcs joined by curvature ramps of TRANSITION_M; the two closing straights
    are solved so that the loop closes (to well under a micrometre).
    """
    closing = solve_closure_smooth(design["segments"], spacing_m)
    pts = _integrate(_segment_curvature(design["segments"], closing), spacing_m)
    xy = pts[:-1]
    # the last arc's ramp wraps past the start: turn the loop so that the first straight
    # (its middle, clear of the ramps) runs exactly along +x from the origin
    mid = min(len(xy) - 2, round(0.5 * closing[0] / (np.hypot(*(xy[1] - xy[0])))))
    h = np.arctan2(*(xy[mid + 1] - xy[mid])[::-1])
    rot = np.array([[np.cos(h), np.sin(h)], [-np.sin(h), np.cos(h)]])
    xy = xy @ rot.T
    n = len(xy)
    hw = design["half_width_m"]
    return np.column_stack([xy, np.full(n, hw), np.full(n, hw)])


def render_csv(rows: np.ndarray) -> str:
    """The F1TENTH centreline CSV text of (n, 4) rows."""
    lines = ["# x_m, y_m, w_tr_right_m, w_tr_left_m"]
    lines += [f"{x:.6f}, {y:.6f}, {wr:.3f}, {wl:.3f}" for x, y, wr, wl in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the built-in track CSVs next to this module."""
    out_dir = Path(__file__).with_name("builtin")
    out_dir.mkdir(exist_ok=True)
    for name, design in DESIGNS.items():
        path = out_dir / f"{name}_centerline.csv"
        path.write_text(render_csv(sample_design(design)), encoding="utf-8")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
