"""Replay pacing, free of ROS: which bag messages form a frame, when each frame is due, how stamps
move on for later loops and how far ahead of downstream the player may run (stamps are read and
rewritten in the serialised bytes: msg_adapters.cdr_header).

A frame is every message sharing one log stamp (all cameras of one dataset frame). A *set* (for
bags of a rig whose cameras stamp their own capture times) is one synchronised capture: the
cameras' image messages grouped by approximate synchronisation of their header stamps (the graph's
own rule, core.association.approximate_sync, with the graph's max_skew), with the messages that go
with them (each camera's CameraInfo); see group_sets. Loop k >= 1
replays the bag with every stamp moved on by k * (last - first + one frame period), so the stream
stays strictly increasing and keeps its frame spacing across the seam.
"""
from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator, Sequence

from msg_adapters.cdr_header import NS, header_stamp_ns
from mvpose_ros.core.association.approximate_sync import ApproximateSync
from mvpose_ros.core.defaults import FRAME_RATE

FRAME_PERIOD_NS = round(1e9 / FRAME_RATE)  # the datasets' frame f has stamp f * FRAME_PERIOD_NS


@dataclass
class Frame:
    """Messages of one log stamp, in bag order.

    messages: (topic, msgtype, CDR bytes) tuples.
    """

    stamp_ns: int
    messages: list[tuple[str, str, bytes]] = field(default_factory=list)


def group_frames(messages: Iterable[tuple[str, str, int, bytes]]) -> Iterator[Frame]:
    """(topic, msgtype, stamp ns, CDR) in log-time order -> frames of equal stamps.

    A stamp lower than its predecessor is a ValueError: frames would be split and replayed out
    of order.
    """
    frame: Frame | None = None
    for topic, msgtype, stamp, cdr in messages:
        if frame is not None and stamp != frame.stamp_ns:
            if stamp < frame.stamp_ns:
                raise ValueError(f'messages out of log-time order: {topic} at {stamp} ns after '
                                 f'{frame.stamp_ns} ns')
            yield frame
            frame = None
        if frame is None:
            frame = Frame(stamp)
        frame.messages.append((topic, msgtype, cdr))
    if frame is not None:
        yield frame


@dataclass
class SyncSet(Frame):
    """One synchronised set of a rig bag: stamp_ns is the earliest member's header stamp (the
    stamp the graph gives the set and its skeletons); index: its number in the bag from 0;
    members: camera topic -> its header stamp (ns); skew_ns: newest minus oldest member stamp;
    messages: the members and the messages going with them, in bag order."""

    index: int = 0
    members: dict[str, int] = field(default_factory=dict)
    skew_ns: int = 0

    def moved(self, offset_ns: int, index: int) -> SyncSet:
        """This set as a later pass of the bag plays it: every stamp, its members' too, moved by
        offset_ns (loop_offset_ns), numbered index; no messages."""
        return SyncSet(self.stamp_ns + offset_ns, index=index,
                       members={t: m + offset_ns for t, m in self.members.items()}, skew_ns=self.skew_ns)


