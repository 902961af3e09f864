"""A message on the wire: compact, typed, safe to decode from the network.

Layout (little-endian)::

    b"SG"  version:u8  header_len:u32  header (UTF-8 JSON)  buffer 0  buffer 1 ...

The header is the message as :func:`~sage_robot.core.msgs.to_dict` writes it (``type`` names
the registered message), except that numpy arrays and ``bytes`` are not inlined: they are
``{"__nd__": i, "dtype": "<f4", "shape": [360]}`` and ``{"__b__": i}``, references to raw
buffers that follow the header, whose lengths the header lists under ``"__buffers__"``. A
360-beam scan is 1.4 kB of floats plus ~150 bytes of header; a camera frame is its JPEG plus
~120 bytes. Decoding checks every field against the message's type as
:func:`~sage_robot.core.msgs.from_dict` checks JSON (one error naming the field); arrays may
only have plain numeric dtypes (no object arrays), and every length is checked against the
frame. Nothing is ever unpickled.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import json
import struct
import types
import typing
from collections.abc import Callable
from typing import Any

import numpy as np

from sage_robot.core.msgs import REGISTRY

MAGIC = b"SG"
VERSION = 1
_PREFIX = struct.Struct("<2sBI")  # magic, version, header length (bytes)
MAX_HEADER_BYTES = 16 * 1024 * 1024  # a frame's JSON header (a 1000-node health report is ~200 kB)
ARRAY_KINDS = frozenset("biuf")  # bool, signed, unsigned, float: the only dtypes on the wire
BUFFERS_KEY = "__buffers__"


class WireError(ValueError):
    """A frame that is not a valid encoded message (says why in one line)."""


def encode(msg: Any) -> bytes:
    """The frame for a registered message. Raises TypeError for anything else."""
    name = type(msg).__name__
    if REGISTRY.get(name) is not type(msg):
        raise TypeError(f"{name} is not a registered message")
    buffers: list[bytes] = []
    head: dict[str, Any] = _encode(msg, buffers)
    head["type"] = name
    head[BUFFERS_KEY] = [len(b) for b in buffers]
    text = json.dumps(head, separators=(",", ":"), default=_json_scalar).encode("utf-8")
    return b"".join([_PREFIX.pack(MAGIC, VERSION, len(text)), text, *buffers])


def _json_scalar(value: Any) -> Any:
    if isinstance(value, np.generic):  # a numpy scalar in a stats dict
        return value.item()
    raise TypeError(f"{type(value).__name__} cannot go on the wire")


_PLAIN = (float, int, str, bool, type(None))  # leaves that JSON writes as they are


_FIELD_NAMES: dict[type, tuple[str, ...] | None] = {}  # class -> its dataclass fields' names


def _field_names(cls: type) -> tuple[str, ...] | None:
    """A dataclass's field names (looked up once per class), None for any other class."""
    if cls not in _FIELD_NAMES:
        fields = dataclasses.fields(cls) if dataclasses.is_dataclass(cls) else None
        _FIELD_NAMES[cls] = None if fields is None else tuple(f.name for f in fields)
    return _FIELD_NAMES[cls]


def _encode(value: Any, buffers: list[bytes]) -> Any:
    cls = type(value)
    if cls in _PLAIN:
        return value
    names = _field_names(cls)
    if names is not None:
        return {name: _encode(getattr(value, name), buffers) for name in names}
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in ARRAY_KINDS:
            raise TypeError(f"arrays of dtype {value.dtype} cannot go on the wire")
        buffers.append(np.ascontiguousarray(value).tobytes())
        return {"__nd__": len(buffers) - 1, "dtype": value.dtype.str, "shape": list(value.shape)}
    if isinstance(value, bytes):
        buffers.append(value)
        return {"__b__": len(buffers) - 1}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, (tuple, list)):
        return [_encode(v, buffers) for v in value]
    if isinstance(value, dict):
        return {str(k): _encode(v, buffers) for k, v in value.items()}
    return value


def decode(frame: bytes | memoryview, expected: type | None = None) -> Any:
    """The message in a frame. Raises :class:`WireError` naming what is wrong."""
    view = memoryview(frame)
    if len(view) < _PREFIX.size:
        raise WireError(f"frame of {len(view)} bytes is too short")
    magic, version, head_len = _PREFIX.unpack_from(view)
    if magic != MAGIC or version != VERSION:
        raise WireError(f"not a SAGE frame (magic {bytes(magic)!r}, version {version})")
    if head_len > MAX_HEADER_BYTES or _PREFIX.size + head_len > len(view):
        raise WireError(f"header of {head_len} bytes does not fit the frame")
    try:
        head = json.loads(bytes(view[_PREFIX.size : _PREFIX.size + head_len]))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise WireError(f"bad header: {exc}") from None
    if not isinstance(head, dict):
        raise WireError("bad header: not an object")
    buffers = _split_buffers(view[_PREFIX.size + head_len :], head.pop(BUFFERS_KEY, None))
    name = head.pop("type", None)
    cls = REGISTRY.get(name) if isinstance(name, str) else None
    if cls is None:
        raise WireError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise WireError(f"expected a {expected.__name__}, got {name}")
    return _fields(cls, head, buffers)


def _split_buffers(body: memoryview, lengths: Any) -> list[memoryview]:
    if not isinstance(lengths, list) or not all(isinstance(n, int) and n >= 0 for n in lengths):
        raise WireError("bad header: no buffer table")
    if sum(lengths) != len(body):
        raise WireError(f"buffers of {sum(lengths)} bytes announced, {len(body)} sent")
    out, at = [], 0
    for n in lengths:
        out.append(body[at : at + n])
        at += n
    return out


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """A message class's field types (resolved once: ``get_type_hints`` is slow)."""
    return typing.get_type_hints(cls)


