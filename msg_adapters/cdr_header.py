"""The std_msgs/Header at the front of a serialised (CDR) message, read and rewritten in the
bytes without deserialising the message: the player moves stamps on for later loops, the
recorder times raw messages, and a node checks an input's stamp, frame and size (or whether it
differs from the last but for its stamp) before paying for its message objects (then deserialise)."""
from __future__ import annotations

import struct
from typing import Any

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2

NS = 1_000_000_000
# serialised bytes of a PointCloud2 beyond its data: header, fields and counts (205 for an OpenPose
# cloud on Shelf): a node's bound on an input's bytes is its bound on the data plus this
CLOUD_OVERHEAD = 4096


class Oversize(ValueError):
    """An input larger than any its source can honestly produce: refused, not decoded."""


# CDR encapsulation identifiers (first two bytes, big-endian) and the struct order they imply.
_BYTE_ORDER = {b'\x00\x00': '>', b'\x00\x01': '<'}
_ENCAPSULATION = 4  # bytes before the payload; a leading std_msgs/Header puts its stamp right after
_FRAME_ID = _ENCAPSULATION + 8  # the frame_id string (uint32 length with its NUL, then the bytes)
STAMP_END = _FRAME_ID  # a message's first bytes up to here are all header_stamp_ns reads


def _byte_order(cdr: bytes) -> str:
    if len(cdr) < STAMP_END or cdr[:2] not in _BYTE_ORDER:
        raise ValueError(f'not a plain CDR message with a header stamp (first bytes {cdr[:4].hex()}, '
                         f'{len(cdr)} bytes)')
    return _BYTE_ORDER[cdr[:2]]


def header_stamp_ns(cdr: bytes) -> int:
    """Header stamp (ns) of a serialised message whose first field is a std_msgs/Header."""
    sec, nanosec = struct.unpack_from(_byte_order(cdr) + 'iI', cdr, _ENCAPSULATION)
    return sec * NS + nanosec


def header_frame_id(cdr: bytes) -> str:
    """Header frame_id of a serialised message whose first field is a std_msgs/Header;
    ValueError for bytes that cannot hold one."""
    order = _byte_order(cdr)
    if len(cdr) < _FRAME_ID + 4:
        raise ValueError(f'not a plain CDR message with a header frame_id ({len(cdr)} bytes)')
    (size,) = struct.unpack_from(order + 'I', cdr, _FRAME_ID)
    start = _FRAME_ID + 4
    if not 1 <= size <= len(cdr) - start or cdr[start + size - 1] != 0:
        raise ValueError(f'not a plain CDR message with a header frame_id (string of {size} bytes in '
                         f'{len(cdr)})')
    try:
        return cdr[start:start + size - 1].decode()
    except UnicodeDecodeError:
        raise ValueError('header frame_id is not UTF-8') from None


def with_header_stamp(cdr: bytes, stamp_ns: int) -> bytes:
    """The serialised message with its header stamp replaced; every other byte unchanged."""
    sec, nanosec = divmod(int(stamp_ns), NS)
    if not -2 ** 31 <= sec < 2 ** 31:
        raise ValueError(f'stamp {stamp_ns} ns does not fit builtin_interfaces/Time')
    out = bytearray(cdr)
    struct.pack_into(_byte_order(cdr) + 'iI', out, _ENCAPSULATION, sec, nanosec)
    return bytes(out)


def after_stamp(cdr: bytes) -> bytes:
    """Every byte of a serialised message whose first field is a std_msgs/Header but its
    encapsulation and stamp: equal for two messages that differ in their stamps alone (a driver's
    CameraInfo with each image), so a node can check such a message once per content."""
    _byte_order(cdr)
    return cdr[STAMP_END:]


def deserialise(cdr: bytes, msg_type: type) -> Any:
    """The message of type msg_type of serialised bytes; ValueError of one line for bytes that do
    not deserialise (rclpy raises RuntimeError with the C error)."""
    try:
        return deserialize_message(cdr, msg_type)
    except RuntimeError as exc:
        raise ValueError(f'{" ".join(str(exc).split())} ({len(cdr)} bytes as a {msg_type.__name__})') from None


def deserialise_cloud(cdr: bytes) -> PointCloud2:
    """The PointCloud2 of serialised bytes (deserialise)."""
    return deserialise(cdr, PointCloud2)
