"""ROS 2 CDR on the wire: the message dicts of :mod:`.recording.ros2` ↔ CDR bytes, and type hashes.

The codec is the ``rosbags`` package's (Apache-2.0, pure Python, numpy-backed arrays), run on its
built-in ROS 2 Jazzy definitions: little-endian XCDR1 (plain CDR) with the 4-byte encapsulation
header ``00 01 00 00`` and the usual alignment (every primitive aligned to its size, counted
from the end of the header). The same typestore computes each type's REP-2011 hash (``RIHS01_``…)
that rmw_zenoh puts in its key expressions. The field mappings stay in :mod:`.recording.ros2`;
this module only turns their dicts into bytes and back. The tests check every type against the
independent serializer of ``mcap-ros2-support`` (driven by the ``.msg`` text of ``recording.ros2``).
"""

from __future__ import annotations

import dataclasses
from functools import cache
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

ROS_DISTRO_STORE = Stores.ROS2_JAZZY  # Jazzy and Kilted share the definitions and hashes we use
ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"  # CDR_LE representation id, options 0
PADDING_MASK = 0x03  # encapsulation options: bytes of padding after the last field
NUMPY_DTYPES = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}  # fmt: skip


class CdrError(ValueError):
    """Bytes that are not a CDR message of the expected type, or a dict that does not fit it."""


@cache
def typestore() -> Typestore:
    return get_typestore(ROS_DISTRO_STORE)


def full_name(ros_type: str) -> str:
    """``geometry_msgs/Twist`` (as in bags) → ``geometry_msgs/msg/Twist``; full names pass."""
    pkg, _, name = ros_type.partition("/")
    return ros_type if "/msg/" in ros_type else f"{pkg}/msg/{name}"


def dds_type_name(ros_type: str) -> str:
    """The DDS name rmw_zenoh puts in key expressions: ``geometry_msgs::msg::dds_::Twist_``."""
    pkg, _, name = full_name(ros_type).split("/")
    return f"{pkg}::msg::dds_::{name}_"


@cache
def type_hash(ros_type: str) -> str:
    """REP-2011 type hash, ``RIHS01_`` + 64 hex digits (as ``ros2 topic info -v`` prints it)."""
    name = full_name(ros_type)
    if name not in typestore().fielddefs:
        raise CdrError(f"unknown ROS 2 type {ros_type!r}")
    return typestore().hash_rihs01(name)


# ------------------------------------------------------------------ dict → message → bytes


def _value(kind: int, spec: Any, value: Any, where: str) -> Any:
    if kind == Nodetype.NAME:
        return _build(spec, value, where)
    if kind == Nodetype.BASE:
        return value
    (sub_kind, sub_spec), _length = spec
    if sub_kind == Nodetype.BASE and sub_spec[0] in NUMPY_DTYPES:
        data = np.frombuffer(value, np.uint8) if isinstance(value, (bytes, bytearray)) else value
        return np.asarray(data, dtype=NUMPY_DTYPES[sub_spec[0]])
    return [_value(sub_kind, sub_spec, v, f"{where}[{i}]") for i, v in enumerate(value)]


def _build(ros_type: str, value: dict[str, Any], where: str) -> Any:
    store = typestore()
    try:
        fields = store.fielddefs[ros_type][1]
        args = {name: _value(kind, spec, value[name], f"{where}.{name}") for name, (kind, spec) in fields}
    except KeyError as exc:
        raise CdrError(f"{where}: missing field {exc.args[0]!r} of {ros_type}") from None
    return store.types[ros_type](**args)


def encode(ros_type: str, value: dict[str, Any]) -> bytes:
    """CDR bytes (with the encapsulation header) of a message dict of ``ros_type``."""
    name = full_name(ros_type)
    if name not in typestore().fielddefs:
        raise CdrError(f"unknown ROS 2 type {ros_type!r}")
    msg = _build(name, value, name.rsplit("/", 1)[-1])
    return bytes(typestore().serialize_cdr(msg, name, little_endian=True))


# ------------------------------------------------------------------ bytes → dict


def _as_dict(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [_as_dict(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: _as_dict(getattr(value, f.name))
            for f in dataclasses.fields(value)
            if not f.name.startswith("__")
        }
    return value


def decode(ros_type: str, data: bytes) -> dict[str, Any]:
    """The message dict of CDR bytes; :class:`CdrError` (one line) for bytes that do not fit."""
    name = full_name(ros_type)
    if len(data) < len(ENCAPSULATION_CDR_LE) or data[:2] not in (b"\x00\x01", b"\x00\x00"):
        raise CdrError(f"{ros_type}: not CDR (header {bytes(data[:4]).hex() or 'missing'})")
    padding = data[3] & PADDING_MASK  # XTypes: the options' low bits count the trailing padding
    if padding:
        data = bytes(data[:4]) + bytes(data[4:-padding])
    try:
        msg = typestore().deserialize_cdr(data, name)
    except Exception as exc:  # rosbags raises assorted errors on truncated or garbled input
        raise CdrError(f"{ros_type}: cannot decode {len(data)} bytes ({exc})") from None
    out = _as_dict(msg)
    assert isinstance(out, dict)
    return out
