"""The ONNX 2D pose models (MoveNet MultiPose, EfficientPose RT / I, the single-person MoveNet
and BlazePose models): what each file must look like (core.detection.onnx_sessions loads and
checks them; this module does not load onnxruntime, so that the parameters naming models cost a
node nothing)."""
from __future__ import annotations

from dataclasses import dataclass

DEFAULT_PROVIDERS = ('CPUExecutionProvider',)


class ModelError(ValueError):
    """A model file that cannot be used (missing, not ONNX, or another model's inputs and
    outputs); the message names the file and the problem."""


@dataclass(frozen=True)
class ModelSpec:
    """A model's file name, its one input and the output used: names, element type, and shape
    (None = any size, e.g. a dynamic batch)."""

    kind: str
    file: str
    input_name: str
    input_type: str
    input_shape: tuple[int | None, ...]
    output_name: str
    output_shape: tuple[int | None, ...]

    @property
    def input_side(self) -> int | None:
        """The fixed square input side (EfficientPose), None when the model takes any size."""
        return self.input_shape[1]


MULTIPOSE = ModelSpec('MoveNet MultiPose', 'movenet_multipose.onnx', 'input', 'tensor(int32)', (1, None, None, 3),
                      'output_0', (1, 6, 56))
EFFICIENTPOSE = {
    variant: ModelSpec(f'EfficientPose {variant.upper()}', f'efficientpose_{variant}.onnx', 'input_res1:0',
                       'tensor(float)', (None, side, side, 3), 'upscaled_confs/BiasAdd:0', (None, side, side, 16))
    for variant, side in (('rt', 224), ('i', 256))
}


COCO_KEYPOINTS = 17


@dataclass(frozen=True)
class SinglePoseSpec:
    """A single-person model: its ModelSpec (input, and the keypoint output checked at load),
    the heatmap output, and for BlazePose the landmark of each COCO-17 joint."""

    spec: ModelSpec
    heatmap_name: str
    offsets_name: str | None  # MoveNet's offsets; None for BlazePose
    landmarks: tuple[int, ...] | None  # BlazePose-33 index of each COCO-17 joint; None for MoveNet

    @property
    def side(self) -> int:
        """The model's square input side, pixels."""
        return int(self.spec.input_shape[1])

    @property
    def movenet(self) -> bool:
        """Whether the model is a MoveNet (keypoints from a heatmap and offsets; BlazePose gives landmarks)."""
        return self.landmarks is None


def _movenet(name: str, side: int) -> SinglePoseSpec:
    spec = ModelSpec(f'MoveNet SinglePose {name.capitalize()}', f'movenet_{name}.onnx', 'input', 'tensor(int32)',
                     (1, side, side, 3), 'keypoints', (1, 1, COCO_KEYPOINTS, 3))
    return SinglePoseSpec(spec, 'heatmap', 'offsets', None)


def _blazepose(name: str) -> SinglePoseSpec:
    spec = ModelSpec(f'BlazePose {name.capitalize()}', f'blazepose_{name}.onnx', 'input', 'tensor(float)',
                     (1, 256, 256, 3), 'landmarks', (1, 195))
    # COCO-17: nose, l/r eye (BlazePose's eye centres), l/r ear, shoulders, elbows, wrists, hips, knees, ankles
    return SinglePoseSpec(spec, 'heatmap', None, (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28))


SINGLE_POSE = {
    'lightning': _movenet('lightning', 192),
    'thunder': _movenet('thunder', 256),
    'blazepose_full': _blazepose('full'),
    'blazepose_heavy': _blazepose('heavy'),
}
