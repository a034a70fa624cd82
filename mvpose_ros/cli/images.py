"""`mvpose-images`: 3D skeletons from one synchronised set of camera images of a calibrated rig.

    mvpose-images (--rig FILE | --calibration FILE) --images CAM0 CAM1 ... [--output DIR] [--frame N]
                  [--model rt|i|lightning|thunder|blazepose_full|blazepose_heavy] [--crop-workers W]
                  [--head-model anatomical|direct] [--ground-truth shelf] [--data-root DIR]
                  [--sets N] [--person-detector-every K] [--max-batch B] [--threads T]
                  [--heatmaps efficientpose|multipose|fused] [--keypoint-sigma F] [--multipose-workers W]

Detects the 2D people of every image with the ONNX backend (MoveNet MultiPose, and EfficientPose
with --heatmaps efficientpose or fused), associates them across the cameras, samples the 3D
hypotheses and runs BP on this one frame, and writes the skeletons as one predictions line
(`<output>/skeletons.jsonl`) and one overlay PNG per camera (`<output>/cam<c>.png`: the
reprojected 3D skeletons in each person's colour over the 2D detections in thin white; with
--ground-truth shelf also the frame's annotated poses, thin yellow, labelled `GT <actor>`). A camera
given `-` instead of an image is left out, as a camera that sent nothing (what a rig gives with
one of its cameras down). Prints the time of each stage of the set (MultiPose, EfficientPose,
heatmaps, association and 3D); with --ground-truth shelf, the per-actor MPJPE and PCP of the
frame against Shelf's actorsGT, and each actor's error per joint.

--sets N detects the same images N times as a sequence of sets (a still scene) and prints each
set's stage times (total: from the set's start to its skeletons), their medians and the sets per
second of the whole sequence; the sequence is solved as the rig graph's bp_solver solves it
(config/rig_template.yaml: a sliding window of sets, warm-started, the newest set out), so every
set costs what it would there. MultiPose's runs of a set start while the set before finishes
(OnnxPoseDetector.start_set: a worker the set's last image leaves idle takes the next set's
first). With --person-detector-every K, MultiPose searches the whole image of every K-th set only;
in the sets between, the previous set's 3D skeletons projected into each camera say where its
people are (core.detection.tracked_crops; a set then starts once the one before is solved): with --heatmaps
multipose MultiPose searches only the region around them, with a smaller input at the same scale;
with efficientpose they are the crops of the crop model (--model: EfficientPose, or a
single-person keypoint model; docs/crop_models.md) and MultiPose does not run (but on a camera
where it last found someone the skeletons do not explain). The files written and
the score are those of the last set.

--heatmaps multipose (the default) renders MultiPose's own keypoints as Gaussians (std
--keypoint-sigma times the person's box diagonal) and runs no EfficientPose (fused takes both;
core.detection.onnx_detector).
"""
from __future__ import annotations

import argparse
import queue
import sys
import threading
import time
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Iterator, Sequence, TextIO

import cv2
import numpy as np

from mvpose_ros.core.geometry.body import HEAD_MODELS, JOINT_NAMES, NUM_JOINTS, UP
from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.core.datasets.shelf_campus import GroundTruth, dataset_dir, load_actors_gt
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.evaluation.pcp import FORMS, evaluate, format_table, match_actors
from mvpose_ros.core.detection.image_file import read_image
from mvpose_ros.core.detection.onnx_config import HEATMAP_SOURCES, MODELS, OnnxDetectorConfig
from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector, PendingSet
from mvpose_ros.core.detection.tracked_crops import CropPlanner
from mvpose_ros.core.detection.upright import UPRIGHT, upright_turns
from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.overlay import overlay
from mvpose_ros.core.stage import StageConfig, Stage3D
from mvpose_ros.core.evaluation.predictions import frame_line
from mvpose_ros.core.types import FrameResult
from mvpose_ros.graph.config import RIG_TEMPLATE, load_params, node_section
from mvpose_ros.package_files import package_path

PROG = 'mvpose-images'
NO_IMAGE = '-'  # in --images: this camera has no image in the set
DEFAULTS = OnnxDetectorConfig(model_dir=Path())


