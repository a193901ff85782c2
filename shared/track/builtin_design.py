"""The design of racestack's built-in tracks, made here from straights and circular arcs.

Each design is a list of segments driven counter-clockwise from the origin heading +x:
``("straight", length_m)`` or ``("arc", radius_m, turn_deg)`` (positive turn = left). Two
straights are marked ``"close"``: their lengths are solved so the loop closes exactly.

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


def _turtle(segments: list, closing: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Walk the segments; return (end position, end heading) after the whole loop."""
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
    base, heading = _turtle(segments, (0.0, 0.0))
    if abs(heading - 2 * np.pi) > 1e-9:
        raise ValueError(f"turns must add to +360 deg, got {np.degrees(heading):.1f}")
    e1, _ = _turtle(segments, (1.0, 0.0))
    e2, _ = _turtle(segments, (0.0, 1.0))
    A = np.stack([e1 - base, e2 - base], axis=1)
    lengths = np.linalg.solve(A, -base)
    if np.any(lengths <= 0):
        raise ValueError(f"closing straights would be negative: {lengths}")
    return float(lengths[0]), float(lengths[1])


def sample_design(design: dict, spacing_m: float = SPACING_M) -> np.ndarray:
    """(n, 4) rows ``x_m, y_m, w_tr_right_m, w_tr_left_m`` sampled every ~`spacing_m`."""
    closing = solve_closure(design["segments"])
    pieces = []
    pos = np.zeros(2)
    heading = 0.0
    k = 0
    for seg in design["segments"]:
        if seg[0] == "straight":
            length = closing[k] if seg[1] == "close" else seg[1]
            k += seg[1] == "close"
            pieces.append(("line", pos.copy(), heading, length))
            pos = pos + length * np.array([np.cos(heading), np.sin(heading)])
        else:
            _, radius, turn_deg = seg
            turn = np.radians(turn_deg)
            sign = np.sign(turn)
            centre = pos + radius * sign * np.array([-np.sin(heading), np.cos(heading)])
            pieces.append(("arc", centre, heading, radius, turn))
            heading += turn
            pos = centre - radius * sign * np.array([-np.sin(heading), np.cos(heading)])
    lengths = [p[3] if p[0] == "line" else p[3] * abs(p[4]) for p in pieces]
    total = float(np.sum(lengths))
    n = round(total / spacing_m)
    s_all = np.arange(n) * total / n
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    xy = np.empty((n, 2))
    for i, s in enumerate(s_all):
        j = int(np.searchsorted(starts, s, side="right") - 1)
        u = s - starts[j]
        p = pieces[j]
        if p[0] == "line":
            xy[i] = p[1] + u * np.array([np.cos(p[2]), np.sin(p[2])])
        else:
            _, centre, h0, radius, turn = p
            sign = np.sign(turn)
            h = h0 + sign * u / radius
            xy[i] = centre - radius * sign * np.array([-np.sin(h), np.cos(h)])
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
