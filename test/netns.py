"""Two "hosts" on one machine: a pair of Linux network namespaces joined by a veth pair.

Each namespace has its loopback and one end of the link, 10.x.y.1/24 and 10.x.y.2/24, and no
other interface and no route out: whatever a process started in it (`Host.command`) sends to
another namespace crosses the veth, where the kernel counts it (`Host.counter`), and nothing
leaves the machine. Needs root and iproute2 (`ip netns`).

    with veth_pair(f'mvpose{os.getpid()}') as (a, b):
        subprocess.run(a.command(['python', '-c', '...']))
        b.counter('rx_bytes')
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator, Sequence

PREFIX_LEN = 24
_IFNAME_MAX = 15  # Linux IFNAMSIZ - 1


@dataclass(frozen=True)
class Host:
    """One namespace of the pair: its name, its end of the link and that end's IPv4 address."""

    namespace: str
    interface: str
    address: str

    def command(self, argv: Sequence[str]) -> list[str]:
        """`argv` run inside this namespace (`ip netns exec` execs it: the pid stays the same)."""
        return ['ip', 'netns', 'exec', self.namespace, *argv]

    def counter(self, name: str) -> int:
        """A statistic of this host's end of the link, e.g. 'rx_bytes', 'tx_packets'."""
        path = f'/sys/class/net/{self.interface}/statistics/{name}'
        return int(_ip('netns', 'exec', self.namespace, 'cat', path).strip())


def _ip(*args: str) -> str:
    """Run `ip args`; RuntimeError with ip's own message when it fails."""
    done = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        raise RuntimeError(f'ip {" ".join(args)}: {(done.stderr or done.stdout).strip()}')
    return done.stdout


def unavailable() -> str | None:
    """Why network namespaces cannot be made here (not root, no iproute2, no permission), or
    None when they can. Tries a throwaway namespace, so a sandbox that forbids them says so."""
    if os.geteuid() != 0:
        return 'network namespaces need root'
    if shutil.which('ip') is None:
        return 'iproute2 (`ip`) is not installed'
    probe = f'mvpose-probe{os.getpid()}-{os.urandom(3).hex()}'
    try:
        _ip('netns', 'add', probe)
    except (RuntimeError, OSError, subprocess.TimeoutExpired) as exc:
        return f'`ip netns` is unavailable: {exc}'
    _delete(probe)
    return None


def _delete(namespace: str) -> None:
    """Kill what still runs in `namespace` (only processes started there by this module's user)
    and delete it, with its end of the link (which takes the peer end with it)."""
    try:
        pids = _ip('netns', 'pids', namespace).split()
    except (RuntimeError, subprocess.TimeoutExpired):
        pids = []
    for pid in pids:
        try:
            os.kill(int(pid), signal.SIGKILL)
        except (ProcessLookupError, ValueError):
            pass
    try:
        _ip('netns', 'del', namespace)
    except (RuntimeError, subprocess.TimeoutExpired):
        pass  # already gone


def _subnet(tag: str) -> str:
    """'10.x.y' from the tag, so that two runs at once use different (private, never routed)
    subnets; each namespace pair is isolated anyway."""
    h = sum(ord(ch) * 131 ** i for i, ch in enumerate(tag)) % 65536
    return f'10.{h >> 8}.{h & 255}'


@contextmanager
def veth_pair(tag: str) -> Iterator[tuple[Host, Host]]:
    """Namespaces `<tag>a` and `<tag>b` linked by a veth pair, loopback and link up; both are
    deleted on exit, also when the body raises or making them fails half-way.

    tag: unique among running tests (put the pid in it); the interfaces are named like the
    namespaces, from the tag's last 14 characters.
    """
    subnet = _subnet(tag)
    short = tag[-(_IFNAME_MAX - 1):]
    hosts = (Host(f'{tag}a', f'{short}a', f'{subnet}.1'), Host(f'{tag}b', f'{short}b', f'{subnet}.2'))
    a, b = hosts
    made: list[str] = []  # delete only what this call made, never a namespace it did not
    try:
        for host in hosts:
            _ip('netns', 'add', host.namespace)
            made.append(host.namespace)
        # Both ends are made directly in their namespaces: nothing appears in the host's own.
        _ip('link', 'add', a.interface, 'netns', a.namespace, 'type', 'veth',
            'peer', 'name', b.interface, 'netns', b.namespace)
        for host in hosts:
            ns = ('-n', host.namespace)
            _ip(*ns, 'addr', 'add', f'{host.address}/{PREFIX_LEN}', 'dev', host.interface)
            _ip(*ns, 'link', 'set', 'lo', 'up')
            _ip(*ns, 'link', 'set', host.interface, 'up')
        yield a, b
    finally:
        for namespace in made:
            _delete(namespace)
