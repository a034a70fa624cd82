"""The node graph split over two hosts, emulated by two network namespaces joined by a veth pair
(test/netns.py): the bag player and the five heatmap detectors on the "camera host", association,
bp_solver and a recorder on the "compute host". DDS runs over UDP on the veth only (the profile
config/fastdds_udp.xml with a white list of each host's veth address, no shared memory), so every
/cam*/people2d message has to cross the link. The same bags through the same nodes all on the
camera host (the usual set-up: shared memory, discovery on localhost) are the reference: the
multi-host run must give every input frame exactly once, with the same people and the same joints.

Needs root and `ip netns` (skipped otherwise). The input is the first 40 Shelf frames at the
recorded rate, from the first: when the recorder sees every endpoint of the graph, a writer may
still match a remote reader seconds later (Fast DDS's periodic announcements), and what it
publishes before that is lost (the data topics are volatile), so the recorder also waits until
the nodes report on /diagnostics every link between them matched at both ends (a detector's
people2d writer and association's reader on the other host), and the player until its own
writers have matched. The recorder is mvpose_ros.graph.recorder, the runner's own, as a process
of its own.
"""
from __future__ import annotations

import itertools
import json
import os
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np
import pytest

import netns
import ros_harness
from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.bags.io import read_bag, write_bag
from mvpose_ros.bags.recipes import shelf_recipe
from mvpose_ros.core.datasets.shelf_campus import dataset_dir
from mvpose_ros.graph.config import graph_nodes, node_command
from mvpose_ros.graph.processes import ProcessGroup

REPO = Path(__file__).resolve().parents[1]
PARAMS = REPO / 'config' / 'shelf.yaml'
SHM_PROFILE = REPO / 'config' / 'fastdds.xml'
UDP_PROFILE = REPO / 'config' / 'fastdds_udp.xml'
RECORDER = [sys.executable, '-m', 'mvpose_ros.graph.recorder']
PROFILE_VARS = ros_harness.PROFILE_VARS
DDS_NS = 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'

CAMERAS = 5
FRAMES = range(300, 340)
CAMERA_NODES = ('heatmap_detector', 'bag_player')  # the rest (association, bp_solver) is compute
# Settings that keep the output independent of timing: association never gives up on a camera
# that is merely late, bp_solver does not flush its window while the graph is still busy.
OVERRIDES = {'association': {'sync_timeout': 30.0}, 'bp_solver': {'idle_flush': 3.0},
             'bag_player': {'rate': 1.0, 'wait_subscribers': 30.0}}
CONNECT_TIMEOUT_S = 90.0
RUN_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class Site:
    """Where processes run: a host of the veth pair and the DDS environment there."""

    host: netns.Host
    env: Mapping[str, str]

    def command(self, argv: Sequence[str]) -> list[str]:
        return self.host.command(['env', *(f'{k}={v}' for k, v in self.env.items()), *argv])


@dataclass
class GraphRun:
    """What the recorder saw: predictions lines in arrival order, its stats, how long the bag took
    to come through, and the bytes the compute host's end of the link received meanwhile."""

    lines: list[dict]
    stats: dict
    seconds: float
    rx_bytes: int
    logs: str = field(repr=False, default='')

    def by_frame(self) -> dict[int, list[dict]]:
        out: dict[int, list[dict]] = {}
        for line in self.lines:
            out.setdefault(line['frame'], []).append(line)
        return out

    def sizes(self, topic: str) -> dict[int, int]:
        """Frame -> serialized bytes of `topic` (a topic the nodes publish; --measure runs)."""
        return _by_frame(self.stats['topics'].get(topic, []))


def _by_frame(sizes: Iterable[tuple[int, int]]) -> dict[int, int]:
    """(stamp ns, bytes) -> {frame: bytes} for the frames of FRAMES."""
    wanted = {stamp_ns(stamp_of_frame(f)): f for f in FRAMES}
    return {wanted[s]: n for s, n in sizes if s in wanted}


