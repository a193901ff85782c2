"""Property tests: no input makes the decoder raise anything but MessageError."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.messages import MESSAGE_TYPES, DriveCmd, Message, MessageError, Plan, decode, decode_any

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
#: Fewer examples for the per-type mutation test (12 types).
FUZZ_PER_TYPE = settings(FUZZ, max_examples=100)

_scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20)
    | st.binary(max_size=40)
)
_values = st.recursive(
    _scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


def _decodes_or_message_error(data: bytes) -> None:
    try:
        msg = decode_any(data)
    except MessageError as exc:
        assert exc.reason and exc.detail is not None
    else:
        assert isinstance(msg, Message)


@FUZZ
@given(st.binary(max_size=512))
def test_arbitrary_bytes_only_raise_message_error(data: bytes) -> None:
    _decodes_or_message_error(data)
    for cls in MESSAGE_TYPES[:3]:
        try:
            decode(data, cls)
        except MessageError:
            pass


@FUZZ
@given(_values)
def test_arbitrary_msgpack_values_only_raise_message_error(obj: Any) -> None:
    _decodes_or_message_error(msgpack.packb(obj, use_bin_type=True))


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.__name__)
def test_mutated_valid_messages_only_raise_message_error(
    cls: type[Message], sample: Callable[[type[Message]], Message]
) -> None:
    wire = msgpack.unpackb(sample(cls).encode(), raw=False)
    names = sorted(wire)

    @FUZZ_PER_TYPE
    @given(st.sampled_from(names), _values, st.booleans())
    def check(name: str, value: Any, delete: bool) -> None:
        mutated = dict(wire)
        if delete:
            del mutated[name]
        else:
            mutated[name] = value
        data = msgpack.packb(mutated, use_bin_type=True)
        _decodes_or_message_error(data)
        try:
            decode(data, cls)
        except MessageError:
            pass

    check()


@FUZZ
@given(st.binary(min_size=1, max_size=64), st.integers(min_value=0, max_value=2000))
def test_corrupted_valid_bytes_only_raise_message_error(noise: bytes, where: int) -> None:

    for msg in (
        DriveCmd(stamp_s=1.0, speed_mps=1.0, steering_rad=0.1),
        Plan(
            stamp_s=1.0,
            horizon=np.zeros((3, 4)),
            inputs=np.zeros((2, 3)),
            beta=np.zeros(2),
            status="solved",
            solver_status="ok",
            iterations=1,
            solve_time_ms=1.0,
            method="mpcc",
            s_m=0.0,
            e_con_m=0.0,
            source_stamp_s=0.0,
            consecutive_failures=0,
        ),
    ):
        data = bytearray(msg.encode())
        i = where % len(data)
        data[i : i + len(noise)] = noise
        _decodes_or_message_error(bytes(data))
