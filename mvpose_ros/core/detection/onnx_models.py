"""The ONNX 2D pose models (MoveNet MultiPose, EfficientPose RT / I): what each file must look
like (core.detection.onnx_sessions loads and checks them; this module does not load
onnxruntime, so that the parameters naming models cost a node nothing)."""
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
