"""What goes into each bag the project ships recipes for, built from the real data.

- `shelf`: Shelf test frames 300..600, per camera c `/cam{c}/camera_info` and `/cam{c}/openpose`
  (the real OpenPose BODY25 output, encoding A), plus `/cam{c}/image_raw` for frame 572, the one
  frame whose real images are available.
- `shelf_images`: frame 572 only, images and camera infos (input of image-based 2D backends).
- `campus`: a user's CampusSeq1 folder; per test frame with images, `/cam{c}/image_raw`,
  `/cam{c}/camera_info` and the annotated actors on `/ground_truth/skeletons` (encoding D,
  person id = actor index).

Frame f is stamped f / 25 s and logged at that time; camera c is rig index c (load_rig order).
A recipe also names the files it reads, so a bag can tell whether it is still up to date.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import camera_to_info
from msg_adapters.image_msg import image_to_msg
from msg_adapters.openpose_msg import openpose_to_msg
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.core.detection.image_file import read_image
from mvpose_ros.core.evaluation.datasets import (CAMPUS_TEST_FRAMES, SHELF_TEST_FRAMES, dataset_cameras, dataset_dir,
                                                 load_actors_gt)
from mvpose_ros.core.detection.openpose import read_body25

# Part of every bag's fingerprint: bump it when a recipe's output changes for the same inputs,
# so bags made by older code count as out of date.
RECIPE_VERSION = 1
RECIPES = ('shelf', 'shelf_images', 'campus')
SHELF_IMAGE_FRAMES = (572,)
GROUND_TRUTH_TOPIC = '/ground_truth/skeletons'

Item = tuple[str, Any, int]  # (topic, rclpy message, log stamp ns)


@dataclass(frozen=True)
class Recipe:
    """A bag's content: its name, the files it is made from, and its messages in log-time order."""

    name: str
    inputs: tuple[Path, ...]
    items: Callable[[], Iterator[Item]]

    def fingerprint(self) -> str:
        """Hash of the recipe version and each input's path, size and modification time."""
        h = hashlib.sha256(f'{self.name} v{RECIPE_VERSION}'.encode())
        for path in self.inputs:
            st = path.stat()
            h.update(f'\n{path.resolve()} {st.st_size} {st.st_mtime_ns}'.encode())
        return h.hexdigest()


def make_recipe(name: str, data_root: str | None = None, campus_dir: str | Path | None = None) -> Recipe:
    """The recipe `name` (one of RECIPES); campus needs campus_dir, the others the data root."""
    if name == 'campus':
        if campus_dir is None:
            raise ValueError('the campus bag needs a CampusSeq1 folder (--campus-dir)')
        return campus_recipe(campus_dir)
    if name in ('shelf', 'shelf_images'):
        return shelf_recipe(dataset_dir('shelf', data_root), images_only=name == 'shelf_images')
    raise ValueError(f'recipe must be one of {", ".join(RECIPES)}; got {name!r}')


def _require(*paths: Path) -> None:
    for path in paths:
        if not path.is_file():
            raise FileNotFoundError(f'{path}: missing')


def _headers(frame: int, n_cameras: int) -> tuple[int, list[Header]]:
    """Log stamp (ns) and one header per camera of `frame`."""
    stamp = stamp_of_frame(frame)
    return stamp_ns(stamp), [Header(stamp=stamp, frame_id=f'cam{c}') for c in range(n_cameras)]


def shelf_recipe(shelf: Path, images_only: bool = False) -> Recipe:
    """The `shelf` bag (or `shelf_images` with images_only) from the Shelf folder `shelf`."""
    calibration = shelf / 'calibration' / 'calibration_shelf.json'
    _require(calibration)
    rig = dataset_cameras('shelf', calibration=calibration)
    images = {(f, c): shelf / 'frames' / f'cam{c}_{f:06d}.png'
              for f in SHELF_IMAGE_FRAMES for c in range(len(rig))}
    detections = [] if images_only else [shelf / 'openpose_body25' / f'{c}.txt' for c in range(len(rig))]
    _require(*images.values(), *detections)
    frames: Sequence[int] = SHELF_IMAGE_FRAMES if images_only else SHELF_TEST_FRAMES

    def items() -> Iterator[Item]:
        openpose = [read_body25(path, cam.width, cam.height) for path, cam in zip(detections, rig)]
        for path, frames_of_camera in zip(detections, openpose):
            if len(frames_of_camera) != len(SHELF_TEST_FRAMES):
                raise ValueError(f'{path}: {len(frames_of_camera)} frames, expected '
                                 f'{len(SHELF_TEST_FRAMES)} (Shelf test frames)')
        for f in frames:
            ns, headers = _headers(f, len(rig))
            for c, cam in enumerate(rig):
                yield f'/cam{c}/camera_info', camera_to_info(cam, headers[c]), ns
            if f in SHELF_IMAGE_FRAMES:
                for c, cam in enumerate(rig):
                    yield f'/cam{c}/image_raw', image_to_msg(read_image(images[f, c], cam), headers[c]), ns
            for c, frames_of_camera in enumerate(openpose):
                yield f'/cam{c}/openpose', openpose_to_msg(frames_of_camera[f - SHELF_TEST_FRAMES.start],
                                                           headers[c]), ns

    name = 'shelf_images' if images_only else 'shelf'
    return Recipe(name, (calibration, *images.values(), *detections), items)


def campus_image(campus_dir: Path, camera: int, frame: int) -> Path:
    """Where CampusSeq1 keeps camera `camera`'s image of `frame`."""
    return campus_dir / f'Camera{camera}' / f'campus4-c{camera}-{frame:05d}.png'


def campus_recipe(campus_dir: str | Path) -> Recipe:
    """The `campus` bag from a CampusSeq1 folder (Camera{c}/ images, actorsGT.mat,
    calibration_campus.json); test frames without any image are left out."""
    campus_dir = Path(campus_dir)
    if not campus_dir.is_dir():
        raise FileNotFoundError(f'CampusSeq1 folder not found: {campus_dir}')
    gt_path, calibration = campus_dir / 'actorsGT.mat', campus_dir / 'calibration_campus.json'
    _require(gt_path, calibration)
    rig = dataset_cameras('campus', calibration=calibration)
    present = {f: [c for c in range(len(rig)) if campus_image(campus_dir, c, f).is_file()]
               for f in CAMPUS_TEST_FRAMES}
    frames = [f for f in CAMPUS_TEST_FRAMES if present[f]]
    if not frames:
        raise FileNotFoundError(f'{campus_dir}: no test frame images (expected e.g. '
                                f'{campus_image(campus_dir, 0, CAMPUS_TEST_FRAMES[0])})')
    try:
        gt = load_actors_gt(gt_path, frames)
    except IndexError as exc:
        raise ValueError(str(exc)) from None
    inputs = (gt_path, calibration, *(campus_image(campus_dir, c, f) for f in frames for c in present[f]))

    def items() -> Iterator[Item]:
        for i, f in enumerate(frames):
            ns, headers = _headers(f, len(rig))
            for c, cam in enumerate(rig):
                yield f'/cam{c}/camera_info', camera_to_info(cam, headers[c]), ns
            for c in present[f]:
                yield f'/cam{c}/image_raw', image_to_msg(read_image(campus_image(campus_dir, c, f), rig[c]),
                                                         headers[c]), ns
            here = gt.present[i]
            yield GROUND_TRUTH_TOPIC, skeletons_to_msg(np.flatnonzero(here), gt.poses[i, here],
                                                       Header(stamp=headers[0].stamp, frame_id='world')), ns

    return Recipe('campus', inputs, items)
