"""core.health statuses <-> diagnostic_msgs/DiagnosticArray (one DiagnosticStatus per status,
values as KeyValue pairs)."""
from __future__ import annotations

from collections.abc import Sequence

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from mvpose_ros.core.health.status import Level, Status


def statuses_to_msg(statuses: Sequence[Status], stamp: Time) -> DiagnosticArray:
    """A DiagnosticArray of `statuses`, stamped `stamp`."""
    return DiagnosticArray(header=Header(stamp=stamp), status=[
        DiagnosticStatus(level=bytes([int(s.level)]), name=s.name, message=s.message, hardware_id=s.hardware_id,
                         values=[KeyValue(key=k, value=v) for k, v in s.values.items()])
        for s in statuses])


def msg_to_statuses(msg: DiagnosticArray) -> list[Status]:
    """The statuses of a DiagnosticArray; ValueError for a level other than OK, WARN, ERROR."""
    out = []
    for s in msg.status:
        level = s.level[0] if isinstance(s.level, (bytes, bytearray)) else int(s.level)
        if level not in tuple(Level):
            raise ValueError(f'diagnostic status {s.name!r}: level {level} is not OK, WARN or ERROR')
        out.append(Status(s.name, Level(level), s.message, {kv.key: kv.value for kv in s.values}, s.hardware_id))
    return out
