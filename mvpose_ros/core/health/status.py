"""One diagnostic status: a name, a level and a message, with named values (the shape of
diagnostic_msgs/DiagnosticStatus, without ROS)."""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Iterable


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels (STALE is the aggregator's, not a node's)."""

    OK = 0
    WARN = 1
    ERROR = 2


@dataclass(frozen=True)
class Status:
    """name: '<node>: <what>' (e.g. 'association: input cam2'); message: the reason for the
    level, or a one-line summary when OK; values: name -> value, as text."""

    name: str
    level: Level
    message: str
    values: dict[str, str] = field(default_factory=dict)
    hardware_id: str = ''


def judged(checks: Iterable[tuple[Level, str]], ok: str) -> tuple[Level, str]:
    """The worst level of (level, reason) checks and the reasons at that level ('; '-joined);
    (OK, ok) when none is above OK."""
    bad = [(level, reason) for level, reason in checks if level > Level.OK]
    if not bad:
        return Level.OK, ok
    worst = max(level for level, _ in bad)
    return worst, '; '.join(reason for level, reason in bad if level == worst)
