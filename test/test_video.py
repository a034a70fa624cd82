"""mvpose-render: a predictions file to a video whose frames show the skeletons where they are,
in their ids' colours."""
from __future__ import annotations

import json

import cv2
import numpy as np

from mvpose_ros.cli.render import main
from mvpose_ros.core.evaluation.datasets import shelf_cameras
from mvpose_ros.core.evaluation.overlay import person_colour
from mvpose_ros.core.evaluation.video import Scene, look_at, render_frame, virtual_camera
from mvpose_ros.core.types import FrameResult


def _person(centre) -> np.ndarray:
    """A standing stick person (14, 3) at centre (x, y), z up."""
    z = np.array([0.0, 0.45, 0.9, 0.9, 0.45, 0.0, 0.9, 1.15, 1.4, 1.4, 1.15, 0.9, 1.5, 1.75])
    x = np.array([-0.1, -0.1, -0.1, 0.1, 0.1, 0.1, -0.3, -0.25, -0.2, 0.2, 0.25, 0.3, 0.0, 0.0])
    return np.column_stack([x + centre[0], np.full(14, centre[1]), z])


def test_look_at_puts_the_target_in_the_middle_and_up_up():
    cam = look_at(np.array([5.0, 0, 2]), np.zeros(3), np.array([0, 0, 1.0]), 640, 480)
    np.testing.assert_allclose(cam.project(np.zeros(3)), [320, 240], atol=1e-9)
    assert cam.project(np.array([0, 0, 1.0]))[1] < 240  # above the target: higher in the image


def test_every_joint_is_in_the_virtual_view_and_drawn_in_its_colour():
    results = [FrameResult(f, [2, 9], np.stack([_person((f * 0.05, 0)), _person((1.5, 1))]), np.ones((2, 14)))
               for f in range(10)]
    rig = shelf_cameras(None)
    view = virtual_camera(results, rig, np.array([0, 0, 1.0]), 640, 480)
    uv = view.project(np.concatenate([r.joints.reshape(-1, 3) for r in results]))
    assert np.isfinite(uv).all() and (uv > 0).all() and (uv[:, 0] < 640).all() and (uv[:, 1] < 480).all()
    img = render_frame(Scene(view, rig, [c.name for c in rig], np.array([0, 0, 1.0])), results[3], 120_000_000)
    for pid, joints in zip(results[3].person_ids, results[3].joints):
        r, g, b = person_colour(pid)
        u, v = np.round(view.project(joints[8])).astype(int)  # a shoulder
        patch = img[v - 2:v + 3, u - 2:u + 3].reshape(-1, 3).astype(int)
        assert np.abs(patch - [255 * b, 255 * g, 255 * r]).sum(axis=1).min() < 40


def test_render_command_writes_a_video_of_every_frame_and_a_still(tmp_path):
    lines = [{'frame': 300 + f, 'stamp': 12_000_000_000 + 40_000_000 * f,
              'people': [{'id': 1, 'joints': _person((0.1 * f, 0)).tolist(), 'confidence': [0.5] * 14}]}
             for f in range(6)]
    predictions = tmp_path / 'p.jsonl'
    predictions.write_text(''.join(json.dumps(line) + '\n' for line in lines))
    video, still = tmp_path / 'v.mp4', tmp_path / 's.png'
    assert main([str(predictions), '--output', str(video), '--size', '320x240', '--camera', '1',
                 '--still', '303', '--still-output', str(still)]) == 0
    cap = cv2.VideoCapture(str(video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    ok, frame = cap.read()
    assert ok and frame.shape[0] == 240 and frame.shape[1] > 320  # the view and camera 1 beside it
    assert cv2.imread(str(still)).shape == frame.shape
    assert main([str(predictions), '--output', str(tmp_path / 'v.gif')]) == 2
    assert main([str(predictions), '--output', str(video), '--still', '999']) == 2
