"""The wire format of racestack messages: field specs, the ``Message`` base and the codec.

Wire format (one message = one msgpack map with string keys)::

    {"type": "<tag>", "v": <schema version>, "stamp_s": <float>, "seq": <int>, <fields>...}

* Floats are msgpack floats (an integer is accepted where a float is expected); ``None``
  (optional fields) is msgpack nil; booleans are msgpack booleans; strings are UTF-8.
* numpy arrays are maps ``{"dtype": "<f8", "shape": [n, m], "data": <bin>}`` with
  little-endian dtype strings; the dtype must be exactly the declared one.
* Unknown extra keys are ACCEPTED AND IGNORED, in every message and in array maps, so a
  newer sender may add optional fields without breaking older receivers; anything that
  changes the meaning or type of an existing field bumps the type's version ``"v"``, and a
  receiver rejects every version but its own.
* A field with a default in the record (the optional ones) may be absent on the wire;
  every other field is required, and so is ``seq`` (it defaults to 0 only in constructors).

Every record validates itself on construction (types, finiteness, ranges, array dtype and
shape, allowed strings) and so does ``decode``: a record that exists is valid. Any problem
raises ``MessageError`` with a short machine-readable ``reason`` (one of ``REASONS``) and a
human-readable ``detail``; decoding never raises anything else.
"""

from __future__ import annotations

import copy
import math
import numbers
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, ClassVar, Self, TypeVar

import msgpack
import numpy as np

#: Largest payload ``decode`` accepts [bytes].
MAX_PAYLOAD_BYTES = 4 * 1024 * 1024
#: Largest string field accepted [characters] (unless a field declares a smaller limit).
MAX_STR_LEN = 8192
#: Largest number of elements of an array field.
MAX_ARRAY_ELEMENTS = 1_000_000

#: Every ``MessageError.reason``.
REASONS = frozenset(
    {
        "too_large",  # payload longer than MAX_PAYLOAD_BYTES
        "not_msgpack",  # not decodable msgpack (garbage, truncated, trailing bytes, bad UTF-8)
        "not_a_map",  # valid msgpack but not a map with string keys
        "no_type",  # the "type" tag is missing or not a string
        "unknown_type",  # the "type" tag names no known message
        "wrong_type",  # a known type, but not the one expected on this key
        "wrong_version",  # "v" missing, not an int, or not this type's version
        "missing_field",  # a required field is absent
        "bad_type",  # a field has the wrong type (e.g. a string for a float)
        "not_finite",  # NaN or infinity where a finite number is required
        "out_of_range",  # a number outside its allowed range
        "bad_array",  # malformed array map, wrong dtype, shape or length
        "bad_value",  # a string outside its allowed set or pattern, an inconsistency
    }
)


