"""The wire format of racestack messages: the ``Message`` base (a msgspec Struct) and the codec.

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

A record is a frozen ``msgspec.Struct`` whose field annotations carry the rules
(``Annotated[float, Meta(ge=..., le=...)]``, ``Literal[...]``, ``Meta(max_length=...)``, and
``Annotated[np.ndarray, Array(...)]`` for arrays). msgspec checks them in C, in one pass, both
when a record is built in code (the constructor is ``msgspec.convert`` of its keyword
arguments) and when bytes are decoded; arrays and cross-field rules are checked by the
record's ``__post_init__``. A record that exists is valid. Any problem raises
``MessageError`` with a short machine-readable ``reason`` (one of ``REASONS``) and a
human-readable ``detail``; decoding never raises anything else.
"""

from __future__ import annotations

import math
import numbers
import re
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Self, TypeVar

import msgspec
import numpy as np
from msgspec import Meta

#: Largest payload ``decode`` accepts [bytes].
MAX_PAYLOAD_BYTES = 4 * 1024 * 1024
#: Largest string field accepted [characters] (unless a field declares a smaller limit).
MAX_STR_LEN = 8192
#: Largest number of elements of an array field.
MAX_ARRAY_ELEMENTS = 1_000_000
#: Sender timestamps [s] accepted: sim time from 0, wall time up to year ~2286.
MAX_STAMP_S = 1e10
#: Largest sequence number.
MAX_SEQ = 2**63 - 1

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
        "out_of_range",  # a number outside its allowed range, a string too long
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


# --------------------------------------------------------------------------- arrays
@dataclass(frozen=True)
class Array:
    """Rules of a numpy array field: ``name: Annotated[np.ndarray, Array(...)]``.

    An array of dtype ``dtype`` (little-endian) with ``ndim`` dimensions; ``cols`` fixes the
    size of the last dimension (None: free); the first dimension must lie in
    ``[min_len, max_len]``. Values must be finite (``+inf`` allowed with ``allow_pos_inf``)
    and inside ``[lo, hi]``. Constructors accept anything numeric (lists, other float
    dtypes) and store a read-only contiguous copy; decoding demands the exact dtype string.
    """

    dtype: str = "<f8"
    ndim: int = 1
    cols: int | None = None
    min_len: int = 0
    max_len: int = MAX_ARRAY_ELEMENTS
    lo: float = -math.inf
    hi: float = math.inf
    allow_pos_inf: bool = False

    def coerce(self, where: str, value: np.ndarray) -> np.ndarray:
        """The validated read-only array of `value` (a ``_WireArray`` or a constructor's)."""
        if type(value) is _WireArray:
            if value.dtype.str != self.dtype:
                raise MessageError(
                    "bad_array", f"{where}: dtype {value.dtype.str!r}, expected {self.dtype!r}"
                )
            self._check_shape(where, value.shape)
            a = value.view(np.ndarray)  # read-only already: a view of the payload's bytes
        else:
            if value.dtype.kind not in "fiu":
                raise MessageError("bad_array", f"{where}: non-numeric dtype {value.dtype}")
            a = np.array(value, dtype=self.dtype, copy=True, order="C")
            self._check_shape(where, a.shape)
            a.setflags(write=False)
        if a.size:  # min and max are NaN if any value is: two passes over the data
            lo, hi = a.min(), a.max()
            if math.isnan(lo) or lo == -math.inf or (hi == math.inf and not self.allow_pos_inf):
                raise MessageError("not_finite", f"{where}: contains NaN or infinity")
            if hi == math.inf and self.hi != math.inf:  # the largest finite value counts
                hi = a[np.isfinite(a)].max(initial=-math.inf)
            if lo < self.lo or hi > self.hi:
                raise MessageError(
                    "out_of_range", f"{where}: values outside [{self.lo:g}, {self.hi:g}]"
                )
        return a

    def _check_shape(self, where: str, shape: tuple[int, ...]) -> None:
        if len(shape) != self.ndim:
            raise MessageError("bad_array", f"{where}: expected {self.ndim}-D, got {shape}")
        if self.cols is not None and shape[-1] != self.cols:
            raise MessageError("bad_array", f"{where}: expected {self.cols} columns, got {shape}")
        if not self.min_len <= shape[0] <= self.max_len:
            raise MessageError(
                "bad_array",
                f"{where}: length {shape[0]} outside [{self.min_len}, {self.max_len}]",
            )

    def describe(self) -> str:
        dims = ["n"] * self.ndim
        if self.cols is not None:
            dims[-1] = str(self.cols)
        return f"{np.dtype(self.dtype).name}[{', '.join(dims)}]"


