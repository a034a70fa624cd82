"""The bag_player node: replays any rosbag2 bag (sqlite3 or mcap) into the graph, on the bag's own
topics.

Frames (or, with `sets`, synchronised sets) go out as the bag's CDR bytes at the recorded rate
times `rate`, or with rate 0 as fast as downstream acknowledges them on `ack_topic` (lockstep with
`sets` and `max_in_flight` 1). Topics are relative, so a namespace moves the whole input. Nothing
goes out before the graph's readers have matched, so the first frame reaches every node.
Pacing and stamps: mvpose_ros.bags.replay. Behaviour in detail (QoS, the start wait, `start_topic`):
docs/operations.md#bag_player."""
from __future__ import annotations

import time
from typing import Any, Iterator

from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Empty

from msg_adapters.cdr_header import NS, header_stamp_ns, with_header_stamp
from msg_adapters.definitions import message_class
from msg_adapters.stamp import stamp_of_ns
from mvpose_ros.bags.io import bag_size, bag_summary, has_header, read_bag
from mvpose_ros.bags.replay import Frame, InFlight, due_s, group_frames, group_sets, looped
from mvpose_ros.core.defaults import FRAME_RATE, SYNC_TIMEOUT_S, default_max_skew
from mvpose_ros.core.health.monitor import NodeMonitor, node_status
from mvpose_ros.core.health.status import Status
from mvpose_ros.core.health.thresholds import HealthThresholds
from mvpose_ros.core.parameters import Param
from mvpose_ros.nodes.health import NodeHealth
from mvpose_ros.nodes.runtime import DATA_QOS, StartupError, declare, live_parameters, run
from mvpose_ros.topics import IMAGE, OPENPOSE, SKELETONS

LOG_EVERY = 100  # frames between progress lines
ACK_TIMEOUT_S = 5.0  # at the end, wait this long for subscribers to confirm receipt
_POLL_S = 0.05  # subscriber polling period while waiting to start
# The start signal (parameter start_topic): latched, so it arrives whenever the reader matches.
START_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                       history=HistoryPolicy.KEEP_LAST, depth=1)
# parameter qos -> what the player publishes with: reliable (the graph's own) or a camera driver's
PLAYER_QOS = {'reliable': DATA_QOS, 'sensor': qos_profile_sensor_data}
IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')


def relative(topic: str) -> str:
    """A bag's topic name as the player publishes it: '/cam0/openpose' -> 'cam0/openpose'."""
    return topic.lstrip('/')


def _camera_input(topic: str, name: str) -> bool:
    """Whether `topic` ('cam<c>/<name>', relative) is a camera's `name` topic."""
    head, _, tail = relative(topic).partition('/')
    return head.startswith('cam') and head[3:].isdigit() and tail == name


