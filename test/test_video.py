"""mvpose-render: a predictions file to a video whose frames show the skeletons where they are,
in their ids' colours."""
from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np

from mvpose_ros.cli.render import main
from mvpose_ros.core.datasets.shelf_campus import shelf_cameras
from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.overlay import GROUND_TRUTH_BGR
from mvpose_ros.core.drawing.video import Scene, look_at, render_frame, virtual_camera
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


def test_the_ground_truth_is_drawn_in_both_views_where_a_frame_has_it():
    rig = shelf_cameras(None)
    result = FrameResult(7, [2], _person((0.0, 0.0))[None], np.ones((1, 14)))
    truth = _person((0.6, 0.0))
    view = virtual_camera([result], rig, np.array([0, 0, 1.0]), 640, 480)
    scene = Scene(view, rig, [c.name for c in rig], np.array([0, 0, 1.0]), camera=1)
    plain = render_frame(scene, result, None)
    drawn = render_frame(replace(scene, truth=lambda frame: (np.array([frame]), truth[None])), result, None)
    nothing = render_frame(replace(scene, truth=lambda frame: (np.zeros(0, int), np.zeros((0, 14, 3)))), result, None)
    assert np.array_equal(nothing, plain)
    panel = cv2.resize(np.zeros((rig[1].height, rig[1].width, 3), np.uint8), (drawn.shape[1] - 640, 480))
    scale = panel.shape[1] / rig[1].width
    for uv, offset in ((view.project(truth), 0), (rig[1].project(truth) * scale, 640)):
        for u, v in np.round(uv).astype(int)[[8, 9, 13]]:  # shoulders and head top
            patch = drawn[v - 4:v + 5, offset + u - 4:offset + u + 5].reshape(-1, 3).astype(int)
            assert (np.abs(patch - GROUND_TRUTH_BGR).sum(axis=1) < 90).any()
            assert not (np.abs(plain[v - 4:v + 5, offset + u - 4:offset + u + 5].reshape(-1, 3).astype(int)
                               - GROUND_TRUTH_BGR).sum(axis=1) < 90).any()


def test_render_command_draws_shelf_annotations_and_refuses_frames_it_lacks(tmp_path, capsys):
    def predictions(frames):
        path = tmp_path / f'p{frames[0]}.jsonl'
        path.write_text(''.join(json.dumps({'frame': f, 'people': [{'id': 1, 'joints': _person((0, 0)).tolist()}]})
                                + '\n' for f in frames))
        return str(path)

    stills = {}
    for flag in ([], ['--ground-truth', 'shelf']):
        still = tmp_path / f'still{len(flag)}.png'
        assert main([predictions([571, 572]), '--output', str(tmp_path / 'v.mp4'), '--size', '320x240',
                     '--still', '572', '--still-output', str(still), *flag]) == 0
        stills[bool(flag)] = cv2.imread(str(still))
    # frame 572 annotates actors 1, 3 and 4: drawn in the ground-truth colour, nowhere without the flag
    colour = (np.abs(stills[True].astype(int) - GROUND_TRUTH_BGR).sum(axis=2) < 60).sum()
    assert colour > 100 and (np.abs(stills[False].astype(int) - GROUND_TRUTH_BGR).sum(axis=2) < 60).sum() < colour / 10
    capsys.readouterr()
    assert main([predictions([99999]), '--output', str(tmp_path / 'w.mp4'), '--ground-truth', 'shelf']) == 2
    assert "--ground-truth shelf: the predictions' frames are not all Shelf frames" in capsys.readouterr().err
