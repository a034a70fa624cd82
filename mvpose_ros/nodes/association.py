"""The association node: synchronises every rig camera's 2D people into sets, tracks them per
camera, matches them across views and publishes the people seen by at least two cameras, each
with a stable 3D id, as one bundle message per set (people/bundles, PointCloud2 encoding C).

In: `<camera name>/people2d` of each rig camera, each under that camera's frame_id. A set holds at
most one message per camera within `max_skew` (core.association.approximate_sync) and needs
`min_cameras` members; a smaller set's stamp goes out on skeletons/dropped. Every set yields one
bundle, empty when nobody is seen twice, stamped with the set's earliest member stamp. Each view's
record goes into the bundle as it came, not decoded and encoded again.
Behaviour in detail (synchronisation, what is dropped and why, intrinsics):
docs/operations.md#association."""
from __future__ import annotations

import json
import os
import time
from collections import Counter
from functools import partial
from typing import Any
from pathlib import Path

import numpy as np
import rclpy.logging
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.cdr_header import CLOUD_OVERHEAD, Oversize, deserialise_cloud, header_frame_id, header_stamp_ns
from msg_adapters.people_msg import max_people_bytes, msg_to_wire_people, wire_bundles_to_msg
from msg_adapters.stamp import stamp_of_ns
from mvpose_ros import topics
from mvpose_ros.core.association.approximate_sync import ApproximateSync, Drop, SyncedSet
from mvpose_ros.core.association.associator import Associator
from mvpose_ros.core.defaults import FRAME_RATE, SYNC_TIMEOUT_S, max_skew_or_default
from mvpose_ros.core.geometry.frame_id import CameraFrameId
from mvpose_ros.core.heatmap import load_kernels
from mvpose_ros.core.health.monitor import InputMonitor, NodeMonitor, input_statuses, node_status
from mvpose_ros.core.health.status import Status
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.stage import ASSOCIATION_PARAMETERS, LiveStageParameters, StageConfig, parameter_specs
from mvpose_ros.core.throttled_log import ThrottledLog
from mvpose_ros.nodes.health import NodeHealth
from mvpose_ros.nodes.runtime import (DATA_QOS, RigIntrinsics, StartupError, declare, live_parameters,
                                      load_rig_parameter, rig_parameters, run)

EXPIRE_PERIOD_S = 0.05
REPORT_EVERY = 100  # sets between two skew reports
STATE_PERIOD_S = 0.2  # s between two writes of the identity state (a person moves little in it)


