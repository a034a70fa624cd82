"""How well the crops planned from the 3D skeletons cover the people of the next set, on real
motion: Shelf's OpenPose clip through the 3D stage with the graph's settings; for each frame, the
live skeletons of the frame before, moved on by their last step (tracked_crops.predicted_joints),
projected into each camera (tracked_crops.projected_boxes) and grown by the onnx detector's
box_margin, as the detector crops them; scored against Shelf's 2D annotation of that frame.

    python -m mvpose_ros.bench.crop_prediction [--config config/shelf.yaml] [--data-root DIR]

An annotated person-view counts when at least one of its annotated joints lies inside the image;
it is covered when one crop holds every such joint.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Sequence

import numpy as np

from mvpose_ros.core.detection.onnx_config import OnnxDetectorConfig
from mvpose_ros.core.detection.tracked_crops import grown_boxes, predicted_joints, projected_boxes
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import FrameResult


@dataclass(frozen=True)
class Coverage:
    """Per annotated person-view in view (N,): whether a crop held all its joints inside the image,
    and the area of the smallest such crop over the area of its joints' box (NaN when none held
    them)."""

    covered: np.ndarray
    area_ratio: np.ndarray

    def line(self) -> str:
        """'crops cover 1234 of 1250 annotated person-views (98.72%); mean crop area 3.10 x the annotation's box'."""
        n, k = len(self.covered), int(self.covered.sum())
        share = 100 * k / n if n else float('nan')
        ratio = float(np.nanmean(self.area_ratio)) if k else float('nan')
        return (f'crops cover {k} of {n} annotated person-views ({share:.2f}%); mean crop area {ratio:.2f} x the '
                f"annotation's box")


def coverage(boxes: np.ndarray, uv: np.ndarray, size: tuple[int, int]) -> Coverage:
    """Coverage of the annotated people uv (A, J, 2) pixels (NaN where not annotated) of one camera
    of image size (width, height) by the crops boxes (Q, 4) u0, v0, u1, v1."""
    width, height = size
    inside = np.isfinite(uv).all(axis=-1) & (uv[..., 0] >= 0) & (uv[..., 0] < width) & \
        (uv[..., 1] >= 0) & (uv[..., 1] < height)  # (A, J)
    seen = inside.any(axis=1)
    uv, inside = uv[seen], inside[seen]
    lo = np.where(inside[..., None], uv, np.inf).min(axis=1)  # (A', 2)
    hi = np.where(inside[..., None], uv, -np.inf).max(axis=1)
    # crop q holds person a: every joint of a inside the image lies in it
    holds = ((~inside[:, None]) | ((uv[:, None] >= boxes[None, :, None, :2]) &
                                   (uv[:, None] <= boxes[None, :, None, 2:])).all(axis=-1)).all(axis=-1)  # (A', Q)
    area = np.prod(boxes[:, 2:] - boxes[:, :2], axis=1)  # (Q,)
    own = np.prod(np.maximum(hi - lo, 1.0), axis=1)  # (A',) at least a pixel a side
    smallest = np.where(holds, area[None], np.inf).min(axis=1, initial=np.inf)
    covered = np.isfinite(smallest)
    return Coverage(covered, np.where(covered, smallest / own, np.nan))


def frame_coverage(cameras: Sequence[Camera], before: FrameResult, earlier: FrameResult | None,
                   annotated: np.ndarray, margin: float) -> Coverage:
    """The crops of one set planned from the live skeletons of the set before (`before`) and the
    one before that (`earlier`, None: no motion), scored against that set's annotation annotated
    (A, C, J, 2) pixels."""
    joints = np.asarray(before.joints, dtype=np.float64)
    if earlier is not None and len(earlier.person_ids):
        joints = predicted_joints(joints, np.asarray(before.person_ids), np.asarray(earlier.joints),
                                  np.asarray(earlier.person_ids))
    parts = [coverage(grown_boxes(projected_boxes(joints, camera), margin), annotated[:, c],
                      (camera.width, camera.height)) for c, camera in enumerate(cameras)]
    return Coverage(np.concatenate([p.covered for p in parts]), np.concatenate([p.area_ratio for p in parts]))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: print the coverage of the Shelf clip's crops."""
    from mvpose_ros.bench.runs import graph_config_from
    from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir, load_actors_gt_2d
    from mvpose_ros.core.evaluation.offline import shelf_openpose
    from mvpose_ros.core.stage import Stage3D
    from mvpose_ros.package_files import package_path

    p = argparse.ArgumentParser(prog='python -m mvpose_ros.bench.crop_prediction', description=__doc__.split('\n')[0])
    p.add_argument('--config', type=Path, default=package_path('config/shelf.yaml'),
                   help='graph parameter file whose detector and 3D stage settings are used '
                        '(default: the Shelf graph\'s)')
    p.add_argument('--data-root', help='the shared data (default: ../shared or MVPOSE_DATA_ROOT)')
    args = p.parse_args(argv)
    config = graph_config_from(args.config)
    seq = shelf_openpose(args.data_root, config.detector())
    stage = Stage3D(seq.cameras, config.stage())
    annotated = load_actors_gt_2d(dataset_dir('shelf', args.data_root) / 'actorsGT.mat', list(SHELF_TEST_FRAMES))
    margin = next(f.default for f in fields(OnnxDetectorConfig) if f.name == 'box_margin')
    live: list[FrameResult | None] = []
    parts = []
    for i, (frame, people) in enumerate(zip(seq.frames, seq.people)):
        if i >= 1 and live[-1] is not None:
            parts.append(frame_coverage(seq.cameras, live[-1], live[-2] if i >= 2 else None, annotated[i], margin))
        stage.push(frame, people)
        live.append(stage.solver.live())
    total = Coverage(np.concatenate([c.covered for c in parts]), np.concatenate([c.area_ratio for c in parts]))
    print(f'Shelf frames {seq.frames[1]}-{seq.frames[-1]}, crops from the live skeletons of the frame before '
          f'(box_margin {margin:g}): {total.line()}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
