"""The overlay node as a process: a probe plays a two-camera rig's images (one CompressedImage, one
raw Image, stamped 6 ms apart), their 2D people and a set's skeletons, and reads back each camera's
overlay: the skeleton drawn where it projects, in its person's colour, on the image of the set;
bytes that are no image named in the log."""
from __future__ import annotations

import cv2
import numpy as np
import yaml
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CompressedImage, Image, PointCloud2
from std_msgs.msg import Header

from msg_adapters.image_msg import image_to_compressed_msg, image_to_msg
from msg_adapters.people_msg import people_to_msg
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import stamp_ns, stamp_of_ns
from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.video import look_at
from mvpose_ros.core.types import Person2D
from mvpose_ros.nodes.runtime import DATA_QOS, VIEWER_QOS
from mvpose_ros.topics import OVERLAY, PEOPLE2D, SKELETONS_DROPPED, SKELETONS_LIVE, camera_topic
from ros_harness import NodeLinks, matched, probe, spin_until, start_node, stop

W, H = 320, 240
# a driver's publisher: best effort, as the camera inputs take it
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)


def _person(x: float) -> np.ndarray:
    """A standing stick person (14, 3) at (x, 0), z up."""
    z = np.array([0.0, 0.45, 0.9, 0.9, 0.45, 0.0, 0.9, 1.15, 1.4, 1.4, 1.15, 0.9, 1.5, 1.75])
    dx = np.array([-0.1, -0.1, -0.1, 0.1, 0.1, 0.1, -0.3, -0.25, -0.2, 0.2, 0.25, 0.3, 0.0, 0.0])
    return np.column_stack([dx + x, np.zeros(14), z])


def _rig(tmp_path):
    cameras = [look_at(np.array([x, -5.0, 1.2]), np.array([0.0, 0.0, 1.0]), np.array([0, 0, 1.0]), W, H)
               for x in (-2.0, 2.0)]
    entries = []
    for name, cam, image in zip(('a', 'b'), cameras, ('a/image_raw/compressed', 'b/image_raw')):
        entries.append({'name': name, 'image': image, 'camera_info': f'{name}/camera_info',
                        'frame_id': f'{name}_optical', 'position': cam.centre.tolist(),
                        'orientation': Rotation.from_matrix(cam.R.T).as_quat().tolist(),
                        'width': W, 'height': H, 'K': cam.K.tolist(), 'distortion_model': 'plumb_bob',
                        'D': [0.0] * 5})
    path = tmp_path / 'rig.yaml'
    path.write_text(yaml.safe_dump({'world_frame': 'world', 'cameras': entries}))
    return path, cameras


def _colour_near(img: np.ndarray, uv: np.ndarray, bgr: tuple[int, int, int], radius: int = 3) -> bool:
    u, v = np.round(uv).astype(int)
    patch = img[max(v - radius, 0):v + radius + 1, max(u - radius, 0):u + radius + 1].reshape(-1, 3).astype(int)
    return bool((np.abs(patch - np.array(bgr)).sum(axis=1) < 80).any())


