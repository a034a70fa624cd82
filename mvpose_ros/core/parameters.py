"""A node parameter as the nodes declare it: name, default, description, the numeric range a value
must lie in, and whether a change takes effect while the node runs (ROS-free; nodes/runtime.py
turns it into a ParameterDescriptor)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Param:
    """name, default (its type is the parameter's type), description; low and high: the inclusive
    range of a numeric value (None: unbounded on that side); live: a change applies at once (the
    node's parameter callback takes it), else the parameter is read-only (a change needs a restart)."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    live: bool = False

    def __post_init__(self) -> None:
        numeric = isinstance(self.default, (int, float)) and not isinstance(self.default, bool)
        if numeric and (self.low is None and self.high is None):
            raise ValueError(f'parameter {self.name}: a numeric parameter needs a range (low and/or high)')
        if not numeric and (self.low is not None or self.high is not None):
            raise ValueError(f'parameter {self.name}: a range needs a numeric default, got {self.default!r}')
        if numeric and not ((self.low is None or self.default >= self.low)
                            and (self.high is None or self.default <= self.high)):
            raise ValueError(f'parameter {self.name}: default {self.default} outside [{self.low}, {self.high}]')