def build_parser() -> argparse.ArgumentParser:
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
    p.add_argument('--model', choices=MODELS, default=DEFAULTS.model,
                   help='the model on each person crop (--heatmaps efficientpose or fused): EfficientPose rt or i '
                        '(heatmaps), or a single-person keypoint model, MoveNet lightning or thunder, BlazePose '
                        f'blazepose_full or blazepose_heavy (keypoints as Gaussians; docs/crop_models.md) '
                        f'(default: {DEFAULTS.model})')
    p.add_argument('--crop-workers', type=int, default=DEFAULTS.crop_workers,
                   help='single-person keypoint models: crops run at once, each with --threads intra-op threads '
                        f'(default: {DEFAULTS.crop_workers})')
    p.add_argument('--providers', nargs='+', default=list(DEFAULTS.providers),
                   help='onnxruntime execution providers (default: CPUExecutionProvider)')
    p.add_argument('--input-size', type=int, default=DEFAULTS.input_size,
                   help='MultiPose input side, a multiple of 32 (default: 384)')
    p.add_argument('--threads', type=int, default=DEFAULTS.threads,
                   help='onnxruntime intra-op threads per model (default: 0, one per core)')
    p.add_argument('--max-batch', type=int, default=DEFAULTS.max_batch,
                   help=f'EfficientPose crops per run, 0 = all crops of the set in one (default: {DEFAULTS.max_batch})')
    p.add_argument('--multipose-workers', type=int, default=DEFAULTS.multipose_workers,
                   help='images MultiPose runs on at once, each with --threads intra-op threads (default: '
                        f'{DEFAULTS.multipose_workers}; on two cores 2 with --threads 1 was faster)')
    p.add_argument('--sets', type=int, default=1, help='detect the images this many times as a sequence (default: 1)')
    p.add_argument('--person-detector-every', type=int, default=1,
                   help='run MultiPose on the whole image of every K-th set only; between, where the previous '
                        "set's 3D skeletons project: MultiPose on that region (heatmaps multipose) or EfficientPose "
                        'on those crops (default: 1, every set)')
    p.add_argument('--heatmaps', choices=HEATMAP_SOURCES, default=DEFAULTS.heatmaps,
                   help="heatmap source: EfficientPose on crops, MultiPose's keypoints as Gaussians, or both fused "
                        f'(default: {DEFAULTS.heatmaps})')
    p.add_argument('--keypoint-sigma', type=float, default=DEFAULTS.keypoint_sigma,
                   help="multipose, fused: std of the Gaussians of MultiPose's keypoints, as a fraction of the "
                        f"person's box diagonal (default: {DEFAULTS.keypoint_sigma:g})")
    p.add_argument('--stride', type=float, default=DEFAULTS.stride, help='heatmap cell size, pixels (default: 4)')
    p.add_argument('--no-ears', dest='ears', action='store_false',
                   help="leave the ear joints empty instead of taking MultiPose's COCO ears")
    p.add_argument('--tile-levels', type=int, default=DEFAULTS.tile_levels,
                   help='a MultiPose run that comes back full (6 people) is repeated on two overlapping halves of '
                        f'what it searched, at most this many levels deep (crowds; 0: never; default: '
                        f'{DEFAULTS.tile_levels})')
    p.add_argument('--no-upright', dest='upright', action='store_false', default=UPRIGHT,
                   help='detect in every image as it comes, not turned by quarter turns so that the people of a '
                        "camera mounted on its side or upside down stand up (from its orientation and the rig's up)")
    p.add_argument('--head-model', choices=HEAD_MODELS, default='anatomical',
                   help='how the head joints are derived in 3D (default: anatomical, from the COCO ears and the '
                        'MPII upper neck; direct: MPII upper neck and head top)')
    p.add_argument('--ground-truth', choices=('shelf',),
                   help="score the frame against this dataset's actorsGT (--frame is its frame index)")
    return p


def _rig_and_images(args: argparse.Namespace) -> tuple[list[Camera], np.ndarray, list[np.ndarray | None]]:
    """The rig's cameras, its up (3,) and the images (None for a camera given NO_IMAGE): checked
    against the sizes a rig file gives, or giving a calibration json (which records neither: +z
    up) each camera its image's size (a camera without one: the first image's)."""
    given = [str(path) != NO_IMAGE for path in args.images]
    if sum(given) < 2:
        raise ValueError(f'--images: {sum(given)} of {len(given)} cameras have an image; 3D needs at least two')
    if args.rig is not None:
        rig = load_rig_file(args.rig, data_root=partial(data_root, args.data_root))
        cameras = rig.calibrated_cameras()
        _same_count(args.images, cameras)
        return cameras, rig.up, [read_image(path, cam) if has else None
                                 for path, cam, has in zip(args.images, cameras, given)]
    images = [read_image(path) if has else None for path, has in zip(args.images, given)]
    height, width = next(im for im in images if im is not None).shape[:2]
    cameras = load_rig(args.calibration, width, height)
    _same_count(args.images, cameras)
    return [cam if im is None else replace(cam, width=im.shape[1], height=im.shape[0])
            for cam, im in zip(cameras, images)], UP, images


