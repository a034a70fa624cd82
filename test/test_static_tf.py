"""A rig's camera frames as static TF: the arguments of tf2_ros's static_transform_publisher give
back each camera's pose, so a point moved into a camera's frame through TF is where the camera
model puts it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.rig import Rig, load_rig_file, quaternion_to_matrix
from mvpose_ros.graph.static_tf import TF_EXECUTABLE, TF_PACKAGE, static_transform_nodes

SHELF_RIG = Path(__file__).resolve().parents[1] / 'config' / 'rigs' / 'shelf.yaml'
FLAGS = ('--x', '--y', '--z', '--qx', '--qy', '--qz', '--qw', '--frame-id', '--child-frame-id')


def parsed(arguments: list[str]) -> dict[str, str]:
    """static_transform_publisher's named arguments as flag -> value (each flag once, none other)."""
    flags, values = arguments[::2], arguments[1::2]
    assert sorted(flags) == sorted(FLAGS) and len(values) == len(flags)
    return dict(zip(flags, values))


def camera_from_world(args: dict[str, str], X: np.ndarray) -> np.ndarray:
    """(N, 3) world points in the child frame of the transform the arguments publish: TF's
    transform parent -> child maps child coordinates into the parent, so the inverse maps X."""
    position = np.array([float(args[f]) for f in FLAGS[:3]])
    rotation = quaternion_to_matrix(np.array([float(args[f]) for f in FLAGS[3:7]]))
    return (X - position) @ rotation


def _explicit_rig(tmp_path: Path) -> Rig:
    """Two cameras with driver-style frame ids and a tilted, turned pose, in world frame 'map'."""
    turned = [0.2705980500730985, -0.6532814824381882, 0.6532814824381883, -0.2705980500730985]
    doc = {'world_frame': 'map', 'cameras': [
        {'name': 'left', 'frame_id': 'left_optical_frame', 'position': [1.5, -2.0, 2.25],
         'orientation': turned},
        {'name': 'right', 'frame_id': 'right_optical_frame', 'position': [-0.5, 3.0, 1.0],
         'orientation': [0.0, 0.0, 0.0, 1.0]}]}
    path = tmp_path / 'rig.yaml'
    path.write_text(yaml.safe_dump(doc))
    return load_rig_file(path)


@pytest.mark.parametrize('which', ['explicit', 'shelf calibration'])
def test_each_camera_frame_is_the_transform_from_the_world_frame(tmp_path, which):
    rig = _explicit_rig(tmp_path) if which == 'explicit' else load_rig_file(SHELF_RIG, data_root=data_root())
    nodes = static_transform_nodes(rig)
    assert [n['name'] for n in nodes] == [f'{name}_frame' for name in rig.names]
    assert all((n['package'], n['executable']) == (TF_PACKAGE, TF_EXECUTABLE) for n in nodes)
    X = np.random.default_rng(0).uniform([-3.0, -3.0, 0.0], [3.0, 3.0, 2.5], (50, 3))
    for node, cam in zip(nodes, rig.cameras):
        args = parsed(node['arguments'])
        assert (args['--frame-id'], args['--child-frame-id']) == (rig.world_frame, cam.frame_id)
        # x_cam = R X + t, the camera model's own convention
        np.testing.assert_allclose(camera_from_world(args, X), X @ cam.R.T + cam.t, atol=1e-12)


def test_numbers_are_written_exactly():
    """repr of each float64: the published pose is the rig file's to the last bit."""
    rig = load_rig_file(SHELF_RIG, data_root=data_root())
    for node, cam in zip(static_transform_nodes(rig), rig.cameras):
        args = parsed(node['arguments'])
        assert [float(args[f]) for f in FLAGS[:3]] == cam.position.tolist()
        assert [float(args[f]) for f in FLAGS[3:7]] == cam.orientation.tolist()


def test_a_camera_without_frame_id_is_refused_with_the_fix(tmp_path):
    """A rig file may leave frame_id to the messages, but TF must name the frame before any comes."""
    doc = {'cameras': [{'name': 'hd00', 'position': [0.0, 0.0, 1.0], 'orientation': [0.0, 0.0, 0.0, 1.0]}]}
    path = tmp_path / 'rig.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=r"camera 'hd00': tf needs its frame_id in the rig file .*hd00_optical_frame"):
        static_transform_nodes(load_rig_file(path))
