"""The ONNX detector's settings (core.detection.onnx_detector), apart from the detector so that a
node can declare them without loading onnxruntime and OpenCV."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mvpose_ros.core.detection.onnx_models import DEFAULT_PROVIDERS, EFFICIENTPOSE, SINGLE_POSE

MODELS = tuple(EFFICIENTPOSE) + tuple(SINGLE_POSE)  # 'rt', 'i', then the single-person keypoint models
HEATMAP_SOURCES = ('efficientpose', 'multipose', 'fused')


@dataclass(frozen=True)
class OnnxDetectorConfig:
    """model_dir: folder of the .onnx files (<data root>/models). model: the crop model, one of MODELS:
    EfficientPose 'rt' (224 px crops) or 'i' (256 px), or a single-person keypoint model (see the
    core.detection.onnx_detector's docstring); crop_workers: crops those run at once. providers: onnxruntime execution
    providers in order of preference; threads: intra-op threads per session (0 = one per core).
    input_size: MultiPose's square input side (a multiple of 32). box_margin: each side of a
    MultiPose box grows by this fraction of the box's width (height) before the crop.
    min_person_score: MultiPose people below it are dropped. min_joint_score, heatmap_floor, stride:
    see the module docstring. ears: fill the ear joints from MultiPose's COCO ears, rendered as
    Gaussians of std sigma px. max_batch: EfficientPose crops per run (0 = all crops of a set in one
    run): on a CPU small runs are as fast as one large one, whose tensors leave the cache; a GPU
    gains from 0. heatmaps: one of HEATMAP_SOURCES, see the
    module docstring; keypoint_sigma: the std of the Gaussians of MultiPose's keypoints there, as a
    fraction of the person's box diagonal. multipose_workers: images of a set MultiPose runs on at
    once, each run with `threads` intra-op threads: one run keeps a CPU's cores busy only part of the
    time, so two workers of one thread each beat one worker of every core.
    region_margin: with heatmaps 'multipose' and given boxes, each box grows by this fraction of its
    size before MultiPose searches the region holding them all (tracked_crops.people_region).
    tile_levels: a MultiPose run that comes back full (6 people, all scoring min_person_score) is
    repeated on two overlapping halves of the part it searched, down to this many levels (0: never;
    see the module docstring)."""

    model_dir: Path
    model: str = 'rt'
    crop_workers: int = 1
    providers: tuple[str, ...] = DEFAULT_PROVIDERS
    threads: int = 0
    input_size: int = 384
    box_margin: float = 0.1
    min_person_score: float = 0.25
    min_joint_score: float = 0.1
    heatmap_floor: float = 0.1
    stride: float = 4.0
    ears: bool = True
    sigma: float = 6.0
    max_batch: int = 4
    heatmaps: str = 'multipose'
    keypoint_sigma: float = 0.025
    multipose_workers: int = 1
    region_margin: float = 0.25
    tile_levels: int = 2

    def __post_init__(self) -> None:
        problems = []
        if self.model not in MODELS:
            problems.append(f'model {self.model!r} is not one of {", ".join(MODELS)}')
        if self.heatmaps not in HEATMAP_SOURCES:
            problems.append(f'heatmaps {self.heatmaps!r} is not one of {", ".join(HEATMAP_SOURCES)}')
        if not (self.input_size >= 32 and self.input_size % 32 == 0):
            problems.append(f'input_size {self.input_size} is not a positive multiple of 32')
        if self.threads < 0 or self.max_batch < 0:
            problems.append(f'threads {self.threads} and max_batch {self.max_batch} must be >= 0')
        if self.heatmaps == 'fused' and self.model in SINGLE_POSE:
            problems.append(f"heatmaps 'fused' needs an EfficientPose model ({', '.join(EFFICIENTPOSE)}), "
                            f'not {self.model!r}')
        if self.multipose_workers < 1:
            problems.append(f'multipose_workers {self.multipose_workers} must be >= 1')
        if self.crop_workers < 1:
            problems.append(f'crop_workers {self.crop_workers} must be >= 1')
        if not 0 <= self.tile_levels <= 4:
            problems.append(f'tile_levels {self.tile_levels} must lie in 0..4')
        if not (self.box_margin >= 0 and self.region_margin >= 0):
            problems.append(f'box_margin {self.box_margin} and region_margin {self.region_margin} must be >= 0')
        if not (0 <= self.min_person_score <= 1 and 0 <= self.min_joint_score <= 1 and 0 <= self.heatmap_floor < 1):
            problems.append(f'min_person_score {self.min_person_score}, min_joint_score {self.min_joint_score} '
                            f'must lie in [0, 1] and heatmap_floor {self.heatmap_floor} in [0, 1)')
        if not (self.stride > 0 and self.sigma > 0):
            problems.append(f'stride {self.stride} and sigma {self.sigma} must be > 0')
        if not self.keypoint_sigma > 0:
            problems.append(f'keypoint_sigma {self.keypoint_sigma} must be > 0')
        if problems:
            raise ValueError('; '.join(problems))
