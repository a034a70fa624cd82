"""onnxruntime sessions of the ONNX 2D pose models, checked against their onnx_models.ModelSpec
when they are loaded, so that a wrong file is a clear error at start-up rather than a shape error
on the first image."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import onnxruntime as ort

from mvpose_ros.core.detection.onnx_models import DEFAULT_PROVIDERS, ModelError, ModelSpec


def check_providers(providers: Sequence[str]) -> tuple[str, ...]:
    """The execution providers, ValueError when one is not in this onnxruntime build (which
    would otherwise fall back to the CPU with only a warning)."""
    available = ort.get_available_providers()
    missing = [p for p in providers if p not in available]
    if not providers or missing:
        raise ValueError(f'execution providers {list(providers)}: '
                         f'{"none given" if not providers else f"{missing} not available"} '
                         f'(this onnxruntime has {", ".join(available)})')
    return tuple(providers)


def _shape_matches(shape: Sequence[object], expected: Sequence[int | None]) -> bool:
    # ONNX symbolic dimensions come back as strings (or None): they match a None in the spec only
    return len(shape) == len(expected) and all(e is None or s == e for s, e in zip(shape, expected))


def _describe(args: Sequence[ort.NodeArg]) -> str:
    return ', '.join(f'{a.name} {a.type} {list(a.shape)}' for a in args) or 'none'


def session_options(threads: int = 0) -> ort.SessionOptions:
    """The options of every model session: `threads` intra-op threads (0 = onnxruntime's default,
    one per core), all graph optimisations, operators one after the other, and idle threads that
    sleep instead of spinning."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL  # the models are chains: nothing to run in parallel
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    # Spinning threads burn the cores the Python side (crops, heatmap resampling) and the other
    # nodes need between runs: on 2 loaded cores a set took about twice as long with it.
    options.add_session_config_entry('session.intra_op.allow_spinning', '0')
    options.log_severity_level = 3  # errors only: onnxruntime's warnings are not the user's business
    return options


def load_session(path: str | Path, spec: ModelSpec, providers: Sequence[str] = DEFAULT_PROVIDERS,
                 threads: int = 0) -> ort.InferenceSession:
    """An onnxruntime session of the model file `path` (session_options(threads)), checked against
    `spec`. ModelError when the file is missing, is not an ONNX model, or has other inputs or
    outputs than spec."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f'{path}: {spec.kind} model file not found')
    options = session_options(threads)
    try:
        session = ort.InferenceSession(str(path), options, providers=list(providers))
    except Exception as exc:  # onnxruntime's own exception types (InvalidProtobuf, Fail, ...) share no base
        reason = ' '.join(str(exc).split())
        raise ModelError(f'{path}: not a loadable ONNX model ({reason})') from None
    inputs, outputs = session.get_inputs(), session.get_outputs()
    output = [o for o in outputs if o.name == spec.output_name]
    if not (len(inputs) == 1 and inputs[0].name == spec.input_name and inputs[0].type == spec.input_type
            and _shape_matches(inputs[0].shape, spec.input_shape)
            and output and _shape_matches(output[0].shape, spec.output_shape)):
        expected = (f'input {spec.input_name} {spec.input_type} {list(spec.input_shape)}, output '
                    f'{spec.output_name} {list(spec.output_shape)} (None = any)')
        raise ModelError(f'{path}: not the {spec.kind} model: expected {expected}; the file has input '
                         f'{_describe(inputs)}, output {_describe(outputs)}')
    return session