def base_env() -> dict[str, str]:
    """The inherited environment without any DDS choice of its own, one BLAS thread per node."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY', 'ROS_DOMAIN_ID',
                        'RMW_IMPLEMENTATION', ros_harness.QOS_FROM_XML, *PROFILE_VARS)}
    return env | {'PYTHONPATH': str(REPO), 'PYTHONUNBUFFERED': '1', 'OMP_NUM_THREADS': '1',
                  'OPENBLAS_NUM_THREADS': '1', 'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'}


def dds_env(domain: int, profile: Path, discovery: str, peers: Sequence[str] = ()) -> dict[str, str]:
    env = {'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': discovery,
           **{var: str(profile) for var in PROFILE_VARS}, ros_harness.QOS_FROM_XML: '1'}
    return env | ({'ROS_STATIC_PEERS': ';'.join(peers)} if peers else {})


def udp_profile(path: Path, addresses: Sequence[str]) -> Path:
    """config/fastdds_udp.xml with its UDP transport limited to `addresses` (interfaceWhiteList)."""
    ET.register_namespace('', DDS_NS)
    tree = ET.parse(UDP_PROFILE)
    [transport] = tree.getroot().iter(f'{{{DDS_NS}}}transport_descriptor')
    white = ET.SubElement(transport, f'{{{DDS_NS}}}interfaceWhiteList')
    for address in addresses:
        ET.SubElement(white, f'{{{DDS_NS}}}address').text = address
    tree.write(path, encoding='utf-8', xml_declaration=True)
    return path


def _logs(group: ProcessGroup, reason: str) -> str:
    tails = '\n'.join(f'--- {name} (exit {group.poll().get(name)}):\n{group.log_tail(name, 8)}' for name in group.procs)
    return f'{reason}\n{tails}'


def _wait(group: ProcessGroup, done: Callable[[], bool], timeout: float, what: str,
          finished_ok: Sequence[str] = ()) -> None:
    """Poll until done(); AssertionError with every log tail on a crash or after timeout s."""
    deadline = time.monotonic() + timeout
    while not done():
        crashed = {n: c for n, c in group.poll().items() if not (n in finished_ok and c == 0)}
        assert not crashed, _logs(group, f'{what}: {crashed} exited')
        assert time.monotonic() < deadline, _logs(group, f'{what}: not within {timeout:g} s')
        time.sleep(0.05)


def run_graph(bag: Path, camera: Site, compute: Site, out: Path, measure: bool = False) -> GraphRun:
    """Play `bag` through the graph with the detectors and the player at `camera` and association,
    bp_solver and the recorder at `compute`; every process is stopped on return."""
    out.mkdir(parents=True)
    ready, predictions, stats = out / 'ready', out / 'predictions.jsonl', out / 'stats.json'
    specs = [replace(s, parameters={**s.parameters, **OVERRIDES.get(s.executable, {})})
             for s in graph_nodes(CAMERAS, str(bag), 1.0)]
    player = specs.pop()
    recorder = [*RECORDER, '--bag', str(bag), '--predictions',
                str(predictions), '--ready', str(ready), '--stats', str(stats), '--cameras', str(CAMERAS),
                '--timeout', str(RUN_TIMEOUT_S), *(['--measure'] if measure else [])]
    with ProcessGroup(out / 'logs', base_env()) as group:
        group.start('recorder', compute.command(recorder))
        for spec in specs:
            site = camera if spec.executable in CAMERA_NODES else compute
            group.start(spec.name, site.command(node_command(spec, PARAMS)))
        _wait(group, ready.exists, CONNECT_TIMEOUT_S, 'graph discovery')
        rx0 = compute.host.counter('rx_bytes')
        started = time.monotonic()
        group.start('bag_player', camera.command(node_command(player, PARAMS)))
        _wait(group, lambda: 'recorder' in group.poll(), RUN_TIMEOUT_S, 'playback',
              finished_ok=('bag_player',))
        seconds = time.monotonic() - started
        rx = compute.host.counter('rx_bytes') - rx0
        logs = _logs(group, 'logs')
        code = group.poll()['recorder']
        group.stop()
    assert code == 0, _logs(group, f'recorder exited with {code}')
    lines = [json.loads(line) for line in predictions.read_text().splitlines() if line.strip()]
    return GraphRun(lines, json.loads(stats.read_text()), seconds, rx, logs)


def _shelf_bag(path: Path) -> Path:
    """The first len(FRAMES) frames of the Shelf bag (camera infos and OpenPose output)."""
    end = stamp_ns(stamp_of_frame(FRAMES.stop))
    write_bag(path, itertools.takewhile(lambda item: item[2] < end, shelf_recipe(dataset_dir('shelf')).items()))
    return path


@pytest.fixture(scope='module')
def domains() -> Iterator[tuple[int, int]]:
    """The ROS domains of the one-host reference and of the multi-host runs: this module's own."""
    one, multi = ros_harness.acquire_domain(), ros_harness.acquire_domain()
    yield one, multi
    ros_harness.release_domain(one)
    ros_harness.release_domain(multi)


@pytest.fixture(scope='module')
def link() -> Iterator[tuple[netns.Host, netns.Host]]:
    """The camera host and the compute host, deleted after the module even when a test fails."""
    reason = netns.unavailable()
    if reason:
        pytest.skip(reason)
    with netns.veth_pair(f'mvpose{os.getpid()}') as hosts:
        yield hosts


@pytest.fixture(scope='module')
def bag(link, tmp_path_factory) -> Path:
    return _shelf_bag(tmp_path_factory.mktemp('bags') / 'shelf40')