def test_each_camera_gets_its_image_of_the_set_with_the_skeletons_drawn(domain, tmp_path):
    rig, cameras = _rig(tmp_path)
    log = tmp_path / 'overlay.log'
    person = _person(0.3)
    colour = tuple(int(255 * c) for c in reversed(person_colour(4)))
    got: dict[str, list] = {'a': [], 'b': []}
    with probe(domain, 'overlay_probe') as (node, executor):
        images = {'a': node.create_publisher(CompressedImage, 'a/image_raw/compressed', SENSOR_QOS),
                  'b': node.create_publisher(Image, 'b/image_raw', SENSOR_QOS)}
        people = {n: node.create_publisher(PointCloud2, camera_topic(n, PEOPLE2D), DATA_QOS) for n in 'ab'}
        live = node.create_publisher(PointCloud2, SKELETONS_LIVE, DATA_QOS)
        dropped = node.create_publisher(Header, SKELETONS_DROPPED, DATA_QOS)
        for n in 'ab':
            node.create_subscription(CompressedImage, camera_topic(n, OVERLAY), got[n].append, VIEWER_QOS)
        links = NodeLinks(node)
        proc = start_node('overlay', domain, log, '-p', f'rig:={rig}', '-p', 'max_rate:=0.0', '-p', 'reduce:=1')
        try:
            endpoints = [*images.values(), *people.values(), live, dropped, *node.subscriptions]
            assert spin_until(executor, lambda: matched(endpoints) and links.reads(
                'overlay', '/' + SKELETONS_LIVE), 30.0), log.read_text()
            set_stamp = 2_000_000_000
            skeletons = skeletons_to_msg(np.array([4]), person[None],
                                         Header(frame_id='world', stamp=stamp_of_ns(set_stamp)),
                                         confidence=np.ones((1, 14)))

            def send_set(last) -> None:
                """Both cameras' image of the set and of the next capture, their people, then last.
                Images go best effort (a large one can be lost under load) and on other topics
                than the skeletons (which may overtake them): sent again until drawn."""
                for k, (n, cam) in enumerate(zip('ab', cameras)):
                    header = Header(frame_id=f'{n}_optical', stamp=stamp_of_ns(set_stamp + 6_000_000 * k))
                    grey = np.full((H, W, 3), 90, np.uint8)
                    later = Header(frame_id=header.frame_id, stamp=stamp_of_ns(set_stamp + 40_000_000 + 6_000_000 * k))
                    for h in (header, later):
                        images[n].publish(image_to_compressed_msg(grey, h) if n == 'a' else image_to_msg(grey, h))
                    keypoints = np.zeros((16, 3))
                    keypoints[:14, :2], keypoints[:14, 2] = cam.project(person), 1.0
                    people[n].publish(people_to_msg([Person2D.from_keypoints(keypoints, 4.0, 6.0)], header))
                last()

            assert _until_drawn(executor, lambda: send_set(lambda: live.publish(skeletons)), got, set_stamp), \
                log.read_text()
            next_set = Header(frame_id='world', stamp=stamp_of_ns(set_stamp + 40_000_000))
            assert _until_drawn(executor, lambda: send_set(lambda: dropped.publish(next_set)), got,
                                set_stamp + 40_000_000), log.read_text()
            # bytes that are no message at all: held as bytes, so named when their stamp is read
            assert spin_until(executor, lambda: images['a'].publish(b'\x07\x07' + bytes(30)) or
                              'a: image not held' in log.read_text()), log.read_text()
        finally:
            stop(proc)
    for k, (n, cam) in enumerate(zip('ab', cameras)):
        first = next(m for m in got[n] if stamp_ns(m.header.stamp) == set_stamp + 6_000_000 * k)
        assert first.header.frame_id == f'{n}_optical'
        drawn = cv2.imdecode(np.frombuffer(bytes(first.data), np.uint8), cv2.IMREAD_COLOR)
        assert drawn.shape == (H, W, 3)
        for uv in cam.project(person):
            assert _colour_near(drawn, uv, colour), (n, uv)
        assert not _colour_near(drawn, np.array([20, 200]), colour, 10)  # grey where nobody is
        # the dropped set: the next capture, with no skeleton
        second = next(m for m in got[n] if stamp_ns(m.header.stamp) == set_stamp + 40_000_000 + 6_000_000 * k)
        bare = cv2.imdecode(np.frombuffer(bytes(second.data), np.uint8), cv2.IMREAD_COLOR)
        assert not any(_colour_near(bare, uv, colour) for uv in cam.project(person))
    assert 'problems: a: ' in log.read_text() and ' x image unreadable\n' in log.read_text(), log.read_text()


def _until_drawn(executor, send, got: dict[str, list], set_stamp: int, tries: int = 50) -> bool:
    """send() until every camera's overlay of the set stamped set_stamp (its member 0 or 6 ms
    later) has come back."""
    def drawn() -> bool:
        return all(any(0 <= stamp_ns(m.header.stamp) - set_stamp <= 6_000_000 for m in g) for g in got.values())
    for _ in range(tries):
        send()
        if spin_until(executor, drawn, 0.3):
            return True
    return False
