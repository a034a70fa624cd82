"""config/mvpose.rviz matches the code: its fixed frame is the Shelf rig's world frame and its
displays read the topics bp_solver publishes, with QoS that connects (the camera frusta are
published once, transient local: the display must ask for transient local to get them)."""
from __future__ import annotations

from pathlib import Path

import yaml

from msg_adapters.skeleton_msg import SKELETON_DTYPE
from mvpose_ros import topics
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.nodes.runtime import LATCHED_QOS

REPO = Path(__file__).resolve().parents[1]


def _config() -> dict:
    return yaml.safe_load((REPO / 'config' / 'mvpose.rviz').read_text())


def _displays(config: dict) -> dict[str, dict]:
    return {d['Topic']['Value']: d for d in config['Visualization Manager']['Displays'] if 'Topic' in d}


def test_fixed_frame_is_the_rigs_world_frame():
    rig = load_rig_file(REPO / 'config' / 'rigs' / 'shelf.yaml', data_root=data_root())
    assert _config()['Visualization Manager']['Global Options']['Fixed Frame'] == rig.world_frame == 'world'


def test_displays_read_the_solvers_topics():
    displays = _displays(_config())
    assert set(displays) == {'/' + topics.MARKERS, '/' + topics.SKELETONS, '/' + topics.CAMERA_MARKERS}
    assert displays['/' + topics.MARKERS]['Class'] == 'rviz_default_plugins/MarkerArray'
    assert displays['/' + topics.CAMERA_MARKERS]['Class'] == 'rviz_default_plugins/MarkerArray'
    cloud = displays['/' + topics.SKELETONS]
    assert cloud['Class'] == 'rviz_default_plugins/PointCloud2'
    assert cloud['Channel Name'] in SKELETON_DTYPE.names and cloud['Channel Name'] == 'confidence'
    for display in displays.values():
        assert display['Topic']['Reliability Policy'] == 'Reliable'


def test_camera_display_is_transient_local_as_published():
    cameras = _displays(_config())['/' + topics.CAMERA_MARKERS]['Topic']
    assert LATCHED_QOS.durability.name == 'TRANSIENT_LOCAL'
    assert cameras['Durability Policy'] == 'Transient Local'
    assert {'frusta', 'camera names'} <= set(_displays(_config())['/' + topics.CAMERA_MARKERS]['Namespaces'])
