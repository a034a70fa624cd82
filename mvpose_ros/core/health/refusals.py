"""The inputs a node refused since it started, by camera and cause, and the verdict that a camera
cannot work as configured: its first REFUSED_AFTER_S s of messages (at least REFUSED_MIN_MESSAGES)
were every one refused for one cause, none used. That is a wrong rig file or topic, not a bad
frame, and is said as such: an ERROR status with the cause (its fix included), which
`mvpose-graph` stops on, and the run summary's table."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Sequence

from mvpose_ros.core.health.status import Level, Status

REFUSED_AFTER_S = 2.0
REFUSED_MIN_MESSAGES = 3
MAX_CAUSES = 8  # per camera; further causes are counted together
OTHER_CAUSES = 'other causes'
STATUS_WHAT = 'refusals'  # a refusals status is named '<node>: refusals <camera>'
USED_KEY = 'used since start'
REFUSED_KEY = 'refused since start: '  # + the cause -> its count


@dataclass
class _Camera:
    used: int = 0
    first_refused: float | None = None  # monotonic s
    causes: Counter = field(default_factory=Counter)


class Refusals:
    """Per camera (by name): messages used, and messages refused by cause, since the start.
    `what` names the messages in the verdict ('image', 'openpose input')."""

    def __init__(self, cameras: Sequence[str], what: str) -> None:
        self._cameras = {name: _Camera() for name in cameras}
        self.what = what

    def refused(self, camera: str, cause: str, now: float) -> None:
        """One of the camera's messages was refused for `cause` (one line, its fix included)."""
        c = self._cameras[camera]
        if c.first_refused is None:
            c.first_refused = now
        c.causes[cause if cause in c.causes or len(c.causes) < MAX_CAUSES else OTHER_CAUSES] += 1

    def used(self, camera: str) -> None:
        """One of the camera's messages was used."""
        self._cameras[camera].used += 1

    def verdict(self, camera: str, now: float) -> str | None:
        """'every <what> refused: <cause>' when the camera cannot work (see the module), else None."""
        c = self._cameras[camera]
        if c.used or len(c.causes) != 1 or c.first_refused is None or now - c.first_refused < REFUSED_AFTER_S:
            return None
        [(cause, count)] = c.causes.items()
        return f'every {self.what} refused: {cause}' if count >= REFUSED_MIN_MESSAGES else None

    def statuses(self, node: str, now: float) -> list[Status]:
        """One status per camera: ERROR with the verdict when it cannot work, else OK with its
        counts; values: USED_KEY and REFUSED_KEY + cause -> count."""
        out = []
        for name, c in self._cameras.items():
            values = {USED_KEY: str(c.used), **{REFUSED_KEY + cause: str(n) for cause, n in c.causes.most_common()}}
            verdict = self.verdict(name, now)
            message = verdict or f'{c.used} used, {sum(c.causes.values())} refused since start'
            out.append(Status(f'{node}: {STATUS_WHAT} {name}', Level.ERROR if verdict else Level.OK, message, values,
                              name))
        return out


def refusals_of(status: Status) -> tuple[str, Counter] | None:
    """(camera, refused count by cause) of a refusals status (Refusals.statuses); None for another."""
    if not status.name.rpartition(': ')[2].startswith(STATUS_WHAT + ' '):
        return None
    causes = Counter({k[len(REFUSED_KEY):]: int(v) for k, v in status.values.items() if k.startswith(REFUSED_KEY)})
    return status.hardware_id, causes
