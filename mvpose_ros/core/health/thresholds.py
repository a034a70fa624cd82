"""The thresholds that turn a node's figures into OK / WARN / ERROR, defined once: their defaults,
ranges and descriptions are the `diagnostics.*` parameters every node declares (docs/operations.md,
"Health and diagnostics", lists them). Every one but `period` and `residual_frames` can be
changed while the node runs."""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

from mvpose_ros.core.parameters import Param

PREFIX = 'diagnostics.'


@dataclass(frozen=True)
class HealthThresholds:
    """See DESCRIPTIONS; seconds, pixels and fractions."""

    period: float = 1.0
    window: float = 5.0
    stale_error: float = 2.0
    rate_warn_ratio: float = 0.5
    drop_warn: float = 0.05
    drop_error: float = 0.5
    latency_warn: float = 1.0
    latency_error: float = 5.0
    residual_ratio: float = 2.0
    residual_floor: float = 10.0
    residual_frames: int = 50
    residual_min_score: float = 0.3

    @classmethod
    def from_params(cls, values: Mapping[str, Any]) -> HealthThresholds:
        """From parameter values named with PREFIX (others are ignored, absent ones keep their defaults)."""
        return cls(**{f.name: values[PREFIX + f.name] for f in fields(cls) if PREFIX + f.name in values})


# name -> (description, low, high, live)
_SPECS: dict[str, tuple[str, float, float, bool]] = {
    'period': ('s between two /diagnostics messages of the node', 0.1, 60.0, False),
    'window': ('s of recent history the rates, drops, stage times and latencies are taken over', 0.5, 600.0, True),
    'stale_error': ('an input silent this many s is ERROR while another input of the node sends (WARN when every '
                    'input is silent: idle, or the end of a replay)', 0.1, 3600.0, True),
    'rate_warn_ratio': ("an input's rate below this fraction of the median rate of the node's other inputs is WARN",
                        0.0, 1.0, True),
    'drop_warn': ("fraction of an input's messages dropped in the window above which it is WARN", 0.0, 1.0, True),
    'drop_error': ("fraction of an input's messages dropped in the window above which it is ERROR", 0.0, 1.0, True),
    'latency_warn': ('s of median latency (in the node, or from the capture stamp when that is on the node\'s '
                     'clock) above which the node is WARN', 0.0, 3600.0, True),
    'latency_error': ('s of median latency above which the node is ERROR', 0.0, 3600.0, True),
    'residual_ratio': ("bp_solver: a camera's reprojection residual above this many times the median of the other "
                       "cameras' (and above residual_floor) is WARN: a camera moved out of its calibration",
                       1.0, 1000.0, True),
    'residual_floor': ('bp_solver: px; a residual below it is never WARN', 0.0, 10000.0, True),
    'residual_frames': ('bp_solver: recent output frames the per-camera residual is the median over', 1, 100000, False),
    'residual_min_score': ('bp_solver: 2D keypoints scoring less are left out of the residual', 0.0, 1.0, True),
}
RESIDUAL = tuple(name for name in _SPECS if name.startswith('residual_'))


def health_parameters(residual: bool = False) -> list[Param]:
    """The `diagnostics.*` parameters (with residual: also the bp_solver's residual ones)."""
    defaults = HealthThresholds()
    return [Param(PREFIX + name, getattr(defaults, name), description, low, high, live)
            for name, (description, low, high, live) in _SPECS.items() if residual or name not in RESIDUAL]