def group_sets(messages: Iterable[tuple[str, str, int, bytes]], cameras: Sequence[str], max_skew: float,
               timeout: float = 0.5, stamped: Callable[[str], bool] = lambda msgtype: True) -> Iterator[SyncSet]:
    """(topic, msgtype, log stamp ns, CDR) in log-time order -> the bag's synchronised sets.

    cameras: the topics whose messages are synchronised (one per camera, each starting with a
    std_msgs/Header); sets are ApproximateSync(len(cameras), timeout, max_skew) over their header
    stamps, arrivals at their log times. Every other message goes with the first set released
    after it whose newest member stamp is not older than its header stamp (unstamped ones: with the
    first set released after them); an image the synchronisation refuses (late, duplicate) is
    treated the same way, so nothing of the bag is left out. What follows the last set goes with it.
    stamped(msgtype): whether that type starts with a header (others count as unstamped).
    """
    cams = list(cameras)
    if not cams:
        raise ValueError('group_sets needs at least one camera topic')
    camera_of = {t: c for c, t in enumerate(cams)}
    sync = ApproximateSync(len(cams), timeout, max_skew)
    order = 0
    extras: list[tuple[int, int | None, tuple[str, str, bytes]]] = []  # (bag order, header stamp, message)
    held: SyncSet | None = None  # the latest set, kept until the next one (the end takes the rest)
    count = 0

    def take(released) -> Iterator[SyncSet]:
        nonlocal held, count, extras
        for synced in released:
            members = {cams[c]: s for c, s in enumerate(synced.stamps) if s is not None}
            newest = max(members.values())
            last_member = max(item[0] for item in synced.items if item is not None)
            mine = [e for e in extras if (e[1] <= newest if e[1] is not None else e[0] < last_member)]
            taken = {e[0] for e in mine}
            extras = [e for e in extras if e[0] not in taken]
            parts = sorted([*mine, *(item for item in synced.items if item is not None)], key=lambda e: e[0])
            if held is not None:
                yield held
            held = SyncSet(synced.stamp_ns, [e[2] for e in parts], index=count, members=members,
                           skew_ns=synced.skew_ns)
            count += 1

    for topic, msgtype, log_ns, cdr in messages:
        entry = (topic, msgtype, cdr)
        c = camera_of.get(topic)
        if c is not None and not stamped(msgtype):
            raise ValueError(f'{topic}: {msgtype} has no header stamp to synchronise on')
        stamp = header_stamp_ns(cdr) if stamped(msgtype) else None
        if c is not None:
            try:
                yield from take(sync.add(stamp, c, (order, stamp, entry), log_ns / NS))
            except ValueError:  # late or duplicate: the graph drops it too; it is played all the same
                extras.append((order, stamp, entry))
        else:
            extras.append((order, stamp, entry))
        order += 1
    yield from take(sync.flush())
    if held is not None:
        held.messages += [e[2] for e in extras]
        yield held


def loop_offset_ns(loop: int, first_ns: int, last_ns: int, period_ns: int = FRAME_PERIOD_NS) -> int:
    """Stamp shift of replay `loop` (0-based) of a bag whose frames span first_ns..last_ns."""
    if loop < 0 or last_ns < first_ns:
        raise ValueError(f'loop must be >= 0 and last >= first; got loop {loop}, {first_ns}..{last_ns} ns')
    return loop * (last_ns - first_ns + period_ns)


def looped(frames_of_pass: Callable[[], Iterable[Frame]], loops: int,
           period_ns: int = FRAME_PERIOD_NS) -> Iterator[tuple[int, int, Frame]]:
    """(loop, stamp offset ns, frame) over `loops` passes; each pass calls frames_of_pass anew.

    The offsets come from the first pass's first and last stamps (a later pass of the same bag
    has the same frames)."""
    if loops < 1:
        raise ValueError(f'loops must be >= 1; got {loops}')
    first = last = None
    for loop in range(loops):
        offset = 0 if loop == 0 else loop_offset_ns(loop, first, last, period_ns)
        for frame in frames_of_pass():
            if loop == 0:
                first = frame.stamp_ns if first is None else first
                last = frame.stamp_ns
            yield loop, offset, frame
        if first is None:  # an empty pass: nothing to repeat
            return


def due_s(stamp_ns: int, first_ns: int, rate: float) -> float:
    """Seconds after the first frame's publication that the frame at stamp_ns is due (rate > 0)."""
    if not rate > 0:
        raise ValueError(f'rate must be > 0 for paced replay; got {rate}')
    return (stamp_ns - first_ns) / NS / rate


class InFlight:
    """Frames published but not yet seen downstream (rate 0: as fast as downstream keeps up).

    Downstream reports stamps in increasing order, and a stamp it reports means every frame up
    to it is done (a frame it skipped must not hold the player back forever).
    """

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError(f'max_in_flight must be >= 1; got {limit}')
        self.limit = limit
        self._stamps: list[int] = []  # increasing
        self._last: int | None = None  # last stamp published, acked or not

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def full(self) -> bool:
        """Publishing another frame would exceed the limit."""
        return len(self._stamps) >= self.limit

    def published(self, stamp_ns: int) -> None:
        if self._last is not None and stamp_ns <= self._last:
            raise ValueError(f'published stamps must increase; got {stamp_ns} after {self._last} ns')
        self._stamps.append(stamp_ns)
        self._last = stamp_ns

    def give_up(self) -> int:
        """Stop waiting for the oldest frame in flight (downstream dropped it); returns its stamp."""
        if not self._stamps:
            raise ValueError('no frame in flight')
        return self._stamps.pop(0)

    def acked(self, stamp_ns: int) -> int:
        """Downstream finished the frame at stamp_ns (and all before it); returns frames released."""
        done = bisect_right(self._stamps, stamp_ns)
        del self._stamps[:done]
        return done
