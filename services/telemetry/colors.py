"""Colour ramps of the telemetry drawings (numpy only; no matplotlib in the service)."""

from __future__ import annotations

import numpy as np

#: A turbo-like ramp, dark blue (low) -> green -> yellow -> dark red (high), RGB 0..255.
_ANCHORS = np.array(
    [
        [48, 18, 59],
        [65, 125, 240],
        [30, 210, 200],
        [120, 250, 80],
        [240, 200, 50],
        [240, 90, 20],
        [122, 4, 3],
    ],
    dtype=float,
)
_POS = np.linspace(0.0, 1.0, len(_ANCHORS))

#: Fixed colours (RGB) of the drawings.
#: Track borders: light on the viewer's black background.
TRACK_EDGE = (215, 215, 215)
CENTRELINE = (110, 110, 110)
CAR = (30, 110, 255)
#: The car's footprint outline and heading arrow.
CAR_OUTLINE = (255, 255, 255)
TRUTH = (160, 160, 160)
HORIZON = (255, 120, 0)
SCAN = (200, 60, 200)


def ramp(values: np.ndarray | float, vmin: float = 0.0, vmax: float = 1.0) -> np.ndarray:
    """RGB uint8 colours (n, 3) of `values` mapped linearly from [vmin, vmax] onto the ramp.

    Values outside the range are clipped; NaN maps to the low end.
    """
    v = np.atleast_1d(np.asarray(values, dtype=float))
    span = vmax - vmin if vmax > vmin else 1.0
    u = np.clip(np.nan_to_num((v - vmin) / span, nan=0.0), 0.0, 1.0)
    rgb = np.stack([np.interp(u, _POS, _ANCHORS[:, k]) for k in range(3)], axis=-1)
    return rgb.astype(np.uint8)
