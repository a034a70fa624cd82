"""A node parameter as the nodes declare it: name, default, description, the numeric range a value
must lie in, the values a string may take, and whether a change takes effect while the node runs
(ROS-free; nodes/runtime.py turns it into a ParameterDescriptor, cli/parameter_options into an
option)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Param:
    """name, default (its type is the parameter's type), description; low and high: the inclusive
    range of a numeric value (None: unbounded on that side); choices: the values a string may take
    (empty: any); live: a change applies at once (the node's parameter callback takes it), else the
    parameter is read-only (a change needs a restart)."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    live: bool = False
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        numeric = isinstance(self.default, (int, float)) and not isinstance(self.default, bool)
        if numeric and (self.low is None and self.high is None):
            raise ValueError(f'parameter {self.name}: a numeric parameter needs a range (low and/or high)')
        if not numeric and (self.low is not None or self.high is not None):
            raise ValueError(f'parameter {self.name}: a range needs a numeric default, got {self.default!r}')
        if numeric and not ((self.low is None or self.default >= self.low)
                            and (self.high is None or self.default <= self.high)):
            raise ValueError(f'parameter {self.name}: default {self.default} outside [{self.low}, {self.high}]')
        if self.choices and self.default not in self.choices:
            raise ValueError(f'parameter {self.name}: default {self.default!r} is not one of its choices')

    def check(self, value: Any) -> None:
        """ValueError naming the parameter unless value is of its type, in its range and among its
        choices (rclpy checks a node's types and ranges, argparse an option's choices: each a part)."""
        if isinstance(self.default, bool) and not isinstance(value, bool):  # bool('false') would be True
            raise ValueError(f'{self.name} must be true or false, got {value!r}')
        if self.choices and value not in self.choices:
            raise ValueError(f'{self.name} {value!r} is not one of {", ".join(self.choices)}')
        if (self.low is not None and value < self.low) or (self.high is not None and value > self.high):
            raise ValueError(f'{self.name} {value} is not in {self.low}..{self.high}')
