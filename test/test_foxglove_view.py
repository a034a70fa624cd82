"""The live view node (nodes.foxglove_view) spoken to by a plain WebSocket client of the Foxglove
protocol (test/foxglove_client.py): nothing subscribed in ROS while no client listens; the scene,
frusta, overlay image and diagnostics decoded by their advertised schemas; a second client; a
client that leaves mid-stream; malformed skeletons skipped with the node still serving."""
from __future__ import annotations

import re
import time

import numpy as np
import pytest
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CompressedImage, PointCloud2
from std_msgs.msg import Header
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from msg_adapters.diagnostics_msg import statuses_to_msg
from msg_adapters.markers import camera_markers
from msg_adapters.skeleton_msg import skeletons_to_msg
from mvpose_ros.cli import graph
from mvpose_ros.core.health.status import Level, Status
from mvpose_ros.graph import session
from mvpose_ros.graph.config import graph_nodes
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.nodes.runtime import DATA_QOS, LATCHED_QOS
from foxglove_client import Client
from ros_harness import probe, spin_until, start_node, stop

SCENE, FRUSTA, DIAG, OVERLAY = '/skeletons/scene', '/cameras/markers', '/diagnostics', '/cam0/overlay/compressed'
ROS_TOPIC = {SCENE: '/skeletons', FRUSTA: FRUSTA, DIAG: DIAG, OVERLAY: OVERLAY}


def _port(log, timeout: float = 30.0) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = re.search(r'ws://127\.0\.0\.1:(\d+)', log.read_text())
        if found:
            return int(found.group(1))
        time.sleep(0.05)
    raise TimeoutError(log.read_text())


class Sender:
    """The graph's side: skeletons frames with person ids 5 and 9, one after another."""

    def __init__(self, node) -> None:
        self.skeletons = node.create_publisher(PointCloud2, 'skeletons', DATA_QOS)
        self.frame = 0

    def people(self, frame: int) -> np.ndarray:
        return np.full((2, 14, 3), 0.01 * frame) + np.arange(14)[None, :, None] * 0.1

    def __call__(self) -> None:
        header = Header(frame_id='world')
        header.stamp.sec, header.stamp.nanosec = 100 + self.frame, 0
        self.skeletons.publish(skeletons_to_msg(np.array([5, 9]), self.people(self.frame), header,
                                                confidence=np.full((2, 14), 0.5)))
        self.frame += 1


