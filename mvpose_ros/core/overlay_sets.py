"""Which camera images and 2D people go with a skeleton set, for overlays drawn while the graph runs.

A set's stamp is the earliest of its members' stamps (core.association.approximate_sync), so the
member of camera c has a stamp in [set stamp, set stamp + max_skew]; its 2D people carry that image's
own stamp (heatmap_detector). Each camera's recent images and 2D people are kept by stamp, bounded
by age behind the camera's newest stamp and, for images, by bytes (a raw 1920 x 1080 image is
6 MB): an image that has fallen out when its set's skeletons arrive is not drawn, and counted.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

T = TypeVar('T')

# A set without skeletons (dropped) is drawn only once a camera has had no image for this long: in
# an overloaded graph most sets are dropped, and their images would take the place of the few
# with skeletons.
DROPPED_PERIOD_S = 1.0


class RecentByStamp(Generic[T]):
    """Items keyed by stamp (integer ns), kept while within `keep_ns` of the newest stamp and, with
    max_bytes, while their sizes add up to at most max_bytes (the oldest go first; the newest item
    stays even when it alone is larger)."""

    def __init__(self, keep_ns: int, max_bytes: int | None = None) -> None:
        if keep_ns < 0 or (max_bytes is not None and max_bytes < 0):
            raise ValueError(f'keep_ns and max_bytes must be >= 0, got {keep_ns}, {max_bytes}')
        self.keep_ns = keep_ns
        self.max_bytes = max_bytes
        self._items: OrderedDict[int, tuple[T, int]] = OrderedDict()  # stamp -> (item, bytes), by stamp
        self._bytes = 0

    def __len__(self) -> int:
        return len(self._items)

    @property
    def bytes(self) -> int:
        """The sizes of the items held, added up."""
        return self._bytes

    def add(self, stamp_ns: int, item: T, size: int = 0) -> None:
        """Keep item under stamp_ns (replacing one of the same stamp), then trim."""
        if stamp_ns in self._items:
            self._bytes -= self._items.pop(stamp_ns)[1]
        late = bool(self._items) and next(reversed(self._items)) > stamp_ns
        self._items[stamp_ns] = (item, size)
        self._bytes += size
        if late:  # out of order: keep them sorted
            self._items = OrderedDict(sorted(self._items.items()))
        self._trim()

    def get(self, stamp_ns: int) -> T | None:
        """The item of exactly stamp_ns, or None."""
        found = self._items.get(stamp_ns)
        return None if found is None else found[0]

    def first_in(self, low_ns: int, high_ns: int) -> tuple[int, T] | None:
        """(stamp, item) of the earliest stamp in [low_ns, high_ns], or None."""
        for stamp, (item, _) in self._items.items():
            if stamp > high_ns:
                return None
            if stamp >= low_ns:
                return stamp, item
        return None

    def _trim(self) -> None:
        newest = next(reversed(self._items))
        while len(self._items) > 1:
            oldest = next(iter(self._items))
            if newest - oldest <= self.keep_ns and (self.max_bytes is None or self._bytes <= self.max_bytes):
                break
            self._bytes -= self._items.pop(oldest)[1]


@dataclass(frozen=True)
class Member:
    """A camera's part of a skeleton set: its image's stamp, the image, and the 2D people detected
    in it as they are held (the overlay node holds the image's type and serialised bytes, and the
    people2d message; people None when it is no longer, or not yet, held)."""

    camera: int
    stamp_ns: int
    image: Any
    people: Any | None


def set_members(set_stamp_ns: int, max_skew_ns: int, images: list[RecentByStamp],
                people: list[RecentByStamp]) -> list[Member]:
    """Each camera's member of the set stamped set_stamp_ns (images[c], people[c]: camera c's recent
    images and 2D people): the camera's earliest 2D people in [stamp, stamp + max_skew] and the image
    of the same stamp; with no 2D people there, its earliest image in that window. Cameras with no
    image in the window are left out."""
    high = set_stamp_ns + max_skew_ns
    members = []
    for camera, (camera_images, camera_people) in enumerate(zip(images, people)):
        found = camera_people.first_in(set_stamp_ns, high)
        image_of_people = None if found is None else camera_images.get(found[0])
        if image_of_people is not None:
            members.append(Member(camera, found[0], image_of_people, found[1]))
            continue
        image = camera_images.first_in(set_stamp_ns, high)
        if image is not None:
            members.append(Member(camera, image[0], image[1], camera_people.get(image[0])))
    return members


def due(now: float, last_drawn: float, period: float, dropped: bool) -> bool:
    """Whether a camera whose last image was drawn at last_drawn (s) draws a set now: one with
    skeletons once `period` s have passed (0: every set), a dropped one once
    max(period, DROPPED_PERIOD_S) have (every set too when period is 0)."""
    wait = max(period, DROPPED_PERIOD_S) if dropped and period > 0 else period
    return now - last_drawn >= wait
