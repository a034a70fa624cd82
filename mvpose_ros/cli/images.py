"""`mvpose-images`: 3D skeletons from one synchronised set of camera images of a calibrated rig.

    mvpose-images (--rig FILE | --calibration FILE) --images CAM0 CAM1 ... [--output DIR] [--frame N]
                  [--model rt|i] [--head-model anatomical|direct] [--ground-truth shelf] [--data-root DIR]

Detects the 2D people of every image with the ONNX backend (MoveNet MultiPose + EfficientPose),
associates them across the cameras, samples the 3D hypotheses and runs BP on this one frame, and
writes the skeletons as one predictions line (`<output>/skeletons.jsonl`) and one overlay PNG per
camera (`<output>/cam<c>.png`: the reprojected 3D skeletons in each person's colour over the 2D
detections in thin white). Prints the latency of each camera's detection and of the whole frame;
with --ground-truth shelf, the per-actor MPJPE and PCP of the frame against Shelf's actorsGT.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Sequence, TextIO

import cv2
import numpy as np

from mvpose_ros.core.geometry.body import HEAD_MODELS, NUM_JOINTS
from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.core.evaluation.datasets import data_root, dataset_dir, load_actors_gt
from mvpose_ros.core.evaluation.pcp import FORMS, evaluate, format_table
from mvpose_ros.core.detection.image_file import read_image
from mvpose_ros.core.detection.onnx_detector import MODELS, OnnxDetectorConfig, OnnxPoseDetector
from mvpose_ros.core.evaluation.overlay import overlay, person_colour
from mvpose_ros.core.stage import StageConfig, Stage3D
from mvpose_ros.core.evaluation.predictions import frame_line
from mvpose_ros.core.types import FrameResult

PROG = 'mvpose-images'
DEFAULTS = OnnxDetectorConfig(model_dir=Path())


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n')[0])
    rig = p.add_mutually_exclusive_group(required=True)
    rig.add_argument('--rig', type=Path, help='rig file (YAML, with every camera\'s intrinsics; see README "Your own '
                                              'cameras"): the images must have the sizes it gives')
    rig.add_argument('--calibration', type=Path, help='calibration json (Shelf layout): each camera at the size of '
                                                      'its image')
    p.add_argument('--images', required=True, nargs='+', type=Path,
                   help='one image per camera, in the rig\'s camera order')
    p.add_argument('--output', type=Path, default=Path('out/images'), help='folder for skeletons.jsonl and '
                   'the overlays (default: out/images)')
    p.add_argument('--frame', type=int, default=0, help='frame number written with the skeletons (default: 0)')
    p.add_argument('--data-root', help='folder holding data/ and models/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--models', type=Path, help='folder of the .onnx files (default: <data root>/models)')
    p.add_argument('--model', choices=MODELS, default=DEFAULTS.model, help='EfficientPose variant (default: rt)')
    p.add_argument('--providers', nargs='+', default=list(DEFAULTS.providers),
                   help='onnxruntime execution providers (default: CPUExecutionProvider)')
    p.add_argument('--input-size', type=int, default=DEFAULTS.input_size,
                   help='MultiPose input side, a multiple of 32 (default: 384)')
    p.add_argument('--stride', type=float, default=DEFAULTS.stride, help='heatmap cell size, pixels (default: 4)')
    p.add_argument('--no-ears', dest='ears', action='store_false',
                   help="leave the ear joints empty instead of taking MultiPose's COCO ears")
    p.add_argument('--head-model', choices=HEAD_MODELS, default='anatomical',
                   help='how the head joints are derived in 3D (default: anatomical, from the COCO ears and the '
                        'MPII upper neck; direct: MPII upper neck and head top)')
    p.add_argument('--ground-truth', choices=('shelf',),
                   help="score the frame against this dataset's actorsGT (--frame is its frame index)")
    return p


def _rig_and_images(args: argparse.Namespace) -> tuple[list[Camera], list[np.ndarray]]:
    """The rig's cameras and their images: checked against the sizes a rig file gives, or giving a
    calibration json (which records none) each camera's size."""
    if args.rig is not None:
        cameras = load_rig_file(args.rig, data_root=data_root(args.data_root)).calibrated_cameras()
        _same_count(args.images, cameras)
        return cameras, [read_image(path, cam) for path, cam in zip(args.images, cameras)]
    images = [read_image(path) for path in args.images]
    height, width = images[0].shape[:2]
    cameras = load_rig(args.calibration, width, height)
    _same_count(args.images, cameras)
    return [replace(cam, width=im.shape[1], height=im.shape[0]) for cam, im in zip(cameras, images)], images


