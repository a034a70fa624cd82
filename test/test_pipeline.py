"""The solver half of the 3D stage (Inference3D) over real Shelf frames, a frame with nobody in
it included: one result per frame, in order."""
from __future__ import annotations

from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.geometry.camera import load_rig
from mvpose_ros.core.evaluation.datasets import dataset_dir
from mvpose_ros.core.heatmap import HeatmapStack
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.inference.solver import Inference3D, StageConfig
from mvpose_ros.core.inference.window import InferenceConfig


def test_a_frame_with_nobody_is_output_empty_and_the_others_go_on():
    root = dataset_dir('shelf')
    cameras = load_rig(root / 'calibration' / 'calibration_shelf.json')
    raw = [read_body25(root / 'openpose_body25' / f'{c}.txt')[:10] for c in range(len(cameras))]
    associator = Associator(cameras, AssociationConfig())
    solver = Inference3D(cameras, StageConfig(inference=InferenceConfig(window=4, lag=1, slide_iterations=1)))
    results = []
    for k in range(10):
        people = [detect_people(raw[c][k], OpenPoseDetectorConfig(stride=8.0)) for c in range(len(cameras))]
        bundles = [(o.person_id, o.views) for o in associator.update(300 + k, people)]
        results += solver.push(300 + k, [] if k == 4 else bundles)  # frame 304: nobody seen
    results += solver.flush()
    assert [r.frame for r in results] == list(range(300, 310))
    assert [len(r.person_ids) for r in results][4] == 0
    assert all(len(r.person_ids) >= 2 for k, r in enumerate(results) if k != 4)
    assert HeatmapStack.of([]).peak().shape == (0, 0, 3)
