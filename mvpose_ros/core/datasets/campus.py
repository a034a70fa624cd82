"""The Campus dataset as a 2D sequence for the 3D stage.

Offline we only have Campus' calibration and three ground-truth frames, no images and no
detections. Without a CampusSeq1 folder the 2D people are therefore the ground truth projected
into each camera (an oracle that checks calibration, sampling, inference and scoring, not
detection). A full CampusSeq1 folder (`actorsGT.mat`, `calibration_campus.json`) is read with
the HRNet COCO-17 detections mmpose and VoxelPose publish for it
(`pred_campus_maskrcnn_hrnet_coco.pkl`, keys '<camera>_<frame>').
"""
from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from mvpose_ros.core.datasets.shelf_campus import (CAMPUS_TEST_FRAMES, GroundTruth, dataset_cameras, dataset_dir,
                                                   load_actors_gt)
from mvpose_ros.core.geometry.body import NUM_INFERENCE_JOINTS, NUM_JOINTS, to_inference
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import Person2D, Sequence2D

DETECTIONS_FILE = 'pred_campus_maskrcnn_hrnet_coco.pkl'
STRIDE, SIGMA = 2.0, 3.0  # px; Campus images are 360x288


def oracle_people(cameras: list[Camera], poses: np.ndarray) -> list[list[Person2D]]:
    """Per camera, the present actors of `poses` (A, 14, 3) projected as 2D people.

    Inference joints 12 and 13 carry the ground-truth bottom and top head (head model
    'direct'); the ears stay undetected."""
    out = []
    for cam in cameras:
        people = []
        for pose in poses[np.isfinite(poses).all(axis=(1, 2))]:
            kp = np.zeros((NUM_INFERENCE_JOINTS, 3))
            kp[:NUM_JOINTS, :2] = cam.project(pose)
            u, v = kp[:NUM_JOINTS, 0], kp[:NUM_JOINTS, 1]
            inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
            kp[:NUM_JOINTS, 2] = inside
            if inside.sum() >= 4:
                people.append(Person2D.from_keypoints(kp, STRIDE, SIGMA))
        out.append(people)
    return out


def campus_sequence(root: str | None, campus_dir: Path | None) -> tuple[Sequence2D, GroundTruth, str]:
    """The sequence, its ground truth and the head model its keypoints need."""
    if campus_dir is None:
        campus = dataset_dir('campus', root)
        cameras = dataset_cameras('campus', root)
        gt = load_actors_gt(campus / 'mmpose_subset' / 'actorsGT.mat')
        people = [oracle_people(cameras, poses) for poses in gt.poses]
        return Sequence2D(cameras, [int(f) for f in gt.frames], people), gt, 'direct'
    campus_dir = Path(campus_dir)
    for name in ('actorsGT.mat', 'calibration_campus.json', DETECTIONS_FILE):
        if not (campus_dir / name).is_file():
            raise FileNotFoundError(f'{campus_dir / name}: missing (a CampusSeq1 folder needs actorsGT.mat, '
                                    f'calibration_campus.json and {DETECTIONS_FILE})')
    cameras = dataset_cameras('campus', calibration=campus_dir / 'calibration_campus.json')
    gt = load_actors_gt(campus_dir / 'actorsGT.mat', CAMPUS_TEST_FRAMES)
    with open(campus_dir / DETECTIONS_FILE, 'rb') as f:
        detections = pickle.load(f)
    people = [[[Person2D.from_keypoints(kp, STRIDE, SIGMA)
                for kp in to_inference(np.array([d['pred'] for d in detections.get(f'{c}_{frame}', [])])
                                       .reshape(-1, 17, 3), 'coco17')
                if (kp[:, 2] > 0).any()]
               for c in range(len(cameras))]
              for frame in CAMPUS_TEST_FRAMES]
    return Sequence2D(cameras, list(CAMPUS_TEST_FRAMES), people), gt, 'anatomical'
