"""Single-person keypoint models on square person crops: MoveNet SinglePose Lightning (192 px) and
Thunder (256 px), BlazePose GHUM Full and Heavy (256 px). Each gives one person's COCO-17
keypoints (u, v, score) in its input's pixels (pixel-centre coordinates, as letterbox.Letterbox's)
from its own decoding, and its raw heatmap, whose read-out (heatmap_keypoints) is checked against
that decoding. The four files have a batch axis fixed at 1: a set's crops run one per run, on
`workers` threads at once (onnxruntime's run is thread-safe on one session).
How each model's outputs are read: docs/crop_models.md#how-each-models-output-is-read."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from mvpose_ros.core.detection.onnx_models import COCO_KEYPOINTS, DEFAULT_PROVIDERS, SINGLE_POSE
from mvpose_ros.core.detection.onnx_sessions import load_session


@dataclass
class SinglePoseOutput:
    """The runs on N crops: keypoints (N, 17, 3) COCO-17 u, v (input pixels) and score in [0, 1];
    heatmap (N, h, w, C) raw, channel last; offsets (N, h, w, 2C) (MoveNet) or None."""

    keypoints: np.ndarray
    heatmap: np.ndarray
    offsets: np.ndarray | None


class SinglePoseModel:
    """One session of a single-person model (SINGLE_POSE[name]), checked at load."""

    def __init__(self, model_dir: str | Path, name: str, providers: Sequence[str] = DEFAULT_PROVIDERS,
                 threads: int = 0, workers: int = 1) -> None:
        if name not in SINGLE_POSE:
            raise ValueError(f'single-person model {name!r} is not one of {", ".join(SINGLE_POSE)}')
        if workers < 1:
            raise ValueError(f'crop workers {workers} must be >= 1')
        self.model = SINGLE_POSE[name]
        self.session = load_session(Path(model_dir) / self.model.spec.file, self.model.spec, providers, threads)
        self._outputs = [self.model.spec.output_name, self.model.heatmap_name] + (
            [self.model.offsets_name] if self.model.offsets_name else [])
        self._pool = ThreadPoolExecutor(workers) if workers > 1 else None

    @property
    def side(self) -> int:
        """The model's square input side, pixels."""
        return self.model.side

    def run(self, rgb: np.ndarray) -> SinglePoseOutput:
        """The model on crops rgb (N, side, side, 3) uint8 RGB, one run per crop."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 4 or rgb.shape[1:] != (self.side, self.side, 3) or rgb.dtype != np.uint8:
            raise ValueError(f'{self.model.spec.kind}: expected crops (N, {self.side}, {self.side}, 3) uint8 RGB, '
                             f'got {rgb.dtype} {rgb.shape}')
        return self.run_cut(rgb.__getitem__, len(rgb))

    def run_cut(self, cut: Callable[[int], np.ndarray], n: int) -> SinglePoseOutput:
        """The model on n crops, crop i (side, side, 3) uint8 RGB made by cut(i) on the worker that
        runs it (cutting a crop from its image is part of each crop's work, side by side)."""
        runs = (self._pool.map(lambda i: self._one(cut(i)), range(n)) if self._pool is not None and n > 1
                else (self._one(cut(i)) for i in range(n)))
        outs = list(runs)
        if not outs:
            c = 17 if self.model.movenet else 39
            m = self.side // 4
            empty = np.zeros((0, m, m, c), dtype=np.float32)
            return SinglePoseOutput(np.zeros((0, COCO_KEYPOINTS, 3)), empty,
                                    np.zeros((0, m, m, 2 * c), dtype=np.float32) if self.model.movenet else None)
        keypoints = np.stack([o[0] for o in outs])
        heatmap = np.concatenate([o[1] for o in outs])
        offsets = np.concatenate([o[2] for o in outs]) if self.model.movenet else None
        return SinglePoseOutput(keypoints, heatmap, offsets)

    def _one(self, rgb: np.ndarray) -> tuple[np.ndarray, ...]:
        """One crop (side, side, 3): its COCO-17 keypoints (17, 3) and the raw maps (1, h, w, C)."""
        if self.model.movenet:
            x = rgb[None].astype(np.int32)
        else:
            x = rgb[None].astype(np.float32) * np.float32(1 / 255.0)
        outs = self.session.run(self._outputs, {self.model.spec.input_name: x})
        return (self.decode(outs[0]),) + tuple(outs[1:])

    def decode(self, raw: np.ndarray) -> np.ndarray:
        """(17, 3) COCO-17 u, v (input pixels) and score of one run's keypoint output."""
        if self.model.movenet:
            yx = np.asarray(raw, dtype=np.float64).reshape(COCO_KEYPOINTS, 3)
            return np.concatenate([yx[:, 1::-1] * self.side - 0.5, yx[:, 2:]], axis=1)
        landmarks = np.asarray(raw, dtype=np.float64).reshape(-1, 5)[list(self.model.landmarks)]
        # x, y are pixel edges (0 = the input's left edge); visibility is a logit
        return np.concatenate([landmarks[:, :2] - 0.5, 1.0 / (1.0 + np.exp(-landmarks[:, 3:4]))], axis=1)

    def heatmap_keypoints(self, heatmap: np.ndarray, offsets: np.ndarray | None = None) -> np.ndarray:
        """(17, 3) COCO-17 u, v (input pixels) and map value at each joint's heatmap argmax, for one
        crop's heatmap (h, w, C) (and MoveNet's offsets (h, w, 2C), which place the joint inside the
        cell; BlazePose: the argmax cell's centre). MoveNet's value is its sigmoid score; BlazePose's
        raw."""
        heatmap = np.asarray(heatmap)
        h, w, _ = heatmap.shape
        channels = np.arange(COCO_KEYPOINTS) if self.model.movenet else np.array(self.model.landmarks)
        flat = heatmap[..., channels].reshape(-1, len(channels))
        row, col = np.divmod(flat.argmax(axis=0), w)
        value = flat[row * w + col, np.arange(len(channels))]
        if self.model.movenet:
            if offsets is None:
                raise ValueError('MoveNet heatmap read-out needs its offsets')
            dy = offsets[row, col, 2 * channels]
            dx = offsets[row, col, 2 * channels + 1]
            y, x = (row + dy) / h * self.side - 0.5, (col + dx) / w * self.side - 0.5
        else:
            y, x = (row + 0.5) * self.side / h - 0.5, (col + 0.5) * self.side / w - 0.5
        return np.stack([x, y, value], axis=1).astype(np.float64)