def _same_count(paths: Sequence[Path], cameras: Sequence[Camera]) -> None:
    if len(paths) != len(cameras):
        raise ValueError(f'--images: {len(paths)} images for {len(cameras)} cameras in the rig')


def _score(result: FrameResult, root: str | None, out: TextIO) -> None:
    """Per-actor MPJPE and PCP of this frame against Shelf's actorsGT, for every actor annotated in
    it (the standard Shelf protocol scores actors 1-3 over frames 300-600, but one frame can lack
    one of them and show actor 4: frame 572 annotates actors 1, 3 and 4)."""
    gt = load_actors_gt(dataset_dir('shelf', root) / 'actorsGT.mat', [result.frame])
    actors = np.flatnonzero(gt.present[0]).tolist()
    if not actors:
        print(f'ground truth: no actor is annotated in Shelf frame {result.frame}', file=out)
        return
    ev = evaluate({result.frame: result.joints}, gt, actors)
    print(format_table(ev), file=out)
    for a, actor in enumerate(ev.actors):
        found = 'found' if ev.missed[a] == 0 else 'NOT found'
        pcp = ', '.join(f'PCP {form} {ev.pcp(form, actor):.1f}%' for form in FORMS)
        print(f'Actor {actor + 1}: {found}, MPJPE {ev.mpjpe[a]:.1f} mm, {pcp}', file=out)


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    cameras, images = _rig_and_images(args)
    models = args.models or data_root(args.data_root) / 'models'
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=models, model=args.model, providers=tuple(args.providers),
                                                   input_size=args.input_size, stride=args.stride, ears=args.ears))
    detector.detect(images[0])  # warm-up: onnxruntime's first run allocates; not a steady-state latency
    start = time.perf_counter()
    people = []
    print(f'{PROG}: {len(cameras)} cameras, EfficientPose {args.model.upper()}, MultiPose input '
          f'{args.input_size} px, {",".join(detector.providers)}', file=out)
    for c, bgr in enumerate(images):
        people.append(detector.detect(bgr))
        t = detector.timing
        print(f'  cam{c}: {t.people} people; MultiPose {1e3 * t.multipose:6.1f} ms, EfficientPose '
              f'{t.people} crops {1e3 * t.efficientpose:6.1f} ms, total {1e3 * t.total:6.1f} ms', file=out)
    detected = time.perf_counter()
    stage = Stage3D(cameras, StageConfig.from_params({'window': 0, 'head_model': args.head_model}))
    results = stage.push(args.frame, people) + stage.flush()
    nobody = FrameResult(args.frame, [], np.zeros((0, NUM_JOINTS, 3)), np.zeros((0, NUM_JOINTS)))
    result = results[0] if results else nobody
    end = time.perf_counter()
    print(f'frame: 2D detection {1e3 * (detected - start):.0f} ms ({len(cameras)} cameras), association and 3D '
          f'{1e3 * (end - detected):.0f} ms, total {1e3 * (end - start):.0f} ms; '
          f'{len(result.person_ids)} people in 3D (ids {result.person_ids})', file=out)

    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / 'skeletons.jsonl').write_text(frame_line(result) + '\n', encoding='utf-8')
    colours = [person_colour(pid) for pid in result.person_ids]
    for c, (cam, bgr) in enumerate(zip(cameras, images)):
        path = args.output / f'cam{c}.png'
        if not cv2.imwrite(str(path), overlay(bgr, cam, people[c], result.joints, colours)):
            raise OSError(f'{path}: could not write the overlay')
    print(f'wrote {args.output / "skeletons.jsonl"} and {len(cameras)} overlays cam0..cam{len(cameras) - 1}.png',
          file=out)
    if args.ground_truth == 'shelf':
        _score(result, args.data_root, out)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (OSError, ValueError) as exc:  # ModelError is a ValueError: a missing or wrong model file
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