def _same_count(paths: Sequence[Path], cameras: Sequence[Camera]) -> None:
    if len(paths) != len(cameras):
        raise ValueError(f'--images: {len(paths)} images for {len(cameras)} cameras in the rig')


def _score(result: FrameResult, gt: GroundTruth, out: TextIO) -> None:
    """Per-actor MPJPE and PCP of this frame against Shelf's actorsGT, for every actor annotated in
    it (the standard Shelf protocol scores actors 1-3 over frames 300-600, but one frame can lack
    one of them and show actor 4: frame 572 annotates actors 1, 3 and 4), and each actor's error
    per joint: where an estimate and the annotation part, the overlays show which one the image
    agrees with. gt: actorsGT at result's frame alone."""
    actors = gt.annotated(0)[0].tolist()
    if not actors:
        print(f'ground truth: no actor is annotated in Shelf frame {result.frame}', file=out)
        return
    predictions = {result.frame: result.joints}
    ev = evaluate(predictions, gt, actors)
    print(format_table(ev), file=out)
    joint_mm = 1e3 * match_actors(predictions, gt, actors).joint_err[0]  # (A, 14)
    for a, actor in enumerate(ev.actors):
        found = 'found' if ev.missed[a] == 0 else 'NOT found'
        pcp = ', '.join(f'PCP {form} {ev.pcp(form, actor):.1f}%' for form in FORMS)
        print(f'Actor {actor + 1}: {found}, MPJPE {ev.mpjpe[a]:.1f} mm, {pcp}', file=out)
        if ev.missed[a] == 0:
            print(f'Actor {actor + 1} per joint (mm): '
                  + ', '.join(f'{name} {e:.0f}' for name, e in zip(JOINT_NAMES, joint_mm[a])), file=out)


def _mpjpe(result: FrameResult, gt: GroundTruth) -> str:
    """Each annotated actor's MPJPE in this frame (gt: actorsGT at it alone), one short line
    ('actor 1 65.6 mm, ...')."""
    actors = gt.annotated(0)[0].tolist()
    if not actors:
        return 'no actor annotated'
    ev = evaluate({result.frame: result.joints}, gt, actors)
    return ', '.join(f'actor {a + 1} {m:.1f} mm' for a, m in zip(ev.actors, ev.mpjpe))


