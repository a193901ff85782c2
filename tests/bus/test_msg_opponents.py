"""The ``Opponents`` record (issue #24): round trip with its tracks, every broken track or
list rejected with a reason, and a subscriber counting and dropping bad payloads while the
good ones go through."""

from __future__ import annotations

import math
from dataclasses import dataclass

import msgpack
import msgspec
import pytest

from shared.bus import DropCounter, Subscription
from shared.messages import MessageError, Opponents, OpponentTrack, decode
from shared.messages.records import MAX_OPPONENTS

KEY = "racestack/car1/opponents"


def track(**kw) -> dict:
    base = dict(id=1, x_m=4.0, y_m=-1.5, vx_mps=2.5, vy_mps=0.5, yaw_rad=0.2, length_m=0.58,
                width_m=0.31, cov_xx_m2=4e-4, cov_xy_m2=1e-5, cov_yy_m2=3e-4,
                speed_var_m2ps2=0.02, age_s=1.25, hits=14)
    return {**base, **kw}


def wire(**kw) -> bytes:
    base = {"type": "opponents", "v": 1, "stamp_s": 8.0, "seq": 1, "source_stamp_s": 7.9,
            "frame": "map", "tracks": [track()]}
    return msgpack.packb({**base, **kw})


def reason(data: bytes) -> str:
    with pytest.raises(MessageError) as err:
        decode(data, Opponents)
    return err.value.reason


def test_round_trip_keeps_every_track_field() -> None:
    msg = Opponents(stamp_s=8.0, source_stamp_s=7.9,
                    tracks=[OpponentTrack(**track()), OpponentTrack(**track(id=2, x_m=-3.0))])
    back = decode(msg.encode(5), Opponents)
    assert back.seq == 5 and back.frame == "map"
    assert [msgspec.structs.asdict(t) for t in back.tracks] == [track(), track(id=2, x_m=-3.0)]
    assert back.tracks[1].vx_mps == 2.5 and back.tracks[0].length_m == 0.58


@pytest.mark.parametrize(("payload", "why"), [
    (dict(tracks=[track(x_m=math.nan)]), {"not_finite", "out_of_range"}),
    (dict(tracks=[{k: v for k, v in track().items() if k != "vx_mps"}]),
     {"missing_field", "bad_value"}),
    (dict(tracks=[track(width_m=0.0)]), {"out_of_range"}),
    (dict(tracks=[track(cov_xx_m2=-1.0)]), {"out_of_range"}),
    (dict(tracks=[track(hits="many")]), {"bad_type"}),
    (dict(tracks=[track(), track()]), {"bad_value"}),  # the same id twice
    (dict(tracks=[track(id=i) for i in range(MAX_OPPONENTS + 1)]), {"out_of_range"}),
    (dict(frame="odom"), {"bad_value"}),
    (dict(tracks="none"), {"bad_type"}),
])
def test_broken_payloads_are_rejected_with_a_reason(payload: dict, why: set[str]) -> None:
    assert reason(wire(**payload)) in why


def test_a_track_built_in_code_is_validated_too() -> None:
    with pytest.raises(MessageError) as err:
        OpponentTrack(**track(y_m=math.inf))
    assert err.value.reason == "not_finite"


@dataclass
class _Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass
class _Sample:
    data: bytes
    key_expr: str = KEY
    kind: str = "SampleKind.PUT"

    @property
    def payload(self) -> _Payload:
        return _Payload(self.data)


def test_a_subscriber_counts_and_drops_bad_payloads_and_keeps_the_good() -> None:
    drops = DropCounter()
    got: list[Opponents] = []
    sub = Subscription(KEY, Opponents, drops, got.append)
    sub.on_sample(_Sample(wire(seq=1)))
    sub.on_sample(_Sample(wire(seq=2, tracks=[track(x_m=math.nan)])))
    sub.on_sample(_Sample(wire(seq=3, frame="odom")))
    sub.on_sample(_Sample(b"\xc1garbage"))
    sub.on_sample(_Sample(wire(seq=4, tracks=[])))
    assert [m.seq for m in got] == [1, 4]
    assert drops.count(KEY) == 3
