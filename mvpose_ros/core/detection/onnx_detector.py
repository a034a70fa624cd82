"""The onnx backend of the heatmap detector: 2D people with per-joint heatmaps from camera images,
MoveNet MultiPose finding the people and (heatmaps 'efficientpose' or 'fused') a crop model giving
each person's joints, on onnxruntime. How it works is OnnxPoseDetector's docstring; what its
settings cost and gain: docs/own_cameras.md (Crowds, Heatmap source) and docs/crop_models.md.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from mvpose_ros.core.geometry.body import (L_EAR, NECK, NUM_INFERENCE_JOINTS, R_EAR, SOURCE_INDEX,
                                           to_inference)
from mvpose_ros.core.heatmap import MARGIN_SIGMAS, PersonHeatmap, render_heatmaps
from mvpose_ros.core.detection.letterbox import Letterbox, letterbox, whole_image
from mvpose_ros.core.detection.onnx_config import OnnxDetectorConfig
from mvpose_ros.core.detection.onnx_models import EFFICIENTPOSE, MULTIPOSE, SINGLE_POSE
from mvpose_ros.core.detection.onnx_sessions import check_providers, load_session
from mvpose_ros.core.detection.single_person import SinglePoseModel
from mvpose_ros.core.detection.tracked_crops import carried_ears, grown_boxes, people_region
from mvpose_ros.core.types import Person2D

# EfficientPose's input normalisation (ImageNet mean and std of RGB in [0, 1])
_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)
_EARS = (R_EAR, L_EAR)
# the joints 'fused' fuses: the limbs; MPII's upper neck and head top are other points than COCO's
# shoulder midpoint and nose
_LIMBS = np.arange(NUM_INFERENCE_JOINTS) < NECK
_MULTIPOSE_KEYPOINTS = 17
# A shrunk image keeps at least this many of its pixels per MultiPose input pixel along the long
# side (reduced_decoding; what one pixel fewer moves the keypoints: docs/own_cameras.md, JPEG decoding)
SHRUNK_OVERSAMPLING = 2
# Two people of one camera closer than this fraction of their size are one (without_duplicates):
# real neighbours' keypoints, even overlapping, lie far apart for most joints.
DUPLICATE_SEPARATION = 0.1
# Crowd tiles: each of the two covers this share of the part searched along its long side, so they
# overlap by a quarter of it: a person up to a quarter as wide as the part lies wholly in one. The
# short side is not cut: people stand across it in most views.
TILE_SHARE = 0.625


@dataclass
class DetectionTiming:
    """Wall seconds of the last set detected (detect, detect_set or finish): MultiPose (from the
    set's start to its last run's end: letterbox, waiting for a worker, runs, decode), EfficientPose
    (crops and runs), heatmaps (finish's own work besides EfficientPose: keypoints, Gaussians,
    resampling), and total, from the start to the people; people found, the images MultiPose
    ran on (the others' crops were given), of those the ones it searched in a region only, and
    the extra runs on crowd tiles."""

    multipose: float = 0.0
    efficientpose: float = 0.0
    heatmaps: float = 0.0
    total: float = 0.0
    people: int = 0
    multipose_runs: int = 0
    multipose_regions: int = 0
    crowd_tiles: int = 0


@dataclass
class _Found:
    """MultiPose's people in the camera's pixels: keypoints (P, 17, 3) u, v, score; boxes (P, 4)
    u0, v0, u1, v1 (edges, pixel-centre coordinates); bounds: (4,) the edges of the part of the
    image searched (the whole image, or a region); done: time.perf_counter() when the run ended."""

    keypoints: np.ndarray
    boxes: np.ndarray
    bounds: np.ndarray
    done: float
    runs: int = 1  # MultiPose runs it took (more for a crowd's tiles)


@dataclass
class PendingSet:
    """A set OnnxPoseDetector.start_set has started: its images, boxes and previous people as
    given, each camera's (width, height) and its camera pixels per image pixel (2,) u, v (None:
    the image is at the camera's size), MultiPose's runs on the images it searches (in camera
    order), and when it started."""

    images: list[np.ndarray | None]
    boxes: list[np.ndarray | None]
    sizes: list[tuple[int, int] | None]
    shrinks: list[np.ndarray | None]
    previous: Sequence[np.ndarray] | None
    turns: list[int]
    finds: list[Future[_Found]]
    regions: int
    started: float


@dataclass
class _Crop:
    """One EfficientPose crop: its camera, letterbox, and MultiPose's keypoints of the person as
    inference joints (16, 3) u, v, score, or None (given boxes: the ears are carried from the
    camera's previous people), with the std of their Gaussians (px)."""

    camera: int
    box: Letterbox
    keypoints: np.ndarray | None
    sigma: float


class OnnxPoseDetector:
    """The sessions are created (and checked) once, here (EfficientPose's not with heatmaps
    'multipose'); detect() runs them on one image, detect_set() on a synchronised set, and
    start_set() / finish() on a sequence of sets, one starting while the one before finishes.

    MultiPose finds the people (boxes and COCO-17 keypoints) in the whole letterboxed frame (its
    batch dimension is fixed at 1: one run per image), then the crop model (`model`) gives each
    person's joints on a letterboxed crop around its box: EfficientPose 'rt' or 'i' MPII-16
    heatmaps, in runs of at most `max_batch` crops over every camera of a set; or a single-person
    keypoint model (single_person.SINGLE_POSE: MoveNet, BlazePose), each crop's COCO-17 keypoints
    rendered as Gaussians of std `keypoint_sigma` times the box diagonal, one crop per run,
    `crop_workers` at once. A camera can be given crops instead (tracked_crops: the previous
    set's skeletons projected into it): MultiPose does not run on its image, and its people's
    ears are carried from the camera's previous people.

    Crowds: MultiPose returns at most 6 people a run. A run that returns 6 all scoring at least
    `min_person_score` is repeated on two overlapping halves along the long side of the part it
    searched, each on MultiPose's whole input, `tile_levels` levels deep, and the people of all
    runs are merged, a person found twice kept once.

    Joints (body.SOURCE_INDEX['mpii16']): the 12 limb joints one-to-one; MPII upper_neck ->
    inference 'neck' and head_top -> 'head', the points the 'direct' head model takes. MPII has
    no ears: with `ears`, the ear joints come from MultiPose's COCO ears (keypoint, and a
    Gaussian of std `sigma` px as their map), which the 'anatomical' head model needs.

    Heatmap source (`heatmaps`): 'efficientpose', the crop model as above; 'multipose' (the
    default), no crop model: each person's joints are MultiPose's own COCO keypoints
    (body.to_inference 'coco17': neck = shoulder midpoint, head = nose), each rendered as a
    Gaussian with its score as peak, of std `keypoint_sigma` times the diagonal of the person's
    box (MultiPose's keypoint error grows with the person's size in the image); 'fused': both,
    per limb joint the pointwise max of the two maps on the crop's grid and the keypoint of the
    source that scores higher.

    Heatmaps: EfficientPose's values (peaks 0.3-0.9, small negatives) are clipped to [0, 1], so a
    map's peak is the joint's confidence; cells below `heatmap_floor` of their map's peak are 0,
    so that sampling a map as a pmf stays near its evidence; a joint whose peak is below
    `min_joint_score` is not detected. Maps are resampled onto an image-aligned grid of `stride`
    px cells, each cut to the cells holding its evidence.
    """

    def __init__(self, config: OnnxDetectorConfig) -> None:
        self.config = config
        providers = check_providers(config.providers)
        model_dir = Path(config.model_dir)
        self._multipose = load_session(model_dir / MULTIPOSE.file, MULTIPOSE, providers, config.threads)
        crops = config.heatmaps != 'multipose'
        self._spec = EFFICIENTPOSE.get(config.model)
        self._efficientpose = (load_session(model_dir / self._spec.file, self._spec, providers, config.threads)
                               if crops and self._spec is not None else None)
        self._single = (SinglePoseModel(model_dir, config.model, providers, config.threads, config.crop_workers)
                        if crops and self._spec is None else None)
        self._crop_side = self._spec.input_side if self._spec is not None else SINGLE_POSE[config.model].side
        # those onnxruntime actually uses
        crop_session = self._single.session if self._single is not None else self._efficientpose
        self.providers = tuple((crop_session or self._multipose).get_providers())
        self.timing = DetectionTiming()
        self._pool = ThreadPoolExecutor(config.multipose_workers) if config.multipose_workers > 1 else None
        self._free_workers = threading.Semaphore(config.multipose_workers)

    def detect(self, bgr: np.ndarray) -> list[Person2D]:
        """The people in bgr (H, W, 3) uint8, each with its 16 inference keypoints and heatmaps;
        self.timing tells how long each step took."""
        return self.detect_set([bgr])[0]

    def detect_set(self, images: Sequence[np.ndarray | None], boxes: Sequence[np.ndarray | None] | None = None,
                   previous: Sequence[np.ndarray] | None = None,
                   sizes: Sequence[tuple[int, int] | None] | None = None,
                   turns: Sequence[int] | None = None) -> list[list[Person2D] | None]:
        """The people of each image (H, W, 3) uint8 BGR of a set (None for a camera without an
        image: None out). boxes: per camera, None to find the people with MultiPose in the whole
        image, else where they are expected: boxes (Q, 4) u0, v0, u1, v1 (pixel edges;
        tracked_crops.projected_boxes). With heatmaps 'multipose' MultiPose then searches only
        the region around them (tracked_crops.people_region; the whole image when Q = 0), at no
        fewer input pixels per image pixel than in the whole image, so a smaller input; else
        EfficientPose takes them as its crops and MultiPose does not run. previous: per camera, the
        inference keypoints (R, 16, 3) of its people in the previous set, whose ears given crops
        carry; sizes: per camera, its (width, height) (None: the image's), of which a smaller image
        is a shrunk copy (reduced_decoding): people come back in the camera's pixels. turns: per
        camera, the quarter turns (np.rot90's) that stand its people up before the networks see
        them (upright.upright_turns; default none): people come back in the camera's own pixels.
        ValueError naming the camera for an image that is not uint8 BGR."""
        return self.finish(self.start_set(images, boxes, previous, sizes, turns))

    def reduced_decoding(self, width: int, height: int, boxes: np.ndarray | None = None) -> int:
        """By how much (1, 2, 4 or 8) an image of a width x height camera may be shrunk before
        detect_set without changing what the detector sees. With heatmaps 'multipose', the most that
        keeps its long side at least SHRUNK_OVERSAMPLING times MultiPose's input side. With a crop
        model, given boxes (Q, 4) (the camera's crops, detect_set's boxes), the most that keeps
        every crop at least as many pixels as the model's input along its long side (8 for none);
        else 1 (MultiPose's people, of any size, become crops)."""
        k = 1
        if self.config.heatmaps != 'multipose':
            if boxes is None:
                return 1
            grown = grown_boxes(np.asarray(boxes, dtype=np.float64).reshape(-1, 4), self.config.box_margin)
            longest = (grown[:, 2:] - grown[:, :2]).max(axis=1)
            least = float(longest.min()) if len(longest) else np.inf
            while k < 8 and least >= 2 * k * self._crop_side:
                k *= 2
            return k
        least = SHRUNK_OVERSAMPLING * self.config.input_size
        while k < 8 and max(width, height) >= 2 * k * least:
            k *= 2
        return k

    def start_set(self, images: Sequence[np.ndarray | None], boxes: Sequence[np.ndarray | None] | None = None,
                  previous: Sequence[np.ndarray] | None = None,
                  sizes: Sequence[tuple[int, int] | None] | None = None,
                  turns: Sequence[int] | None = None) -> PendingSet:
        """detect_set in two steps: check the set and start MultiPose on its images, returning once
        the last of them has a worker; finish() completes it. A caller that starts the next set
        then, while this one finishes, gives its first image the worker this set leaves idle (five
        images on two workers) instead of queueing it behind this set's images."""
        cfg = self.config
        boxes = boxes if boxes is not None else [None] * len(images)
        if len(boxes) != len(images) or (previous is not None and len(previous) != len(images)):
            raise ValueError(f'detect_set: {len(images)} images, {len(boxes)} box lists and '
                             f'{len(previous) if previous is not None else "no"} previous people lists')
        sizes = sizes if sizes is not None else [None] * len(images)
        turns = list(turns) if turns is not None else [0] * len(images)
        if not len(sizes) == len(turns) == len(images):
            raise ValueError(f'detect_set: {len(images)} images, {len(sizes)} sizes and {len(turns)} turns')
        for c, bgr in enumerate(images):
            if bgr is not None and (bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8):
                raise ValueError(f'image{f" of camera {c}" if len(images) > 1 else ""}: expected (H, W, 3) uint8 BGR, '
                                 f'got {bgr.dtype} {bgr.shape}')
        sizes = [None if bgr is None else tuple(size or bgr.shape[1::-1]) for bgr, size in zip(images, sizes)]
        shrinks = [None if bgr is None or bgr.shape[1::-1] == size
                   else np.array(size, dtype=np.float64) / bgr.shape[1::-1] for bgr, size in zip(images, sizes)]
        started = time.perf_counter()
        finds, regions = [], 0
        for bgr, given, size, turn in zip(images, boxes, sizes, turns):
            if bgr is None or not (given is None or cfg.heatmaps == 'multipose'):
                continue
            region = None if given is None or len(given) == 0 else people_region(given, size, cfg.region_margin)
            finds.append(self._start_find(bgr, size, region, turn))
            regions += region is not None
        return PendingSet(list(images), list(boxes), sizes, shrinks, previous, turns, finds, regions, started)

    def _start_find(self, bgr: np.ndarray, size: tuple[int, int], region: np.ndarray | None,
                    turns: int) -> Future[_Found]:
        """_find_people on a free worker, waiting for one (at once without a pool)."""
        if self._pool is None:
            done: Future[_Found] = Future()
            done.set_result(self._find_people(bgr, size, region, turns))
            return done
        self._free_workers.acquire()
        try:
            future = self._pool.submit(self._find_people, bgr, size, region, turns)
        except BaseException:
            self._free_workers.release()
            raise
        future.add_done_callback(lambda _: self._free_workers.release())
        return future

    def finish(self, pending: PendingSet) -> list[list[Person2D] | None]:
        """The people of a set start_set started, as detect_set returns them; self.timing becomes
        this set's. The crops of the cameras given boxes run while MultiPose still searches the
        others (on its workers), then those of the people it found."""
        cfg = self.config
        images, boxes = pending.images, pending.boxes
        out: list[list[Person2D] | None] = [None if bgr is None else [] for bgr in images]
        t0 = time.perf_counter()
        model = 0.0  # seconds in the crop model
        given = [c for c, (bgr, b) in enumerate(zip(images, boxes))
                 if bgr is not None and b is not None and cfg.heatmaps != 'multipose']
        crops = [crop for c in given
                 for crop in self._crops(pending, c, np.asarray(boxes[c], dtype=np.float64), [None] * len(boxes[c]))]
        model += self._add_people(pending, crops, out)
        cropped = {crop.camera for crop in crops}
        t1 = time.perf_counter()
        found_all = [f.result() for f in pending.finds]
        t2 = time.perf_counter()
        searched = [c for c, bgr in enumerate(images) if bgr is not None and c not in given]
        crops = []
        for c, found in zip(searched, found_all):
            inference = self._inference_keypoints(found.keypoints, found.bounds)
            if cfg.heatmaps == 'multipose':
                sigmas = cfg.keypoint_sigma * np.hypot(*(found.boxes[:, 2:] - found.boxes[:, :2]).T)
                out[c] = keypoint_people(inference, sigmas, cfg.stride)
            else:
                crops += self._crops(pending, c, found.boxes, list(inference))
        model += self._add_people(pending, crops, out)
        for c in cropped | {crop.camera for crop in crops}:
            out[c] = without_duplicates(out[c])
        end = time.perf_counter()
        multipose = max((f.done for f in found_all), default=pending.started) - pending.started
        # heatmaps: the set's own work besides the crop model, not counting the wait for MultiPose
        self.timing = DetectionTiming(multipose, model, end - t0 - model - (t2 - t1), end - pending.started,
                                      sum(len(p) for p in out if p is not None), len(found_all), pending.regions,
                                      sum(f.runs - 1 for f in found_all))
        return out

    def _crops(self, pending: PendingSet, camera: int, boxes: np.ndarray,
               keypoints: list[np.ndarray | None]) -> list[_Crop]:
        """The crops of a camera's people boxes (Q, 4) (grown by box_margin), each with its
        MultiPose keypoints (16, 3) or None (given boxes)."""
        boxes = boxes.reshape(-1, 4)
        width, height = pending.sizes[camera]
        sigmas = self.config.keypoint_sigma * np.hypot(*(boxes[:, 2:] - boxes[:, :2]).T)
        return [_Crop(camera, letterbox(width, height, box, self._crop_side, pending.turns[camera]),
                      kp, float(sigma))
                for box, kp, sigma in zip(grown_boxes(boxes, self.config.box_margin), keypoints, sigmas)]

    def _add_people(self, pending: PendingSet, crops: list[_Crop], out: list[list[Person2D] | None]) -> float:
        """The crop model on crops, each one's person added to its camera's list in out; returns
        the seconds the model's runs took."""
        if not crops:
            return 0.0
        images, cfg = pending.images, self.config
        start = time.perf_counter()
        if self._single is not None:  # a single-person keypoint model: its keypoints as Gaussians
            found = self._single.run_cut(lambda i: crops[i].box.apply(images[crops[i].camera],
                                                                      pending.shrinks[crops[i].camera])[..., ::-1],
                                         len(crops))
            took = time.perf_counter() - start
            for crop, coco in zip(crops, found.keypoints):
                out[crop.camera] += keypoint_people(self._crop_keypoints(crop.box, coco)[None],
                                                    np.array([crop.sigma]), cfg.stride)
            return took
        maps = self._heatmaps(images, pending.shrinks, crops)
        took = time.perf_counter() - start
        for crop, raw in zip(crops, maps):
            before = (pending.previous[crop.camera] if pending.previous is not None
                      else np.zeros((0, NUM_INFERENCE_JOINTS, 3)))
            person = self._person(crop, raw, before)
            if person is not None:
                out[crop.camera].append(person)
        return took

    def _find_people(self, bgr: np.ndarray, size: tuple[int, int], region: np.ndarray | None,
                     turns: int, level: int = 0) -> _Found:
        """MultiPose on the letterboxed frame, or on the region (4,) u0, v0, u1, v1 (camera pixel
        edges) of it, turned `turns` quarter turns: people scoring at least min_person_score whose
        box holds pixels of the part searched, in the pixels of a camera of size (width, height),
        of which bgr is a copy (shrunk where smaller). A full run is repeated on tiles of the part
        (crowds, see OnnxPoseDetector's docstring) while `level` is below tile_levels."""
        found, full = self._multipose_run(bgr, size, region, turns, tile=level > 0)
        if not full or level >= self.config.tile_levels:
            return found
        tiles = [self._find_people(bgr, size, tile, turns, level + 1) for tile in crowd_tiles(found.bounds)]
        return _merged([found, *tiles], found.bounds)

    def _multipose_run(self, bgr: np.ndarray, size: tuple[int, int], region: np.ndarray | None,
                       turns: int, tile: bool) -> tuple[_Found, bool]:
        """One MultiPose run of _find_people, and whether it came back full (as many people as the
        model returns, all scoring at least min_person_score). A crowd's tile takes the whole input:
        a crowd's people are small in the image, and MultiPose missed a third of them at the
        whole image's scale (docs/own_cameras.md, Crowds)."""
        shrink = np.array(size, dtype=np.float64) / (bgr.shape[1], bgr.shape[0])  # camera px per bgr px
        if region is None:
            side = self.config.input_size
            lb = whole_image(bgr.shape[1], bgr.shape[0], side, turns)
        else:
            box = (np.asarray(region, dtype=np.float64).reshape(2, 2) + 0.5) / shrink - 0.5
            side = (self.config.input_size if tile else
                    region_input_side(box[1] - box[0], (bgr.shape[1], bgr.shape[0]), self.config.input_size))
            lb = letterbox(bgr.shape[1], bgr.shape[0], box.reshape(4), side, turns)
        rgb = lb.apply(bgr)[None, ..., ::-1].astype(np.int32)  # BGR -> RGB on the small input, not the image
        (out,) = self._multipose.run([MULTIPOSE.output_name], {MULTIPOSE.input_name: rgb})
        rows = out[0]
        n = 3 * _MULTIPOSE_KEYPOINTS
        scoring = rows[:, n + 4] >= self.config.min_person_score
        full = bool(scoring.all())
        rows = rows[scoring]
        # normalised (y, x) -> input pixels: 1.0 is the input's far edge, at pixel side - 0.5
        yx = rows[:, :n].reshape(-1, _MULTIPOSE_KEYPOINTS, 3)
        uv = lb.to_image(yx[..., 1::-1] * side - 0.5)
        ordered = (rows[:, n + 2:n + 4] > rows[:, n:n + 2]).all(axis=1)  # ymax > ymin, xmax > xmin
        corners = lb.to_image(rows[:, [n + 1, n, n + 3, n + 2]].reshape(-1, 2, 2) * side - 0.5)
        corners = np.stack([corners.min(axis=1), corners.max(axis=1)], axis=1)  # a turned box's corners swap
        x0, y0, x1, y1 = lb.roi
        bounds = np.array([x0, y0, x1, y1], dtype=np.float64) - 0.5  # edges of the pixels searched
        if (bgr.shape[1], bgr.shape[0]) != tuple(size):  # a shrunk copy: to the camera's pixels, edges to edges
            uv, corners = (uv + 0.5) * shrink - 0.5, (corners + 0.5) * shrink - 0.5
            bounds = (bounds + 0.5) * np.tile(shrink, 2) - 0.5
        keypoints = np.concatenate([uv, yx[..., 2:]], axis=-1)
        boxes = corners.reshape(-1, 4)
        keep = ordered & ((boxes[:, 2:] > bounds[:2]) & (boxes[:, :2] < bounds[2:])).all(axis=1)
        return _Found(keypoints[keep].astype(np.float64), boxes[keep].astype(np.float64), bounds,
                      time.perf_counter()), full

    def _crop_keypoints(self, lb: Letterbox, coco: np.ndarray) -> np.ndarray:
        """A single-person model's COCO-17 keypoints (17, 3) in its input's pixels as the inference
        joints (16, 3) in the image's: those scoring below min_joint_score or outside the crop's
        region (in its letterbox padding) missing, the ears too without `ears`."""
        coco = np.concatenate([lb.to_image(coco[:, :2]), coco[:, 2:]], axis=1)
        coco[(coco[:, 2] < self.config.min_joint_score) | ~lb.contains(coco[:, :2])] = (np.nan, np.nan, 0.0)
        keypoints = to_inference(coco, 'coco17')
        if not self.config.ears:
            keypoints[list(_EARS)] = (np.nan, np.nan, 0.0)
        return keypoints

    def _inference_keypoints(self, coco: np.ndarray, bounds: np.ndarray) -> np.ndarray:
        """MultiPose's COCO keypoints (P, 17, 3) as inference joints (P, 16, 3): those scoring below
        min_joint_score or outside the part of the image searched, bounds (4,) u0, v0, u1, v1
        (letterbox padding), missing, the ears too without `ears`."""
        keypoints = to_inference(coco, 'coco17')
        with np.errstate(invalid='ignore'):  # NaN rows are missing already
            inside = ((keypoints[..., :2] >= bounds[:2]) & (keypoints[..., :2] <= bounds[2:])).all(axis=-1)
        drop = (keypoints[..., 2] < self.config.min_joint_score) | ~inside
        if not self.config.ears:
            drop[:, _EARS] = True
        keypoints[drop] = (np.nan, np.nan, 0.0)
        return keypoints

    def _heatmaps(self, images: Sequence[np.ndarray | None], shrinks: Sequence[np.ndarray | None],
                  crops: list[_Crop]) -> np.ndarray:
        """EfficientPose heatmaps (N, side, side, 16), channel last, clipped to [0, 1], of the
        letterboxed crops (cut from images, shrunk by shrinks: PendingSet), in runs of at most
        max_batch crops."""
        side = self._spec.input_side
        if not crops:
            return np.zeros((0, side, side, 16), dtype=np.float32)
        batch = self.config.max_batch or len(crops)
        outputs = []
        for first in range(0, len(crops), batch):
            chunk = np.stack([c.box.apply(images[c.camera], shrinks[c.camera])
                              for c in crops[first:first + batch]])[..., ::-1]
            chunk = (chunk.astype(np.float32) * np.float32(1 / 255.0) - _MEAN) / _STD
            (out,) = self._efficientpose.run([self._spec.output_name], {self._spec.input_name: chunk})
            outputs.append(out)
        maps = outputs[0] if len(outputs) == 1 else np.concatenate(outputs)
        return np.clip(maps, 0.0, 1.0, out=maps)

    def _person(self, crop: _Crop, raw: np.ndarray, previous: np.ndarray) -> Person2D | None:
        """One person from its crop's MPII-16 maps raw (side, side, 16), clipped to [0, 1], with
        the crop's ears, or those carried from the camera's previous people's keypoints previous
        (R, 16, 3), and with heatmaps 'fused' the crop's MultiPose keypoints' Gaussians; None when
        no joint is detected."""
        cfg = self.config
        lb = crop.box
        peaks = _peaks(raw)
        mpii = np.concatenate([lb.to_image(peaks[:, :2]), peaks[:, 2:]], axis=1)  # (16, 3) MPII order
        # a peak in the letterbox padding is no detection (and lies outside the maps' grid)
        mpii[(mpii[:, 2] < cfg.min_joint_score) | ~lb.contains(mpii[:, :2]), 2] = 0.0
        keypoints = to_inference(mpii, 'mpii16')
        origin, shape = lb.image_grid(cfg.stride)
        source = SOURCE_INDEX['mpii16']
        has = source >= 0
        maps = np.zeros((NUM_INFERENCE_JOINTS,) + shape, dtype=np.float32)
        maps[has] = lb.maps_to_image(raw[..., source[has]], origin, cfg.stride, shape)
        if cfg.heatmaps == 'fused' and crop.keypoints is not None:
            for joint in np.flatnonzero(_LIMBS & (crop.keypoints[:, 2] > 0) & lb.contains(crop.keypoints[:, :2])):
                np.maximum(maps[joint], _gaussian(crop.keypoints[joint], origin, cfg.stride, shape, crop.sigma),
                           out=maps[joint])
                if crop.keypoints[joint, 2] > keypoints[joint, 2]:
                    keypoints[joint] = crop.keypoints[joint]
        if cfg.ears:
            x0, y0, x1, y1 = lb.roi
            ears = crop.keypoints[list(_EARS)] if crop.keypoints is not None else None
            if ears is None:
                ears = carried_ears(keypoints[NECK], previous, max(x1 - x0, y1 - y0))
            for joint, ear in zip(_EARS, ears):
                if ear[2] >= cfg.min_joint_score and lb.contains(ear[:2]):
                    keypoints[joint] = ear
                    maps[joint] = _gaussian(ear, origin, cfg.stride, shape, cfg.sigma)
        peak = maps.max(axis=(1, 2), keepdims=True)
        maps[(maps < cfg.heatmap_floor * peak) | (keypoints[:, 2] <= 0)[:, None, None]] = 0.0
        if not (keypoints[:, 2] > 0).any():
            return None
        # a crop's maps cover the crop: each is cut to its evidence
        return Person2D(keypoints, PersonHeatmap(maps, origin, float(cfg.stride)).trimmed())


def crowd_tiles(bounds: np.ndarray) -> list[np.ndarray]:
    """The two overlapping tiles (4,) u0, v0, u1, v1 (pixel edges) of the part bounds (4,) (its
    pixel edges) a full MultiPose run searched: each TILE_SHARE of its long side, from either end,
    and the whole short side."""
    lo, hi = np.asarray(bounds[:2], dtype=np.float64), np.asarray(bounds[2:], dtype=np.float64)
    axis = int(np.argmax(hi - lo))
    span = TILE_SHARE * (hi[axis] - lo[axis])
    first, second = np.concatenate([lo, hi]), np.concatenate([lo, hi])
    first[2 + axis] = lo[axis] + span
    second[axis] = hi[axis] - span
    return [first, second]


def _merged(parts: Sequence[_Found], bounds: np.ndarray) -> _Found:
    """The people of several MultiPose runs over one part of an image (its edges bounds), a person
    found by more than one run kept once, as the finding with the higher score sum. A run's own
    people are distinct (MultiPose separates them, even where one hides another), so runs are
    matched one to one: the closest pair of a kept person and a new one first (keypoints within
    DUPLICATE_SEPARATION of their size, see without_duplicates)."""
    keypoints, boxes = parts[0].keypoints, parts[0].boxes
    for part in parts[1:]:
        gaps = np.array([[_keypoint_gap(a, b) for b in part.keypoints] for a in keypoints]).reshape(
            len(keypoints), len(part.keypoints))
        new = np.ones(len(part.keypoints), dtype=bool)
        keypoints, boxes = keypoints.copy(), boxes.copy()
        while gaps.size and gaps.min() < DUPLICATE_SEPARATION:
            k, j = np.unravel_index(np.argmin(gaps), gaps.shape)
            if np.nansum(part.keypoints[j, :, 2]) > np.nansum(keypoints[k, :, 2]):
                keypoints[k], boxes[k] = part.keypoints[j], part.boxes[j]
            new[j] = False
            gaps[k, :] = gaps[:, j] = np.inf
        keypoints = np.concatenate([keypoints, part.keypoints[new]])
        boxes = np.concatenate([boxes, part.boxes[new]])
    return _Found(keypoints, boxes, np.asarray(bounds, dtype=np.float64), max(p.done for p in parts),
                  sum(p.runs for p in parts))


def region_input_side(extent: np.ndarray, image: tuple[int, int], input_size: int) -> int:
    """MultiPose's input side for a region of extent (2,) width, height of an image (width, height)
    whose whole letterbox is input_size: at least as many input pixels per image pixel, rounded up
    to the model's multiple of 32, at most input_size."""
    side = input_size * float(np.max(extent)) / max(image)
    return int(min(input_size, max(32, 32 * np.ceil(side / 32))))


def keypoint_people(keypoints: np.ndarray, sigmas: np.ndarray, stride: float) -> list[Person2D]:
    """People from their inference keypoints (P, 16, 3) u, v, score alone (heatmaps 'multipose'):
    each joint's map a Gaussian of its person's std sigmas (P,) px with the joint's score as peak
    (heatmap.render_heatmaps, cells of stride px), empty for a joint of score 0; people without
    any joint are dropped."""
    keep = (keypoints[..., 2] > 0).any(axis=1)
    return [Person2D(kp, render_heatmaps(kp[None, :, None], stride, float(sigma))[0])
            for kp, sigma in zip(keypoints[keep], sigmas[keep])]


def without_duplicates(people: Sequence[Person2D], separation: float = DUPLICATE_SEPARATION) -> list[Person2D]:
    """One camera's people without duplicates, in their order: of two people whose keypoints (the
    joints both have) lie at a median distance below `separation` times the larger one's size (the
    diagonal of its keypoints' box), the one with the lower score sum goes. EfficientPose finds a
    person in every crop, so two crops on one person (overlapping boxes; a crop projected from an
    occluded person's skeleton) give that person twice, and crops planned from the skeletons that
    then come out keep the duplicate set after set."""
    kept: list[Person2D] = []
    for person in sorted(people, key=lambda p: -np.nansum(p.keypoints[:, 2])):
        if not any(_same_person(person.keypoints, other.keypoints, separation) for other in kept):
            kept.append(person)
    return [p for p in people if any(p is k for k in kept)]


def _same_person(a: np.ndarray, b: np.ndarray, separation: float) -> bool:
    """Whether keypoints a, b (16, 3) u, v, score lie within separation times the larger size."""
    return bool(_keypoint_gap(a, b) < separation)


def _keypoint_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The median distance between the joints keypoints a, b (J, 3) u, v, score both have, over the
    larger one's size (the diagonal of its keypoints' box); inf with fewer than 2 joints in common."""
    both = (a[:, 2] > 0) & (b[:, 2] > 0)
    if both.sum() < 2:
        return float('inf')
    size = max(np.hypot(*np.ptp(k[k[:, 2] > 0, :2], axis=0)) for k in (a, b))
    return float(np.median(np.hypot(*(a[both, :2] - b[both, :2]).T)) / size)


def _peaks(maps: np.ndarray) -> np.ndarray:
    """(J, 3) x, y (input pixels, sub-pixel by a parabola through the maximum and its two
    neighbours along each axis) and value of each map's maximum (maps (h, w, J), channel last)."""
    h, w, n_j = maps.shape
    j = np.arange(n_j)
    best = maps.reshape(-1, n_j).argmax(axis=0)
    row, col = np.divmod(best, w)
    value = maps[row, col, j]

    def offset(lo: np.ndarray, mid: np.ndarray, hi: np.ndarray) -> np.ndarray:
        curvature = lo - 2.0 * mid + hi
        safe = np.where(curvature < 0, curvature, -1.0)
        return np.where(curvature < 0, np.clip(0.5 * (lo - hi) / safe, -0.5, 0.5), 0.0)

    cl, cr = np.maximum(col - 1, 0), np.minimum(col + 1, w - 1)
    rl, rr = np.maximum(row - 1, 0), np.minimum(row + 1, h - 1)
    dx = offset(maps[row, cl, j], value, maps[row, cr, j]) * ((col > 0) & (col < w - 1))
    dy = offset(maps[rl, col, j], value, maps[rr, col, j]) * ((row > 0) & (row < h - 1))
    return np.stack([col + dx, row + dy, value], axis=1).astype(np.float64)


def _gaussian(centre: np.ndarray, origin: np.ndarray, stride: float, shape: tuple[int, int],
              sigma: float) -> np.ndarray:
    """(h, w) map: a Gaussian of std sigma px and peak centre[2] at pixel centre[:2] on the grid,
    cut to 0 beyond MARGIN_SIGMAS * sigma along u or v as heatmap.render_heatmap does."""
    h, w = shape
    du = origin[0] + stride * np.arange(w) - centre[0]
    dv = origin[1] + stride * np.arange(h) - centre[1]
    gu = np.where(np.abs(du) <= MARGIN_SIGMAS * sigma, np.exp(-0.5 * (du / sigma) ** 2), 0.0)
    gv = np.where(np.abs(dv) <= MARGIN_SIGMAS * sigma, np.exp(-0.5 * (dv / sigma) ** 2), 0.0)
    return (min(float(centre[2]), 1.0) * gv[:, None] * gu[None, :]).astype(np.float32)
