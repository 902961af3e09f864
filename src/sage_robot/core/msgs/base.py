"""Message machinery: every message is a frozen dataclass registered by name.

``@message`` makes the dataclass frozen, gives it an ``__eq__`` that compares numpy
arrays by value, and registers it so :func:`to_dict` / :func:`from_dict` can carry it
as JSON (web pages, recordings, a networked transport). Each message names the ROS 2
type it maps to at the edges (MCAP, Foxglove, a ROS bridge).
"""

from __future__ import annotations

import base64
import dataclasses
import enum
import types
import typing
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from typing_extensions import dataclass_transform

M = TypeVar("M")

REGISTRY: dict[str, type] = {}
ROS_TYPES: dict[str, str] = {}


def _field_equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.shape == b.shape
            and a.dtype == b.dtype
            and bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
        )
    return bool(a == b)


def _eq(self: Any, other: Any) -> bool:
    if type(self) is not type(other):
        return typing.cast(bool, NotImplemented)  # as in __eq__, which mypy exempts by name
    return all(
        _field_equal(getattr(self, f.name), getattr(other, f.name))
        for f in dataclasses.fields(self)
    )


@dataclass_transform(frozen_default=True)
def message(ros_type: str = "") -> Callable[[type[M]], type[M]]:
    """Class decorator: a frozen, registered message. ``ros_type`` e.g. 'geometry_msgs/msg/Twist'."""

    def wrap(cls: type[M]) -> type[M]:
        dc = dataclasses.dataclass(frozen=True, eq=False)(cls)
        dc.__eq__ = _eq  # type: ignore[method-assign]
        dc.__hash__ = None  # type: ignore[assignment]
        name = dc.__name__
        if name in REGISTRY and REGISTRY[name] is not dc:
            raise TypeError(f"message name {name!r} registered twice")
        REGISTRY[name] = dc
        if ros_type:
            ROS_TYPES[name] = ros_type
        return dc

    return wrap


# ---------------------------------------------------------------- JSON codec


