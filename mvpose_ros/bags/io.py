"""rosbag2 bags on disk: writing rclpy messages as CDR, reading raw CDR back in log-time order.

Bags are written with the `rosbags` library (no ROS install needed) but carry what `ros2 bag
info/play` expects: the ROS 2 type name, the `.msg` definition text and the RIHS01 type hash of
every topic, and the QoS the player offers (reliable, volatile, keep-last 100). The payload is the
exact `rclpy.serialization.serialize_message` output, so playing a bag publishes those bytes.
"""
from __future__ import annotations

import shutil
import sqlite3
import struct
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

from rclpy.serialization import serialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, ReaderError, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

if sys.version_info >= (3, 14):
    from compression.zstd import ZstdError
else:  # rosbags' own zstd dependency before 3.14
    from backports.zstd import ZstdError

STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
QOS_DEPTH = 100  # a burst of one frame from every camera must not drop messages

_ZERO = QosTime(0, 0)
# Recorded as each topic's offered QoS, which `ros2 bag play` then publishes with (the graph's data QoS).
OFFERED_QOS = Qos(QosHistory.KEEP_LAST, QOS_DEPTH, QosReliability.RELIABLE, QosDurability.VOLATILE,
                  _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False)

# Damage inside a bag surfaces from rosbags' parsers, sqlite and the decompressors under many types.
_DAMAGE = (ReaderError, ZstdError, EOFError, ValueError, KeyError, IndexError, TypeError,
           struct.error, sqlite3.Error, OSError, RuntimeError, OverflowError, MemoryError)


@dataclass(frozen=True)
class BagSummary:
    """What a bag holds.

    topics: topic -> (msgtype, message count), in topic order; first_ns/last_ns: log time of the
    first and last message (None when empty); custom_data: the metadata's custom_data map.
    """

    path: Path
    topics: dict[str, tuple[str, int]]
    message_count: int
    first_ns: int | None
    last_ns: int | None
    custom_data: dict[str, str]


@cache
def typestore() -> Typestore:
    """Message definitions and hashes of ROS 2 Jazzy (those of the installed rclpy messages)."""
    return get_typestore(Stores.ROS2_JAZZY)


def msgtype_of(msg: Any) -> str:
    """'sensor_msgs/msg/Image' for an rclpy sensor_msgs.msg.Image object."""
    cls = type(msg)
    return '/'.join(cls.__module__.split('.')[:2] + [cls.__name__])


def has_header(msgtype: str) -> bool:
    """The message starts with a std_msgs/Header, so its stamp sits right after the CDR header."""
    fields = typestore().fielddefs.get(msgtype, ((), ()))[1]
    return bool(fields) and fields[0][1][1] == 'std_msgs/msg/Header'


def write_bag(path: str | Path, items: Iterable[tuple[str, Any, int]], storage: str = 'mcap',
              custom_data: Mapping[str, str] | None = None) -> None:
    """Write (topic, rclpy message, log stamp ns) items into a new rosbag2 bag folder `path`.

    The bag is built beside `path` and moved into place only once complete, so an interrupted
    write never leaves something that looks like a bag. MCAP chunks are zstd-compressed (the
    `ros2 bag record --storage-preset-profile zstd_fast` layout).
    """
    path = Path(path)
    if storage not in STORAGES:
        raise ValueError(f'storage must be one of {", ".join(STORAGES)}; got {storage!r}')
    if path.exists():
        raise FileExistsError(f'{path}: already exists, not overwriting')
    staging = path.parent / f'.{path.name}.partial'
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        writer = Writer(staging / path.name, version=Writer.VERSION_LATEST, storage_plugin=STORAGES[storage])
        if storage == 'mcap':
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in (custom_data or {}).items():
            writer.set_custom_data(key, value)
        writer.open()
        try:
            _write_items(writer, items)
        except BaseException:
            writer.abort()
            raise
        writer.close()
        (staging / path.name).rename(path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _write_items(writer: Writer, items: Iterable[tuple[str, Any, int]]) -> None:
    connections = {}
    for topic, msg, stamp_ns in items:
        msgtype = msgtype_of(msg)
        conn = connections.get(topic)
        if conn is None:
            if msgtype not in typestore().fielddefs:
                raise ValueError(f'{topic}: message type {msgtype} has no ROS 2 Jazzy definition')
            conn = connections[topic] = writer.add_connection(
                topic, msgtype, typestore=typestore(), offered_qos_profiles=[OFFERED_QOS])
        elif conn.msgtype != msgtype:
            raise ValueError(f'{topic}: message type {msgtype}, expected {conn.msgtype} as before')
        if int(stamp_ns) < 0:
            raise ValueError(f'{topic}: log stamp must be >= 0 ns; got {stamp_ns}')
        writer.write(conn, int(stamp_ns), serialize_message(msg))


def _one_line(exc: BaseException) -> str:
    return ' '.join(str(exc).split()) or type(exc).__name__


@contextmanager
def _opened(path: str | Path) -> Iterator[Reader]:
    """An open rosbags Reader; missing -> FileNotFoundError, unreadable -> ValueError."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'bag not found: {path}')
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise ValueError(f'{path}: not a rosbag2 bag (no metadata.yaml)')
    try:
        reader = Reader(path)
        reader.open()
    except _DAMAGE as exc:
        raise ValueError(f'{path}: unreadable bag ({_one_line(exc)})') from None
    try:
        yield reader
    finally:
        reader.close()


def bag_summary(path: str | Path) -> BagSummary:
    """Topics with types and counts, first/last log stamp and custom data of the bag at `path`."""
    with _opened(path) as reader:
        topics = {name: (info.msgtype or '?', info.msgcount) for name, info in sorted(reader.topics.items())}
        count = reader.message_count
        custom = reader.storage.metadata.custom or {}
        return BagSummary(Path(path), topics, count, reader.start_time if count else None,
                          reader.end_time - 1 if count else None, dict(custom))


def bag_size(path: str | Path) -> int:
    """Bytes of the bag's files as stored (chunks compressed or not); FileNotFoundError when absent."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'bag not found: {path}')
    return sum(f.stat().st_size for f in path.iterdir() if f.is_file()) if path.is_dir() else path.stat().st_size


def read_bag(path: str | Path, topics: Sequence[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log stamp ns, CDR bytes) of every message, in log-time order.

    topics: only these (all when None or empty); a topic the bag does not hold is a ValueError.
    Damage found while reading raises ValueError naming the bag.
    """
    with _opened(path) as reader:
        connections = reader.connections
        if topics:
            missing = sorted(set(topics) - {c.topic for c in connections})
            if missing:
                raise ValueError(f'{path}: no topic {", ".join(missing)} in the bag '
                                 f'(it has {", ".join(sorted({c.topic for c in connections}))})')
            connections = [c for c in connections if c.topic in set(topics)]
        messages = reader.messages(connections=connections)
        # rosbags skips what a damaged chunk index hides: compare against the recorded counts.
        unread = {c.id: c.msgcount for c in connections}
        while True:
            try:
                conn, stamp, data = next(messages)
            except StopIteration:
                break
            except _DAMAGE as exc:
                raise ValueError(f'{path}: damaged bag ({_one_line(exc)})') from None
            unread[conn.id] -= 1
            yield conn.topic, conn.msgtype, stamp, bytes(data)
        lost = [(c.topic, unread[c.id]) for c in connections if unread[c.id]]
        if lost:
            raise ValueError(f'{path}: damaged bag ({lost[0][1]} messages of {lost[0][0]} unreadable or '
                             f'missing, {len(lost)} topics affected)')
