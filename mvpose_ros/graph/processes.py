"""A supervised group of named child processes that can always be stopped completely.

Each child runs in its own session, so it has its own process group: a terminal's Ctrl-C reaches
only the supervisor, which then stops every child in order (SIGINT, grace period, SIGTERM,
SIGKILL) by signalling the whole group, grandchildren included. Output of each child goes to
`<log_dir>/<name>.log`; a child that has exited can be started again under its name with the same
command (`restart`), its log going on in the same file.
"""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections import deque
from pathlib import Path
from types import FrameType
from typing import Mapping, Sequence

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_POLL_S = 0.02


class Interrupted(BaseException):
    """The supervisor itself received SIGINT or SIGTERM (a BaseException, like KeyboardInterrupt,
    so that `except Exception` blocks do not swallow it)."""

    def __init__(self, signum: int) -> None:
        super().__init__(f'interrupted by {signal.Signals(signum).name}')
        self.signum = signum


def _group_alive(pgid: int) -> bool:
    """Whether a process of group `pgid` is alive. A killed grandchild stays a zombie until init
    reaps it, which some container inits do late: with /proc, zombies do not count."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # a member changed its uid: it exists
        pass
    proc = Path('/proc')
    if not proc.is_dir():
        return True
    for stat in proc.glob('[0-9]*/stat'):
        try:
            # 'pid (comm) state ppid pgrp ...'; comm may hold spaces and parentheses.
            state, _, pgrp = stat.read_text().rpartition(')')[2].split()[:3]
        except (OSError, ValueError):
            continue  # exited while scanning
        if int(pgrp) == pgid and state not in ('Z', 'X'):
            return True
    return False


class ProcessGroup:
    """Named child processes, each in its own process group.

    Use as a context manager: on entry (in the main thread) SIGINT and SIGTERM raise `Interrupted`
    instead of killing the supervisor; on exit every child is stopped and the handlers restored.
    """

    def __init__(self, log_dir: str | Path, env: Mapping[str, str] | None = None, grace: float = 5.0,
                 term_grace: float = 2.0) -> None:
        if grace < 0 or term_grace < 0:
            raise ValueError(f'grace periods must be >= 0 s; got {grace}, {term_grace}')
        self.log_dir = Path(log_dir)
        self.env = dict(os.environ if env is None else env)
        self.grace = grace
        self.term_grace = term_grace
        self.procs: dict[str, subprocess.Popen] = {}
        self.commands: dict[str, list[str]] = {}
        self._gone: set[int] = set()  # empty groups: their ids may be reused, never signal them again
        self._saved_handlers: dict[int, object] = {}

    def log_path(self, name: str) -> Path:
        """Log file of `name` ('cam0/heatmap_detector' -> cam0_heatmap_detector.log)."""
        return self.log_dir / (name.strip('/').replace('/', '_') + '.log')

    def start(self, name: str, command: Sequence[str]) -> subprocess.Popen:
        """Start `command` as `name` with stdout and stderr in its log file."""
        if name in self.procs:
            raise ValueError(f'process name {name!r} already used')
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.commands[name] = list(command)
        return self._spawn(name, 'wb')

    def restart(self, name: str, note: str = '') -> subprocess.Popen:
        """Start `name`'s command again once its process has exited; whatever its group still holds
        (a grandchild) is killed first, and the log goes on after a line with `note`."""
        old = self.procs[name]
        if old.poll() is None:
            raise ValueError(f'process {name!r} is still running')
        if old.pid not in self._gone:
            if _group_alive(old.pid):
                try:
                    os.killpg(old.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            self._gone.add(old.pid)
        with open(self.log_path(name), 'ab') as log:
            log.write(f'--- restarted by the supervisor{": " + note if note else ""} ---\n'.encode())
        return self._spawn(name, 'ab')

    def _spawn(self, name: str, mode: str) -> subprocess.Popen:
        with open(self.log_path(name), mode) as log:
            proc = subprocess.Popen(self.commands[name], stdin=subprocess.DEVNULL, stdout=log,
                                    stderr=subprocess.STDOUT, env=self.env, start_new_session=True)
        self.procs[name] = proc
        return proc

    def poll(self) -> dict[str, int]:
        """Every process that has exited so far -> its return code (negative: killed by that signal)."""
        return {name: code for name, proc in self.procs.items() if (code := proc.poll()) is not None}

    def log_tail(self, name: str, lines: int = 10) -> str:
        """The last `lines` lines of `name`'s log."""
        try:
            with open(self.log_path(name), encoding='utf-8', errors='replace') as f:
                return ''.join(deque(f, maxlen=lines)).rstrip('\n')
        except FileNotFoundError:
            return ''

    def _alive_groups(self) -> list[int]:
        """Process group ids (= leader pids) in which some process still lives."""
        alive = []
        for proc in self.procs.values():
            if proc.pid in self._gone:
                continue
            proc.poll()  # reap the leader so that a zombie does not count as alive
            if _group_alive(proc.pid):
                alive.append(proc.pid)
            else:
                self._gone.add(proc.pid)
        return alive

    def _signal_and_wait(self, sig: int, timeout: float) -> list[int]:
        for pgid in self._alive_groups():
            try:
                os.killpg(pgid, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + timeout
        while (alive := self._alive_groups()) and time.monotonic() < deadline:
            time.sleep(_POLL_S)
        return alive

    def stop(self) -> dict[str, int]:
        """Stop every process group (SIGINT, then SIGTERM after `grace` s, then SIGKILL after
        `term_grace` s) and return every process's exit code."""
        if self._signal_and_wait(signal.SIGINT, self.grace) and self._signal_and_wait(signal.SIGTERM, self.term_grace):
            self._signal_and_wait(signal.SIGKILL, 5.0)
        for proc in self.procs.values():
            proc.wait()
        return self.poll()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        raise Interrupted(signum)

    def __enter__(self) -> ProcessGroup:
        if threading.current_thread() is threading.main_thread():
            self._saved_handlers = {s: signal.signal(s, self._on_signal) for s in _STOP_SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        # A second Ctrl-C must not abandon the children half-stopped; stop() is bounded anyway.
        for s in self._saved_handlers:
            signal.signal(s, signal.SIG_IGN)
        try:
            self.stop()
        finally:
            for s, handler in self._saved_handlers.items():
                signal.signal(s, handler)
            self._saved_handlers = {}
