"""Round trip and rejection of every message type (codec rules of shared.messages)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest
from msgspec.inspect import BoolType, CustomType, FloatType, IntType, LiteralType, StrType

from shared.messages import (
    MESSAGE_TYPES,
    REASONS,
    REGISTRY,
    DriveCmd,
    HorizonCol,
    InputCol,
    LapEvent,
    LogEvent,
    Message,
    MessageError,
    Odom,
    Plan,
    Pose,
    Scan,
    SimControl,
    State,
    VescState,
    decode,
    decode_any,
)
from shared.messages.codec import FieldInfo

Sample = Callable[[type[Message]], Message]
TYPES = pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.__name__)


def _wire(msg: Message) -> dict[str, Any]:
    return msgpack.unpackb(msg.encode(), raw=False)


def _pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def _reason(data: bytes, cls: type[Message] | None = None) -> str:
    with pytest.raises(MessageError) as info:
        if cls is None:
            decode_any(data)
        else:
            decode(data, cls)
    assert info.value.reason in REASONS
    assert str(info.value).startswith(info.value.reason)
    return info.value.reason


# Field kinds as msgspec describes them: floats and ints (with their bounds ge/le), bools,
# strings (free text: StrType; from an allowed set: LiteralType) and arrays (CustomType).
Real, Int, Bool, Array = FloatType, IntType, BoolType, CustomType
Str = (StrType, LiteralType)


def _fields(cls: type[Message], kind: type | tuple[type, ...]) -> list[tuple[str, FieldInfo]]:
    return [(f.name, f) for f in cls.fields_info() if isinstance(f.type, kind)]


def _all(kind: type | tuple[type, ...]) -> list[tuple[type[Message], str, FieldInfo]]:
    return [(c, n, s) for c in MESSAGE_TYPES for n, s in _fields(c, kind)]


def _ids(case: tuple[type[Message], str, Any]) -> str:
    return f"{case[0].__name__}.{case[1]}"


# --------------------------------------------------------------------------- registry
def test_registry_matches_message_types() -> None:
    assert {c.TYPE for c in MESSAGE_TYPES} == set(REGISTRY)
    assert all(REGISTRY[c.TYPE] is c for c in MESSAGE_TYPES)
    assert all(c.VERSION == 1 for c in MESSAGE_TYPES)


# --------------------------------------------------------------------------- round trip
@TYPES
def test_round_trip(cls: type[Message], sample: Sample) -> None:
    msg = sample(cls).with_seq(41)
    data = msg.encode()
    back = decode(data, cls)
    assert back == msg
    assert type(back) is cls
    assert back.seq == 41
    assert decode_any(data) == msg
    wire = _wire(msg)
    assert wire["type"] == cls.TYPE and wire["v"] == cls.VERSION
    assert all(isinstance(k, str) for k in wire)


@TYPES
def test_records_are_frozen_and_arrays_read_only(cls: type[Message], sample: Sample) -> None:
    msg = sample(cls)
    with pytest.raises(AttributeError):
        msg.stamp_s = 3.0  # type: ignore[misc]
    for name, _ in _fields(cls, Array):
        arr = getattr(msg, name)
        if arr is not None:
            assert not arr.flags.writeable
            with pytest.raises(ValueError):
                arr[0] = 0
    assert decode(msg.encode(), cls) == msg  # unchanged


def test_arrays_keep_dtype_and_shape(sample: Sample) -> None:
    plan = decode(sample(Plan).encode(), Plan)
    assert plan.horizon.dtype == np.float64 and plan.horizon.shape == (6, len(HorizonCol))
    assert plan.inputs.shape == (5, len(InputCol)) and plan.n == 5
    assert plan.inputs[0, InputCol.DELTA] == pytest.approx(0.1)
    scan = decode(sample(Scan).encode(), Scan)
    assert scan.ranges_m.dtype == np.float32
    assert np.isinf(scan.ranges_m[2])
    assert scan.angles_rad()[1] == pytest.approx(-2.35 + 0.0043)
    wire = _wire(sample(Scan))
    assert wire["ranges_m"]["dtype"] == "<f4" and wire["ranges_m"]["shape"] == [4]


def test_constructor_coerces_numbers_and_array_likes() -> None:
    cmd = DriveCmd(stamp_s=1, speed_mps=np.float32(2.0), steering_rad=0)
    assert isinstance(cmd.speed_mps, float) and isinstance(cmd.stamp_s, float)
    scan = Scan(stamp_s=0.0, angle_min_rad=0.0, angle_increment_rad=0.1, ranges_m=[1, 2, 3])
    assert scan.ranges_m.dtype == np.float32
    src = np.eye(3)
    pose = Pose(stamp_s=0.0, x_m=0.0, y_m=0.0, yaw_rad=0.0, cov=src)
    src[0, 0] = 5.0  # the record keeps its own copy
    assert pose.cov is not None and pose.cov[0, 0] == 1.0


def test_optional_fields_default_to_none_and_may_be_absent_on_the_wire() -> None:
    v = VescState(stamp_s=0.0, status="disconnected")
    assert v.erpm is None and v.fault_code is None
    wire = _wire(v)
    for f in VescState.fields_info():
        if not f.required:
            del wire[f.name]
    assert decode(_pack(wire), VescState) == v
    odom = Odom(stamp_s=0.0, speed_mps=1.0, steering_rad=0.0)
    assert odom.yaw_rate_radps is None
    assert decode(odom.encode(), Odom).yaw_rate_radps is None
    pose = Pose(stamp_s=0.0, x_m=0.0, y_m=0.0, yaw_rad=0.0)
    assert decode(pose.encode(), Pose).cov is None


def test_int_accepted_for_float_on_the_wire(sample: Sample) -> None:
    wire = _wire(sample(DriveCmd))
    wire["speed_mps"] = 3
    assert decode(_pack(wire), DriveCmd).speed_mps == 3.0


def test_with_seq_copies(sample: Sample) -> None:
    a = sample(DriveCmd)
    b = a.with_seq(7)
    assert (a.seq, b.seq) == (0, 7) and a.speed_mps == b.speed_mps
    with pytest.raises(MessageError):
        a.with_seq(-1)


def test_equality_compares_values() -> None:
    a = SimControl(stamp_s=1.0, action="pause")
    assert a == SimControl(stamp_s=1.0, action="pause")
    assert a != SimControl(stamp_s=1.0, action="resume")
    assert a != DriveCmd(stamp_s=1.0, speed_mps=0.0, steering_rad=0.0)


# --------------------------------------------------------------------------- forward compat
@TYPES
def test_unknown_extra_fields_are_ignored(cls: type[Message], sample: Sample) -> None:
    msg = sample(cls)
    wire = _wire(msg)
    wire["added_in_a_later_release"] = {"anything": [1, 2, 3]}
    assert decode(_pack(wire), cls) == msg


def test_unknown_keys_in_array_map_are_ignored(sample: Sample) -> None:
    wire = _wire(sample(Scan))
    wire["ranges_m"]["order"] = "C"
    assert decode(_pack(wire), Scan) == sample(Scan)


# --------------------------------------------------------------------------- framing errors
@TYPES
def test_garbage_and_truncated_bytes(cls: type[Message], sample: Sample) -> None:
    data = sample(cls).encode()
    assert _reason(b"\xc1\xff\x00garbage", cls) == "not_msgpack"
    assert _reason(b"", cls) == "not_msgpack"
    for cut in (1, len(data) // 2, len(data) - 1):
        assert _reason(data[:cut], cls) == "not_msgpack"
    assert _reason(data + b"\x00", cls) == "not_msgpack"  # trailing bytes


@pytest.mark.parametrize("obj", [[1, 2], 3, "pose", None, 1.5, b"\x01", True])
def test_valid_msgpack_that_is_not_a_map(obj: Any) -> None:
    assert _reason(_pack(obj)) == "not_a_map"
    assert _reason(_pack(obj), DriveCmd) == "not_a_map"


def test_map_with_non_string_keys() -> None:
    assert _reason(_pack({1: "x", "type": "pose"})) == "not_a_map"
    assert _reason(_pack({b"type": b"pose"})) == "not_a_map"


def test_non_bytes_and_oversized_payloads() -> None:
    with pytest.raises(MessageError) as info:
        decode_any("not bytes")  # type: ignore[arg-type]
    assert info.value.reason == "not_msgpack"
    assert _reason(b"\x00" * (4 * 1024 * 1024 + 1)) == "too_large"


def test_invalid_utf8_string() -> None:
    data = b"\x81\xa4type\xa2\xff\xfe"  # {"type": <invalid utf-8>}
    assert _reason(data) == "not_msgpack"


def test_invalid_utf8_in_a_field_and_in_an_unknown_key(sample: Sample) -> None:
    """A string field that is not UTF-8 makes the payload undecodable; an unknown key's value
    is skipped unread, like the rest of that key (so it is not checked either)."""
    good = sample(LogEvent).encode()
    bad_text = good.replace(b"\xaaslow solve", b"\xa2\xff\xfe")
    assert _reason(bad_text, LogEvent) == "not_msgpack"
    wire = _wire(sample(LogEvent))
    wire["zz"] = "x"
    extra = _pack(wire).replace(b"\xa2zz\xa1x", b"\xa2zz\xa2\xff\xfe")
    assert decode(extra, LogEvent) == sample(LogEvent)
    wire["text"] = 1.5  # a bad field beside bad UTF-8: the framing problem is reported first
    both = _pack(wire).replace(b"\xa2zz\xa1x", b"\xa2zz\xa2\xff\xfe")
    assert _reason(both, LogEvent) == "not_msgpack"


# --------------------------------------------------------------------------- type / version
@TYPES
def test_type_tag_problems(cls: type[Message], sample: Sample) -> None:
    wire = _wire(sample(cls))
    other = next(c for c in MESSAGE_TYPES if c is not cls)
    assert _reason(_pack({**wire, "type": other.TYPE}), cls) == "wrong_type"
    assert _reason(_pack({**wire, "type": "warp_drive"}), cls) == "unknown_type"  # no such tag
    assert _reason(_pack({**wire, "type": 3}), cls) == "no_type"
    del wire["type"]
    assert _reason(_pack(wire), cls) == "no_type"
    assert _reason(_pack(wire)) == "no_type"


@TYPES
@pytest.mark.parametrize("version", [2, 0, -1, "1", 1.0, True, None])
def test_wrong_version(cls: type[Message], version: Any, sample: Sample) -> None:
    wire = _wire(sample(cls))
    wire["v"] = version
    assert _reason(_pack(wire), cls) == "wrong_version"
    del wire["v"]
    assert _reason(_pack(wire), cls) == "wrong_version"


def test_decode_any_checks_the_version_too(sample: Sample) -> None:
    wire = _wire(sample(State))
    wire["v"] = 99
    assert _reason(_pack(wire)) == "wrong_version"


# --------------------------------------------------------------------------- fields
@pytest.mark.parametrize(
    ("cls", "name"),
    [(c, f.name) for c in MESSAGE_TYPES for f in c.fields_info() if f.required],
    ids=lambda x: x.__name__ if isinstance(x, type) else x,
)
def test_missing_required_field(cls: type[Message], name: str, sample: Sample) -> None:
    wire = _wire(sample(cls))
    del wire[name]
    assert _reason(_pack(wire), cls) == "missing_field"


@pytest.mark.parametrize("case", _all(Real), ids=_ids)
def test_non_finite_floats(case: tuple[type[Message], str, FieldInfo], sample: Sample) -> None:
    cls, name, _ = case
    for bad in (math.nan, math.inf, -math.inf):
        wire = _wire(sample(cls))
        wire[name] = bad
        assert _reason(_pack(wire), cls) == "not_finite"


@pytest.mark.parametrize(
    "case", [c for c in _all(Real) if c[2].type.le is not None or c[2].type.ge is not None],
    ids=_ids,
)
def test_out_of_range_floats(case: tuple[type[Message], str, FieldInfo], sample: Sample) -> None:
    cls, name, spec = case
    bad = spec.type.le * 2 + 1 if spec.type.le is not None else spec.type.ge * 2 - 1
    wire = _wire(sample(cls))
    wire[name] = bad
    assert _reason(_pack(wire), cls) == "out_of_range"
    with pytest.raises(MessageError):  # the constructor enforces the same rules
        cls(**{**_kwargs(sample(cls)), name: bad})


@pytest.mark.parametrize("case", _all(Real) + _all(Int) + _all(Str), ids=_ids)
def test_wrong_field_types(case: tuple[type[Message], str, FieldInfo], sample: Sample) -> None:
    cls, name, spec = case
    bad_values: list[Any] = [[1.0], {"x": 1}, b"\x00"]
    bad_values.append(1.0 if isinstance(spec.type, Str) else "1.0")
    if not isinstance(spec.type, Str):
        bad_values.append(True)  # booleans are not numbers here
    if isinstance(spec.type, Int):
        bad_values.append(1.5)
    if not spec.optional:
        bad_values.append(None)
    for bad in bad_values:
        wire = _wire(sample(cls))
        wire[name] = bad
        assert _reason(_pack(wire), cls) == "bad_type", (name, bad)


@pytest.mark.parametrize("case", _all(Bool), ids=_ids)
def test_bool_fields_reject_other_types(
    case: tuple[type[Message], str, FieldInfo], sample: Sample
) -> None:
    cls, name, _ = case
    for bad in (1, 0, "true", None, 1.0):
        wire = _wire(sample(cls))
        wire[name] = bad
        assert _reason(_pack(wire), cls) == "bad_type"


@pytest.mark.parametrize("case", _all(LiteralType), ids=_ids)
def test_strings_outside_the_allowed_set(
    case: tuple[type[Message], str, FieldInfo], sample: Sample
) -> None:
    cls, name, _ = case
    wire = _wire(sample(cls))
    wire[name] = "definitely-not-allowed"
    assert _reason(_pack(wire), cls) == "bad_value"


def test_too_long_text() -> None:
    with pytest.raises(MessageError) as info:
        LogEvent(stamp_s=0.0, level="info", source="x" * 65, text="")
    assert info.value.reason == "out_of_range"
    LogEvent(stamp_s=0.0, level="info", source="x" * 64, text="y" * 8192)


# --------------------------------------------------------------------------- arrays
@pytest.mark.parametrize("case", _all(Array), ids=_ids)
def test_array_wire_problems(case: tuple[type[Message], str, FieldInfo], sample: Sample) -> None:
    cls, name, field = case
    spec = field.array
    assert spec is not None
    good = _wire(sample(cls))[name]
    other_dtype = "<f4" if spec.dtype == "<f8" else "<f8"
    arr = np.frombuffer(good["data"], dtype=spec.dtype).reshape(good["shape"])
    problems = [
        {**good, "dtype": ">f8" if spec.dtype == "<f8" else ">f4"},  # big-endian
        {**good, "dtype": other_dtype, "data": arr.astype(other_dtype).tobytes()},
        {**good, "dtype": "<i8", "data": np.nan_to_num(arr, posinf=0).astype("<i8").tobytes()},
        {**good, "data": good["data"][:-1]},  # truncated data
        {**good, "shape": [*good["shape"], 1]},  # wrong ndim
        {**good, "shape": [-1, *good["shape"][1:]]},
        {**good, "shape": "4"},
        {**good, "data": "text"},
        {k: v for k, v in good.items() if k != "dtype"},
        [1.0, 2.0],
        "array",
    ]
    for bad in problems:
        wire = _wire(sample(cls))
        wire[name] = bad
        assert _reason(_pack(wire), cls) == "bad_array", bad


@pytest.mark.parametrize("case", _all(Array), ids=_ids)
def test_array_nan(case: tuple[type[Message], str, FieldInfo], sample: Sample) -> None:
    cls, name, _ = case
    kwargs = _kwargs(sample(cls))
    arr = np.array(kwargs[name], copy=True)
    arr.flat[0] = np.nan
    wire = _wire(sample(cls))
    wire[name] = {**wire[name], "data": arr.tobytes()}
    assert _reason(_pack(wire), cls) == "not_finite"
    with pytest.raises(MessageError):
        cls(**{**kwargs, name: arr})


def test_plan_shapes_must_agree(sample: Sample) -> None:
    kw = _kwargs(sample(Plan))
    for change in (
        {"horizon": np.zeros((5, 4))},  # N rows instead of N+1
        {"beta": np.zeros(4)},
        {"inputs": np.zeros((5, 2))},
        {"horizon": np.zeros((6, 3))},
        {"inputs": np.zeros((0, 3)), "horizon": np.zeros((1, 4)), "beta": np.zeros(0)},
    ):
        with pytest.raises(MessageError):
            Plan(**{**kw, **change})
    wire = _wire(sample(Plan))
    h = np.zeros((5, 4))
    wire["horizon"] = {"dtype": "<f8", "shape": [5, 4], "data": h.tobytes()}
    assert _reason(_pack(wire), Plan) == "bad_value"


def test_plan_value_ranges(sample: Sample) -> None:
    kw = _kwargs(sample(Plan))
    inputs = np.array(kw["inputs"], copy=True)
    inputs[0, InputCol.DELTA] = 1.5
    with pytest.raises(MessageError, match="delta"):
        Plan(**{**kw, "inputs": inputs})
    beta = np.array(kw["beta"], copy=True)
    beta[0] = 1.2
    with pytest.raises(MessageError):
        Plan(**{**kw, "beta": beta})
    horizon = np.array(kw["horizon"], copy=True)
    horizon[0, HorizonCol.X] = 2e4
    with pytest.raises(MessageError):
        Plan(**{**kw, "horizon": horizon})


def test_pose_covariance_checks() -> None:
    base = {"stamp_s": 0.0, "x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}
    cov = np.eye(3)
    cov[0, 1] = 0.5
    with pytest.raises(MessageError, match="symmetric"):
        Pose(**base, cov=cov)
    with pytest.raises(MessageError, match="variance"):
        Pose(**base, cov=-np.eye(3))
    with pytest.raises(MessageError):
        Pose(**base, cov=np.eye(2))


def test_scan_rules() -> None:
    base = {"stamp_s": 0.0, "angle_min_rad": 0.0}
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.0, ranges_m=[1.0])
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.1, ranges_m=[])
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.1, ranges_m=[-1.0])
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.1, ranges_m=[-np.inf])
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.1, ranges_m=[[1.0, 2.0]])
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.1, ranges_m=["a"])
    with pytest.raises(MessageError):
        Scan(**base, angle_increment_rad=0.1, ranges_m=[[1.0], [2.0, 3.0]])


# --------------------------------------------------------------------------- typical limits
@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda: DriveCmd(stamp_s=0.0, speed_mps=2.0, steering_rad=1.01), "out_of_range"),
        (lambda: DriveCmd(stamp_s=0.0, speed_mps=-50.5, steering_rad=0.0), "out_of_range"),
        (lambda: DriveCmd(stamp_s=-1.0, speed_mps=0.0, steering_rad=0.0), "out_of_range"),
        (lambda: DriveCmd(stamp_s=0.0, speed_mps=math.nan, steering_rad=0.0), "not_finite"),
        (lambda: DriveCmd(stamp_s=0.0, speed_mps="1", steering_rad=0.0), "bad_type"),
        (lambda: LapEvent(stamp_s=0.0, kind="lap", lap=1, off_track_events=0), "bad_value"),
        (lambda: LapEvent(stamp_s=0.0, kind="start", lap=-1, off_track_events=0), "out_of_range"),
        (lambda: VescState(stamp_s=0.0, status="ok", duty=1.5), "out_of_range"),
        (lambda: VescState(stamp_s=0.0, status="ok", fault_code=300), "out_of_range"),
        (lambda: VescState(stamp_s=0.0, status="weird"), "bad_value"),
        (lambda: LogEvent(stamp_s=0.0, level="fatal", source="x", text=""), "bad_value"),
        (lambda: SimControl(stamp_s=0.0, action="explode"), "bad_value"),
    ],
)
def test_constructor_rejects(make: Callable[[], Message], reason: str) -> None:
    with pytest.raises(MessageError) as info:
        make()
    assert info.value.reason == reason


def test_constructors_take_known_keywords_only() -> None:
    with pytest.raises(TypeError):
        DriveCmd(0.0, 1.0, 0.0)  # type: ignore[misc]
    with pytest.raises(TypeError, match="steering_rad"):
        DriveCmd(stamp_s=0.0, speed_mps=1.0)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="steer"):
        DriveCmd(stamp_s=0.0, speed_mps=1.0, steering_rad=0.0, steer=0.1)  # type: ignore[call-arg]


def test_check_field_validates_one_value() -> None:
    assert VescState.check_field("duty", np.float32(0.5)) == 0.5
    assert type(VescState.check_field("erpm", 12000)) is float
    assert VescState.check_field("fault_code", None) is None
    for name, bad, reason in (("duty", 1.5, "out_of_range"), ("duty", math.nan, "not_finite"),
                              ("fault_code", 1.0, "bad_type"), ("status", "weird", "bad_value")):
        with pytest.raises(MessageError) as info:
            VescState.check_field(name, bad)
        assert info.value.reason == reason and name in info.value.detail


@TYPES
def test_records_pickle_and_copy(cls: type[Message], sample: Sample) -> None:
    import copy
    import pickle

    msg = sample(cls).with_seq(5)
    for other in (pickle.loads(pickle.dumps(msg)), copy.copy(msg), copy.deepcopy(msg)):
        assert type(other) is cls and other == msg and other.encode() == msg.encode()


def test_fields_info_in_wire_order() -> None:
    names = [f.name for f in DriveCmd.fields_info()]
    assert names == ["stamp_s", "seq", "speed_mps", "steering_rad"]
    assert list(_wire(DriveCmd(stamp_s=0.0, speed_mps=0.0, steering_rad=0.0))) == [
        "type", "v", *names
    ]
    info = {f.name: f for f in DriveCmd.fields_info()}
    assert info["steering_rad"].describe() == "float in [-1, 1]"


def test_edge_values_accepted() -> None:
    DriveCmd(stamp_s=0.0, speed_mps=50.0, steering_rad=-1.0)
    LapEvent(stamp_s=0.0, kind="start", lap=0, off_track_events=0)
    VescState(stamp_s=0.0, status="fault", fault_code=255, duty=-1.0)


def _kwargs(msg: Message) -> dict[str, Any]:
    return {f.name: getattr(msg, f.name) for f in type(msg).fields_info()}


def test_numbers_of_any_numeric_type_are_normalised() -> None:
    """Plain floats and ints take a fast path; numpy scalars and ints still validate and
    are stored as Python numbers; NaN and out-of-range values fail on every path."""
    for x in (1.5, np.float64(1.5), np.float32(1.5), 1, np.int64(1)):
        c = DriveCmd(stamp_s=x, speed_mps=x, steering_rad=0.1, seq=np.int32(3))
        assert type(c.stamp_s) is float and type(c.speed_mps) is float and type(c.seq) is int
        assert c.speed_mps == float(x) and c.seq == 3
    for bad, reason in ((float("nan"), "not_finite"), (np.float64("inf"), "not_finite"),
                        (-1.0, "out_of_range"), (np.float64(-1.0), "out_of_range")):
        with pytest.raises(MessageError) as info:
            DriveCmd(stamp_s=bad, speed_mps=0.0, steering_rad=0.0)
        assert info.value.reason == reason
    for bad_seq, reason in ((-1, "out_of_range"), (True, "bad_type"), (2**63, "out_of_range")):
        with pytest.raises(MessageError) as info:
            DriveCmd(stamp_s=0.0, speed_mps=0.0, steering_rad=0.0, seq=bad_seq)
        assert info.value.reason == reason