class _WireArray(np.ndarray):
    """An array just read off the wire: its dtype is checked against the field's next."""


#: dtype strings an array map may declare (little-endian or byte-order-free numbers).
_WIRE_DTYPES = {(d := np.dtype(c).newbyteorder("<")).str: d for c in "bBhHiIlLqQefd"}


def _array_from_wire(_: type, raw: Any) -> np.ndarray:
    """Decoder hook: a ``{dtype, shape, data}`` map -> a read-only array over its bytes."""
    if not isinstance(raw, dict):
        raise MessageError("bad_array", "expected a {dtype, shape, data} map")
    dtype, shape, data = raw.get("dtype"), raw.get("shape"), raw.get("data")
    dt = _WIRE_DTYPES.get(dtype) if type(dtype) is str else None
    if dt is None:
        raise MessageError("bad_array", f"dtype {dtype!r} is not a little-endian number type")
    if not isinstance(data, bytes):
        raise MessageError("bad_array", "data is not binary")
    if not isinstance(shape, list) or not all(type(n) is int and n >= 0 for n in shape):
        raise MessageError("bad_array", f"bad shape {shape!r}")
    count = math.prod(shape)
    if count > MAX_ARRAY_ELEMENTS or count * dt.itemsize != len(data):
        raise MessageError("bad_array", f"{len(data)} data bytes do not match shape {shape}")
    return np.frombuffer(data, dtype=dt).reshape(shape).view(_WireArray)


def _array_from_value(_: type, value: Any) -> np.ndarray:
    """Constructor hook: anything array-like (lists, tuples) -> an array."""
    if isinstance(value, str | bytes | Mapping) or value is None:
        raise MessageError("bad_type", f"expected an array, got {type(value).__name__}")
    try:
        return np.asarray(value)
    except Exception as exc:  # ragged nested lists and the like
        raise MessageError("bad_array", f"not an array ({exc})") from None


def _array_to_wire(value: Any) -> Any:
    """Encoder hook: an array -> its ``{dtype, shape, data}`` map (and a str subclass, which
    a string field keeps as given, e.g. ``np.str_``, -> its plain str)."""
    if isinstance(value, np.ndarray):
        return {"dtype": value.dtype.str, "shape": list(value.shape), "data": value.tobytes()}
    if isinstance(value, str):
        return str.__str__(value)
    raise NotImplementedError(f"cannot encode {type(value).__name__}")


def coerce_arrays(record: Message) -> None:
    """Validate the array fields of `record` in place (called by ``__post_init__``)."""
    for name, spec, where in type(record)._info.arrays:
        value = getattr(record, name)
        if value is not None:
            msgspec.structs.force_setattr(record, name, spec.coerce(where, value))


# --------------------------------------------------------------------------- fields
@dataclass(frozen=True)
class FieldInfo:
    """One field of a message class, as msgspec checks it (documentation, tests, tools).

    Attributes:
        name: the field (and wire key) name.
        type: the ``msgspec.inspect`` type of a given value (None stripped), e.g.
            ``FloatType(ge=..., le=...)``, ``IntType``, ``BoolType``, ``StrType(max_length)``,
            ``LiteralType(values)`` or ``CustomType`` (arrays: see ``array``).
        optional: None is accepted.
        required: the key must be present on the wire.
        array: the rules of an array field, else None.
    """

    name: str
    type: msgspec.inspect.Type
    optional: bool
    required: bool
    array: Array | None

    def describe(self) -> str:
        """A short human description (type and range)."""
        t = self.type
        if self.array is not None:
            text = self.array.describe()
        elif isinstance(t, msgspec.inspect.FloatType):
            text = f"float in [{t.ge:g}, {t.le:g}]"
        elif isinstance(t, msgspec.inspect.IntType):
            text = f"int in [{t.ge}, {t.le}]"
        elif isinstance(t, msgspec.inspect.LiteralType):
            text = " | ".join(f'"{c}"' for c in sorted(t.values))
        elif isinstance(t, msgspec.inspect.StrType):
            text = f"str (<= {t.max_length} chars)"
        else:
            text = "bool"
        return text + (" or None" if self.optional else "")


@dataclass(frozen=True)
class _ClassInfo:
    """What the codec needs of one message class (built once, with the class)."""

    names: frozenset[str]
    fields: tuple[FieldInfo, ...]
    types: dict[str, Any]  # name -> annotation (what ``check_field`` converts to)
    arrays: tuple[tuple[str, Array, str], ...]  # (name, rules, "Class.name")
    decoder: msgspec.msgpack.Decoder
    prefix: bytes  # map header with room for "type" and "v", then those two entries
    skip: int  # length of msgspec's own map header, replaced by ``prefix``