class AssociationNode(Node):
    """<camera>/people2d of every rig camera in, people/bundles out (names relative: see topics)."""

    def __init__(self, **options: Any) -> None:
        """options: rclpy Node's (cli_args: this node's own --ros-args, as in a composed process)."""
        super().__init__('association', **options)
        load_kernels()
        p = declare(self, [
            *rig_parameters(),
            Param('sync_timeout', SYNC_TIMEOUT_S, 's to wait for a camera missing from a set before going on without '
                  'it', 0.001, 3600.0, live=True),
            Param('max_skew', 0.0, 's between the oldest and newest stamp of a set (0: half a frame period)',
                  0.0, 3600.0, live=True),
            Param('min_cameras', 2, 'cameras a set needs to be bundled (smaller sets are dropped: nobody in them is '
                                    'seen twice)', 1, 65535),
            *parameter_specs(ASSOCIATION_PARAMETERS),
            Param('frame_rate', FRAME_RATE, 'nominal frames per second of the cameras (max_skew 0 is half its period; '
                  'a camera not heard yet is waited one period)', 0.1, 1000.0),
            Param('state_dir', '', 'folder for the person ids\' state, kept across a restart (empty: none kept)'),
            Param('state_max_age', 30.0, 's: positions in an older state are not used (ids are still not reused)', 0.0,
                  86400.0),
        ])
        rig = load_rig_parameter(p)
        n = len(rig.cameras)
        if not 1 <= p['min_cameras'] <= n:
            raise StartupError(f'parameter min_cameras: must be in 1..{n} (the rig has {n} cameras)')
        try:
            self._config = StageConfig.from_params(p).association
        except ValueError as exc:
            raise StartupError(f'parameters: {exc}') from None
        self._rig = rig
        self._names = rig.names
        self._frame_rate = p['frame_rate']
        self._live = LiveStageParameters(p)
        max_skew = max_skew_or_default(p['max_skew'], p['frame_rate'])
        # a camera whose intrinsics are still unknown (no CameraInfo yet) is left out of the sets
        self._intrinsics = None if rig.calibrated else RigIntrinsics(self, rig)
        self._associator = Associator(rig.calibrated_cameras() if rig.calibrated else self._intrinsics.known,
                                      self._config)
        # a camera that has sent nothing yet (one starting late) holds a set back one frame period at most
        self._sync = ApproximateSync(n, p['sync_timeout'], max_skew, p['min_cameras'], first_wait=1.0 / p['frame_rate'])
        self.dropped: Counter[str] = Counter()  # every dropped input message, by reason
        self._log = ThrottledLog(self.get_logger())
        self._skews: list[int] = []  # ns, of the sets since the last report
        now = time.monotonic()
        self._inputs = [InputMonitor(name, now) for name in self._names]
        self._frame_ids = [CameraFrameId(c.name, c.frame_id) for c in rig.cameras]
        self._arrivals: dict[tuple[int, int], float] = {}  # (camera, stamp) of pending messages -> arrival
        self._monitor = NodeMonitor()
        self._health = NodeHealth(self, self._statuses)
        live_parameters(self, ['sync_timeout', 'max_skew',
                               *[s.name for s in parameter_specs(ASSOCIATION_PARAMETERS) if s.live]],
                        self._live.refusal, self._retune)
        self._state = Path(p['state_dir'], self.get_fully_qualified_name().strip('/').replace('/', '_') + '.json') \
            if p['state_dir'] else None
        self._state_saved = -float('inf')
        if self._state is not None:
            self._restore_ids(p['state_max_age'])
        self._publisher = self.create_publisher(PointCloud2, topics.BUNDLES, DATA_QOS)
        self._lost = self.create_publisher(Header, topics.SKELETONS_DROPPED, DATA_QOS)
        for c, camera in enumerate(rig.cameras):
            self.create_subscription(PointCloud2, topics.camera_topic(camera.name, topics.PEOPLE2D),
                                     partial(self._on_people, c), DATA_QOS, raw=True)
        self.create_timer(EXPIRE_PERIOD_S, self._on_timer)
        self.get_logger().info(f'{n} cameras ({", ".join(self._names)}), max skew {1e3 * max_skew:.1f} ms, '
                               f'sync timeout {p["sync_timeout"]} s, sets of >= {p["min_cameras"]} cameras'
                               + ('' if rig.calibrated else ', intrinsics from CameraInfo'))

    def _retune(self, changes: dict[str, Any]) -> None:
        config = self._live.apply(changes)
        p = self._live.values
        self._sync.retune(p['sync_timeout'], max_skew_or_default(p['max_skew'], self._frame_rate))
        self._associator.retune(config.association)

    def _restore_ids(self, max_age: float) -> None:
        """Take over the ids' state a previous process of this node left in state_dir."""
        try:
            state = json.loads(self._state.read_text(encoding='utf-8'))
            age = time.time() - float(state['saved_at'])
            if age > max_age:
                state = {**state, 'people': []}
            self._associator.identities.restore(state)
        except FileNotFoundError:
            self.get_logger().info(f'no identity state in {self._state}: ids from 0')
            return
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.get_logger().error(f'identity state {self._state} not used ({exc}): ids from 0')
            return
        self.get_logger().info(f'identity state from {self._state}, saved {age:.1f} s ago: next id {state["next_id"]}, '
                               f'{len(state["people"])} people restored'
                               + (f' (positions older than {max_age:g} s not used)' if age > max_age else ''))

    def _save_ids(self) -> None:
        now = time.monotonic()
        if now - self._state_saved < STATE_PERIOD_S:
            return
        self._state_saved = now
        partial_file = self._state.with_name(self._state.name + '.partial')
        try:
            self._state.parent.mkdir(parents=True, exist_ok=True)
            partial_file.write_text(json.dumps({'saved_at': time.time(), **self._associator.identities.state()}),
                                    encoding='utf-8')
            os.replace(partial_file, self._state)
        except OSError as exc:
            self._log.log(('state', 'not written'), f'identity state not written to {self._state}: {exc}')

    def _drop(self, camera: int, stamp: int | None, reason: str, detail: str) -> None:
        self.dropped[reason] += 1
        self._inputs[camera].dropped(time.monotonic(), reason)
        self._arrivals.pop((camera, stamp), None)
        self._log.log((self._names[camera], f'dropped ({reason})'),
                      f'{self._names[camera]} people2d stamp {stamp} ns dropped ({reason}): {detail}')

    def _ready(self, camera: int) -> bool:
        """Whether camera's intrinsics are known (taking them into the associator once they are)."""
        if self._associator.cameras[camera] is None:
            self._associator.cameras[camera] = self._intrinsics.known[camera]
        return self._associator.cameras[camera] is not None

    def _on_people(self, camera: int, cdr: bytes) -> None:
        """A people2d message as bytes: its stamp, frame_id and size are checked on them, so junk
        (a flood, an oversized message) is refused before its message objects are made."""
        arrival = time.monotonic()
        try:
            stamp = header_stamp_ns(cdr)
            frame_id = header_frame_id(cdr)
        except ValueError as exc:
            self._inputs[camera].received(arrival, None)
            self._drop(camera, None, 'malformed', str(exc))
            return
        self._inputs[camera].received(arrival, stamp)
        if not self._ready(camera):
            self._drop(camera, stamp, 'no intrinsics', 'no CameraInfo from this camera yet')
            return
        try:
            self._frame_ids[camera].check(frame_id, 'people2d')
        except ValueError as exc:
            self._drop(camera, stamp, 'frame_id', str(exc))
            return
        seen_by = self._associator.cameras[camera]
        limit = max_people_bytes(seen_by.width, seen_by.height)
        if len(cdr) > limit + CLOUD_OVERHEAD:
            self._drop(camera, stamp, 'oversize', f'{len(cdr)} serialised bytes, more than a people2d of a '
                                                  f'{seen_by.width}x{seen_by.height} camera carries ({limit} + '
                                                  f'{CLOUD_OVERHEAD})')
            return
        try:
            msg = deserialise_cloud(cdr)
            if len(msg.data) > limit:
                raise Oversize(f'{len(msg.data)} data bytes, more than a people2d of a {seen_by.width}x'
                               f'{seen_by.height} camera carries ({limit})')
            people = msg_to_wire_people(msg)
        except ValueError as exc:
            self._drop(camera, stamp, 'oversize' if isinstance(exc, Oversize) else 'malformed', str(exc))
            return
        before = Counter(self._sync.dropped)
        try:
            released = self._sync.add(stamp, camera, people, arrival)
        except ValueError as exc:
            reason = next((r for r, k in self._sync.dropped.items() if k != before[r]), 'late')
            self._drop(camera, stamp, reason, str(exc))
            return
        self._arrivals[camera, stamp] = arrival
        self._release(released)

    def _on_timer(self) -> None:
        self._release(self._sync.expire(time.monotonic()))

    def _release(self, sets: list[SyncedSet]) -> None:
        for drop in self._sync.take_drops():
            self._sync_drop(drop)
        for stamp in self._sync.take_lost():
            self._lost.publish(Header(stamp=stamp_of_ns(stamp), frame_id=self._rig.world_frame))
        for synced in sets:
            self._publish(synced)

    def _sync_drop(self, drop: Drop) -> None:
        detail = ('no other camera within max_skew (a set needs min_cameras)' if drop.reason == 'unmatched'
                  else 'too many messages pending from this camera')
        self._drop(drop.camera, drop.stamp_ns, drop.reason, detail)

    def _publish(self, synced: SyncedSet) -> None:
        stamp = stamp_of_ns(synced.stamp_ns)
        if synced.missing:
            names = ', '.join(self._names[c] for c in synced.missing)
            self._log.log((names, 'missing from sets'), f'set {synced.index} stamp {synced.stamp_ns} ns: no data from '
                                                        f'{names}; going on without')
        t0 = time.perf_counter()
        observations = self._associator.update(synced.stamp_ns / 1e9, synced.items)
        bundles = [(obs.person_id, obs.views) for obs in observations]
        self._publisher.publish(wire_bundles_to_msg(bundles, Header(stamp=stamp, frame_id=self._rig.world_frame)))
        self._observe(synced, time.perf_counter() - t0)
        if self._state is not None:
            self._save_ids()
        self._skews.append(synced.skew_ns)
        if len(self._skews) == REPORT_EVERY:
            skews = np.array(self._skews) / 1e6
            drops = ', '.join(f'{r} {k}' for r, k in sorted(self.dropped.items())) or 'none'
            self.get_logger().info(f'{synced.index + 1} sets; skew of the last {len(skews)}: median '
                                   f'{np.median(skews):.1f} ms, max {skews.max():.1f} ms; messages dropped: {drops}')
            self._skews = []

    def _observe(self, synced: SyncedSet, seconds: float) -> None:
        """Diagnostics of one published set: its members' offsets, its skew, cost and latency."""
        now = time.monotonic()
        arrivals = [self._arrivals.pop((c, s), None) for c, s in enumerate(synced.stamps) if s is not None]
        for c, s in enumerate(synced.stamps):
            if s is not None:
                self._inputs[c].synchronised(now, (s - synced.stamp_ns) / 1e9)
        self._monitor.processed(now, {'association': seconds})
        self._monitor.set_skew(now, synced.skew_ns / 1e9)
        known = [a for a in arrivals if a is not None]
        self._monitor.delivered(now, now - min(known) if known else None,
                                (self.get_clock().now().nanoseconds - synced.stamp_ns) / 1e9)

    def _statuses(self, now: float, t: HealthThresholds) -> list[Status]:
        node = self._health.prefix()
        return [*input_statuses(node, [i.stats(now, t.window) for i in self._inputs], t),
                node_status(node, self._monitor.stats(now, t.window), self._sync.pending, t,
                            {'sets out': str(self._sync.sets)})]

    def destroy_node(self) -> None:
        """Log the totals of the problems logged throttled, then destroy the node."""
        if hasattr(self, '_log') and self._log.counts:
            rclpy.logging.get_logger(f'{self.get_logger().name}.totals').info(f'problems: {self._log.summary()}')
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Entry point of `ros2 run mvpose_ros association`."""
    run(AssociationNode, args)


if __name__ == '__main__':
    main()