class MessageError(ValueError):
    """A payload or record is malformed, of the wrong type or version, or out of range.

    Attributes:
        reason: short machine-readable cause, one of ``REASONS`` (used to count drops).
        detail: human-readable explanation naming the message type and field.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


# --------------------------------------------------------------------------- field specs
class Spec:
    """How one field is validated and carried on the wire (subclasses below)."""

    optional: bool = False

    def check(self, where: str, value: Any) -> Any:
        """Validate and normalise a value given to the constructor; MessageError if bad."""
        raise NotImplementedError

    def to_wire(self, value: Any) -> Any:
        """The msgpack-ready form of a validated value."""
        return value

    def from_wire(self, where: str, raw: Any) -> Any:
        """Turn the raw msgpack value into what ``check`` accepts (arrays are maps)."""
        return raw

    def describe(self) -> str:
        """A short human description (type and range) for documentation."""
        raise NotImplementedError


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


@dataclass(frozen=True)
class Real(Spec):
    """A float in ``[lo, hi]``; finite unless ``allow_inf``; None allowed if ``optional``."""

    lo: float = -math.inf
    hi: float = math.inf
    optional: bool = False
    allow_inf: bool = False

    def check(self, where: str, value: Any) -> float | None:
        if type(value) is float:  # the common case, without the ABC checks
            x = value
        elif value is None and self.optional:
            return None
        elif not _is_number(value):
            raise MessageError("bad_type", f"{where}: expected a number, got {_tname(value)}")
        else:
            x = float(value)
        if math.isnan(x) or (math.isinf(x) and not self.allow_inf):
            raise MessageError("not_finite", f"{where}: {x} is not finite")
        if not self.lo <= x <= self.hi:
            raise MessageError("out_of_range", f"{where}: {x} outside [{self.lo}, {self.hi}]")
        return x

    def describe(self) -> str:
        return f"float in [{self.lo:g}, {self.hi:g}]" + (" or None" if self.optional else "")


@dataclass(frozen=True)
class Int(Spec):
    """An integer in ``[lo, hi]`` (booleans rejected); None allowed if ``optional``."""

    lo: int = 0
    hi: int = 2**63 - 1
    optional: bool = False

    def check(self, where: str, value: Any) -> int | None:
        if type(value) is int:  # the common case, without the ABC checks
            if not self.lo <= value <= self.hi:
                raise MessageError(
                    "out_of_range", f"{where}: {value} outside [{self.lo}, {self.hi}]"
                )
            return value
        if value is None and self.optional:
            return None
        if not isinstance(value, numbers.Integral) or isinstance(value, bool | np.bool_):
            raise MessageError("bad_type", f"{where}: expected an integer, got {_tname(value)}")
        n = int(value)
        if not self.lo <= n <= self.hi:
            raise MessageError("out_of_range", f"{where}: {n} outside [{self.lo}, {self.hi}]")
        return n

    def describe(self) -> str:
        return f"int in [{self.lo}, {self.hi}]" + (" or None" if self.optional else "")


@dataclass(frozen=True)
class Bool(Spec):
    """A boolean (integers are not accepted)."""

    def check(self, where: str, value: Any) -> bool:
        if not isinstance(value, bool | np.bool_):
            raise MessageError("bad_type", f"{where}: expected a bool, got {_tname(value)}")
        return bool(value)

    def describe(self) -> str:
        return "bool"


@dataclass(frozen=True)
class Str(Spec):
    """A string: one of ``choices`` if given, else any text of at most ``max_len`` chars."""

    choices: frozenset[str] | None = None
    max_len: int = MAX_STR_LEN
    optional: bool = False

    def check(self, where: str, value: Any) -> str | None:
        if value is None and self.optional:
            return None
        if not isinstance(value, str):
            raise MessageError("bad_type", f"{where}: expected a string, got {_tname(value)}")
        if self.choices is not None and value not in self.choices:
            raise MessageError(
                "bad_value", f"{where}: {value[:40]!r} not one of {sorted(self.choices)}"
            )
        if len(value) > self.max_len:
            raise MessageError("out_of_range", f"{where}: longer than {self.max_len} characters")
        return value

    def describe(self) -> str:
        if self.choices is not None:
            return " | ".join(f'"{c}"' for c in sorted(self.choices))
        return f"str (<= {self.max_len} chars)"


@dataclass(frozen=True)
class Array(Spec):
    """A numpy array of dtype ``dtype`` (little-endian) with ``ndim`` dimensions.

    ``cols`` fixes the size of the last dimension (None: free); the first dimension must
    lie in ``[min_len, max_len]``. Values must be finite (``+inf`` allowed with
    ``allow_pos_inf``) and inside ``[lo, hi]``. Constructors accept anything numeric
    (lists, other float dtypes) and store a read-only contiguous copy; decoding demands the
    exact dtype string.
    """

    dtype: str = "<f8"
    ndim: int = 1
    cols: int | None = None
    min_len: int = 0
    max_len: int = MAX_ARRAY_ELEMENTS
    lo: float = -math.inf
    hi: float = math.inf
    allow_pos_inf: bool = False
    optional: bool = False

    def check(self, where: str, value: Any) -> np.ndarray | None:
        if value is None and self.optional:
            return None
        if isinstance(value, str | bytes | Mapping) or value is None:
            raise MessageError("bad_type", f"{where}: expected an array, got {_tname(value)}")
        try:
            raw = np.asarray(value)
        except Exception as exc:  # ragged nested lists and the like
            raise MessageError("bad_array", f"{where}: not an array ({exc})") from None
        if raw.dtype.kind not in "fiu":
            raise MessageError("bad_array", f"{where}: non-numeric dtype {raw.dtype}")
        a = np.array(raw, dtype=np.dtype(self.dtype), copy=True, order="C")
        self._check_shape(where, a.shape)
        if a.size:
            bad = np.isnan(a) | (np.isinf(a) & ~(self.allow_pos_inf & (a > 0)))
            if bad.any():
                raise MessageError("not_finite", f"{where}: contains NaN or infinity")
            finite = a[np.isfinite(a)]
            if finite.size and (finite.min() < self.lo or finite.max() > self.hi):
                raise MessageError(
                    "out_of_range", f"{where}: values outside [{self.lo:g}, {self.hi:g}]"
                )
        a.setflags(write=False)
        return a

    def _check_shape(self, where: str, shape: tuple[int, ...]) -> None:
        if len(shape) != self.ndim:
            raise MessageError("bad_array", f"{where}: expected {self.ndim}-D, got shape {shape}")
        if self.cols is not None and shape[-1] != self.cols:
            raise MessageError(
                "bad_array", f"{where}: expected {self.cols} columns, got shape {shape}"
            )
        if not self.min_len <= shape[0] <= self.max_len:
            raise MessageError(
                "bad_array",
                f"{where}: length {shape[0]} outside [{self.min_len}, {self.max_len}]",
            )

    def to_wire(self, value: np.ndarray | None) -> dict[str, Any] | None:
        if value is None:
            return None
        return {"dtype": value.dtype.str, "shape": list(value.shape), "data": value.tobytes()}

    def from_wire(self, where: str, raw: Any) -> np.ndarray | None:
        if raw is None and self.optional:
            return None
        if not isinstance(raw, dict):
            raise MessageError("bad_array", f"{where}: expected a {{dtype, shape, data}} map")
        dtype, shape, data = raw.get("dtype"), raw.get("shape"), raw.get("data")
        if dtype != np.dtype(self.dtype).str:
            raise MessageError(
                "bad_array", f"{where}: dtype {dtype!r}, expected {np.dtype(self.dtype).str!r}"
            )
        if not isinstance(data, bytes):
            raise MessageError("bad_array", f"{where}: data is not binary")
        if (
            not isinstance(shape, list)
            or len(shape) != self.ndim
            or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
        ):
            raise MessageError("bad_array", f"{where}: bad shape {shape!r}")
        count = math.prod(shape)
        if count > MAX_ARRAY_ELEMENTS or count * np.dtype(self.dtype).itemsize != len(data):
            raise MessageError(
                "bad_array", f"{where}: {len(data)} data bytes do not match shape {shape}"
            )
        self._check_shape(where, tuple(shape))
        return np.frombuffer(data, dtype=np.dtype(self.dtype)).reshape(shape)

    def describe(self) -> str:
        dims = ["n"] * self.ndim
        if self.cols is not None:
            dims[-1] = str(self.cols)
        return f"{np.dtype(self.dtype).name}[{', '.join(dims)}]"


def _tname(value: Any) -> str:
    return type(value).__name__


# --------------------------------------------------------------------------- field helpers
_SPEC = "racestack_spec"
#: Metadata flag: required on the wire although the constructor has a default (``seq``).
_WIRE_REQUIRED = "racestack_wire_required"


def f_real(lo: float = -math.inf, hi: float = math.inf, *, allow_inf: bool = False) -> Any:
    """A required float field in ``[lo, hi]``."""
    return field(metadata={_SPEC: Real(lo, hi, allow_inf=allow_inf)})


def f_opt_real(lo: float = -math.inf, hi: float = math.inf) -> Any:
    """An optional float field (None when unknown), in ``[lo, hi]`` when given."""
    return field(default=None, metadata={_SPEC: Real(lo, hi, optional=True)})


def f_int(lo: int = 0, hi: int = 2**63 - 1) -> Any:
    """A required integer field in ``[lo, hi]``."""
    return field(metadata={_SPEC: Int(lo, hi)})


def f_opt_int(lo: int = 0, hi: int = 2**63 - 1) -> Any:
    """An optional integer field (None when unknown)."""
    return field(default=None, metadata={_SPEC: Int(lo, hi, optional=True)})


def f_bool() -> Any:
    """A required boolean field."""
    return field(metadata={_SPEC: Bool()})


def f_choice(*choices: str) -> Any:
    """A required string field from an allowed set."""
    return field(metadata={_SPEC: Str(frozenset(choices))})


def f_str(max_len: int = MAX_STR_LEN) -> Any:
    """A required free-text field of at most `max_len` characters."""
    return field(metadata={_SPEC: Str(None, max_len)})


def meta(spec: Spec) -> dict[str, Spec]:
    """Field metadata carrying `spec`: ``field(metadata=meta(Array(...)))``."""
    return {_SPEC: spec}


# --------------------------------------------------------------------------- base record
#: type tag -> message class, filled by ``Message.__init_subclass__``.
REGISTRY: dict[str, type[Message]] = {}
_FIELD_CACHE: dict[type, tuple[tuple[str, Spec, bool], ...]] = {}

#: Sender timestamps [s] accepted: sim time from 0, wall time up to year ~2286.
MAX_STAMP_S = 1e10


@dataclass(frozen=True, kw_only=True, eq=False)
class Message:
    """Base of every message record: frozen, validated, with stamp and sequence number.

    Attributes:
        stamp_s: the sender's timestamp [s] (sim time or wall time, its own clock), >= 0.
        seq: sequence number, stamped by the bus publisher (0 until published).

    Subclasses set ``TYPE`` (the wire tag), ``VERSION`` (the schema version) and
    ``RELIABLE`` (default delivery of their publishers: True = reliable and
    congestion-control BLOCK, for commands and events; False = DROP, for high-rate data).
    """

    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    RELIABLE: ClassVar[bool] = False

    stamp_s: float = f_real(0.0, MAX_STAMP_S)
    seq: int = field(default=0, metadata={_SPEC: Int(0, 2**63 - 1), _WIRE_REQUIRED: True})

    __hash__ = None  # type: ignore[assignment]  # arrays make value hashing meaningless

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        tag = cls.__dict__.get("TYPE", "")
        if tag:
            if tag in REGISTRY:
                raise TypeError(f"message type tag {tag!r} registered twice")
            REGISTRY[tag] = cls

    def __post_init__(self) -> None:
        for fname, spec, where in _checks(type(self)):
            value = spec.check(where, getattr(self, fname))
            object.__setattr__(self, fname, value)
        self._check()

    def _check(self) -> None:
        """Cross-field checks of a subclass (raise MessageError("bad_value", ...))."""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for fname, _, _ in field_specs(type(self)):
            a, b = getattr(self, fname), getattr(other, fname)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if not (
                    isinstance(a, np.ndarray)
                    and isinstance(b, np.ndarray)
                    and a.dtype == b.dtype
                    and np.array_equal(a, b)
                ):
                    return False
            elif a != b:
                return False
        return True

    def with_seq(self, seq: int) -> Self:
        """A copy with another sequence number (no re-validation of the other fields)."""
        _SEQ.check(f"{type(self).__name__}.seq", seq)
        out = copy.copy(self)
        object.__setattr__(out, "seq", int(seq))
        return out

    def to_wire(self) -> dict[str, Any]:
        """The msgpack-ready map (``"type"``, ``"v"`` and every field)."""
        wire: dict[str, Any] = {"type": self.TYPE, "v": self.VERSION}
        for fname, spec, _ in field_specs(type(self)):
            wire[fname] = spec.to_wire(getattr(self, fname))
        return wire

    def encode(self, seq: int | None = None) -> bytes:
        """The msgpack bytes of this record, or of its copy with sequence number `seq`."""
        wire = self.to_wire()
        if seq is not None:
            wire["seq"] = _SEQ.check(f"{type(self).__name__}.seq", seq)
        return msgpack.packb(wire, use_bin_type=True)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Decode and validate bytes that must hold this type (MessageError otherwise)."""
        return decode(data, cls)

    @classmethod
    def fields_doc(cls) -> list[tuple[str, str]]:
        """(field name, type/range description) of every field, for documentation."""
        return [(fname, spec.describe()) for fname, spec, _ in field_specs(cls)]