def _map_header(n: int) -> bytes:
    return bytes([0x80 | n]) if n < 16 else b"\xde" + n.to_bytes(2, "big")


def _class_info(cls: type[Message]) -> _ClassInfo:
    hints = typing.get_type_hints(cls, include_extras=True)
    fields, arrays = [], []
    for f in msgspec.inspect.type_info(cls).fields:
        t = f.type
        optional = isinstance(t, msgspec.inspect.UnionType)
        if optional:
            (t,) = [x for x in t.types if not isinstance(x, msgspec.inspect.NoneType)]
        spec = _array_rules(hints[f.name])
        if spec is not None:
            arrays.append((f.name, spec, f"{cls.__name__}.{f.name}"))
        required = f.required or f.name == "seq"
        fields.append(FieldInfo(f.name, t, optional, required, spec))
    n = len(fields)
    head = msgspec.msgpack.encode({"type": cls.TYPE, "v": cls.VERSION})[1:]
    return _ClassInfo(
        names=frozenset(cls.__struct_fields__),
        fields=tuple(fields),
        types={name: hints[name] for name in cls.__struct_fields__},
        arrays=tuple(arrays),
        decoder=msgspec.msgpack.Decoder(cls, dec_hook=_array_from_wire),
        prefix=_map_header(n + 2) + head,
        skip=len(_map_header(n)),
    )


def _array_rules(annotation: Any) -> Array | None:
    """The ``Array`` in ``Annotated[np.ndarray, Array(...)]`` (or in a union with None)."""
    for arg in typing.get_args(annotation):
        if isinstance(arg, Array):
            return arg
        if (found := _array_rules(arg)) is not None:
            return found
    return None


# --------------------------------------------------------------------------- base record
#: type tag -> message class, filled when each class is defined.
REGISTRY: dict[str, type[Message]] = {}


class _RecordMeta(msgspec.StructMeta):
    """Metaclass of the records: keyword-only fields, registration, validating constructor."""

    def __new__(mcls, name: str, bases: tuple[type, ...], ns: dict[str, Any], **kw: Any):
        kw.setdefault("kw_only", True)  # base fields (stamp_s, seq) stay first on the wire
        return super().__new__(mcls, name, bases, ns, **kw)

    def __init__(cls, name: str, bases: tuple[type, ...], ns: dict[str, Any], **kw: Any):
        super().__init__(name, bases, ns, **kw)
        tag = ns.get("TYPE", "")
        if tag:
            if tag in REGISTRY:
                raise TypeError(f"message type tag {tag!r} registered twice")
            REGISTRY[tag] = cls  # type: ignore[assignment]
        cls._info = _class_info(cls)  # type: ignore[arg-type]

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        """Build and validate a record (keyword arguments only); MessageError if invalid."""
        info: _ClassInfo = cls._info
        if args:
            raise TypeError(f"{cls.__name__}() takes keyword arguments only")
        if not kwargs.keys() <= info.names:
            unknown = sorted(kwargs.keys() - info.names)
            raise TypeError(f"{cls.__name__}() got unexpected keyword arguments {unknown}")
        try:
            return msgspec.convert(kwargs, cls, dec_hook=_array_from_value)
        except msgspec.ValidationError as exc:
            first = exc
        plain = {k: _plain(v) for k, v in kwargs.items()}  # numpy scalars, int subclasses...
        if any(type(plain[k]) is not type(v) for k, v in kwargs.items()):
            try:
                return msgspec.convert(plain, cls, dec_hook=_array_from_value)
            except msgspec.ValidationError as exc:
                first = exc
        if missing := _MISSING.match(str(first)):
            raise TypeError(f"{cls.__name__}() missing keyword argument {missing[1]!r}") from None
        raise _field_error(cls, first, plain.get) from None


def _plain(value: Any) -> Any:
    """The plain Python value of a numpy scalar or a number/str subclass (else `value`)."""
    if type(value) in (float, int, str, bool) or value is None:
        return value
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    if isinstance(value, str):
        return str.__str__(value)
    return value