def stage_config(sets: int, head_model: str) -> StageConfig:
    """One set: the clip of one frame, BP from scratch. A sequence: the rig graph's bp_solver
    parameters (a set solved with at most `window` - 1 before it; solving the whole clip so far
    again at every set made a set's 3D stage grow from about 25 ms to 100-175 ms over 20 sets)."""
    if sets == 1:
        return StageConfig.from_params({'window': 0, 'head_model': head_model})
    solver = node_section([load_params(package_path(RIG_TEMPLATE))], 'bp_solver')
    return StageConfig.from_params({**solver, 'head_model': head_model})


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    if args.sets < 1:
        raise ValueError(f'--sets {args.sets} must be >= 1')
    cameras, up, images = _rig_and_images(args)
    models = args.models or data_root(args.data_root) / 'models'
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=models, model=args.model, providers=tuple(args.providers),
                                                   threads=args.threads, input_size=args.input_size,
                                                   crop_workers=args.crop_workers,
                                                   stride=args.stride, ears=args.ears, max_batch=args.max_batch,
                                                   keypoint_sigma=args.keypoint_sigma, heatmaps=args.heatmaps,
                                                   multipose_workers=args.multipose_workers,
                                                   tile_levels=args.tile_levels))
    planner = CropPlanner(cameras, args.person_detector_every)
    # warm-up: onnxruntime's first run allocates; not a steady-state latency
    detector.detect(next(im for im in images if im is not None))
    turns = [upright_turns(cam.R, up) if args.upright else 0 for cam in cameras]
    source = 'MultiPose keypoints' if args.heatmaps == 'multipose' else f'{args.heatmaps} {args.model.upper()}'
    print(f'{PROG}: {len(cameras)} cameras, heatmaps {source}, MultiPose input '
          f'{args.input_size} px, {",".join(detector.providers)}', file=out)
    stage = Stage3D(cameras, stage_config(args.sets, args.head_model), up)
    gt = (load_actors_gt(dataset_dir('shelf', args.data_root) / 'actorsGT.mat', [args.frame])
          if args.ground_truth == 'shelf' else None)
    nobody = FrameResult(args.frame, [], np.zeros((0, NUM_JOINTS, 3)), np.zeros((0, NUM_JOINTS)))
    # With MultiPose on every set, the next set's runs start while this one finishes (its people
    # and 3D stage): crops from skeletons would need this set's 3D first.
    ahead = _started_ahead(detector, images, args.sets, turns) if planner.every == 1 else None
    times = []
    first = time.perf_counter()
    for n in range(args.sets):
        plan = planner.plan()
        pending = next(ahead) if ahead is not None else detector.start_set(images, plan, planner.previous, turns=turns)
        people = detector.finish(pending)
        detected = time.perf_counter()
        results = stage.push(args.frame + n, people) + stage.flush()
        result = replace(results[0], frame=args.frame) if results else nobody
        planner.update(plan, people)
        planner.skeletons(result.joints, np.asarray(result.person_ids))
        end = time.perf_counter()
        t = detector.timing
        times.append((t.multipose, t.efficientpose, t.heatmaps, end - detected, end - pending.started))
        found = ' '.join(f'cam{c}:{NO_IMAGE if p is None else len(p)}' for c, p in enumerate(people))
        scored = f'; MPJPE {_mpjpe(result, gt)}' if gt is not None else ''
        regions = f' ({t.multipose_regions} regions)' if t.multipose_regions else ''
        regions += f' (+{t.crowd_tiles} crowd tiles)' if t.crowd_tiles else ''
        print(f'set {n}: MultiPose on {t.multipose_runs} images{regions} {1e3 * t.multipose:6.1f} ms, crop model '
              f'{t.people} people {1e3 * t.efficientpose:6.1f} ms, heatmaps {1e3 * t.heatmaps:5.1f} ms, '
              f'association and 3D {1e3 * (end - detected):5.1f} ms, total {1e3 * times[-1][4]:6.1f} ms; people '
              f'{found}; {len(result.person_ids)} in 3D{scored}', file=out)
    if args.sets > 1:
        median = 1e3 * np.median(np.array(times), axis=0)
        print(f'median of {args.sets} sets: MultiPose {median[0]:.1f} ms, crop model {median[1]:.1f} ms, heatmaps '
              f'{median[2]:.1f} ms, association and 3D {median[3]:.1f} ms, total {median[4]:.1f} ms; '
              f'{args.sets / (time.perf_counter() - first):.2f} sets/s', file=out)

    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / 'skeletons.jsonl').write_text(frame_line(result) + '\n', encoding='utf-8')
    colours = [person_colour(pid) for pid in result.person_ids]
    actors, truth = gt.annotated(0) if gt is not None else ((), None)
    drawn = [c for c, bgr in enumerate(images) if bgr is not None]
    for c in drawn:
        cam, bgr, path = cameras[c], images[c], args.output / f'cam{c}.png'
        if not cv2.imwrite(str(path), overlay(bgr, cam, people[c], result.joints, colours, truth, actors)):
            raise OSError(f'{path}: could not write the overlay')
    print(f'wrote {args.output / "skeletons.jsonl"} and {len(drawn)} overlays '
          f'{", ".join(f"cam{c}.png" for c in drawn)}', file=out)
    if gt is not None:
        _score(result, gt, out)
    return 0


def _started_ahead(detector: OnnxPoseDetector, images: list[np.ndarray | None], sets: int,
                   turns: list[int]) -> Iterator[PendingSet]:
    """`sets` sets of the same images, each started (OnnxPoseDetector.start_set) by a feeder thread
    as soon as MultiPose has a worker free for it, one set at most waiting started."""
    ready: queue.Queue[PendingSet | Exception] = queue.Queue(maxsize=1)

    def feed() -> None:
        try:
            for _ in range(sets):
                ready.put(detector.start_set(images, turns=turns))
        except Exception as exc:  # handed to the consumer, which raises it
            ready.put(exc)

    threading.Thread(target=feed, name='start_sets', daemon=True).start()
    for _ in range(sets):
        item = ready.get()
        if isinstance(item, Exception):
            raise item
        yield item


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (OSError, ValueError) as exc:  # ModelError is a ValueError: a missing or wrong model file
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