_SEQ = Int(0, 2**63 - 1)
_CHECK_CACHE: dict[type, tuple[tuple[str, Spec, str], ...]] = {}


def _checks(cls: type) -> tuple[tuple[str, Spec, str], ...]:
    """(name, spec, "Class.name") of every field of `cls`: what ``__post_init__`` checks."""
    checks = _CHECK_CACHE.get(cls)
    if checks is None:
        checks = _CHECK_CACHE[cls] = tuple(
            (fname, spec, f"{cls.__name__}.{fname}") for fname, spec, _ in field_specs(cls)
        )
    return checks


def field_specs(cls: type) -> tuple[tuple[str, Spec, bool], ...]:
    """(name, spec, required on the wire) of every field of message class `cls` (cached)."""
    specs = _FIELD_CACHE.get(cls)
    if specs is None:
        out = []
        for f in fields(cls):
            spec = f.metadata.get(_SPEC)
            if spec is None:
                raise TypeError(f"{cls.__name__}.{f.name} has no field spec")
            required = (f.default is MISSING and f.default_factory is MISSING) or f.metadata.get(
                _WIRE_REQUIRED, False
            )
            out.append((f.name, spec, required))
        specs = _FIELD_CACHE[cls] = tuple(out)
    return specs


# --------------------------------------------------------------------------- codec
M = TypeVar("M", bound=Message)


