"""PointCloud2 as a packed table of records: a numpy structured dtype and its PointField layout,
the carrier shared by every record encoding of the ROS graph contract."""
from __future__ import annotations

import array
import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

UINT16_MAX = (1 << 16) - 1
UINT32_MAX = (1 << 32) - 1  # also the PointField count range

# (numpy kind, item size) -> PointField datatype
_DATATYPES = {
    ('i', 1): PointField.INT8, ('u', 1): PointField.UINT8,
    ('i', 2): PointField.INT16, ('u', 2): PointField.UINT16,
    ('i', 4): PointField.INT32, ('u', 4): PointField.UINT32,
    ('f', 4): PointField.FLOAT32, ('f', 8): PointField.FLOAT64,
}
_DATATYPE_NAMES = {
    PointField.INT8: 'INT8', PointField.UINT8: 'UINT8', PointField.INT16: 'INT16',
    PointField.UINT16: 'UINT16', PointField.INT32: 'INT32', PointField.UINT32: 'UINT32',
    PointField.FLOAT32: 'FLOAT32', PointField.FLOAT64: 'FLOAT64',
}


def _datatype_name(datatype: int) -> str:
    return f'{_DATATYPE_NAMES.get(datatype, "unknown")} ({datatype})'


class _Field(NamedTuple):
    name: str
    offset: int
    datatype: int
    count: int


def fields_of(dtype: np.dtype) -> list[PointField]:
    """The PointFields of a packed little-endian structured dtype, in its field order; a subarray
    field of shape s becomes one PointField of count prod(s)."""
    return [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
            for f in _layout(np.dtype(dtype))]


@lru_cache(maxsize=64)
def _layout(dtype: np.dtype) -> tuple[_Field, ...]:
    """fields_of's layout, worked out once per dtype: every message of an encoding shares it, and
    a flood of junk is checked against it at the cost of a comparison."""
    if dtype.names is None:
        raise ValueError(f'record dtype must be structured, got {dtype}')
    fields = []
    end = 0
    for name in dtype.names:
        sub, offset = dtype.fields[name][:2]
        base = sub.base
        key = (base.kind, base.itemsize)
        if key not in _DATATYPES or base.newbyteorder('<') != base:
            raise ValueError(f'record field {name!r}: {base.str} has no little-endian PointField '
                             f'datatype')
        if offset != end:
            raise ValueError(f'record field {name!r}: offset {offset}, expected {end} '
                             f'(records must be packed)')
        fields.append(_Field(name, offset, _DATATYPES[key], math.prod(sub.shape)))
        end = offset + sub.itemsize
    if end != dtype.itemsize:
        raise ValueError(f'record dtype has {dtype.itemsize - end} trailing padding bytes')
    return tuple(fields)


def to_cloud(records: np.ndarray, header: Header) -> PointCloud2:
    """A PointCloud2 of height 1 holding the records (N,) (structured, packed, little-endian)
    one per point."""
    records = np.asarray(records)
    if records.ndim != 1:
        raise ValueError(f'records must be one-dimensional, got shape {records.shape}')
    fields = fields_of(records.dtype)
    step = records.dtype.itemsize
    return PointCloud2(header=header, height=1, width=len(records), fields=fields,
                       is_bigendian=False, point_step=step, row_step=step * len(records),
                       data=array.array('B', np.ascontiguousarray(records).tobytes()),
                       is_dense=True)


def from_cloud(msg: PointCloud2, dtype: np.dtype) -> np.ndarray:
    """The records (N,) of a PointCloud2 whose layout must be exactly dtype's: field names,
    datatypes, counts and offsets, point_step, row_step and the data length are checked, and the
    first mismatch raises ValueError. Returns a copy, independent of the message."""
    dtype = np.dtype(dtype)
    expected = _layout(dtype)
    if msg.height != 1:
        raise ValueError(f'PointCloud2 height: expected 1, got {msg.height}')
    if msg.is_bigendian:
        raise ValueError('PointCloud2 is_bigendian: expected False, got True')
    if len(msg.fields) != len(expected):
        raise ValueError(f'PointCloud2 fields: expected {len(expected)} '
                         f'{[f.name for f in expected]}, got {len(msg.fields)} '
                         f'{[f.name for f in msg.fields]}')
    for i, (want, got) in enumerate(zip(expected, msg.fields)):
        if got.name != want.name:
            raise ValueError(f'PointCloud2 field {i} name: expected {want.name!r}, got {got.name!r}')
        if got.datatype != want.datatype:
            raise ValueError(f'PointCloud2 field {want.name!r} datatype: expected '
                             f'{_datatype_name(want.datatype)}, got {_datatype_name(got.datatype)}')
        if got.count != want.count:
            raise ValueError(f'PointCloud2 field {want.name!r} count: expected {want.count}, '
                             f'got {got.count}')
        if got.offset != want.offset:
            raise ValueError(f'PointCloud2 field {want.name!r} offset: expected {want.offset}, '
                             f'got {got.offset}')
    if msg.point_step != dtype.itemsize:
        raise ValueError(f'PointCloud2 point_step: expected {dtype.itemsize}, got {msg.point_step}')
    if msg.row_step != msg.point_step * msg.width:
        raise ValueError(f'PointCloud2 row_step: expected point_step * width = '
                         f'{msg.point_step * msg.width}, got {msg.row_step}')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if len(data) != msg.row_step:
        raise ValueError(f'PointCloud2 data: expected row_step = {msg.row_step} bytes, '
                         f'got {len(data)}')
    return np.frombuffer(data, dtype=dtype, count=msg.width).copy()
