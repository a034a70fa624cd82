"""config/foxglove_layout.json matches the code: every panel it places is configured and every
configured panel placed; its 3D panel shows the scene the view serves, the markers a recording
holds and the frusta, in the rig's world frame; its image panels the overlay topics of the Shelf
rig's cameras; its diagnostics panel /diagnostics."""
from __future__ import annotations

import json
from pathlib import Path

from mvpose_ros import topics
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.nodes.foxglove_view import SCENE_SUFFIX

REPO = Path(__file__).resolve().parents[1]


def _layout() -> dict:
    return json.loads((REPO / 'config' / 'foxglove_layout.json').read_text())


def _placed(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    return _placed(node['first']) + _placed(node['second'])


def test_every_panel_is_placed_and_configured():
    layout = _layout()
    placed = _placed(layout['layout'])
    for panel in list(placed):
        if panel.startswith('Tab!'):
            placed += [tab['layout'] for tab in layout['configById'][panel]['tabs']]
    assert sorted(placed) == sorted(layout['configById'])


def test_panels_read_the_topics_the_view_and_a_recording_carry():
    config = _layout()['configById']
    rig = load_rig_file(REPO / 'config' / 'rigs' / 'shelf.yaml', data_root=data_root())
    three_d = config['3D!skeletons']
    assert three_d['followTf'] == rig.world_frame
    assert set(three_d['topics']) == {'/' + topics.SKELETONS + SCENE_SUFFIX, '/' + topics.MARKERS,
                                      '/' + topics.CAMERA_MARKERS}
    images = {c['imageMode']['imageTopic'] for k, c in config.items() if k.startswith('Image!')}
    assert images == {'/' + topics.camera_topic(name, topics.OVERLAY) for name in rig.names}
    assert config['DiagnosticSummary!graph']['topicToRender'] == topics.DIAGNOSTICS