def unpack_map(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """msgpack bytes -> a dict with string keys; MessageError for anything else."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise MessageError("not_msgpack", f"payload is {_tname(data)}, not bytes")
    if len(data) > MAX_PAYLOAD_BYTES:
        raise MessageError("too_large", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        obj = msgpack.unpackb(bytes(data), raw=False, strict_map_key=False, use_list=True)
    except Exception as exc:  # ExtraData, FormatError, StackError, UnicodeDecodeError, ...
        raise MessageError("not_msgpack", f"undecodable msgpack ({type(exc).__name__})") from None
    if not isinstance(obj, dict) or not all(isinstance(k, str) for k in obj):
        raise MessageError("not_a_map", f"payload is msgpack {_tname(obj)}, not a string map")
    return obj


def _message_class(wire: dict[str, Any]) -> type[Message]:
    tag = wire.get("type")
    if not isinstance(tag, str):
        raise MessageError("no_type", "the 'type' tag is missing or not a string")
    cls = REGISTRY.get(tag)
    if cls is None:
        raise MessageError("unknown_type", f"unknown message type {tag[:40]!r}")
    return cls


def from_wire(wire: dict[str, Any], expected: type[M] | None = None) -> M | Message:
    """Validate an unpacked map into its record (of type `expected` when given)."""
    cls = _message_class(wire)
    if expected is not None and cls is not expected:
        raise MessageError("wrong_type", f"got {cls.TYPE!r}, expected {expected.TYPE!r}")
    v = wire.get("v")
    if not isinstance(v, int) or isinstance(v, bool) or v != cls.VERSION:
        raise MessageError(
            "wrong_version", f"{cls.TYPE}: version {v!r}, this build reads {cls.VERSION}"
        )
    # Build the record directly (what the constructor does, each field set once): every
    # field from the wire or its default, validated by its spec, then the cross-field checks.
    obj = object.__new__(cls)
    try:
        for fname, spec, required, where, default in _wire_fields(cls):
            if fname in wire:
                value = spec.check(where, spec.from_wire(where, wire[fname]))
            elif required:
                raise MessageError("missing_field", f"{where} is missing")
            else:
                value = default
            object.__setattr__(obj, fname, value)
        obj._check()
    except MessageError:
        raise
    except Exception as exc:  # defensive: a validator bug must still be a MessageError
        raise MessageError("bad_value", f"{cls.__name__}: {type(exc).__name__}: {exc}") from None
    return obj


_WIRE_CACHE: dict[type, tuple[tuple[str, Spec, bool, str, Any], ...]] = {}


def _wire_fields(cls: type) -> tuple[tuple[str, Spec, bool, str, Any], ...]:
    """(name, spec, required on the wire, "Class.name", default) of every field (cached);
    a default is already validated (by the spec) once, here."""
    out = _WIRE_CACHE.get(cls)
    if out is None:
        defaults = {f.name: f.default for f in fields(cls)}
        rows = []
        for (fname, spec, required), (_, _, where) in zip(
            field_specs(cls), _checks(cls), strict=True
        ):
            default = defaults[fname]
            if not required:
                default = spec.check(where, default)
            rows.append((fname, spec, required, where, default))
        out = _WIRE_CACHE[cls] = tuple(rows)
    return out


def _decode(data: bytes | bytearray | memoryview, expected: type[M] | None) -> Message:
    try:
        return from_wire(unpack_map(data), expected)
    except MessageError:
        raise
    except Exception as exc:  # defensive: nothing else may escape a decode
        raise MessageError("bad_value", f"{type(exc).__name__}: {exc}") from None


def decode(data: bytes | bytearray | memoryview, expected: type[M]) -> M:
    """Decode bytes that must hold a message of type `expected`; raises only MessageError."""
    return _decode(data, expected)  # type: ignore[return-value]


def decode_any(data: bytes | bytearray | memoryview) -> Message:
    """Decode bytes holding any known message type; raises only MessageError."""
    return _decode(data, None)


def encode(record: Message) -> bytes:
    """The msgpack bytes of a record (same as ``record.encode()``)."""
    return record.encode()
