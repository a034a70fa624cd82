"""Wall time per named step of the 3D stage, accumulated over a run (seconds)."""
from __future__ import annotations

import time
from collections import defaultdict


class StageTimer:
    """Accumulated wall time per named step, in seconds."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def add(self, name: str, since: float) -> float:
        """Charge the time since `since` (a time.perf_counter() value) to `name`; returns now."""
        now = time.perf_counter()
        self.seconds[name] += now - since
        return now