class Message(msgspec.Struct, metaclass=_RecordMeta, frozen=True, eq=False, gc=False):
    """Base of every message record: frozen, validated, with stamp and sequence number.

    Attributes:
        stamp_s: the sender's timestamp [s] (sim time or wall time, its own clock), >= 0.
        seq: sequence number, stamped by the bus publisher (0 until published).

    Subclasses set ``TYPE`` (the wire tag), ``VERSION`` (the schema version) and
    ``RELIABLE`` (default delivery of their publishers: True = reliable and
    congestion-control BLOCK, for commands and events; False = DROP, for high-rate data).
    A subclass with array fields or cross-field rules defines ``__post_init__`` (calling
    ``coerce_arrays(self)`` first, raising ``MessageError`` for a broken rule).
    """

    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    RELIABLE: ClassVar[bool] = False
    _info: ClassVar[_ClassInfo]

    stamp_s: Annotated[float, Meta(ge=0.0, le=MAX_STAMP_S)]
    seq: Annotated[int, Meta(ge=0, le=MAX_SEQ)] = 0

    __hash__ = None  # type: ignore[assignment]  # arrays make value hashing meaningless

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for name in self.__struct_fields__:
            a, b = getattr(self, name), getattr(other, name)
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

    def __reduce__(self) -> tuple[Any, ...]:  # pickle and deepcopy rebuild (and re-validate)
        return (_rebuild, (type(self), msgspec.structs.asdict(self)))

    def with_seq(self, seq: int) -> Self:
        """A copy with another sequence number (no re-validation of the other fields)."""
        if type(seq) is not int or not 0 <= seq <= MAX_SEQ:
            seq = type(self).check_field("seq", seq)
        out = self.__copy__()
        msgspec.structs.force_setattr(out, "seq", seq)
        return out

    def to_wire(self) -> dict[str, Any]:
        """The msgpack-ready map (``"type"``, ``"v"`` and every field)."""
        wire: dict[str, Any] = {"type": self.TYPE, "v": self.VERSION}
        for name in self.__struct_fields__:
            value = getattr(self, name)
            wire[name] = _array_to_wire(value) if isinstance(value, np.ndarray) else value
        return wire

    def encode(self, seq: int | None = None) -> bytes:
        """The msgpack bytes of this record, or of its copy with sequence number `seq`."""
        record = self if seq is None else self.with_seq(seq)
        info = self._info
        # msgspec writes the map of the fields; "type" and "v" go in front of them
        return info.prefix + _ENCODER.encode(record)[info.skip :]

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Decode and validate bytes that must hold this type (MessageError otherwise)."""
        return decode(data, cls)

    @classmethod
    def fields_info(cls) -> tuple[FieldInfo, ...]:
        """Every field in wire order (``stamp_s``, ``seq``, then the type's own)."""
        return cls._info.fields

    @classmethod
    def check_field(cls, name: str, value: Any) -> Any:
        """`value` as field `name` would store it (e.g. an int as a float); MessageError if
        the field rejects it. Lets a driver drop one bad value instead of a whole record."""
        info = cls._info
        where = f"{cls.__name__}.{name}"
        try:
            value = msgspec.convert(_plain(value), info.types[name], dec_hook=_array_from_value)
        except msgspec.ValidationError as exc:
            raise _field_error(cls, exc, lambda _: _plain(value), name) from None
        spec = next((s for n, s, _ in info.arrays if n == name), None)
        return spec.coerce(where, value) if spec is not None and value is not None else value


def _rebuild(cls: type[Message], fields: dict[str, Any]) -> Message:
    return cls(**fields)


_ENCODER = msgspec.msgpack.Encoder(enc_hook=_array_to_wire)


# --------------------------------------------------------------------------- errors
#: msgspec's error text: "<text>" or "<text> - at `$.<field>...`".
_ERROR_TEXT = re.compile(r"(?P<text>.*?)(?: - at `\$(?P<path>[^`]*)`)?", re.S)
_FIELD = re.compile(r"\.(\w+)")
_MISSING = re.compile(r"Object missing required field `(\w+)`\Z")
_BOUND = re.compile(r"Expected `\w+(?: \| null)?` (?:>=|<=|of length)")  # a broken Meta bound


def _field_error(
    cls: type[Message], exc: msgspec.ValidationError, raw: Callable[[str], Any],
    name: str | None = None,
) -> MessageError:
    """The MessageError of a msgspec validation failure of `cls`.

    `raw(name)` gives the value that was checked (to tell NaN and infinity from a plain
    out-of-range number: msgspec reports both as a broken bound); `name` is the field when
    a single value was checked.
    """
    if missing := _MISSING.match(str(exc)):
        return MessageError("missing_field", f"{cls.__name__}.{missing[1]} is missing")
    m = _ERROR_TEXT.fullmatch(str(exc))  # always matches
    text, path = m["text"], m["path"] or ""
    if name is None and (f := _FIELD.match(path)):
        name = f[1]
    where = f"{cls.__name__}.{name}" if name else cls.__name__
    cause = exc.__cause__
    if isinstance(cause, MessageError):  # raised by an array hook or a __post_init__ rule
        return MessageError(cause.reason, f"{where}: {cause.detail}" if name else cause.detail)
    if text.startswith("Invalid enum value"):
        return MessageError("bad_value", f"{where}: {text}")
    if ", got `" in text:
        return MessageError("bad_type", f"{where}: {text}")
    if _BOUND.match(text):
        value = raw(name or "")
        if isinstance(value, float) and not math.isfinite(value):
            return MessageError("not_finite", f"{where}: {value} is not finite")
        return MessageError("out_of_range", f"{where}: {text} (got {value!r:.40})")
    return MessageError("bad_value", f"{where}: {text}")


# --------------------------------------------------------------------------- codec
M = TypeVar("M", bound=Message)


class _Envelope(msgspec.Struct):
    """The keys read before the fields: type tag, version and the presence of ``seq``."""

    type: Any = msgspec.UNSET
    v: Any = msgspec.UNSET
    seq: Any = msgspec.UNSET


_ENVELOPE = msgspec.msgpack.Decoder(_Envelope)


def _check_bytes(data: Any) -> None:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise MessageError("not_msgpack", f"payload is {type(data).__name__}, not bytes")
    if len(data) > MAX_PAYLOAD_BYTES:
        raise MessageError("too_large", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")


def _ext(code: int, data: memoryview) -> msgspec.msgpack.Ext:
    if code < 0:  # reserved by the msgpack spec (-1, the timestamp, never gets here)
        raise ValueError(f"reserved ext type {code}")
    return msgspec.msgpack.Ext(code, bytes(data))


_ANY = msgspec.msgpack.Decoder(ext_hook=_ext)


def unpack_map(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """msgpack bytes -> a dict with string keys; MessageError for anything else."""
    _check_bytes(data)
    try:
        obj = _ANY.decode(data)
    except Exception as exc:  # DecodeError, RecursionError, ...
        raise MessageError("not_msgpack", f"undecodable msgpack ({type(exc).__name__})") from None
    if not isinstance(obj, dict) or not all(isinstance(k, str) for k in obj):
        raise MessageError("not_a_map", f"payload is {type(obj).__name__}, not a string map")
    return obj


def _decode(data: bytes | bytearray | memoryview, expected: type[M] | None) -> Message:
    _check_bytes(data)
    cls = None
    try:
        env = _ENVELOPE.decode(data)  # one pass over the map: type, v, seq; fields skipped
        cls = _class_of(env, expected)
        return cls._info.decoder.decode(data)  # one pass: every field decoded and checked
    except Exception as exc:  # nothing but MessageError leaves a decode
        # Rejected. Framing problems come first, as a full parse finds them: not msgpack
        # (truncated, trailing bytes, bad UTF-8 anywhere), not a string-keyed map.
        wire = unpack_map(data)
        if isinstance(exc, MessageError):
            raise
        if cls is None or not isinstance(exc, msgspec.ValidationError):
            raise MessageError("bad_value", f"{type(exc).__name__}: {exc}") from None
        raise _field_error(cls, exc, wire.get) from None


def _class_of(env: _Envelope, expected: type[M] | None) -> type[Message]:
    """The message class of an envelope; MessageError if it is not an expected message."""
    tag = env.type
    if type(tag) is not str:
        raise MessageError("no_type", "the 'type' tag is missing or not a string")
    cls = REGISTRY.get(tag)
    if cls is None:
        raise MessageError("unknown_type", f"unknown message type {tag[:40]!r}")
    if expected is not None and cls is not expected:
        raise MessageError("wrong_type", f"got {cls.TYPE!r}, expected {expected.TYPE!r}")
    if type(env.v) is not int or env.v != cls.VERSION:
        raise MessageError(
            "wrong_version", f"{cls.TYPE}: version {env.v!r}, this build reads {cls.VERSION}"
        )
    if env.seq is msgspec.UNSET:
        raise MessageError("missing_field", f"{cls.__name__}.seq is missing")
    return cls


def decode(data: bytes | bytearray | memoryview, expected: type[M]) -> M:
    """Decode bytes that must hold a message of type `expected`; raises only MessageError."""
    return _decode(data, expected)  # type: ignore[return-value]


def decode_any(data: bytes | bytearray | memoryview) -> Message:
    """Decode bytes holding any known message type; raises only MessageError."""
    return _decode(data, None)


def encode(record: Message) -> bytes:
    """The msgpack bytes of a record (same as ``record.encode()``)."""
    return record.encode()
