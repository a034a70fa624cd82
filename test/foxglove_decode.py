"""Decoding Foxglove's protobuf messages from the schema that comes with them (a
FileDescriptorSet, as a server advertises it and an MCAP stores it) with the protobuf package:
no code of foxglove-sdk's in the way."""
from __future__ import annotations

from functools import lru_cache

from google.protobuf import descriptor_pb2, descriptor_pool
from google.protobuf.message_factory import GetMessageClass


@lru_cache(maxsize=None)
def _message_class(name: str, descriptor_set: bytes):
    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return GetMessageClass(pool.FindMessageTypeByName(name))


def decode(name: str, descriptor_set: bytes, data: bytes):
    """The protobuf message `name` (e.g. 'foxglove.SceneUpdate') in `data`."""
    return _message_class(name, bytes(descriptor_set)).FromString(bytes(data))
