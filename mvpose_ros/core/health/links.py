"""A node's matched endpoints as a status, and the check a runner waits on before playing.

A DDS writer sends a volatile message only to the readers it has matched when it writes it, and
a reader keeps only what comes from writers it has matched. Whether a node's writer has matched
another node's reader is known only inside those two processes, so each node reports its counts
on /diagnostics (`<node>: links`): per topic it publishes, the readers its writer has matched;
per topic it reads, the writers its reader has matched. A runner that sees every endpoint of the
graph compares the counts with the endpoints it sees, and plays once every link between the
graph's nodes is matched at both ends: the first frame then reaches every node.
"""
from __future__ import annotations

from typing import Iterable, Mapping

from mvpose_ros.core.health.status import Level, Status

LINKS = 'links'  # the status's name after '<node>: '
READERS = 'matched readers of '  # + the fully qualified topic: readers this node's writer has matched
WRITERS = 'matched writers of '  # + the topic: writers this node's reader has matched


def links_status(node: str, readers: Mapping[str, int], writers: Mapping[str, int]) -> Status:
    """node's links: readers maps each topic it publishes to the readers matched, writers each
    topic it reads to the writers matched. Always OK: an output nobody reads is no fault."""
    values = {**{READERS + t: str(n) for t, n in sorted(readers.items())},
              **{WRITERS + t: str(n) for t, n in sorted(writers.items())}}
    return Status(f'{node}: {LINKS}', Level.OK,
                  f'{len(readers)} topics written, {len(writers)} read', values)


def unmatched_links(statuses: Iterable[Status], seen: Mapping[str, tuple[int, int]]) -> list[str]:
    """The links of `seen` (topic -> the writers and readers a runner sees on it in the graph)
    that the nodes' latest links statuses do not show matched, e.g. '/cam1/people2d: a writer
    has matched 0 of 1 readers'. A topic with no node reporting one of its ends is unmatched too
    (its node has not published its diagnostics yet)."""
    reports: dict[tuple[str, str], list[int]] = {}
    for status in statuses:
        if status.name.endswith(f': {LINKS}'):
            for key, value in status.values.items():
                for prefix, end in ((READERS, 'writer'), (WRITERS, 'reader')):
                    if key.startswith(prefix) and value.isdigit():
                        reports.setdefault((key[len(prefix):], end), []).append(int(value))
    out = []
    for topic, (writers, readers) in seen.items():
        for end, other, wanted in (('writer', 'readers', readers), ('reader', 'writers', writers)):
            counts = reports.get((topic, end), [])
            if not counts:
                out.append(f'{topic}: no {end} has reported its links yet')
            elif min(counts) < wanted:
                out.append(f'{topic}: a {end} has matched {min(counts)} of {wanted} {other}')
    return out
