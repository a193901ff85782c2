"""Cost of the message codec per record type: build, encode, decode (median and p99).

For State, Pose, DriveCmd and a 1080-beam Scan (a Hokuyo UST-10LX sweep), times the
constructor (validation included), ``record.encode(seq)`` (what a bus publisher does),
``decode(data, cls)`` (what a subscriber does: bytes -> validated record) and
``decode_any``. Each sample is the mean of ``--batch`` back-to-back calls (so the clock's own
cost stays small against sub-microsecond calls); the figures are the median and the 99th
percentile of ``--samples`` such samples, in microseconds per call. Only the public API of
``shared.messages`` is used, so the same file measures any implementation of it (A/B):

    .venv/bin/python -m benchmarks.codec_cost
    .venv/bin/python -m benchmarks.codec_cost --samples 20000 --batch 10
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from collections.abc import Callable

import numpy as np

from shared.messages import DriveCmd, Message, Pose, Scan, State, decode, decode_any

#: Beams of the benchmark scan (270 degrees at 0.25 degrees).
BEAMS = 1080


def _state() -> State:
    return State(
        stamp_s=1_700_000_000.123, x_m=1.0, y_m=2.0, yaw_rad=-3.0, speed_mps=2.2,
        yaw_rate_radps=0.1, steering_rad=0.05, source_stamp_s=1_700_000_000.1, valid=True,
    )


def _pose() -> Pose:
    return Pose(stamp_s=1_700_000_000.123, x_m=1.5, y_m=-2.0, yaw_rad=0.3, cov=None)


def _drive_cmd() -> DriveCmd:
    return DriveCmd(stamp_s=1_700_000_000.123, speed_mps=3.3, steering_rad=0.21)


_RANGES = np.linspace(0.05, 30.0, BEAMS).astype(np.float32)
_RANGES[::7] = np.inf


def _scan() -> Scan:
    return Scan(
        stamp_s=1_700_000_000.123, angle_min_rad=-2.35, angle_increment_rad=4.7 / BEAMS,
        ranges_m=_RANGES,
    )


CASES: dict[str, Callable[[], Message]] = {
    "State": _state,
    "Pose": _pose,
    "DriveCmd": _drive_cmd,
    f"Scan({BEAMS})": _scan,
}


def time_call(fn: Callable[[], object], samples: int, batch: int) -> np.ndarray:
    """Per-call times [us] of `fn`: `samples` means of `batch` calls each."""
    for _ in range(max(10, samples // 20)):  # warm up
        fn()
    out = np.empty(samples)
    clock = time.perf_counter_ns
    gc.disable()
    try:
        for i in range(samples):
            t0 = clock()
            for _ in range(batch):
                fn()
            out[i] = (clock() - t0) / batch / 1e3
    finally:
        gc.enable()
    return out


def measure(samples: int, batch: int) -> list[tuple[str, str, float, float]]:
    """(record, operation, median us, p99 us) of every case and operation."""
    rows = []
    for name, make in CASES.items():
        msg = make()
        cls = type(msg)
        data = msg.encode(seq=12345)
        ops: dict[str, Callable[[], object]] = {
            "build": make,
            "encode": lambda m=msg: m.encode(seq=12345),
            "decode": lambda d=data, c=cls: decode(d, c),
            "decode_any": lambda d=data: decode_any(d),
        }
        for op, fn in ops.items():
            t = time_call(fn, samples, batch)
            rows.append((name, op, float(np.median(t)), float(np.percentile(t, 99))))
    return rows


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5000, help="samples per operation")
    ap.add_argument("--batch", type=int, default=10, help="calls averaged per sample")
    args = ap.parse_args(argv)
    if args.samples < 10 or args.batch < 1:
        ap.error("--samples must be >= 10 and --batch >= 1")
    import shared.messages as messages

    print(f"codec: {messages.__file__}; {args.samples} samples of {args.batch} calls; "
          "us per call")
    print(f"{'record':12s} {'operation':11s} {'median':>8s} {'p99':>8s}")
    for name, op, med, p99 in measure(args.samples, args.batch):
        print(f"{name:12s} {op:11s} {med:8.2f} {p99:8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