class BagPlayerNode(Node):
    """Publishes a bag's frames; `finished` completes with the process exit code."""

    def __init__(self) -> None:
        super().__init__('bag_player')
        self.finished = Future()
        try:
            self._configure()
        except (StartupError, FileNotFoundError, ValueError, ParameterException, NameValidationException) as exc:
            self.get_logger().fatal(' '.join(str(exc).split()))
            self.destroy_node()
            raise SystemExit(2) from None

    def _declare(self) -> dict[str, Any]:
        """Declare the parameters; returns their values."""
        return declare(self, [
            Param('bag', 'bags/shelf', 'rosbag2 folder to play'),
            Param('rate', 1.0, 'x recorded speed; 0.0 = as fast as downstream keeps up (see max_in_flight)',
                  0.0, 1e6),
            Param('clock', False, 'publish /clock with the current bag stamp'),
            Param('loops', 1, 'passes over the bag; later passes move stamps on', 1, 1_000_000),
            # An empty list cannot type itself: declared by type, unset means all topics.
            Param('topics', Parameter.Type.STRING_ARRAY, 'topics to play; empty = all'),
            Param('wait_subscribers', 10.0, 's to wait for a matched reader on every cam*/openpose (else '
                  'cam*/image_raw) topic and for every visible reader to match', 0.0, 3600.0, live=True),
            Param('start_topic', '', 'if set, also wait for a message there (std_msgs/Empty, reliable, transient '
                  'local) before playing'),
            Param('ack_topic', SKELETONS, 'downstream output whose stamps release frames when rate is 0'),
            Param('max_in_flight', 16, 'rate 0: at most this many frames (sets) published but not yet seen on '
                  'ack_topic', 1, 1_000_000),
            Param('qos', 'reliable',
                  "'reliable' (the graph's own links) or 'sensor' (best-effort keep-last, as a camera driver)"),
            Param('sets', False, 'play synchronised sets of the image topics instead of frames of one log stamp'),
            Param('max_skew', default_max_skew(FRAME_RATE), 'sets: s between the oldest and newest stamp of a set '
                  '(as the graph)', 0.0, 3600.0),
            Param('sync_timeout', SYNC_TIMEOUT_S, 'sets: s of bag time a set waits for a camera that sent nothing',
                  0.001, 3600.0),
            Param('ack_timeout', 0.0, 'rate 0: s without an ack after which the oldest frame in flight is given up '
                  '(0 = wait forever)', 0.0, 3600.0, live=True),
            Param('preload_mib', 256.0, 'a bag whose files take at most this many MiB is read into memory before '
                  'it plays, every loop replayed from there; a larger one is read while playing', 0.0, 1e6),
        ])

    def _configure(self) -> None:
        p = self._declare()
        self._bag, self._rate, self._loops = p['bag'], p['rate'], p['loops']
        self._in_flight = InFlight(p['max_in_flight']) if p['rate'] == 0 else None
        if self._in_flight is not None and not p['ack_topic']:
            raise StartupError('parameter ack_topic: required with rate 0')
        if p['qos'] not in PLAYER_QOS:
            raise StartupError(f'parameter qos: expected one of {", ".join(PLAYER_QOS)}, got {p["qos"]!r}')
        self._ack_timeout = p['ack_timeout']
        self._progress = 0.0  # monotonic s of the last publication or ack (rate 0)
        self._given_up = 0
        qos = PLAYER_QOS[p['qos']]
        self._best_effort = qos.reliability == ReliabilityPolicy.BEST_EFFORT

        summary = bag_summary(self._bag)
        in_bag = {relative(t): t for t in summary.topics}
        wanted = [relative(t) for t in p['topics'] or []]
        unknown = sorted(set(wanted) - set(in_bag))
        if unknown:
            raise StartupError(f'parameter topics: {", ".join(unknown)} not in {self._bag} '
                               f'(it has {", ".join(summary.topics)})')
        self._topics = [in_bag[t] for t in wanted] if wanted else list(summary.topics)
        self._pubs = {t: self.create_publisher(message_class(summary.topics[t][0]), relative(t), qos)
                      for t in self._topics}
        self._stamped = {t: has_header(summary.topics[t][0]) for t in self._topics}
        self._clock_pub = self.create_publisher(ClockMsg, '/clock', DATA_QOS) if p['clock'] else None
        if self._in_flight is not None:
            self.create_subscription(PointCloud2, p['ack_topic'], self._on_ack, DATA_QOS, raw=True)

        # Start when the 2D stage listens: detections if the bag has them, else images.
        images = [t for t in self._topics if summary.topics[t][0] in IMAGE_TYPES]
        inputs = [t for t in self._topics if _camera_input(t, OPENPOSE)]
        self._awaited = inputs or [t for t in self._topics if _camera_input(t, IMAGE)] or images
        self._wait_s = p['wait_subscribers']
        self._wait_until = time.monotonic() + self._wait_s
        self._started = not p['start_topic']
        if not self._started:
            self.create_subscription(Empty, p['start_topic'], self._on_start, START_QOS)

        self._unit = 'sets' if p['sets'] else 'frames'
        cameras = images or inputs
        if p['sets'] and not cameras:
            raise StartupError(f'parameter sets: {self._bag} has no image (or cam<c>/openpose) topic to '
                               f'synchronise')

        def read_pass() -> Iterator[Frame]:
            messages = read_bag(self._bag, self._topics)
            if p['sets']:
                return group_sets(messages, cameras, p['max_skew'], p['sync_timeout'], has_header)
            return group_frames(messages)
        if bag_size(self._bag) <= p['preload_mib'] * 2 ** 20:
            # Read while playing, a bag's chunks are decompressed between two frames on the cores the
            # graph works on, and delay them. Damage is then found before anything plays.
            frames = list(read_pass())
            self._frames = looped(lambda: frames, self._loops)
        else:
            self._frames = looped(read_pass, self._loops)
        self._next = None  # the (loop, offset, frame) to publish next
        self._first_ns = None
        self._start = 0.0
        self._playing = False
        self._frames_out = self._messages_out = 0
        self.get_logger().info(f'{self._bag}: {summary.message_count} messages on {len(summary.topics)} topics, '
                               f'playing {len(self._topics)} by {self._unit} at rate {self._rate:g}, loops '
                               f'{self._loops}, qos {p["qos"]}')
        self._timer = self.create_timer(_POLL_S, self._on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._monitor = NodeMonitor()
        self._health = NodeHealth(self, self._statuses)
        live_parameters(self, ['wait_subscribers', 'ack_timeout'], lambda changes: None, self._retune)

    def _retune(self, changes: dict[str, Any]) -> None:
        self._ack_timeout = changes.get('ack_timeout', self._ack_timeout)
        if 'wait_subscribers' in changes:
            self._wait_until += changes['wait_subscribers'] - self._wait_s
            self._wait_s = changes['wait_subscribers']

    def _statuses(self, now: float, t: HealthThresholds) -> list[Status]:
        extra = {'frames out' if self._unit == 'frames' else 'sets out': str(self._frames_out),
                 'messages out': str(self._messages_out), 'playing': str(self._playing).lower(),
                 'given up (never acknowledged)': str(self._given_up)}
        return [node_status(self._health.prefix(), self._monitor.stats(now, t.window),
                            0 if self._in_flight is None else len(self._in_flight), t, extra)]

    def _unmatched(self) -> list[str]:
        """Topics still waiting for readers: an awaited input without a matched reader, or a topic
        with fewer matched readers than the ROS graph shows readers this writer can match (a
        reliable reader never matches a best-effort writer: it is not waited for)."""
        out = []
        for topic, pub in self._pubs.items():
            count = pub.get_subscription_count()
            if count < max(1 if topic in self._awaited else 0, self._compatible_readers(pub.topic_name)):
                out.append(pub.topic_name)
        return out

    def _compatible_readers(self, topic: str) -> int:
        readers = self.get_subscriptions_info_by_topic(topic)
        if self._best_effort:
            readers = [r for r in readers if r.qos_profile.reliability != ReliabilityPolicy.RELIABLE]
        return len(readers)

    def _on_start(self, msg: Empty) -> None:
        if not self._started:
            self._started = True
            self._wait_until = time.monotonic() + self._wait_s  # the readers' wait starts now
            self.get_logger().info('start signal received')

    def _on_timer(self) -> None:
        if not self._playing:
            if not self._started:
                return
            idle = self._unmatched()
            if idle and time.monotonic() < self._wait_until:
                return
            if idle:
                self.get_logger().warning(f'readers not all matched on {", ".join(idle)}; playing anyway')
            self._playing = True
            self._start = time.monotonic()
            if not self._advance():
                return
        if self._next is None:
            self._drain()
        else:
            self._play()

    def _on_ack(self, cdr: bytes) -> None:
        try:
            stamp = header_stamp_ns(cdr)
        except ValueError as exc:
            self.get_logger().warning(f'ignoring a message on the ack topic: {exc}')
            return
        if self._in_flight.acked(stamp) and self._playing and not self.finished.done():
            self._progress = time.monotonic()
            if self._next is None:
                self._drain()
            else:
                self._play()

    def _advance(self) -> bool:
        """Read the next frame into self._next; False once finished (end of bag or damage)."""
        try:
            self._next = next(self._frames, None)
        except (FileNotFoundError, ValueError) as exc:
            self.get_logger().fatal(str(exc))
            self._finish(2)
            return False
        if self._next is None:
            self._drain()
            return False
        if self._first_ns is None:
            self._first_ns = self._next[2].stamp_ns
        return True

    def _play(self) -> None:
        """Publish every frame that is due, then sleep until the next one (or the next ack)."""
        while True:
            loop, offset, frame = self._next
            stamp = frame.stamp_ns + offset
            behind = None
            if self._in_flight is None:
                wait = self._start + due_s(stamp, self._first_ns, self._rate) - time.monotonic()
                behind = max(0.0, -wait)
                if wait > 0:
                    self._timer.timer_period_ns = max(1, int(wait * NS))
                    self._timer.reset()
                    return
            elif self._in_flight.full:
                if self._waiting_for_ack():
                    return
                self._give_up()
            t0 = time.perf_counter()
            self._publish(loop, stamp, offset, frame)
            self._monitor.processed(time.monotonic(), {'publish': time.perf_counter() - t0})
            self._monitor.delivered(time.monotonic(), behind, None)
            if not self._advance():
                return

    def _drain(self) -> None:
        """The bag is played: finish, with rate 0 once downstream has acknowledged every frame in
        flight (or ack_timeout has given them up). Exiting at once could take the last frame with
        it: the middleware sends large messages from a thread of this process, and a best-effort
        writer has no acknowledgement to wait for."""
        if self._in_flight is not None and len(self._in_flight):
            if self._waiting_for_ack():
                return
            while len(self._in_flight):
                self._give_up()
        self._finish(0)

    def _waiting_for_ack(self) -> bool:
        """Rate 0, frames in flight: whether to wait on (the timer armed for the rest of
        ack_timeout, or left to _on_ack without one) rather than give up the oldest."""
        if not self._ack_timeout:
            self._timer.cancel()  # _on_ack resumes
            return True
        wait = self._progress + self._ack_timeout - time.monotonic()
        if wait > 0:
            self._timer.timer_period_ns = max(1, int(wait * NS))
            self._timer.reset()  # _on_ack resumes sooner
            return True
        return False

    def _give_up(self) -> None:
        """Stop waiting for the oldest frame in flight: downstream dropped it."""
        given_up = self._in_flight.give_up()
        self._given_up += 1
        self._progress = time.monotonic()
        self.get_logger().warning(f'no ack of stamp {given_up} ns within {self._ack_timeout:g} s: '
                                  f'dropped downstream ({self._given_up} so far)')

    def _publish(self, loop: int, stamp: int, offset: int, frame: Frame) -> None:
        if self._clock_pub is not None:
            self._clock_pub.publish(ClockMsg(clock=stamp_of_ns(stamp)))
        for topic, _, cdr in frame.messages:
            self._pubs[topic].publish(with_header_stamp(cdr, stamp) if offset and self._stamped[topic] else cdr)
        if self._in_flight is not None:
            self._in_flight.published(stamp)
            self._progress = time.monotonic()
        self._frames_out += 1
        self._messages_out += len(frame.messages)
        if self._frames_out % LOG_EVERY == 0:
            elapsed = time.monotonic() - self._start
            self.get_logger().info(f'{self._frames_out} {self._unit} (stamp {stamp / NS:.3f} s, loop {loop + 1}/'
                                   f'{self._loops}), {self._frames_out / max(elapsed, 1e-9):.1f} {self._unit}/s')

    def _finish(self, code: int) -> None:
        self._timer.cancel()
        if code == 0:
            elapsed = time.monotonic() - self._start
            self.get_logger().info(f'done: {self._frames_out} {self._unit}, {self._messages_out} messages, '
                                   f'{self._loops} loop(s) in {elapsed:.2f} s '
                                   f'({self._frames_out / max(elapsed, 1e-9):.1f} {self._unit}/s)'
                                   + (f', {self._given_up} never acknowledged' if self._given_up else ''))
            deadline = time.monotonic() + ACK_TIMEOUT_S
            publishers = [*self._pubs.values(), *([self._clock_pub] if self._clock_pub else [])]
            unacked = [pub.topic_name for pub in publishers if not pub.wait_for_all_acked(
                Duration(nanoseconds=max(0, int((deadline - time.monotonic()) * NS))))]
            if unacked:
                self.get_logger().warning(f'not confirmed by every subscriber within {ACK_TIMEOUT_S:g} s: '
                                          f'{", ".join(unacked)}')
        self.finished.set_result(code)


def main(args: list[str] | None = None) -> None:
    """Entry point of `ros2 run mvpose_ros bag_player`."""
    run(BagPlayerNode, args)


if __name__ == '__main__':
    main()
