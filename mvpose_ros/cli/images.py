"""`mvpose-images`: 3D skeletons from one synchronised set of camera images of a calibrated rig.

Detects the 2D people of every image with the onnx backend (its options: the detector's table,
core.detection.detector_settings), associates them across the cameras and solves the 3D stage on
this one frame (bench.still_sets); writes `<output>/skeletons.jsonl` and an overlay
`<output>/cam<c>.png` per camera, prints each stage's time and, with --ground-truth shelf, the
frame's per-actor MPJPE and PCP. A camera given `-` instead of an image is left out, as one that
sent nothing. --sets N detects the same images N times as a still sequence, solved as the rig
graph's bp_solver solves it (docs/own_cameras.md: what --sets, --person-detector-every and
--multipose-workers measure).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence, TextIO

from mvpose_ros.bench.still_sets import NO_IMAGE, detect_sets, rig_and_images, score, stage_config, write_outputs
from mvpose_ros.cli.parameter_options import add_parameter_options, parameter_values
from mvpose_ros.core.detection.detector_settings import ONNX_PARAMETERS, DetectorConfig
from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector
from mvpose_ros.core.detection.tracked_crops import CropPlanner
from mvpose_ros.core.detection.upright import upright_turns
from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.body import HEAD_MODELS
from mvpose_ros.core.stage import SOLVER_PARAMETERS, Stage3D, StageConfig

PROG = 'mvpose-images'
HEAD_MODEL = StageConfig().solver.head_model


def build_parser() -> argparse.ArgumentParser:
    """The command line of `mvpose-images`."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n')[0])
    rig = p.add_mutually_exclusive_group(required=True)
    rig.add_argument('--rig', type=Path, help='rig file (YAML, with every camera\'s intrinsics; see '
                                              'docs/own_cameras.md): the images must have the sizes it gives')
    rig.add_argument('--calibration', type=Path, help='calibration json (Shelf layout): each camera at the size of '
                                                      'its image')
    p.add_argument('--images', required=True, nargs='+', type=Path,
                   help=f'one image per camera, in the rig\'s camera order; {NO_IMAGE} for a camera without one '
                        '(left out of the set, as a camera that sent nothing)')
    p.add_argument('--output', type=Path, default=Path('out/images'), help='folder for skeletons.jsonl and '
                   'the overlays (default: out/images)')
    p.add_argument('--frame', type=int, default=0, help='frame number written with the skeletons (default: 0)')
    p.add_argument('--data-root', help='folder holding data/ and models/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--models', type=Path, help='folder of the .onnx files (default: <data root>/models)')
    p.add_argument('--sets', type=int, default=1, help='detect the images this many times as a sequence (default: 1)')
    add_parameter_options(p, ONNX_PARAMETERS)
    p.add_argument('--head-model', choices=HEAD_MODELS, default=HEAD_MODEL,
                   help=f'{SOLVER_PARAMETERS["head_model"]} (default: {HEAD_MODEL})')
    p.add_argument('--ground-truth', choices=('shelf',),
                   help="score the frame against this dataset's actorsGT (--frame is its frame index)")
    return p


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    """Do what the parsed command line `args` of `mvpose-images` says; returns the exit code."""
    out = out or sys.stdout
    if args.sets < 1:
        raise ValueError(f'--sets {args.sets} must be >= 1')
    cameras, up, images = rig_and_images(args.rig, args.calibration, args.images, args.data_root)
    models = args.models or data_root(args.data_root) / 'models'
    settings = DetectorConfig.from_params(parameter_values(args, ONNX_PARAMETERS), models)
    detector = OnnxPoseDetector(settings.onnx)
    planner = CropPlanner(cameras, settings.person_detector_every)
    # warm-up: onnxruntime's first run allocates; not a steady-state latency
    detector.detect(next(im for im in images if im is not None))
    turns = [upright_turns(cam.R, up) if settings.upright else 0 for cam in cameras]
    onnx = settings.onnx
    source = 'MultiPose keypoints' if onnx.heatmaps == 'multipose' else f'{onnx.heatmaps} {onnx.model.upper()}'
    print(f'{PROG}: {len(cameras)} cameras, heatmaps {source}, MultiPose input '
          f'{onnx.input_size} px, {",".join(detector.providers)}', file=out)
    stage = Stage3D(cameras, stage_config(args.sets, args.head_model), up)
    gt = (load_actors_gt(dataset_dir('shelf', args.data_root) / 'actorsGT.mat', [args.frame])
          if args.ground_truth == 'shelf' else None)
    result, people = detect_sets(detector, planner, stage, images, turns, args.sets, args.frame, gt, out)
    write_outputs(args.output, result, cameras, images, people, gt, out)
    if gt is not None:
        score(result, gt, out)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-images`; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (OSError, ValueError) as exc:  # ModelError is a ValueError: a missing or wrong model file
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