@pytest.fixture(scope='module')
def one_host(link, bag, domains, tmp_path_factory) -> GraphRun:
    """The reference: every node on one host (the camera host: a namespace of its own, so that no
    other run on this machine can join) as mvpose-graph runs them, shared memory and discovery on
    localhost; it also records the size of every message the nodes publish."""
    here = Site(link[0], dds_env(domains[0], SHM_PROFILE, 'LOCALHOST'))
    return run_graph(bag, here, here, tmp_path_factory.mktemp('one_host') / 'run', measure=True)


def _people(line: dict) -> tuple[list[int], np.ndarray]:
    people = line['people']
    return [p['id'] for p in people], np.array([p['joints'] for p in people], dtype=float).reshape(-1, 14, 3)


def multihost_site(host: netns.Host, other: netns.Host, discovery: str, folder: Path, domain: int) -> Site:
    """`host`'s DDS settings. 'subnet': multicast discovery (the ROS default range), UDP on the
    link's address only. 'static_peers': no multicast at all, discovery by unicast to the other
    host's address; the white list then needs loopback too: with the link's address alone, two
    nodes of one host never found each other in this mode."""
    if discovery == 'subnet':
        return Site(host, dds_env(domain, udp_profile(folder / f'{host.namespace}.xml', [host.address]),
                                  'SUBNET'))
    profile = udp_profile(folder / f'{host.namespace}.xml', [host.address, '127.0.0.1'])
    return Site(host, dds_env(domain, profile, 'LOCALHOST', peers=[other.address]))


@pytest.mark.parametrize('discovery', ['subnet', 'static_peers'])
def test_graph_across_two_hosts_gives_the_one_host_output(link, bag, domains, one_host, tmp_path, discovery):
    """Same frames, people and joints as on one host, with the 2D people over the link."""
    camera_host, compute_host = link
    sites = [multihost_site(camera_host, compute_host, discovery, tmp_path, domains[1]),
             multihost_site(compute_host, camera_host, discovery, tmp_path, domains[1])]
    run = run_graph(bag, *sites, tmp_path / 'run')

    # every input frame exactly once from the first, nothing else
    ref = one_host.by_frame()
    got = run.by_frame()
    for frames, logs in ((ref, one_host.logs), (got, run.logs)):
        assert set(frames) == set(FRAMES), f'frames {sorted(set(FRAMES) ^ set(frames))} missing or unexpected\n{logs}'
        assert [f for f, v in frames.items() if len(v) > 1] == [], logs
    assert run.stats['bad'] == one_host.stats['bad'] == []
    # the same people and joints (files hold 0.1 mm: equal float32 values round the same): every
    # frame came, in order, so bp_solver seeded each frame's hypotheses with the same number
    worst = 0.0
    for f in FRAMES:
        ids, joints = _people(got[f][0])
        ref_ids, ref_joints = _people(ref[f][0])
        assert ids == ref_ids, f'frame {f}: people {ids}, one host {ref_ids}\n{run.logs}'
        np.testing.assert_allclose(joints, ref_joints, rtol=0, atol=1e-4 + 1e-9, err_msg=f'frame {f}')
        worst = max(worst, float(np.abs(joints - ref_joints).max(initial=0.0)))
    assert sum(len(_people(got[f][0])[0]) for f in FRAMES) >= 2 * len(FRAMES)  # people were seen

    # the 2D people really crossed the link: the compute host received at least their volume
    people2d = [one_host.sizes(f'/cam{c}/people2d') for c in range(CAMERAS)]
    assert all(sorted(sizes) == list(FRAMES) for sizes in people2d)
    volume = sum(sum(sizes.values()) for sizes in people2d)
    assert volume > 100_000
    assert run.rx_bytes >= volume, f'{run.rx_bytes} bytes over the veth < {volume} of /cam*/people2d'
    assert one_host.rx_bytes < volume  # while the reference kept to its host

    print(f'\n{discovery}: {len(FRAMES)} frames at 25 Hz, bag start to last output: one host {one_host.seconds:.1f} s, '
          f'two hosts {run.seconds:.1f} s; the compute host received {run.rx_bytes / 1e6:.2f} MB over the veth '
          f'for {volume / 1e6:.2f} MB of /cam*/people2d (one host: {one_host.rx_bytes} bytes); largest joint '
          f'difference {worst:.1e} m')
    played = [(topic, stamp, len(cdr)) for topic, _, stamp, cdr in read_bag(bag)]
    for topic in ('/cam*/camera_info', '/cam*/openpose', '/cam*/people2d', '/people/bundles', '/skeletons',
                  '/skeletons/markers'):
        sizes = []
        for name in {topic.replace('*', str(c)) for c in range(CAMERAS)}:
            sizes += [*one_host.sizes(name).values(), *_by_frame((t, n) for p, t, n in played if p == name).values()]
        print(f'{topic:20s} {np.mean(sizes) / 1e3:6.1f} kB a message (max {max(sizes) / 1e3:5.1f}), '
              f'{sum(sizes) / len(FRAMES) * 25 / 1e6:5.2f} MB/s at 25 Hz for all cameras')