Convert = Callable[[Any, list[memoryview]], Any]  # a header value and the frame's buffers -> the field


@functools.cache
def _plan(cls: type) -> tuple[tuple[str, Convert, bool], ...]:
    """How to decode a message class, worked out once: (field, converter, required) per field."""
    hints = _hints(cls)
    return tuple(
        (f.name, _converter(hints[f.name]),
         f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)
        for f in dataclasses.fields(cls)
    )  # fmt: skip


def _fields(cls: type, data: Any, buffers: list[memoryview]) -> Any:
    """The header's values as the message's field types, checked like
    :func:`~sage_robot.core.msgs.from_dict` checks JSON (one error naming the field)."""
    if not isinstance(data, dict):
        raise WireError(f"{cls.__name__}: expected an object, got {type(data).__name__}")
    kwargs = {}
    for name, convert, required in _plan(cls):
        if name in data:
            try:
                kwargs[name] = convert(data[name], buffers)
            except (TypeError, ValueError, KeyError, IndexError) as exc:
                raise WireError(f"{cls.__name__}.{name}: {exc}") from None
        elif required:
            raise WireError(f"{cls.__name__}: missing field {name!r}")
    return cls(**kwargs)


def _converter(tp: Any) -> Convert:
    """The converter of one field type (checks as :func:`~sage_robot.core.msgs.from_dict`)."""
    origin = typing.get_origin(tp)
    if origin is not None:
        return _generic(origin, typing.get_args(tp))
    if tp is Any:
        return lambda v, _b: v
    scalar = _SCALARS.get(tp)
    if scalar is not None:
        return lambda v, _b: scalar(v)
    if tp is np.ndarray:
        return _array
    if tp is bytes:
        return _bytes
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return lambda v, _b: tp(v)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return lambda v, b: _fields(tp, v, b)  # its plan is made when first needed (nesting)

    def undecodable(_v: Any, _b: list[memoryview]) -> Any:
        raise TypeError(f"field type {tp} cannot be decoded")

    return undecodable


def _generic(origin: Any, args: tuple[Any, ...]) -> Convert:
    if origin is typing.Union or origin is types.UnionType:
        return _union(args)
    if origin is dict:
        item = _converter(args[1])

        def mapping(v: Any, b: list[memoryview]) -> Any:
            if not isinstance(_sequence(v), dict):
                raise TypeError(f"expected an object, got {v!r}")
            return {str(k): item(x, b) for k, x in v.items()}

        return mapping
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        each = _converter(args[0])
        return lambda v, b: tuple(each(x, b) for x in _sequence(v))
    if origin is tuple:
        parts = [_converter(a) for a in args]
        return lambda v, b: tuple(c(x, b) for c, x in zip(parts, _sequence(v), strict=True))
    if origin is list:
        each = _converter(args[0])
        return lambda v, b: [each(x, b) for x in _sequence(v)]

    def undecodable(_v: Any, _b: list[memoryview]) -> Any:
        raise TypeError(f"field type {origin} cannot be decoded")

    return undecodable


def _union(args: tuple[Any, ...]) -> Convert:
    may_be_none = type(None) in args
    options = [_converter(a) for a in args if a is not type(None)]

    def union(v: Any, b: list[memoryview]) -> Any:
        if v is None and may_be_none:
            return None
        for convert in options:
            try:
                return convert(v, b)
            except (TypeError, ValueError, KeyError):
                continue
        raise ValueError(f"{v!r} matches none of {args}")

    return union


def _sequence(v: Any) -> Any:
    if not isinstance(v, (list, dict)):
        raise TypeError(f"expected a list or an object, got {v!r}")
    return v


def _bytes(v: Any, buffers: list[memoryview]) -> bytes:
    if not isinstance(v, dict) or not isinstance(v.get("__b__"), int):
        raise TypeError("expected a bytes reference")
    return bytes(buffers[v["__b__"]])


def _float(v: Any) -> float:
    if v is None:  # NaN as the JSON codec writes it
        return float("nan")
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        raise TypeError(f"expected a number, got {v!r}")
    return float(v)


def _typed(kind: type) -> Any:
    def check(v: Any) -> Any:
        if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
            raise TypeError(f"expected {kind.__name__}, got {v!r}")
        return v

    return check


_SCALARS: dict[Any, Any] = {float: _float, int: _typed(int), str: _typed(str), bool: _typed(bool)}


def _array(ref: Any, buffers: list[memoryview]) -> np.ndarray:
    try:
        dtype = np.dtype(ref["dtype"])
        shape = tuple(int(n) for n in ref["shape"])
        buf = buffers[ref["__nd__"]]
    except (TypeError, ValueError, KeyError, IndexError) as exc:
        raise WireError(f"bad array reference: {exc}") from None
    if dtype.kind not in ARRAY_KINDS:
        raise WireError(f"arrays of dtype {dtype} are not accepted")
    if any(n < 0 for n in shape) or int(np.prod(shape)) * dtype.itemsize != len(buf):
        raise WireError(f"array of shape {shape} and dtype {dtype} does not match its {len(buf)} bytes")
    # A copy: the message owns writable memory, not the network buffer.
    arr: np.ndarray = np.frombuffer(buf, dtype=dtype).reshape(shape).copy()
    return arr