def test_the_view_serves_scene_frusta_images_and_diagnostics_to_clients(domain, tmp_path, shelf_rig):
    log = tmp_path / 'view.log'
    proc = start_node('foxglove_view', domain, log, '-p', 'port:=0', '-p', 'discover_period:=0.2')
    try:
        with probe(domain, 'graph') as (node, executor):
            port = _port(log)
            url = f'ws://127.0.0.1:{port}'
            header = Header(frame_id='world')
            frusta = camera_markers(shelf_rig, [f'cam{c}' for c in range(len(shelf_rig))], header)
            node.create_publisher(type(frusta), 'cameras/markers', LATCHED_QOS).publish(frusta)
            overlay = node.create_publisher(CompressedImage, 'cam0/overlay/compressed', QoSProfile(depth=10))
            diagnostics = node.create_publisher(type(statuses_to_msg([], header.stamp)), '/diagnostics',
                                                DIAGNOSTICS_QOS)
            send = Sender(node)
            # the SDK's server speaks foxglove.sdk.v1 only (docs/visualize.md says so)
            with pytest.raises(InvalidStatus, match='400'):
                connect(url, subprotocols=['foxglove.websocket.v1'], open_timeout=10).close()
            with Client(url) as first:
                ids = first.wait_channels({SCENE, FRUSTA, DIAG, OVERLAY})
                assert first.channels[ids[SCENE]]['schemaName'] == 'foxglove.SceneUpdate'
                assert first.channels[ids[OVERLAY]]['schemaName'] == 'sensor_msgs/msg/CompressedImage'
                # read only: a client cannot publish into the graph, call services or set parameters
                assert first.server_info['op'] == 'serverInfo'
                assert not {'clientPublish', 'services', 'parameters'} & set(first.server_info['capabilities'])
                # a client that subscribed to nothing costs the graph nothing: no ROS reader yet
                time.sleep(0.5)  # several of the node's looks at its channels
                assert [node.count_subscribers(t) for t in ROS_TOPIC.values()] == [0, 0, 0, 0]

                first.subscribe(ids.values())
                assert spin_until(executor, lambda: all(node.count_subscribers(t) == 1 for t in ROS_TOPIC.values()))
                status = Status('/bp_solver: latency', Level.OK, 'p50 140 ms')

                def tick() -> None:
                    send()
                    overlay.publish(CompressedImage(header=header, format='jpeg', data=b'\xff\xd8overlay'))
                    diagnostics.publish(statuses_to_msg([status], header.stamp))
                    time.sleep(0.02)

                def every_topic(got) -> bool:
                    return {SCENE, FRUSTA, DIAG, OVERLAY} <= {r.topic for r in got}

                got = first.receive(every_topic, tick=tick)
                assert every_topic(got), {r.topic for r in got}
                scene = [r.message for r in got if r.topic == SCENE]
                assert [e.id for e in scene[-1].entities] == ['person 5', 'person 9']
                frame = scene[-1].entities[0].timestamp.seconds - 100
                np.testing.assert_allclose([[s.pose.position.x, s.pose.position.y, s.pose.position.z]
                                            for s in scene[-1].entities[0].spheres], send.people(frame)[0])
                markers = next(r.message for r in got if r.topic == FRUSTA).markers
                assert [(m.ns, m.id) for m in markers] == [(m.ns, m.id) for m in frusta.markers]
                image = next(r.message for r in got if r.topic == OVERLAY)
                assert image.format == 'jpeg' and bytes(image.data) == b'\xff\xd8overlay'
                assert next(r.message for r in got if r.topic == DIAG).status[0].message == 'p50 140 ms'

                # a second client: both get the frames that follow
                with Client(url) as second:
                    second.subscribe([second.wait_channels({SCENE})[SCENE]])
                    got2 = second.receive(lambda g: len(g) >= 3, tick=send)
                    assert len(got2) >= 3 and all(r.topic == SCENE for r in got2)
                    assert first.receive(lambda g: len([r for r in g if r.topic == SCENE]) >= 3, tick=send)
                    # malformed skeletons are skipped: the node goes on serving
                    send.skeletons.publish(PointCloud2(header=header, width=3, data=b'\x01\x02\x03'))
                    # the first client leaves in mid-stream; the second goes on
                    first.ws.close()
                    after = second.receive(lambda g: len(g) >= 3, tick=send)
                    assert len(after) >= 3
                    # what only the first client wanted is read no more
                    assert spin_until(executor, lambda: [node.count_subscribers(t) for t in (DIAG, OVERLAY)] == [0, 0])
                    assert node.count_subscribers('/skeletons') == 1
                # nobody left: no reader of the skeletons either
                assert spin_until(executor, lambda: node.count_subscribers('/skeletons') == 0)
        assert proc.poll() is None, log.read_text()
        assert 'not shown' in log.read_text()  # the malformed message, named in the log
    finally:
        stop(proc)
    assert 'sent ' in log.read_text() and 'CPU ' in log.read_text()


def test_mvpose_graph_runs_the_view_before_the_player_on_the_port_asked(capsys):
    nodes = graph_nodes(2, 'bags/shelf', 1.0)
    assert session._with_view(nodes, None) == nodes
    with_view = session._with_view(nodes, 8790)
    assert [n.executable for n in with_view[-2:]] == ['foxglove_view', 'bag_player']
    assert with_view[-2].parameters == {'port': 8790} and len(with_view) == len(nodes) + 1
    assert graph.main(['--config', 'config/shelf.yaml', '--foxglove-port', '70000']) == 2
    assert '--foxglove-port must be in 0-65535' in capsys.readouterr().err