def _encode(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        data = value.tolist()
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            data = _nonfinite_to_json(data)
        return {"__ndarray__": data, "dtype": str(value.dtype), "shape": list(value.shape)}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, bytes):
        return {"__bytes__": base64.b64encode(value).decode("ascii")}
    if isinstance(value, (tuple, list)):
        return [_encode(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, float) and value != value:  # NaN is not JSON
        return None
    return value


_NONFINITE = {"inf": float("inf"), "-inf": float("-inf"), "nan": float("nan")}


def _nonfinite_to_json(data: Any) -> Any:
    """JSON has no inf/nan: write them as the strings "inf", "-inf", "nan"."""
    if isinstance(data, list):
        return [_nonfinite_to_json(v) for v in data]
    if data != data:
        return "nan"
    if data in (float("inf"), float("-inf")):
        return "inf" if data > 0 else "-inf"
    return data


def _nonfinite_from_json(data: Any) -> Any:
    if isinstance(data, list):
        return [_nonfinite_from_json(v) for v in data]
    return _NONFINITE[data] if isinstance(data, str) else data


def to_dict(msg: Any) -> dict[str, Any]:
    """Encode a registered message as a JSON-ready dict with a ``type`` key."""
    name = type(msg).__name__
    if REGISTRY.get(name) is not type(msg):
        raise TypeError(f"{name} is not a registered message")
    out: dict[str, Any] = _encode(msg)
    out["type"] = name
    return out


def _decode(tp: Any, value: Any) -> Any:
    """``value`` (as :func:`_encode` wrote it) as the field type ``tp``."""
    if tp is Any:
        return value
    generic = _GENERIC_DECODERS.get(typing.get_origin(tp))
    if generic is not None:
        return generic(tp, value)
    if isinstance(tp, type):
        return _decode_class(tp, value)
    return value


def _decode_class(tp: type, value: Any) -> Any:
    exact = _TYPE_DECODERS.get(tp)
    if exact is not None:
        return exact(value)
    if issubclass(tp, enum.Enum):
        return tp(value)
    if dataclasses.is_dataclass(tp):
        return _from_fields(tp, value)
    return value


# ---- generic types: by their origin (``int | None`` → UnionType, ``tuple[int, ...]`` → tuple)


def _decode_union(tp: Any, value: Any) -> Any:
    args = typing.get_args(tp)
    if value is None and type(None) in args:
        return None
    for arg in args:
        if arg is type(None):
            continue
        try:
            return _decode(arg, value)
        except (TypeError, ValueError, KeyError):
            continue
    raise ValueError(f"{value!r} matches none of {tp}")


def _decode_tuple(tp: Any, value: Any) -> tuple[Any, ...]:
    args = typing.get_args(tp)
    if len(args) == 2 and args[1] is Ellipsis:
        return tuple(_decode(args[0], v) for v in value)
    return tuple(_decode(a, v) for a, v in zip(args, value, strict=True))


def _decode_dict(tp: Any, value: Any) -> dict[Any, Any]:
    _, vt = typing.get_args(tp)
    return {k: _decode(vt, v) for k, v in value.items()}


_GENERIC_DECODERS: dict[Any, Callable[[Any, Any], Any]] = {
    typing.Union: _decode_union,
    types.UnionType: _decode_union,
    tuple: _decode_tuple,
    dict: _decode_dict,
}


# ---- plain types, by the type itself


def _decode_array(value: Any) -> np.ndarray:
    if not isinstance(value, dict) or "__ndarray__" not in value:
        raise ValueError("expected an encoded array")
    arr = np.array(_nonfinite_from_json(value["__ndarray__"]), dtype=value["dtype"])
    shaped: np.ndarray = arr.reshape(value["shape"])
    return shaped


def _decode_bytes(value: Any) -> bytes:
    if not isinstance(value, dict) or "__bytes__" not in value:
        raise ValueError("expected encoded bytes")
    return base64.b64decode(value["__bytes__"])


def _decode_float(value: Any) -> float:
    if value is None:  # NaN was written as null
        return float("nan")
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise TypeError(f"expected a number, got {value!r}")
    return float(value)


def _decode_int(value: Any) -> int:
    if not isinstance(value, int) or isinstance(value, bool):
        raise TypeError(f"expected an integer, got {value!r}")
    return value


def _decode_str(value: Any) -> str:
    if not isinstance(value, str):
        raise TypeError(f"expected a string, got {value!r}")
    return value


def _decode_bool(value: Any) -> bool:
    if not isinstance(value, bool):
        raise TypeError(f"expected true/false, got {value!r}")
    return value


_TYPE_DECODERS: dict[type, Callable[[Any], Any]] = {
    np.ndarray: _decode_array,
    bytes: _decode_bytes,
    float: _decode_float,
    int: _decode_int,
    str: _decode_str,
    bool: _decode_bool,
}


def _from_fields(cls: type, data: Any) -> Any:
    if not isinstance(data, dict):
        raise TypeError(f"{cls.__name__}: expected an object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in data:
            try:
                kwargs[f.name] = _decode(hints[f.name], data[f.name])
            except (TypeError, ValueError, KeyError) as exc:
                raise ValueError(f"{cls.__name__}.{f.name}: {exc}") from None
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"{cls.__name__}: missing field {f.name!r}")
    return cls(**kwargs)


def from_dict(data: dict[str, Any], expected: type[M] | None = None) -> M:
    """Decode a dict made by :func:`to_dict`. Raises ValueError naming the bad field."""
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object, got {type(data).__name__}")
    name = data.get("type")
    cls = REGISTRY.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ValueError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise ValueError(f"expected a {expected.__name__}, got {name}")
    body = {k: v for k, v in data.items() if k != "type"}
    return typing.cast(M, _from_fields(cls, body))
