"""Worker threads for independent per-person work.

The compiled kernels run without the GIL (core.compiled), so people's BP chains and temporal
tables, which share no state, can be solved side by side on a multi-core machine. Each person's
arithmetic is the same whichever thread does it, so results never depend on the thread count.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor, wait
from typing import Callable, Sequence, TypeVar

Item = TypeVar('Item')
Result = TypeVar('Result')


class Workers:
    """`threads` threads in all, the caller's included (1: everything in the caller's thread).
    The pool is started at the first call that can use it."""

    def __init__(self, threads: int) -> None:
        if threads < 1:
            raise ValueError(f'threads must be >= 1, got {threads}')
        self.threads = threads
        self._pool: ThreadPoolExecutor | None = None

    def split(self, items: Sequence[Item], cost: Callable[[Item], float] | None = None) -> list[list[Item]]:
        """items in at most `threads` non-empty parts of about equal total cost (default 1 each):
        the costliest first, each to the part with the least so far."""
        n = min(self.threads, len(items))
        parts: list[list[Item]] = [[] for _ in range(n)]
        loads = [0.0] * n
        weigh = cost or (lambda _: 1.0)
        for item in sorted(items, key=weigh, reverse=True):
            k = loads.index(min(loads))
            parts[k].append(item)
            loads[k] += weigh(item)
        return parts

    def map(self, fn: Callable[[Item], Result], parts: Sequence[Item]) -> list[Result]:
        """[fn(p) for p in parts], the first part in the caller's thread and the others in the
        pool at the same time. An exception is raised once no part is running any more."""
        if len(parts) < 2 or self.threads < 2:
            return [fn(p) for p in parts]
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix='mvpose-worker')
        futures = [self._pool.submit(fn, p) for p in parts[1:]]
        try:
            first = fn(parts[0])
        finally:
            wait(futures)
        return [first, *(f.result() for f in futures)]
