"""A bounded hand-over between a producer and a slower consumer (the cameras and the detector):
the `capacity` newest items wait, an older one is dropped whole when a newer one arrives and the
queue is full, and every drop is counted. Latency stays bounded and no queue grows, whatever
the input rate; capacity 1 is "only the newest waits" (live cameras), a larger capacity keeps
every item of a replay that bursts (lockstep) while still bounding memory."""
from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

T = TypeVar('T')


class NewestQueue(Generic[T]):
    """Thread-safe: put() from the producer, take() from the consumer's thread."""

    def __init__(self, capacity: int = 1) -> None:
        if capacity < 1:
            raise ValueError(f'capacity must be >= 1, got {capacity}')
        self.capacity = capacity
        self.put_count = 0
        self.dropped = 0
        self._items: deque[T] = deque()
        self._closed = False
        self._condition = threading.Condition()

    def put(self, item: T) -> list[T]:
        """Add item; returns the older items dropped to make room (oldest first)."""
        with self._condition:
            self.put_count += 1
            self._items.append(item)
            dropped = [self._items.popleft() for _ in range(len(self._items) - self.capacity)]
            self.dropped += len(dropped)
            self._condition.notify()
        return dropped

    def __len__(self) -> int:
        """Items waiting."""
        with self._condition:
            return len(self._items)

    def take(self) -> T | None:
        """The oldest waiting item, blocking until there is one; None once closed."""
        with self._condition:
            while not self._items and not self._closed:
                self._condition.wait()
            return None if self._closed else self._items.popleft()

    def close(self) -> None:
        """Wake and end every take() (what still waits is abandoned)."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()
