"""One synchronised set of a calibrated rig's images through the onnx detector and the 3D stage,
as mvpose-images runs it: once, or N times as a still sequence of sets solved as the rig graph's
bp_solver solves it (each set's stage times printed); the skeletons and overlays written, and the
frame scored against a dataset's annotation."""
from __future__ import annotations

import queue
import threading
import time
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Iterator, Sequence, TextIO

import cv2
import numpy as np

from mvpose_ros.core.detection.image_file import read_image
from mvpose_ros.core.detection.onnx_detector import OnnxPoseDetector, PendingSet
from mvpose_ros.core.detection.tracked_crops import CropPlanner
from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.overlay import overlay
from mvpose_ros.core.evaluation.pcp import FORMS, evaluate, format_table, match_actors
from mvpose_ros.core.evaluation.predictions import frame_line
from mvpose_ros.core.geometry.body import JOINT_NAMES, NUM_JOINTS, UP
from mvpose_ros.core.geometry.camera import Camera, load_rig
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.core.stage import Stage3D, StageConfig
from mvpose_ros.core.types import FrameResult, Person2D
from mvpose_ros.graph.config import RIG_TEMPLATE, load_params, node_section
from mvpose_ros.package_files import package_path

NO_IMAGE = '-'  # among the image paths: this camera has no image in the set


def rig_and_images(rig_file: Path | None, calibration: Path | None, paths: Sequence[Path],
                   root: str | None = None) -> tuple[list[Camera], np.ndarray, list[np.ndarray | None]]:
    """The cameras of a rig file or (without one) a calibration json, the rig's up (3,), and each
    camera's image of `paths` (None for NO_IMAGE): checked against the sizes a rig file gives, or
    giving a calibration json (which records neither: +z up) each camera its image's size (a
    camera without one: the first image's). root: the data root (None: the default)."""
    given = [str(path) != NO_IMAGE for path in paths]
    if sum(given) < 2:
        raise ValueError(f'--images: {sum(given)} of {len(given)} cameras have an image; 3D needs at least two')
    if rig_file is not None:
        rig = load_rig_file(rig_file, data_root=partial(data_root, root))
        cameras = rig.calibrated_cameras()
        _same_count(paths, cameras)
        images = [read_image(path, cam) if has else None for path, cam, has in zip(paths, cameras, given)]
        return cameras, rig.up, images
    images = [read_image(path) if has else None for path, has in zip(paths, given)]
    height, width = next(im for im in images if im is not None).shape[:2]
    cameras = load_rig(calibration, width, height)
    _same_count(paths, cameras)
    return [cam if im is None else replace(cam, width=im.shape[1], height=im.shape[0])
            for cam, im in zip(cameras, images)], UP, images


def _same_count(paths: Sequence[Path], cameras: Sequence[Camera]) -> None:
    if len(paths) != len(cameras):
        raise ValueError(f'--images: {len(paths)} images for {len(cameras)} cameras in the rig')


def stage_config(sets: int, head_model: str) -> StageConfig:
    """One set: the clip of one frame, BP from scratch. A sequence: the rig graph's bp_solver
    parameters (a set solved with at most `window` - 1 before it, so that a set's 3D stage does
    not grow with the sequence)."""
    if sets == 1:
        return StageConfig.from_params({'window': 0, 'head_model': head_model})
    solver = node_section([load_params(package_path(RIG_TEMPLATE))], 'bp_solver')
    return StageConfig.from_params({**solver, 'head_model': head_model})


def detect_sets(detector: OnnxPoseDetector, planner: CropPlanner, stage: Stage3D, images: list[np.ndarray | None],
                turns: list[int], sets: int, frame: int, gt: GroundTruth | None,
                out: TextIO) -> tuple[FrameResult, list[list[Person2D] | None]]:
    """The images detected `sets` times as a sequence of sets and solved by `stage`, each set's
    stage times (and with gt, its MPJPE) printed, and with more than one set their medians and
    the sets per second; the last set's 3D result (numbered `frame`) and 2D people."""
    nobody = FrameResult(frame, [], np.zeros((0, NUM_JOINTS, 3)), np.zeros((0, NUM_JOINTS)))
    # With MultiPose on every set, the next set's runs start while this one finishes (its people
    # and 3D stage): crops from skeletons would need this set's 3D first.
    ahead = _started_ahead(detector, images, sets, turns) if planner.every == 1 else None
    times = []
    first = time.perf_counter()
    for n in range(sets):
        plan = planner.plan()
        pending = next(ahead) if ahead is not None else detector.start_set(images, plan, planner.previous, turns=turns)
        people = detector.finish(pending)
        detected = time.perf_counter()
        results = stage.push(frame + n, people) + stage.flush()
        result = replace(results[0], frame=frame) if results else nobody
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
    if sets > 1:
        median = 1e3 * np.median(np.array(times), axis=0)
        print(f'median of {sets} sets: MultiPose {median[0]:.1f} ms, crop model {median[1]:.1f} ms, heatmaps '
              f'{median[2]:.1f} ms, association and 3D {median[3]:.1f} ms, total {median[4]:.1f} ms; '
              f'{sets / (time.perf_counter() - first):.2f} sets/s', file=out)
    return result, people


def write_outputs(output: Path, result: FrameResult, cameras: Sequence[Camera], images: list[np.ndarray | None],
                  people: list[list[Person2D] | None], gt: GroundTruth | None, out: TextIO) -> None:
    """`output`/skeletons.jsonl (the result as one predictions line) and an overlay cam<c>.png per
    camera with an image: the reprojected skeletons over its 2D people (and gt's annotated poses)."""
    output.mkdir(parents=True, exist_ok=True)
    (output / 'skeletons.jsonl').write_text(frame_line(result) + '\n', encoding='utf-8')
    colours = [person_colour(pid) for pid in result.person_ids]
    actors, truth = gt.annotated(0) if gt is not None else ((), None)
    drawn = [c for c, bgr in enumerate(images) if bgr is not None]
    for c in drawn:
        path = output / f'cam{c}.png'
        if not cv2.imwrite(str(path), overlay(images[c], cameras[c], people[c], result.joints, colours, truth, actors)):
            raise OSError(f'{path}: could not write the overlay')
    print(f'wrote {output / "skeletons.jsonl"} and {len(drawn)} overlays '
          f'{", ".join(f"cam{c}.png" for c in drawn)}', file=out)


def score(result: FrameResult, gt: GroundTruth, out: TextIO) -> None:
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
